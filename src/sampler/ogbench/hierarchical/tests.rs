//! Both HGCDataset classes against their rules, written out again here from their code: every
//! derived key exact given the draws (subgoal steps at each clipping edge, targets, masks,
//! rewards, offsets), and the draws in their fractions.
use std::sync::Arc;

use super::super::tests::{drawn, sigma_bound};
use super::super::*;
use crate::sampler::view::InMemory;
use crate::trajectory::Episodes;

/// 20 episodes (T = 50) of a maze-named table whose observations are e·1000 + s and whose
/// achieved goals (its oracle representations) are −(e·1000 + s).
fn maze() -> InMemory {
    let mut d = Episodes::coded(0, 20, |_, _| 0.0);
    d.task.name = "antmaze-medium-v0".into();
    d.ag.iter_mut().for_each(|x| *x = -*x);
    InMemory(Arc::new(d))
}

fn code(e: i64, s: i64) -> f32 {
    (e * 1000 + s) as f32
}

fn names(b: &OgbenchBatch) -> Vec<&str> {
    b.keys.iter().filter(|k| !k.provenance).map(|k| k.name.as_str()).collect()
}

fn col<'a>(b: &'a OgbenchBatch, k: &str) -> &'a [i64] {
    b.i64(k).unwrap_or_else(|| panic!("no {k}"))
}

fn hgc(code: Code) -> OgbenchConfig {
    OgbenchConfig { code, dataset_class: DatasetClass::HGCDataset, subgoal_steps: Some(10), ..OgbenchConfig::default() }
}

#[test]
fn ogbench_s_hgcdataset_keys_follow_its_rules() {
    let v = maze();
    let (t, last) = (v.t() as i64, v.t() as i64 - 2);
    let cfg = OgbenchConfig { actor_p_trajgoal: 0.7, actor_p_randomgoal: 0.3, ..hgc(Code::Ogbench) };
    let n = 20_000;
    let b = drawn(&v, &cfg, n, 11);
    assert_eq!(
        names(&b),
        [
            "observations",
            "next_observations",
            "actions",
            "terminals",
            "value_goals",
            "low_actor_goals",
            "high_actor_goals",
            "high_actor_targets",
            "rewards",
            "masks"
        ]
    );
    let (e, s) = (col(&b, "episode"), col(&b, "step"));
    let kinds = b.kinds("high_actor_goal_kind").unwrap();
    let mut random = 0;
    for i in 0..n {
        let (e, s) = (e[i], s[i]);
        assert_eq!(b.row("observations", i).unwrap()[0], code(e, s));
        assert_eq!(b.f32("terminals").unwrap().0[i], if s == t - 2 { 1.0 } else { 0.0 });
        // Observations are goals in OGBench's classes.
        let (ve, vs) = (col(&b, "value_goal_episode")[i], col(&b, "value_goal_step")[i]);
        assert_eq!(b.row("value_goals", i).unwrap()[0], code(ve, vs), "row {i}");
        let success = if (ve, vs) == (e, s) { 1.0 } else { 0.0 };
        assert_eq!((b.f64("masks").unwrap()[i], b.f64("rewards").unwrap()[i]), (1.0 - success, success - 1.0));
        assert_eq!(b.row("low_actor_goals", i).unwrap()[0], code(e, (s + 10).min(last)), "row {i}");
        let (he, hs) = (col(&b, "high_actor_goal_episode")[i], col(&b, "high_actor_goal_step")[i]);
        assert_eq!(b.row("high_actor_goals", i).unwrap()[0], code(he, hs));
        let target = match kinds[i] {
            GoalKind::Random => {
                random += 1;
                (s + 10).min(last)
            }
            GoalKind::Trajectory => {
                // Uniform (actor_geom_sample false) between min(s + 1, L) and L.
                assert!(he == e && hs >= (s + 1).min(last) && hs <= last, "row {i}: {he}, {hs} for {e}, {s}");
                (s + 10).min(hs)
            }
            k => panic!("row {i}: a high-level actor goal of kind {k:?}"),
        };
        assert_eq!(b.row("high_actor_targets", i).unwrap()[0], code(e, target), "row {i}");
        assert_eq!((col(&b, "high_actor_target_episode")[i], col(&b, "high_actor_target_step")[i]), (e, target));
    }
    sigma_bound(random, n, 0.3);
}

/// Horizon Reduction's `compute_high_next_idxs` on flat indices (episode·T + step), as its code
/// has it: the subgoal step of a goal at flat index `goal` from row (e, s).
fn hr_subgoal(t: i64, (e, s): (i64, i64), goal: i64, steps: i64) -> i64 {
    let (idx, final_idx) = (e * t + s, e * t + t - 2);
    let k = steps.min(final_idx - idx);
    let diff = goal - idx;
    if 0 <= diff && diff < k { diff } else { k }
}

