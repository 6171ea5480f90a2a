//! `pgser._pgser`: the compiled half of the `pgser` Python package (python/pgser/ is the other).
//!
//! Every function here calls the same library functions as the CLI, so a table, a batch or an
//! episode is the same bytes whichever door it came through. What this layer adds is only what
//! crossing into Python needs:
//! - errors become Python exceptions carrying pgser's one-line message (`FileNotFoundError` when
//!   a named file is missing, `ValueError` otherwise), and arguments pgser would assert on
//!   (an action of the wrong length) are checked first, so no panic reaches Python;
//! - long calls run with the GIL released, and those that wait (the sampler's `__next__`) wake
//!   every 100 ms to let Ctrl-C through;
//! - arrays cross as numpy arrays that take over the Rust vectors (no copy), tables as pyarrow
//!   tables over the Arrow buffers the Parquet reader filled (the Arrow C data interface).

mod envs;
mod sampler;

use std::path::{Path, PathBuf};

use arrow_array::RecordBatch;
use arrow_array::RecordBatchReader;
use arrow_pyarrow::IntoPyArrow;
use parquet::arrow::ProjectionMask;
use pyo3::exceptions::{PyFileNotFoundError, PyValueError};
use pyo3::prelude::*;

/// pgser's error as the Python exception a user expects: `FileNotFoundError` when the fault is
/// a missing file, `ValueError` otherwise, with the same one line the CLI prints.
pub(crate) fn py_err(e: anyhow::Error) -> PyErr {
    let line = format!("{e:#}").replace('\n', " ");
    let missing = e
        .chain()
        .any(|c| c.downcast_ref::<std::io::Error>().is_some_and(|io| io.kind() == std::io::ErrorKind::NotFound));
    if missing { PyFileNotFoundError::new_err(line) } else { PyValueError::new_err(line) }
}

/// Runs a long job (convert, score) on its own thread while this one waits with the GIL
/// released, waking every 100 ms to let Ctrl-C through. On Ctrl-C the job's progress bar is
/// finished, which the job reads as "stop" at its next step ([`pgser::progress::advance`]): it
/// returns, its atomic output leaves no file, and the KeyboardInterrupt is raised.
pub(crate) fn interruptible<T: Send>(
    py: Python<'_>,
    job: impl FnOnce(&indicatif::ProgressBar) -> anyhow::Result<T> + Send,
) -> PyResult<T> {
    let bar = indicatif::ProgressBar::hidden();
    std::thread::scope(|s| {
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let rx = std::sync::Mutex::new(rx); // waited on with the GIL released, from another thread's view
        let b = &bar;
        let worker = s.spawn(move || {
            let r = job(b);
            let _ = tx.send(());
            r
        });
        loop {
            let done = py.detach(|| rx.lock().unwrap().recv_timeout(std::time::Duration::from_millis(100)));
            if !matches!(done, Err(std::sync::mpsc::RecvTimeoutError::Timeout)) {
                return match worker.join() {
                    Ok(r) => r.map_err(py_err),
                    Err(_) => Err(PyValueError::new_err("pgser: the job panicked (a bug: please report it)")),
                };
            }
            if let Err(interrupt) = py.check_signals() {
                bar.finish();
                let _ = py.detach(|| worker.join());
                return Err(interrupt);
            }
        }
    })
}

/// A path argument that must name an existing file or folder: `FileNotFoundError` naming it.
pub(crate) fn existing(path: &Path) -> PyResult<()> {
    if path.exists() {
        Ok(())
    } else {
        Err(PyFileNotFoundError::new_err(format!("{}: no such file or folder", path.display())))
    }
}

/// JSON (a table's footer, a summary) as the Python objects `json.loads` would give.
pub(crate) fn json_to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    let json = py.import("json")?;
    json.call_method1("loads", (v.to_string(),))
}

/// Any pgser table (trajectory, transition, batches) as a `pyarrow.Table`, optionally only
/// `columns`, once their column chunks match the footer's checksums (a corrupt file raises
/// `ValueError` with `pgser-etl verify`'s line). The Parquet reader's Arrow buffers are handed to
/// pyarrow as they are; the footer
/// stays in the schema's metadata under `pgser` (`read_footer` parses it).
#[pyfunction]
#[pyo3(signature = (path, columns=None))]
fn read_table(py: Python<'_>, path: PathBuf, columns: Option<Vec<String>>) -> PyResult<Py<PyAny>> {
    existing(&path)?;
    let batches = py.detach(|| read_batches(&path, columns.as_deref())).map_err(py_err)?;
    let (schema, batches) = batches;
    let reader = arrow_array::RecordBatchIterator::new(batches.into_iter().map(Ok), schema);
    let reader: Box<dyn RecordBatchReader + Send> = Box::new(reader);
    let pa_reader = reader.into_pyarrow(py)?;
    Ok(pa_reader.call_method0("read_all")?.unbind())
}

type Batches = (arrow_schema::SchemaRef, Vec<RecordBatch>);

