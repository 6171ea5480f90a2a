//! OGBench's batch layout against GCDataset's rules: provenance, success, goal kinds and their fractions.
use std::sync::Arc;

use super::*;
use crate::sampler::view::InMemory;
use crate::trajectory::Episodes;

/// 20 FetchReach episodes (T = 50) whose every observation is the number e·1000 + s.
fn coded(n: usize) -> InMemory {
    InMemory(Arc::new(Episodes::coded(0, n, |_, _| 0.0)))
}

/// The flat class's keys, as fields.
#[derive(Debug)]
struct Flat {
    n: usize,
    obs_dim: usize,
    act_dim: usize,
    observations: Vec<f32>,
    next_observations: Vec<f32>,
    actions: Vec<f32>,
    terminals: Vec<f32>,
    rewards: Vec<f64>,
    masks: Vec<f64>,
    value_goals: Vec<f32>,
    actor_goals: Vec<f32>,
    episode: Vec<i64>,
    step: Vec<i64>,
    value_goal_episode: Vec<i64>,
    value_goal_step: Vec<i64>,
    actor_goal_episode: Vec<i64>,
    actor_goal_step: Vec<i64>,
    value_goal_kind: Vec<GoalKind>,
    actor_goal_kind: Vec<GoalKind>,
}

fn flat(b: &OgbenchBatch) -> Flat {
    let f = |k: &str| b.f32(k).unwrap_or_else(|| panic!("no {k}")).0.to_vec();
    let i = |k: &str| b.i64(k).unwrap_or_else(|| panic!("no {k}")).to_vec();
    let kinds = |k: &str| b.kinds(k).unwrap_or_else(|| panic!("no {k}")).to_vec();
    Flat {
        n: b.n,
        obs_dim: b.f32("observations").unwrap().1,
        act_dim: b.f32("actions").unwrap().1,
        observations: f("observations"),
        next_observations: f("next_observations"),
        actions: f("actions"),
        terminals: f("terminals"),
        rewards: b.f64("rewards").unwrap().to_vec(),
        masks: b.f64("masks").unwrap().to_vec(),
        value_goals: f("value_goals"),
        actor_goals: f("actor_goals"),
        episode: i("episode"),
        step: i("step"),
        value_goal_episode: i("value_goal_episode"),
        value_goal_step: i("value_goal_step"),
        actor_goal_episode: i("actor_goal_episode"),
        actor_goal_step: i("actor_goal_step"),
        value_goal_kind: kinds("value_goal_kind"),
        actor_goal_kind: kinds("actor_goal_kind"),
    }
}

pub(super) fn drawn(v: &InMemory, cfg: &OgbenchConfig, n: usize, seed: u64) -> OgbenchBatch {
    let ctx = Ctx { view: v, swap: None, cfg, augment: true };
    let mut rng = NpRandom::spawned(seed, &[STREAM_OGBENCH, 0]);
    match cfg.dataset_class {
        DatasetClass::GCDataset => draw(&ctx, &mut rng, n),
        DatasetClass::HGCDataset => hierarchical::draw(&ctx, &mut rng, n),
    }
}

fn batch(cfg: &OgbenchConfig, n: usize, seed: u64) -> (InMemory, Flat) {
    let v = coded(20);
    let b = flat(&drawn(&v, cfg, n, seed));
    (v, b)
}

/// The (episode, step) an observation of the coded table says it is.
fn code(x: f32) -> (i64, i64) {
    let c = x as i64;
    (c / 1000, c % 1000)
}

pub(super) fn sigma_bound(count: usize, n: usize, p: f64) {
    let sd = (n as f64 * p * (1.0 - p)).sqrt();
    assert!((count as f64 - n as f64 * p).abs() <= 4.0 * sd + 1e-9, "{count} of {n} where p = {p}");
}

