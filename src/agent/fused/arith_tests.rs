//! Portable arithmetic (`product.rs`): its paths give the same bits, each forced on one machine;
//! it computes the product; a run trained in it scores and acts in it after a checkpoint.

use burn::tensor::Device;

use super::product::{Path, Product, portable};
use super::*;
use crate::agent::testdata::{batch, norms};
use crate::agent::{Agent, Arithmetic, Backend, Shards, checkpoint};
use crate::task::Task;

/// The vector paths this CPU runs (with a note for those it does not: their bits are checked
/// on machines that have them).
fn vector_paths() -> Vec<Path> {
    let (have, lack): (Vec<Path>, Vec<Path>) = [Path::Avx2, Path::Avx512].into_iter().partition(|p| p.available());
    if !lack.is_empty() {
        eprintln!("this CPU lacks {lack:?}: those paths are not checked here");
    }
    have
}

fn values(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = NpRandom::new(seed);
    (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32).collect()
}

#[test]
fn portable_products_are_one_fma_chain_on_every_path() {
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let mut seed = 0;
    // Edges of the 6 × 16 blocks and of the 8-lane masks, the engine's own shapes (a 256-row part,
    // Q's one column, an action's four), and every layout the engine passes: A plain or read
    // transposed, B dense or strided (a transpose, which is packed).
    for (m, n, k) in [
        (1, 1, 1),
        (5, 7, 3),
        (6, 8, 9),
        (7, 9, 17),
        (13, 16, 32),
        (12, 17, 5),
        (256, 1, 256),
        (256, 4, 64),
        (40, 33, 256),
        (3, 40, 0),
    ] {
        for (a_t, b_t) in [(false, false), (true, false), (false, true), (true, true)] {
            seed += 1;
            let (av, bv) = (values(m * k, seed), values(k * n, 1000 + seed));
            let a = if a_t { (&av[..], 1, m) } else { (&av[..], k, 1) };
            let b = if b_t { (&bv[..], 1, k) } else { (&bv[..], n, 1) };
            let at = |i: usize, p: usize| a.0[i * a.1 + p * a.2];
            let bt = |p: usize, j: usize| b.0[p * b.1 + j * b.2];
            let mut scalar = vec![f32::NAN; m * n];
            portable(m, n, k, &mut scalar, a, b, Path::Scalar);
            // The definition, written out: one FMA chain from 0 in increasing p.
            let mut chain = vec![0.0f32; m * n];
            let mut worst = 0.0f64;
            for i in 0..m {
                for j in 0..n {
                    let (mut acc, mut exact, mut size) = (0.0f32, 0.0f64, 0.0f64);
                    for p in 0..k {
                        acc = at(i, p).mul_add(bt(p, j), acc);
                        exact += at(i, p) as f64 * bt(p, j) as f64;
                        size += (at(i, p) as f64 * bt(p, j) as f64).abs();
                    }
                    chain[i * n + j] = acc;
                    // A chain of k roundings is within k·2⁻²⁴ of Σ|a·b| of the exact sum.
                    worst =
                        worst.max((acc as f64 - exact).abs() / (k.max(1) as f64 * 2f64.powi(-24) * size).max(1e-30));
                }
            }
            let at_ = format!("{m}×{k}·{k}×{n} (A transposed {a_t}, B transposed {b_t})");
            assert_eq!(bits(&scalar), bits(&chain), "{at_}: the scalar path is not the chain");
            assert!(worst <= 1.0, "{at_}: {worst} of the rounding bound from the f64 product");
            for path in vector_paths() {
                let mut fast = vec![f32::NAN; m * n];
                portable(m, n, k, &mut fast, a, b, path);
                assert_eq!(bits(&fast), bits(&scalar), "{at_}: the {path:?} path and the scalar path differ");
            }
        }
    }
}