fn read_batches(path: &Path, columns: Option<&[String]>) -> anyhow::Result<Batches> {
    if pgser::trajectory::folder::is_folder(path) {
        return read_folder(path, columns);
    }
    read_file(path, columns)
}

/// A table folder as one table: its shards in order, `episode` numbered across the folder (each
/// shard file numbers its own from 0), and the manifest's footer (the shards' shared one with the
/// folder's totals) in the schema's metadata.
fn read_folder(dir: &Path, columns: Option<&[String]>) -> anyhow::Result<Batches> {
    use arrow_array::{Array, Int64Array};
    let folder = pgser::trajectory::folder::TableFolder::open(dir)?;
    let footer = serde_json::to_string(folder.footer())?;
    let mut out = Vec::new();
    let mut schema = None;
    for (shard, path) in folder.manifest.shards.iter().zip(folder.shard_paths()) {
        let (s, batches) = read_file(&path, columns)?;
        let mut metadata = s.metadata().clone();
        metadata.insert(pgser::table::FOOTER_KEY.to_string(), footer.clone());
        let s = schema.get_or_insert_with(|| std::sync::Arc::new(s.as_ref().clone().with_metadata(metadata))).clone();
        for b in batches {
            let mut cols = b.columns().to_vec();
            if let Ok(i) = s.index_of("episode") {
                let e = cols[i].as_any().downcast_ref::<Int64Array>().expect("episode is int64");
                let first = shard.first_episode as i64;
                cols[i] = std::sync::Arc::new(e.iter().map(|v| v.map(|v| v + first)).collect::<Int64Array>());
                debug_assert_eq!(cols[i].len(), b.num_rows());
            }
            out.push(RecordBatch::try_new(s.clone(), cols)?);
        }
    }
    Ok((schema.expect("a folder has shards"), out))
}

fn read_file(path: &Path, columns: Option<&[String]>) -> anyhow::Result<Batches> {
    use anyhow::Context;
    let at = path.display();
    // pyarrow gets the decoded buffers as they are: the chunks it will get are checked first.
    let names: Option<Vec<&str>> = columns.map(|c| c.iter().map(String::as_str).collect());
    let (mut b, _) = pgser::table::open_checked(path, names.as_deref())?;
    if let Some(cols) = columns {
        let names: Vec<&str> = b.schema().fields().iter().map(|f| f.name().as_str()).collect();
        if let Some(bad) = cols.iter().find(|c| !names.contains(&c.as_str())) {
            anyhow::bail!("{at}: no column {bad} (columns: {})", names.join(", "));
        }
        let mask = ProjectionMask::columns(b.parquet_schema(), cols.iter().map(String::as_str));
        b = b.with_projection(mask);
    }
    // The file's key-value metadata (the `pgser` footer among it) rides on the schema, as
    // pyarrow.parquet.read_table has it.
    let metadata = b.schema().metadata().clone();
    let reader = b.with_batch_size(65_536).build().with_context(|| format!("{at}: cannot read"))?;
    let schema = std::sync::Arc::new(reader.schema().as_ref().clone().with_metadata(metadata));
    let batches = reader
        .map(|b| Ok(b?.with_schema(schema.clone())?))
        .collect::<anyhow::Result<Vec<_>>>()
        .with_context(|| format!("{at}: cannot read"))?;
    Ok((schema, batches))
}

/// A pgser table's footer (the `pgser` key of its Parquet metadata) as a dict.
#[pyfunction]
fn read_footer(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyAny>> {
    existing(&path)?;
    let footer = if pgser::trajectory::folder::is_folder(&path) {
        // A table folder's footer: the manifest's (the shards' shared one, the folder's totals).
        let folder = pgser::trajectory::folder::TableFolder::open(&path).map_err(py_err)?;
        serde_json::to_value(folder.footer()).map_err(|e| py_err(e.into()))?
    } else {
        pgser::table::read_footer(&path).map_err(py_err)?
    };
    json_to_py(py, &footer)
}

/// `pgser-etl convert`: WGCSL pickles (never executed) or one Minari dataset folder into a
/// trajectory table. Returns a summary dict; notes the CLI prints are in `notes`.
#[pyfunction]
#[pyo3(signature = (inputs, output, *, task=None, threshold=None, episodes=None, float32=false,
    allow_nonfinite=false, exact_length=false, row_group_rows=65_536, full_goal=false, drop=Vec::new()))]
