//! The TD3 / TD3+BC / DDPG update of a stack of agents on the CPU, written out by hand: forward
//! pass, backward pass, losses, gradients and Adam in buffers allocated once, each layer one
//! `gemm` product, and bias, ReLU, tanh and their derivatives folded into one pass over each
//! product's output. The default CPU engine; burn's flex backend (`--device cpu-burn`) is the
//! reference it is tested against (`tests.rs`), and the GPU path.
//!
//! Why by hand: on two cores burn spends about a third of an update outside the products
//! (zero-filling and realigning every output, elementwise kernels, autodiff bookkeeping), and a
//! lone agent runs mostly on one thread (BENCHMARKS.md). Here the products are the work.
//!
//! **Parallelism without changing a bit.** Each agent's batch is cut into a fixed number of parts
//! (`parts`, from the batch size alone); every (agent, part) computes its rows' activations and
//! its own partial weight gradients, and Adam adds the parts' gradients in part order. Work is
//! spread over the rayon pool by (agent, part), so a lone agent uses two cores, and since
//! nothing depends on which thread ran what, the bytes are the same at any thread count.
//!
//! **The backward pass** (one network, layers l = 0..L−1, input x₀, zₗ = xₗWₗ + bₗ,
//! xₗ₊₁ = relu(zₗ) below the top, output z_{L−1}). Given G = ∂loss/∂z_{L−1}:
//! ∂W_l = xₗᵀ·G, ∂bₗ = Σ_rows G, and G ← (G·Wₗᵀ) ⊙ [xₗ > 0] for the layer below (the
//! mask and the next ∂b in the same pass). The input's gradient, where asked (the actor's action
//! columns of the critic's input), is G·W₀ᵀ restricted to those columns.
//!
//! **The losses**, per agent with n rows, weights wᵢ (1 without priorities) and target yᵢ:
//! - critics: L = Σ_k (1/n) Σᵢ wᵢ (Q_k(sᵢ, aᵢ) − yᵢ)², so ∂L/∂Q_k(i) = 2wᵢ(Q_k(i) − yᵢ)/n;
//! - actor (π = tanh(u)): L = −λ/n Σᵢ Q₁(sᵢ, πᵢ) [TD3+BC: + 1/(n·d) Σᵢⱼ (πᵢⱼ − aᵢⱼ)²]
//!   [+ l2/(n·d) Σᵢⱼ πᵢⱼ²], λ = α / mean|Q₁| for TD3+BC (a constant: no gradient), 1 otherwise.
//!   ∂L/∂πᵢⱼ = λ·(∂Q₁/∂π with ∂L/∂Q₁ = −1/n) + 2(πᵢⱼ − aᵢⱼ)/(n·d) + 2·l2·πᵢⱼ/(n·d), and
//!   ∂L/∂uᵢⱼ = ∂L/∂πᵢⱼ · (1 − πᵢⱼ²). The critic is a constant here: only its input gradient is
//!   computed, never its weights'.

use rayon::prelude::*;

use super::engine::{Batch, Engine, Nets, State, Stats};
use super::{AgentConfig, Algo, Normalizer};
use crate::nprandom::NpRandom;

#[cfg(test)]
mod arith_tests;
mod net;
mod product;
#[cfg(test)]
mod tests;

pub use net::flatten;
#[cfg(test)]
pub(in crate::agent) use net::gemm_raw;
pub(in crate::agent) use net::{ADAM_BETAS, AdamStep, Shape, adam_step, unflatten};
use net::{MAX_PARTS, adam, backward, forward};
pub(in crate::agent) use product::Product;

/// The parts a batch of `n` rows is cut into: about 256 rows each (a product of that height still
/// runs near the micro-kernel's peak), at least one, at most four. A function of `n` only, so the
/// bytes never depend on the machine.
pub fn parts(n: usize) -> usize {
    (n / 256).clamp(1, MAX_PARTS)
}

