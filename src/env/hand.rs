//! The Shadow Hand in-hand manipulation tasks of gymnasium-robotics 1.4.2 that the paper uses,
//! `HandManipulateBlockRotateZ-v1` and `HandManipulateEggRotate-v1`
//! (`envs/shadow_dexterous_hand/manipulate.py`, `hand_env.py`, `envs/robot_env.py`), ported
//! call for call onto MuJoCo 3.17.0 like the Fetch tasks (docs/domain.md).
//!
//! What makes these differ from Fetch, and must be kept to stay equal to Python:
//! * reset does **not** call `mj_resetData`: time, qpos and qvel go back to their initial values,
//!   but controls, warm-start accelerations and everything else carry over from the previous
//!   episode;
//! * the object's start pose is drawn (a rotation, then Gaussian position noise from numpy's
//!   ziggurat, [`crate::nprandom::ziggurat`]), the hand holds still for 10 × 20 steps, and the reset is
//!   redrawn until the object rests above the palm;
//! * actions are absolute: each of the 20 values maps [−1, 1] onto its actuator's control range;
//! * only the rotation counts (`target_position = "ignore"`): success is a rotation distance
//!   below 0.1 rad ([`crate::task::GoalMetric::QuatAngle`]).

use std::f64::consts::PI;
use std::path::Path;

use anyhow::{Result, anyhow, bail, ensure};
use mujoco_rs::prelude::*;

use super::{GoalEnv, Obs, Step, asset};
use crate::nprandom::NpRandom;
use crate::nprandom::ziggurat::{self, Ziggurat};
use crate::task::Task;

/// The tasks this module simulates, by their pgser names.
pub const TASKS: [&str; 2] = ["HandManipulateBlockRotateZ", "HandManipulateEggRotate"];

/// MuJoCo steps per environment step (`n_substeps`).
const N_SUBSTEPS: usize = 20;
/// `_reset_sim`'s settling: this many zero-action steps of `N_SUBSTEPS`.
const SETTLE_STEPS: usize = 10;
/// `is_on_palm`: the object's centre must end the settling above this height (m).
const PALM_HEIGHT: f64 = 0.04;
/// Standard deviation of the start-position noise (`normal(size=3, scale=0.005)`).
const POSITION_NOISE: f64 = 0.005;

/// `target_rotation` of the two tasks (both have `target_position = "ignore"`).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Rotation {
    /// About the vertical axis only (BlockRotateZ).
    Z,
    /// About a random axis (EggRotate).
    Xyz,
}

fn config(task: &str) -> Option<(&'static str, Rotation)> {
    match task {
        "HandManipulateBlockRotateZ" => Some(("hand/manipulate_block.xml", Rotation::Z)),
        "HandManipulateEggRotate" => Some(("hand/manipulate_egg.xml", Rotation::Xyz)),
        _ => None,
    }
}

/// √(x·x) as numpy's `linalg.norm` computes it for a small vector here: OpenBLAS's `ddot`, whose
/// tail loop (all of a 3- or 4-vector) accumulates one element after another. Whether each step
/// is one fused multiply-add depends on the kernel OpenBLAS picks for the CPU at run time: the
/// SkylakeX one (AVX-512; its C is compiled for that CPU, so the compiler fuses) does, the
/// Haswell one (AVX2 CPUs, Intel or AMD Zen without AVX-512) does not. The two differ in the last
/// bit for ~10 % of vectors, and an episode's contacts amplify that, so the environment follows
/// the kernel numpy would use on the same CPU ([`blas_dot_fuses`]); tests/env_parity.rs checks
/// it against numpy on the machine it runs on.
fn norm(x: &[f64]) -> f64 {
    if blas_dot_fuses() {
        x.iter().fold(0.0f64, |acc, &v| v.mul_add(v, acc)).sqrt()
    } else {
        x.iter().fold(0.0f64, |acc, &v| acc + v * v).sqrt()
    }
}

