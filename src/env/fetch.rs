//! The Fetch v4 tasks of gymnasium-robotics 1.4.2 (`envs/fetch/fetch_env.py` and one file per
//! task, `envs/robot_env.py`, `utils/mujoco_utils.py`), ported call for call onto MuJoCo 3.17.0.
//!
//! Every MuJoCo call the Python environment makes is made here in the same order with the same
//! inputs, down to the float32 rounding of the action and the stale kinematics an unblocked
//! gripper leaves after `mj_step`: that is what keeps positions equal to Python's bit for bit
//! (docs/domain.md). Python helper names are kept in comments so the two can be read side by side.

use std::path::Path;

use anyhow::{Context, Result, anyhow, bail, ensure};
use mujoco_rs::prelude::*;

use super::{GoalEnv, Obs, Step, asset};
use crate::nprandom::NpRandom;
use crate::task::Task;

/// The tasks this module simulates, by their pgser (gymnasium id minus version) names.
pub const TASKS: [&str; 4] = ["FetchReach", "FetchPush", "FetchPickAndPlace", "FetchSlide"];

/// MuJoCo steps per environment step (`n_substeps`, all Fetch tasks).
const N_SUBSTEPS: usize = 20;
/// `_set_action`'s fixed end-effector rotation, added to the body quaternion as is.
const ROT_CTRL: [f64; 4] = [1.0, 0.0, 1.0, 0.0];

/// The constructor arguments each task file passes to `MujocoFetchEnv.__init__`.
struct Config {
    xml: &'static str,
    initial_qpos: &'static [(&'static str, &'static [f64])],
    has_object: bool,
    block_gripper: bool,
    gripper_extra_height: f64,
    target_in_the_air: bool,
    target_offset: [f64; 3],
    obj_range: f64,
    target_range: f64,
}

const OBJECT_QPOS: (&str, &[f64]) = ("object0:joint", &[1.25, 0.53, 0.4, 1.0, 0.0, 0.0, 0.0]);

fn config(task: &str) -> Option<Config> {
    let base = Config {
        xml: "fetch/push.xml",
        initial_qpos: &[
            ("robot0:slide0", &[0.405]),
            ("robot0:slide1", &[0.48]),
            ("robot0:slide2", &[0.0]),
            OBJECT_QPOS,
        ],
        has_object: true,
        block_gripper: true,
        gripper_extra_height: 0.0,
        target_in_the_air: false,
        target_offset: [0.0; 3],
        obj_range: 0.15,
        target_range: 0.15,
    };
    Some(match task {
        "FetchPush" => base,
        "FetchReach" => Config {
            xml: "fetch/reach.xml",
            initial_qpos: &[("robot0:slide0", &[0.4049]), ("robot0:slide1", &[0.48]), ("robot0:slide2", &[0.0])],
            has_object: false,
            gripper_extra_height: 0.2,
            target_in_the_air: true,
            ..base
        },
        "FetchPickAndPlace" => Config {
            xml: "fetch/pick_and_place.xml",
            block_gripper: false,
            gripper_extra_height: 0.2,
            target_in_the_air: true,
            ..base
        },
        "FetchSlide" => Config {
            xml: "fetch/slide.xml",
            initial_qpos: &[
                ("robot0:slide0", &[0.05]),
                ("robot0:slide1", &[0.48]),
                ("robot0:slide2", &[0.0]),
                ("object0:joint", &[1.7, 1.1, 0.41, 1.0, 0.0, 0.0, 0.0]),
            ],
            gripper_extra_height: -0.02,
            target_offset: [0.4, 0.0, 0.0],
            obj_range: 0.1,
            target_range: 0.3,
            ..base
        },
        _ => return None,
    })
}

/// Model indices looked up once, by the names the Python code uses.
struct Ids {
    grip_site: usize,
    /// Site and free-joint qpos address of `object0`, for tasks with an object.
    object: Option<(usize, usize)>,
    /// qpos addresses `_step_callback` zeroes when the gripper is blocked.
    fingers: [usize; 2],
    /// (qpos, qvel) addresses of the last two `robot*` joints: `robot_get_obs(...)[-2:]`.
    gripper_state: [(usize, usize); 2],
    /// (mocap id, welded body) per weld, as `reset_mocap2body_xpos` pairs them.
    welds: Vec<(usize, usize)>,
    /// Per actuator, as `ctrl_set_action` treats it: `None` sets ctrl to the action, `Some(adr)`
    /// (a biased, i.e. position, actuator) to `qpos[adr]` + the action.
    actuators: Vec<Option<usize>>,
}