/// The scratch of one (agent, part): its rows' inputs, every layer's output, the backward
/// pass's two gradient buffers, and its partial weight gradients. Sized on the first update.
#[derive(Default)]
struct Work {
    /// Rows `[start, start + rows)` of the agent's batch.
    start: usize,
    rows: usize,
    /// `[rows, s+g+a]`: normalized (s, g) then the batch's action: the critics' input, whose
    /// first s+g columns are the actor's.
    sa: Vec<f32>,
    /// The same for (s', g) and the target action.
    next_sa: Vec<f32>,
    /// (s, g) and π(s, g): the critic's input in the actor's loss.
    spi: Vec<f32>,
    y: Vec<f32>,
    actor_out: Vec<Vec<f32>>,
    critic_out: Vec<Vec<Vec<f32>>>,
    grad_out: Vec<f32>,
    grad_tmp: Vec<f32>,
    /// ∂(−Q₁/n)/∂π, `[rows, a]`.
    dpi: Vec<f32>,
    actor_grad: Vec<f32>,
    critic_grad: Vec<Vec<f32>>,
    sums: Sums,
}

/// One part's sums over its rows, for the losses the trainer logs and TD3+BC's λ.
#[derive(Default, Clone, Copy)]
struct Sums {
    /// Σ_k Σᵢ wᵢ(Q_k − yᵢ)².
    critic: f64,
    /// Σᵢ Q₁(sᵢ, aᵢ).
    q: f64,
    /// Σᵢ Q₁(sᵢ, πᵢ) and Σᵢ |Q₁(sᵢ, πᵢ)| (f32, as the reference's mean).
    pi_q: f64,
    pi_q_abs: f32,
    /// Σᵢⱼ (πᵢⱼ − aᵢⱼ)² and Σᵢⱼ πᵢⱼ².
    bc: f64,
    l2: f64,
}

/// The stack's training state in host buffers, and the scratch of its update.
pub struct Fused {
    actor: Shape,
    critic: Shape,
    pub nets: Vec<Nets>,
    pub actor_step: u64,
    pub critic_step: u64,
    work: Vec<Work>,
    /// The batch size `work` is sized for (0: not yet).
    sized_for: usize,
    /// Each agent's target-policy noise for the current update, `[n, a]`.
    noise: Vec<Vec<f32>>,
    /// Each agent's λ in the current update.
    lambdas: Vec<f32>,
}

impl Fused {
    /// A stack whose products are `gemm`'s (native arithmetic): the tests'.
    #[cfg(test)]
    pub fn new(
        actor_sizes: &[usize],
        critic_sizes: &[usize],
        nets: Vec<Nets>,
        actor_step: u64,
        critic_step: u64,
    ) -> Fused {
        Fused::with_product(actor_sizes, critic_sizes, nets, actor_step, critic_step, Product::Native)
    }

    /// A stack whose products are computed as `product` says (`product.rs`).
    pub(in crate::agent) fn with_product(
        actor_sizes: &[usize],
        critic_sizes: &[usize],
        nets: Vec<Nets>,
        actor_step: u64,
        critic_step: u64,
        product: Product,
    ) -> Fused {
        Fused {
            actor: Shape::with(actor_sizes, product),
            critic: Shape::with(critic_sizes, product),
            noise: vec![Vec::new(); nets.len()],
            lambdas: vec![1.0; nets.len()],
            nets,
            actor_step,
            critic_step,
            work: Vec::new(),
            sized_for: 0,
        }
    }

