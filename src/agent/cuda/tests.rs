//! The CUDA engine against the CPU engine (its reference), on the host shim; and its kernels
//! through NVRTC for the GPUs pgser is measured on.

use burn::tensor::Device;

use super::host::HostGpu;
use super::*;
use crate::agent::engine::{Nets, Rows, Table};
use crate::agent::fused::Fused;
use crate::agent::testdata::{batch, norms};
use crate::agent::{Agent, AgentConfig, Algo};
use crate::task::Task;

/// A new stack of `seeds.len()` agents on the CPU engine, the same state on the shim's engine,
/// and the agents' normalizers and noise streams.
fn pair(cfg: &AgentConfig, task: &Task, seeds: &[u64]) -> (Fused, CudaEngine<HostGpu>, Vec<Normalizer>, Vec<NpRandom>) {
    let agent = Agent::stack_new(cfg.clone(), task.clone(), norms(task, seeds.len()), seeds, Device::flex());
    let s = agent.burn_state();
    let (actor, critic) = crate::agent::net_sizes(cfg, task);
    let fused = Fused::new(&actor, &critic, s.nets.clone(), s.actor_step, s.critic_step);
    let engine = CudaEngine::new(
        HostGpu::default(),
        &actor,
        &critic,
        task.obs_dim,
        &s.nets,
        &agent.norms,
        s.actor_step,
        s.critic_step,
    )
    .expect("the shim's engine");
    (fused, engine, agent.norms, agent.noise_rngs)
}

/// Compares two stacks' every network, target and Adam moment: the largest difference relative
/// to each buffer's scale.
fn worst(x: &[Nets], y: &[Nets]) -> f32 {
    let nets = |n: &[Nets]| {
        n.iter().flat_map(|a| std::iter::once(a.actor.clone()).chain(a.critics.clone())).collect::<Vec<_>>()
    };
    let mut worst = 0.0f32;
    for (a, b) in nets(x).iter().zip(nets(y)) {
        for (u, v) in [(&a.p, &b.p), (&a.m, &b.m), (&a.v, &b.v), (&a.target, &b.target)] {
            let scale = u.iter().fold(0.0f32, |m, x| m.max(x.abs())).max(f32::MIN_POSITIVE);
            let diff = u.iter().zip(v).fold(0.0f32, |m, (p, q)| m.max((p - q).abs()));
            worst = worst.max(diff / scale);
        }
    }
    worst
}

#[test]
fn the_cuda_engine_on_the_host_shim_is_the_cpu_engine_bit_for_bit() {
    // The CUDA engine's kernels (compiled as C++) and its launch sequence, with the CPU engine's
    // products standing in for cuBLAS's: a stack of three agents, batches of 520 rows in two
    // parts, priorities on one agent, per-agent normalizers, DDPG with its action penalty. Every
    // logged loss, every weight, target and Adam moment must be the CPU engine's bits over 200
    // updates (the issue asks 1e-5; bit equality is what the design gives, and it makes a wrong
    // index impossible to hide behind a tolerance).
    let task = Task::known("FetchPush").unwrap();
    for algo in [Algo::Td3bc, Algo::Td3, Algo::Ddpg] {
        let cfg = AgentConfig { algo, hidden: 64, layers: 2, lr: Some(3e-4), ..AgentConfig::default() };
        let n = 520;
        assert_eq!(parts(n), 2);
        let (mut f, mut engine, norms, mut cpu_rngs) = pair(&cfg, &task, &[3, 8, 21]);
        let mut rngs = cpu_rngs.clone();
        for u in 0..200u64 {
            let b: Vec<Batch> = (0..3).map(|i| batch(&task, n, 1000 * u + i, i == 1)).collect();
            let x = f.update(&cfg, &b, &norms, &mut cpu_rngs, u + 1);
            let y = engine.update(&cfg, &b, &norms, &mut rngs, u + 1, true).unwrap().unwrap();
            assert_eq!(x, y, "{algo:?} update {u}: logged losses");
        }
        assert_eq!(cpu_rngs, rngs, "{algo:?}: noise streams");
        assert_eq!((f.actor_step, f.critic_step), (engine.actor_step, engine.critic_step), "{algo:?}: Adam steps");
        let gpu_nets = engine.nets().unwrap();
        assert_eq!(worst(&f.nets, &gpu_nets), 0.0, "{algo:?}: the state differs");

        // Acting and scoring: every agent's policy, and agent 0's min Q.
        let rows: Vec<Batch> = (0..3).map(|i| batch(&task, 37, 77 + i, false)).collect();
        let pairs: Vec<(&[f32], &[f32])> = rows.iter().map(|b| (&b.obs[..], &b.goal[..])).collect();
        assert_eq!(f.act_all(&norms, &pairs, 37), engine.act_all(&norms, &pairs, 37).unwrap(), "{algo:?}: act_all");
        let r = &rows[0];
        assert_eq!(
            f.q(&norms[0], &r.obs, &r.goal, &r.action, 37),
            engine.q(&norms[0], &r.obs, &r.goal, &r.action, 37).unwrap(),
            "{algo:?}: q"
        );
    }
}

