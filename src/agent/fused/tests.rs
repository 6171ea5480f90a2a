//! The hand-written engine against burn's (the reference) and against finite differences.

use burn::tensor::Device;

use super::*;
use crate::agent::testdata::{batch, norms};
use crate::agent::{Agent, Backend, Mlp, Shards};
use crate::task::Task;

/// Every parameter tensor of a stack: networks, targets, Adam moments (each `Mlp::tensors`).
fn state(a: &Agent) -> Vec<(String, Vec<f32>)> {
    let mut out = Vec::new();
    let mut push = |name: &str, net: &Mlp| {
        for (j, (_, v)) in net.tensors().into_iter().enumerate() {
            out.push((format!("{name}[{j}]"), v));
        }
    };
    push("actor", &a.actor);
    push("critics", &a.critics);
    push("actor_target", &a.actor_target);
    push("critics_target", &a.critics_target);
    let (a_m, a_v) = (0..a.agents()).map(|i| a.actor_opt.member(i)).unzip::<_, _, Vec<_>, Vec<_>>();
    let k = a.config.algo.critics();
    let (c_m, c_v) = (0..a.agents() * k).map(|i| a.critics_opt.member(i)).unzip::<_, _, Vec<_>, Vec<_>>();
    for (name, members) in
        [("adam.actor.m", a_m), ("adam.actor.v", a_v), ("adam.critics.m", c_m), ("adam.critics.v", c_v)]
    {
        out.push((name.to_string(), members.iter().flat_map(flatten).collect()));
    }
    out
}

#[test]
fn the_fused_engine_trains_a_stack_as_burn_does() {
    // A stack of two agents trained on both engines: every weight, target and Adam moment agrees
    // within 1e-5 of its tensor's scale. Batches of 520 rows are cut into two parts of 260,
    // priorities are on, DDPG has its action penalty.
    //
    // How long two engines can agree is bounded by the networks, not the code: the engines round
    // differently (by ~1e-7), and once a ReLU's input on one row lies within that of zero, the
    // two take different sides of the kink and part ways by a row's share of a gradient, which
    // Adam then carries. burn against itself with one weight nudged by one ulp parts the same
    // way (measured: at lr 1e-3, TD3 by 5e-4 within 200 updates). Where the kinks fall depends
    // on the CPU as well, since burn's matrix products round by the vector units they find: at
    // lr 3e-4 TD3+BC stays within 2.4e-6 for 200 updates on both machines measured; DDPG, whose
    // actor moves every update, meets a kink at update 59 on a 2-core AMD EPYC without AVX-512
    // (the losses still agree to 1e-7 there), and TD3 between updates 61 and 70 on a Zen 4 with
    // AVX-512 (3.3e-7 before, 1.6e-5 after; it had stayed within 2.4e-6 for 200 on the first),
    // so both are held to 50.
    let task = Task::known("FetchPush").unwrap();
    for (algo, updates) in [(Algo::Td3bc, 200), (Algo::Td3, 50), (Algo::Ddpg, 50)] {
        let cfg = AgentConfig { algo, hidden: 64, layers: 2, lr: Some(3e-4), ..AgentConfig::default() };
        let n = 520;
        assert_eq!(parts(n), 2);
        let new = || Agent::stack_new(cfg.clone(), task.clone(), norms(&task, 2), &[3, 8], Device::flex());
        let (mut burn, mut fused) = (new(), new());
        fused.fuse();
        let mut worst_loss = 0.0f64;
        for u in 0..updates {
            let b: Vec<Batch> = (0..2).map(|i| batch(&task, n, 1000 * u + i, i == 0)).collect();
            let (x, y) = (burn.update(&b).read(), fused.update(&b).read());
            for ((c1, q1, a1), (c2, q2, a2)) in x.iter().zip(&y) {
                assert_eq!(a1.is_some(), a2.is_some(), "{algo:?} update {u}: the actor moved in one engine only");
                worst_loss =
                    worst_loss.max((c1 - c2).abs() / c1.abs().max(1e-3)).max((q1 - q2).abs() / q1.abs().max(1.0));
                if let (Some(a1), Some(a2)) = (a1, a2) {
                    worst_loss = worst_loss.max((a1 - a2).abs() / a1.abs().max(1.0));
                }
            }
        }
        assert!(worst_loss < 1e-4, "{algo:?}: logged losses differ by {worst_loss:e}");
        fused.sync();
        assert!(!fused.is_stale());
        assert_eq!(burn.noise_rngs, fused.noise_rngs, "{algo:?}: noise streams");
        assert_eq!((burn.actor_opt.step, burn.critics_opt.step), (fused.actor_opt.step, fused.critics_opt.step));
        for ((name, x), (_, y)) in state(&burn).iter().zip(state(&fused)) {
            let scale = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let diff = x.iter().zip(&y).fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(diff <= 1e-5 * scale, "{algo:?} {name}: differs by {diff:e} at scale {scale:e}");
        }
    }
}