    /// Buffers for batches of `n` rows (once; again only if the batch size changes).
    fn size_work(&mut self, n: usize, k: usize) {
        if self.sized_for == n {
            return;
        }
        self.sized_for = n;
        let p = parts(n);
        let width = self.critic.sizes[0];
        let act = *self.actor.sizes.last().expect("sizes");
        let outs = |s: &Shape, rows: usize| s.sizes[1..].iter().map(|&d| vec![0.0; rows * d]).collect::<Vec<_>>();
        self.work = (0..self.nets.len() * p)
            .map(|j| {
                let part = j % p;
                let (start, end) = (n * part / p, n * (part + 1) / p);
                let rows = end - start;
                let widest = self.actor.widest().max(self.critic.widest());
                Work {
                    start,
                    rows,
                    sa: vec![0.0; rows * width],
                    next_sa: vec![0.0; rows * width],
                    spi: vec![0.0; rows * width],
                    y: vec![0.0; rows],
                    actor_out: outs(&self.actor, rows),
                    critic_out: (0..k).map(|_| outs(&self.critic, rows)).collect(),
                    grad_out: vec![0.0; rows * widest],
                    grad_tmp: vec![0.0; rows * widest],
                    dpi: vec![0.0; rows * act],
                    actor_grad: vec![0.0; self.actor.len],
                    critic_grad: vec![vec![0.0; self.critic.len]; k],
                    sums: Sums::default(),
                }
            })
            .collect();
        for noise in &mut self.noise {
            *noise = vec![0.0; n * act];
        }
    }

    /// One update of every agent, agent i on `batches[i]`, with its normalizer and noise stream;
    /// `updates` is the count after this update (it decides the delayed actor and targets).
    pub fn update(
        &mut self,
        c: &AgentConfig,
        batches: &[Batch],
        norms: &[Normalizer],
        noise_rngs: &mut [NpRandom],
        updates: u64,
    ) -> Stats {
        let (n, k, ddpg) = (batches[0].n, c.algo.critics(), c.algo == Algo::Ddpg);
        self.size_work(n, k);
        let p = parts(n);
        let act = *self.actor.sizes.last().expect("sizes");
        if !ddpg {
            // Each agent's noise from its own stream, in the reference's order (all n·a values).
            noise_rngs.par_iter_mut().zip(&mut self.noise).for_each(|(rng, noise)| {
                for x in noise.iter_mut() {
                    *x = (rng.standard_normal() * c.policy_noise).clamp(-c.noise_clip, c.noise_clip) as f32;
                }
            });
        }
        let (actor, critic) = (&self.actor, &self.critic);

        // 1. The TD target and the critics' gradients, every (agent, part) side by side.
        {
            let noise = &self.noise;
            let nets = &self.nets;
            self.work.par_iter_mut().enumerate().for_each(|(j, w)| {
                let i = j / p;
                critic_part(c, actor, critic, &nets[i], &batches[i], &norms[i], &noise[i], w, n);
            });
        }
        let delayed = updates.is_multiple_of(c.policy_delay);
        let (lr, tau) = (c.lr(), delayed.then_some(c.tau));
        // TD3 trains the actor on the critic after its step; DDPG (HER's order) on the one before.
        if !ddpg {
            self.critic_step += 1;
            step_critics(&mut self.nets, &self.work, self.critic_step, lr, tau, p);
        }
        let actor_moves = ddpg || delayed;
        self.lambdas.fill(1.0);
        if actor_moves {
            // 2. The actor's forward pass and the critic's input gradient, then λ per agent,
            //    then the actor's backward pass.
            let nets = &self.nets;
            self.work.par_iter_mut().enumerate().for_each(|(j, w)| {
                actor_forward(actor, critic, &nets[j / p], w, n, act);
            });
            if c.algo == Algo::Td3bc {
                for (i, l) in self.lambdas.iter_mut().enumerate() {
                    let abs: f32 = self.work[i * p..(i + 1) * p].iter().map(|w| w.sums.pi_q_abs).sum();
                    *l = c.alpha as f32 * (1.0 / (abs / n as f32));
                }
            }
            let (bc, l2, lambdas) = (c.algo == Algo::Td3bc, c.action_l2() as f32, &self.lambdas);
            self.work.par_iter_mut().enumerate().for_each(|(j, w)| {
                let i = j / p;
                actor_backward(actor, &nets[i], &batches[i], w, lambdas[i], bc, l2, n, act);
            });
        }
        if ddpg {
            self.critic_step += 1;
            step_critics(&mut self.nets, &self.work, self.critic_step, lr, tau, p);
        }
        if actor_moves {
            self.actor_step += 1;
            let (step, work) = (self.actor_step, &self.work);
            self.nets.par_iter_mut().enumerate().for_each(|(i, nets)| {
                let grads = &work[i * p..(i + 1) * p];
                adam(&mut nets.actor, |q| &grads[q].actor_grad, p, lr, step, tau);
            });
        }

        (0..self.nets.len())
            .map(|i| {
                let ws = &self.work[i * p..(i + 1) * p];
                let sum = |f: fn(&Sums) -> f64| ws.iter().map(|w| f(&w.sums)).sum::<f64>();
                let (nf, cells) = (n as f64, (n * act) as f64);
                let actor_loss = actor_moves.then(|| {
                    let mut loss = -(self.lambdas[i] as f64) * sum(|s| s.pi_q) / nf;
                    if c.algo == Algo::Td3bc {
                        loss += sum(|s| s.bc) / cells;
                    }
                    loss += c.action_l2() * sum(|s| s.l2) / cells;
                    loss as f32
                });
                ((sum(|s| s.critic) / nf) as f32, (sum(|s| s.q) / nf) as f32, actor_loss)
            })
            .collect()
    }

