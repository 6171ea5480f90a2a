//! Unit tests of the pieces of the agent that are easy to get subtly wrong.

use burn::tensor::{Device, Tensor, TensorData};

use super::*;
use crate::task::Task;

fn device() -> Device {
    Device::flex()
}

fn small_config(algo: Algo) -> AgentConfig {
    AgentConfig { algo, hidden: 16, layers: 2, ..AgentConfig::default() }
}

fn unit_norm(task: &Task) -> Normalizer {
    Normalizer::identity(task, 5.0)
}

fn random_batch(task: &Task, n: usize, seed: u64) -> Batch {
    let mut rng = NpRandom::new(seed);
    let mut u = |k: usize| (0..k).map(|_| rng.uniform(-1.0, 1.0) as f32).collect::<Vec<_>>();
    Batch {
        n,
        obs: u(n * task.obs_dim),
        goal: u(n * task.goal_dim),
        action: u(n * task.act_dim),
        reward: u(n).into_iter().map(|x| if x < 0.0 { -1.0 } else { 0.0 }).collect(),
        next_obs: u(n * task.obs_dim),
        weight: vec![],
    }
}

fn values(net: &Mlp) -> Vec<Vec<f32>> {
    net.tensors().into_iter().map(|(_, v)| v).collect()
}

#[test]
fn soft_update_is_polyak_averaging() {
    let mut rng = NpRandom::new(1);
    let mut target = Mlp::from_members(&[init_member(&[3, 4, 2], &mut rng)], &device());
    let online = Mlp::from_members(&[init_member(&[3, 4, 2], &mut rng)], &device());
    let (t0, o) = (values(&target), values(&online));
    target.soft_update(&online, 0.25);
    for ((t1, t0), o) in values(&target).iter().zip(&t0).zip(&o) {
        for ((a, b), c) in t1.iter().zip(t0).zip(o) {
            let want = 0.75 * b + 0.25 * c;
            assert!((a - want).abs() <= 1e-6 * want.abs().max(1.0), "{a} vs {want}");
        }
    }
    // τ = 1 copies, τ = 0 keeps.
    target.soft_update(&online, 1.0);
    assert_eq!(values(&target), o);
}

#[test]
fn td_target_is_clipped_to_the_return_range() {
    let c = AgentConfig::default(); // γ = 0.98: returns lie in [−50, 0]
    let t = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [4, 1]), &device());
    let y = td_target(&c, t(vec![0.0, -1.0, -1.0, 0.0]), t(vec![10.0, -100.0, -10.0, -0.5]));
    let got = host(y).1;
    let want = [0.0, -50.0, -1.0 - 0.98 * 10.0, -0.98 * 0.5];
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-5, "{got:?} vs {want:?}");
    }
}

#[test]
fn normalizer_standardizes_and_clips() {
    let obs = [1.0f32, 10.0, 3.0, 10.0]; // two rows of obs_dim 2: dim 1 is constant
    let goals = [0.0f32, 2.0];
    let n = Normalizer::fit(&[&obs], 2, &[&goals], 1, 5.0);
    assert_eq!(n.obs_mean, vec![2.0, 10.0]);
    assert_eq!(n.obs_std, vec![1.0, 0.01]); // the constant dimension gets the floor
    assert_eq!((n.goal_mean[0], n.goal_std[0]), (1.0, 1.0));
    let mut x = Vec::new();
    n.input(&[3.0, 10.5], &[100.0], 1, &mut x);
    assert_eq!(x, vec![1.0, 5.0, 5.0]); // (10.5 − 10)/0.01 = 50 and 99 are clipped to 5
}

