//! The Rust Fetch and hand environments against gymnasium-robotics 1.4.2 on the same MuJoCo
//! 3.17.0, and the Rust numpy generator (uniforms, ziggurat normals) against numpy. Python writes reference runs
//! (`tests/py/env_parity.py`, floats as IEEE bits); Rust replays the same seeds and actions.
//! Positions (and goals, object placement, sim time, rewards) must be equal bit for bit; the
//! rest (Euler angles, Jacobian velocities, where numpy's libm/BLAS may round differently) within
//! 1e-6. Run with `--nocapture` to see the largest differences per task.

mod common;

use pgser::env::fetch::{FetchEnv, TASKS};
use pgser::env::hand::{self, HandEnv};
use pgser::env::{GoalEnv, Obs, assets_dir};
use pgser::nprandom::NpRandom;
use pgser::nprandom::ziggurat;
use serde_json::Value;

const SEEDS: [u64; 3] = [0, 1, 7];
const STEPS: usize = 50;
const TOLERANCE: f64 = 1e-6;

/// A list of u64 IEEE bit patterns, as the Python side writes floats.
fn floats(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|b| f64::from_bits(b.as_u64().unwrap())).collect()
}

fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits() || (*x == 0.0 && *y == 0.0))
}

#[test]
fn numpy_generator_is_reproduced() {
    let seeds: [u64; 5] = [0, 1, 42, (1 << 32) + 5, 1 << 63];
    let list = seeds.map(|s| s.to_string()).join(",");
    let out = common::py_ok("env_parity.py", &["rng", "--seeds", &list, "--n", "1000"]);
    let py: Value = serde_json::from_slice(&out.stdout).unwrap();
    for s in seeds {
        let want = &py[s.to_string()];
        let mut g = NpRandom::new(s);
        let random: Vec<f64> = (0..1000).map(|_| g.random()).collect();
        assert!(same_bits(&random, &floats(&want["random"])), "random() differs for seed {s}");
        let mut u = NpRandom::new(s);
        let mut uniform: Vec<f64> = (0..1000).map(|_| u.uniform(-0.3, 0.7)).collect();
        uniform.push(u.uniform(0.0, 0.45));
        assert!(same_bits(&uniform, &floats(&want["uniform"])), "uniform() differs for seed {s}");
        let (zig, mut n) = (ziggurat::tables().unwrap(), NpRandom::new(s));
        let normal: Vec<f64> = (0..1000).map(|_| zig.normal(&mut n, 0.0, 0.005)).collect();
        assert!(same_bits(&normal, &floats(&want["normal"])), "normal() differs for seed {s}");
    }
}

/// Largest |difference| seen per part of the observation, and whether positions stayed exact.
#[derive(Default)]
struct Diffs {
    positions: f64,
    euler: f64,
    velocities: f64,
    compared: usize,
}

impl Diffs {
    /// Compare one observation; `what` names it in failure messages.
    fn check(&mut self, task: &str, what: &str, got: &Obs, want: &Value) {
        let (obs, ag, g) =
            (floats(&want["observation"]), floats(&want["achieved_goal"]), floats(&want["desired_goal"]));
        assert_eq!(got.observation.len(), obs.len(), "{task} {what}: observation length");
        assert!(same_bits(&got.achieved_goal, &ag), "{task} {what}: achieved goal {:?} != {ag:?}", got.achieved_goal);
        assert!(same_bits(&got.desired_goal, &g), "{task} {what}: desired goal {:?} != {g:?}", got.desired_goal);
        // Positions: grip, object, object − grip, fingers (Reach: grip, fingers).
        let (npos, euler) = if obs.len() == 10 { (5, 5..5) } else { (11, 11..14) };
        let diff = |r: std::ops::Range<usize>| r.map(|i| (got.observation[i] - obs[i]).abs()).fold(0.0f64, f64::max);
        let n = obs.len();
        let (p, e, v) = (diff(0..npos), diff(euler.clone()), diff(euler.end..n));
        self.positions = self.positions.max(p);
        self.euler = self.euler.max(e);
        self.velocities = self.velocities.max(v);
        self.compared += 1;
        assert!(
            same_bits(&got.observation[..npos], &obs[..npos]),
            "{task} {what}: positions differ\nrust   {:?}\npython {:?}",
            &got.observation[..npos],
            &obs[..npos]
        );
        assert!(
            e.max(v) <= TOLERANCE,
            "{task} {what}: observation differs by {}\nrust   {:?}\npython {obs:?}",
            e.max(v),
            got.observation
        );
    }
}

