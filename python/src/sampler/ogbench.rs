//! `layout="ogbench"`: an OGBench agent's config read into [`OgbenchConfig`], the worker that
//! draws batches of any size asked for, and the dict OGBench's agents take.

use std::collections::VecDeque;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError};
use std::sync::{Arc, Mutex};

use numpy::{IntoPyArray, PyArrayMethods};
use pgser::sampler::ogbench::{OgbenchBatch, OgbenchConfig, OgbenchStream};
use pgser::sampler::pool::PoolStats;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::OgDrawn;
use crate::py_err;

/// OGBench's config keys this sampler reads; any other key of an agent's config is ignored.
pub(super) const OG_FLOATS: [&str; 8] = [
    "discount",
    "p_swapgoal",
    "value_p_curgoal",
    "value_p_trajgoal",
    "value_p_randomgoal",
    "actor_p_curgoal",
    "actor_p_trajgoal",
    "actor_p_randomgoal",
];
pub(super) const OG_BOOLS: [&str; 4] = ["value_geom_sample", "actor_geom_sample", "gc_negative", "swap_actor_goals"];

/// OGBench's settings: its defaults, then an agent's `config` (any mapping: a dict, an
/// `ml_collections.ConfigDict`), then the keyword arguments. Keys OGBench's GCDataset reads but
/// pgser does not draw (`frame_stack`, `p_aug`, a `dataset_class` other than GCDataset) are
/// refused when set, so a config is never silently trained on other batches than it asks for.
pub(super) fn ogbench_config<'py>(
    config: Option<&Bound<'py, PyAny>>,
    kw: &[(&str, Option<f64>)],
    kw_bools: &[(&str, Option<bool>)],
) -> PyResult<OgbenchConfig> {
    let mut values = serde_json::to_value(OgbenchConfig::default()).expect("a plain struct");
    let obj = values.as_object_mut().expect("a struct is an object");
    if let Some(c) = config.filter(|c| !c.is_none()) {
        // A key that is absent or None is not set (ConfigDict's placeholders are None).
        let get = |k: &str| -> PyResult<Option<Bound<'py, PyAny>>> {
            if !c.contains(k)? {
                return Ok(None);
            }
            let v = c.get_item(k)?;
            Ok(if v.is_none() { None } else { Some(v) })
        };
        for k in OG_FLOATS {
            if let Some(v) = get(k)? {
                let x: f64 = v.extract().map_err(|_| PyValueError::new_err(format!("config[{k:?}]: not a number")))?;
                obj.insert(k.into(), x.into());
            }
        }
        for k in OG_BOOLS {
            if let Some(v) = get(k)? {
                obj.insert(k.into(), v.is_truthy()?.into());
            }
        }
        if let Some(v) = get("frame_stack")? {
            return Err(PyValueError::new_err(format!(
                "config[\"frame_stack\"] = {}: frame stacking (OGBench's pixel tasks) is not drawn by pgser; use None",
                v.repr()?
            )));
        }
        if let Some(v) = get("p_aug")?
            && v.extract::<f64>().map_or(true, |p| p != 0.0)
        {
            return Err(PyValueError::new_err(format!(
                "config[\"p_aug\"] = {}: image augmentation (OGBench's pixel tasks) is not done by pgser; use 0 or None",
                v.repr()?
            )));
        }
        if let Some(v) = get("dataset_class")? {
            let name: String = v.str()?.to_cow()?.into_owned();
            if name != "GCDataset" {
                return Err(PyValueError::new_err(format!(
                    "config[\"dataset_class\"] = {name:?}: pgser draws GCDataset's batches only (not HGCDataset's subgoals)"
                )));
            }
        }
    }
    for &(k, v) in kw {
        if let Some(x) = v {
            obj.insert(k.into(), x.into());
        }
    }
    for &(k, v) in kw_bools {
        if let Some(x) = v {
            obj.insert(k.into(), x.into());
        }
    }
    let cfg: OgbenchConfig = serde_json::from_value(values).map_err(|e| PyValueError::new_err(e.to_string()))?;
    cfg.validate().map_err(py_err)?;
    Ok(cfg)
}

/// The batch size from `config["batch_size"]`, when an agent's config carries one.
pub(super) fn config_batch_size(config: Option<&Bound<'_, PyAny>>) -> PyResult<Option<usize>> {
    match config.filter(|c| !c.is_none()) {
        Some(c) if c.contains("batch_size")? => Ok(Some(
            c.get_item("batch_size")?
                .extract()
                .map_err(|_| PyValueError::new_err("config[\"batch_size\"]: not a positive int"))?,
        )),
        _ => Ok(None),
    }
}

