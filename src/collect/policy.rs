//! The policies `collect` runs: the scripted experts and trained actors (`checkpoint:FILE`),
//! optionally noisy, and uniform random actions, each drawing from its own episode's generator.
//!
//! Why here and not in `env`: a `checkpoint:FILE` policy is a trained actor
//! ([`crate::agent::HostActor`]), and `env` sits below `agent` (the simulator knows nothing of
//! learning). `collect` is the lowest module that sees both, and the only one that runs these
//! policies. `eval` does not share them: its `Policy` trait is deterministic and
//! batched (one forward pass for every live episode of a stack per step), while these act one
//! observation at a time inside the worker that owns the episode, drawing noise from that
//! episode's own generator. One trait for both would have to be the slower shape for one of them.
//!
//! An episode's randomness depends on (seed, episode index) only, never on the thread that
//! simulates it: episode i draws from numpy's `default_rng(SeedSequence(seed,
//! spawn_key=(i,)))`, i.e. child i of `SeedSequence(seed).spawn(n)`, numpy's own recipe for
//! independent parallel streams. Per step, in this order:
//! * random policy: `rng.uniform(-1, 1, size=act_dim)`;
//! * expert or checkpoint with `epsilon` > 0: one `rng.random()`; below epsilon the action is a random one as
//!   above and nothing else is drawn;
//! * expert or checkpoint with `noise` > 0: per action value a standard normal from two `rng.random()` draws
//!   (Box–Muller, [`NpRandom::standard_normal`]), scaled by `noise` and added; then the action
//!   is clipped to [−1, 1].

use std::path::Path;
use std::sync::Arc;

use anyhow::{Result, bail};

use crate::agent::HostActor;
use crate::env::Obs;
use crate::env::expert::Expert;
use crate::nprandom::NpRandom;

/// Which policy acts.
#[derive(Debug, Clone)]
pub enum PolicyKind {
    Expert,
    Random,
    /// A trained actor (agent 0 of a pgser checkpoint), shared by every worker.
    Checkpoint(Arc<HostActor>),
    /// OGBench's scripted oracle with its dataset recipe (`collect::ogbench`): a whole episode
    /// generator of its own rather than a per-step policy.
    Oracle,
}

impl PolicyKind {
    /// `expert`, `random`, or `checkpoint:FILE` (the file is read here).
    pub fn parse(name: &str) -> Result<PolicyKind> {
        match name {
            "expert" => Ok(PolicyKind::Expert),
            "random" => Ok(PolicyKind::Random),
            "oracle" => Ok(PolicyKind::Oracle),
            _ => match name.strip_prefix("checkpoint:") {
                Some(file) if !file.is_empty() => {
                    Ok(PolicyKind::Checkpoint(Arc::new(HostActor::load(Path::new(file))?)))
                }
                _ => bail!("unknown policy '{name}': use expert, random, oracle or checkpoint:FILE"),
            },
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            PolicyKind::Expert => "expert",
            PolicyKind::Random => "random",
            PolicyKind::Checkpoint(_) => "checkpoint",
            PolicyKind::Oracle => "oracle",
        }
    }
}

impl PolicyKind {
    /// The action noise when none is given: OGBench's σ = 0.5 for its oracle data, else none.
    pub fn default_noise(&self) -> f64 {
        if *self == PolicyKind::Oracle { crate::env::pointmaze::ORACLE_NOISE } else { 0.0 }
    }

    /// What a table's footer records: the name, and for a checkpoint its file.
    pub fn describe(&self) -> String {
        match self {
            PolicyKind::Checkpoint(a) => format!("checkpoint:{}", a.source),
            other => other.name().to_string(),
        }
    }
}

impl PartialEq for PolicyKind {
    fn eq(&self, other: &PolicyKind) -> bool {
        match (self, other) {
            (PolicyKind::Checkpoint(a), PolicyKind::Checkpoint(b)) => Arc::ptr_eq(a, b),
            _ => self.name() == other.name(),
        }
    }
}

/// A policy and its exploration settings.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicySpec {
    pub kind: PolicyKind,
    /// Standard deviation of Gaussian noise added to each expert or checkpoint action value.
    pub noise: f64,
    /// Probability of replacing an expert or checkpoint action by a uniform random one.
    pub epsilon: f64,
}

impl PolicySpec {
    /// Refuse settings that make no sense rather than silently ignoring them.
    pub fn validate(&self) -> Result<()> {
        if !(self.noise.is_finite() && self.noise >= 0.0) {
            bail!("--noise must be a finite standard deviation ≥ 0, got {}", self.noise);
        }
        if !(0.0..=1.0).contains(&self.epsilon) {
            bail!("--epsilon must be a probability in [0, 1], got {}", self.epsilon);
        }
        if self.kind == PolicyKind::Random && (self.noise > 0.0 || self.epsilon > 0.0) {
            bail!("--noise and --epsilon perturb the expert or a checkpoint; the random policy takes neither");
        }
        Ok(())
    }
}

/// Who picks the actions of an episode before any noise.
enum Actor {
    Random,
    Expert(Expert),
    Trained(Arc<HostActor>),
}

/// One episode's policy: its actor and the episode's generator.
pub struct EpisodePolicy {
    spec: PolicySpec,
    actor: Actor,
    rng: NpRandom,
}