    /// Every agent's policy, agent i on `rows[i]` (raw observations and goals, `n` rows).
    pub fn act_all(&self, norms: &[Normalizer], rows: &[(&[f32], &[f32])], n: usize) -> Vec<Vec<f32>> {
        let width = self.actor.sizes[0];
        self.nets
            .par_iter()
            .zip(rows)
            .zip(norms)
            .map(|((nets, (obs, goal)), norm)| {
                let mut x = vec![0.0; n * width];
                normalize_into(norm, obs, goal, &mut x, width, 0..n);
                let mut outs = self.actor.sizes[1..].iter().map(|&d| vec![0.0; n * d]).collect::<Vec<_>>();
                forward(&self.actor, &nets.actor.p, &x, width, n, &mut outs);
                outs.pop().expect("layers").into_iter().map(f32::tanh).collect()
            })
            .collect()
    }

    /// The smallest of agent 0's critics' values for `n` rows (raw s, g, a).
    pub fn q(&self, norm: &Normalizer, obs: &[f32], goal: &[f32], action: &[f32], n: usize) -> Vec<f32> {
        let width = self.critic.sizes[0];
        let act = action.len() / n.max(1);
        let mut x = vec![0.0; n * width];
        normalize_into(norm, obs, goal, &mut x, width, 0..n);
        for r in 0..n {
            x[r * width + width - act..(r + 1) * width].copy_from_slice(&action[r * act..(r + 1) * act]);
        }
        let mut best = vec![f32::INFINITY; n];
        for net in &self.nets[0].critics {
            let mut outs = self.critic.sizes[1..].iter().map(|&d| vec![0.0; n * d]).collect::<Vec<_>>();
            forward(&self.critic, &net.p, &x, width, n, &mut outs);
            for (b, q) in best.iter_mut().zip(outs.last().expect("layers")) {
                *b = b.min(*q);
            }
        }
        best
    }
}

impl Engine for Fused {
    fn update(
        &mut self,
        c: &AgentConfig,
        batches: &[Batch],
        norms: &[Normalizer],
        noise_rngs: &mut [NpRandom],
        updates: u64,
        _stats: bool,
    ) -> anyhow::Result<Option<Stats>> {
        // The sums are a by-product here: returning them costs nothing.
        Ok(Some(Fused::update(self, c, batches, norms, noise_rngs, updates)))
    }

    fn act_all(&self, norms: &[Normalizer], rows: &[(&[f32], &[f32])], n: usize) -> anyhow::Result<Vec<Vec<f32>>> {
        Ok(Fused::act_all(self, norms, rows, n))
    }

    fn q(&self, norm: &Normalizer, obs: &[f32], goal: &[f32], action: &[f32], n: usize) -> anyhow::Result<Vec<f32>> {
        Ok(Fused::q(self, norm, obs, goal, action, n))
    }

    fn state(&self) -> anyhow::Result<State> {
        Ok(State { nets: self.nets.clone(), actor_step: self.actor_step, critic_step: self.critic_step })
    }
}

