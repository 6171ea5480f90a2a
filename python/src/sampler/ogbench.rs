//! `layout="ogbench"`: an OGBench agent's config read into [`OgbenchConfig`], the worker that
//! draws batches of any size asked for, and the dict OGBench's agents take.

use std::collections::VecDeque;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError};
use std::sync::{Arc, Mutex};

use numpy::{IntoPyArray, PyArrayMethods};
use pgser::sampler::ogbench::{Code, Column, OgbenchBatch, OgbenchConfig, OgbenchStream};
use pgser::sampler::pool::PoolStats;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::OgDrawn;
use crate::py_err;

/// The config keys this sampler reads; any other key of an agent's config is ignored.
pub(super) const OG_FLOATS: [&str; 9] = [
    "discount",
    "p_swapgoal",
    "value_p_curgoal",
    "value_p_trajgoal",
    "value_p_randomgoal",
    "actor_p_curgoal",
    "actor_p_trajgoal",
    "actor_p_randomgoal",
    "p_aug",
];
pub(super) const OG_BOOLS: [&str; 4] = ["value_geom_sample", "actor_geom_sample", "gc_negative", "swap_actor_goals"];
/// HGCDataset's subgoal steps (Horizon Reduction's class reads the value and actor ones apart).
const OG_STEPS: [&str; 3] = ["subgoal_steps", "value_subgoal_steps", "actor_subgoal_steps"];

