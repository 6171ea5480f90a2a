//! TD3 and TD3+BC for goal-conditioned offline data, and DDPG for online HER, one update top to
//! bottom.
//!
//! Follows sfujim/TD3_BC `TD3_BC.py` (losses, noise, delay, Polyak) with GoFAR's
//! goal-conditioned settings (normalized [s, g] inputs, γ = 0.98, target clipped to
//! [−1/(1−γ), 0], no terminal masking: a goal-reaching task never ends early); docs/domain.md.
//! DDPG is the same update with one critic, no target noise and MRN's actor loss (docs/online.md).

use burn::tensor::activation::tanh;
use burn::tensor::{Device, Tensor, TensorData};

use anyhow::{Result, bail};

use super::engine::{Batch, Engine, EngineKind, Net, Nets, Rows, State, Stats, Table};
use super::fused::{self, Fused, Product};
use super::{Adam, AgentConfig, Algo, Arithmetic, Member, Mlp, Normalizer, host, init_member};
use crate::nprandom::NpRandom;
use crate::task::Task;

/// Losses of one update per agent (`[A]` tensors), left on the device: reading them forces a
/// sync, so the trainer reads them only when it logs.
pub struct UpdateStats {
    pub critic_loss: Tensor<1>,
    pub q_mean: Tensor<1>,
    pub actor_loss: Option<Tensor<1>>,
}

impl UpdateStats {
    /// (critic loss, mean Q, actor loss if the actor moved) of each agent.
    pub fn read(&self) -> Vec<(f64, f64, Option<f64>)> {
        let values = |t: &Tensor<1>| host(t.clone()).1.into_iter().map(f64::from).collect::<Vec<f64>>();
        let (critic, q) = (values(&self.critic_loss), values(&self.q_mean));
        let actor = self.actor_loss.as_ref().map(values);
        (0..critic.len()).map(|i| (critic[i], q[i], actor.as_ref().map(|a| a[i]))).collect()
    }
}

/// y = clip(r + γ·min(Q1', Q2')(s', g, ã), −1/(1−γ), 0). No (1 − done) factor: reaching a goal
/// does not end a WGCSL episode, so every transition bootstraps.
pub fn td_target<const D: usize>(c: &AgentConfig, reward: Tensor<D>, next_q: Tensor<D>) -> Tensor<D> {
    let (lo, hi) = c.target_range();
    (reward + next_q.mul_scalar(c.gamma)).clamp(lo, hi)
}

/// A learners that train side by side in one set of stacked tensors: same settings and task,
/// each with its own seed (initial weights, target noise), normalizer and batches. Every layer
/// of every network is one batched matmul over the agents, which is what keeps both CPU cores,
/// or a GPU, busy with networks this small. A = 1 is a single agent. Field order is the order
/// of the algorithm.
pub struct Agent {
    pub config: AgentConfig,
    pub task: Task,
    /// Agent i's input normalizer (fitted on its own data).
    pub norms: Vec<Normalizer>,
    pub device: Device,
    /// A actors.
    pub actor: Mlp,
    /// K·A critics (K = `config.algo.critics()`): agent i's are members K·i .. K·i + K − 1 (TD3's
    /// twins an ensemble of two, DDPG's one critic).
    pub critics: Mlp,
    pub actor_target: Mlp,
    pub critics_target: Mlp,
    pub actor_opt: Adam,
    pub critics_opt: Adam,
    /// Critic updates done so far (the same for every agent: they move in lockstep).
    pub updates: u64,
    /// Agent i's target-policy smoothing noise stream.
    pub noise_rngs: Vec<NpRandom>,
    /// The hand-written engine (`engine.rs`: the CPU's or the GPU's), when this stack trains on
    /// one: it then holds the newest networks, targets and Adam state, and the burn fields above
    /// are as of the last `sync` (`stale` says whether updates came since). Checkpoints are
    /// written from the burn fields and refuse a stale agent, so a missed `sync` fails loudly,
    /// never silently.
    pub(super) engine: Option<Box<dyn Engine>>,
    stale: bool,
}