/// Normalized (s, g) of `rows` of a batch into the first s+g columns of `out` (row stride
/// `stride`), as `Normalizer::input` computes them.
fn normalize_into(
    norm: &Normalizer,
    obs: &[f32],
    goal: &[f32],
    out: &mut [f32],
    stride: usize,
    rows: std::ops::Range<usize>,
) {
    let (od, gd, clip) = (norm.obs_mean.len(), norm.goal_mean.len(), norm.clip);
    for (r, row) in rows.zip(out.chunks_exact_mut(stride)) {
        let o = &obs[r * od..(r + 1) * od];
        for ((y, x), (m, s)) in row[..od].iter_mut().zip(o).zip(norm.obs_mean.iter().zip(&norm.obs_std)) {
            *y = ((x - m) / s).clamp(-clip, clip);
        }
        let g = &goal[r * gd..(r + 1) * gd];
        for ((y, x), (m, s)) in row[od..od + gd].iter_mut().zip(g).zip(norm.goal_mean.iter().zip(&norm.goal_std)) {
            *y = ((x - m) / s).clamp(-clip, clip);
        }
    }
}

/// Step 1 for one (agent, part): inputs, the TD target from the target networks, and each
/// critic's forward and backward pass into the part's critic gradients.
#[allow(clippy::too_many_arguments)]
fn critic_part(
    c: &AgentConfig,
    actor: &Shape,
    critic: &Shape,
    nets: &Nets,
    batch: &Batch,
    norm: &Normalizer,
    noise: &[f32],
    w: &mut Work,
    n: usize,
) {
    let (width, act) = (critic.sizes[0], *actor.sizes.last().expect("sizes"));
    let sg = width - act;
    let rows = w.start..w.start + w.rows;
    normalize_into(norm, &batch.obs, &batch.goal, &mut w.sa, width, rows.clone());
    normalize_into(norm, &batch.next_obs, &batch.goal, &mut w.next_sa, width, rows.clone());
    for (r, row) in rows.clone().zip(w.sa.chunks_exact_mut(width)) {
        row[sg..].copy_from_slice(&batch.action[r * act..(r + 1) * act]);
    }

    // The target action: tanh of the target actor, plus clipped noise (TD3), clipped to ±1.
    forward(actor, &nets.actor.target, &w.next_sa, width, w.rows, &mut w.actor_out);
    let ddpg = c.algo == Algo::Ddpg;
    let top = w.actor_out.last().expect("layers");
    for (r, row) in w.next_sa.chunks_exact_mut(width).enumerate() {
        for j in 0..act {
            let a = top[r * act + j].tanh();
            row[sg + j] = if ddpg { a } else { (a + noise[(w.start + r) * act + j]).clamp(-1.0, 1.0) };
        }
    }
    // y = clip(r + γ·min_k Q'_k(s', g, ã)).
    let (lo, hi) = c.target_range();
    let (gamma, lo, hi) = (c.gamma as f32, lo as f32, hi as f32);
    w.y.fill(f32::INFINITY);
    for (k, target) in nets.critics.iter().enumerate() {
        forward(critic, &target.target, &w.next_sa, width, w.rows, &mut w.critic_out[k]);
        for (y, q) in w.y.iter_mut().zip(w.critic_out[k].last().expect("layers")) {
            *y = y.min(*q);
        }
    }
    for (y, r) in w.y.iter_mut().zip(&batch.reward[rows.clone()]) {
        *y = (r + *y * gamma).clamp(lo, hi);
    }

    // Each critic regresses on y: G = 2w(Q − y)/n.
    let (mut loss, mut q_sum) = (0.0f64, 0.0f64);
    let scale = 2.0 / n as f32;
    for (k, net) in nets.critics.iter().enumerate() {
        forward(critic, &net.p, &w.sa, width, w.rows, &mut w.critic_out[k]);
        let q = w.critic_out[k].last().expect("layers");
        for (r, (g, (&q, &y))) in w.grad_out.iter_mut().zip(q.iter().zip(&w.y)).enumerate() {
            let weight = batch.weight.get(w.start + r).copied().unwrap_or(1.0);
            let d = q - y;
            *g = scale * weight * d;
            loss += (weight * d * d) as f64;
            if k == 0 {
                q_sum += q as f64;
            }
        }
        backward(
            critic,
            &net.p,
            &w.sa,
            width,
            w.rows,
            &w.critic_out[k],
            &mut w.grad_out,
            &mut w.grad_tmp,
            Some(&mut w.critic_grad[k]),
            None,
        );
    }
    w.sums.critic = loss;
    w.sums.q = q_sum;
}

