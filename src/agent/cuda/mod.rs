//! The TD3 / TD3+BC / DDPG update of a stack of agents on an NVIDIA GPU, written out by hand:
//! every layer of every agent one strided-batched SGEMM (cuBLAS), the elementwise work and the
//! reductions in the kernels of `kernels.cu` (compiled at start by NVRTC), all state and scratch
//! in device buffers allocated once. `--device cuda`.
//!
//! Why by hand: burn's CUDA backend spent 10–22 ms on every update whatever the stack's size
//! (BENCHMARKS.md): the cost was per update, not arithmetic. Here an update is a fixed list of
//! about 40 launches and one upload of the batch.
//!
//! **The same update as the CPU engine, to the bit where the products are.** This is `fused/`'s
//! update (its doc comment has the derivation: the backward pass, the critics' and the actor's
//! losses, λ, Adam and Polyak), with the same layout (each network flat in `Shape` order), the
//! same parts (a batch of n rows cut into `fused::parts(n)` parts; each part's weight gradient is
//! its own product, and Adam adds the parts in part order) and every sum in the same order, one
//! thread per sum (kernels.cu's header). Only the products differ: cuBLAS rounds its dot products
//! in its own order. On the host (`host.rs`: the same kernel source compiled as C++, and the CPU
//! engine's own `gemm` calls for cuBLAS) the engine is therefore the CPU engine's bits, which the
//! tests check over hundreds of updates: that tests every index and every formula of the kernels
//! and of the launch sequence below, on a machine without a GPU.
//!
//! **Layout.** A agents, K critics each (TD3: 2, DDPG: 1), batches of n rows, p parts:
//! - the actors' parameters `[A, len_a]`, the critics' `[A·K, len_c]` (agent a's critic k is member
//!   a·K + k), each with its Adam moments and target copy;
//! - the critics' inputs `sa`, `next_sa`: `[A·K, n, W]` (W = obs + goal + action), each critic with
//!   its own copy of its agent's rows, so that every layer of every critic is one batched product;
//! - each layer's output `[members, n, d]`, the backward pass's two gradient buffers
//!   `[A·K, n, widest]`, the weight gradients `[members, p, len]`, the sums `[A, p, 6]` (f64).
//!
//! **Where it runs** is the `Gpu` trait: `driver.rs` (cudarc: cuBLAS, NVRTC, the driver) or
//! `host.rs` (the shim). The engine never waits for the device inside an update; the trainer's
//! logging steps read the sums back (`Engine::update`'s `stats`).
//!
//! **Files.** This one holds the engine's state and its seam (`Engine`: construction, holding
//! the episodes, acting, scoring); `update.rs` is one update, launch by launch, in order;
//! `staging.rs` what the host uploads for it; `net.rs` a network's forward and backward passes
//! and Adam; `kernels.cu` the kernels.

mod device;
mod driver;
#[cfg(test)]
mod host;
mod net;
pub mod nvrtc;
mod staging;
#[cfg(test)]
mod tests;
mod update;

use std::sync::Mutex;

use anyhow::{Context, Result};

use super::engine::{Batch, Engine, Net, Nets, Rows, State, Stats, Table};
use super::fused::{Shape, parts};
use super::{AgentConfig, Normalizer};
use crate::nprandom::NpRandom;

pub use device::{Arg, Gemm, Gpu, Mat, Ptr, arg_pointers};
use device::{Temp, at, download_f32, f32_bytes};
pub use driver::{CudaGpu, driver_present, open};
use net::{View, forward, inputs};
use staging::{Base, Staged};
use update::Input;

/// Per-(agent, part) sums (kernels.cu's PGSER_SUMS, in its order).
const SUMS: usize = 6;

/// One stack of networks on the device: parameters, Adam moments and targets, `[members, len]`.
struct NetBufs {
    p: Ptr,
    m: Ptr,
    v: Ptr,
    target: Ptr,
}

/// The tables a stack's batches come from, on the device (`Engine::hold`): every table's
/// observations, goals (achieved, then desired) and actions, concatenated, and where each
/// table starts.
struct Held {
    obs: Ptr,
    goals: Ptr,
    actions: Ptr,
    bases: Vec<Base>,
}