#[test]
fn checkpoint_round_trip_keeps_policy_q_and_normalizer() {
    let task = Task::known("FetchReach").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.ckpt");
    let mut norm = unit_norm(&task);
    norm.obs_mean[3] = 0.5;
    norm.goal_std[1] = 2.0;
    let mut agent = Agent::new(small_config(Algo::Td3bc), task.clone(), norm, 7, device());
    for i in 0..3 {
        agent.update(&[random_batch(&task, 32, i)]);
    }
    checkpoint::save(&agent, 0, &path, &Default::default()).unwrap();
    let (back, meta) = checkpoint::load(&path, device()).unwrap();
    assert_eq!(back.norms, agent.norms);
    assert_eq!(back.config, agent.config);
    assert_eq!(back.task, agent.task);
    assert_eq!(back.updates, 3);
    assert_eq!(meta["format"], checkpoint::FORMAT);
    let b = random_batch(&task, 16, 99);
    assert_eq!(back.act(&b.obs, &b.goal, 16), agent.act(&b.obs, &b.goal, 16));
    assert_eq!(back.q(&b.obs, &b.goal, &b.action, 16), agent.q(&b.obs, &b.goal, &b.action, 16));
}

#[test]
fn resumed_updates_equal_uninterrupted_ones() {
    for algo in [Algo::Td3bc, Algo::Ddpg] {
        resumed_updates_equal_uninterrupted_ones_for(algo);
    }
}

fn resumed_updates_equal_uninterrupted_ones_for(algo: Algo) {
    let task = Task::known("FetchReach").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.ckpt");
    let batches: Vec<Batch> = (0..6).map(|i| random_batch(&task, 32, i)).collect();
    let mut straight = Agent::new(small_config(algo), task.clone(), unit_norm(&task), 3, device());
    for b in &batches {
        straight.update(std::slice::from_ref(b));
    }
    let mut first = Agent::new(small_config(algo), task.clone(), unit_norm(&task), 3, device());
    for b in &batches[..3] {
        first.update(std::slice::from_ref(b));
    }
    checkpoint::save(&first, 0, &path, &Default::default()).unwrap();
    checkpoint::save_resume(&first, 0, &checkpoint::resume_path(&path), &Default::default()).unwrap();
    drop(first);
    let (mut resumed, _) = checkpoint::load(&path, device()).unwrap();
    checkpoint::load_resume(&mut resumed, &checkpoint::resume_path(&path)).unwrap();
    for b in &batches[3..] {
        resumed.update(std::slice::from_ref(b));
    }
    for (a, b) in [
        (&straight.actor, &resumed.actor),
        (&straight.critics, &resumed.critics),
        (&straight.actor_target, &resumed.actor_target),
        (&straight.critics_target, &resumed.critics_target),
    ] {
        assert_eq!(values(a), values(b));
    }
}

#[test]
fn ddpg_has_one_critic_moves_its_actor_every_update_and_its_targets_on_schedule() {
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { policy_delay: 3, tau: 0.1, ..small_config(Algo::Ddpg) };
    let mut agent = Agent::new(cfg, task.clone(), unit_norm(&task), 2, device());
    assert_eq!(agent.critics.members(), 1);
    let start_target = values(&agent.actor_target);
    for i in 0..3 {
        let before = values(&agent.actor);
        let stats = agent.update(&[random_batch(&task, 32, i)]).read();
        assert!(stats[0].2.is_some(), "the actor moves every update");
        assert_ne!(values(&agent.actor), before);
        let moved = values(&agent.actor_target) != start_target;
        assert_eq!(moved, i == 2, "targets move on update 3 only (update {})", i + 1);
    }
    // The checkpoint holds the one critic (as critic1) and loads back to the same Q.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("d.ckpt");
    checkpoint::save(&agent, 0, &path, &Default::default()).unwrap();
    let header = String::from_utf8_lossy(&std::fs::read(&path).unwrap()[..4096]).to_string();
    assert!(header.contains("critic1.0.weight") && !header.contains("critic2"), "{header}");
    let (back, _) = checkpoint::load(&path, device()).unwrap();
    let b = random_batch(&task, 8, 50);
    assert_eq!(back.q(&b.obs, &b.goal, &b.action, 8), agent.q(&b.obs, &b.goal, &b.action, 8));
}

