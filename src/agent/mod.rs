//! The agent: a goal-conditioned actor and twin critics (one for DDPG; burn modules), their
//! normalizer, and the TD3 / TD3+BC / DDPG update (`td3.rs`, on burn; `fused/`, the same update
//! written out by hand, the CPU's default), Adam (`adam.rs`) and the checkpoint file
//! (`checkpoint.rs`).
//!
//! The agent dimension: an `Agent` is a stack of A agents of the same settings, each network
//! layer one `[A, in, out]` tensor (the twin critics an ensemble of two inside it), so that a
//! grid of runs trains as one batched job. Each agent keeps its own seed streams, normalizer,
//! batches and checkpoint file; a stack of one is a single run, and an agent trained in a stack
//! ends with the same bits as trained alone (`tests.rs`).
//!
//! Parameters are kept as plain (non-autodiff) tensors. An update makes autodiff leaves of the
//! networks it trains (`Mlp::tracked`), reads their gradients, and lets our own Adam write new
//! plain tensors. That keeps every piece of training state (weights, targets, Adam moments,
//! step counts) in structs we can name, save and restore exactly, which `--resume` needs.

mod adam;
pub mod checkpoint;
pub mod cuda;
pub mod engine;
mod fused;
mod host;
mod shards;
mod td3;
#[cfg(test)]
mod testdata;
#[cfg(test)]
mod tests;

use burn::module::{Module, Param};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use clap::{Args, ValueEnum};
use serde::{Deserialize, Serialize};

pub use adam::Adam;
pub use engine::{Batch, EngineKind, Precision, Rows, Table};
pub use host::HostActor;
pub use shards::Shards;
pub use td3::{Agent, UpdateStats, net_sizes, td_target};

use crate::nprandom::NpRandom;

/// Which learner: TD3 (Fujimoto et al. 2018), TD3+BC (Fujimoto & Gu 2021), or DDPG (Lillicrap et
/// al. 2016) as HER and MRN train it online (`pgser-train online`, docs/online.md): one critic,
/// an action penalty, the actor every update and the targets every `policy_delay` updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Algo {
    Td3,
    Td3bc,
    Ddpg,
}

impl Algo {
    /// The name users write (flags, pipeline files, file names).
    pub fn name(self) -> &'static str {
        match self {
            Algo::Td3 => "td3",
            Algo::Td3bc => "td3bc",
            Algo::Ddpg => "ddpg",
        }
    }

    /// Critics per agent: TD3's twins, or DDPG's one.
    pub fn critics(self) -> usize {
        match self {
            Algo::Td3 | Algo::Td3bc => 2,
            Algo::Ddpg => 1,
        }
    }
}

/// Every hyper-parameter of the update, with the defaults of docs/domain.md (GoFAR's goal-conditioned
/// offline settings, sfujim/TD3_BC's losses). Each field is a `pgser-train` flag.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Args)]
pub struct AgentConfig {
    /// Learner.
    #[arg(long, value_enum, default_value = "td3bc")]
    pub algo: Algo,
    /// Discount factor γ.
    #[arg(long, default_value_t = 0.98)]
    pub gamma: f64,
    /// Adam learning rate of actor and critics [default: 1e-3 for td3 and ddpg, 3e-4 for td3bc].
    #[arg(long)]
    pub lr: Option<f64>,
    /// TD3+BC's α: the actor loss is −α/mean|Q| · mean Q + MSE(π(s), a).
    #[arg(long, default_value_t = 2.5)]
    pub alpha: f64,
    /// Std of the Gaussian noise added to the target policy's action.
    #[arg(long, default_value_t = 0.2)]
    pub policy_noise: f64,
    /// That noise is clipped to ±noise_clip.
    #[arg(long, default_value_t = 0.5)]
    pub noise_clip: f64,
    /// The actor and the targets are updated every `policy_delay` critic updates (ddpg: the
    /// actor every update, the targets every `policy_delay`).
    #[arg(long, default_value_t = 2)]
    pub policy_delay: u64,
    /// Polyak rate of the target networks.
    #[arg(long, default_value_t = 0.005)]
    pub tau: f64,
    /// Units per hidden layer.
    #[arg(long, default_value_t = 256)]
    pub hidden: usize,
    /// Hidden layers per network.
    #[arg(long, default_value_t = 3)]
    pub layers: usize,
    /// Normalized inputs are clipped to ±norm_clip.
    #[arg(long, default_value_t = 5.0)]
    pub norm_clip: f64,
    /// Action penalty: action_l2 · mean π² is added to the actor loss [default: 1 for ddpg, as
    /// HER and MRN have it; 0 for td3 and td3bc].
    #[arg(long)]
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub action_l2: Option<f64>,
    /// How the CPU engine's matrix products round: `native` (gemm's fastest kernels for this CPU:
    /// the bytes are the same on another machine only when it picks the same kernels), or
    /// `portable` (one fixed order: the same bytes on every x86-64, at a cost; docs/domain.md,
    /// "The same bytes on another machine"). Only `--device cpu` has it.
    #[arg(long, value_enum, default_value = "native")]
    #[serde(default, skip_serializing_if = "Arithmetic::is_native")]
    pub arithmetic: Arithmetic,
}