#[test]
fn the_fused_engine_is_the_same_bits_on_one_thread_or_two_and_alone_or_stacked() {
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { algo: Algo::Td3bc, hidden: 32, layers: 2, ..AgentConfig::default() };
    let seeds = [4u64, 9, 30];
    let n = 600; // three parts... two: 600 / 256
    let batches: Vec<Vec<Batch>> =
        (0..6).map(|u| seeds.iter().map(|&s| batch(&task, n, 7 * s + u, s == 9)).collect()).collect();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let alone: Vec<Agent> = seeds
                .iter()
                .map(|&s| Agent::new(cfg.clone(), task.clone(), Normalizer::identity(&task, 5.0), s, Device::flex()))
                .collect();
            let mut grid = Shards::new(alone, Backend::Cpu).unwrap();
            let stats: Vec<_> = batches.iter().map(|b| grid.update(b).read()).collect();
            grid.sync();
            (grid, stats)
        })
    };
    let (one, s1) = run(1);
    let (two, s2) = run(2);
    assert_eq!(s1, s2, "losses on 1 and 2 threads");
    assert_eq!(one.parts().len(), 1, "one stack on the fused engine");
    for i in 0..seeds.len() {
        let ((p1, j1), (p2, _)) = (one.locate(i), two.locate(i));
        assert_eq!(state(p1), state(p2), "agent {i}: 1 vs 2 threads");
        let mut alone =
            Agent::new(cfg.clone(), task.clone(), Normalizer::identity(&task, 5.0), seeds[i], Device::flex());
        alone.fuse();
        for b in &batches {
            alone.update(std::slice::from_ref(&b[i]));
        }
        alone.sync();
        assert_eq!(alone.actor.member(0), p1.actor.member(j1), "agent {i}: alone vs stacked");
        assert_eq!(alone.critics_target.member(1), p1.critics_target.member(2 * j1 + 1));
        assert_eq!(alone.critics_opt.member(0), p1.critics_opt.member(2 * j1));
    }
}

#[test]
fn a_fused_stack_acts_and_scores_as_its_synced_networks() {
    let task = Task::known("FetchPush").unwrap();
    let cfg = AgentConfig { algo: Algo::Td3, hidden: 32, layers: 2, ..AgentConfig::default() };
    let mut a = Agent::stack_new(cfg, task.clone(), norms(&task, 2), &[1, 2], Device::flex());
    a.fuse();
    for u in 0..5 {
        a.update(&[batch(&task, 64, u, false), batch(&task, 64, 50 + u, false)]);
    }
    assert!(a.is_stale());
    let b = batch(&task, 10, 99, false);
    let rows = [(&b.obs[..], &b.goal[..]); 2];
    let (acts, q) = (a.act_all(&rows, 10), a.q(&b.obs, &b.goal, &b.action, 10));
    a.sync();
    let mut burn = Agent::stack(vec![a]); // a copy on burn's engine
    assert!(!burn.is_stale());
    let close = |x: &[f32], y: &[f32]| x.iter().zip(y).all(|(a, b)| (a - b).abs() <= 1e-5 * b.abs().max(1.0));
    for (mine, theirs) in acts.iter().zip(burn.act_all(&rows, 10)) {
        assert!(close(mine, &theirs), "{mine:?} vs {theirs:?}");
    }
    assert!(close(&q, &burn.q(&b.obs, &b.goal, &b.action, 10)));
    burn.update(&[batch(&task, 64, 7, false), batch(&task, 64, 8, false)]);
}

#[test]
#[should_panic(expected = "Agent::sync missed")]
fn a_checkpoint_from_a_stale_stack_is_refused() {
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { hidden: 8, layers: 1, ..AgentConfig::default() };
    let mut a = Agent::new(cfg, task.clone(), Normalizer::identity(&task, 5.0), 0, Device::flex());
    a.fuse();
    a.update(&[batch(&task, 8, 0, false)]);
    let dir = tempfile::tempdir().unwrap();
    let _ = crate::agent::checkpoint::save(&a, 0, &dir.path().join("a.ckpt"), &Default::default());
}