#[test]
fn the_shim_engine_is_the_cpu_engine_with_one_part_and_with_four() {
    // Batch sizes that cut into one part (255 rows) and four (1031 rows, uneven parts), where
    // every per-part index is exercised differently.
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { algo: Algo::Td3bc, hidden: 32, layers: 3, ..AgentConfig::default() };
    for n in [255, 1031] {
        let (mut f, mut engine, norms, mut cpu_rngs) = pair(&cfg, &task, &[5]);
        engine.graphs = false; // every launch as it comes (the other test replays graphs)
        let mut rngs = cpu_rngs.clone();
        for u in 0..6u64 {
            let b = vec![batch(&task, n, 31 * u + n as u64, true)];
            f.update(&cfg, &b, &norms, &mut cpu_rngs, u + 1);
            engine.update(&cfg, &b, &norms, &mut rngs, u + 1, false).unwrap();
        }
        assert_eq!(worst(&f.nets, &engine.nets().unwrap()), 0.0, "n = {n} ({} parts)", parts(n));
    }
}

#[test]
fn a_refused_graph_capture_falls_back_to_plain_launches_with_the_same_bits() {
    // A driver that cannot capture (the second update of a kind is the one captured): the engine
    // warns, launches that update as it comes, stops capturing, and trains exactly as an engine
    // that never captured.
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { algo: Algo::Td3, hidden: 32, layers: 2, ..AgentConfig::default() };
    let (_, mut refused, norms, rngs) = pair(&cfg, &task, &[4, 9]);
    let (_, mut plain, _, _) = pair(&cfg, &task, &[4, 9]);
    refused.gpu.lock().unwrap().refuse_capture = true;
    plain.graphs = false;
    let (mut r1, mut r2) = (rngs.clone(), rngs);
    for u in 0..8u64 {
        let b: Vec<Batch> = (0..2).map(|i| batch(&task, 64, 17 * u + i, false)).collect();
        let x = refused.update(&cfg, &b, &norms, &mut r1, u + 1, true).unwrap();
        let y = plain.update(&cfg, &b, &norms, &mut r2, u + 1, true).unwrap();
        assert_eq!(x, y, "update {u}");
    }
    assert!(!refused.graphs, "the engine goes on without graphs");
    assert_eq!(worst(&refused.nets().unwrap(), &plain.nets().unwrap()), 0.0);
    assert_eq!(r1, r2);
}