/// The part of free device memory that held tables may take: the rest stays for the update's
/// buffers (small: tens of MB at 60 agents), cuBLAS, and whatever else shares the GPU.
const HOLD_SHARE: f64 = 0.5;

/// The scratch of updates with batches of `n` rows.
struct Scratch {
    n: usize,
    /// One upload per update: Adam's constants (actor, then critics), then the batch:
    /// obs, goal, next_obs, action, reward, weight, noise, each `[A, n, ·]`.
    staging: Ptr,
    staging_len: usize,
    sa: Ptr,
    next_sa: Ptr,
    spi: Ptr,
    y: Ptr,
    actor_out: Vec<Ptr>,
    critic_out: Vec<Ptr>,
    q1_out: Vec<Ptr>,
    g: Ptr,
    tmp: Ptr,
    dpi: Ptr,
    lambda: Ptr,
    actor_grad: Ptr,
    critic_grad: Ptr,
    sums: Ptr,
    /// The kinds of update seen, and each one's graph once captured.
    graphs: Mutex<Vec<(UpdateKind, Option<usize>)>>,
}

/// What decides an update's launches: the batch size, whether the actor moves, and whether the
/// batch is gathered from held tables.
type UpdateKind = (usize, bool, bool);

/// The stack's training state on a device, and the scratch of its update.
pub struct CudaEngine<G: Gpu> {
    gpu: Mutex<G>,
    actor: Shape,
    critic: Shape,
    agents: usize,
    k: usize,
    obs_dim: usize,
    goal_dim: usize,
    actor_net: NetBufs,
    critic_net: NetBufs,
    pub actor_step: u64,
    pub critic_step: u64,
    /// The normalizers on the device (means and stds `[A, obs + goal]`, clips `[A]`) and the
    /// host copy they were uploaded from.
    norm_mean: Ptr,
    norm_std: Ptr,
    norm_clip: Ptr,
    norms: Vec<Normalizer>,
    scratch: Option<Scratch>,
    /// The episodes the device holds (`hold`), when it does.
    held: Option<Held>,
    /// Whether updates are captured once as CUDA graphs and replayed (the default), or every
    /// kernel launched each time (PGSER_CUDA_GRAPHS=0: to time what graphs save).
    pub graphs: bool,
}