/// What the keyword arguments set over an agent's config.
#[derive(Clone, Default)]
pub(super) struct Overrides {
    pub floats: Vec<(&'static str, Option<f64>)>,
    pub bools: Vec<(&'static str, Option<bool>)>,
    pub oracle_reps: Option<bool>,
    pub clip_actions: Option<f64>,
    pub frame_stack: Option<u64>,
}

/// The settings of `code`'s classes: pgser's defaults, then an agent's `config` (any mapping: a
/// dict, an `ml_collections.ConfigDict`), then the keyword arguments. Keys a class reads but
/// pgser does not draw (`frame_stack`, `p_aug`) are refused when set, and so is a key of another
/// class or another code's ([`OgbenchConfig::validate`]), so a config is never silently trained
/// on other batches than it asks for.
pub(super) fn ogbench_config(code: Code, config: Option<&Bound<'_, PyAny>>, kw: &Overrides) -> PyResult<OgbenchConfig> {
    let mut values = serde_json::to_value(OgbenchConfig { code, ..OgbenchConfig::default() }).expect("a plain struct");
    let obj = values.as_object_mut().expect("a struct is an object");
    if let Some(c) = config.filter(|c| !c.is_none()) {
        // A key that is absent or None is not set (ConfigDict's placeholders are None).
        let get = |k: &str| -> PyResult<Option<Bound<'_, PyAny>>> {
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
        for k in OG_STEPS {
            if let Some(v) = get(k)? {
                let x: i64 = v.extract().map_err(|_| {
                    PyValueError::new_err(format!("config[{k:?}] = {}: not a whole number of steps", repr(&v)))
                })?;
                if x < 0 {
                    return Err(PyValueError::new_err(format!(
                        "config[{k:?}] = {x}: a subgoal is at least one step ahead"
                    )));
                }
                obj.insert(k.into(), x.into());
            }
        }
        // Horizon Reduction's class asks `'low_discount' in config`: the key, even at None.
        if c.contains("low_discount")? {
            obj.insert("low_value_goals".into(), true.into());
            if let Some(v) = get("low_discount")? {
                let x: f64 = v.extract().map_err(|_| {
                    PyValueError::new_err(format!("config[\"low_discount\"] = {}: not a number", repr(&v)))
                })?;
                obj.insert("low_discount".into(), x.into());
            }
        }
        if let Some(v) = get("frame_stack")? {
            let k: u64 = v.extract().map_err(|_| {
                PyValueError::new_err(format!("config[\"frame_stack\"] = {}: not a whole number of frames", repr(&v)))
            })?;
            obj.insert("frame_stack".into(), k.into());
        }
        if let Some(v) = get("dataset_class")? {
            let name: String = v.str()?.to_cow()?.into_owned();
            let class = match name.as_str() {
                "GCDataset" => "GCDataset",
                "HGCDataset" => "HGCDataset",
                _ => {
                    return Err(PyValueError::new_err(format!(
                        "config[\"dataset_class\"] = {name:?}: pgser draws GCDataset's and HGCDataset's batches"
                    )));
                }
            };
            obj.insert("dataset_class".into(), class.into());
        }
    }
    for &(k, v) in &kw.floats {
        if let Some(x) = v {
            obj.insert(k.into(), x.into());
        }
    }
    for &(k, v) in &kw.bools {
        if let Some(x) = v {
            obj.insert(k.into(), x.into());
        }
    }
    if let Some(x) = kw.oracle_reps {
        obj.insert("oracle_reps".into(), x.into());
    }
    if let Some(x) = kw.clip_actions {
        obj.insert("clip_actions".into(), x.into());
    }
    if let Some(x) = kw.frame_stack {
        obj.insert("frame_stack".into(), x.into());
    }
    let cfg: OgbenchConfig = serde_json::from_value(values).map_err(|e| PyValueError::new_err(e.to_string()))?;
    cfg.validate().map_err(py_err)?;
    Ok(cfg)
}

fn repr(v: &Bound<'_, PyAny>) -> String {
    v.repr().map(|r| r.to_string()).unwrap_or_else(|_| "?".into())
}

/// The environment an OGBench dataset or environment name names, OGBench's way
/// (`make_env_and_datasets`), and whether it asks for oracle representations: the dataset type
/// and the word `oraclerep` dropped (`puzzle-4x5-play-oraclerep-v0` → `puzzle-4x5-v0`, true).
pub(super) fn env_of(name: &str) -> (String, bool) {
    let words: Vec<&str> = name.split('-').collect();
    let oracle = words.contains(&"oraclerep");
    let kept = words.iter().copied().filter(|w| *w != "oraclerep").collect::<Vec<_>>().join("-");
    // A dataset's name drops its type; an environment's name is kept as it is.
    (pgser::ogbench::env_name(&kept).unwrap_or(kept), oracle)
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

/// What the sampler asks its worker for.
pub(super) enum Request {
    /// The next batch, of this many rows; an evaluation batch (no crops) when true.
    Batch(usize, bool),
    /// Draw the batches from the next on with these settings (the agent's config changed).
    Config(Box<OgbenchConfig>),
}

/// The ogbench layout's worker. Batch k of the stream is drawn from its own generator, so the
/// worker keeps batches k, k+1, … of the default size ready and, asked for another size, drops
/// them and draws batch k at that size. A request for the default size is answered as soon as
/// batch k is ready, before the queue is topped up, so a learner waits for a draw only when it
/// has used up the queue.
///
/// The bytes depend on the calls alone, never on `prefetch` or timing. A pool's resident data
/// follow the rows drawn, so batches are drawn ahead only while they take no block in: those
/// dropped for a request of another size (or for a config change) are taken back
/// (`drop_ahead`), and the pool is as if they had never been drawn. The batch that takes a block
/// in is drawn once its request comes, at the size asked, its block read and taken from the
/// loader beforehand (`stage`): a short wait once a block's worth of draws (placing the block,
/// and one draw).
pub(super) fn og_worker(
    mut stream: OgbenchStream,
    (size, prefetch): (usize, usize),
    req: Receiver<Request>,
    out: SyncSender<OgDrawn>,
    pool: Arc<Mutex<Option<PoolStats>>>,
) {
    let mut ready: VecDeque<OgDrawn> = VecDeque::new();
    let mut k = 0u64;
    // A config the stream refused: the answer to the next request.
    let mut refused: Option<anyhow::Error> = None;
    // Draws the next default-size batch into the queue, unless it is full, ends in an error, or
    // the batch would take a block in: then it readies that block (waiting for the loader while
    // the learner uses up the queue) and the batch waits for its request.
    let top_up = |stream: &mut OgbenchStream, ready: &mut VecDeque<OgDrawn>, k: u64| -> bool {
        if ready.len() >= prefetch || ready.back().is_some_and(|b| b.is_err()) {
            return false;
        }
        if stream.would_rotate(size) {
            stream.stage();
            return false;
        }
        ready.push_back(stream.batch(k + ready.len() as u64, size));
        *pool.lock().unwrap() = stream.pool_stats();
        true
    };
    let on_request = |stream: &mut OgbenchStream, n: usize, k: u64, evaluation: bool| {
        let b = stream.batch_for(k, n, evaluation);
        *pool.lock().unwrap() = stream.pool_stats();
        b
    };
    // Drops the queue, giving its draws back to the pool; a queued failure (a block the pool
    // could not read) is kept as the answer to the next request: dropping it would lose it.
    let drop_queue = |stream: &mut OgbenchStream, ready: &mut VecDeque<OgDrawn>| -> Option<OgDrawn> {
        if let Some(failed) = ready.iter().position(|b| b.is_err()) {
            return ready.drain(..).nth(failed);
        }
        stream.drop_ahead(ready.len() * size);
        ready.clear();
        None
    };
    loop {
        let r = match req.try_recv() {
            Ok(r) => r,
            Err(TryRecvError::Disconnected) => return,
            Err(TryRecvError::Empty) => {
                if refused.is_none() && top_up(&mut stream, &mut ready, k) {
                    continue;
                }
                // A closed request channel: the sampler was closed or dropped.
                let Ok(r) = req.recv() else { return };
                r
            }
        };
        let (n, evaluation) = match r {
            Request::Config(cfg) => {
                if let Some(failed) = drop_queue(&mut stream, &mut ready) {
                    ready.push_back(failed);
                } else if let Err(e) = stream.reconfigure(*cfg) {
                    refused = Some(e.context("the agent's config changed"));
                }
                continue;
            }
            Request::Batch(n, evaluation) => (n, evaluation),
        };
        // Batches drawn ahead are training batches of the default size; any other is drawn at
        // its request, the queue given back first.
        let b = if let Some(e) = refused.take() {
            Err(e)
        } else if n == size && !evaluation {
            match ready.pop_front() {
                Some(b) => b,
                None => on_request(&mut stream, n, k, false),
            }
        } else {
            match drop_queue(&mut stream, &mut ready) {
                Some(failed) => failed,
                None => on_request(&mut stream, n, k, evaluation),
            }
        };
        k += 1;
        let failed = b.is_err();
        if out.send(b).is_err() || failed {
            return;
        }
    }
}

/// A batch as the class it follows gives it, with its dtypes: float32 vectors and terminals,
/// uint8 images [n, H, W, C] (a visual dataset's observation keys),
/// float64 rewards and masks (`successes.astype(float)`), int64 subgoal steps and offsets; and,
/// with `provenance`, pgser's columns of where each row and goal came from (int64 episodes and
/// steps, uint8 goal kinds: `GoalKind::code`).
pub(super) fn og_dict(py: Python<'_>, b: OgbenchBatch, provenance: bool) -> PyResult<Bound<'_, PyDict>> {
    let n = b.n;
    let d = PyDict::new(py);
    for key in b.keys {
        if key.provenance && !provenance {
            continue;
        }
        match key.column {
            Column::F32 { dim: Some(dim), values } => {
                d.set_item(key.name, values.into_pyarray(py).reshape([n, dim])?)?
            }
            Column::F32 { dim: None, values } => d.set_item(key.name, values.into_pyarray(py))?,
            Column::F64(v) => d.set_item(key.name, v.into_pyarray(py))?,
            Column::I64(v) => d.set_item(key.name, v.into_pyarray(py))?,
            Column::Kind(v) => {
                d.set_item(key.name, v.iter().map(|k| k.code()).collect::<Vec<u8>>().into_pyarray(py))?
            }
            Column::U8 { shape, values } => {
                let dims: Vec<usize> = std::iter::once(n).chain(shape).collect();
                d.set_item(key.name, values.into_pyarray(py).reshape(dims)?)?
            }
        }
    }
    Ok(d)
}