#[test]
fn rows_are_transitions_and_goals_are_the_observations_they_name() {
    let (v, b) = batch(&OgbenchConfig::default(), 5000, 1);
    let (od, ad) = (b.obs_dim, b.act_dim);
    for i in 0..b.n {
        let (e, s) = (b.episode[i] as usize, b.step[i] as usize);
        assert!(s + 1 < v.t(), "row {i}: step {s}");
        assert_eq!(&b.observations[i * od..(i + 1) * od], v.obs(e, s), "row {i}");
        assert_eq!(&b.next_observations[i * od..(i + 1) * od], v.obs(e, s + 1), "row {i}");
        assert_eq!(&b.actions[i * ad..(i + 1) * ad], v.action(e, s), "row {i}");
        assert_eq!(b.terminals[i], if s == v.t() - 2 { 1.0 } else { 0.0 }, "row {i}");
        for (goals, ep, st) in [
            (&b.value_goals, &b.value_goal_episode, &b.value_goal_step),
            (&b.actor_goals, &b.actor_goal_episode, &b.actor_goal_step),
        ] {
            // A goal is a transition's observation: never an episode's last observation.
            assert!((st[i] as usize) < v.t() - 1, "row {i}: goal step {}", st[i]);
            assert_eq!(&goals[i * od..(i + 1) * od], v.obs(ep[i] as usize, st[i] as usize), "row {i}");
        }
    }
}

#[test]
fn rewards_say_success_exactly_when_the_value_goal_is_the_current_observation() {
    for gc_negative in [true, false] {
        let cfg = OgbenchConfig { gc_negative, ..OgbenchConfig::default() };
        let (_, b) = batch(&cfg, 20_000, 2);
        let od = b.obs_dim;
        let mut successes = 0;
        for i in 0..b.n {
            // Observations are unique in the coded table, so equal vectors are the same index.
            let same = b.value_goals[i * od..(i + 1) * od] == b.observations[i * od..(i + 1) * od];
            assert_eq!(b.masks[i], if same { 0.0 } else { 1.0 }, "row {i}");
            let want = if same { 1.0 } else { 0.0 } - if gc_negative { 1.0 } else { 0.0 };
            assert_eq!(b.rewards[i], want, "row {i}");
            assert_eq!(code(b.value_goals[i * od]), (b.value_goal_episode[i], b.value_goal_step[i]));
            successes += same as usize;
            if b.value_goal_kind[i] == GoalKind::Current {
                assert!(same, "row {i}: a current goal is a success");
            }
        }
        // Current goals (0.2) plus trajectory goals of last transitions and random hits.
        assert!(successes as f64 > 0.2 * b.n as f64, "{successes}");
    }
}

#[test]
fn goal_kinds_come_in_their_fractions() {
    let n = 40_000;
    let (_, b) = batch(&OgbenchConfig::default(), n, 3);
    let count = |k: &[GoalKind], kind| k.iter().filter(|&&x| x == kind).count();
    sigma_bound(count(&b.value_goal_kind, GoalKind::Current), n, 0.2);
    sigma_bound(count(&b.value_goal_kind, GoalKind::Trajectory), n, 0.5);
    sigma_bound(count(&b.value_goal_kind, GoalKind::Random), n, 0.3);
    // The actor's defaults: every goal from the trajectory.
    assert_eq!(count(&b.actor_goal_kind, GoalKind::Trajectory), n);
    let cfg = OgbenchConfig {
        actor_p_curgoal: 0.1,
        actor_p_trajgoal: 0.6,
        actor_p_randomgoal: 0.3,
        value_p_curgoal: 1.0,
        value_p_trajgoal: 0.0,
        value_p_randomgoal: 0.0,
        ..OgbenchConfig::default()
    };
    let (_, b) = batch(&cfg, n, 4);
    assert_eq!(count(&b.value_goal_kind, GoalKind::Current), n);
    assert!(b.rewards.iter().all(|&r| r == 0.0) && b.masks.iter().all(|&m| m == 0.0));
    sigma_bound(count(&b.actor_goal_kind, GoalKind::Current), n, 0.1);
    sigma_bound(count(&b.actor_goal_kind, GoalKind::Trajectory), n, 0.6);
}

/// Trajectory goals stay in the row's episode at steps min(s + 1, L)..=L.
fn trajectory_rows(b: &Flat, t: usize) -> Vec<(usize, usize)> {
    let last = t - 2;
    let mut rows = Vec::new();
    for i in 0..b.n {
        if b.value_goal_kind[i] == GoalKind::Trajectory {
            let (s, g) = (b.step[i] as usize, b.value_goal_step[i] as usize);
            assert_eq!(b.value_goal_episode[i], b.episode[i], "row {i}");
            assert!(g >= (s + 1).min(last) && g <= last, "row {i}: goal step {g} for step {s}");
            rows.push((s, g));
        }
    }
    rows
}