/// Layer sizes of the actor ([s, g] → action) and of each critic ([s, g, a] → Q).
pub fn net_sizes(config: &AgentConfig, task: &Task) -> (Vec<usize>, Vec<usize>) {
    let (o, g, a, h) = (task.obs_dim, task.goal_dim, task.act_dim, config.hidden);
    let actor = [o + g].into_iter().chain(vec![h; config.layers]).chain([a]).collect();
    let critic = [o + g + a].into_iter().chain(vec![h; config.layers]).chain([1]).collect();
    (actor, critic)
}

/// Spawn keys of the agent's random streams under the run's seed.
const STREAM_INIT: u64 = 1;
const STREAM_NOISE: u64 = 2;

impl Agent {
    /// One agent: a stack of one.
    pub fn new(config: AgentConfig, task: Task, norm: Normalizer, seed: u64, device: Device) -> Agent {
        Agent::stack_new(config, task, vec![norm], &[seed], device)
    }

    /// `seeds.len()` agents, agent i with `norms[i]` and `seeds[i]`; each has the initial
    /// weights and noise it would have alone.
    pub fn stack_new(config: AgentConfig, task: Task, norms: Vec<Normalizer>, seeds: &[u64], device: Device) -> Agent {
        assert_eq!(norms.len(), seeds.len(), "one normalizer per agent");
        let (actor_sizes, critic_sizes) = net_sizes(&config, &task);
        let (mut actors, mut critics) = (Vec::new(), Vec::new());
        for &seed in seeds {
            // Per agent, in this order from its own stream: actor, critic 1, critic 2.
            let mut init = NpRandom::spawned(seed, &[STREAM_INIT]);
            actors.push(init_member(&actor_sizes, &mut init));
            for _ in 0..config.algo.critics() {
                critics.push(init_member(&critic_sizes, &mut init));
            }
        }
        let actor = Mlp::from_members(&actors, &device);
        let critics = Mlp::from_members(&critics, &device);
        let lr = config.lr();
        Agent {
            actor_opt: Adam::new(lr, &actor),
            critics_opt: Adam::new(lr, &critics),
            actor_target: actor.copy(),
            critics_target: critics.copy(),
            actor,
            critics,
            updates: 0,
            noise_rngs: seeds.iter().map(|&s| NpRandom::spawned(s, &[STREAM_NOISE])).collect(),
            engine: None,
            stale: false,
            config,
            task,
            norms,
            device,
        }
    }

    /// Agents trained separately (same settings, task and update count) as one stack, in order,
    /// on burn's engine (`fuse` moves it to the CPU engine).
    pub fn stack(mut parts: Vec<Agent>) -> Agent {
        parts.iter_mut().for_each(Agent::sync);
        let first = &parts[0];
        for p in &parts[1..] {
            assert!(p.config == first.config && p.task == first.task && p.updates == first.updates);
        }
        let cat = |f: fn(&Agent) -> &Mlp| Mlp::concat(&parts.iter().map(f).collect::<Vec<_>>());
        let opt = |f: fn(&Agent) -> &Adam| Adam::concat(&parts.iter().map(f).collect::<Vec<_>>());
        Agent {
            actor: cat(|p| &p.actor),
            critics: cat(|p| &p.critics),
            actor_target: cat(|p| &p.actor_target),
            critics_target: cat(|p| &p.critics_target),
            actor_opt: opt(|p| &p.actor_opt),
            critics_opt: opt(|p| &p.critics_opt),
            norms: parts.iter().flat_map(|p| p.norms.clone()).collect(),
            noise_rngs: parts.iter().flat_map(|p| p.noise_rngs.clone()).collect(),
            config: first.config.clone(),
            task: first.task.clone(),
            updates: first.updates,
            device: first.device.clone(),
            engine: None,
            stale: false,
        }
    }

    /// Trains from now on with the hand-written CPU engine (`fused/`), from the current state.
    pub fn fuse(&mut self) {
        self.attach(EngineKind::Cpu).expect("the CPU engine starts without fail");
    }