#[test]
fn a_launch_that_fails_under_capture_is_the_error_reported() {
    // The capture of a failed launch is invalid too; the error must name the launch.
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { algo: Algo::Td3bc, hidden: 32, layers: 2, ..AgentConfig::default() };
    let (_, mut engine, norms, mut rngs) = pair(&cfg, &task, &[1]);
    let b = vec![batch(&task, 64, 5, false)];
    // Updates 1 and 3 are of one kind (the delayed actor rests in both): the first runs eagerly,
    // the second is captured.
    engine.update(&cfg, &b, &norms, &mut rngs, 1, false).unwrap();
    {
        let mut gpu = engine.gpu.lock().unwrap();
        gpu.fail_launch = Some("pgser_td_target");
        gpu.refuse_capture = true;
    }
    let e = engine.update(&cfg, &b, &norms, &mut rngs, 3, false).unwrap_err();
    assert!(format!("{e:#}").contains("launching pgser_td_target failed"), "{e:#}");
    assert!(!engine.gpu.lock().unwrap().capturing(), "the capture was ended");
}

/// A table of `episodes` episodes of T = 7 (random values), as the sampler lends it to an engine.
struct OwnedTable {
    obs: Vec<f32>,
    ag: Vec<f32>,
    g: Vec<f32>,
    u: Vec<f32>,
    dims: (usize, usize, usize),
    episodes: usize,
}

const T: usize = 7;

impl OwnedTable {
    fn new(task: &Task, episodes: usize, seed: u64) -> OwnedTable {
        let mut rng = NpRandom::new(seed);
        let mut u = |k: usize| (0..k).map(|_| rng.uniform(-1.0, 1.0) as f32).collect::<Vec<_>>();
        let (od, gd, ad) = (task.obs_dim, task.goal_dim, task.act_dim);
        let (rows, steps) = (episodes * T, episodes * (T - 1));
        OwnedTable {
            obs: u(rows * od),
            ag: u(rows * gd),
            g: u(steps * gd),
            u: u(steps * ad),
            dims: (od, gd, ad),
            episodes,
        }
    }

    fn table(&self) -> Table<'_> {
        let (obs_dim, goal_dim, act_dim) = self.dims;
        Table { obs_dim, goal_dim, act_dim, obs: &self.obs, ag: &self.ag, g: &self.g, u: &self.u }
    }

    /// `n` random rows of this table (as table `index`): transitions, goals of either kind,
    /// rewards, and weights when `weighted`.
    fn rows(&self, index: usize, n: usize, seed: u64, weighted: bool) -> Rows {
        let mut rng = NpRandom::new(seed);
        let goal_rows = self.table().goal_rows();
        let mut r = Rows { table: index, ..Rows::default() };
        for _ in 0..n {
            let (e, t) = (rng.below(self.episodes), rng.below(T - 1));
            r.obs.push((e * T + t) as u32);
            r.action.push((e * (T - 1) + t) as u32);
            r.goal.push(rng.below(goal_rows) as u32);
            r.reward.push(if rng.random() < 0.5 { -1.0 } else { 0.0 });
            if weighted {
                r.weight.push(0.5 + rng.random() as f32);
            }
        }
        r
    }
}

#[test]
fn batches_gathered_from_held_tables_train_as_the_cpu_engine_on_the_hosts_batches() {
    // The trainer's path on a GPU: the tables held on the device, each update's rows sent as
    // numbers, `pgser_gather` building the batch. Against the CPU engine trained on the same rows
    // gathered on the host (`Rows::gather`, what it trains on everywhere else): the same bits.
    // Two tables (a grid's cells may bring different data), agents 0 and 2 on the first, the
    // second table's rows offset in the device's concatenation, priorities' weights on agent 1.
    let task = Task::known("FetchPush").unwrap();
    let tables = [OwnedTable::new(&task, 40, 1), OwnedTable::new(&task, 25, 2)];
    let views: Vec<Table> = tables.iter().map(OwnedTable::table).collect();
    for algo in [Algo::Td3bc, Algo::Td3] {
        let cfg = AgentConfig { algo, hidden: 64, layers: 2, lr: Some(3e-4), ..AgentConfig::default() };
        let (mut f, mut engine, norms, mut cpu_rngs) = pair(&cfg, &task, &[3, 8, 21]);
        assert!(engine.hold(&views).unwrap(), "the shim holds them");
        let mut rngs = cpu_rngs.clone();
        for u in 0..40u64 {
            let rows: Vec<Rows> = (0..3)
                .map(|i| {
                    let t = usize::from(i == 1);
                    tables[t].rows(t, 300, 100 * u + i as u64, i == 1)
                })
                .collect();
            let b: Vec<Batch> = rows.iter().map(|r| r.gather(&views[r.table])).collect();
            let x = f.update(&cfg, &b, &norms, &mut cpu_rngs, u + 1);
            let y = engine.update_rows(&cfg, &rows, &norms, &mut rngs, u + 1, true).unwrap().unwrap();
            assert_eq!(x, y, "{algo:?} update {u}: logged losses");
        }
        assert_eq!(cpu_rngs, rngs, "{algo:?}: noise streams");
        assert_eq!(worst(&f.nets, &engine.nets().unwrap()), 0.0, "{algo:?}: the state differs");
    }
}

