//! The tasks pgser knows: their episode length, dimensions, and goal metric.
//!
//! Values from Farama-Foundation/Gymnasium-Robotics 1.4.2 (`envs/fetch/*.py`,
//! `envs/shadow_dexterous_hand/manipulate.py`); see docs/domain.md. A task pgser does not know can
//! still be used for data jobs: its dimensions come from the data and its success threshold from
//! the user (`Task::custom`), with the Euclidean goal metric.

use serde::{Deserialize, Serialize};

/// How the distance between an achieved and a desired goal is measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GoalMetric {
    /// ‖ag − g‖₂ (Fetch: goals are 3-D positions).
    Euclidean,
    /// Angle between the quaternions in components 3..7, position ignored (Hand *Rotate*
    /// tasks): `2·acos(clip(⟨q_a, q_b⟩, −1, 1))`, the w component of `q_a ⊗ conj(q_b)`,
    /// exactly as gymnasium-robotics' `_goal_distance` computes it (no |·|).
    QuatAngle,
    /// The goal is several objects' 3-D positions, consecutive (x, y, z) triples, and is reached
    /// when every object is within the threshold of its own: the distance is the largest of the
    /// objects' Euclidean distances (OGBench's cube tasks).
    EachObject,
    /// The largest of the values' absolute differences: reached when every value is within the
    /// threshold of its own (OGBench's puzzles: each button's state, 0 or 1, within 0.5).
    EachValue,
    /// OGBench's scene: the goal is each cube's position (x, y, z, in the observation's ×10
    /// units), then the buttons' states (0 or 1), then the drawer's and the window's positions
    /// (×18 and ×15), each part reached within its own tolerance ([`SCENE_TOLERANCES`]: 0.04 m
    /// for a cube, the drawer and the window, a button its state). The distance is the largest
    /// part's distance divided by its tolerance, so the threshold is 1 and a user's `--threshold`
    /// scales every tolerance at once. At a threshold of 1, `d / tol ≤ 1` is `d ≤ tol` exactly:
    /// for a positive tolerance that is no power of two, the next double above it divided by it
    /// is above 1 + 2⁻⁵³ and rounds above 1, and rounding keeps `d ≤ tol ⇒ d / tol ≤ 1`.
    Scene,
}

/// The tolerances of a [`GoalMetric::Scene`] goal's parts, in the units OGBench's scene
/// observation gives them: a cube within 0.04 m (0.4 at ×10), a button within 0.5 of its 0/1
/// target (its state), the drawer and the window within 0.04 m (0.72 at ×18, 0.6 at ×15), as
/// OGBench's `SceneEnv._compute_successes`.
pub const SCENE_TOLERANCES: SceneTolerances = SceneTolerances { cube: 0.4, button: 0.5, drawer: 0.72, window: 0.6 };