    /// Trains from now on with the hand-written engine `kind`, from the current state (a no-op
    /// when it already trains on a hand-written engine). Fails where the engine cannot start
    /// (no GPU, no driver), in one line.
    pub fn attach(&mut self, kind: EngineKind) -> Result<()> {
        if self.engine.is_some() {
            return Ok(());
        }
        let (actor_sizes, critic_sizes) = super::net_sizes(&self.config, &self.task);
        if kind != EngineKind::Cpu && !self.config.arithmetic.is_native() {
            bail!(
                "--arithmetic {}: only the CPU engine (--device cpu) has it; a GPU rounds as its own library does",
                self.config.arithmetic.name()
            );
        }
        let state = self.burn_state();
        self.engine = Some(match kind {
            EngineKind::Cpu => Box::new(Fused::with_product(
                &actor_sizes,
                &critic_sizes,
                state.nets,
                state.actor_step,
                state.critic_step,
                Product::of(self.config.arithmetic),
            )),
            EngineKind::Cuda(precision) => Box::new(super::cuda::CudaEngine::new(
                super::cuda::open(0, precision)?,
                &actor_sizes,
                &critic_sizes,
                self.task.obs_dim,
                &state.nets,
                &self.norms,
                state.actor_step,
                state.critic_step,
            )?),
        });
        Ok(())
    }

    /// The burn fields' training state in the engines' flat layout.
    pub(in crate::agent) fn burn_state(&self) -> State {
        let k = self.config.algo.critics();
        let flat = |m: &Member| fused::flatten(m);
        let (actor, actor_target, critics, critics_target) =
            (self.actor.tensors(), self.actor_target.tensors(), self.critics.tensors(), self.critics_target.tensors());
        let net = |p: &[(Vec<usize>, Vec<f32>)], t: &[(Vec<usize>, Vec<f32>)], opt: &Adam, j: usize| {
            let (m, v) = opt.member(j);
            Net { p: flat(&super::member_of(p, j)), m: flat(&m), v: flat(&v), target: flat(&super::member_of(t, j)) }
        };
        let nets = (0..self.agents())
            .map(|i| Nets {
                actor: net(&actor, &actor_target, &self.actor_opt, i),
                critics: (0..k).map(|c| net(&critics, &critics_target, &self.critics_opt, k * i + c)).collect(),
            })
            .collect();
        State { nets, actor_step: self.actor_opt.step, critic_step: self.critics_opt.step }
    }

    /// Writes the engine's state back into the burn fields (a no-op when they are current).
    /// Panics if the engine cannot give its state back (a GPU lost mid-run), so no checkpoint is
    /// ever written from old fields.
    pub fn sync(&mut self) {
        let Some(e) = self.engine.as_deref() else { return };
        if !self.stale {
            return;
        }
        let state = e.state().unwrap_or_else(|err| panic!("reading the training state back from the engine: {err:#}"));
        let (k, d, lr) = (self.config.algo.critics(), &self.device, self.config.lr());
        let (actor_sizes, critic_sizes) = super::net_sizes(&self.config, &self.task);
        let unflat = |v: &Vec<f32>, sizes: &[usize]| fused::unflatten(v, sizes);
        let actors = |pick: fn(&Net) -> &Vec<f32>| {
            state.nets.iter().map(|n| unflat(pick(&n.actor), &actor_sizes)).collect::<Vec<_>>()
        };
        let critics = |pick: fn(&Net) -> &Vec<f32>| {
            state.nets.iter().flat_map(|n| n.critics.iter().map(|c| unflat(pick(c), &critic_sizes))).collect::<Vec<_>>()
        };
        debug_assert!(state.nets.iter().all(|n| n.critics.len() == k));
        self.actor = Mlp::from_members(&actors(|n| &n.p), d);
        self.actor_target = Mlp::from_members(&actors(|n| &n.target), d);
        self.actor_opt = Adam::from_members(lr, state.actor_step, &actors(|n| &n.m), &actors(|n| &n.v), d);
        self.critics = Mlp::from_members(&critics(|n| &n.p), d);
        self.critics_target = Mlp::from_members(&critics(|n| &n.target), d);
        self.critics_opt = Adam::from_members(lr, state.critic_step, &critics(|n| &n.m), &critics(|n| &n.v), d);
        self.stale = false;
    }

    /// Whether updates on the hand-written engine came since the last `sync`.
    pub fn is_stale(&self) -> bool {
        self.stale
    }

    /// Agents in the stack.
    pub fn agents(&self) -> usize {
        self.norms.len()
    }