#[test]
fn tables_too_large_for_the_device_are_not_held_and_rows_are_refused_then() {
    let task = Task::known("FetchReach").unwrap();
    let table = OwnedTable::new(&task, 10, 3);
    let cfg = AgentConfig { hidden: 16, layers: 2, ..AgentConfig::default() };
    let (_, mut engine, norms, mut rngs) = pair(&cfg, &task, &[1]);
    // The table is 10 · 7 · (10 + 3) + 10 · 6 · (3 + 4) floats: 5.3 kB, over half of 8 kB.
    engine.gpu.get_mut().unwrap().free_bytes = 8_000;
    assert!(!engine.hold(&[table.table()]).unwrap());
    let rows = [table.rows(0, 8, 1, false)];
    let err = engine.update_rows(&cfg, &rows, &norms, &mut rngs, 1, false).unwrap_err().to_string();
    assert!(err.contains("holds no tables"), "{err}");
    engine.gpu.get_mut().unwrap().free_bytes = 16_000;
    assert!(engine.hold(&[table.table()]).unwrap());
    engine.update_rows(&cfg, &rows, &norms, &mut rngs, 1, false).unwrap();
}

#[test]
fn the_shim_refuses_an_operand_outside_its_buffers() {
    let mut gpu = HostGpu::default();
    let a = gpu.alloc(4 * 6).unwrap();
    let c = gpu.alloc(4 * 4).unwrap();
    let m = |ptr, ld| Mat { ptr, ld, trans: false, stride: 0 };
    // 2×3 · 3×2 reads B as 3×2 from a 6-float buffer: fine; 3×3 reads past it.
    let ok = Gemm { m: 2, n: 2, k: 3, a: m(a, 3), b: m(a, 2), c: m(c, 2), batch: 1, parts: None };
    gpu.gemm(&ok).unwrap();
    let err = gpu.gemm(&Gemm { n: 3, b: m(a, 3), ..ok }).unwrap_err().to_string();
    assert!(err.contains("gemm B") && err.contains("outside every allocation"), "{err}");
    assert!(gpu.launch("pgser_nonexistent", 1, &[]).unwrap_err().to_string().contains("no kernel named"));
}

