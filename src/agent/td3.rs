//! TD3 and TD3+BC for goal-conditioned offline data, one update top to bottom.
//!
//! Follows sfujim/TD3_BC `TD3_BC.py` (losses, noise, delay, Polyak) with GoFAR's
//! goal-conditioned settings (normalized [s, g] inputs, γ = 0.98, target clipped to
//! [−1/(1−γ), 0], no terminal masking: a goal-reaching task never ends early). SPEC §4.3.

use burn::tensor::activation::tanh;
use burn::tensor::{Device, Tensor, TensorData};

use super::{Adam, AgentConfig, Algo, Mlp, Normalizer, host};
use crate::env::rng::NpRandom;
use crate::task::Task;

/// A training batch on the host: row i is (s, g, a, r, s'). `goal` is the goal the transition is
/// trained on (original, relabelled or swapped) and `reward` was computed for that goal.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Batch {
    pub n: usize,
    pub obs: Vec<f32>,
    pub goal: Vec<f32>,
    pub action: Vec<f32>,
    pub reward: Vec<f32>,
    pub next_obs: Vec<f32>,
    /// Importance-sampling weights of the critic loss per row; empty means all 1.
    pub weight: Vec<f32>,
}

impl Batch {
    /// Appends `other`'s rows (weights are handled by the caller, who knows both halves).
    pub fn append(&mut self, other: &Batch) {
        self.n += other.n;
        self.obs.extend_from_slice(&other.obs);
        self.goal.extend_from_slice(&other.goal);
        self.action.extend_from_slice(&other.action);
        self.reward.extend_from_slice(&other.reward);
        self.next_obs.extend_from_slice(&other.next_obs);
    }
}

/// Losses of one update, left on the device: reading them forces a sync, so the trainer reads
/// them only when it logs.
pub struct UpdateStats {
    pub critic_loss: Tensor<1>,
    pub q_mean: Tensor<1>,
    pub actor_loss: Option<Tensor<1>>,
}

impl UpdateStats {
    pub fn read(&self) -> (f64, f64, Option<f64>) {
        let scalar = |t: &Tensor<1>| host(t.clone()).1[0] as f64;
        (scalar(&self.critic_loss), scalar(&self.q_mean), self.actor_loss.as_ref().map(scalar))
    }
}

/// y = clip(r + γ·min(Q1', Q2')(s', g, ã), −1/(1−γ), 0). No (1 − done) factor: reaching a goal
/// does not end a WGCSL episode, so every transition bootstraps.
pub fn td_target(c: &AgentConfig, reward: Tensor<2>, next_q: Tensor<2>) -> Tensor<2> {
    let (lo, hi) = c.target_range();
    (reward + next_q.mul_scalar(c.gamma)).clamp(lo, hi)
}

/// Everything a TD3 learner owns. Field order is the order of the algorithm.
pub struct Agent {
    pub config: AgentConfig,
    pub task: Task,
    pub norm: Normalizer,
    pub device: Device,
    pub actor: Mlp,
    pub critic1: Mlp,
    pub critic2: Mlp,
    pub actor_target: Mlp,
    pub critic1_target: Mlp,
    pub critic2_target: Mlp,
    pub actor_opt: Adam,
    pub critic1_opt: Adam,
    pub critic2_opt: Adam,
    /// Critic updates done so far.
    pub updates: u64,
    /// The target-policy smoothing noise stream.
    pub noise_rng: NpRandom,
}

/// Spawn keys of the agent's random streams under the run's seed.
const STREAM_INIT: u64 = 1;
const STREAM_NOISE: u64 = 2;

impl Agent {
    pub fn new(config: AgentConfig, task: Task, norm: Normalizer, seed: u64, device: Device) -> Agent {
        let (o, g, a, h) = (task.obs_dim, task.goal_dim, task.act_dim, config.hidden);
        let actor_sizes: Vec<usize> = [o + g].into_iter().chain(vec![h; config.layers]).chain([a]).collect();
        let critic_sizes: Vec<usize> = [o + g + a].into_iter().chain(vec![h; config.layers]).chain([1]).collect();
        let mut init = NpRandom::spawned(seed, &[STREAM_INIT]);
        let actor = Mlp::init(&actor_sizes, &mut init, &device);
        let critic1 = Mlp::init(&critic_sizes, &mut init, &device);
        let critic2 = Mlp::init(&critic_sizes, &mut init, &device);
        let lr = config.lr();
        Agent {
            actor_opt: Adam::new(lr, &actor),
            critic1_opt: Adam::new(lr, &critic1),
            critic2_opt: Adam::new(lr, &critic2),
            actor_target: actor.copy(),
            critic1_target: critic1.copy(),
            critic2_target: critic2.copy(),
            actor,
            critic1,
            critic2,
            updates: 0,
            noise_rng: NpRandom::spawned(seed, &[STREAM_NOISE]),
            config,
            task,
            norm,
            device,
        }
    }