#[test]
fn ddpg_actor_loss_is_minus_q_plus_the_action_penalty() {
    // With a zero learning rate nothing moves, so the reported loss must be −mean Q(s, π(s)) +
    // action_l2 · mean π², recomputed here from the agent's own forward passes.
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { lr: Some(0.0), action_l2: Some(0.5), ..small_config(Algo::Ddpg) };
    let mut agent = Agent::new(cfg, task.clone(), unit_norm(&task), 4, device());
    let b = random_batch(&task, 16, 3);
    let pi = agent.act(&b.obs, &b.goal, 16);
    let q = agent.q(&b.obs, &b.goal, &pi, 16);
    let want = -q.iter().map(|&x| x as f64).sum::<f64>() / 16.0
        + 0.5 * pi.iter().map(|&x| (x as f64) * (x as f64)).sum::<f64>() / pi.len() as f64;
    let got = agent.update(std::slice::from_ref(&b)).read()[0].2.unwrap();
    assert!((got - want).abs() < 1e-5 * want.abs().max(1.0), "{got} vs {want}");
}

#[test]
fn a_resume_file_from_another_update_is_refused() {
    let task = Task::known("FetchReach").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.ckpt");
    let mut agent = Agent::new(small_config(Algo::Td3), task.clone(), unit_norm(&task), 0, device());
    checkpoint::save_resume(&agent, 0, &checkpoint::resume_path(&path), &Default::default()).unwrap();
    agent.update(&[random_batch(&task, 8, 0)]);
    checkpoint::save(&agent, 0, &path, &Default::default()).unwrap();
    let (mut back, _) = checkpoint::load(&path, device()).unwrap();
    let err = checkpoint::load_resume(&mut back, &checkpoint::resume_path(&path)).unwrap_err().to_string();
    assert!(err.contains("update 0") && err.contains("update 1"), "{err}");
}

#[test]
fn td3bc_actor_moves_toward_the_data_actions() {
    // With α = 0 the TD3+BC actor loss is pure behaviour cloning: it must fall.
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { alpha: 0.0, policy_delay: 1, lr: Some(1e-3), ..small_config(Algo::Td3bc) };
    let mut agent = Agent::new(cfg, task.clone(), unit_norm(&task), 0, device());
    let b = random_batch(&task, 64, 5);
    let first = agent.update(std::slice::from_ref(&b)).read()[0].2.unwrap();
    let mut last = first;
    for _ in 0..200 {
        last = agent.update(std::slice::from_ref(&b)).read()[0].2.unwrap();
    }
    assert!(last < 0.6 * first, "BC loss {first} -> {last}");
}

/// The first `k` rows of a batch (noise for them is the first draws of the stream either way).
fn head(b: &Batch, task: &Task, k: usize) -> Batch {
    Batch {
        n: k,
        obs: b.obs[..k * task.obs_dim].to_vec(),
        goal: b.goal[..k * task.goal_dim].to_vec(),
        action: b.action[..k * task.act_dim].to_vec(),
        reward: b.reward[..k].to_vec(),
        next_obs: b.next_obs[..k * task.obs_dim].to_vec(),
        weight: vec![],
    }
}

/// All online critic weights, flattened.
fn critic_params(a: &Agent) -> Vec<f32> {
    values(&a.critics).into_iter().flatten().collect()
}

#[test]
fn importance_weights_scale_the_critic_loss() {
    // Constant weights c: the weighted loss is exactly c times the unweighted one (a loss that
    // ignored the weights would report the same value, one that inverted them 1/c times it).
    let task = Task::known("FetchReach").unwrap();
    let b = random_batch(&task, 32, 11);
    let loss = |weight: Vec<f32>| {
        let mut agent = Agent::new(small_config(Algo::Td3bc), task.clone(), unit_norm(&task), 5, device());
        agent.update(&[Batch { weight, ..b.clone() }]).read()[0].0
    };
    let plain = loss(vec![]);
    let quarter = loss(vec![0.25; 32]);
    assert!(plain > 0.0);
    assert!((quarter - 0.25 * plain).abs() <= 1e-6 * plain, "weighted {quarter} vs 0.25 × {plain}");
}