impl EpisodePolicy {
    /// The policy for episode `episode` of a run seeded with `seed`.
    pub fn new(spec: PolicySpec, task: &str, seed: u64, episode: u64) -> Result<EpisodePolicy> {
        spec.validate()?;
        let actor = match &spec.kind {
            PolicyKind::Random => Actor::Random,
            PolicyKind::Expert => match Expert::for_task(task) {
                Some(e) => Actor::Expert(e),
                None => bail!(
                    "{task}: pgser has no scripted expert for this task (a trained one: --policy checkpoint:FILE)"
                ),
            },
            PolicyKind::Checkpoint(a) => {
                let t = crate::task::Task::known(task).map_or_else(|| task.to_string(), |t| t.name);
                if a.task.name != t {
                    bail!("--policy checkpoint: the checkpoint's actor was trained on {}, not {t}", a.task.name);
                }
                Actor::Trained(a.clone())
            }
            PolicyKind::Oracle => bail!("{task}: the oracle makes OGBench's datasets (collect::ogbench), not steps"),
        };
        Ok(EpisodePolicy { spec, actor, rng: NpRandom::spawned(seed, &[episode]) })
    }

    /// Write the action for `obs` into `out` (the task's act_dim values, within [−1, 1]).
    pub fn act(&mut self, obs: &Obs, out: &mut [f64]) {
        if matches!(self.actor, Actor::Random) || (self.spec.epsilon > 0.0 && self.rng.random() < self.spec.epsilon) {
            return self.uniform(out);
        }
        match &self.actor {
            Actor::Expert(expert) => {
                let a = expert.act(obs);
                assert_eq!(out.len(), a.len(), "the {expert:?} expert acts in {} dimensions", a.len());
                out.copy_from_slice(&a);
            }
            Actor::Trained(actor) => actor.act(&obs.observation, &obs.desired_goal, out),
            Actor::Random => unreachable!("handled above"),
        }
        if self.spec.noise > 0.0 {
            for x in out.iter_mut() {
                *x += self.spec.noise * self.rng.standard_normal();
            }
        }
        for x in out.iter_mut() {
            *x = x.clamp(-1.0, 1.0);
        }
    }

    fn uniform(&mut self, out: &mut [f64]) {
        for x in out.iter_mut() {
            *x = self.rng.uniform(-1.0, 1.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(kind: PolicyKind, noise: f64, epsilon: f64) -> PolicySpec {
        PolicySpec { kind, noise, epsilon }
    }

    fn obs() -> Obs {
        Obs {
            observation: vec![1.3, 0.7, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            achieved_goal: vec![1.3, 0.7, 0.5],
            desired_goal: vec![1.32, 0.7, 0.5],
        }
    }

    #[test]
    fn random_actions_are_numpy_uniforms_of_the_spawned_stream() {
        let mut p = EpisodePolicy::new(spec(PolicyKind::Random, 0.0, 0.0), "FetchReach", 5, 3).unwrap();
        let mut a = [0.0; 4];
        p.act(&obs(), &mut a);
        let mut rng = NpRandom::spawned(5, &[3]);
        let want: [f64; 4] = rng.uniform_n(-1.0, 1.0);
        assert_eq!(a, want);
    }

    #[test]
    fn noise_perturbs_and_actions_stay_in_the_box() {
        let mut clean = EpisodePolicy::new(spec(PolicyKind::Expert, 0.0, 0.0), "FetchReach", 0, 0).unwrap();
        let mut noisy = EpisodePolicy::new(spec(PolicyKind::Expert, 0.5, 0.0), "FetchReach", 0, 0).unwrap();
        let (mut a, mut b) = ([0.0; 4], [0.0; 4]);
        clean.act(&obs(), &mut a);
        assert!((a[0] - 0.4).abs() < 1e-12 && a[1..] == [0.0; 3], "{a:?}");
        let mut moved = 0;
        for _ in 0..50 {
            noisy.act(&obs(), &mut b);
            assert!(b.iter().all(|x| (-1.0..=1.0).contains(x)));
            moved += (b != a) as usize;
        }
        assert_eq!(moved, 50);
        // Same seed and episode, same stream; another episode, another stream.
        let draw = |ep| {
            let mut p = EpisodePolicy::new(spec(PolicyKind::Expert, 0.5, 0.0), "FetchReach", 0, ep).unwrap();
            let mut x = [0.0; 4];
            p.act(&obs(), &mut x);
            x
        };
        assert_eq!(draw(1), draw(1));
        assert_ne!(draw(1), draw(2));
    }

    #[test]
    fn epsilon_one_is_the_random_policy_after_one_coin() {
        let mut p = EpisodePolicy::new(spec(PolicyKind::Expert, 0.0, 1.0), "FetchReach", 2, 0).unwrap();
        let mut a = [0.0; 4];
        p.act(&obs(), &mut a);
        let mut rng = NpRandom::spawned(2, &[0]);
        rng.random();
        assert_eq!(a, rng.uniform_n::<4>(-1.0, 1.0));
    }

    #[test]
    fn nonsense_settings_are_refused() {
        let e = |s: PolicySpec| s.validate().unwrap_err().to_string();
        assert!(e(spec(PolicyKind::Random, 0.1, 0.0)).contains("random policy"));
        assert!(e(spec(PolicyKind::Expert, -1.0, 0.0)).contains("--noise"));
        assert!(e(spec(PolicyKind::Expert, f64::NAN, 0.0)).contains("--noise"));
        assert!(e(spec(PolicyKind::Expert, 0.0, 1.5)).contains("--epsilon"));
        assert!(PolicyKind::parse("greedy").unwrap_err().to_string().contains("checkpoint:FILE"));
        assert!(PolicyKind::parse("checkpoint:").is_err());
        let e = PolicyKind::parse("checkpoint:/nonexistent/a.ckpt").err().unwrap().to_string();
        assert!(e.contains("/nonexistent/a.ckpt"), "{e}");
        let p = EpisodePolicy::new(spec(PolicyKind::Expert, 0.0, 0.0), "PointReach", 0, 0);
        assert!(p.err().unwrap().to_string().contains("no scripted expert"));
    }
}