// ---- Gradients against finite differences, one loss term at a time ----

/// A lone agent on the fused engine with tiny networks, and one part's scratch for `b`.
fn tiny(algo: Algo, alpha: f64, l2: Option<f64>, b: &Batch) -> (AgentConfig, Fused, Normalizer) {
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { algo, alpha, action_l2: l2, hidden: 6, layers: 2, ..AgentConfig::default() };
    let mut a = Agent::new(cfg.clone(), task.clone(), norms(&task, 1).remove(0), 11, Device::flex());
    // Targets apart from the networks, so the TD target is not the critic's own value.
    a.update(std::slice::from_ref(b));
    a.update(std::slice::from_ref(b));
    let (actor_sizes, critic_sizes) = crate::agent::net_sizes(&cfg, &task);
    let s = a.burn_state();
    let mut f = Fused::new(&actor_sizes, &critic_sizes, s.nets, s.actor_step, s.critic_step);
    f.size_work(b.n, cfg.algo.critics());
    assert_eq!(f.work.len(), 1, "one part");
    (cfg, f, a.norms[0].clone())
}

/// The critic loss Σ_k (1/n) Σ w(Q_k − y)² and its gradient for critic k.
fn critic_loss(cfg: &AgentConfig, f: &mut Fused, norm: &Normalizer, b: &Batch, k: usize) -> (f64, Vec<f32>) {
    let noise = vec![0.1; b.n * f.actor.sizes.last().unwrap()];
    let (actor, critic) = (f.actor.clone(), f.critic.clone());
    let w = &mut f.work[0];
    critic_part(cfg, &actor, &critic, &f.nets[0], b, norm, &noise, w, b.n);
    (w.sums.critic / b.n as f64, w.critic_grad[k].clone())
}

/// The actor loss with λ fixed at `lambda` (None: TD3+BC's own, from this forward pass) and its
/// gradient.
fn actor_loss(
    cfg: &AgentConfig,
    f: &mut Fused,
    norm: &Normalizer,
    b: &Batch,
    lambda: Option<f32>,
) -> (f64, Vec<f32>, f32) {
    let (actor, critic) = (f.actor.clone(), f.critic.clone());
    let act = *actor.sizes.last().unwrap();
    let (n, nets) = (b.n, &f.nets[0]);
    let w = &mut f.work[0];
    normalize_into(norm, &b.obs, &b.goal, &mut w.sa, critic.sizes[0], 0..n);
    for r in 0..n {
        let width = critic.sizes[0];
        w.sa[r * width + width - act..(r + 1) * width].copy_from_slice(&b.action[r * act..(r + 1) * act]);
    }
    actor_forward(&actor, &critic, nets, w, n, act);
    let own = if cfg.algo == Algo::Td3bc { cfg.alpha as f32 / (w.sums.pi_q_abs / n as f32) } else { 1.0 };
    let lambda = lambda.unwrap_or(own);
    actor_backward(&actor, nets, b, w, lambda, cfg.algo == Algo::Td3bc, cfg.action_l2() as f32, n, act);
    let cells = (n * act) as f64;
    let bc = if cfg.algo == Algo::Td3bc { w.sums.bc / cells } else { 0.0 };
    let loss = -(lambda as f64) * w.sums.pi_q / n as f64 + bc + cfg.action_l2() * w.sums.l2 / cells;
    (loss, w.actor_grad.clone(), lambda)
}