impl<G: Gpu> CudaEngine<G> {
    /// A stack on `gpu` from its state on the host (as `Fused::new` takes it) and its agents'
    /// normalizers.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        mut gpu: G,
        actor_sizes: &[usize],
        critic_sizes: &[usize],
        obs_dim: usize,
        nets: &[Nets],
        norms: &[Normalizer],
        actor_step: u64,
        critic_step: u64,
    ) -> Result<CudaEngine<G>> {
        let (actor, critic) = (Shape::new(actor_sizes), Shape::new(critic_sizes));
        let (agents, k) = (nets.len(), nets[0].critics.len());
        let sg = actor_sizes[0];
        let mut upload_net = |len: usize, members: Vec<&Net>| -> Result<NetBufs> {
            let mut buf = |pick: fn(&Net) -> &Vec<f32>| -> Result<Ptr> {
                let ptr = gpu.alloc(4 * len * members.len())?;
                let host: Vec<f32> = members.iter().flat_map(|n| pick(n).iter().copied()).collect();
                gpu.upload(ptr, f32_bytes(&host))?;
                Ok(ptr)
            };
            Ok(NetBufs { p: buf(|n| &n.p)?, m: buf(|n| &n.m)?, v: buf(|n| &n.v)?, target: buf(|n| &n.target)? })
        };
        let actor_net = upload_net(actor.len, nets.iter().map(|n| &n.actor).collect())?;
        let critic_net = upload_net(critic.len, nets.iter().flat_map(|n| n.critics.iter()).collect())?;
        let norm_mean = gpu.alloc(4 * agents * sg)?;
        let norm_std = gpu.alloc(4 * agents * sg)?;
        let norm_clip = gpu.alloc(4 * agents)?;
        let mut engine = CudaEngine {
            gpu: Mutex::new(gpu),
            actor,
            critic,
            agents,
            k,
            obs_dim,
            goal_dim: sg - obs_dim,
            actor_net,
            critic_net,
            actor_step,
            critic_step,
            norm_mean,
            norm_std,
            norm_clip,
            norms: Vec::new(),
            scratch: None,
            held: None,
            graphs: std::env::var_os("PGSER_CUDA_GRAPHS").is_none_or(|v| v != "0"),
        };
        engine.set_norms(norms)?;
        Ok(engine)
    }

    fn act_dim(&self) -> usize {
        *self.actor.sizes.last().expect("sizes")
    }

    /// The networks, targets and Adam moments on the host, in `Fused`'s form.
    pub fn nets(&self) -> Result<Vec<Nets>> {
        let gpu = &mut *self.gpu.lock().expect("the device lock");
        let (la, lc, k) = (self.actor.len, self.critic.len, self.k);
        let mut get = |b: &NetBufs, members: usize, len: usize| -> Result<Vec<Net>> {
            let (p, m, v, t) = (
                download_f32(gpu, b.p, members * len)?,
                download_f32(gpu, b.m, members * len)?,
                download_f32(gpu, b.v, members * len)?,
                download_f32(gpu, b.target, members * len)?,
            );
            let cut = |x: &[f32], j: usize| x[j * len..(j + 1) * len].to_vec();
            Ok((0..members).map(|j| Net { p: cut(&p, j), m: cut(&m, j), v: cut(&v, j), target: cut(&t, j) }).collect())
        };
        let actors = get(&self.actor_net, self.agents, la)?;
        let mut critics = get(&self.critic_net, self.agents * k, lc)?.into_iter();
        Ok(actors.into_iter().map(|actor| Nets { actor, critics: critics.by_ref().take(k).collect() }).collect())
    }

    /// Uploads the normalizers when they differ from the ones on the device.
    fn set_norms(&mut self, norms: &[Normalizer]) -> Result<()> {
        if self.norms == norms {
            return Ok(());
        }
        let mean: Vec<f32> = norms.iter().flat_map(|n| n.obs_mean.iter().chain(&n.goal_mean).copied()).collect();
        let std: Vec<f32> = norms.iter().flat_map(|n| n.obs_std.iter().chain(&n.goal_std).copied()).collect();
        let clip: Vec<f32> = norms.iter().map(|n| n.clip).collect();
        let gpu = self.gpu.get_mut().expect("the device lock");
        gpu.upload(self.norm_mean, f32_bytes(&mean))?;
        gpu.upload(self.norm_std, f32_bytes(&std))?;
        gpu.upload(self.norm_clip, f32_bytes(&clip))?;
        self.norms = norms.to_vec();
        Ok(())
    }

    /// Scratch for batches of `n` rows (once; again only if the batch size changes).
    fn size_scratch(&mut self, n: usize) -> Result<()> {
        if self.scratch.as_ref().is_some_and(|s| s.n == n) {
            return Ok(());
        }
        let (a, k, p, act) = (self.agents, self.k, parts(n), self.act_dim());
        let w = self.critic.sizes[0];
        let widest = self.actor.widest().max(self.critic.widest());
        // The block laid out for rows of held tables: the larger, so it serves both inputs.
        let staged = Staged::new(a, n, self.obs_dim, self.goal_dim, act, true);
        let gpu = self.gpu.get_mut().expect("the device lock");
        let mut f32s = |len: usize| gpu.alloc(4 * len.max(1));
        let outs = |f32s: &mut dyn FnMut(usize) -> Result<Ptr>, s: &Shape, members: usize| -> Result<Vec<Ptr>> {
            s.sizes[1..].iter().map(|&d| f32s(members * n * d)).collect()
        };
        let scratch = Scratch {
            n,
            staging: f32s(staged.len)?,
            staging_len: staged.len,
            sa: f32s(a * k * n * w)?,
            next_sa: f32s(a * k * n * w)?,
            spi: f32s(a * n * w)?,
            y: f32s(a * n)?,
            actor_out: outs(&mut f32s, &self.actor, a)?,
            critic_out: outs(&mut f32s, &self.critic, a * k)?,
            q1_out: outs(&mut f32s, &self.critic, a)?,
            g: f32s(a * k * n * widest)?,
            tmp: f32s(a * k * n * widest)?,
            dpi: f32s(a * n * act)?,
            lambda: f32s(a)?,
            actor_grad: f32s(a * p * self.actor.len)?,
            critic_grad: f32s(a * k * p * self.critic.len)?,
            sums: f32s(2 * a * p * SUMS)?, // f64
            graphs: Mutex::new(Vec::new()),
        };
        self.scratch = Some(scratch);
        Ok(())
    }

    fn norm_bufs(&self) -> (Ptr, Ptr, Ptr) {
        (self.norm_mean, self.norm_std, self.norm_clip)
    }
}