    /// One TD3 / TD3+BC / DDPG update of every agent, agent i on `batches[i]` (all of one size).
    pub fn update(&mut self, batches: &[Batch]) -> UpdateStats {
        self.step(batches, true).expect("asked for")
    }

    /// Keeps `tables` on the hand-written engine's device (`Engine::hold`); returns whether it
    /// does, and so whether the stack trains on `step_rows`. burn's engine holds none.
    pub fn hold(&mut self, tables: &[Table]) -> Result<bool> {
        match self.engine.as_deref_mut() {
            Some(e) => e.hold(tables),
            None => Ok(false),
        }
    }

    /// `step`, agent i on the batch `rows[i]` names in the tables the engine holds (`hold`).
    pub fn step_rows(&mut self, rows: &[Rows], stats: bool) -> Option<UpdateStats> {
        assert_eq!(rows.len(), self.agents(), "one batch per agent");
        assert!(rows.iter().all(|r| r.len() == rows[0].len()), "the agents' batches differ in size");
        assert!(self.engine.is_some(), "step_rows on a stack that holds its tables");
        self.engine_step(|e, c, norms, rngs, u| e.update_rows(c, rows, norms, rngs, u, stats))
    }

    /// One update on the hand-written engine (`run` calls it with the update's count), and its
    /// per-agent losses, if it returned them, as burn columns.
    fn engine_step(
        &mut self,
        run: impl FnOnce(&mut dyn Engine, &AgentConfig, &[Normalizer], &mut [NpRandom], u64) -> Result<Option<Stats>>,
    ) -> Option<UpdateStats> {
        let e = self.engine.as_deref_mut().expect("a hand-written engine");
        self.updates += 1;
        self.stale = true;
        let stats = run(e, &self.config, &self.norms, &mut self.noise_rngs, self.updates)
            .unwrap_or_else(|err| panic!("update {}: {err:#}", self.updates))?;
        let column = |v: Vec<f32>| Tensor::from_data(TensorData::new(v, [stats.len()]), &self.device);
        let actor = stats[0].2.is_some().then(|| column(stats.iter().map(|s| s.2.unwrap_or(0.0)).collect()));
        Some(UpdateStats {
            critic_loss: column(stats.iter().map(|s| s.0).collect()),
            q_mean: column(stats.iter().map(|s| s.1).collect()),
            actor_loss: actor,
        })
    }

