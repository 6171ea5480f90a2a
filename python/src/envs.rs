//! pgser's environments and policies for Python: the engines under `pgser.envs` (which adds
//! gymnasium's `Env`/`VectorEnv` interfaces, spaces and registration in Python).
//!
//! `Env` is one [`pgser::env::GoalEnv`]; `VecEnv` steps n of them on pgser's worker threads in one
//! call with the GIL released, with gymnasium 1.x's default autoreset (next-step: the call after
//! an episode ends resets that environment and ignores its action), so a Python loop pays one
//! crossing per step of all n instead of n. `Policy` is the per-episode policy `pgser-etl
//! collect` runs: the scripted experts, uniform random actions, or a checkpoint's actor.

use std::sync::Mutex;

use numpy::ndarray::Array2;
use numpy::{
    IntoPyArray, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pgser::collect::policy::{EpisodePolicy, PolicyKind, PolicySpec};
use pgser::env::{GoalEnv, Obs};
use pgser::task::Task;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;

use crate::py_err;

/// An observation as gymnasium's goal environments give it: a dict of three float64 arrays.
fn obs_dict<'py>(py: Python<'py>, o: Obs) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("observation", o.observation.into_pyarray(py))?;
    d.set_item("achieved_goal", o.achieved_goal.into_pyarray(py))?;
    d.set_item("desired_goal", o.desired_goal.into_pyarray(py))?;
    Ok(d)
}

/// n observations stacked: each key an (n, dim) float64 array.
fn stacked_dict<'py>(py: Python<'py>, task: &Task, obs: Vec<Obs>) -> PyResult<Bound<'py, PyDict>> {
    let n = obs.len();
    let d = PyDict::new(py);
    let stack = |dim: usize, f: &dyn Fn(&Obs) -> &[f64]| {
        let mut v = Vec::with_capacity(n * dim);
        obs.iter().for_each(|o| v.extend_from_slice(f(o)));
        Array2::from_shape_vec((n, dim), v).expect("n rows of dim values")
    };
    d.set_item("observation", stack(task.obs_dim, &|o| &o.observation).into_pyarray(py))?;
    d.set_item("achieved_goal", stack(task.goal_dim, &|o| &o.achieved_goal).into_pyarray(py))?;
    d.set_item("desired_goal", stack(task.goal_dim, &|o| &o.desired_goal).into_pyarray(py))?;
    Ok(d)
}

fn make(task: &str) -> PyResult<Box<dyn GoalEnv + Send>> {
    pgser::env::make(task).map_err(py_err)
}

fn check_action(task: &Task, got: usize) -> PyResult<()> {
    if got != task.act_dim {
        return Err(PyValueError::new_err(format!("{}: an action has {} values, got {got}", task.name, task.act_dim)));
    }
    Ok(())
}

/// One environment: `reset`, `step`, `compute_reward`, and the task's constants.
#[pyclass(module = "pgser._pgser")]
pub struct Env {
    env: Mutex<Box<dyn GoalEnv + Send>>,
    task: Task,
}

#[pymethods]
impl Env {
    #[new]
    fn new(task: &str) -> PyResult<Env> {
        let env = make(task)?;
        let task = env.task().clone();
        Ok(Env { env: Mutex::new(env), task })
    }

    /// `reset(seed)` as gymnasium's: a seed re-seeds, None continues the generator's stream.
    #[pyo3(signature = (seed=None))]
    fn reset<'py>(&self, py: Python<'py>, seed: Option<u64>) -> PyResult<Bound<'py, PyDict>> {
        let o = py.detach(|| self.env.lock().unwrap().reset(seed));
        obs_dict(py, o)
    }

    /// One step: (observation dict, reward, is_success).
    fn step<'py>(
        &self,
        py: Python<'py>,
        action: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<(Bound<'py, PyDict>, f64, bool)> {
        let a = action.as_slice()?.to_vec();
        check_action(&self.task, a.len())?;
        let s = py.detach(|| self.env.lock().unwrap().step(&a));
        Ok((obs_dict(py, s.obs)?, s.reward, s.success))
    }

    #[getter]
    fn task<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        crate::json_to_py(py, &serde_json::to_value(&self.task).map_err(|e| py_err(e.into()))?)
    }

    /// Whether an episode ends at its first success (OGBench's mazes: `terminated`).
    #[getter]
    fn ends_at_success(&self) -> bool {
        self.env.lock().unwrap().ends_at_success()
    }
}