#[test]
fn importance_weights_act_on_the_critic_gradient() {
    // Weight 0 on the second half of a batch: the critics' step must be the step of the first
    // half alone (same direction; Adam's first step does not depend on the gradient's scale), and
    // far from the step the whole batch would give if the weights were ignored.
    let task = Task::known("FetchReach").unwrap();
    let full = random_batch(&task, 32, 12);
    let step = |b: &Batch| {
        let mut agent = Agent::new(small_config(Algo::Td3bc), task.clone(), unit_norm(&task), 9, device());
        let before = critic_params(&agent);
        agent.update(std::slice::from_ref(b));
        critic_params(&agent).iter().zip(&before).map(|(a, b)| a - b).collect::<Vec<f32>>()
    };
    let mut weight = vec![1.0; 16];
    weight.extend(vec![0.0; 16]);
    let weighted = step(&Batch { weight, ..full.clone() });
    let half = step(&head(&full, &task, 16));
    let ignored = step(&full);
    let dist = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>().sqrt();
    let (to_half, to_ignored) = (dist(&weighted, &half), dist(&weighted, &ignored));
    assert!(weighted.iter().all(|x| x.is_finite()));
    assert!(
        to_half < 0.01 * to_ignored,
        "weighted step is {to_half} from the half batch's, {to_ignored} from the whole's"
    );
}

#[test]
fn checkpoint_files_are_the_same_bytes_every_time() {
    // The metadata has a dozen keys; written through a HashMap they came out in another order
    // on each write, so a rebuilt checkpoint never matched its record.
    let task = Task::known("FetchReach").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut agent = Agent::new(small_config(Algo::Td3bc), task.clone(), unit_norm(&task), 4, device());
    agent.update(&[random_batch(&task, 16, 0)]);
    let extra: std::collections::BTreeMap<String, String> =
        (0..8).map(|i| (format!("key{i}"), format!("value \"{i}\""))).collect();
    let write = |name: &str| {
        let p = dir.path().join(name);
        checkpoint::save(&agent, 0, &p, &extra).unwrap();
        checkpoint::save_resume(&agent, 0, &checkpoint::resume_path(&p), &extra).unwrap();
        (std::fs::read(&p).unwrap(), std::fs::read(checkpoint::resume_path(&p)).unwrap())
    };
    let first = write("a.ckpt");
    for name in ["b.ckpt", "c.ckpt", "d.ckpt"] {
        assert!(write(name) == first, "{name} differs from a.ckpt");
    }
    // Still a safetensors file any reader opens, with the metadata and tensors it had.
    let st = safetensors::SafeTensors::deserialize(&first.0).unwrap();
    assert_eq!(st.tensor("actor.0.weight").unwrap().shape(), [16, task.obs_dim + task.goal_dim]);
    let (_, meta) = safetensors::SafeTensors::read_metadata(&first.0).unwrap();
    assert_eq!(meta.metadata().as_ref().unwrap()["key3"], "value \"3\"");
}

#[test]
fn agents_in_a_stack_train_as_they_would_alone() {
    // Three agents (own seeds, normalizers and batches; prioritized weights on one) in one stack
    // for 6 updates (three actor steps) vs each trained alone: same draws, same weights.
    let task = Task::known("FetchReach").unwrap();
    let seeds = [3u64, 8, 21];
    let norms: Vec<Normalizer> = seeds
        .iter()
        .map(|&s| {
            let mut n = unit_norm(&task);
            n.obs_mean[1] = s as f32 * 0.01;
            n.goal_std[2] = 1.0 + s as f32 * 0.1;
            n
        })
        .collect();
    let batches: Vec<Vec<Batch>> = (0..6)
        .map(|u| {
            seeds
                .iter()
                .map(|&s| {
                    let mut b = random_batch(&task, 32, 100 * s + u);
                    if s == 8 {
                        b.weight = (0..32).map(|i| 0.25 + (i % 4) as f32 * 0.25).collect();
                    }
                    b
                })
                .collect()
        })
        .collect();
    let cfg = small_config(Algo::Td3bc);
    let mut stack = Agent::stack_new(cfg.clone(), task.clone(), norms.clone(), &seeds, device());
    let mut stack_losses = Vec::new();
    for b in &batches {
        stack_losses.push(stack.update(b).read());
    }
    let mut worst = 0.0f32;
    for (i, &seed) in seeds.iter().enumerate() {
        let mut alone = Agent::new(cfg.clone(), task.clone(), norms[i].clone(), seed, device());
        for (u, b) in batches.iter().enumerate() {
            let (c, q, a) = alone.update(std::slice::from_ref(&b[i])).read()[0];
            let (sc, sq, sa) = stack_losses[u][i];
            assert!((c - sc).abs() <= 1e-5 * c.abs().max(1.0) && (q - sq).abs() <= 1e-5 * q.abs().max(1.0));
            assert_eq!(a.is_some(), sa.is_some());
        }
        assert_eq!(alone.noise_rngs[0].words(), stack.noise_rngs[i].words(), "agent {i}: noise streams");
        for (mine, theirs) in [
            (alone.actor.member(0), stack.actor.member(i)),
            (alone.critics.member(0), stack.critics.member(2 * i)),
            (alone.critics.member(1), stack.critics.member(2 * i + 1)),
            (alone.actor_target.member(0), stack.actor_target.member(i)),
            (alone.critics_target.member(1), stack.critics_target.member(2 * i + 1)),
        ] {
            for ((w1, b1), (w2, b2)) in mine.iter().zip(&theirs) {
                for (x, y) in w1.iter().chain(b1).zip(w2.iter().chain(b2)) {
                    worst = worst.max((x - y).abs());
                }
            }
        }
    }
    // Bit-identical on the flex backend: each agent's matrices go through the same gemm whether
    // alone or stacked (gemm's result does not depend on its threading), and Adam and Polyak are
    // elementwise. A GPU backend may differ by round-off.
    assert_eq!(worst, 0.0, "largest weight difference between stacked and alone");
}

