//! One update of the stack on the device: the host's part (its batch or its rows staged in one
//! upload) and the device's part (every launch and product in order, captured once as a graph
//! and replayed), and the losses read back on logging steps. The derivation is `mod.rs`'s and
//! `fused/`'s doc comments'; the order of launches here is the CPU engine's order of work.

use anyhow::Result;

use super::device::at;
use super::net::{View, adam, backward, forward, inputs};
use super::staging::{CONSTS, Staged};
use super::{Arg, CudaEngine, Gpu, Mat, Ptr, SUMS, Scratch};
use crate::agent::engine::{Batch, Rows, Stats};
use crate::agent::fused::parts;
use crate::agent::{AgentConfig, Algo, Normalizer};
use crate::nprandom::NpRandom;

/// An update's batches: from the host, or rows of the held tables.
#[derive(Clone, Copy)]
pub(super) enum Input<'a> {
    Batches(&'a [Batch]),
    Rows(&'a [Rows]),
}

impl<G: Gpu> CudaEngine<G> {
    /// Every launch and product of one update, in order, on batches of `s.n` rows staged at
    /// `staged`'s offsets.
    fn launches(
        &self,
        gpu: &mut dyn Gpu,
        c: &AgentConfig,
        s: &Scratch,
        staged: &Staged,
        actor_moves: bool,
    ) -> Result<()> {
        let (a, n, k, act) = (self.agents, s.n, self.k, self.act_dim());
        let (od, gd) = (self.obs_dim, self.goal_dim);
        let (ddpg, p) = (c.algo == Algo::Ddpg, parts(n));
        let batch = |off: usize| at(s.staging, off);
        let (consts_actor, consts_critic) = (s.staging, at(s.staging, CONSTS));
        let (actor, critic) = (&self.actor, &self.critic);
        let w = critic.sizes[0];
        let (ai, ki, ni) = (a as i32, k as i32, n as i32);
        let actors = |params: Ptr| View { params, member_stride: actor.len, items: a };
        let critics = |params: Ptr| View { params, member_stride: critic.len, items: a * k };
        let sa_rows = Mat { ptr: s.sa, ld: w, trans: false, stride: n * w };
        // The actor reads its agent's first critic copy of sa: member a·K.
        let actor_in = |ptr: Ptr| Mat { ptr, ld: w, trans: false, stride: k * n * w };

        // 0. The batch from the held tables, when the host sent row numbers.
        if let (Some(index), Some(h)) = (staged.index, self.held.as_ref()) {
            gpu.launch(
                "pgser_gather",
                a * n * (2 * od + gd + act),
                &[
                    Arg::L((a * n) as i64),
                    Arg::I(od as i32),
                    Arg::I(gd as i32),
                    Arg::I(act as i32),
                    Arg::P(batch(index)),
                    Arg::P(h.obs),
                    Arg::P(h.goals),
                    Arg::P(h.actions),
                    Arg::P(batch(staged.obs)),
                    Arg::P(batch(staged.goal)),
                    Arg::P(batch(staged.next_obs)),
                    Arg::P(batch(staged.action)),
                ],
            )?;
        }

        // 1. Inputs; the TD target from the target networks; the critics' gradients.
        let src = (batch(staged.obs), batch(staged.goal), batch(staged.next_obs), batch(staged.action));
        inputs(gpu, a, k, n, (od, gd, act), src, self.norm_bufs(), (s.sa, s.next_sa))?;
        forward(gpu, actor, actors(self.actor_net.target), actor_in(s.next_sa), &s.actor_out, n, p)?;
        gpu.launch(
            "pgser_target_action",
            a * k * n * act,
            &[
                Arg::I(ai),
                Arg::I(ki),
                Arg::I(ni),
                Arg::I(act as i32),
                Arg::I(w as i32),
                Arg::P(*s.actor_out.last().expect("layers")),
                Arg::P(batch(staged.noise)),
                Arg::P(s.next_sa),
                Arg::I(ddpg as i32),
            ],
        )?;
        let next_rows = Mat { ptr: s.next_sa, ..sa_rows };
        forward(gpu, critic, critics(self.critic_net.target), next_rows, &s.critic_out, n, p)?;
        let (lo, hi) = c.target_range();
        let q_top = *s.critic_out.last().expect("layers");
        gpu.launch(
            "pgser_td_target",
            a * n,
            &[
                Arg::I(ai),
                Arg::I(ki),
                Arg::I(ni),
                Arg::P(q_top),
                Arg::P(batch(staged.reward)),
                Arg::F(c.gamma as f32),
                Arg::F(lo as f32),
                Arg::F(hi as f32),
                Arg::P(s.y),
            ],
        )?;
        forward(gpu, critic, critics(self.critic_net.p), sa_rows, &s.critic_out, n, p)?;
        let qyw = [Arg::P(q_top), Arg::P(s.y), Arg::P(batch(staged.weight))];
        gpu.launch(
            "pgser_critic_grad",
            a * k * n,
            &[&[Arg::I(ai), Arg::I(ki), Arg::I(ni)][..], &qyw, &[Arg::F(2.0 / n as f32), Arg::P(s.g)]].concat(),
        )?;
        gpu.launch(
            "pgser_critic_sums",
            a * p,
            &[&[Arg::I(ai), Arg::I(ki), Arg::I(ni), Arg::I(p as i32)][..], &qyw, &[Arg::P(s.sums)]].concat(),
        )?;
        let grads = Some(s.critic_grad);
        backward(gpu, critic, critics(self.critic_net.p), sa_rows, &s.critic_out, (s.g, s.tmp), grads, None, n, p)?;
        // TD3 trains the actor on the critic after its step; DDPG (HER's order) on the one before.
        if !ddpg {
            adam(gpu, &self.critic_net, a * k, critic.len, p, s.critic_grad, consts_critic)?;
        }

        // 2. The actor: π(s, g), Q₁(s, g, π) and ∂(−Q₁/n)/∂π, λ, then the actor's backward pass.
        if actor_moves {
            forward(gpu, actor, actors(self.actor_net.p), actor_in(s.sa), &s.actor_out, n, p)?;
            let pi_top = *s.actor_out.last().expect("layers");
            gpu.launch(
                "pgser_policy_input",
                a * n * w,
                &[
                    Arg::I(ai),
                    Arg::I(ki),
                    Arg::I(ni),
                    Arg::I(w as i32),
                    Arg::I(act as i32),
                    Arg::P(s.sa),
                    Arg::P(pi_top),
                    Arg::P(s.spi),
                ],
            )?;
            let q1 = View { params: self.critic_net.p, member_stride: k * critic.len, items: a };
            let spi_rows = Mat { ptr: s.spi, ld: w, trans: false, stride: n * w };
            forward(gpu, critic, q1, spi_rows, &s.q1_out, n, p)?;
            let q1_top = *s.q1_out.last().expect("layers");
            gpu.launch(
                "pgser_pi_sums",
                a * p,
                &[Arg::I(ai), Arg::I(ni), Arg::I(p as i32), Arg::P(q1_top), Arg::P(s.sums)],
            )?;
            gpu.launch("pgser_fill", a * n, &[Arg::L((a * n) as i64), Arg::F(-1.0 / n as f32), Arg::P(s.g)])?;
            let dx = Some((s.dpi, w - act));
            backward(gpu, critic, q1, spi_rows, &s.q1_out, (s.g, s.tmp), None, dx, n, p)?;
            let td3bc = c.algo == Algo::Td3bc;
            gpu.launch(
                "pgser_lambdas",
                a,
                &[
                    Arg::I(ai),
                    Arg::I(p as i32),
                    Arg::I(ni),
                    Arg::F(c.alpha as f32),
                    Arg::I(td3bc as i32),
                    Arg::P(s.sums),
                    Arg::P(s.lambda),
                ],
            )?;
            let (bc, l2) = (Arg::I(td3bc as i32), Arg::F(c.action_l2() as f32));
            let action = Arg::P(batch(staged.action));
            gpu.launch(
                "pgser_actor_grad",
                a * n * act,
                &[
                    Arg::I(ai),
                    Arg::I(ni),
                    Arg::I(act as i32),
                    Arg::I(w as i32),
                    Arg::P(s.spi),
                    Arg::P(s.dpi),
                    action,
                    Arg::P(s.lambda),
                    bc,
                    l2,
                    Arg::F(2.0 / (n * act) as f32),
                    Arg::P(s.g),
                ],
            )?;
            gpu.launch(
                "pgser_actor_sums",
                a * p,
                &[
                    Arg::I(ai),
                    Arg::I(ni),
                    Arg::I(p as i32),
                    Arg::I(act as i32),
                    Arg::I(w as i32),
                    Arg::P(s.spi),
                    action,
                    bc,
                    l2,
                    Arg::P(s.sums),
                ],
            )?;
            let grads = Some(s.actor_grad);
            backward(
                gpu,
                actor,
                actors(self.actor_net.p),
                actor_in(s.sa),
                &s.actor_out,
                (s.g, s.tmp),
                grads,
                None,
                n,
                p,
            )?;
        }
        if ddpg {
            adam(gpu, &self.critic_net, a * k, critic.len, p, s.critic_grad, consts_critic)?;
        }
        if actor_moves {
            adam(gpu, &self.actor_net, a, actor.len, p, s.actor_grad, consts_actor)?;
        }
        Ok(())
    }

    /// One update of every agent on `input`, with its normalizer and noise stream; `updates` is
    /// the count after this update (it decides the delayed actor and targets). With `stats`,
    /// waits for the update and returns its losses (the trainer asks on logging steps).
    pub(super) fn step(
        &mut self,
        c: &AgentConfig,
        input: Input,
        norms: &[Normalizer],
        noise_rngs: &mut [NpRandom],
        updates: u64,
        stats: bool,
    ) -> Result<Option<Stats>> {
        let n = match input {
            Input::Batches(b) => b[0].n,
            Input::Rows(r) => r[0].len(),
        };
        let (a, act) = (self.agents, self.act_dim());
        let ddpg = c.algo == Algo::Ddpg;
        let p = parts(n);
        self.set_norms(norms)?;
        self.size_scratch(n)?;
        let delayed = updates.is_multiple_of(c.policy_delay);
        let actor_moves = ddpg || delayed;
        let tau = delayed.then_some(c.tau);
        let critic_step = self.critic_step + 1;
        let actor_step = self.actor_step + u64::from(actor_moves);

        // The host's part: Adam's constants and the batch, or its rows' numbers in the held
        // tables (and TD3's target noise, drawn from each agent's stream in the CPU engine's
        // order), written straight into the staging buffer and copied in one transfer.
        let (od, gd) = (self.obs_dim, self.goal_dim);
        let held = matches!(input, Input::Rows(_));
        let staged = Staged::new(a, n, od, gd, act, held);
        let s = self.scratch.as_ref().expect("sized");
        debug_assert!(staged.len <= s.staging_len);
        let steps = (actor_step, critic_step);
        let gpu = &mut *self.gpu.lock().expect("the device lock");
        gpu.stage(s.staging, staged.upload, &mut |host: &mut [f32]| match input {
            Input::Batches(b) => staged.fill(host, c, b, noise_rngs, steps, tau),
            Input::Rows(r) => {
                let bases = &self.held.as_ref().expect("rows come only once tables are held").bases;
                staged.fill_rows(host, c, r, bases, noise_rngs, steps, tau)
            }
        })?;

        // The device's part: one captured graph per kind of update, replayed. The first update
        // of a kind runs eagerly: cuBLAS and the driver load what they load lazily then, which a
        // capture forbids; the second is captured. PGSER_CUDA_GRAPHS=0 launches every kernel
        // every time instead (to time what graphs save).
        let key = (n, actor_moves, held);
        let seen = s.graphs.lock().expect("graphs").iter().find(|g| g.0 == key).map(|g| g.1);
        match seen {
            Some(Some(id)) => gpu.replay(id)?,
            Some(None) if self.graphs => {
                gpu.begin_capture()?;
                let recorded = self.launches(gpu, c, s, &staged, actor_moves);
                let captured = gpu.end_capture();
                // A launch's own error comes first: a failed launch invalidates the capture, and
                // the capture's error would name only the capture.
                recorded?;
                match captured {
                    Ok(id) => {
                        s.graphs.lock().expect("graphs").iter_mut().find(|g| g.0 == key).expect("seen").1 = Some(id);
                        gpu.replay(id)?;
                    }
                    // Nothing recorded has run, so the update is launched again as it comes, and
                    // every later one too: graphs save launch time, never change a result.
                    Err(e) => {
                        eprintln!(
                            "--device cuda: capturing the update as a CUDA graph failed ({e:#}); every kernel is launched as it comes from now on (PGSER_CUDA_GRAPHS=0)"
                        );
                        self.graphs = false;
                        self.launches(gpu, c, s, &staged, actor_moves)?;
                    }
                }
            }
            _ => {
                self.launches(gpu, c, s, &staged, actor_moves)?;
                if seen.is_none() {
                    s.graphs.lock().expect("graphs").push((key, None));
                }
            }
        }
        self.critic_step = critic_step;
        self.actor_step = actor_step;
        if !stats {
            return Ok(None);
        }
        let mut sums = vec![0.0f64; a * p * SUMS];
        // SAFETY: f64 has no padding; the vector outlives the slice.
        let bytes = unsafe { std::slice::from_raw_parts_mut(sums.as_mut_ptr().cast::<u8>(), 8 * sums.len()) };
        gpu.download(s.sums, bytes)?;
        Ok(Some(stats_from_sums(c, &sums, a, p, n, act, actor_moves)))
    }
}

/// The per-agent losses from the per-(agent, part) sums, as `Fused::update` computes them.
fn stats_from_sums(
    c: &AgentConfig,
    sums: &[f64],
    a: usize,
    p: usize,
    n: usize,
    act: usize,
    actor_moves: bool,
) -> Stats {
    (0..a)
        .map(|i| {
            let sum = |j: usize| (0..p).map(|q| sums[(i * p + q) * SUMS + j]).sum::<f64>();
            let (nf, cells) = (n as f64, (n * act) as f64);
            let actor_loss = actor_moves.then(|| {
                let lambda = if c.algo == Algo::Td3bc {
                    let abs = (0..p).map(|q| sums[(i * p + q) * SUMS + 3] as f32).sum::<f32>();
                    c.alpha as f32 * (1.0 / (abs / n as f32))
                } else {
                    1.0
                };
                let mut loss = -(lambda as f64) * sum(2) / nf;
                if c.algo == Algo::Td3bc {
                    loss += sum(4) / cells;
                }
                loss += c.action_l2() * sum(5) / cells;
                loss as f32
            });
            ((sum(0) / nf) as f32, (sum(1) / nf) as f32, actor_loss)
        })
        .collect()
}