/// gymnasium-robotics' `compute_reward` for `task` over any leading shape: 0 where the goal is
/// reached, −1 elsewhere, as float32 (the same function as the tables' reward column).
#[pyfunction]
pub fn compute_reward<'py>(
    py: Python<'py>,
    task: &str,
    achieved_goal: PyReadonlyArrayDyn<'py, f64>,
    desired_goal: PyReadonlyArrayDyn<'py, f64>,
) -> PyResult<Bound<'py, PyAny>> {
    let task = pgser::env::task(task).map_err(py_err)?;
    let (ag, g) = (achieved_goal, desired_goal);
    let (sa, sg) = (ag.shape().to_vec(), g.shape().to_vec());
    if sa != sg || sa.last() != Some(&task.goal_dim) {
        return Err(PyValueError::new_err(format!(
            "{}: achieved_goal {sa:?} and desired_goal {sg:?} must have one shape, ending in {}",
            task.name, task.goal_dim
        )));
    }
    let (a, b) =
        (ag.as_array().iter().copied().collect::<Vec<f64>>(), g.as_array().iter().copied().collect::<Vec<f64>>());
    let mut out = vec![0f32; a.len() / task.goal_dim];
    task.rewards(&a, &b, &mut out);
    let lead = &sa[..sa.len() - 1];
    Ok(out.into_pyarray(py).reshape(lead.to_vec())?.into_any())
}

/// One environment of a `VecEnv`, with its step count and whether its episode has ended.
struct Slot {
    env: Box<dyn GoalEnv + Send>,
    steps: usize,
    ended: bool,
}

/// What a `VecEnv` step returns for one environment.
struct Stepped {
    obs: Obs,
    reward: f64,
    terminated: bool,
    truncated: bool,
    success: bool,
}

/// n environments of one task, stepped together on pgser's worker threads.
#[pyclass(module = "pgser._pgser")]
pub struct VecEnv {
    slots: Mutex<Vec<Slot>>,
    task: Task,
    #[pyo3(get)]
    num_envs: usize,
    /// Steps per episode, after which an episode is truncated (gymnasium-robotics' limits).
    #[pyo3(get)]
    max_episode_steps: usize,
}

#[pymethods]
impl VecEnv {
    #[new]
    #[pyo3(signature = (task, num_envs, max_episode_steps))]
    fn new(task: &str, num_envs: usize, max_episode_steps: usize) -> PyResult<VecEnv> {
        if num_envs == 0 {
            return Err(PyValueError::new_err("num_envs must be at least 1"));
        }
        let slots = (0..num_envs)
            .map(|_| Ok(Slot { env: make(task)?, steps: 0, ended: false }))
            .collect::<PyResult<Vec<_>>>()?;
        let task = slots[0].env.task().clone();
        Ok(VecEnv { slots: Mutex::new(slots), task, num_envs, max_episode_steps })
    }