/// How the hand-written CPU engine computes its matrix products (`fused/product.rs` says why and
/// how). Not written into a run's settings when native, so that the runs before this setting
/// existed keep their bytes and their pipelines' keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Arithmetic {
    /// `gemm`'s kernels for the CPU at hand (AVX-512, AVX2 or scalar): fastest; a machine with
    /// other kernels trains a run that is the same in distribution, not in bytes.
    #[default]
    Native,
    /// Every sum in one fixed order of single-rounding FMAs: the same bytes on any machine.
    Portable,
}

impl Arithmetic {
    pub fn is_native(&self) -> bool {
        *self == Arithmetic::Native
    }

    /// The name users write (flags, pipeline files).
    pub fn name(self) -> &'static str {
        match self {
            Arithmetic::Native => "native",
            Arithmetic::Portable => "portable",
        }
    }
}

impl Default for AgentConfig {
    fn default() -> Self {
        AgentConfig {
            algo: Algo::Td3bc,
            gamma: 0.98,
            lr: None,
            alpha: 2.5,
            policy_noise: 0.2,
            noise_clip: 0.5,
            policy_delay: 2,
            tau: 0.005,
            hidden: 256,
            layers: 3,
            norm_clip: 5.0,
            action_l2: None,
            arithmetic: Arithmetic::Native,
        }
    }
}

impl AgentConfig {
    pub fn lr(&self) -> f64 {
        self.lr.unwrap_or(match self.algo {
            Algo::Td3 | Algo::Ddpg => 1e-3,
            Algo::Td3bc => 3e-4,
        })
    }

    /// The weight of the action penalty: DDPG's 1 unless set (baselines' HER and MRN), none
    /// for the TD3 learners unless set.
    pub fn action_l2(&self) -> f64 {
        self.action_l2.unwrap_or(match self.algo {
            Algo::Ddpg => 1.0,
            Algo::Td3 | Algo::Td3bc => 0.0,
        })
    }

    /// Rewards are in {−1, 0}, so returns, and Q, lie in [−1/(1−γ), 0]; clipping the TD target
    /// there keeps bootstrapping from drifting out of that range on unreachable goals.
    pub fn target_range(&self) -> (f64, f64) {
        (-1.0 / (1.0 - self.gamma), 0.0)
    }
}

/// One fully connected layer for each of `M` members stacked on the first dimension: the weight
/// is `[M, in, out]` so the forward pass is one batched `x·W + b` for all members (CORL's
/// `VectorizedLinear`), and the bias is `[M, 1, out]` so it broadcasts over the batch rows.
#[derive(Module, Debug)]
pub struct Dense {
    pub weight: Param<Tensor<3>>,
    pub bias: Param<Tensor<3>>,
}

/// `M` ReLU multilayer perceptrons of the same shapes with a linear last layer, held as one
/// stack: the actors of A agents (M = A), or their twin critics (M = 2A, agent a's critic 1 at
/// member 2a and critic 2 at 2a + 1; DDPG: M = A, one critic each). Member m only ever sees row block m of the input, so
/// members train independently; a stack of one is a plain network.
#[derive(Module, Debug)]
pub struct Mlp {
    pub layers: Vec<Dense>,
}

/// One member's parameters on the host, layer by layer: weight `[in, out]` and bias `[out]`.
pub type Member = Vec<(Vec<f32>, Vec<f32>)>;