/// Step 2a for one (agent, part): π(s, g), Q₁(s, g, π), and ∂(−Q₁/n)/∂π into `dpi`.
fn actor_forward(actor: &Shape, critic: &Shape, nets: &Nets, w: &mut Work, n: usize, act: usize) {
    let width = critic.sizes[0];
    let sg = width - act;
    forward(actor, &nets.actor.p, &w.sa, width, w.rows, &mut w.actor_out);
    let top = w.actor_out.last().expect("layers");
    for (r, (dst, src)) in w.spi.chunks_exact_mut(width).zip(w.sa.chunks_exact(width)).enumerate() {
        dst[..sg].copy_from_slice(&src[..sg]);
        for j in 0..act {
            dst[sg + j] = top[r * act + j].tanh();
        }
    }
    let q1 = &nets.critics[0].p;
    forward(critic, q1, &w.spi, width, w.rows, &mut w.critic_out[0]);
    let (mut q_sum, mut abs) = (0.0f64, 0.0f32);
    for q in w.critic_out[0].last().expect("layers") {
        q_sum += *q as f64;
        abs += q.abs();
    }
    w.sums.pi_q = q_sum;
    w.sums.pi_q_abs = abs;
    w.grad_out[..w.rows].fill(-1.0 / n as f32);
    backward(
        critic,
        q1,
        &w.spi,
        width,
        w.rows,
        &w.critic_out[0],
        &mut w.grad_out,
        &mut w.grad_tmp,
        None,
        Some((&mut w.dpi, sg)),
    );
}

/// Step 2b for one (agent, part): ∂L/∂u from λ·dpi and the behaviour-cloning and action-penalty
/// terms, then the actor's backward pass into the part's actor gradient.
#[allow(clippy::too_many_arguments)]
fn actor_backward(
    actor: &Shape,
    nets: &Nets,
    batch: &Batch,
    w: &mut Work,
    lambda: f32,
    bc: bool,
    l2: f32,
    n: usize,
    act: usize,
) {
    let width = w.sa.len() / w.rows;
    let sg = width - act;
    let scale = 2.0 / (n * act) as f32;
    let (mut bc_sum, mut l2_sum) = (0.0f64, 0.0f64);
    for r in 0..w.rows {
        for j in 0..act {
            let pi = w.spi[r * width + sg + j];
            let mut d = lambda * w.dpi[r * act + j];
            if bc {
                let diff = pi - batch.action[(w.start + r) * act + j];
                d += scale * diff;
                bc_sum += (diff * diff) as f64;
            }
            if l2 > 0.0 {
                d += scale * l2 * pi;
                l2_sum += (pi * pi) as f64;
            }
            w.grad_out[r * act + j] = d * (1.0 - pi * pi);
        }
    }
    w.sums.bc = bc_sum;
    w.sums.l2 = l2_sum;
    backward(
        actor,
        &nets.actor.p,
        &w.sa,
        width,
        w.rows,
        &w.actor_out,
        &mut w.grad_out,
        &mut w.grad_tmp,
        Some(&mut w.actor_grad),
        None,
    );
}

/// The critics' Adam step of every agent (and with `tau`, their targets' Polyak step).
fn step_critics(nets: &mut [Nets], work: &[Work], step: u64, lr: f64, tau: Option<f64>, p: usize) {
    nets.par_iter_mut().enumerate().for_each(|(i, nets)| {
        let grads = &work[i * p..(i + 1) * p];
        for (k, net) in nets.critics.iter_mut().enumerate() {
            adam(net, |q| &grads[q].critic_grad[k], p, lr, step, tau);
        }
    });
}