    /// `update`, returning the losses only when `stats` (a GPU engine then waits for the update;
    /// the trainer asks on logging steps only). Panics, with the engine's one-line error, where a
    /// hand-written engine fails mid-run (a GPU fault): nothing can be trained on after that.
    pub fn step(&mut self, batches: &[Batch], stats: bool) -> Option<UpdateStats> {
        let c = &self.config;
        let (a, n, act_dim, k) = (self.agents(), batches[0].n, self.task.act_dim, c.algo.critics());
        let ddpg = c.algo == Algo::Ddpg;
        assert_eq!(batches.len(), a, "one batch per agent");
        assert!(batches.iter().all(|b| b.n == n), "the agents' batches differ in size");
        if self.engine.is_some() {
            return self.engine_step(|e, c, norms, rngs, u| e.update(c, batches, norms, rngs, u, stats));
        }
        let sg = self.input(batches.iter().map(|b| (&b.obs[..], &b.goal[..])), n);
        let next_sg = self.input(batches.iter().map(|b| (&b.next_obs[..], &b.goal[..])), n);
        let action = self.stacked(batches.iter().map(|b| &b.action[..]), [a, n, act_dim]);
        let reward = self.stacked(batches.iter().map(|b| &b.reward[..]), [a, n, 1]);

        // 1. The TD target, from the target networks with a smoothed target action (TD3) or the
        //    target actor's own (DDPG), and the smaller of the twins' values (TD3).
        let next_action = tanh(self.actor_target.forward(next_sg.clone()));
        let next_action = if ddpg {
            next_action
        } else {
            let noise: Vec<f32> = self
                .noise_rngs
                .iter_mut()
                .flat_map(|rng| {
                    (0..n * act_dim)
                        .map(|_| (rng.standard_normal() * c.policy_noise).clamp(-c.noise_clip, c.noise_clip) as f32)
                        .collect::<Vec<f32>>()
                })
                .collect();
            let noise = Tensor::from_data(TensorData::new(noise, [a, n, act_dim]), &self.device);
            (next_action + noise).clamp(-1.0, 1.0)
        };
        let next_q = ensemble(&self.critics_target, Tensor::cat(vec![next_sg, next_action], 2), k);
        let target = td_target(c, reward, smallest(next_q)).unsqueeze_dim::<4>(1); // [A, 1, n, 1]

        // DDPG's actor ascends the critic as it was before this step (HER's and MRN's order:
        // both losses are built first, then both networks step).
        let critics_before = ddpg.then(|| self.critics.copy());

        // 2. Every critic of every agent regresses on its target: the loss is the sum over agents
        //    and critics of mean squared errors, so each agent's gradient is its own loss's.
        let tracked = self.critics.tracked();
        let q = ensemble(&tracked, Tensor::cat(vec![sg.clone(), action.clone()], 2), k); // [A, K, n, 1]
        let q_mean = q.clone().detach().narrow(1, 0, 1).mean_dims(&[1, 2, 3]).reshape([a]).without_autodiff();
        let sq = (q - target).square();
        let sq = if batches.iter().all(|b| b.weight.is_empty()) {
            sq
        } else {
            // Prioritized rows are over-represented; their weights undo that in expectation. An
            // agent without weights (another cell of the grid) gets weight 1 on every row.
            let ones = vec![1.0f32; n];
            let w = batches.iter().map(|b| if b.weight.is_empty() { &ones[..] } else { &b.weight[..] });
            sq * self.stacked(w, [a, n, 1]).unsqueeze_dim::<4>(1)
        };
        let per_agent = sq.mean_dim(2).sum_dim(1); // [A, 1, 1, 1]
        let grads = per_agent.clone().sum().backward();
        self.critics_opt.step(&mut self.critics, &tracked, &grads);
        self.updates += 1;

        // 3. Every `policy_delay` updates (DDPG: every update): the actor ascends Q1 (TD3+BC:
        //    plus behaviour cloning, with λ = α / mean|Q| per agent so the two terms stay on one
        //    scale; with `action_l2`: minus the action penalty); every `policy_delay` updates
        //    the targets follow.
        let mut actor_loss = None;
        let delayed = self.updates.is_multiple_of(c.policy_delay);
        if ddpg || delayed {
            let tracked = self.actor.tracked();
            let pi = tanh(tracked.forward(sg.clone()));
            // Critic 1 of each agent, as a constant: no gradient flows into it.
            let critic = match critics_before {
                Some(before) => before,
                None => self.critics.every(2, 0),
            };
            let q = critic.forward(Tensor::cat(vec![sg, pi.clone()], 2)); // [A, n, 1]
            let loss = match c.algo {
                Algo::Td3 | Algo::Ddpg => q.mean_dim(1).neg(),
                Algo::Td3bc => {
                    let lambda = q.clone().abs().mean_dim(1).detach().recip().mul_scalar(c.alpha);
                    (q.mean_dim(1) * lambda).neg() + (pi.clone() - action).square().mean_dims(&[1, 2])
                }
            }; // [A, 1, 1]
            let l2 = c.action_l2();
            let loss = if l2 > 0.0 { loss + pi.square().mean_dims(&[1, 2]).mul_scalar(l2) } else { loss };
            let grads = loss.clone().sum().backward();
            self.actor_opt.step(&mut self.actor, &tracked, &grads);
            actor_loss = Some(loss.detach().reshape([a]).without_autodiff());
        }
        if delayed {
            self.actor_target.soft_update(&self.actor, c.tau);
            self.critics_target.soft_update(&self.critics, c.tau);
        }
        Some(UpdateStats { critic_loss: per_agent.detach().reshape([a]).without_autodiff(), q_mean, actor_loss })
    }

    /// The deterministic policy π(s, g) of agent 0 for `n` rows of raw observations and goals.
    pub fn act(&self, obs: &[f32], goal: &[f32], n: usize) -> Vec<f32> {
        self.act_all(&vec![(obs, goal); self.agents()], n).swap_remove(0)
    }