/// Whether numpy's OpenBLAS (DYNAMIC_ARCH, as in numpy's wheels) runs its SkylakeX `ddot` on this
/// CPU: it does where AVX-512 F, BW, DQ and VL are all there (measured on an AMD EPYC without
/// them: OpenBLAS reports `Core: Haswell` and numpy's norm is the unfused sum for 20,000 of 20,000
/// random 3- and 4-vectors, the fused one for 17,738). Elsewhere than x86_64 the fused sum is kept.
///
/// `OPENBLAS_CORETYPE`, when set, overrides OpenBLAS's own choice, and so ours: some machines set
/// it to `Haswell` because older OpenBLAS builds misbehave on their AVX-512 (an AMD EPYC with
/// AVX-512 and `OPENBLAS_CORETYPE=Haswell`, 2026-11-27: numpy's norm was the unfused sum, and
/// env_parity failed at episode 1's reset until this was read). Only OpenBLAS's AVX-512 cores
/// (SkylakeX, CooperLake, SapphireRapids) fuse.
fn blas_dot_fuses() -> bool {
    static FUSES: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *FUSES.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            if let Some(core) = std::env::var("OPENBLAS_CORETYPE").ok().filter(|c| !c.is_empty()) {
                return matches!(core.to_ascii_lowercase().as_str(), "skylakex" | "cooperlake" | "sapphirerapids");
            }
            std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512dq")
                && std::arch::is_x86_feature_detected!("avx512vl")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            true
        }
    })
}

/// `rotations.quat_mul` (w, x, y, z), term order kept.
fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    let [w0, x0, y0, z0] = a;
    let [w1, x1, y1, z1] = b;
    [
        w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
        w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
        w0 * y1 + y0 * w1 + z0 * x1 - x0 * z1,
        w0 * z1 + z0 * w1 + x0 * y1 - y0 * x1,
    ]
}

/// `manipulate.quat_from_angle_and_axis`: the axis normalised, then the quaternion.
fn quat_from_angle_and_axis(angle: f64, axis: [f64; 3]) -> [f64; 4] {
    let n = norm(&axis);
    let axis = axis.map(|v| v / n);
    let (c, s) = ((angle / 2.0).cos(), (angle / 2.0).sin());
    normalized([c, s * axis[0], s * axis[1], s * axis[2]])
}

fn normalized(q: [f64; 4]) -> [f64; 4] {
    let n = norm(&q);
    q.map(|v| v / n)
}

/// Model indices looked up once, by the names the Python code uses.
struct Ids {
    /// qpos and qvel addresses of `object:joint` (free: 7 and 6 wide).
    object_qpos: usize,
    object_qvel: usize,
    /// The `object:center` site, whose height decides whether a reset succeeded.
    center_site: usize,
    /// (qpos, qvel) address of each joint named `robot*`, in id order (`robot_get_obs`).
    robot: Vec<(usize, usize)>,
}

/// One hand task: a MuJoCo model and data, its goal, and numpy's generator for resets.
pub struct HandEnv {
    task: Task,
    rotation: Rotation,
    data: MjData<Box<MjModel>>,
    ids: Ids,
    /// Per actuator: the middle and half-width of its control range, and the range itself.
    ctrl_center: Vec<f64>,
    ctrl_half: Vec<f64>,
    ctrl_range: Vec<[f64; 2]>,
    /// `initial_time`, `initial_qpos`, `initial_qvel` after `_env_setup`.
    init: (f64, Vec<f64>, Vec<f64>),
    rng: NpRandom,
    zig: &'static Ziggurat,
    goal: [f64; 7],
    /// The integration state (everything `mj_step` reads: time, qpos, qvel, controls, warm
    /// starts, …) as `gym.make` leaves it, for [`GoalEnv::restart`]. A state, not a copy of the
    /// whole `MjData`: that would double the ~20 MB each environment holds.
    pristine: Box<[f64]>,
}

fn id(model: &MjModel, kind: MjtObjBase, name: &str) -> Result<usize> {
    model.name_to_id(kind, name).ok_or_else(|| anyhow!("the hand model has no {kind:?} named {name}"))
}