#[test]
fn horizon_reduction_s_hgcdataset_keys_are_exact_at_every_clipping_edge() {
    let v = maze();
    let t = v.t() as i64;
    let last = t - 2;
    for gc_negative in [false, true] {
        let cfg = OgbenchConfig {
            value_subgoal_steps: Some(5),
            actor_subgoal_steps: Some(8),
            subgoal_steps: None,
            low_value_goals: true,
            low_discount: Some(0.9),
            value_geom_sample: false,
            actor_p_trajgoal: 0.5,
            actor_p_randomgoal: 0.5,
            actor_geom_sample: true,
            gc_negative,
            oracle_reps: true,
            ..hgc(Code::HorizonReduction)
        };
        let n = 20_000;
        let b = drawn(&v, &cfg, n, 12);
        assert_eq!(
            names(&b),
            [
                "observations",
                "next_observations",
                "actions",
                "terminals",
                "valids",
                "oracle_reps",
                "high_value_reps",
                "high_value_goals",
                "high_value_actions",
                "high_value_next_observations",
                "low_value_goals",
                "high_actor_goals",
                "high_actor_actions",
                "high_actor_next_observations",
                "low_actor_goals",
                "high_value_offsets",
                "high_value_subgoal_steps",
                "high_value_masks",
                "high_value_rewards",
                "low_value_rewards",
                "low_value_masks",
                "rewards",
                "masks"
            ]
        );
        let (e, s) = (col(&b, "episode"), col(&b, "step"));
        let rep = |k: &str, i: usize| b.row(k, i).unwrap()[0];
        // Rows whose value subgoal was clipped to the episode's end, to the goal, or not at all.
        let (mut to_end, mut to_goal, mut whole) = (0, 0, 0);
        for i in 0..n {
            let (e, s) = (e[i], s[i]);
            assert_eq!(b.f32("valids").unwrap().0[i], 1.0);
            assert_eq!(rep("oracle_reps", i), -code(e, s));
            assert_eq!(rep("high_value_reps", i), -code(e, s));
            let (ge, gs) = (col(&b, "high_value_goal_episode")[i], col(&b, "high_value_goal_step")[i]);
            assert_eq!(rep("high_value_goals", i), -code(ge, gs), "row {i}: goals are representations");
            let k = hr_subgoal(t, (e, s), ge * t + gs, 5);
            match k {
                _ if k == 5 => whole += 1,
                _ if k == last - s && ge * t + gs - (e * t + s) != k => to_end += 1,
                _ => to_goal += 1,
            }
            assert_eq!(col(&b, "high_value_subgoal_steps")[i], k, "row {i}: ({e}, {s}) to ({ge}, {gs})");
            assert_eq!(col(&b, "high_value_offsets")[i], ge * t + gs - (e * t + s));
            assert_eq!(rep("high_value_actions", i), -code(e, s + k));
            assert_eq!(rep("high_value_next_observations", i), code(e, s + k));
            let reached = if k < 5 { 1.0 } else { 0.0 };
            assert_eq!(b.f64("high_value_masks").unwrap()[i], 1.0 - reached);
            let r = b.f64("high_value_rewards").unwrap()[i];
            let want = if gc_negative {
                -(1.0 - 0.99f64.powf(k as f64)) / (1.0 - 0.99)
            } else {
                0.99f64.powf(k as f64) * reached
            };
            assert_eq!(r, want, "row {i}: k = {k}");
            let one = if (ge, gs) == (e, s) { 1.0 } else { 0.0 };
            let offset = if gc_negative { 1.0 } else { 0.0 };
            assert_eq!((b.f64("masks").unwrap()[i], b.f64("rewards").unwrap()[i]), (1.0 - one, one - offset));
            let (le, ls) = (col(&b, "low_value_goal_episode")[i], col(&b, "low_value_goal_step")[i]);
            assert_eq!(rep("low_value_goals", i), -code(le, ls));
            let low = if (le, ls) == (e, s) { 1.0 } else { 0.0 };
            assert_eq!(
                (b.f64("low_value_masks").unwrap()[i], b.f64("low_value_rewards").unwrap()[i]),
                (1.0 - low, low - offset)
            );
            let (ae, st) = (col(&b, "high_actor_goal_episode")[i], col(&b, "high_actor_goal_step")[i]);
            assert_eq!(rep("high_actor_goals", i), -code(ae, st));
            let ka = hr_subgoal(t, (e, s), ae * t + st, 8);
            assert_eq!(rep("high_actor_actions", i), -code(e, s + ka), "row {i}");
            assert_eq!(rep("high_actor_next_observations", i), code(e, s + ka));
            assert_eq!(rep("low_actor_goals", i), -code(e, (s + 8).min(last)));
        }
        assert!(
            to_end > 100 && to_goal > 100 && whole > 100,
            "edges: {to_end} to the end, {to_goal} to the goal, {whole}"
        );
    }
}

