//! Goal-conditioned simulation environments: the gymnasium-robotics 1.4.2 Fetch v4 tasks and the
//! two Shadow Hand v1 tasks of the paper (BlockRotateZ, EggRotate) on MuJoCo 3.17.0
//! (docs/domain.md, tasks).
//!
//! They exist so pgser can collect trajectories and evaluate policies without Python. Being a
//! port and not a look-alike is the point: with the same MuJoCo library, the same seed and the
//! same actions, an episode here equals the Python one (positions bit for bit;
//! `tests/env_parity.rs` checks it), so data and scores from either side are interchangeable.

pub mod expert;
pub mod fetch;
pub mod hand;
pub mod pointmaze;

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

use crate::task::Task;

/// One observation, split as gymnasium's goal environments split it.
#[derive(Debug, Clone, PartialEq)]
pub struct Obs {
    pub observation: Vec<f64>,
    pub achieved_goal: Vec<f64>,
    pub desired_goal: Vec<f64>,
}

/// What `step` returns. Fetch tasks never terminate on their own; episodes end by length
/// ([`Task::t`]), so there is no `terminated`/`truncated`.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    pub obs: Obs,
    /// [`Task::reward`]: 0 when the goal is reached, −1 otherwise.
    pub reward: f64,
    /// [`Task::success`] of the new achieved goal (gymnasium's `info["is_success"]`).
    pub success: bool,
}

impl Step {
    /// The step that returned `obs`: `task`'s reward and success for its goals.
    pub fn of(task: &Task, obs: Obs) -> Step {
        let reward = task.reward(&obs.achieved_goal, &obs.desired_goal) as f64;
        let success = task.success(&obs.achieved_goal, &obs.desired_goal);
        Step { obs, reward, success }
    }
}

/// A goal-conditioned environment, shaped like gymnasium's `GoalEnv`.
pub trait GoalEnv {
    fn task(&self) -> &Task;
    /// Start an episode. `Some(seed)` re-seeds the generator as `env.reset(seed=seed)` does;
    /// `None` continues its stream, as `env.reset()` does, so N episodes after one seeded reset
    /// match Python's. An environment never seeded behaves as if seeded with 0 (gymnasium would
    /// use OS entropy; pgser runs are meant to be reproducible).
    fn reset(&mut self, seed: Option<u64>) -> Obs;
    /// Start an episode as a newly made environment would: `gym.make(id).reset(seed=seed)`.
    /// For Fetch that is `reset`; the hand tasks carry controls and warm starts over from one
    /// episode to the next, so `collect` and `eval`, which hand episodes to whichever worker is
    /// free, start every episode with this to keep it independent of the one before it.
    fn restart(&mut self, seed: u64) -> Obs {
        self.reset(Some(seed))
    }
    /// Whether an episode ends at its first success, as OGBench's mazes end it
    /// (`terminate_at_goal`): evaluation then counts the episode a success and steps it no
    /// further. The Fetch and hand tasks run their whole length and count the last step's.
    fn ends_at_success(&self) -> bool {
        false
    }
    /// The fixed evaluation task (1…K) the last `restart` set up, for environments that have
    /// them (OGBench's mazes: 5, cycled by seed); evaluation reports each one's success.
    fn eval_task(&self) -> Option<usize> {
        None
    }
    /// Apply one action (`task().act_dim` values, clipped to [−1, 1]). Values are first rounded
    /// to f32, the action space's dtype, because gymnasium computes with a float32 action as a
    /// policy hands it over. Panics if the action has the wrong length, as gymnasium raises.
    fn step(&mut self, action: &[f64]) -> Step;
}

/// One action value as the environments apply it: rounded to f32, the action space's dtype
/// (gymnasium computes with a float32 action as a policy hands it over), then clipped to
/// [−1, 1]. Collectors record exactly this, so replaying a stored action reproduces the step.
pub fn applied_action(value: f64) -> f32 {
    (value as f32).clamp(-1.0, 1.0)
}