#[allow(clippy::needless_range_loop)] // `e` indexes the parameters through `params(f)` as well
/// Central differences of `loss` over every parameter of `params(f)`, against `grad`.
fn check(
    name: &str,
    f: &mut Fused,
    grad: &[f32],
    params: fn(&mut Fused) -> &mut Vec<f32>,
    loss: &dyn Fn(&mut Fused) -> f64,
) {
    let scale = grad.iter().fold(0.0f32, |m, g| m.max(g.abs())) as f64;
    assert!(scale > 0.0, "{name}: the gradient is zero");
    let mut worst = 0.0f64;
    let mut at = (0, 0.0, 0.0);
    let mut kinks = 0;
    for e in 0..grad.len() {
        let x = params(f)[e];
        let mut central = |h: f32| {
            params(f)[e] = x + h;
            let up = loss(f);
            params(f)[e] = x - h;
            let down = loss(f);
            params(f)[e] = x;
            (up - down) / (2.0 * h as f64)
        };
        let h = 1e-2f32 * x.abs().max(0.1);
        let (fd, fd_half) = (central(h), central(h / 2.0));
        // A ReLU that switches inside ±h makes the loss kinked there: no difference quotient
        // approximates the derivative, and two step sizes disagree. Such parameters are skipped.
        if (fd - fd_half).abs() > 1e-3 * scale {
            kinks += 1;
            continue;
        }
        let err = (fd - grad[e] as f64).abs() / scale;
        if err > worst {
            (worst, at) = (err, (e, fd, grad[e] as f64));
        }
    }
    assert!(kinks * 10 < grad.len(), "{name}: {kinks} of {} parameters sit at a kink", grad.len());
    assert!(
        worst < 5e-3,
        "{name}: the gradient differs from finite differences by {worst:e} of its largest entry {scale:e} (parameter {}: {} vs {})",
        at.0,
        at.1,
        at.2
    );
}

#[test]
fn the_critic_gradient_is_the_weighted_td_loss_s() {
    let b = batch(&Task::known("FetchReach").unwrap(), 64, 5, true);
    let (cfg, mut f, norm) = tiny(Algo::Td3, 2.5, None, &b);
    for k in 0..2 {
        let (_, grad) = critic_loss(&cfg, &mut f, &norm, &b, k);
        let params: fn(&mut Fused) -> &mut Vec<f32> =
            if k == 0 { |f| &mut f.nets[0].critics[0].p } else { |f| &mut f.nets[0].critics[1].p };
        check(&format!("critic {k}"), &mut f, &grad, params, &|f| critic_loss(&cfg, f, &norm, &b, k).0);
    }
}

fn actor_params(f: &mut Fused) -> &mut Vec<f32> {
    &mut f.nets[0].actor.p
}

#[test]
fn the_actor_gradient_of_the_q_term_is_td3_s() {
    let b = batch(&Task::known("FetchReach").unwrap(), 64, 6, false);
    let (cfg, mut f, norm) = tiny(Algo::Td3, 2.5, None, &b);
    let (_, grad, _) = actor_loss(&cfg, &mut f, &norm, &b, None);
    check("−mean Q₁", &mut f, &grad, actor_params, &|f| actor_loss(&cfg, f, &norm, &b, None).0);
}

#[test]
fn the_actor_gradient_of_the_bc_term_is_mse_s() {
    // α = 0: λ = 0, the behaviour-cloning term alone.
    let b = batch(&Task::known("FetchReach").unwrap(), 64, 7, false);
    let (cfg, mut f, norm) = tiny(Algo::Td3bc, 0.0, None, &b);
    let (_, grad, lambda) = actor_loss(&cfg, &mut f, &norm, &b, None);
    assert_eq!(lambda, 0.0);
    check("MSE(π, a)", &mut f, &grad, actor_params, &|f| actor_loss(&cfg, f, &norm, &b, None).0);
}

#[test]
fn the_actor_gradient_of_td3bc_holds_lambda_constant() {
    // λ = α / mean|Q₁| is a constant of the gradient: the finite difference holds it fixed.
    let b = batch(&Task::known("FetchReach").unwrap(), 64, 8, false);
    let (cfg, mut f, norm) = tiny(Algo::Td3bc, 2.5, None, &b);
    let (_, grad, lambda) = actor_loss(&cfg, &mut f, &norm, &b, None);
    assert!(lambda > 0.0 && lambda.is_finite());
    check("−λ mean Q₁ + MSE", &mut f, &grad, actor_params, &|f| actor_loss(&cfg, f, &norm, &b, Some(lambda)).0);
}

#[test]
fn the_actor_gradient_of_the_action_penalty_is_l2_s() {
    // DDPG's actor loss: −mean Q₁ + l2 · mean π², with a large l2 so the penalty dominates.
    let b = batch(&Task::known("FetchReach").unwrap(), 64, 9, false);
    let (cfg, mut f, norm) = tiny(Algo::Ddpg, 2.5, Some(50.0), &b);
    let (_, grad, _) = actor_loss(&cfg, &mut f, &norm, &b, None);
    check("−mean Q₁ + l2 · mean π²", &mut f, &grad, actor_params, &|f| actor_loss(&cfg, f, &norm, &b, None).0);
}