#[test]
fn fetch_envs_match_python() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("runs.json");
    let seeds = SEEDS.map(|s| s.to_string()).join(",");
    let steps = STEPS.to_string();
    let args = ["env", "--tasks", &TASKS.join(","), "--seeds", &seeds, "--steps", &steps];
    common::py_ok("env_parity.py", &[&args[..], &["--out", path.to_str().unwrap()]].concat());
    let runs: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();

    for task in TASKS {
        let mut env = FetchEnv::new(task, &assets_dir()).unwrap();
        let mut d = Diffs::default();
        for seed in SEEDS {
            let run = &runs[task][seed.to_string()];
            // _env_setup: where the gripper ends up and the table height, bit for bit.
            assert!(same_bits(&env.initial_gripper_xpos(), &floats(&run["initial_gripper_xpos"])), "{task} setup");
            assert_eq!(env.height_offset().to_bits(), floats(&run["height_offset"])[0].to_bits(), "{task} height");
            let obs = env.reset(Some(seed));
            d.check(task, &format!("seed {seed} reset"), &obs, &run["reset"]);
            for (t, want) in run["steps"].as_array().unwrap().iter().enumerate() {
                let action = floats(&want["action"]);
                let step = env.step(&action);
                let what = format!("seed {seed} step {t}");
                d.check(task, &what, &step.obs, want);
                assert_eq!(step.reward, want["reward"].as_f64().unwrap(), "{task} {what}: reward");
                assert_eq!(step.success, want["success"].as_bool().unwrap(), "{task} {what}: success");
                assert_eq!(env.time().to_bits(), floats(&want["time"])[0].to_bits(), "{task} {what}: time");
            }
        }
        println!(
            "{task:<18} {} observations: positions exact (max diff {:e}), euler max diff {:e}, velocities max diff {:e}",
            d.compared, d.positions, d.euler, d.velocities
        );
    }
}

/// The hand tasks, replayed: several episodes per environment with `reset()` in between, so
/// what carries over from one episode to the next (controls, warm starts: reset does not clear
/// them) is checked too. Everything in the observation is a raw qpos/qvel, so all of it must be
/// equal bit for bit, as must goals, rewards, successes and time.
#[test]
fn hand_envs_match_python() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hand.json");
    let (seeds, episodes, steps) = ([0u64, 3], 3, 40);
    let seed_list = seeds.map(|s| s.to_string()).join(",");
    let (e, st) = (episodes.to_string(), steps.to_string());
    let args = ["hand", "--tasks", &hand::TASKS.join(","), "--seeds", &seed_list, "--episodes", &e, "--steps", &st];
    common::py_ok("env_parity.py", &[&args[..], &["--out", path.to_str().unwrap()]].concat());
    let runs: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    let exact = |task: &str, what: &str, got: &Obs, want: &Value| {
        for (key, g) in [
            ("observation", &got.observation),
            ("achieved_goal", &got.achieved_goal),
            ("desired_goal", &got.desired_goal),
        ] {
            let w = floats(&want[key]);
            assert!(same_bits(g, &w), "{task} {what}: {key} differs\nrust   {g:?}\npython {w:?}");
        }
    };
    for task in hand::TASKS {
        let mut successes = 0;
        for seed in seeds {
            let mut env = HandEnv::new(task, &assets_dir()).unwrap();
            for (ep, run) in runs[task][seed.to_string()].as_array().unwrap().iter().enumerate() {
                let obs = env.reset(if ep == 0 { Some(seed) } else { None });
                exact(task, &format!("seed {seed} episode {ep} reset"), &obs, &run["reset"]);
                assert_eq!(
                    env.time().to_bits(),
                    floats(&run["time"])[0].to_bits(),
                    "{task} seed {seed} episode {ep}: time"
                );
                for (t, want) in run["steps"].as_array().unwrap().iter().enumerate() {
                    let step = env.step(&floats(&want["action"]));
                    let what = format!("seed {seed} episode {ep} step {t}");
                    exact(task, &what, &step.obs, want);
                    assert_eq!(step.reward, want["reward"].as_f64().unwrap(), "{task} {what}: reward");
                    assert_eq!(step.success, want["success"].as_bool().unwrap(), "{task} {what}: success");
                    assert_eq!(env.time().to_bits(), floats(&want["time"])[0].to_bits(), "{task} {what}: time");
                    successes += step.success as usize;
                }
            }
            // After those episodes, a restart is a newly made environment again: episode 0.
            let first = &runs[task][seed.to_string()][0];
            let obs = env.restart(seed);
            exact(task, &format!("seed {seed} restart"), &obs, &first["reset"]);
            for (t, want) in first["steps"].as_array().unwrap().iter().enumerate() {
                exact(task, &format!("seed {seed} restart step {t}"), &env.step(&floats(&want["action"])).obs, want);
            }
        }
        println!(
            "{task}: {} episodes × {steps} steps equal to Python bit for bit ({successes} successful steps)",
            seeds.len() * episodes
        );
    }
}