#[test]
fn portable_training_is_the_same_bits_on_every_path_and_close_to_burn() {
    // Whole updates of a stack of two, on each path from the same state: every weight, target,
    // Adam moment, logged loss, action and Q to the bit. 520-row batches are cut into two parts;
    // the first agent's rows carry priority weights. And the portable run stays within 1e-5 of
    // burn's, as the native one does (`tests.rs`).
    let task = Task::known("FetchPush").unwrap();
    let paths: Vec<Path> = std::iter::once(Path::Scalar).chain(vector_paths()).collect();
    for (algo, updates) in [(Algo::Td3bc, 30), (Algo::Ddpg, 20)] {
        let cfg = AgentConfig {
            algo,
            hidden: 24,
            layers: 2,
            lr: Some(3e-4),
            arithmetic: Arithmetic::Portable,
            ..AgentConfig::default()
        };
        let (actor_sizes, critic_sizes) = crate::agent::net_sizes(&cfg, &task);
        let mut burn = Agent::stack_new(cfg.clone(), task.clone(), norms(&task, 2), &[5, 6], Device::flex());
        let s = burn.burn_state();
        let mut runs: Vec<(Fused, Vec<NpRandom>)> = paths
            .iter()
            .map(|&path| {
                let f = Fused::with_product(
                    &actor_sizes,
                    &critic_sizes,
                    s.nets.clone(),
                    s.actor_step,
                    s.critic_step,
                    Product::Portable(path),
                );
                (f, burn.noise_rngs.clone())
            })
            .collect();
        let bits =
            |s: &Stats| s.iter().map(|(c, q, a)| (c.to_bits(), q.to_bits(), a.map(f32::to_bits))).collect::<Vec<_>>();
        for u in 1..=updates {
            let b: Vec<Batch> = (0..2).map(|i| batch(&task, 520, 100 * u + i, i == 0)).collect();
            let stats: Vec<_> =
                runs.iter_mut().map(|(f, rngs)| bits(&f.update(&cfg, &b, &burn.norms, rngs, u))).collect();
            for (path, st) in paths.iter().zip(&stats) {
                assert_eq!(
                    st, &stats[0],
                    "{algo:?} update {u}: the losses of the {path:?} path differ from the scalar's"
                );
            }
            burn.update(&b);
        }
        let flat = |f: &Fused| {
            f.nets
                .iter()
                .flat_map(|n| std::iter::once(&n.actor).chain(&n.critics))
                .flat_map(|n| [&n.p, &n.m, &n.v, &n.target])
                .flat_map(|v| v.iter().map(|x| x.to_bits()))
                .collect::<Vec<_>>()
        };
        let b = batch(&task, 50, 7, false);
        let rows = [(&b.obs[..], &b.goal[..]); 2];
        let scalar = &runs[0].0;
        for (path, (f, _)) in paths.iter().zip(&runs) {
            assert_eq!(flat(f), flat(scalar), "{algo:?}: the {path:?} path's training state differs from the scalar's");
            assert_eq!(f.act_all(&burn.norms, &rows, 50), scalar.act_all(&burn.norms, &rows, 50), "{path:?}");
            let q = |f: &Fused| f.q(&burn.norms[0], &b.obs, &b.goal, &b.action, 50);
            assert_eq!(q(f), q(scalar), "{algo:?}: the {path:?} path's Q");
        }
        let reference = burn.burn_state();
        for (mine, theirs) in scalar.nets.iter().zip(&reference.nets) {
            for (x, y) in std::iter::once((&mine.actor, &theirs.actor)).chain(mine.critics.iter().zip(&theirs.critics))
            {
                let scale = y.p.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                let diff = x.p.iter().zip(&y.p).fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
                assert!(diff <= 1e-5 * scale, "{algo:?}: portable is {diff:e} from burn at scale {scale:e}");
            }
        }
    }
}

#[test]
fn a_portable_checkpoint_acts_and_scores_in_its_own_arithmetic() {
    // Scoring and evaluation load a checkpoint without an engine; a portable run's Q and policy
    // must then come from the portable products, the very bits the engine gave, not burn's.
    let task = Task::known("FetchPush").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cfg = AgentConfig { hidden: 32, layers: 2, arithmetic: Arithmetic::Portable, ..AgentConfig::default() };
    let mut agent = Agent::new(cfg.clone(), task.clone(), norms(&task, 1).remove(0), 3, Device::flex());
    agent.fuse();
    for u in 0..4 {
        agent.update(&[batch(&task, 64, u, false)]);
    }
    let b = batch(&task, 300, 77, false);
    let (q, pi) = (agent.q(&b.obs, &b.goal, &b.action, 300), agent.act(&b.obs, &b.goal, 300));
    agent.sync();
    let path = dir.path().join("p.ckpt");
    checkpoint::save(&agent, 0, &path, &Default::default()).unwrap();
    let (back, meta) = checkpoint::load(&path, Device::flex()).unwrap();
    assert_eq!(back.config.arithmetic, Arithmetic::Portable);
    assert!(meta["config"].contains("\"arithmetic\":\"portable\""), "{}", meta["config"]);
    assert_eq!(back.q(&b.obs, &b.goal, &b.action, 300), q);
    assert_eq!(back.act(&b.obs, &b.goal, 300), pi);

    // A native run's metadata names no arithmetic: its checkpoints keep the bytes they had.
    let native = Agent::new(
        AgentConfig { arithmetic: Arithmetic::Native, ..cfg },
        task.clone(),
        norms(&task, 1).remove(0),
        3,
        Device::flex(),
    );
    let path = dir.path().join("n.ckpt");
    checkpoint::save(&native, 0, &path, &Default::default()).unwrap();
    let (_, meta) = checkpoint::load(&path, Device::flex()).unwrap();
    assert!(!meta["config"].contains("arithmetic"), "{}", meta["config"]);
}

#[test]
fn portable_arithmetic_is_refused_where_burn_does_the_products() {
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { hidden: 8, layers: 1, arithmetic: Arithmetic::Portable, ..AgentConfig::default() };
    let agent = || Agent::new(cfg.clone(), task.clone(), norms(&task, 1).remove(0), 0, Device::flex());
    let e = Shards::new(vec![agent()], Backend::CpuBurn).err().expect("refused");
    assert!(format!("{e:#}").contains("--arithmetic portable with --device cpu-burn"), "{e:#}");
    assert!(Shards::new(vec![agent()], Backend::Cpu).is_ok());
}
