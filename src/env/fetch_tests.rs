//! Properties of the Fetch port that hold without Python (parity with Python itself is
//! `tests/env_parity.rs`). These need the assets `make deps` unpacks.

use super::*;
use crate::env::assets_dir;

fn env(task: &str) -> FetchEnv {
    FetchEnv::new(task, &assets_dir()).unwrap()
}

/// A fixed, varied action sequence (no RNG needed).
fn action(t: usize) -> [f64; 4] {
    let t = t as f64;
    [(0.7 * t).sin(), (0.3 * t).cos(), (1.1 * t).sin() - 0.2, (0.5 * t).cos()]
}

#[test]
fn every_task_has_the_dimensions_of_its_task() {
    for name in TASKS {
        let mut e = env(name);
        let o = e.reset(Some(0));
        let t = e.task().clone();
        assert_eq!((o.observation.len(), o.achieved_goal.len(), o.desired_goal.len()), (t.obs_dim, 3, 3));
        let s = e.step(&action(0));
        assert_eq!(s.obs.observation.len(), t.obs_dim);
        assert!(s.reward == 0.0 || s.reward == -1.0);
        assert_eq!(s.success, s.reward == 0.0);
        assert!(s.obs.observation.iter().all(|x| x.is_finite()), "{name}");
    }
}

#[test]
fn same_seed_same_episode_and_unseeded_resets_continue_the_stream() {
    let run = |e: &mut FetchEnv, seed| {
        let mut v = vec![e.reset(seed)];
        v.extend((0..5).map(|t| e.step(&action(t)).obs));
        v
    };
    let (mut a, mut b) = (env("FetchPickAndPlace"), env("FetchPickAndPlace"));
    let first = run(&mut a, Some(3));
    assert_eq!(first, run(&mut b, Some(3)));
    // A second, unseeded episode differs from the first but is the same on both copies.
    let second = run(&mut a, None);
    assert_ne!(first[0].desired_goal, second[0].desired_goal);
    assert_eq!(second, run(&mut b, None));
    // Resetting returns the robot to the same start whatever happened before.
    assert_eq!(first[0].observation[..3], second[0].observation[..3]);
    assert_eq!(a.time(), b.time());
}

#[test]
fn objects_start_away_from_the_gripper_and_goals_follow_the_task() {
    for name in ["FetchPush", "FetchSlide", "FetchPickAndPlace"] {
        let mut e = env(name);
        let g0 = e.initial_gripper_xpos();
        for seed in 0..20 {
            let o = e.reset(Some(seed));
            let obj = &o.observation[3..6];
            assert!((obj[0] - g0[0]).hypot(obj[1] - g0[1]) >= 0.1, "{name} seed {seed}");
            assert_eq!(o.achieved_goal, obj);
            let g = e.goal();
            match name {
                "FetchSlide" => assert!((g[0] - g0[0] - 0.4).abs() <= 0.3 + 1e-12 && g[2] == e.height_offset()),
                "FetchPush" => assert_eq!(g[2], e.height_offset()),
                _ => assert!(g[2] >= e.height_offset() && g[2] < e.height_offset() + 0.45),
            }
        }
    }
    let mut reach = env("FetchReach");
    let g0 = reach.initial_gripper_xpos();
    let o = reach.reset(Some(1));
    assert_eq!(o.achieved_goal, o.observation[..3]);
    assert!(o.desired_goal.iter().zip(g0).all(|(g, c)| (g - c).abs() <= 0.15));
}

#[test]
fn blocked_grippers_stay_shut_and_the_free_one_opens() {
    let open = [0.0, 0.0, 0.0, 1.0];
    let mut push = env("FetchPush");
    push.reset(Some(0));
    let s = (0..5).map(|_| push.step(&open)).last().unwrap();
    assert_eq!(s.obs.observation[9..11], [0.0, 0.0]);
    let mut pick = env("FetchPickAndPlace");
    pick.reset(Some(0));
    let s = (0..5).map(|_| pick.step(&open)).last().unwrap();
    assert!(s.obs.observation[9] > 0.01 && s.obs.observation[10] > 0.01, "{:?}", &s.obs.observation[9..11]);
}

#[test]
fn actions_are_clipped_to_the_unit_box() {
    let (mut a, mut b) = (env("FetchReach"), env("FetchReach"));
    a.reset(Some(0));
    b.reset(Some(0));
    assert_eq!(a.step(&[5.0, -9.0, 1.0, 3.0]).obs, b.step(&[1.0, -1.0, 1.0, 1.0]).obs);
}

#[test]
#[should_panic(expected = "takes 4 action values")]
fn wrong_action_length_panics() {
    let mut e = env("FetchReach");
    e.reset(Some(0));
    e.step(&[0.0; 3]);
}

#[test]
fn assets_override_is_honoured_in_errors() {
    let e = FetchEnv::new("FetchPush", Path::new("/no/such/dir")).err().unwrap().to_string();
    assert!(e.contains("/no/such/dir/fetch/push.xml") && e.contains("make deps"), "{e}");
}