#[test]
fn low_value_goals_come_with_the_key_and_take_the_discount_while_it_is_none() {
    let v = maze();
    let mean_offset = |low_discount: Option<f64>| {
        let cfg = OgbenchConfig {
            discount: 0.9,
            low_value_goals: true,
            low_discount,
            value_p_curgoal: 0.0,
            value_p_trajgoal: 1.0,
            value_p_randomgoal: 0.0,
            ..hgc(Code::HorizonReduction)
        };
        let b = drawn(&v, &cfg, 20_000, 13);
        let (s, g) = (col(&b, "step"), col(&b, "low_value_goal_step"));
        // Rows far enough from the end that the clip at L hardly moves the mean.
        let far: Vec<f64> = s.iter().zip(g).filter(|(s, _)| **s < 5).map(|(s, g)| (g - s) as f64).collect();
        far.iter().sum::<f64>() / far.len() as f64
    };
    // Geometric(1 − γ) has mean 1 / (1 − γ): 2 at 0.5; at 0.9 (the discount), 10 less the clip
    // at L − s ≥ 44 (0.9^44 · 10 ≈ 0.1).
    let (half, none) = (mean_offset(Some(0.5)), mean_offset(None));
    assert!((half - 2.0).abs() < 0.15, "{half}");
    assert!((none - 9.9).abs() < 0.6, "{none}");
    let b = drawn(&v, &hgc(Code::HorizonReduction), 10, 14);
    assert!(b.names().all(|k| !k.starts_with("low_value")), "no low_discount key, no low-level value goals");
}

#[test]
fn actions_clip_as_numpy_clips_float32() {
    let v = maze();
    let cfg = OgbenchConfig { code: Code::HorizonReduction, clip_actions: Some(0.9), ..OgbenchConfig::default() };
    let b = drawn(&v, &cfg, 2000, 15);
    let plain = drawn(&v, &OgbenchConfig { clip_actions: None, ..cfg.clone() }, 2000, 15);
    let (hi, lo) = ((1.0 - 0.9f64) as f32, (-1.0 + 0.9f64) as f32);
    let (clipped, raw) = (b.f32("actions").unwrap().0, plain.f32("actions").unwrap().0);
    let mut moved = 0;
    for (c, r) in clipped.iter().zip(raw) {
        assert_eq!(*c, r.clamp(lo, hi));
        moved += (c != r) as usize;
    }
    assert!(moved > 0 && moved < raw.len(), "{moved} of {} moved", raw.len());
}

#[test]
fn configs_the_classes_do_not_fit_are_refused_naming_the_key() {
    let whole = || Beta::Whole(maze().0);
    let hr = hgc(Code::HorizonReduction);
    let og = hgc(Code::Ogbench);
    let cases: Vec<(OgbenchConfig, &str)> = vec![
        (OgbenchConfig { subgoal_steps: Some(0), ..og.clone() }, "subgoal steps = 0"),
        (OgbenchConfig { subgoal_steps: Some(50), ..og.clone() }, "longer than this table's episodes (49 transitions"),
        (OgbenchConfig { subgoal_steps: None, ..og.clone() }, "HGCDataset needs subgoal_steps"),
        (
            OgbenchConfig { value_subgoal_steps: Some(1), ..og.clone() },
            "value_subgoal_steps = 1: a key of Horizon Reduction's",
        ),
        (OgbenchConfig { low_value_goals: true, ..og.clone() }, "low_discount = None: a key of Horizon Reduction's"),
        (
            OgbenchConfig { subgoal_steps: Some(25), dataset_class: DatasetClass::GCDataset, ..og.clone() },
            "subgoal_steps = 25: a key of HGCDataset",
        ),
        (
            OgbenchConfig { low_value_goals: true, low_discount: Some(1.5), ..hr.clone() },
            "low_discount = 1.5: must be in (0, 1)",
        ),
        (OgbenchConfig { subgoal_steps: None, actor_subgoal_steps: Some(3), ..hr.clone() }, "(or value_subgoal_steps)"),
        (OgbenchConfig { oracle_reps: true, ..og.clone() }, "use layout=\"horizon_reduction\""),
        (OgbenchConfig { clip_actions: Some(1.5), ..hr.clone() }, "clip_actions = 1.5"),
    ];
    for (cfg, msg) in cases {
        let e = OgbenchStream::new(whole(), cfg.clone(), 0).err().unwrap_or_else(|| panic!("{cfg:?} taken"));
        assert!(e.to_string().contains(msg), "{e}\nwanted: {msg}");
    }
    // Oracle representations only where the table's goals are them.
    let fetch = Beta::Whole(Arc::new(Episodes::coded(0, 2, |_, _| 0.0)));
    let e = OgbenchStream::new(fetch, OgbenchConfig { oracle_reps: true, ..hr.clone() }, 0).err().expect("refused");
    assert!(e.to_string().contains("FetchReach's table goals are not OGBench's oracle representations"), "{e}");
    assert!(OgbenchStream::new(whole(), OgbenchConfig { oracle_reps: true, ..hr }, 0).is_ok());
}
