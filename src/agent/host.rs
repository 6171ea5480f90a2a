//! A trained actor on the host, without burn: for `collect --policy checkpoint:FILE`, which
//! acts one observation at a time inside many worker threads.
//!
//! Collect runs each episode start to end on one worker (its environment must step in order),
//! so the policy is called with one row at a time; a 3-layer MLP of that size is ~0.1 ms of
//! plain loops, and the weights can be shared across threads as plain vectors. The function is
//! the same as `Agent::act` (normalizer, ReLU layers, tanh); the result agrees with it to float
//! round-off (`tests.rs`), and collect records the actions it applied, so the data is exact
//! whatever the rounding.

use std::path::Path;

use anyhow::{Context, Result};

use super::{Member, Normalizer, checkpoint};
use crate::task::Task;

/// Agent 0's actor and normalizer from a checkpoint file.
#[derive(Debug, Clone)]
pub struct HostActor {
    pub task: Task,
    /// The file it came from, as given (recorded in the footer of what it collects).
    pub source: String,
    norm: Normalizer,
    layers: Member,
}

impl HostActor {
    pub fn load(path: &Path) -> Result<HostActor> {
        let device = super::Backend::Cpu.device()?;
        let (agent, _) =
            checkpoint::load(path, device).with_context(|| format!("--policy checkpoint:{}", path.display()))?;
        Ok(HostActor {
            task: agent.task.clone(),
            source: path.display().to_string(),
            norm: agent.norms[0].clone(),
            layers: agent.actor.member(0),
        })
    }

    /// π(s, g) for one observation: `act_dim` values in (−1, 1).
    pub fn act(&self, obs: &[f64], goal: &[f64], out: &mut [f64]) {
        let (o, g): (Vec<f32>, Vec<f32>) =
            (obs.iter().map(|&x| x as f32).collect(), goal.iter().map(|&x| x as f32).collect());
        let mut x = Vec::new();
        self.norm.input(&o, &g, 1, &mut x);
        let last = self.layers.len() - 1;
        for (l, (w, b)) in self.layers.iter().enumerate() {
            let mut y = b.clone();
            for (i, &xi) in x.iter().enumerate() {
                for (yj, &wij) in y.iter_mut().zip(&w[i * b.len()..(i + 1) * b.len()]) {
                    *yj += xi * wij;
                }
            }
            if l < last {
                y.iter_mut().for_each(|v| *v = v.max(0.0));
            }
            x = y;
        }
        for (a, v) in out.iter_mut().zip(&x) {
            *a = v.tanh() as f64;
        }
    }
}