    /// Every agent's policy at once, agent i on `rows[i]` = (observations, goals) of `n` rows:
    /// one forward pass for all agents' environments.
    pub fn act_all(&self, rows: &[(&[f32], &[f32])], n: usize) -> Vec<Vec<f32>> {
        if let Some(e) = self.engine.as_deref() {
            return e.act_all(&self.norms, rows, n).unwrap_or_else(|err| panic!("acting: {err:#}"));
        }
        if let Some(f) = self.portable() {
            return f.act_all(&self.norms, rows, n);
        }
        let out = host(tanh(self.actor.forward(self.input(rows.iter().copied(), n)))).1;
        out.chunks(n * self.task.act_dim).map(<[f32]>::to_vec).collect()
    }

    /// min(Q1, Q2)(s, g, a) of agent 0 for `n` rows (DDPG: its critic's Q): the score PGSER's
    /// Alg. 2 ranks swapped transitions by.
    pub fn q(&self, obs: &[f32], goal: &[f32], action: &[f32], n: usize) -> Vec<f32> {
        if let Some(e) = self.engine.as_deref() {
            return e.q(&self.norms[0], obs, goal, action, n).unwrap_or_else(|err| panic!("scoring: {err:#}"));
        }
        if let Some(f) = self.portable() {
            return f.q(&self.norms[0], obs, goal, action, n);
        }
        let a = self.agents();
        let sg = self.input(std::iter::repeat_n((obs, goal), a), n);
        let act = self.stacked(std::iter::repeat_n(action, a), [a, n, self.task.act_dim]);
        let q = ensemble(&self.critics, Tensor::cat(vec![sg, act], 2), self.config.algo.critics());
        host(smallest(q)).1[..n].to_vec()
    }

    /// With portable arithmetic and no engine (a checkpoint loaded to act or to score), the CPU
    /// engine's forward pass on the current networks: burn's products round as `gemm` picks, and
    /// a run that pins its arithmetic must score and act in the same fixed order it trained in.
    fn portable(&self) -> Option<Fused> {
        if self.config.arithmetic != Arithmetic::Portable {
            return None;
        }
        let (actor_sizes, critic_sizes) = super::net_sizes(&self.config, &self.task);
        let state = self.burn_state();
        let product = Product::of(self.config.arithmetic);
        Some(Fused::with_product(&actor_sizes, &critic_sizes, state.nets, state.actor_step, state.critic_step, product))
    }

    /// Normalized [s, g] of each agent's rows, `[A, n, obs + goal]`.
    fn input<'a>(&self, rows: impl Iterator<Item = (&'a [f32], &'a [f32])>, n: usize) -> Tensor<3> {
        let width = self.task.obs_dim + self.task.goal_dim;
        let mut all = Vec::with_capacity(self.agents() * n * width);
        let mut x = Vec::new();
        for ((obs, goal), norm) in rows.zip(&self.norms) {
            norm.input(obs, goal, n, &mut x);
            all.extend_from_slice(&x);
        }
        Tensor::from_data(TensorData::new(all, [self.agents(), n, width]), &self.device)
    }

    fn stacked<'a>(&self, parts: impl Iterator<Item = &'a [f32]>, shape: [usize; 3]) -> Tensor<3> {
        let values: Vec<f32> = parts.flat_map(|p| p.iter().copied()).collect();
        Tensor::from_data(TensorData::new(values, shape), &self.device)
    }
}

/// The `k` critics of every agent on the agent's inputs `x` `[A, n, in]`: returns `[A, k, n, 1]`.
fn ensemble(critics: &Mlp, x: Tensor<3>, k: usize) -> Tensor<4> {
    let [a, n, d] = x.dims();
    let x = x.unsqueeze_dim::<4>(1).expand([a, k, n, d]).reshape([k * a, n, d]);
    critics.forward(x).reshape([a, k, n, 1])
}

/// The smallest of each agent's critics' values `[A, k, n, 1]`, as `[A, n, 1]` (TD3's clipped
/// double Q; with one critic, its value). A minimum rounds nothing, so this is the same bits
/// as taking it pairwise.
fn smallest(q: Tensor<4>) -> Tensor<3> {
    let [a, _, n, _] = q.dims();
    q.min_dim(1).reshape([a, n, 1])
}