/// PyTorch's default `nn.Linear` initialisation, U(±1/√fan_in) for weights and biases, drawn
/// from our own seeded stream (in PyTorch's `[out, in]` order, then transposed to ours) so a
/// seed fixes the initial weights on every backend and whatever stack the network sits in.
pub fn init_member(sizes: &[usize], rng: &mut NpRandom) -> Member {
    sizes
        .windows(2)
        .map(|io| {
            let (fan_in, fan_out) = (io[0], io[1]);
            let bound = 1.0 / (fan_in as f64).sqrt();
            let mut draw = |n| (0..n).map(|_| rng.uniform(-bound, bound) as f32).collect::<Vec<f32>>();
            let w = draw(fan_in * fan_out);
            let b = draw(fan_out);
            (transpose(&w, fan_out, fan_in), b)
        })
        .collect()
}

/// `values` of a `[rows, cols]` matrix in `[cols, rows]` order.
pub fn transpose(values: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut out = vec![0.0; values.len()];
    for r in 0..rows {
        for c in 0..cols {
            out[c * rows + r] = values[r * cols + c];
        }
    }
    out
}

impl Mlp {
    /// A stack of the given members (all of the same shapes).
    pub fn from_members(members: &[Member], device: &Device) -> Mlp {
        let m = members.len();
        let layers = (0..members[0].len())
            .map(|l| {
                let (fan_out, fan_in) = (members[0][l].1.len(), members[0][l].0.len() / members[0][l].1.len());
                let w: Vec<f32> = members.iter().flat_map(|mem| mem[l].0.iter().copied()).collect();
                let b: Vec<f32> = members.iter().flat_map(|mem| mem[l].1.iter().copied()).collect();
                Dense {
                    weight: Param::from_tensor(Tensor::from_data(TensorData::new(w, [m, fan_in, fan_out]), device)),
                    bias: Param::from_tensor(Tensor::from_data(TensorData::new(b, [m, 1, fan_out]), device)),
                }
            })
            .collect();
        Mlp { layers }
    }

    /// Members in the stack.
    pub fn members(&self) -> usize {
        self.layers[0].weight.val().dims()[0]
    }

    /// `x` is `[M, rows, in]` (row block m goes through member m); returns `[M, rows, out]`.
    pub fn forward(&self, mut x: Tensor<3>) -> Tensor<3> {
        let last = self.layers.len() - 1;
        for (i, layer) in self.layers.iter().enumerate() {
            x = x.matmul(layer.weight.val()) + layer.bias.val();
            if i < last {
                x = relu(x);
            }
        }
        x
    }

    /// A network of the same shapes whose weights are `w(weight)` and biases `b(bias)`.
    fn map(&self, w: impl Fn(Tensor<3>) -> Tensor<3>, b: impl Fn(Tensor<3>) -> Tensor<3>) -> Mlp {
        let layer = |l: &Dense| Dense {
            weight: Param::from_tensor(w(l.weight.val())),
            bias: Param::from_tensor(b(l.bias.val())),
        };
        Mlp { layers: self.layers.iter().map(layer).collect() }
    }

    /// A copy whose parameters are fresh autodiff leaves, for one backward pass.
    pub fn tracked(&self) -> Mlp {
        self.map(|t| t.autodiff().require_grad(), |t| t.autodiff().require_grad())
    }

    /// A detached copy (the tensors are shared, not copied: burn tensors are immutable handles).
    pub fn copy(&self) -> Mlp {
        self.map(|t| t, |t| t)
    }

    /// A network of the same shapes with every parameter zero (Adam's initial moments).
    pub fn zeros_like(&self) -> Mlp {
        self.map(|t| t.zeros_like(), |t| t.zeros_like())
    }

    /// Every `stride`-th member from `offset` on (critic 1 of each agent: stride 2, offset 0), as
    /// a stack of its own.
    pub fn every(&self, stride: usize, offset: usize) -> Mlp {
        let pick = |t: Tensor<3>| {
            let [m, r, c] = t.dims();
            t.reshape([m / stride, stride, r, c]).narrow(1, offset, 1).reshape([m / stride, r, c])
        };
        self.map(pick, pick)
    }