/// The state `_initialize_simulation` records after `_env_setup`; every reset returns to it.
struct Initial {
    time: f64,
    qpos: Vec<f64>,
    qvel: Vec<f64>,
    gripper_xpos: [f64; 3],
    height_offset: f64,
}

/// One Fetch task: a MuJoCo model and data, its goal, and numpy's generator for resets.
pub struct FetchEnv {
    task: Task,
    cfg: Config,
    data: MjData<Box<MjModel>>,
    ids: Ids,
    init: Initial,
    rng: NpRandom,
    goal: [f64; 3],
    /// `n_substeps * opt.timestep`, the factor on every velocity in the observation.
    dt: f64,
}

fn id(model: &MjModel, kind: MjtObjBase, name: &str) -> Result<usize> {
    model.name_to_id(kind, name).ok_or_else(|| anyhow!("the Fetch model has no {kind:?} named {name}"))
}

/// Width of a joint's qpos slice, as `mujoco_utils.set_joint_qpos` sizes it.
fn qpos_width(model: &MjModel, joint: usize) -> usize {
    match model.jnt_type()[joint] {
        MjtJoint::mjJNT_FREE => 7,
        MjtJoint::mjJNT_BALL => 4,
        _ => 1,
    }
}

impl FetchEnv {
    /// Load `task`'s model from `assets` (a `gymnasium_robotics/envs/assets` folder) and run
    /// `_env_setup`, as `gym.make` does.
    pub fn new(task: &str, assets: &Path) -> Result<FetchEnv> {
        let (Some(cfg), Some(t)) = (config(task), Task::known(task)) else {
            bail!("{task}: no environment for this task (pgser simulates {})", TASKS.join(", "));
        };
        let path = asset(assets, cfg.xml)?;
        let mut model = MjModel::from_xml(&path).map_err(|e| anyhow!("loading {}: {e:?}", path.display()))?;
        // reset_mocap_welds, model half: weld anchors and relative poses to identity, so the
        // weld pulls the gripper onto the mocap body. Python does it after setting initial_qpos
        // on the data; eq_data only matters from the next mj_forward on, so order is immaterial.
        if model.ffi().nmocap > 0 {
            for i in 0..model.ffi().neq as usize {
                if model.eq_type()[i] == MjtEq::mjEQ_WELD {
                    // SAFETY: plain numbers; no MjData exists yet to be invalidated by the change.
                    let eq_data = unsafe { model.eq_data_mut() };
                    eq_data[i][..7].copy_from_slice(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
                }
            }
        }
        let ids = Self::lookup(&model, &cfg)?;
        let dt = N_SUBSTEPS as f64 * model.opt().timestep;
        let mut data = MjData::new(Box::new(model));
        Self::setup(&mut data, &cfg, &ids)?;
        let site = data.site_xpos();
        let init = Initial {
            time: data.time(),
            qpos: data.qpos().to_vec(),
            qvel: data.qvel().to_vec(),
            gripper_xpos: site[ids.grip_site],
            height_offset: ids.object.map_or(0.0, |(s, _)| site[s][2]),
        };
        let rng = NpRandom::new(0);
        Ok(FetchEnv { task: t, cfg, data, ids, init, rng, goal: [0.0; 3], dt })
    }

    fn lookup(m: &MjModel, cfg: &Config) -> Result<Ids> {
        const JOINT: MjtObjBase = MjtObjBase::mjOBJ_JOINT;
        const SITE: MjtObjBase = MjtObjBase::mjOBJ_SITE;
        let joint_qpos = |name: &str| -> Result<usize> { Ok(m.jnt_qposadr()[id(m, JOINT, name)?] as usize) };
        let object = if cfg.has_object { Some((id(m, SITE, "object0")?, joint_qpos("object0:joint")?)) } else { None };
        // robot_get_obs: joints named robot*, in id order; the gripper state is the last two.
        let robot: Vec<usize> = (0..m.ffi().njnt as usize)
            .filter(|&j| m.id_to_name(JOINT, j).is_some_and(|n| n.starts_with("robot")))
            .collect();
        ensure!(robot.len() >= 2, "the Fetch model has fewer than two robot joints");
        let last2 = [robot[robot.len() - 2], robot[robot.len() - 1]];
        ensure!(last2.iter().all(|&j| qpos_width(m, j) == 1), "the gripper joints are not 1-dof");
        let gripper_state = last2.map(|j| (m.jnt_qposadr()[j] as usize, m.jnt_dofadr()[j] as usize));
        let mut welds = Vec::new();
        for i in 0..m.ffi().neq as usize {
            if m.eq_type()[i] != MjtEq::mjEQ_WELD {
                continue;
            }
            let (b1, b2) = (m.eq_obj1id()[i] as usize, m.eq_obj2id()[i] as usize);
            let (mocap, body) = match m.body_mocapid()[b1] {
                -1 => (m.body_mocapid()[b2], b1),
                mid => (mid, b2),
            };
            ensure!(mocap >= 0, "weld {i} joins no mocap body");
            welds.push((mocap as usize, body));
        }
        let actuators = (0..m.ffi().nu as usize)
            .map(|i| match m.actuator_biastype()[i] {
                MjtBias::mjBIAS_NONE => None,
                _ => Some(m.jnt_qposadr()[m.actuator_trnid()[i][0] as usize] as usize),
            })
            .collect();
        Ok(Ids {
            grip_site: id(m, SITE, "robot0:grip")?,
            object,
            fingers: [joint_qpos("robot0:l_gripper_finger_joint")?, joint_qpos("robot0:r_gripper_finger_joint")?],
            gripper_state,
            welds,
            actuators,
        })
    }

    /// `_env_setup`: initial joint positions, then drive the mocap to the start pose for
    /// 10 × `n_substeps` steps.
    fn setup(data: &mut MjData<Box<MjModel>>, cfg: &Config, ids: &Ids) -> Result<()> {
        for &(name, value) in cfg.initial_qpos {
            let m = data.model();
            let j = id(m, MjtObjBase::mjOBJ_JOINT, name)?;
            ensure!(qpos_width(m, j) == value.len(), "initial qpos for {name} has the wrong length");
            let adr = m.jnt_qposadr()[j] as usize;
            data.qpos_mut()[adr..adr + value.len()].copy_from_slice(value);
        }
        data.forward(); // reset_mocap_welds ends with mj_forward
        data.forward(); // _env_setup's own
        let g = data.site_xpos()[ids.grip_site];
        let offset = [-0.498, 0.005, -0.431 + cfg.gripper_extra_height];
        let m = data.model();
        let mocap = m.body_mocapid()[id(m, MjtObjBase::mjOBJ_BODY, "robot0:mocap")?];
        let mocap = usize::try_from(mocap).context("robot0:mocap is not a mocap body")?;
        data.mocap_pos_mut()[mocap] = std::array::from_fn(|i| offset[i] + g[i]);
        data.mocap_quat_mut()[mocap] = ROT_CTRL;
        for _ in 0..10 {
            for _ in 0..N_SUBSTEPS {
                data.step();
            }
        }
        Ok(())
    }

    /// The gripper site position after setup; goals and objects are sampled around it.
    pub fn initial_gripper_xpos(&self) -> [f64; 3] {
        self.init.gripper_xpos
    }

    /// The object's height after setup (the table top), where table goals lie; 0 for Reach.
    pub fn height_offset(&self) -> f64 {
        self.init.height_offset
    }

    pub fn goal(&self) -> [f64; 3] {
        self.goal
    }

    /// Simulation time (Python's `data.time`).
    pub fn time(&self) -> f64 {
        self.data.time()
    }

    /// `_sample_goal`. The draws and their order are gymnasium's: three uniforms, then for
    /// PickAndPlace a coin and, half the time, a height.
    fn sample_goal(&mut self) -> [f64; 3] {
        let r = self.cfg.target_range;
        let u: [f64; 3] = self.rng.uniform_n(-r, r);
        let mut goal: [f64; 3] = std::array::from_fn(|i| self.init.gripper_xpos[i] + u[i]);
        if self.cfg.has_object {
            for (g, o) in goal.iter_mut().zip(self.cfg.target_offset) {
                *g += o;
            }
            goal[2] = self.init.height_offset;
            if self.cfg.target_in_the_air && self.rng.uniform(0.0, 1.0) < 0.5 {
                goal[2] += self.rng.uniform(0.0, 0.45);
            }
        }
        goal
    }

    /// `_reset_sim` of MujocoFetchEnv (which replaces, not extends, MujocoRobotEnv's).
    fn reset_sim(&mut self) {
        self.data.reset(); // mj_resetData: also puts the mocap back at its model pose, ctrl to 0
        self.data.set_time(self.init.time);
        self.data.qpos_mut().copy_from_slice(&self.init.qpos);
        self.data.qvel_mut().copy_from_slice(&self.init.qvel);
        if let Some((_, obj_qpos)) = self.ids.object {
            let g = self.init.gripper_xpos;
            let r = self.cfg.obj_range;
            let mut xy = [g[0], g[1]];
            // Resample until the object is at least 10 cm (in xy) from the gripper. The distance
            // is of the sum minus the gripper, as Python computes it, not of the raw draw.
            while ((xy[0] - g[0]) * (xy[0] - g[0]) + (xy[1] - g[1]) * (xy[1] - g[1])).sqrt() < 0.1 {
                let u: [f64; 2] = self.rng.uniform_n(-r, r);
                xy = [g[0] + u[0], g[1] + u[1]];
            }
            self.data.qpos_mut()[obj_qpos..obj_qpos + 2].copy_from_slice(&xy);
        }
        self.data.forward();
    }

    /// `_set_action` + `ctrl_set_action` + `mocap_set_action`.
    fn set_action(&mut self, action: &[f64]) {
        // The action space is float32: gymnasium clips in float32 and scales the position part
        // in float32 (`pos_ctrl *= 0.05` on a float32 array); only then does `np.concatenate`
        // widen it to float64. A policy's actions are float32 in Python, so we round to them.
        let a: [f32; 4] = std::array::from_fn(|i| super::applied_action(action[i]));
        let pos_delta: [f64; 3] = std::array::from_fn(|i| (a[i] * 0.05f32) as f64);
        let gripper = if self.cfg.block_gripper { 0.0 } else { a[3] as f64 };
        // ctrl_set_action: the two gripper values go to the first actuators (PickAndPlace only).
        for (i, act) in self.ids.actuators.iter().enumerate().take(2) {
            let ctrl = match *act {
                None => gripper,
                Some(adr) => self.data.qpos()[adr] + gripper,
            };
            self.data.ctrl_mut()[i] = ctrl;
        }
        if self.ids.welds.is_empty() {
            return;
        }
        // reset_mocap2body_xpos: the mocap jumps to the welded body's current (possibly stale)
        // pose, then moves by the delta; the quaternion is the body's plus ROT_CTRL, unnormalised.
        for &(mocap, body) in &self.ids.welds {
            let (p, q) = (self.data.xpos()[body], self.data.xquat()[body]);
            self.data.mocap_pos_mut()[mocap] = p;
            self.data.mocap_quat_mut()[mocap] = q;
        }
        for p in self.data.mocap_pos_mut() {
            for (x, d) in p.iter_mut().zip(pos_delta) {
                *x += d;
            }
        }
        for q in self.data.mocap_quat_mut() {
            for (x, d) in q.iter_mut().zip(ROT_CTRL) {
                *x += d;
            }
        }
    }

    /// `_step_callback`: a blocked gripper's fingers are forced shut, then kinematics refreshed.
    /// PickAndPlace skips this, so its observation reads kinematics from before the last
    /// integration, exactly as Python's does.
    fn step_callback(&mut self) {
        if self.cfg.block_gripper {
            for adr in self.ids.fingers {
                self.data.qpos_mut()[adr] = 0.0;
            }
            self.data.forward();
        }
    }
}

impl GoalEnv for FetchEnv {
    fn task(&self) -> &Task {
        &self.task
    }

    fn reset(&mut self, seed: Option<u64>) -> Obs {
        if let Some(s) = seed {
            self.rng = NpRandom::new(s);
        }
        self.reset_sim();
        self.goal = self.sample_goal();
        self.obs()
    }

    fn step(&mut self, action: &[f64]) -> Step {
        assert_eq!(action.len(), 4, "{} takes 4 action values, got {}", self.task.name, action.len());
        self.set_action(action);
        for _ in 0..N_SUBSTEPS {
            self.data.step();
        }
        self.step_callback();
        Step::of(&self.task, self.obs())
    }
}

#[path = "fetch_obs.rs"]
mod obs;

#[cfg(test)]
#[path = "fetch_tests.rs"]
mod tests;
