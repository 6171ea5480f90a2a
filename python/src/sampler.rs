//! `pgser.Sampler`: the batches `pgser-train` trains on, as an iterator of dicts of numpy arrays.
//!
//! It is [`pgser::sampler::stream`] itself, not a Python port of it: same settings and seed, same
//! batches (tests/python/test_sampler.py checks it against `pgser-train batches`). The stream runs
//! on a background thread that keeps `prefetch` batches ready, so a Python trainer's update and
//! the next batch's sampling (and the prioritized half's disk reads) overlap; the thread never
//! holds the GIL. Dropping the sampler, or the end of `num_batches`, stops the thread.

use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::mpsc::{Receiver, RecvTimeoutError, sync_channel};
use std::thread::JoinHandle;
use std::time::Duration;

use numpy::{IntoPyArray, PyArrayMethods};
use pgser::agent::Batch;
use pgser::sampler::priority::{PriorityConfig, PriorityKind};
use pgser::sampler::stream::{BatchSource, RowIds, StreamConfig};
use pgser::sampler::{SamplerConfig, Swap};
use pyo3::exceptions::{PyStopIteration, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{existing, py_err};

type Drawn = anyhow::Result<(Batch, RowIds)>;

/// Batches of a trajectory table (original data, HER, optional random swapping) or of a scored
/// table (the `-mem` mix: original rows plus rows drawn by priority from its swapped rows).
#[pyclass(module = "pgser._pgser")]
pub struct Sampler {
    rx: Mutex<Option<Receiver<Drawn>>>,
    worker: Mutex<Option<JoinHandle<()>>>,
    dims: (usize, usize, usize),
    #[pyo3(get)]
    task: String,
    #[pyo3(get)]
    batch_size: usize,
    #[pyo3(get)]
    scored: bool,
}

fn parse_swap(s: Option<&str>) -> PyResult<Swap> {
    match s {
        None | Some("none") => Ok(Swap::None),
        Some("random") => Ok(Swap::Random),
        Some(o) => Err(PyValueError::new_err(format!("swap={o:?}: use None, \"none\" or \"random\""))),
    }
}

fn parse_priority(s: &str) -> PyResult<PriorityKind> {
    match s {
        "q" => Ok(PriorityKind::Q),
        "rank" => Ok(PriorityKind::Rank),
        "uniform" => Ok(PriorityKind::Uniform),
        o => Err(PyValueError::new_err(format!("priority={o:?}: use \"q\", \"rank\" or \"uniform\""))),
    }
}

#[pymethods]
impl Sampler {
    /// Arguments mirror `pgser-train`'s flags: `her` is --her-ratio, `swap`/`swap_ratio` are
    /// --swap/--swap-ratio, `aug_ratio`, `priority`, `alpha` (--priority-alpha), `eps`
    /// (--priority-eps), `is_beta`, `seed`, `in_memory` (--aug-in-memory).
    #[new]
    #[pyo3(signature = (path, *, batch_size=512, her=0.5, swap=None, swap_ratio=0.5, aug_ratio=0.5,
        priority="rank", alpha=1.0, eps=0.01, is_beta=None, seed=0, in_memory=false, num_batches=None, prefetch=4))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        path: PathBuf,
        batch_size: usize,
        her: f64,
        swap: Option<&str>,
        swap_ratio: f64,
        aug_ratio: f64,
        priority: &str,
        alpha: f64,
        eps: f64,
        is_beta: Option<f64>,
        seed: u64,
        in_memory: bool,
        num_batches: Option<u64>,
        prefetch: usize,
    ) -> PyResult<Sampler> {
        existing(&path)?;
        for (name, v) in [("her", her), ("swap_ratio", swap_ratio)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(PyValueError::new_err(format!("{name}={v}: must be in [0, 1]")));
            }
        }
        let cfg = StreamConfig {
            sampler: SamplerConfig { swap: parse_swap(swap)?, swap_ratio, her_ratio: her },
            batch_size,
            aug_ratio,
            priority: PriorityConfig {
                priority: parse_priority(priority)?,
                priority_alpha: alpha,
                priority_eps: eps,
                is_beta,
            },
            aug_in_memory: in_memory,
            seed,
        };
        let source = py.detach(|| BatchSource::open(&path, &cfg)).map_err(py_err)?;
        let t = source.data.task.clone();
        let scored = source.is_scored();
        let mut stream = py.detach(|| source.start(&cfg)).map_err(py_err)?;
        let (tx, rx) = sync_channel::<Drawn>(prefetch.max(1));
        let worker = std::thread::Builder::new()
            .name("pgser-py-sampler".into())
            .spawn(move || {
                let mut sent = 0u64;
                while num_batches.is_none_or(|n| sent < n) {
                    let b = stream.next_batch();
                    let failed = b.is_err();
                    // A closed channel: the sampler was dropped.
                    if tx.send(b).is_err() || failed {
                        return;
                    }
                    sent += 1;
                }
            })
            .map_err(|e| py_err(e.into()))?;
        Ok(Sampler {
            rx: Mutex::new(Some(rx)),
            worker: Mutex::new(Some(worker)),
            dims: (t.obs_dim, t.goal_dim, t.act_dim),
            task: t.name,
            batch_size,
            scored,
        })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// The next batch: obs, goal, action, reward, next_obs, weight (float32), episode, step,
    /// scored_row (int64; −1 for rows of the original data).
    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let drawn = loop {
            let got =
                py.detach(|| self.rx.lock().unwrap().as_ref().map(|rx| rx.recv_timeout(Duration::from_millis(100))));
            match got {
                None => return Err(PyValueError::new_err("the sampler is closed")),
                Some(Ok(d)) => break d,
                Some(Err(RecvTimeoutError::Timeout)) => py.check_signals()?,
                // The worker ended: `num_batches` were handed out (or its error was, last).
                Some(Err(RecvTimeoutError::Disconnected)) => return Err(PyStopIteration::new_err(())),
            }
        };
        let (b, ids) = drawn.map_err(py_err)?;
        self.to_dict(py, b, ids)
    }

    /// Stops the background thread now (also done when the sampler is dropped).
    fn close(&self) {
        self.stop();
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, _args: &Bound<'_, pyo3::types::PyTuple>) -> bool {
        self.stop();
        false
    }
}