    /// The stacks of `parts` one after the other, as one stack.
    pub fn concat(parts: &[&Mlp]) -> Mlp {
        let layers = (0..parts[0].layers.len())
            .map(|l| Dense {
                weight: Param::from_tensor(Tensor::cat(parts.iter().map(|p| p.layers[l].weight.val()).collect(), 0)),
                bias: Param::from_tensor(Tensor::cat(parts.iter().map(|p| p.layers[l].bias.val()).collect(), 0)),
            })
            .collect();
        Mlp { layers }
    }

    /// Parameters in a fixed order (w0, b0, w1, b1, ...) as flat f32 with their stacked
    /// `[M, in, out]` / `[M, 1, out]` shapes: what Adam's state and the tests walk over.
    pub fn tensors(&self) -> Vec<(Vec<usize>, Vec<f32>)> {
        let mut out = Vec::with_capacity(2 * self.layers.len());
        for l in &self.layers {
            out.push(host(l.weight.val()));
            out.push(host(l.bias.val()));
        }
        out
    }

    /// Member `m`'s parameters on the host (weights `[in, out]`, biases `[out]`).
    pub fn member(&self, m: usize) -> Member {
        member_of(&self.tensors(), m)
    }

    /// Replaces every parameter, in `tensors()` order (stacked shapes).
    pub fn set_tensors(&mut self, values: &[Vec<f32>], device: &Device) {
        for (i, l) in self.layers.iter_mut().enumerate() {
            let [m, fin, fout] = l.weight.val().dims();
            l.weight =
                Param::from_tensor(Tensor::from_data(TensorData::new(values[2 * i].clone(), [m, fin, fout]), device));
            l.bias =
                Param::from_tensor(Tensor::from_data(TensorData::new(values[2 * i + 1].clone(), [m, 1, fout]), device));
        }
    }

    /// target ← (1 − τ)·target + τ·online, layer by layer.
    pub fn soft_update(&mut self, online: &Mlp, tau: f64) {
        for (t, o) in self.layers.iter_mut().zip(&online.layers) {
            t.weight = Param::from_tensor(t.weight.val().mul_scalar(1.0 - tau) + o.weight.val().mul_scalar(tau));
            t.bias = Param::from_tensor(t.bias.val().mul_scalar(1.0 - tau) + o.bias.val().mul_scalar(tau));
        }
    }
}

/// Member `m` of stacked tensors in `Mlp::tensors()` layout: each tensor's leading dimension is
/// the member, so its block is one contiguous slice.
pub fn member_of(stacked: &[(Vec<usize>, Vec<f32>)], m: usize) -> Member {
    stacked
        .chunks(2)
        .map(|wb| {
            let slice = |(shape, values): &(Vec<usize>, Vec<f32>)| {
                let len = values.len() / shape[0];
                values[m * len..(m + 1) * len].to_vec()
            };
            (slice(&wb[0]), slice(&wb[1]))
        })
        .collect()
}

/// A tensor's shape and values on the host.
pub fn host<const D: usize>(t: Tensor<D>) -> (Vec<usize>, Vec<f32>) {
    let dims = t.dims().to_vec();
    let data = t.into_data();
    let values = data.as_slice::<f32>().expect("pgser networks are float32").to_vec();
    (dims, values)
}

/// Mean and standard deviation per dimension of observations and goals, fitted once on the data.
///
/// Offline, the data never changes, so the running statistics GoFAR updates per batch converge
/// to these; fitting them once makes the normalizer a fixed function that the checkpoint can
/// carry and evaluation reuses bit for bit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Normalizer {
    pub obs_mean: Vec<f32>,
    pub obs_std: Vec<f32>,
    pub goal_mean: Vec<f32>,
    pub goal_std: Vec<f32>,
    pub clip: f32,
}

impl Normalizer {
    /// No normalization (mean 0, std 1) but the clip: for benchmarks and tests on random data.
    pub fn identity(task: &crate::task::Task, clip: f64) -> Normalizer {
        Normalizer {
            obs_mean: vec![0.0; task.obs_dim],
            obs_std: vec![1.0; task.obs_dim],
            goal_mean: vec![0.0; task.goal_dim],
            goal_std: vec![1.0; task.goal_dim],
            clip: clip as f32,
        }
    }
}

/// GoFAR's normalizer floors the std at 0.01 so constant dimensions do not blow up.
const MIN_STD: f64 = 1e-2;