/// `collect --policy random` over 100 episodes against gymnasium doing the same (a newly made
/// environment per episode, reset with seed S + i, numpy's spawned action stream): the same
/// final-step successes and the same summed rewards.
#[test]
fn random_hand_episodes_succeed_as_in_python() {
    let dir = tempfile::tempdir().unwrap();
    for task in hand::TASKS {
        let out =
            common::py_ok("env_parity.py", &["random-success", "--task", task, "--seed", "1000", "--episodes", "100"]);
        let py: Value = serde_json::from_slice(&out.stdout).unwrap();
        let py_successes = py["success"].as_array().unwrap().iter().filter(|v| v.as_bool().unwrap()).count();
        let py_return: f64 = py["returns"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).sum();
        let opts = pgser::collect::CollectOptions {
            task: task.to_string(),
            policy: pgser::collect::policy::PolicySpec {
                kind: pgser::collect::policy::PolicyKind::Random,
                noise: 0.0,
                epsilon: 0.0,
            },
            episodes: 100,
            seed: 1000,
            output: dir.path().join(format!("{task}.parquet")),
            float32: false,
            row_group_rows: 65_536,
            command: "test".into(),
        };
        let s = pgser::collect::collect(&opts, &indicatif::ProgressBar::hidden()).unwrap();
        println!(
            "{task}: random actions, 100 episodes: {} successes (Python {py_successes}), mean return {} (Python {})",
            s.successes,
            s.mean_return,
            py_return / 100.0
        );
        assert_eq!(s.successes, py_successes, "{task}: final-step successes");
        assert_eq!((s.mean_return * 100.0).round(), py_return, "{task}: summed rewards");
    }
}

/// OGBench's PointMaze, replayed: per maze and seed, an episode of a given task after
/// `np.random.seed(seed)` and one of a random task continuing numpy's global generator, each of
/// 200 noisy straight-line steps toward the goal, so the point runs into walls (MuJoCo's contacts
/// push it back) and, in the teleport maze, onto the pads. Starts, goals, positions and
/// successes are equal to Python's bit for bit.
#[test]
fn pointmaze_envs_match_python() {
    use pgser::env::pointmaze::PointMazeEnv;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pointmaze.json");
    let mazes = ["pointmaze-medium-v0", "pointmaze-large-v0", "pointmaze-giant-v0", "pointmaze-teleport-v0"];
    let args = ["pointmaze", "--mazes", &mazes.join(","), "--seeds", "0,1,7", "--steps", "200"];
    common::py_ok("env_parity.py", &[&args[..], &["--out", path.to_str().unwrap()]].concat());
    let runs: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    for maze in mazes {
        let mut env = PointMazeEnv::new(maze).unwrap();
        let (mut steps, mut contacts, mut jumps, mut successes) = (0, 0, 0, 0);
        for seed in [0u64, 1, 7] {
            let episodes = runs[maze][seed.to_string()].as_array().unwrap();
            env.seed(seed);
            for (k, ep) in episodes.iter().enumerate() {
                let task = ep["task_id"].as_u64().unwrap() as usize;
                let obs = env.reset_task(if k == 0 { Some(task) } else { None });
                assert_eq!(env.task_id(), task, "{maze} seed {seed} episode {k}: task");
                assert!(same_bits(&obs.observation, &floats(&ep["reset"])), "{maze} seed {seed} episode {k}: start");
                assert!(same_bits(&env.goal(), &floats(&ep["goal"])), "{maze} seed {seed} episode {k}: goal");
                let mut last = obs.observation;
                for (t, want) in ep["steps"].as_array().unwrap().iter().enumerate() {
                    let action = floats(&want["action"]);
                    let s = env.step(&action);
                    let o = &s.obs.observation;
                    assert!(
                        same_bits(o, &floats(&want["obs"])),
                        "{maze} seed {seed} episode {k} step {t}: {o:?} vs {:?}",
                        floats(&want["obs"])
                    );
                    assert_eq!(
                        s.success,
                        want["success"].as_bool().unwrap(),
                        "{maze} seed {seed} episode {k} step {t}: success"
                    );
                    let moved = ((o[0] - last[0]).powi(2) + (o[1] - last[1]).powi(2)).sqrt();
                    let free = 0.2 * (action[0].powi(2) + action[1].powi(2)).sqrt();
                    contacts += usize::from((moved - free).abs() > 1e-6 && moved < 1.0);
                    jumps += usize::from(moved > 1.0);
                    successes += usize::from(s.success);
                    steps += 1;
                    last = o.clone();
                }
            }
        }
        println!(
            "{maze:<22} {steps} steps equal to Python's: {contacts} touched a wall, {jumps} teleports, {successes} at the goal"
        );
        assert!(contacts > 0, "{maze}: no step ran into a wall; the replay checks nothing of MuJoCo");
        if maze.contains("teleport") {
            assert!(jumps > 0, "{maze}: no teleport happened");
        }
    }
}