#[test]
fn a_stack_of_separately_trained_agents_continues_each_exactly() {
    // Agent::stack (what resuming a batched step does) then updates = each agent continuing alone.
    let task = Task::known("FetchReach").unwrap();
    let cfg = small_config(Algo::Td3);
    let (b0, b1) = (random_batch(&task, 16, 1), random_batch(&task, 16, 2));
    let mut parts = Vec::new();
    let mut alone = Vec::new();
    for (seed, b) in [(5u64, &b0), (6, &b1)] {
        let mut a = Agent::new(cfg.clone(), task.clone(), unit_norm(&task), seed, device());
        a.update(std::slice::from_ref(b));
        let mut c = Agent::new(cfg.clone(), task.clone(), unit_norm(&task), seed, device());
        c.update(std::slice::from_ref(b));
        parts.push(a);
        alone.push(c);
    }
    let mut stack = Agent::stack(parts);
    assert_eq!(stack.agents(), 2);
    stack.update(&[b1.clone(), b0.clone()]);
    alone[0].update(std::slice::from_ref(&b1));
    alone[1].update(std::slice::from_ref(&b0));
    for (i, a) in alone.iter().enumerate() {
        assert_eq!(a.actor.member(0), stack.actor.member(i));
        assert_eq!(a.critics.member(1), stack.critics.member(2 * i + 1));
    }
}

