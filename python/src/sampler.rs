//! `pgser.Sampler`: the batches `pgser-train` trains on (`layout="pgser"`), or OGBench's
//! goal-conditioned batches (`layout="ogbench"`), as dicts of numpy arrays.
//!
//! Each layout is the library's own stream, not a Python port of it. `layout="pgser"` is
//! [`pgser::sampler::stream`]: same settings and seed, same batches as `pgser-train`
//! (tests/python/test_sampler.py checks it against `pgser-train batches`). `layout="ogbench"` is
//! [`pgser::sampler::ogbench`]: OGBench's `GCDataset.sample` rules (tests/python/
//! test_ogbench_sampler.py checks their distribution against OGBench's rules in numpy).
//!
//! Both draw on a background thread that keeps `prefetch` batches ready, so a Python trainer's
//! update and the next batch's sampling (and a pool's or the prioritized half's disk reads)
//! overlap; the thread never holds the GIL. Dropping the sampler, `close()`, or the end of
//! `num_batches` stops the thread.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, channel, sync_channel};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use numpy::{IntoPyArray, PyArrayMethods};
use pgser::agent::Batch;
use pgser::sampler::ogbench::{Code, OgbenchBatch, OgbenchConfig, OgbenchStream};
use pgser::sampler::pool::PoolStats;
use pgser::sampler::priority::{PriorityConfig, PriorityKind};
use pgser::sampler::stream::{BatchSource, RowIds, StreamConfig};
use pgser::sampler::view::{Budget, parse_bytes};
use pgser::sampler::{SamplerConfig, Swap};
use pyo3::exceptions::{PyStopIteration, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use crate::{existing, py_err};
use ogbench::{Overrides, Request, config_batch_size, env_of, og_dict, og_worker, ogbench_config};

mod ogbench;

type Drawn = anyhow::Result<(Batch, RowIds)>;
pub(crate) type OgDrawn = anyhow::Result<OgbenchBatch>;

/// How long a wait sleeps between checks for Ctrl-C.
const TICK: Duration = Duration::from_millis(100);

/// pgser's own batches (original data, HER, random swapping, the prioritized `-mem` mix), or
/// OGBench's (`layout="ogbench"`).
#[pyclass(module = "pgser._pgser")]
pub struct Sampler {
    kind: Kind,
    #[pyo3(get)]
    task: String,
    /// The size of the batches iteration yields (and `sample()` without an argument).
    #[pyo3(get)]
    batch_size: usize,
    #[pyo3(get)]
    scored: bool,
    #[pyo3(get)]
    layout: String,
    num_batches: Option<u64>,
    /// Batches handed out so far (iteration and `sample()` together).
    handed: AtomicU64,
    /// The pool's disk waits after the last batch the worker drew; None while β is held whole.
    pool: Arc<Mutex<Option<PoolStats>>>,
}

enum Kind {
    /// A worker that sends batches of `batch_size`, `num_batches` of them, in order.
    Pgser { rx: Mutex<Option<Receiver<Drawn>>>, worker: Mutex<Option<JoinHandle<()>>>, dims: (usize, usize, usize) },
    /// A worker that answers requests for batches of any size ([`og_worker`]).
    Ogbench {
        chan: Mutex<Option<OgChannel>>,
        worker: Mutex<Option<JoinHandle<()>>>,
        live: Box<Mutex<Live>>,
        provenance: bool,
    },
}

/// The agent's config as the sampler last read it. Their dataset classes read the config at
/// every `sample`, and an agent may set a key after its dataset was made (Horizon Reduction's
/// double SHARSA sets `low_discount` in `create`), so the config is read again at every batch
/// and a change is sent to the worker before the batch is asked for.
struct Live {
    config: Option<Py<PyAny>>,
    code: Code,
    overrides: Overrides,
    current: OgbenchConfig,
}

struct OgChannel {
    req: Sender<Request>,
    rx: Receiver<OgDrawn>,
    /// Answers still owed to requests whose wait was interrupted (Ctrl-C): read and dropped first.
    stale: usize,
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

/// `memory_budget=`: None (the whole table in memory), bytes as an int, or a size string; with
/// `draws_per_row=` (1 when None), which needs a budget.
fn parse_budget(b: Option<&Bound<'_, PyAny>>, draws_per_row: Option<u32>) -> PyResult<Budget> {
    if draws_per_row == Some(0) {
        return Err(PyValueError::new_err("draws_per_row=0: must be at least 1"));
    }
    let Some(b) = b.filter(|b| !b.is_none()) else {
        return match draws_per_row {
            Some(n) => Err(PyValueError::new_err(format!(
                "draws_per_row={n} needs memory_budget=: it says how long a streamed row group stays"
            ))),
            None => Ok(Budget::Unbounded),
        };
    };
    let bytes = if let Ok(s) = b.cast::<PyString>() {
        parse_bytes(&s.to_cow()?).map_err(|e| PyValueError::new_err(format!("memory_budget={e}")))?
    } else {
        match b.extract::<i128>() {
            Ok(n) if n >= 1 && n <= u64::MAX as i128 => n as u64,
            _ => {
                return Err(PyValueError::new_err(format!(
                    "memory_budget={}: use None, a number of bytes (at least 1), or a size such as \"2GB\"",
                    b.repr()?
                )));
            }
        }
    };
    Ok(Budget::Bytes { bytes, draws_per_row: draws_per_row.unwrap_or(1) })
}

#[pymethods]
impl Sampler {
    /// `layout="pgser"` (the default): arguments mirror `pgser-train`'s flags: `her` is
    /// --her-ratio (0.5), `swap`/`swap_ratio` are --swap/--swap-ratio (0.5), `aug_ratio` (0.5),
    /// `priority` ("rank"), `alpha` (--priority-alpha, 1.0), `eps` (--priority-eps, 0.01),
    /// `is_beta`, `seed`, `in_memory` (--aug-in-memory).
    ///
    /// `layout="ogbench"`: OGBench's GCDataset batches; `config` is an OGBench agent's config
    /// (a dict or ConfigDict, passed unchanged: its sampling keys are read, the rest ignored),
    /// and `discount`, `value_p_curgoal`, … `gc_negative` override it. From a scored table,
    /// `p_swapgoal` (0) of each batch's rows are PGSER's swapped rows, drawn by `priority`,
    /// `alpha` and `eps`; `swap_actor_goals` (True) gives their actor goal the swapped goal too.
    ///
    /// Both: `batch_size` (default `config["batch_size"]`, else 512), `memory_budget` (None: the
    /// whole table in memory; bytes, or a size such as "2GB": an out-of-core pool when the table
    /// is larger), `draws_per_row` (with a budget: draws per transition a streamed row group
    /// stays for; 1, or 2 to read half as much), `shard_window` (instead of a budget: one shard
    /// of a folder held at a time, the next every N batches of `batch_size`, every goal from the
    /// held shard: Horizon Reduction's loading, to compare with), `num_batches` (how many
    /// batches iteration yields; None: endless), `prefetch`.
    #[new]
    #[pyo3(signature = (path, *, layout="pgser", batch_size=None, her=None, swap=None, swap_ratio=None,
        aug_ratio=None, priority=None, alpha=None, eps=None, is_beta=None, seed=0, in_memory=false,
        num_batches=None, prefetch=4, memory_budget=None, config=None, discount=None, value_p_curgoal=None,
        value_p_trajgoal=None, value_p_randomgoal=None, value_geom_sample=None, actor_p_curgoal=None,
        actor_p_trajgoal=None, actor_p_randomgoal=None, actor_geom_sample=None, gc_negative=None,
        p_swapgoal=None, swap_actor_goals=None, draws_per_row=None, oracle_reps=None, clip_actions=None,
        env_name=None, provenance=true, shard_window=None, p_aug=None, frame_stack=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        path: PathBuf,
        layout: &str,
        batch_size: Option<usize>,
        her: Option<f64>,
        swap: Option<&str>,
        swap_ratio: Option<f64>,
        aug_ratio: Option<f64>,
        priority: Option<&str>,
        alpha: Option<f64>,
        eps: Option<f64>,
        is_beta: Option<f64>,
        seed: u64,
        in_memory: bool,
        num_batches: Option<u64>,
        prefetch: usize,
        memory_budget: Option<&Bound<'_, PyAny>>,
        config: Option<&Bound<'_, PyAny>>,
        discount: Option<f64>,
        value_p_curgoal: Option<f64>,
        value_p_trajgoal: Option<f64>,
        value_p_randomgoal: Option<f64>,
        value_geom_sample: Option<bool>,
        actor_p_curgoal: Option<f64>,
        actor_p_trajgoal: Option<f64>,
        actor_p_randomgoal: Option<f64>,
        actor_geom_sample: Option<bool>,
        gc_negative: Option<bool>,
        p_swapgoal: Option<f64>,
        swap_actor_goals: Option<bool>,
        draws_per_row: Option<u32>,
        oracle_reps: Option<bool>,
        clip_actions: Option<f64>,
        env_name: Option<&str>,
        provenance: bool,
        shard_window: Option<u64>,
        p_aug: Option<f64>,
        frame_stack: Option<u64>,
    ) -> PyResult<Sampler> {
        existing(&path)?;
        let mut budget = parse_budget(memory_budget, draws_per_row)?;
        let kw = [
            ("discount", discount),
            ("value_p_curgoal", value_p_curgoal),
            ("value_p_trajgoal", value_p_trajgoal),
            ("value_p_randomgoal", value_p_randomgoal),
            ("actor_p_curgoal", actor_p_curgoal),
            ("actor_p_trajgoal", actor_p_trajgoal),
            ("actor_p_randomgoal", actor_p_randomgoal),
            ("p_swapgoal", p_swapgoal),
            ("p_aug", p_aug),
        ];
        let kw_bools = [
            ("value_geom_sample", value_geom_sample),
            ("actor_geom_sample", actor_geom_sample),
            ("gc_negative", gc_negative),
            ("swap_actor_goals", swap_actor_goals),
        ];
        let pgser_args = [
            ("her", her.is_some()),
            ("swap", swap.is_some()),
            ("swap_ratio", swap_ratio.is_some()),
            ("aug_ratio", aug_ratio.is_some()),
            ("is_beta", is_beta.is_some()),
            ("in_memory", in_memory),
        ];
        let misplaced = |given: &mut dyn Iterator<Item = &str>, other: &str| -> PyResult<()> {
            match given.next() {
                Some(k) => Err(PyValueError::new_err(format!(
                    "{k}= is a setting of layout=\"{other}\", not of layout={layout:?}"
                ))),
                None => Ok(()),
            }
        };
        let priorities = PriorityConfig {
            priority: parse_priority(priority.unwrap_or("rank"))?,
            priority_alpha: alpha.unwrap_or(1.0),
            priority_eps: eps.unwrap_or(0.01),
            is_beta: None,
        };
        let batch_size = match batch_size {
            Some(b) => b,
            None => config_batch_size(config)?.unwrap_or(512),
        };
        // `shard_window=N`: Horizon Reduction's loading, one shard held and the next taken every
        // N batches of `batch_size` (their `dataset_replace_interval`), every goal from it.
        if let Some(n) = shard_window {
            if budget != Budget::Unbounded {
                return Err(PyValueError::new_err(
                    "shard_window= and memory_budget= (or draws_per_row=) are two ways of holding a folder; give one",
                ));
            }
            if n == 0 {
                return Err(PyValueError::new_err("shard_window=0: at least one batch a shard"));
            }
            budget = Budget::ShardWindow(n.saturating_mul(batch_size as u64));
        }
        match layout {
            "pgser" => {
                let stack = frame_stack.map(|_| "frame_stack");
                let og = kw.iter().filter(|k| k.1.is_some()).map(|k| k.0).chain(stack);
                let og_bools = kw_bools.iter().filter(|k| k.1.is_some()).map(|k| k.0);
                let with_config = config.filter(|c| !c.is_none()).map(|_| "config");
                misplaced(&mut og.chain(og_bools).chain(with_config), "ogbench")?;
                Self::pgser(
                    py,
                    path,
                    budget,
                    StreamConfig {
                        sampler: SamplerConfig {
                            swap: parse_swap(swap)?,
                            swap_ratio: swap_ratio.unwrap_or(0.5),
                            her_ratio: her.unwrap_or(0.5),
                        },
                        batch_size,
                        aug_ratio: aug_ratio.unwrap_or(0.5),
                        priority: PriorityConfig { is_beta, ..priorities },
                        aug_in_memory: in_memory,
                        seed,
                    },
                    num_batches,
                    prefetch,
                )
            }
            "ogbench" | "horizon_reduction" => {
                misplaced(&mut pgser_args.iter().filter(|k| k.1).map(|k| k.0), "pgser")?;
                if batch_size == 0 {
                    return Err(PyValueError::new_err("batch_size=0: must be at least 1"));
                }
                let code = if layout == "ogbench" { Code::Ogbench } else { Code::HorizonReduction };
                // `env_name`: OGBench's dataset or environment name; `-oraclerep` asks for oracle
                // representations, as OGBench's `make_env_and_datasets` reads it.
                let env = env_name.map(env_of);
                let oracle_reps = match (oracle_reps, &env) {
                    (Some(o), Some((_, named))) if o != *named => {
                        return Err(PyValueError::new_err(format!(
                            "oracle_reps={} and env_name={:?} disagree: an -oraclerep name asks for oracle \
                             representations; give one of the two",
                            if o { "True" } else { "False" },
                            env_name.unwrap_or_default()
                        )));
                    }
                    (Some(o), _) => Some(o),
                    (None, Some((_, named))) => Some(*named),
                    (None, None) => None,
                };
                let overrides =
                    Overrides { floats: kw.to_vec(), bools: kw_bools.to_vec(), oracle_reps, clip_actions, frame_stack };
                let cfg = ogbench_config(code, config, &overrides)?;
                let live = Live {
                    config: config.filter(|c| !c.is_none()).map(|c| c.clone().unbind()),
                    code,
                    overrides,
                    current: cfg.clone(),
                };
                let env = env.map(|(e, _)| (e, env_name.unwrap_or_default().to_string()));
                Self::ogbench(
                    py,
                    path,
                    budget,
                    (cfg, priorities),
                    seed,
                    batch_size,
                    num_batches,
                    prefetch,
                    (live, provenance, env),
                )
            }
            o => {
                Err(PyValueError::new_err(format!("layout={o:?}: use \"pgser\", \"ogbench\" or \"horizon_reduction\"")))
            }
        }
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// The next batch of `batch_size` rows. `layout="pgser"`: obs, goal, action, reward,
    /// next_obs, weight (float32), episode, step, scored_row (int64; −1 for rows of the original
    /// data). `layout="ogbench"`: as `sample()`.
    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        if self.num_batches.is_some_and(|n| self.handed.load(Ordering::SeqCst) >= n) {
            return Err(PyStopIteration::new_err(()));
        }
        self.draw(py, self.batch_size, false)
    }

    /// A batch of `batch_size` rows (default: the sampler's). `layout="ogbench"`: any size, as
    /// OGBench's `GCDataset.sample(batch_size)`: observations, next_observations, actions,
    /// value_goals, actor_goals, terminals (float32), rewards, masks (float64, as OGBench's), and
    /// where each row came from (int64): episode, step (table-wide episode numbers, in shard order
    /// across a folder), value_goal_episode, value_goal_step, actor_goal_episode, actor_goal_step,
    /// and scored_row (the scored table's row of a swapped row, −1 for the others).
    /// `layout="pgser"`: the next batch, whose size is fixed when the sampler is made.
    /// `evaluation=True` (OGBench's `sample(..., evaluation=True)`): the batch's images are not
    /// cropped.
    #[pyo3(signature = (batch_size=None, idxs=None, evaluation=false))]
    fn sample<'py>(
        &self,
        py: Python<'py>,
        batch_size: Option<usize>,
        idxs: Option<&Bound<'py, PyAny>>,
        evaluation: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        if idxs.is_some_and(|i| !i.is_none()) {
            return Err(PyValueError::new_err(
                "idxs=: pgser draws its own rows (from disk, within the budget); batches at given indices are not \
                 drawn",
            ));
        }
        let n = batch_size.unwrap_or(self.batch_size);
        if n == 0 {
            return Err(PyValueError::new_err("batch_size=0: must be at least 1"));
        }
        if matches!(self.kind, Kind::Pgser { .. }) && n != self.batch_size {
            return Err(PyValueError::new_err(format!(
                "batch_size={n}: layout=\"pgser\" draws batches of the size it was made with ({}); make another \
                 Sampler for another size",
                self.batch_size
            )));
        }
        if evaluation && matches!(self.kind, Kind::Pgser { .. }) {
            return Err(PyValueError::new_err(
                "evaluation=True: a key of OGBench's layout (no crops); layout=\"pgser\" has none",
            ));
        }
        self.draw(py, n, evaluation)
    }

    /// What the out-of-core pool's disk reads have cost the drawing so far, as of the last batch
    /// the background thread drew (it draws `prefetch` ahead): blocks rotated in (each in place of the
    /// oldest), rotations that waited for their block, the seconds waited in all, the longest wait, and the longest rotation
    /// besides its wait (placing a block between two batches). None while the
    /// table is held whole. Waits here are the disk's; a slow batch without one is scheduling.
    fn pool_stats<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(s) = *self.pool.lock().unwrap() else { return Ok(None) };
        let d = PyDict::new(py);
        d.set_item("rotations", s.rotations)?;
        d.set_item("waits", s.waits)?;
        d.set_item("waited_seconds", s.waited.as_secs_f64())?;
        d.set_item("longest_wait_seconds", s.longest_wait.as_secs_f64())?;
        d.set_item("longest_rotation_seconds", s.longest_rotation.as_secs_f64())?;
        Ok(Some(d))
    }

    /// Stops the background thread now (also done when the sampler is dropped).
    fn close(&self, py: Python<'_>) {
        // Without the GIL: another thread's `sample` may hold the channel and need the GIL.
        py.detach(|| self.stop());
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, py: Python<'_>, _args: &Bound<'_, pyo3::types::PyTuple>) -> bool {
        py.detach(|| self.stop());
        false
    }
}