impl HandEnv {
    /// Load `task`'s model from `assets` (a `gymnasium_robotics/envs/assets` folder) and run
    /// `_env_setup` (no initial joint values for these tasks: one `mj_forward`).
    pub fn new(task: &str, assets: &Path) -> Result<HandEnv> {
        let (Some((xml, rotation)), Some(t)) = (config(task), Task::known(task)) else {
            bail!("{task}: no hand environment for this task (pgser simulates {})", TASKS.join(", "));
        };
        let zig = ziggurat::tables()?;
        let path = asset(assets, xml)?;
        let model = MjModel::from_xml(&path).map_err(|e| anyhow!("loading {}: {e:?}", path.display()))?;
        // Python's reset sets `act` to NaN when the model has activations; these have none.
        ensure!(model.ffi().na == 0, "{}: actuators with activation state are not supported", path.display());
        let ids = Self::lookup(&model)?;
        ensure!(
            ids.robot.len() == 24 && model.ffi().nu == 20,
            "{}: not the 24-joint, 20-actuator Shadow Hand",
            path.display()
        );
        let ctrl_range: Vec<[f64; 2]> = model.actuator_ctrlrange().to_vec();
        let ctrl_center = ctrl_range.iter().map(|r| (r[1] + r[0]) / 2.0).collect();
        let ctrl_half = ctrl_range.iter().map(|r| (r[1] - r[0]) / 2.0).collect();
        let mut data = MjData::new(Box::new(model));
        data.forward();
        let init = (data.time(), data.qpos().to_vec(), data.qvel().to_vec());
        let rng = NpRandom::new(0);
        let pristine = data.state(MjtState::mjSTATE_INTEGRATION as u32);
        let goal = [0.0; 7];
        Ok(HandEnv { task: t, rotation, data, ids, ctrl_center, ctrl_half, ctrl_range, init, rng, zig, goal, pristine })
    }

    fn lookup(m: &MjModel) -> Result<Ids> {
        const JOINT: MjtObjBase = MjtObjBase::mjOBJ_JOINT;
        let object = id(m, JOINT, "object:joint")?;
        ensure!(m.jnt_type()[object] == MjtJoint::mjJNT_FREE, "object:joint is not a free joint");
        let robot = (0..m.ffi().njnt as usize)
            .filter(|&j| m.id_to_name(JOINT, j).is_some_and(|n| n.starts_with("robot")))
            .map(|j| {
                ensure!(
                    matches!(m.jnt_type()[j], MjtJoint::mjJNT_HINGE | MjtJoint::mjJNT_SLIDE),
                    "robot joint {j} is not 1-dof"
                );
                Ok((m.jnt_qposadr()[j] as usize, m.jnt_dofadr()[j] as usize))
            })
            .collect::<Result<_>>()?;
        Ok(Ids {
            object_qpos: m.jnt_qposadr()[object] as usize,
            object_qvel: m.jnt_dofadr()[object] as usize,
            center_site: id(m, MjtObjBase::mjOBJ_SITE, "object:center")?,
            robot,
        })
    }

    pub fn goal(&self) -> [f64; 7] {
        self.goal
    }

    /// Simulation time (Python's `data.time`).
    pub fn time(&self) -> f64 {
        self.data.time()
    }

    /// A random rotation as the task draws one: an angle in [−π, π), then (EggRotate) an axis.
    fn sample_rotation(&mut self) -> [f64; 4] {
        let angle = self.rng.uniform(-PI, PI);
        let axis = match self.rotation {
            Rotation::Z => [0.0, 0.0, 1.0],
            Rotation::Xyz => self.rng.uniform_n(-1.0, 1.0),
        };
        quat_from_angle_and_axis(angle, axis)
    }

    /// `_set_action`: absolute control, `center + a · half-range`, clipped to the range.
    fn set_action(&mut self, action: &[f64]) {
        for (i, &a) in action.iter().enumerate() {
            let [lo, hi] = self.ctrl_range[i];
            self.data.ctrl_mut()[i] = (self.ctrl_center[i] + a * self.ctrl_half[i]).max(lo).min(hi);
        }
    }

    /// `MujocoManipulateEnv._reset_sim`: one attempt; false when the object fell off the palm.
    fn reset_sim(&mut self) -> bool {
        // No mj_resetData here (unlike Fetch): only these three go back.
        self.data.set_time(self.init.0);
        self.data.qpos_mut().copy_from_slice(&self.init.1);
        self.data.qvel_mut().copy_from_slice(&self.init.2);
        self.data.forward();
        let o = self.ids.object_qpos;
        let start: [f64; 7] = self.data.qpos()[o..o + 7].try_into().unwrap();
        let mut pos = [start[0], start[1], start[2]];
        let offset = self.sample_rotation();
        let quat = quat_mul([start[3], start[4], start[5], start[6]], offset);
        for p in &mut pos {
            *p += self.zig.normal(&mut self.rng, 0.0, POSITION_NOISE);
        }
        let quat = normalized(quat);
        self.data.qpos_mut()[o..o + 7].copy_from_slice(&[pos[0], pos[1], pos[2], quat[0], quat[1], quat[2], quat[3]]);
        let zero = [0.0; 20];
        for _ in 0..SETTLE_STEPS {
            self.set_action(&zero);
            for _ in 0..N_SUBSTEPS {
                self.data.step();
            }
        }
        self.data.forward();
        self.data.site_xpos()[self.ids.center_site][2] > PALM_HEIGHT
    }