#[test]
fn a_grid_split_across_cores_trains_each_agent_as_alone() {
    // Three agents in two shards on a 2-thread pool vs each alone on 1 thread, with layers wide
    // enough (256 rows × 192 × 192) that gemm splits a lone agent's products across threads and
    // burn splits a stack's batched products by matrix: neither may change a bit.
    let task = Task::known("FetchPush").unwrap();
    let cfg = AgentConfig { algo: Algo::Td3, hidden: 192, layers: 2, ..AgentConfig::default() };
    let seeds = [4u64, 9, 30];
    let batches: Vec<Vec<Batch>> =
        (0..4).map(|u| seeds.iter().map(|&s| random_batch(&task, 256, 7 * s + u)).collect()).collect();
    let two = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let (grid, stats) = two.install(|| {
        let alone: Vec<Agent> =
            seeds.iter().map(|&s| Agent::new(cfg.clone(), task.clone(), unit_norm(&task), s, device())).collect();
        let mut grid = Shards::new(alone, Backend::CpuBurn).unwrap();
        let stats: Vec<_> = batches.iter().map(|b| grid.update(b).read()).collect();
        (grid, stats)
    });
    assert_eq!(grid.parts().len(), 2, "two shards on two threads");
    assert_eq!((grid.agents(), grid.updates()), (3, 4));
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    for (i, &seed) in seeds.iter().enumerate() {
        let mut alone = Agent::new(cfg.clone(), task.clone(), unit_norm(&task), seed, device());
        let mut alone2 = Agent::new(cfg.clone(), task.clone(), unit_norm(&task), seed, device());
        for (u, b) in batches.iter().enumerate() {
            let got = one.install(|| alone.update(std::slice::from_ref(&b[i])).read()[0]);
            assert_eq!(got, stats[u][i], "agent {i}, update {u}: losses");
            two.install(|| alone2.update(std::slice::from_ref(&b[i])));
        }
        assert_eq!(alone.critics.member(0), alone2.critics.member(0), "agent {i}: alone on 1 vs 2 threads");
        let (part, j) = grid.locate(i);
        assert_eq!(alone.actor.member(0), part.actor.member(j), "agent {i}: actor");
        assert_eq!(alone.critics.member(1), part.critics.member(2 * j + 1), "agent {i}: critic 2");
        assert_eq!(alone.critics_target.member(0), part.critics_target.member(2 * j), "agent {i}: target");
    }
    // Batched evaluation: each agent's actions are its own policy's, in order.
    let rows: Vec<(Vec<f32>, Vec<f32>)> = batches[0].iter().map(|b| (b.obs.clone(), b.goal.clone())).collect();
    let refs: Vec<(&[f32], &[f32])> = rows.iter().map(|(o, g)| (&o[..], &g[..])).collect();
    let acts = two.install(|| grid.act_all(&refs, 256));
    for (i, (o, g)) in refs.iter().enumerate() {
        let (part, j) = grid.locate(i);
        let mine = part.act_all(&vec![(*o, *g); part.agents()], 256).swap_remove(j);
        assert_eq!(acts[i], mine, "agent {i}: actions");
    }
}

#[test]
fn a_save_killed_between_its_renames_leaves_a_pair_that_loads() {
    // checkpoint::commit_with's two crash windows, taken by hand: killed before the checkpoint's
    // rename (the old pair in place, the new resume state pending), and after it (the new
    // checkpoint in place beside the old resume state, the new one pending).
    let task = Task::known("FetchReach").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.ckpt");
    let resume = checkpoint::resume_path(&path);
    let mut agent = Agent::new(small_config(Algo::Td3), task.clone(), unit_norm(&task), 1, device());
    agent.update(&[random_batch(&task, 16, 0)]);
    let old = |a: &Agent| {
        checkpoint::commit_with(
            checkpoint::stage(a, 0, &path, &Default::default()).unwrap(),
            vec![checkpoint::stage_resume(a, 0, &resume, &Default::default()).unwrap()],
        )
        .unwrap()
    };
    old(&agent);
    agent.update(&[random_batch(&task, 16, 1)]);
    let model = checkpoint::stage(&agent, 0, &path, &Default::default()).unwrap();
    let staged = checkpoint::stage_resume(&agent, 0, &resume, &Default::default()).unwrap();
    staged.commit_as(&checkpoint::pending_path(&resume)).unwrap();
    // Window 1: the old checkpoint and its own resume state.
    let (mut back, _) = checkpoint::load(&path, device()).unwrap();
    checkpoint::load_resume(&mut back, &resume).unwrap();
    assert_eq!(back.updates, 1);
    // Window 2: the new checkpoint; its resume state is the pending one.
    model.commit().unwrap();
    let (mut back, _) = checkpoint::load(&path, device()).unwrap();
    checkpoint::load_resume(&mut back, &resume).unwrap();
    assert_eq!((back.updates, back.critics_opt.step), (2, 2));
    assert_eq!(back.critics_opt.member(1), agent.critics_opt.member(1));
    // Without the pending file the pair is refused, as before.
    std::fs::remove_file(checkpoint::pending_path(&resume)).unwrap();
    let (mut back, _) = checkpoint::load(&path, device()).unwrap();
    let err = checkpoint::load_resume(&mut back, &resume).unwrap_err().to_string();
    assert!(err.contains("do not belong together"), "{err}");
    // A completed save leaves no pending file.
    old(&agent);
    assert!(!checkpoint::pending_path(&resume).exists());
}