#[allow(clippy::too_many_arguments)]
fn convert<'py>(
    py: Python<'py>,
    inputs: Vec<PathBuf>,
    output: PathBuf,
    task: Option<String>,
    threshold: Option<f64>,
    episodes: Option<Vec<usize>>,
    float32: bool,
    allow_nonfinite: bool,
    exact_length: bool,
    row_group_rows: usize,
    full_goal: bool,
    drop: Vec<String>,
) -> PyResult<Bound<'py, PyAny>> {
    for i in &inputs {
        existing(i)?;
    }
    let command = format!(
        "pgser.convert({})",
        inputs.iter().map(|p| format!("{:?}", p.display().to_string())).collect::<Vec<_>>().join(", ")
    );
    let opts = pgser::convert::ConvertOptions {
        inputs,
        output: output.clone(),
        task,
        threshold,
        episodes,
        float32,
        allow_nonfinite,
        exact_length,
        row_group_rows,
        full_goal,
        drop,
        command,
    };
    let s = interruptible(py, |bar| pgser::convert::convert(&opts, bar))?;
    let mut notes: Vec<String> = s.skipped_keys.iter().map(|k| format!("left out {k} (drop=)")).collect();
    notes.extend(s.notes.iter().cloned());
    let summary = serde_json::json!({
        "output": output, "task": s.task.name, "float_type": s.float_type.name(), "episodes": s.episodes,
        "rows": s.rows, "bytes": s.bytes, "notes": notes, "kept": s.kept,
    });
    json_to_py(py, &summary)
}

/// `pgser-etl score`: goal-swapped transitions of a trajectory table with the Q of a critic
/// checkpoint. Returns the summary `--json` prints, as a dict.
#[pyfunction]
#[pyo3(signature = (q, data, output, *, swaps=pgser::score::DEFAULT_SWAPS, seed=0, include_original=false,
    chunk_episodes=None, goal_sample=None, threads=0))]
#[allow(clippy::too_many_arguments)]
fn score<'py>(
    py: Python<'py>,
    q: PathBuf,
    data: PathBuf,
    output: PathBuf,
    swaps: usize,
    seed: u64,
    include_original: bool,
    chunk_episodes: Option<usize>,
    goal_sample: Option<usize>,
    threads: usize,
) -> PyResult<Bound<'py, PyAny>> {
    existing(&q)?;
    existing(&data)?;
    let command = format!("pgser.score(q={:?}, data={:?})", q.display().to_string(), data.display().to_string());
    let o = pgser::score::ScoreOptions {
        checkpoint: q,
        data,
        output,
        swaps,
        seed,
        include_original,
        device: pgser::agent::Backend::Cpu,
        chunk_episodes,
        goal_sample,
        threads,
        shard: None,
        command,
    };
    let s = interruptible(py, |bar| pgser::score::score(&o, bar))?;
    json_to_py(py, &serde_json::to_value(&s).map_err(|e| py_err(e.into()))?)
}

/// The task's dimensions and constants as a dict (name, T, obs_dim, goal_dim, act_dim,
/// threshold, metric), for any task pgser knows.
/// OGBench's goal map φ for an environment (`antmaze-large-v0`, `cube-double-v0`): the goal
/// values of observations (n, obs_dim) or (obs_dim,), as pgser's tables hold goals (the agent's
/// x, y; the cubes' positions). OGBench evaluates with a whole goal observation (`info["goal"]`):
/// this is the goal a pgser agent takes for it.
#[pyfunction]
fn ogbench_goal<'py>(py: Python<'py>, env: &str, observations: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    use numpy::{IntoPyArray, PyUntypedArrayMethods};
    let np = py.import("numpy")?;
    let a: numpy::PyReadonlyArrayDyn<'py, f64> =
        np.call_method1("ascontiguousarray", (observations, "float64"))?.extract()?;
    let shape = a.shape().to_vec();
    let (n, dim) = match shape.as_slice() {
        [d] => (None, *d),
        [n, d] => (Some(*n), *d),
        _ => return Err(PyValueError::new_err(format!("observations must be (n, dim) or (dim,), got {shape:?}"))),
    };
    let map = pgser::ogbench::goal_map(env, dim).map_err(py_err)?;
    let values = a.as_slice()?;
    let goals: Vec<f64> = values.chunks_exact(dim.max(1)).flat_map(|row| map.map(row)).collect();
    let g = map.goal_dim();
    let arr = numpy::ndarray::ArrayD::from_shape_vec(
        match n {
            Some(n) => vec![n, g],
            None => vec![g],
        },
        goals,
    )
    .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(arr.into_pyarray(py).into_any())
}

#[pyfunction]
fn task_info<'py>(py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
    let task = pgser::env::task(name).map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
    json_to_py(py, &serde_json::to_value(&task).map_err(|e| py_err(e.into()))?)
}

#[pymodule]
fn _pgser(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // "0.4.0 (MuJoCo 3.17.0)": the library actually loaded, as `pgser-etl --version` says.
    m.add("long_version", pgser::cli::LONG_VERSION.as_str())?;
    m.add_function(wrap_pyfunction!(read_table, m)?)?;
    m.add_function(wrap_pyfunction!(read_footer, m)?)?;
    m.add_function(wrap_pyfunction!(convert, m)?)?;
    m.add_function(wrap_pyfunction!(score, m)?)?;
    m.add_function(wrap_pyfunction!(task_info, m)?)?;
    m.add_function(wrap_pyfunction!(ogbench_goal, m)?)?;
    m.add_function(wrap_pyfunction!(envs::compute_reward, m)?)?;
    m.add_class::<sampler::Sampler>()?;
    m.add_class::<envs::Env>()?;
    m.add_class::<envs::VecEnv>()?;
    m.add_class::<envs::Policy>()?;
    Ok(())
}