/// The ogbench layout's worker. Batch k of the stream is drawn from its own generator, so the
/// worker keeps batches k, k+1, … of the default size ready and, asked for another size, drops
/// them and draws batch k at that size. A request for the default size is answered as soon as
/// batch k is ready, before the queue is topped up, so a learner waits for a draw only when it
/// has used up the queue.
///
/// The bytes depend on the calls alone, never on `prefetch` or timing. A pool's resident data
/// follow the rows drawn, so batches are drawn ahead only while they take no block in: those
/// dropped for a request of another size are taken back (`drop_ahead`), and the pool is as if
/// they had never been drawn. The batch that takes a block in is drawn once its request comes,
/// at the size asked, its block read and taken from the loader beforehand (`stage`): a short
/// wait once a block's worth of draws (placing the block, and one draw).
pub(super) fn og_worker(
    mut stream: OgbenchStream,
    (size, prefetch): (usize, usize),
    req: Receiver<usize>,
    out: SyncSender<OgDrawn>,
    pool: Arc<Mutex<Option<PoolStats>>>,
) {
    let mut ready: VecDeque<OgDrawn> = VecDeque::new();
    let mut k = 0u64;
    // Draws the next default-size batch into the queue, unless it is full, ends in an error, or
    // the batch would take a block in: then it readies that block (waiting for the loader while
    // the learner uses up the queue) and the batch waits for its request.
    let top_up = |stream: &mut OgbenchStream, ready: &mut VecDeque<OgDrawn>, k: u64| -> bool {
        if ready.len() >= prefetch || ready.back().is_some_and(|b| b.is_err()) {
            return false;
        }
        if stream.would_swap(size) {
            stream.stage();
            return false;
        }
        ready.push_back(stream.batch(k + ready.len() as u64, size));
        *pool.lock().unwrap() = stream.pool_stats();
        true
    };
    let on_request = |stream: &mut OgbenchStream, n: usize, k: u64| {
        let b = stream.batch(k, n);
        *pool.lock().unwrap() = stream.pool_stats();
        b
    };
    loop {
        let n = match req.try_recv() {
            Ok(n) => n,
            Err(TryRecvError::Disconnected) => return,
            Err(TryRecvError::Empty) => {
                if top_up(&mut stream, &mut ready, k) {
                    continue;
                }
                // A closed request channel: the sampler was closed or dropped.
                let Ok(n) = req.recv() else { return };
                n
            }
        };
        let b = if n == size {
            match ready.pop_front() {
                Some(b) => b,
                None => on_request(&mut stream, n, k),
            }
        } else if let Some(failed) = ready.iter().position(|b| b.is_err()) {
            // A queued failure (a block the pool could not read) is the answer: dropping it with
            // the queue would lose the error.
            ready.drain(..).nth(failed).expect("found")
        } else {
            stream.drop_ahead(ready.len() * size);
            ready.clear();
            on_request(&mut stream, n, k)
        };
        k += 1;
        let failed = b.is_err();
        if out.send(b).is_err() || failed {
            return;
        }
    }
}

/// OGBench's batch dict, with its dtypes: float32 vectors and terminals, float64 rewards and
/// masks (`successes.astype(float)` in its GCDataset), and pgser's int64 provenance columns.
pub(super) fn og_dict(py: Python<'_>, b: OgbenchBatch) -> PyResult<Bound<'_, PyDict>> {
    let (n, od, ad) = (b.n, b.obs_dim, b.act_dim);
    let d = PyDict::new(py);
    let matrix = |v: Vec<f32>, dim: usize| v.into_pyarray(py).reshape([n, dim]);
    let wide = |v: Vec<f32>| v.into_iter().map(f64::from).collect::<Vec<f64>>().into_pyarray(py);
    d.set_item("observations", matrix(b.observations, od)?)?;
    d.set_item("next_observations", matrix(b.next_observations, od)?)?;
    d.set_item("actions", matrix(b.actions, ad)?)?;
    d.set_item("terminals", b.terminals.into_pyarray(py))?;
    d.set_item("rewards", wide(b.rewards))?;
    d.set_item("masks", wide(b.masks))?;
    d.set_item("value_goals", matrix(b.value_goals, od)?)?;
    d.set_item("actor_goals", matrix(b.actor_goals, od)?)?;
    d.set_item("episode", b.episode.into_pyarray(py))?;
    d.set_item("step", b.step.into_pyarray(py))?;
    d.set_item("value_goal_episode", b.value_goal_episode.into_pyarray(py))?;
    d.set_item("value_goal_step", b.value_goal_step.into_pyarray(py))?;
    d.set_item("actor_goal_episode", b.actor_goal_episode.into_pyarray(py))?;
    d.set_item("actor_goal_step", b.actor_goal_step.into_pyarray(py))?;
    d.set_item("scored_row", b.scored_row.into_pyarray(py))?;
    Ok(d)
}