    /// Resets every environment: environment i with seed + i (gymnasium's vector rule), or
    /// each continuing its own stream when seed is None.
    #[pyo3(signature = (seed=None))]
    fn reset<'py>(&self, py: Python<'py>, seed: Option<u64>) -> PyResult<Bound<'py, PyDict>> {
        let obs = py.detach(|| {
            let mut slots = self.slots.lock().unwrap();
            slots
                .par_iter_mut()
                .enumerate()
                .map(|(i, s)| {
                    (s.steps, s.ended) = (0, false);
                    s.env.reset(seed.map(|x| x + i as u64))
                })
                .collect::<Vec<_>>()
        });
        stacked_dict(py, &self.task, obs)
    }

    /// One step of every environment: (obs dict, reward, terminated, truncated, is_success,
    /// was_reset). An environment whose episode ended on the previous step is reset instead
    /// (its action ignored, reward 0, not terminated or truncated) and flagged in was_reset.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        actions: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<(
        Bound<'py, PyDict>,
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
        Bound<'py, PyAny>,
    )> {
        let shape = actions.shape().to_vec();
        if shape[0] != self.num_envs {
            return Err(PyValueError::new_err(format!(
                "{}: actions for {} environments, got {}",
                self.task.name, self.num_envs, shape[0]
            )));
        }
        check_action(&self.task, shape[1])?;
        let a = actions.as_array().iter().copied().collect::<Vec<f64>>();
        let limit = self.max_episode_steps;
        let results = py.detach(|| {
            let mut slots = self.slots.lock().unwrap();
            slots
                .par_iter_mut()
                .zip(a.par_chunks(self.task.act_dim))
                .map(|(s, a)| {
                    if s.ended {
                        (s.steps, s.ended) = (0, false);
                        return (
                            Stepped {
                                obs: s.env.reset(None),
                                reward: 0.0,
                                terminated: false,
                                truncated: false,
                                success: false,
                            },
                            true,
                        );
                    }
                    let st = s.env.step(a);
                    s.steps += 1;
                    let terminated = st.success && s.env.ends_at_success();
                    s.ended = terminated || s.steps >= limit;
                    let truncated = !terminated && s.ended;
                    (Stepped { obs: st.obs, reward: st.reward, terminated, truncated, success: st.success }, false)
                })
                .collect::<Vec<_>>()
        });
        let reward: Vec<f64> = results.iter().map(|r| r.0.reward).collect();
        let truncated: Vec<bool> = results.iter().map(|r| r.0.truncated).collect();
        let terminated: Vec<bool> = results.iter().map(|r| r.0.terminated).collect();
        let success: Vec<f64> = results.iter().map(|r| if r.0.success { 1.0 } else { 0.0 }).collect();
        let was_reset: Vec<bool> = results.iter().map(|r| r.1).collect();
        let obs = results.into_iter().map(|r| r.0.obs).collect();
        Ok((
            stacked_dict(py, &self.task, obs)?,
            reward.into_pyarray(py).into_any(),
            terminated.into_pyarray(py).into_any(),
            truncated.into_pyarray(py).into_any(),
            success.into_pyarray(py).into_any(),
            was_reset.into_pyarray(py).into_any(),
        ))
    }
}

/// A policy of `pgser-etl collect` for one episode: "expert" (the scripted Fetch experts),
/// "random", or "checkpoint:FILE" (a trained actor), with collect's `noise` and `epsilon`.
/// Episode `episode` of a run seeded `seed` draws the same noise as collect's episode does.
/// `Policy("run.ckpt")` is that checkpoint's actor, on its own task (any task pgser trains on,
/// OGBench's included), and its `act` takes batches of observations and goals.
#[pyclass(module = "pgser._pgser")]
pub struct Policy {
    policy: Mutex<EpisodePolicy>,
    task: Task,
    /// A checkpoint's actor, for `act`'s deterministic batches.
    actor: Option<std::sync::Arc<pgser::agent::HostActor>>,
}

#[pymethods]
impl Policy {
    #[new]
    #[pyo3(signature = (task, policy=None, *, seed=0, episode=0, noise=0.0, epsilon=0.0))]
    fn new(task: &str, policy: Option<&str>, seed: u64, episode: u64, noise: f64, epsilon: f64) -> PyResult<Policy> {
        // `Policy("run.ckpt")`: a file in the task's place is a checkpoint, its task its own.
        let (kind, t) = match policy {
            None if std::path::Path::new(task).is_file() => {
                let kind = PolicyKind::parse(&format!("checkpoint:{task}")).map_err(py_err)?;
                let PolicyKind::Checkpoint(a) = &kind else { unreachable!("parsed as a checkpoint") };
                let t = a.task.clone();
                (kind, t)
            }
            _ => {
                let t = Task::known(task).ok_or_else(|| {
                    PyValueError::new_err(format!("{task}: unknown task (or no such checkpoint file)"))
                })?;
                (PolicyKind::parse(policy.unwrap_or("expert")).map_err(py_err)?, t)
            }
        };
        let actor = match &kind {
            PolicyKind::Checkpoint(a) => Some(a.clone()),
            _ => None,
        };
        let spec = PolicySpec { kind, noise, epsilon };
        let policy = EpisodePolicy::new(spec, &t.name, seed, episode).map_err(py_err)?;
        Ok(Policy { policy: Mutex::new(policy), task: t, actor })
    }