/// Pearson's χ² of counts against expectations, bins of expectation < 5 pooled; and the bins.
fn chi_square(counts: &[f64], expected: &[f64]) -> (f64, usize) {
    let (mut chi, mut bins, mut c, mut x) = (0.0, 0usize, 0.0, 0.0);
    for (k, (&o, &e)) in counts.iter().zip(expected).enumerate() {
        c += o;
        x += e;
        if x >= 5.0 || k + 1 == counts.len() {
            chi += (c - x) * (c - x) / x;
            bins += 1;
            c = 0.0;
            x = 0.0;
        }
    }
    (chi, bins)
}

/// χ² of the geometric offsets against Geometric(1 − discount) truncated at L − s, row by row.
fn offsets_chi_square(rows: &[(usize, usize)], discount: f64, last: usize) -> (f64, usize) {
    let p = 1.0 - discount;
    let (mut counts, mut expected) = (vec![0.0; last + 1], vec![0.0; last + 1]);
    for &(s, g) in rows {
        counts[g - s] += 1.0;
        // P(k = j) = (1 − p)^(j − 1) p for j < L − s; the rest of the mass at L − s.
        let room = last - s;
        if room == 0 {
            expected[0] += 1.0;
            continue;
        }
        for (j, x) in expected.iter_mut().enumerate().take(room).skip(1) {
            *x += (1.0 - p).powi(j as i32 - 1) * p;
        }
        expected[room] += (1.0 - p).powi(room as i32 - 1);
    }
    chi_square(&counts, &expected)
}

#[test]
fn geometric_trajectory_goals_follow_the_truncated_geometric() {
    // discount 0.9: offsets of mean 10, well inside T = 50 episodes, and the clip still hit.
    let cfg = OgbenchConfig {
        discount: 0.9,
        value_p_curgoal: 0.0,
        value_p_trajgoal: 1.0,
        value_p_randomgoal: 0.0,
        ..OgbenchConfig::default()
    };
    let (v, b) = batch(&cfg, 40_000, 5);
    let rows = trajectory_rows(&b, v.t());
    assert_eq!(rows.len(), b.n);
    let (chi, bins) = offsets_chi_square(&rows, 0.9, v.t() - 2);
    let df = (bins - 1) as f64;
    // χ²(df): mean df, sd √(2 df); 5 sd above the mean a correct sampler does not reach.
    assert!(chi < df + 5.0 * (2.0 * df).sqrt(), "χ² {chi} with {df} degrees of freedom");
    // The test has power: the same offsets against discount 0.88 are far out.
    let (wrong, _) = offsets_chi_square(&rows, 0.88, v.t() - 2);
    assert!(wrong > df + 10.0 * (2.0 * df).sqrt(), "χ² {wrong} against the wrong discount");
    // OGBench's default discount clips most offsets of steps near the end; rows of step 0
    // keep their mean min(k, 49): (1 − 0.99^49) / 0.01 = 38.9.
    let (_, b) = batch(
        &OgbenchConfig {
            value_p_curgoal: 0.0,
            value_p_trajgoal: 1.0,
            value_p_randomgoal: 0.0,
            ..OgbenchConfig::default()
        },
        40_000,
        6,
    );
    let rows = trajectory_rows(&b, v.t());
    let (chi, bins) = offsets_chi_square(&rows, 0.99, v.t() - 2);
    let df = (bins - 1) as f64;
    assert!(chi < df + 5.0 * (2.0 * df).sqrt(), "χ² {chi} with {df} degrees of freedom at discount 0.99");
}

#[test]
fn uniform_trajectory_goals_are_ogbench_rounded_uniforms() {
    // The actor's default: uniform between s + 1 and L, end points at half weight.
    let (v, b) = batch(
        &OgbenchConfig {
            value_geom_sample: false,
            value_p_curgoal: 0.0,
            value_p_trajgoal: 1.0,
            value_p_randomgoal: 0.0,
            ..OgbenchConfig::default()
        },
        60_000,
        7,
    );
    let last = v.t() - 2;
    let rows = trajectory_rows(&b, v.t());
    let (mut counts, mut expected) = (vec![0.0; last + 1], vec![0.0; last + 1]);
    for &(s, g) in &rows {
        counts[g] += 1.0;
        let lo = (s + 1).min(last);
        if lo == last {
            expected[last] += 1.0;
            continue;
        }
        let width = (last - lo) as f64;
        for (j, x) in expected.iter_mut().enumerate().take(last + 1).skip(lo) {
            *x += if j == lo || j == last { 0.5 / width } else { 1.0 / width };
        }
    }
    let (chi, bins) = chi_square(&counts, &expected);
    let df = (bins - 1) as f64;
    assert!(chi < df + 5.0 * (2.0 * df).sqrt(), "χ² {chi} with {df} degrees of freedom");
    // The actor goals of the same batch (the default) are the same kind of draw.
    let a: Vec<_> = (0..b.n).map(|i| (b.step[i], b.actor_goal_step[i])).collect();
    assert!(a.iter().all(|&(s, g)| g >= (s + 1).min(last as i64) && g <= last as i64));
}