impl Normalizer {
    /// Statistics of `obs` rows (dimension `obs_dim`) and of `goals` rows (dimension `goal_dim`);
    /// each argument is a list of flat slices so callers can pass several arrays without copying.
    pub fn fit(obs: &[&[f32]], obs_dim: usize, goals: &[&[f32]], goal_dim: usize, clip: f64) -> Normalizer {
        let (obs_mean, obs_std) = mean_std(obs, obs_dim);
        let (goal_mean, goal_std) = mean_std(goals, goal_dim);
        Normalizer { obs_mean, obs_std, goal_mean, goal_std, clip: clip as f32 }
    }

    /// Writes the network input `[clip((o − μ)/σ), clip((g − μ)/σ)]` for `n` rows into `out`.
    pub fn input(&self, obs: &[f32], goal: &[f32], n: usize, out: &mut Vec<f32>) {
        let (od, gd) = (self.obs_mean.len(), self.goal_mean.len());
        out.clear();
        out.reserve(n * (od + gd));
        let c = self.clip;
        for i in 0..n {
            let o = &obs[i * od..(i + 1) * od];
            out.extend(o.iter().zip(&self.obs_mean).zip(&self.obs_std).map(|((x, m), s)| ((x - m) / s).clamp(-c, c)));
            let g = &goal[i * gd..(i + 1) * gd];
            out.extend(g.iter().zip(&self.goal_mean).zip(&self.goal_std).map(|((x, m), s)| ((x - m) / s).clamp(-c, c)));
        }
    }
}

fn mean_std(parts: &[&[f32]], dim: usize) -> (Vec<f32>, Vec<f32>) {
    let mut sum = vec![0.0f64; dim];
    let mut n = 0usize;
    for p in parts {
        for row in p.chunks_exact(dim) {
            for (s, &x) in sum.iter_mut().zip(row) {
                *s += x as f64;
            }
            n += 1;
        }
    }
    let mean: Vec<f64> = sum.iter().map(|s| s / n.max(1) as f64).collect();
    let mut sq = vec![0.0f64; dim];
    for p in parts {
        for row in p.chunks_exact(dim) {
            for ((s, &x), m) in sq.iter_mut().zip(row).zip(&mean) {
                *s += (x as f64 - m) * (x as f64 - m);
            }
        }
    }
    let std = sq.iter().map(|s| (s / n.max(1) as f64).sqrt().max(MIN_STD) as f32).collect();
    (mean.iter().map(|&m| m as f32).collect(), std)
}

/// Where the networks run, and on which engine.
/// - `cpu`: the hand-written update (`fused/`), pgser's fastest on a CPU (BENCHMARKS.md);
/// - `cpu-burn`: burn's flex backend, the reference the hand-written engines are tested against;
/// - `cuda`: the hand-written CUDA engine (`cuda/`) on NVIDIA GPU 0, FP32; `cuda-tf32` the same
///   with TF32 tensor cores in its products (opt-in). In every build: the driver, cuBLAS and NVRTC
///   are opened at run time (docs/gpu.md says where they come from);
/// - `wgpu` (Vulkan, Metal, DX12): burn on a GPU, when pgser is built with `--features wgpu`;
/// - `cuda-burn`: burn on an NVIDIA GPU through CUDA, when pgser is built with `--features
///   cuda-burn` (`make build-cuda`: its LLVM comes from the package registry, docs/gpu.md).
///
/// Everything but training (evaluation, scoring, reports) runs the same on `cpu` and `cpu-burn`.
/// A precision is a device here rather than a flag of its own, so that pipelines, Slurm jobs and
/// checkpoints carry it as they carry the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    Cpu,
    CpuBurn,
    Cuda,
    CudaTf32,
    Wgpu,
    CudaBurn,
}