impl Sampler {
    #[allow(clippy::too_many_arguments)]
    fn pgser(
        py: Python<'_>,
        path: PathBuf,
        budget: Budget,
        cfg: StreamConfig,
        num_batches: Option<u64>,
        prefetch: usize,
    ) -> PyResult<Sampler> {
        for (name, v) in [("her", cfg.sampler.her_ratio), ("swap_ratio", cfg.sampler.swap_ratio)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(PyValueError::new_err(format!("{name}={v}: must be in [0, 1]")));
            }
        }
        let source = py.detach(|| BatchSource::open_within(&path, &cfg, budget)).map_err(py_err)?;
        let t = source.task().clone();
        let scored = source.is_scored();
        let mut stream = py.detach(|| source.start(&cfg)).map_err(py_err)?;
        let (tx, rx) = sync_channel::<Drawn>(prefetch.max(1));
        let pool = Arc::new(Mutex::new(stream.pool().map(|p| p.stats())));
        let shared = pool.clone();
        let worker = std::thread::Builder::new()
            .name("pgser-py-sampler".into())
            .spawn(move || {
                let mut sent = 0u64;
                while num_batches.is_none_or(|n| sent < n) {
                    let b = stream.next_batch();
                    *shared.lock().unwrap() = stream.pool().map(|p| p.stats());
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
            kind: Kind::Pgser {
                rx: Mutex::new(Some(rx)),
                worker: Mutex::new(Some(worker)),
                dims: (t.obs_dim, t.goal_dim, t.act_dim),
            },
            task: t.name,
            batch_size: cfg.batch_size,
            scored,
            layout: "pgser".into(),
            num_batches,
            handed: AtomicU64::new(0),
            pool,
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn ogbench(
        py: Python<'_>,
        path: PathBuf,
        budget: Budget,
        (cfg, priority): (OgbenchConfig, PriorityConfig),
        seed: u64,
        batch_size: usize,
        num_batches: Option<u64>,
        prefetch: usize,
        (live, provenance, env): (Live, bool, Option<(String, String)>),
    ) -> PyResult<Sampler> {
        let layout = cfg.code.layout();
        let stream = py.detach(|| OgbenchStream::open(&path, budget, cfg, &priority, seed)).map_err(py_err)?;
        let task = stream.view().task().name.clone();
        // `env_name` must name the table's environment; checked before anything is drawn.
        if let Some((env, name)) = env
            && env != task
        {
            return Err(PyValueError::new_err(format!(
                "env_name={name:?} names the environment {env:?}, and the table holds {task:?}"
            )));
        }
        let pool = Arc::new(Mutex::new(stream.pool_stats()));
        let shared = pool.clone();
        let scored = stream.is_scored();
        let (req_tx, req_rx) = channel::<Request>();
        let (tx, rx) = sync_channel::<OgDrawn>(1);
        let worker = std::thread::Builder::new()
            .name("pgser-py-ogbench".into())
            .spawn(move || og_worker(stream, (batch_size, prefetch.max(1)), req_rx, tx, shared))
            .map_err(|e| py_err(e.into()))?;
        Ok(Sampler {
            kind: Kind::Ogbench {
                chan: Mutex::new(Some(OgChannel { req: req_tx, rx, stale: 0 })),
                worker: Mutex::new(Some(worker)),
                live: Box::new(Mutex::new(live)),
                provenance,
            },
            task,
            batch_size,
            scored,
            layout: layout.into(),
            num_batches,
            handed: AtomicU64::new(0),
            pool,
        })
    }

    /// The next batch, of `n` rows (`n` is the sampler's own size for `layout="pgser"`).
    fn draw<'py>(&self, py: Python<'py>, n: usize, evaluation: bool) -> PyResult<Bound<'py, PyDict>> {
        let d = match &self.kind {
            Kind::Pgser { rx, dims, .. } => {
                let drawn = loop {
                    let got = py.detach(|| rx.lock().unwrap().as_ref().map(|rx| rx.recv_timeout(TICK)));
                    match got {
                        None => return Err(PyValueError::new_err("the sampler is closed")),
                        Some(Ok(d)) => break d,
                        Some(Err(RecvTimeoutError::Timeout)) => py.check_signals()?,
                        // The worker ended: `num_batches` were handed out (or its error was, last).
                        Some(Err(RecvTimeoutError::Disconnected)) => return Err(PyStopIteration::new_err(())),
                    }
                };
                let (b, ids) = drawn.map_err(py_err)?;
                pgser_dict(py, *dims, b, ids)?
            }
            Kind::Ogbench { chan, live, provenance, .. } => {
                let changed = {
                    let mut live = live.lock().unwrap();
                    match &live.config {
                        Some(c) => {
                            let now = ogbench_config(live.code, Some(c.bind(py)), &live.overrides)?;
                            (now != live.current).then(|| {
                                live.current = now.clone();
                                now
                            })
                        }
                        None => None,
                    }
                };
                // The channel is locked with the GIL released, so a thread that waits for it never
                // holds the GIL that the one holding it needs to check for Ctrl-C.
                let got = py.detach(|| -> PyResult<OgDrawn> {
                    let mut guard = chan.lock().unwrap();
                    let Some(c) = guard.as_mut() else { return Err(PyValueError::new_err("the sampler is closed")) };
                    let ended = || PyValueError::new_err("the sampler's worker has ended (after an error it raised)");
                    while c.stale > 0 {
                        let _stale = c.rx.recv().map_err(|_| ended())?;
                        c.stale -= 1;
                    }
                    if let Some(cfg) = changed {
                        c.req.send(Request::Config(Box::new(cfg))).map_err(|_| ended())?;
                    }
                    c.req.send(Request::Batch(n, evaluation)).map_err(|_| ended())?;
                    loop {
                        match c.rx.recv_timeout(TICK) {
                            Ok(b) => return Ok(b),
                            Err(RecvTimeoutError::Timeout) => {
                                if let Err(interrupt) = Python::attach(|py| py.check_signals()) {
                                    c.stale += 1;
                                    return Err(interrupt);
                                }
                            }
                            Err(RecvTimeoutError::Disconnected) => return Err(ended()),
                        }
                    }
                })?;
                og_dict(py, got.map_err(py_err)?, *provenance)?
            }
        };
        self.handed.fetch_add(1, Ordering::SeqCst);
        Ok(d)
    }

    fn stop(&self) {
        // Dropping the receiver (and the request channel) makes the worker's next send (or wait)
        // fail, which ends it.
        match &self.kind {
            Kind::Pgser { rx, worker, .. } => {
                rx.lock().unwrap().take();
                if let Some(w) = worker.lock().unwrap().take() {
                    let _ = w.join();
                }
            }
            Kind::Ogbench { chan, worker, .. } => {
                chan.lock().unwrap().take();
                if let Some(w) = worker.lock().unwrap().take() {
                    let _ = w.join();
                }
            }
        }
    }
}

fn pgser_dict<'py>(
    py: Python<'py>,
    dims: (usize, usize, usize),
    b: Batch,
    ids: RowIds,
) -> PyResult<Bound<'py, PyDict>> {
    let (od, gd, ad) = dims;
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

impl Drop for Sampler {
    fn drop(&mut self) {
        self.stop();
    }
}