/// The scene's buttons: OGBench's `SceneEnv._num_buttons`.
pub const SCENE_BUTTONS: usize = 2;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneTolerances {
    pub cube: f64,
    pub button: f64,
    pub drawer: f64,
    pub window: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Task {
    pub name: String,
    /// Observations per episode (actions per episode = T − 1).
    #[serde(rename = "T")]
    pub t: usize,
    pub obs_dim: usize,
    pub goal_dim: usize,
    pub act_dim: usize,
    /// Success iff distance < threshold.
    pub threshold: f64,
    pub metric: GoalMetric,
}

/// (name, T, obs, goal, act, threshold, metric)
const KNOWN: &[(&str, usize, usize, usize, usize, f64, GoalMetric)] = &[
    ("FetchReach", 50, 10, 3, 4, 0.05, GoalMetric::Euclidean),
    ("FetchPush", 50, 25, 3, 4, 0.05, GoalMetric::Euclidean),
    ("FetchPickAndPlace", 50, 25, 3, 4, 0.05, GoalMetric::Euclidean),
    ("FetchSlide", 50, 25, 3, 4, 0.05, GoalMetric::Euclidean),
    ("HandManipulateBlockRotateZ", 100, 61, 7, 20, 0.1, GoalMetric::QuatAngle),
    ("HandManipulateEggRotate", 100, 61, 7, 20, 0.1, GoalMetric::QuatAngle),
];

impl Task {
    /// A built-in task by name. Accepts gymnasium ids with a version suffix (`FetchPush-v4`).
    pub fn known(name: &str) -> Option<Task> {
        let base = name.split_once("-v").map_or(name, |(b, _)| b);
        KNOWN.iter().find(|k| k.0.eq_ignore_ascii_case(base)).map(
            |&(name, t, obs_dim, goal_dim, act_dim, threshold, metric)| Task {
                name: name.to_string(),
                t,
                obs_dim,
                goal_dim,
                act_dim,
                threshold,
                metric,
            },
        )
    }

    /// The built-in name closest to a mistyped one (edit distance ≤ 1/3 of its length), for
    /// "did you mean" in error messages.
    pub fn suggest(name: &str) -> Option<&'static str> {
        let base = name.split_once("-v").map_or(name, |(b, _)| b).to_ascii_lowercase();
        let distance = |a: &str| {
            let (a, b): (Vec<char>, Vec<char>) = (a.to_ascii_lowercase().chars().collect(), base.chars().collect());
            let mut row: Vec<usize> = (0..=b.len()).collect();
            for (i, ca) in a.iter().enumerate() {
                let mut prev = row[0];
                row[0] = i + 1;
                for (j, cb) in b.iter().enumerate() {
                    let cur = row[j + 1];
                    row[j + 1] = (prev + usize::from(ca != cb)).min(row[j] + 1).min(cur + 1);
                    prev = cur;
                }
            }
            row[b.len()]
        };
        KNOWN.iter().map(|k| (distance(k.0), k.0)).min().filter(|&(d, _)| d > 0 && d * 3 <= base.len()).map(|(_, n)| n)
    }

    pub fn known_names() -> Vec<&'static str> {
        KNOWN.iter().map(|k| k.0).collect()
    }

    /// Built-in tasks whose dimensions and T match, for inferring a task from data.
    pub fn matching(t: usize, obs: usize, goal: usize, act: usize) -> Vec<Task> {
        KNOWN
            .iter()
            .filter_map(|k| Task::known(k.0))
            .filter(|k| (k.t, k.obs_dim, k.goal_dim, k.act_dim) == (t, obs, goal, act))
            .collect()
    }

    /// A user-defined task: dimensions from the data, Euclidean goals.
    pub fn custom(name: &str, t: usize, obs: usize, goal: usize, act: usize, threshold: f64) -> Task {
        Task {
            name: name.to_string(),
            t,
            obs_dim: obs,
            goal_dim: goal,
            act_dim: act,
            threshold,
            metric: GoalMetric::Euclidean,
        }
    }

    /// Distance between one achieved goal and one desired goal.
    pub fn distance<F: Copy + Into<f64>>(&self, ag: &[F], g: &[F]) -> f64 {
        match self.metric {
            GoalMetric::Euclidean => ag
                .iter()
                .zip(g)
                .map(|(&a, &b)| {
                    let d = a.into() - b.into();
                    d * d
                })
                .sum::<f64>()
                .sqrt(),
            GoalMetric::QuatAngle => {
                let dot: f64 = ag[3..7].iter().zip(&g[3..7]).map(|(&a, &b)| a.into() * b.into()).sum();
                2.0 * dot.clamp(-1.0, 1.0).acos()
            }
            GoalMetric::EachObject => ag
                .chunks(3)
                .zip(g.chunks(3))
                .map(|(a, b)| {
                    a.iter()
                        .zip(b)
                        .map(|(&x, &y)| {
                            let d = x.into() - y.into();
                            d * d
                        })
                        .sum::<f64>()
                        .sqrt()
                })
                .fold(0.0, f64::max),
            GoalMetric::EachValue => ag.iter().zip(g).map(|(&a, &b)| (a.into() - b.into()).abs()).fold(0.0, f64::max),
            GoalMetric::Scene => scene_distance(ag, g),
        }
    }

    pub fn success<F: Copy + Into<f64>>(&self, ag: &[F], g: &[F]) -> bool {
        self.distance(ag, g) < self.threshold
    }

    /// The paper's eq. 2 sparse reward: 0 when the goal is reached, −1 otherwise. Written as
    /// gymnasium-robotics' `compute_reward` does, `−(d > threshold)`: at exactly d = threshold
    /// the reward is 0 although `success` (d < threshold) is false, as in the Python envs.
    ///
    /// The hand tasks compute it as `success − 1` instead, so there d = threshold gives −1.
    pub fn reward<F: Copy + Into<f64>>(&self, ag: &[F], g: &[F]) -> f32 {
        let d = self.distance(ag, g);
        match self.metric {
            GoalMetric::Euclidean | GoalMetric::EachObject | GoalMetric::EachValue | GoalMetric::Scene => {
                if d > self.threshold { -1.0 } else { 0.0 }
            }
            GoalMetric::QuatAngle => {
                if d < self.threshold {
                    0.0
                } else {
                    -1.0
                }
            }
        }
    }

    /// [`Task::reward`] for many rows at once: `achieved` and `goals` hold rows of `goal_dim`
    /// values, `out` gets one reward per row. This is what goal swapping calls on whole batches
    /// of relabelled transitions (float32 from tables, float64 from the simulator), so it is one
    /// tight loop rather than a call per row; the result equals `reward` row by row.
    ///
    /// Panics if the lengths disagree (a caller bug, not a data fault).
    pub fn rewards<F: Copy + Into<f64>>(&self, achieved: &[F], goals: &[F], out: &mut [f32]) {
        let dim = self.goal_dim;
        assert!(dim > 0, "{}: goal_dim is 0", self.name);
        assert!(
            achieved.len() == goals.len() && achieved.len() == out.len() * dim,
            "rewards: {} achieved and {} goal values for {} rows of {dim}",
            achieved.len(),
            goals.len(),
            out.len()
        );
        for ((r, ag), g) in out.iter_mut().zip(achieved.chunks_exact(dim)).zip(goals.chunks_exact(dim)) {
            *r = self.reward(ag, g);
        }
    }
}