#[test]
fn transitions_and_random_goals_are_uniform_over_the_table() {
    let cfg = OgbenchConfig {
        value_p_curgoal: 0.0,
        value_p_trajgoal: 0.0,
        value_p_randomgoal: 1.0,
        ..OgbenchConfig::default()
    };
    let (v, b) = batch(&cfg, 60_000, 8);
    let (episodes, steps) = (v.episodes(), v.t() - 1);
    let bound = |df: f64| df + 5.0 * (2.0 * df).sqrt();
    for (what, ep, st) in
        [("transitions", &b.episode, &b.step), ("random goals", &b.value_goal_episode, &b.value_goal_step)]
    {
        let (mut by_e, mut by_s) = (vec![0.0; episodes], vec![0.0; steps]);
        for i in 0..b.n {
            // The last observation (step T − 1) is not a transition: never drawn.
            assert!((st[i] as usize) < steps, "{what}: row {i} at step {}", st[i]);
            by_e[ep[i] as usize] += 1.0;
            by_s[st[i] as usize] += 1.0;
        }
        let (ce, _) = chi_square(&by_e, &vec![b.n as f64 / episodes as f64; episodes]);
        let (cs, _) = chi_square(&by_s, &vec![b.n as f64 / steps as f64; steps]);
        assert!(ce < bound((episodes - 1) as f64), "{what}: episodes χ² {ce}");
        assert!(cs < bound((steps - 1) as f64), "{what}: steps χ² {cs}");
    }
    // Random goals are drawn apart from their rows: about 1 in 20·50 lands on the row itself.
    let hits = (0..b.n).filter(|&i| b.rewards[i] == 0.0).count();
    sigma_bound(hits, b.n, 1.0 / (episodes * steps) as f64);
}

#[test]
fn same_seed_same_bytes_and_batches_are_their_own_streams() {
    let open = || OgbenchStream::new(Beta::Whole(coded(5).0), OgbenchConfig::default(), 9).unwrap();
    let (mut a, mut b) = (open(), open());
    let a0 = a.next_batch(64).unwrap();
    assert_eq!(a0, b.next_batch(64).unwrap());
    // Batch 1 is the same whether or not batch 0 was drawn at another size first.
    let _ = b.batch(0, 7).unwrap();
    assert_eq!(a.next_batch(64).unwrap(), b.next_batch(64).unwrap());
    assert_ne!(a0, a.next_batch(64).unwrap(), "batches differ from one another");
    let mut c = OgbenchStream::new(Beta::Whole(coded(5).0), OgbenchConfig::default(), 10).unwrap();
    assert_ne!(a0, c.next_batch(64).unwrap(), "seeds differ");
}

#[test]
fn settings_ogbench_refuses_are_refused() {
    let bad = [
        OgbenchConfig { value_p_randomgoal: 0.4, ..OgbenchConfig::default() },
        OgbenchConfig { actor_p_trajgoal: -0.5, actor_p_randomgoal: 1.5, ..OgbenchConfig::default() },
        OgbenchConfig { discount: 1.0, ..OgbenchConfig::default() },
    ];
    let msgs =
        ["value_p_curgoal + value_p_trajgoal + value_p_randomgoal = 1.1", "actor_p_trajgoal = -0.5", "discount = 1"];
    for (cfg, msg) in bad.iter().zip(msgs) {
        let e = OgbenchStream::new(Beta::Whole(coded(2).0), cfg.clone(), 0).err().expect("refused");
        assert!(e.to_string().contains(msg), "{e}");
    }
    // Within np.isclose of 1 is accepted, as OGBench accepts it.
    let near = OgbenchConfig { value_p_randomgoal: 0.3 + 5e-6, ..OgbenchConfig::default() };
    assert!(near.validate().is_ok());
    let parsed: OgbenchConfig = serde_json::from_str(r#"{"discount": 0.999}"#).unwrap();
    assert_eq!(parsed, OgbenchConfig { discount: 0.999, ..OgbenchConfig::default() });
    assert!(serde_json::from_str::<OgbenchConfig>(r#"{"value_p_curgoa": 0.1}"#).is_err());
}