    /// One TD3 / TD3+BC update on `b`.
    pub fn update(&mut self, b: &Batch) -> UpdateStats {
        let c = &self.config;
        let (n, act_dim) = (b.n, self.task.act_dim);
        let sg = self.input(&b.obs, &b.goal, n);
        let next_sg = self.input(&b.next_obs, &b.goal, n);
        let action = self.tensor(b.action.clone(), [n, act_dim]);
        let reward = self.tensor(b.reward.clone(), [n, 1]);

        // 1. The TD target, from the target networks with a smoothed target action.
        let noise: Vec<f32> = (0..n * act_dim)
            .map(|_| (self.noise_rng.standard_normal() * c.policy_noise).clamp(-c.noise_clip, c.noise_clip) as f32)
            .collect();
        let next_action =
            (tanh(self.actor_target.forward(next_sg.clone())) + self.tensor(noise, [n, act_dim])).clamp(-1.0, 1.0);
        let next_x = Tensor::cat(vec![next_sg, next_action], 1);
        let next_q = self.critic1_target.forward(next_x.clone()).min_pair(self.critic2_target.forward(next_x));
        let target = td_target(c, reward, next_q);

        // 2. Both critics regress on the target.
        let x = Tensor::cat(vec![sg.clone(), action.clone()], 1);
        let (c1, c2) = (self.critic1.tracked(), self.critic2.tracked());
        let q1 = c1.forward(x.clone());
        let q2 = c2.forward(x);
        let q_mean = q1.clone().detach().mean().without_autodiff();
        let critic_loss = if b.weight.is_empty() {
            (q1 - target.clone()).square().mean() + (q2 - target).square().mean()
        } else {
            // Prioritized rows are over-represented; their weights undo that in expectation.
            let w = self.tensor(b.weight.clone(), [n, 1]);
            ((q1 - target.clone()).square() * w.clone()).mean() + ((q2 - target).square() * w).mean()
        };
        let grads = critic_loss.backward();
        self.critic1_opt.step(&mut self.critic1, &c1, &grads);
        self.critic2_opt.step(&mut self.critic2, &c2, &grads);
        self.updates += 1;

        // 3. Every `policy_delay` updates: the actor ascends Q1 (TD3+BC: plus behaviour
        //    cloning, with λ = α / mean|Q| so the two terms stay on one scale), then the targets.
        let mut actor_loss = None;
        if self.updates.is_multiple_of(c.policy_delay) {
            let tracked = self.actor.tracked();
            let pi = tanh(tracked.forward(sg.clone()));
            // The updated critic, as a constant: no gradient flows into its weights.
            let q = self.critic1.forward(Tensor::cat(vec![sg, pi.clone()], 1));
            let loss = match c.algo {
                Algo::Td3 => q.mean().neg(),
                Algo::Td3bc => {
                    let lambda = q.clone().abs().mean().detach().recip().mul_scalar(c.alpha);
                    (q.mean() * lambda).neg() + (pi - action).square().mean()
                }
            };
            let grads = loss.backward();
            self.actor_opt.step(&mut self.actor, &tracked, &grads);
            actor_loss = Some(loss.detach().without_autodiff());
            self.actor_target.soft_update(&self.actor, c.tau);
            self.critic1_target.soft_update(&self.critic1, c.tau);
            self.critic2_target.soft_update(&self.critic2, c.tau);
        }
        UpdateStats { critic_loss: critic_loss.detach().without_autodiff(), q_mean, actor_loss }
    }

    /// The deterministic policy π(s, g) for `n` rows of raw observations and goals.
    pub fn act(&self, obs: &[f32], goal: &[f32], n: usize) -> Vec<f32> {
        host(tanh(self.actor.forward(self.input(obs, goal, n)))).1
    }

    /// min(Q1, Q2)(s, g, a) for `n` rows: the score PGSER's Alg. 2 ranks swapped transitions by.
    pub fn q(&self, obs: &[f32], goal: &[f32], action: &[f32], n: usize) -> Vec<f32> {
        let x = Tensor::cat(vec![self.input(obs, goal, n), self.tensor(action.to_vec(), [n, self.task.act_dim])], 1);
        host(self.critic1.forward(x.clone()).min_pair(self.critic2.forward(x))).1
    }

    fn input(&self, obs: &[f32], goal: &[f32], n: usize) -> Tensor<2> {
        let mut x = Vec::new();
        self.norm.input(obs, goal, n, &mut x);
        self.tensor(x, [n, self.task.obs_dim + self.task.goal_dim])
    }

    fn tensor(&self, values: Vec<f32>, shape: [usize; 2]) -> Tensor<2> {
        Tensor::from_data(TensorData::new(values, shape), &self.device)
    }
}