    /// The task's name, and its observation, goal and action sizes.
    #[getter]
    fn task(&self) -> (String, usize, usize, usize) {
        let t = &self.task;
        (t.name.clone(), t.obs_dim, t.goal_dim, t.act_dim)
    }

    /// A checkpoint's deterministic actions for a batch: `observations` (n, obs_dim) and `goals`
    /// (n, goal_dim), float32 or float64, give (n, act_dim) float32 actions in (−1, 1), π(s, g)
    /// as evaluation computes it (no noise). Rows run in parallel, without the GIL.
    fn act<'py>(
        &self,
        py: Python<'py>,
        observations: &Bound<'py, PyAny>,
        goals: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let np = py.import("numpy")?;
        let as_f64 = |x: &Bound<'py, PyAny>| -> PyResult<PyReadonlyArrayDyn<'py, f64>> {
            Ok(np.call_method1("ascontiguousarray", (x, "float64"))?.extract()?)
        };
        let (observations, goals) = (as_f64(observations)?, as_f64(goals)?);
        let Some(actor) = &self.actor else {
            return Err(PyValueError::new_err(
                "act() is a checkpoint's actor on batches; call an expert or random policy with an observation dict",
            ));
        };
        let t = &self.task;
        let rows = |a: &PyReadonlyArrayDyn<'py, f64>, dim: usize, what: &str| -> PyResult<(usize, Vec<f64>)> {
            let shape = a.shape().to_vec();
            let n = match shape.as_slice() {
                [d] if *d == dim => 1,
                [n, d] if *d == dim => *n,
                _ => {
                    return Err(PyValueError::new_err(format!(
                        "{}: {what} must be (n, {dim}) or ({dim},), got {shape:?}",
                        t.name
                    )));
                }
            };
            Ok((n, a.as_array().iter().copied().collect()))
        };
        let (n, o) = rows(&observations, t.obs_dim, "observations")?;
        let (m, g) = rows(&goals, t.goal_dim, "goals")?;
        if n != m {
            return Err(PyValueError::new_err(format!("{n} observations but {m} goals")));
        }
        let (od, gd, ad) = (t.obs_dim, t.goal_dim, t.act_dim);
        let out: Vec<f32> = py.detach(|| {
            let mut out = vec![0.0f64; n * ad];
            out.par_chunks_mut(ad).enumerate().for_each(|(i, a)| {
                actor.act(&o[i * od..(i + 1) * od], &g[i * gd..(i + 1) * gd], a);
            });
            out.into_iter().map(|x| x as f32).collect()
        });
        let arr = Array2::from_shape_vec((n, ad), out).map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(arr.into_pyarray(py).into_any())
    }

    /// The action for a goal-environment observation dict, as float64 in [−1, 1].
    fn __call__<'py>(&self, py: Python<'py>, obs: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyAny>> {
        let get = |k: &str| -> PyResult<Vec<f64>> {
            let v = obs.get_item(k)?.ok_or_else(|| PyValueError::new_err(format!("the observation has no {k:?}")))?;
            let a: PyReadonlyArray1<f64> = v.extract()?;
            Ok(a.as_slice()?.to_vec())
        };
        let o = Obs {
            observation: get("observation")?,
            achieved_goal: get("achieved_goal")?,
            desired_goal: get("desired_goal")?,
        };
        let t = &self.task;
        for (k, got, want) in [
            ("observation", o.observation.len(), t.obs_dim),
            ("achieved_goal", o.achieved_goal.len(), t.goal_dim),
            ("desired_goal", o.desired_goal.len(), t.goal_dim),
        ] {
            if got != want {
                return Err(PyValueError::new_err(format!("{}: {k} has {want} values, got {got}", t.name)));
            }
        }
        let mut out = vec![0.0; t.act_dim];
        self.policy.lock().unwrap().act(&o, &mut out);
        Ok(out.into_pyarray(py).into_any())
    }
}