impl<G: Gpu + 'static> Engine for CudaEngine<G> {
    fn update(
        &mut self,
        c: &AgentConfig,
        batches: &[Batch],
        norms: &[Normalizer],
        noise_rngs: &mut [NpRandom],
        updates: u64,
        stats: bool,
    ) -> Result<Option<Stats>> {
        self.step(c, Input::Batches(batches), norms, noise_rngs, updates, stats)
    }

    /// Uploads `tables` once (concatenated: observations, goals, actions), when they take at most
    /// `HOLD_SHARE` of the free device memory; a FetchPush data set of the paper's size is 18 MB.
    /// From then on an update's upload is 12 bytes of row numbers, a reward, a weight and the
    /// target noise per row (36 bytes on FetchPush, against 252 with the rows), and `pgser_gather`
    /// builds the batch on the device: the copy the host made per row is gone. The rewards stay
    /// the host's (the task's reward function in f64, exactly the CPU engine's), 4 bytes a row.
    /// PGSER_CUDA_HOLD=0 declines (to time what holding saves).
    fn hold(&mut self, tables: &[Table]) -> Result<bool> {
        if std::env::var_os("PGSER_CUDA_HOLD").is_some_and(|v| v == "0") || tables.is_empty() {
            return Ok(false);
        }
        let t0 = tables[0];
        anyhow::ensure!(
            tables.iter().all(|t| (t.obs_dim, t.goal_dim, t.act_dim) == (self.obs_dim, self.goal_dim, self.act_dim())),
            "held tables must have the stack's dimensions"
        );
        let bytes: usize = tables.iter().map(Table::bytes).sum();
        let gpu = self.gpu.get_mut().expect("the device lock");
        if bytes as f64 > HOLD_SHARE * gpu.free_memory()? as f64 {
            return Ok(false);
        }
        let (od, gd, ad) = (t0.obs_dim, t0.goal_dim, t0.act_dim);
        let rows = |len: usize, d: usize| -> Result<u32> {
            u32::try_from(len / d)
                .map_err(|_| anyhow::anyhow!("a held table of {} rows: more than u32 numbers", len / d))
        };
        let mut bases = Vec::with_capacity(tables.len());
        let mut end = Base::default();
        for t in tables {
            bases.push(end);
            end.obs = end.obs.checked_add(rows(t.obs.len(), od)?).context("held observations: more than u32 rows")?;
            end.goal =
                end.goal.checked_add(rows(t.ag.len() + t.g.len(), gd)?).context("held goals: more than u32 rows")?;
            end.action = end.action.checked_add(rows(t.u.len(), ad)?).context("held actions: more than u32 rows")?;
        }
        let mut upload = |parts: &mut dyn Iterator<Item = &[f32]>, len: usize| -> Result<Ptr> {
            let ptr = gpu.alloc(4 * len)?;
            let mut off = 0;
            for part in parts {
                gpu.upload(at(ptr, off), f32_bytes(part))?;
                off += part.len();
            }
            Ok(ptr)
        };
        let obs = upload(&mut tables.iter().map(|t| t.obs), end.obs as usize * od)?;
        let goals = upload(&mut tables.iter().flat_map(|t| [t.ag, t.g]), end.goal as usize * gd)?;
        let actions = upload(&mut tables.iter().map(|t| t.u), end.action as usize * ad)?;
        self.held = Some(Held { obs, goals, actions, bases });
        Ok(true)
    }

    fn update_rows(
        &mut self,
        c: &AgentConfig,
        rows: &[Rows],
        norms: &[Normalizer],
        noise_rngs: &mut [NpRandom],
        updates: u64,
        stats: bool,
    ) -> Result<Option<Stats>> {
        anyhow::ensure!(self.held.is_some(), "rows for an engine that holds no tables");
        self.step(c, Input::Rows(rows), norms, noise_rngs, updates, stats)
    }

    /// Every agent's policy, agent i on `rows[i]` (raw observations and goals, `n` rows each),
    /// as `Fused::act_all` computes it (one product over all rows, no parts).
    fn act_all(&self, norms: &[Normalizer], rows: &[(&[f32], &[f32])], n: usize) -> Result<Vec<Vec<f32>>> {
        anyhow::ensure!(norms == self.norms, "the CUDA engine holds other normalizers than the agent's");
        let (a, od, gd, act) = (self.agents, self.obs_dim, self.goal_dim, self.act_dim());
        let sg = od + gd;
        let obs: Vec<f32> = rows.iter().flat_map(|(o, _)| o[..n * od].iter().copied()).collect();
        let goal: Vec<f32> = rows.iter().flat_map(|(_, g)| g[..n * gd].iter().copied()).collect();
        let gpu = &mut *self.gpu.lock().expect("the device lock");
        let mut temp = Temp::new(gpu);
        let (obs_d, goal_d, x) = (temp.upload(&obs)?, temp.upload(&goal)?, temp.zeros(a * n * sg)?);
        let outs = self.actor.sizes[1..].iter().map(|&d| temp.zeros(a * n * d)).collect::<Result<Vec<_>>>()?;
        let gpu = &mut *temp.gpu;
        inputs(gpu, a, 1, n, (od, gd, 0), (obs_d, goal_d, 0, 0), self.norm_bufs(), (x, 0))?;
        let view = View { params: self.actor_net.p, member_stride: self.actor.len, items: a };
        forward(gpu, &self.actor, view, Mat { ptr: x, ld: sg, trans: false, stride: n * sg }, &outs, n, 1)?;
        let top = *outs.last().expect("layers");
        gpu.launch("pgser_tanh", a * n * act, &[Arg::L((a * n * act) as i64), Arg::P(top)])?;
        let pi = download_f32(gpu, top, a * n * act)?;
        temp.free()?;
        Ok(pi.chunks(n * act).map(<[f32]>::to_vec).collect())
    }

    /// The smallest of agent 0's critics' values for `n` rows (raw s, g, a), as `Fused::q`.
    fn q(&self, norm: &Normalizer, obs: &[f32], goal: &[f32], action: &[f32], n: usize) -> Result<Vec<f32>> {
        anyhow::ensure!(norm == &self.norms[0], "the CUDA engine holds another normalizer than agent 0's");
        let (k, od, gd, act) = (self.k, self.obs_dim, self.goal_dim, self.act_dim());
        let w = od + gd + act;
        let gpu = &mut *self.gpu.lock().expect("the device lock");
        let mut temp = Temp::new(gpu);
        let (obs_d, goal_d, act_d) =
            (temp.upload(&obs[..n * od])?, temp.upload(&goal[..n * gd])?, temp.upload(&action[..n * act])?);
        let x = temp.zeros(k * n * w)?;
        let outs = self.critic.sizes[1..].iter().map(|&d| temp.zeros(k * n * d)).collect::<Result<Vec<_>>>()?;
        let best = temp.zeros(n)?;
        let gpu = &mut *temp.gpu;
        inputs(gpu, 1, k, n, (od, gd, act), (obs_d, goal_d, 0, act_d), self.norm_bufs(), (x, 0))?;
        let view = View { params: self.critic_net.p, member_stride: self.critic.len, items: k };
        forward(gpu, &self.critic, view, Mat { ptr: x, ld: w, trans: false, stride: n * w }, &outs, n, 1)?;
        let top = *outs.last().expect("layers");
        gpu.launch("pgser_min_q", n, &[Arg::I(k as i32), Arg::I(n as i32), Arg::P(top), Arg::P(best)])?;
        let out = download_f32(gpu, best, n)?;
        temp.free()?;
        Ok(out)
    }

    fn state(&self) -> Result<State> {
        Ok(State { nets: self.nets()?, actor_step: self.actor_step, critic_step: self.critic_step })
    }
}