    /// `_sample_goal`: the object's position (ignored by the metric) and a random rotation.
    fn sample_goal(&mut self) -> [f64; 7] {
        let o = self.ids.object_qpos;
        let pos: [f64; 3] = self.data.qpos()[o..o + 3].try_into().unwrap();
        let q = normalized(self.sample_rotation());
        [pos[0], pos[1], pos[2], q[0], q[1], q[2], q[3]]
    }

    /// `_get_obs` (61): 24 robot joint positions, 24 velocities, the object's 6 velocities and
    /// its 7-value pose, which is also the achieved goal.
    fn obs(&self) -> Obs {
        let (qpos, qvel) = (self.data.qpos(), self.data.qvel());
        let (o, v) = (self.ids.object_qpos, self.ids.object_qvel);
        let mut obs = Vec::with_capacity(self.task.obs_dim);
        obs.extend(self.ids.robot.iter().map(|&(p, _)| qpos[p]));
        obs.extend(self.ids.robot.iter().map(|&(_, d)| qvel[d]));
        obs.extend_from_slice(&qvel[v..v + 6]);
        obs.extend_from_slice(&qpos[o..o + 7]);
        debug_assert_eq!(obs.len(), self.task.obs_dim);
        Obs { observation: obs, achieved_goal: qpos[o..o + 7].to_vec(), desired_goal: self.goal.to_vec() }
    }
}

impl GoalEnv for HandEnv {
    fn task(&self) -> &Task {
        &self.task
    }

    fn reset(&mut self, seed: Option<u64>) -> Obs {
        if let Some(s) = seed {
            self.rng = NpRandom::new(s);
        }
        while !self.reset_sim() {}
        self.goal = self.sample_goal();
        self.obs()
    }

    /// Back to the state `new` left (controls, warm starts, everything), then `reset(seed)`.
    fn restart(&mut self, seed: u64) -> Obs {
        self.data
            .set_state(&self.pristine, MjtState::mjSTATE_INTEGRATION as u32)
            .expect("the state was taken from this model");
        self.reset(Some(seed))
    }

    fn step(&mut self, action: &[f64]) -> Step {
        assert_eq!(action.len(), 20, "{} takes 20 action values, got {}", self.task.name, action.len());
        let a: Vec<f64> = action.iter().map(|&v| super::applied_action(v) as f64).collect();
        self.set_action(&a);
        for _ in 0..N_SUBSTEPS {
            self.data.step();
        }
        Step::of(&self.task, self.obs())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_helpers_follow_gymnasium() {
        // A quarter turn about z, composed twice, is a half turn.
        let q = quat_from_angle_and_axis(PI / 2.0, [0.0, 0.0, 2.0]);
        let h = quat_mul(q, q);
        assert!((h[0]).abs() < 1e-15 && (h[3] - 1.0).abs() < 1e-15, "{h:?}");
        assert_eq!(norm(&[3.0, 4.0]), 5.0);
        let n = normalized([1.0, 1.0, 1.0, 1.0]);
        assert_eq!(n, [0.5; 4]);
    }

    #[test]
    fn resets_rest_the_object_on_the_palm_and_goals_are_unit_rotations() {
        for task in TASKS {
            let mut env = HandEnv::new(task, &super::super::assets_dir()).unwrap();
            for seed in 0..3 {
                let obs = env.reset(Some(seed));
                assert_eq!(obs.observation.len(), 61);
                let g = env.goal();
                assert!((norm(&g[3..]) - 1.0).abs() < 1e-12, "{task}: goal quaternion {g:?}");
                assert!(env.data.site_xpos()[env.ids.center_site][2] > PALM_HEIGHT);
                let s = env.step(&[0.0; 20]);
                assert_eq!(s.reward, if s.success { 0.0 } else { -1.0 });
            }
        }
    }
}