/// [`GoalMetric::Scene`]'s distance: the goal is `3·cubes` cube values, [`SCENE_BUTTONS`]
/// button states, the drawer's and the window's positions, so its width gives the cubes.
fn scene_distance<F: Copy + Into<f64>>(ag: &[F], g: &[F]) -> f64 {
    let tol = SCENE_TOLERANCES;
    let cubes = (ag.len().min(g.len())).saturating_sub(SCENE_BUTTONS + 2) / 3;
    let abs = |i: usize| (ag[i].into() - g[i].into()).abs();
    let mut d = 0.0f64;
    for c in 0..cubes {
        let sq: f64 = (3 * c..3 * c + 3)
            .map(|i| {
                let x = ag[i].into() - g[i].into();
                x * x
            })
            .sum();
        d = d.max(sq.sqrt() / tol.cube);
    }
    let buttons = 3 * cubes;
    for i in buttons..buttons + SCENE_BUTTONS {
        d = d.max(abs(i) / tol.button);
    }
    let drawer = buttons + SCENE_BUTTONS;
    d.max(abs(drawer) / tol.drawer).max(abs(drawer + 1) / tol.window)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_accepts_gym_ids() {
        assert_eq!(Task::known("FetchPush-v4").unwrap().obs_dim, 25);
        assert_eq!(Task::known("fetchreach").unwrap().name, "FetchReach");
        assert!(Task::known("PointReach").is_none());
        assert_eq!(Task::matching(50, 25, 3, 4).len(), 3);
    }

    #[test]
    fn each_object_must_be_within_the_threshold() {
        let t = Task {
            metric: GoalMetric::EachObject,
            threshold: 0.4,
            ..Task::custom("cube-double-v0", 1001, 37, 6, 5, 0.4)
        };
        let g = [0.0; 6];
        // Both cubes 0.3 away: jointly 0.42 (Euclidean would fail), each within 0.4.
        assert!((t.distance(&[0.3, 0.0, 0.0, 0.0, 0.3, 0.0], &g) - 0.3).abs() < 1e-15);
        assert_eq!(t.reward(&[0.3, 0.0, 0.0, 0.0, 0.3, 0.0], &g), 0.0);
        assert_eq!(t.reward(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.5], &g), -1.0);
        assert!(t.success(&[0.1, 0.1, 0.1, 0.0, 0.0, 0.0], &g));
    }

    #[test]
    fn each_value_must_be_within_the_threshold() {
        let t = Task { metric: GoalMetric::EachValue, ..Task::custom("puzzle-3x3-v0", 1001, 51, 9, 5, 0.5) };
        let g = [1.0, 0.0, 1.0];
        assert_eq!(t.distance(&[1.0, 0.0, 1.0], &g), 0.0);
        assert!(t.success(&[1.0, 0.0, 1.0], &g) && t.reward(&[1.0, 0.0, 1.0], &g) == 0.0);
        // One button off: distance 1, however many are right.
        assert_eq!(t.distance(&[1.0, 1.0, 1.0], &g), 1.0);
        assert!(!t.success(&[1.0, 1.0, 1.0], &g) && t.reward(&[1.0, 1.0, 1.0], &g) == -1.0);
    }

    /// Each part of a scene goal within its own tolerance, on the boundary to the bit: a part
    /// exactly at its tolerance is reached, one ulp beyond is not, and one part off is enough.
    #[test]
    fn scene_parts_each_within_their_tolerance() {
        let t = Task { metric: GoalMetric::Scene, ..Task::custom("scene-v0", 751, 40, 7, 5, 1.0) };
        let g = [0.0f64; 7];
        let up = |x: f64| f64::from_bits(x.to_bits() + 1);
        let tol = SCENE_TOLERANCES;
        // (index, tolerance): the cube along x, a button, the drawer, the window.
        for (i, at) in [(0, tol.cube), (4, tol.button), (5, tol.drawer), (6, tol.window)] {
            let mut a = g;
            a[i] = at;
            assert_eq!(t.reward(&a, &g), 0.0, "part {i} at its tolerance {at}");
            a[i] = up(at);
            assert_eq!(t.reward(&a, &g), -1.0, "part {i} one ulp beyond {at}");
            a[i] = -at;
            assert_eq!(t.reward(&a, &g), 0.0, "part {i} at minus its tolerance");
        }
        // The cube is measured in 3-D: 0.3 along two axes is 0.42, beyond 0.4; the drawer's 0.7
        // is within its 0.72 though beyond the cube's 0.4.
        assert_eq!(t.reward(&[0.3, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0], &g), -1.0);
        assert_eq!(t.reward(&[0.3, 0.0, 0.0, 0.0, 0.0, 0.7, 0.5], &g), 0.0);
        // A button in the other state is never reached, whatever else is.
        assert_eq!(t.reward(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], &g), -1.0);
        assert!((t.distance(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.36, 0.0], &g) - 0.5).abs() < 1e-15);
        // Two cubes: the second cube's values come before the buttons.
        let t2 = Task { goal_dim: 10, ..t.clone() };
        let mut a = [0.0f64; 10];
        a[5] = 0.41;
        assert_eq!(t2.reward(&a, &[0.0; 10]), -1.0);
        a[5] = 0.0;
        a[6] = 1.0;
        assert_eq!(t2.reward(&a, &[0.0; 10]), -1.0);
        a[6] = 0.0;
        a[8] = 0.7;
        assert_eq!(t2.reward(&a, &[0.0; 10]), 0.0);
    }

    #[test]
    fn fetch_reward_is_thresholded_distance() {
        let t = Task::known("FetchReach").unwrap();
        assert_eq!(t.reward(&[0.0, 0.0, 0.0], &[0.03, 0.03, 0.0]), 0.0); // 0.0424 < 0.05
        assert_eq!(t.reward(&[0.0, 0.0, 0.0], &[0.04, 0.04, 0.0]), -1.0); // 0.0566
        // Exactly on the threshold: reward 0 (−(d > thr)) yet not a success (d < thr).
        assert_eq!(t.reward(&[0.0, 0.0, 0.0], &[0.05, 0.0, 0.0]), 0.0);
        assert!(!t.success(&[0.0, 0.0, 0.0], &[0.05, 0.0, 0.0]));
    }

    #[test]
    fn batched_rewards_equal_the_per_row_reward() {
        // Rows straddling the threshold, including exactly on it, in both float widths.
        let t = Task::known("FetchPush").unwrap();
        let n = 257;
        let ag: Vec<f64> = (0..n * 3).map(|i| (i as f64 * 0.37).sin() * 0.1).collect();
        let g: Vec<f64> = (0..n * 3).map(|i| (i as f64 * 0.11).cos() * 0.1).collect();
        let mut out = vec![9.0f32; n];
        t.rewards(&ag, &g, &mut out);
        for (r, (a, b)) in out.iter().zip(ag.chunks(3).zip(g.chunks(3))) {
            assert_eq!(*r, t.reward(a, b));
        }
        assert!(out.contains(&0.0) && out.contains(&-1.0));
        let (ag32, g32): (Vec<f32>, Vec<f32>) =
            (ag.iter().map(|&x| x as f32).collect(), g.iter().map(|&x| x as f32).collect());
        t.rewards(&ag32, &g32, &mut out);
        for (r, (a, b)) in out.iter().zip(ag32.chunks(3).zip(g32.chunks(3))) {
            assert_eq!(*r, t.reward(a, b));
        }
        let mut edge = [1.0f32];
        t.rewards(&[0.0, 0.0, 0.0], &[0.05, 0.0, 0.0], &mut edge);
        assert_eq!(edge, [0.0]);
        let hand = Task::known("HandManipulateEggRotate").unwrap();
        let (a, b) = ([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]);
        let mut two = [0.0f32; 2];
        hand.rewards(&[a, a].concat(), &[a, b].concat(), &mut two);
        assert_eq!(two, [0.0, -1.0]);
    }

    #[test]
    #[should_panic(expected = "rows of 3")]
    fn batched_rewards_check_lengths() {
        Task::known("FetchReach").unwrap().rewards(&[0.0f32; 6], &[0.0f32; 6], &mut [0.0; 3]);
    }

    #[test]
    fn quaternion_angle_ignores_position() {
        let t = Task::known("HandManipulateEggRotate").unwrap();
        let half = 0.04f64; // rotation of 0.08 rad about z
        let a = [9.0, 9.0, 9.0, 1.0, 0.0, 0.0, 0.0];
        let b = [0.0, 0.0, 0.0, half.cos(), 0.0, 0.0, half.sin()];
        assert!((t.distance(&a, &b) - 0.08).abs() < 1e-12);
        assert!(t.success(&a, &b));
    }
}