impl Backend {
    /// The burn device of the agent's own fields: the GPU for burn's GPU backends, the CPU
    /// otherwise (a hand-written engine keeps the training state itself). `cuda` checks here that
    /// the NVIDIA driver loads, so a machine without one fails before any step starts.
    pub fn device(self) -> anyhow::Result<Device> {
        match self {
            Backend::Cpu | Backend::CpuBurn => Ok(Device::flex()),
            Backend::Cuda | Backend::CudaTf32 => {
                if !cuda::driver_present() {
                    anyhow::bail!(
                        "--device {}: no NVIDIA driver here (libcuda.so.1 does not load): use --device cpu, or run on a machine with an NVIDIA GPU and its driver",
                        self.name()
                    );
                }
                Ok(Device::flex())
            }
            #[cfg(feature = "wgpu")]
            Backend::Wgpu => Ok(wgpu_device()),
            #[cfg(feature = "cuda-burn")]
            Backend::CudaBurn => cuda_device(),
            #[allow(unreachable_patterns)]
            other => anyhow::bail!(
                "--device {}: this pgser was built without that backend (rebuild with {})",
                other.name(),
                other.build_command()
            ),
        }
    }

    /// How to get a build with this backend: a cargo feature, or for `cuda-burn` the make target
    /// that first installs the LLVM its build script would otherwise download (docs/gpu.md).
    fn build_command(self) -> &'static str {
        match self {
            Backend::Cpu | Backend::CpuBurn | Backend::Cuda | Backend::CudaTf32 => "`cargo build --release`",
            Backend::Wgpu => "`cargo build --release --features wgpu`",
            Backend::CudaBurn => "`make build-cuda`, which installs the LLVM it needs; docs/gpu.md",
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::CpuBurn => "cpu-burn",
            Backend::Cuda => "cuda",
            Backend::CudaTf32 => "cuda-tf32",
            Backend::Wgpu => "wgpu",
            Backend::CudaBurn => "cuda-burn",
        }
    }

    /// The hand-written engine stacks train on, if any (else burn's update).
    pub fn engine(self) -> Option<EngineKind> {
        match self {
            Backend::Cpu => Some(EngineKind::Cpu),
            Backend::Cuda => Some(EngineKind::Cuda(Precision::F32)),
            Backend::CudaTf32 => Some(EngineKind::Cuda(Precision::Tf32)),
            Backend::CpuBurn | Backend::Wgpu | Backend::CudaBurn => None,
        }
    }
}

/// CUDA device 0, after checking that the driver's library loads. Why check first: cudarc opens
/// `libcuda.so` in burn's worker thread and panics there when it is missing, and the caller then
/// dies on a closed channel with no word about CUDA; a machine without the NVIDIA driver must get
/// one line instead. The device's name is logged once, as wgpu's adapter is.
#[cfg(feature = "cuda-burn")]
fn cuda_device() -> anyhow::Result<Device> {
    static LOGGED: std::sync::Once = std::sync::Once::new();
    // SAFETY: dlopen of a shared library by name, flags from libc; the handle is closed at once.
    let handle = unsafe { libc::dlopen(c"libcuda.so.1".as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL) };
    if handle.is_null() {
        anyhow::bail!(
            "--device cuda-burn: no NVIDIA driver here (libcuda.so.1 does not load): use --device cpu, or run on a machine with an NVIDIA GPU and its driver"
        );
    }
    // SAFETY: the handle came from the dlopen above and is not used after.
    unsafe { libc::dlclose(handle) };
    let device = Device::cuda(0);
    LOGGED.call_once(|| match device.identity() {
        Some(id) => eprintln!("--device cuda-burn: running on {}", id.name),
        None => eprintln!("--device cuda-burn: running on CUDA device 0"),
    });
    Ok(device)
}

/// The adapter wgpu picks by its own heuristics (a discrete GPU first). Which one it picked is
/// logged once per process: wgpu falls back to whatever the machine offers, down to a software
/// rasterizer such as Mesa's lavapipe, and a grid meant for a GPU must not run for hours on a
/// CPU-emulated one without saying so. Opening the device here also makes a machine without any
/// adapter fail before a step starts, not at its first tensor.
#[cfg(feature = "wgpu")]
fn wgpu_device() -> Device {
    static LOGGED: std::sync::Once = std::sync::Once::new();
    let device = Device::wgpu(burn::tensor::DeviceKind::default());
    LOGGED.call_once(|| match device.identity() {
        Some(id) if id.physical.is_none() => eprintln!(
            "--device wgpu: running on {} (no GPU: a software adapter; a GPU needs its vendor's Vulkan driver)",
            id.name
        ),
        Some(id) => eprintln!("--device wgpu: running on {}", id.name),
        None => eprintln!("--device wgpu: running on an adapter that does not name itself"),
    });
    device
}