impl Sampler {
    fn to_dict<'py>(&self, py: Python<'py>, b: Batch, ids: RowIds) -> PyResult<Bound<'py, PyDict>> {
        let (od, gd, ad) = self.dims;
        let n = b.n;
        let d = PyDict::new(py);
        let matrix = |v: Vec<f32>, dim: usize| v.into_pyarray(py).reshape([n, dim]);
        d.set_item("obs", matrix(b.obs, od)?)?;
        d.set_item("goal", matrix(b.goal, gd)?)?;
        d.set_item("action", matrix(b.action, ad)?)?;
        d.set_item("reward", b.reward.into_pyarray(py))?;
        d.set_item("next_obs", matrix(b.next_obs, od)?)?;
        let weight = if b.weight.is_empty() { vec![1.0f32; n] } else { b.weight };
        d.set_item("weight", weight.into_pyarray(py))?;
        let wide = |v: Vec<u32>| v.into_iter().map(i64::from).collect::<Vec<i64>>().into_pyarray(py);
        d.set_item("episode", wide(ids.episode))?;
        d.set_item("step", wide(ids.step))?;
        d.set_item("scored_row", ids.scored_row.into_pyarray(py))?;
        Ok(d)
    }

    fn stop(&self) {
        // Dropping the receiver makes the worker's next send fail, which ends it.
        self.rx.lock().unwrap().take();
        if let Some(w) = self.worker.lock().unwrap().take() {
            let _ = w.join();
        }
    }
}

impl Drop for Sampler {
    fn drop(&mut self) {
        self.stop();
    }
}