#[test]
fn every_kernel_compiles_for_sm_90_with_no_register_spills() {
    // NVRTC from the nvidia-cuda-nvrtc wheel that `make test` unpacks into .deps/nvrtc. `make test`
    // sets PGSER_REQUIRE_NVRTC, so there a missing NVRTC fails; a bare `cargo test` says it skipped.
    if !nvrtc::available() {
        assert!(
            std::env::var_os("PGSER_REQUIRE_NVRTC").is_none(),
            "PGSER_REQUIRE_NVRTC is set but NVRTC does not load: run `make nvrtc-deps`"
        );
        eprintln!("SKIPPED: NVRTC (libnvrtc.so.13) not found: `make nvrtc-deps` installs it");
        return;
    }
    let (major, minor) = nvrtc::version().unwrap();
    assert_eq!((major, minor), (13, 0), "NVRTC 13.0 is pinned: newer PTX does not load on driver 580");
    let cubin = nvrtc::compile("sm_90", true).unwrap();
    assert_eq!(&cubin.image[..4], b"\x7fELF", "a cubin is an ELF image");
    let report = nvrtc::ptxas_report(&cubin.log);
    for (k, regs, ..) in &report {
        eprintln!("{k}: {regs} registers");
    }
    for k in nvrtc::KERNELS {
        let (_, regs, stores, loads) = report
            .iter()
            .find(|r| r.0 == *k)
            .unwrap_or_else(|| panic!("{k} missing from ptxas' report:\n{}", cubin.log));
        assert_eq!((*stores, *loads), (0, 0), "{k} spills ({regs} registers)");
        assert!(*regs <= 64, "{k} uses {regs} registers: more than a full-occupancy block allows");
    }
    let ptx = String::from_utf8(nvrtc::compile("compute_90", false).unwrap().image).unwrap();
    assert!(ptx.contains(".version 9.0"), "PTX 9.0 (CUDA 13.0): {}", &ptx[..ptx.len().min(400)]);
    for k in nvrtc::KERNELS {
        assert!(ptx.contains(&format!(".entry {k}(")), "{k} is not an entry of the PTX");
    }
}

#[test]
fn a_broken_kernel_gives_the_compilers_log() {
    if !nvrtc::available() {
        eprintln!("SKIPPED: NVRTC not found");
        return;
    }
    let err =
        nvrtc::compile_source("extern \"C\" __global__ void k(float* x) { x[0] = undefined_name; }", "sm_90", false)
            .unwrap_err()
            .to_string();
    assert!(err.contains("undefined_name") && err.contains("sm_90"), "{err}");
}

#[test]
fn the_kernel_lists_agree() {
    // Three lists name the kernels: kernels.cu's definitions, shim.cpp's launch table and
    // `nvrtc::KERNELS` (what the GPU side loads). They must be one set.
    let defined: Vec<&str> =
        nvrtc::SOURCE.split("__global__ void ").skip(1).map(|s| s.split('(').next().unwrap().trim()).collect();
    let shim = include_str!("shim.cpp");
    let table: Vec<&str> = shim.split("PGSER_KERNEL(").skip(2).map(|s| s.split(')').next().unwrap()).collect();
    let mut listed = nvrtc::KERNELS.to_vec();
    for v in [&defined, &table] {
        let mut v = v.clone();
        v.sort_unstable();
        listed.sort_unstable();
        assert_eq!(v, listed);
    }
}

#[test]
fn the_engine_names_each_cuda_library_it_mapped_once() {
    let maps = "\
7f0000000000-7f0000001000 r--p 00000000 08:01 1 /usr/local/cuda-12/lib64/libcublas.so.12.4.5.8
7f0000001000-7f0000002000 r-xp 00001000 08:01 1 /usr/local/cuda-12/lib64/libcublas.so.12.4.5.8
7f0000002000-7f0000003000 r--p 00000000 08:01 2 /venv/nvidia/cu13/lib/libcublasLt.so.13
7f0000003000-7f0000004000 r--p 00000000 08:01 3 /usr/lib/x86_64-linux-gnu/libcudart.so.12
7f0000004000-7f0000005000 r--p 00000000 08:01 4 /usr/lib/x86_64-linux-gnu/libcuda.so.580.65.06
7f0000005000-7f0000006000 rw-p 00000000 00:00 0
7f0000006000-7f0000007000 r--p 00000000 08:01 5 /venv/nvidia/cu13/lib/libnvrtc.so.13
";
    assert_eq!(
        nvrtc::cuda_libraries_in(maps),
        [
            "/usr/local/cuda-12/lib64/libcublas.so.12.4.5.8",
            "/venv/nvidia/cu13/lib/libcublasLt.so.13",
            "/usr/lib/x86_64-linux-gnu/libcuda.so.580.65.06",
            "/venv/nvidia/cu13/lib/libnvrtc.so.13",
        ]
    );
}