/// The task of the environment [`make`] makes for `name`, without making it.
pub fn task(name: &str) -> Result<Task> {
    if let Some(t) = pointmaze::task(name) {
        return Ok(t);
    }
    Task::known(name).ok_or_else(|| {
        let hint = Task::suggest(name).map(|s| format!(" (did you mean {s}?)")).unwrap_or_default();
        anyhow::anyhow!(
            "{name}: unknown task{hint}; known: {}, {}",
            Task::known_names().join(", "),
            pointmaze::TASKS.join(", ")
        )
    })
}

/// The environment for a task name or gymnasium id (`FetchPush`, `FetchPush-v4`,
/// `HandManipulateEggRotate-v1`), or an OGBench PointMaze id or dataset name
/// (`pointmaze-medium-v0`, `pointmaze-medium-navigate-v0`). Other versions are refused: Fetch v1–v3 reset differently and
/// hand v0 runs on mujoco-py, so their data would not match.
pub fn make(task_name: &str) -> Result<Box<dyn GoalEnv + Send>> {
    if pointmaze::resolve(task_name).is_some() {
        return Ok(Box::new(pointmaze::PointMazeEnv::new(task_name)?));
    }
    let simulated = || [&fetch::TASKS[..], &hand::TASKS[..], &pointmaze::TASKS[..]].concat().join(", ");
    let Some(task) = Task::known(task_name).filter(|t| simulated().contains(t.name.as_str())) else {
        let hint = Task::suggest(task_name).map(|s| format!(" (did you mean {s}?)")).unwrap_or_default();
        bail!("{task_name}: no environment for this task{hint}; pgser simulates {}", simulated());
    };
    let version = task_name.split_once("-v").map(|(_, v)| v);
    let (family, want) = if hand::TASKS.contains(&task.name.as_str()) { ("hand", "1") } else { ("Fetch", "4") };
    if let Some(v) = version
        && v != want
    {
        bail!("{task_name}: pgser simulates the v{want} {family} environments only (use -v{want} or no suffix)");
    }
    Ok(match family {
        "hand" => Box::new(hand::HandEnv::new(&task.name, &assets_dir())?),
        _ => Box::new(fetch::FetchEnv::new(&task.name, &assets_dir())?),
    })
}

/// Where the gymnasium-robotics assets are: `$PGSER_ASSETS` if set, else an installed wheel's
/// `pgser/assets`, else the folder `make deps` fills (baked in by build.rs): [`crate::install`].
pub fn assets_dir() -> PathBuf {
    crate::install::data_path("PGSER_ASSETS", "assets", env!("PGSER_FETCH_ASSETS"))
}

/// A model file under the assets folder, or an error that says how to get it.
pub(crate) fn asset(dir: &Path, rel: &str) -> Result<PathBuf> {
    let p = dir.join(rel);
    if !p.is_file() {
        bail!(
            "{} is missing: run `make deps` (it unpacks the gymnasium-robotics 1.4.2 wheel's assets into \
             .deps/gymnasium_robotics/assets), or point PGSER_ASSETS at a gymnasium_robotics/envs/assets folder",
            p.display()
        );
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn make_refuses_what_it_cannot_simulate() {
        let err = |n: &str| make(n).err().unwrap().to_string();
        assert!(err("FetchPush-v1").contains("v4"));
        assert!(err("HandManipulateEggRotate-v0").contains("v1 hand"));
        assert!(err("PointReach").contains("no environment") && err("PointReach").contains("HandManipulateEggRotate"));
        let typo = err("HandManipulateBlockRotZ");
        assert!(typo.contains("did you mean HandManipulateBlockRotateZ?") && !typo.contains('\n'), "{typo}");
    }

    #[test]
    fn missing_assets_name_the_path_and_the_fix() {
        let e = asset(Path::new("/nonexistent/assets"), "fetch/push.xml").unwrap_err().to_string();
        assert!(e.contains("/nonexistent/assets/fetch/push.xml") && e.contains("make deps"), "{e}");
    }
}
