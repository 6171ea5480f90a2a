//! `pgser-etl convert`: WGCSL pickles → trajectory table.
//!
//! Every input is memory-mapped and parsed by the safe pickle reader; all keys, shapes, dtypes
//! and dimensions are validated before the output is created. Then episodes stream out in row
//! groups of whole episodes, built and encoded in parallel windows, so memory stays near one
//! copy of the inputs (the mapped pages) plus a few row groups.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use arrow_array::types::{Float32Type, Float64Type};
use arrow_array::{
    ArrayRef, ArrowPrimitiveType, FixedSizeListArray, Int32Array, Int64Array, PrimitiveArray, RecordBatch,
};
use arrow_buffer::{BooleanBuffer, NullBuffer, ScalarBuffer};
use arrow_schema::{DataType, Field, SchemaRef};
use indicatif::ProgressBar;
use rayon::prelude::*;
use sha2::{Digest, Sha256};

use super::{FloatType, Footer, SourceFile, schema};
use crate::pickle::{DTypeKind, MappedFile, NdArray, Obj, Pickle};
use crate::table::TableWriter;
use crate::task::Task;

#[derive(Debug, Clone)]
pub struct ConvertOptions {
    pub inputs: Vec<PathBuf>,
    pub output: PathBuf,
    /// Task name; inferred from the dimensions when absent and unambiguous.
    pub task: Option<String>,
    /// Success threshold: required for tasks pgser does not know, an override otherwise.
    pub threshold: Option<f64>,
    /// Take the first k_i episodes of input i (GoFAR's expert/random mix).
    pub episodes: Option<Vec<usize>>,
    pub float32: bool,
    pub allow_nonfinite: bool,
    /// Target rows per row group; row groups always hold whole episodes.
    pub row_group_rows: usize,
    /// The command line, recorded in the footer.
    pub command: String,
}

#[derive(Debug, Clone)]
pub struct ConvertSummary {
    pub task: Task,
    pub float_type: FloatType,
    pub episodes: usize,
    pub rows: usize,
    pub bytes: u64,
    /// "file: key" for keys that are not part of the WGCSL format and were left out.
    pub skipped_keys: Vec<String>,
}

const KEYS: [&str; 4] = ["o", "ag", "u", "g"];

/// One input's four arrays, validated.
struct Source<'a> {
    path: &'a Path,
    /// o, ag, u, g in native C order.
    arrays: [NdArray<'a>; 4],
    episodes: usize,
    take: usize,
}

impl Source<'_> {
    fn o(&self) -> &NdArray<'_> {
        &self.arrays[0]
    }
    fn dim(&self, k: usize) -> usize {
        self.arrays[k].shape[2]
    }
}

pub fn convert(opts: &ConvertOptions, bar: &ProgressBar) -> Result<ConvertSummary> {
    if opts.inputs.is_empty() {
        bail!("convert needs at least one input pickle");
    }
    crate::output::check_not_an_input(&opts.output, &opts.inputs)?;
    if let Some(ks) = &opts.episodes
        && ks.len() != opts.inputs.len()
    {
        bail!("--episodes has {} values for {} input files: give one count per input", ks.len(), opts.inputs.len());
    }

    let maps: Vec<MappedFile> = opts
        .inputs
        .iter()
        .map(|p| MappedFile::open(p).with_context(|| format!("{}: cannot open", p.display())))
        .collect::<Result<_>>()?;
    // Hash the inputs on a thread of their own while we parse, validate and write.
    std::thread::scope(|scope| {
        let hashes = scope.spawn(|| maps.iter().map(sha256_releasing).collect::<Vec<_>>());
        let mut skipped_keys = Vec::new();
        let mut sources = Vec::with_capacity(maps.len());
        for (i, (path, map)) in opts.inputs.iter().zip(&maps).enumerate() {
            let (mut src, skipped) = read_wgcsl(path, map.bytes())?;
            skipped_keys.extend(skipped.into_iter().map(|k| format!("{}: {k}", path.display())));
            if let Some(ks) = &opts.episodes {
                if ks[i] > src.episodes {
                    bail!(
                        "{}: --episodes asks for {} episodes but the file has {}",
                        path.display(),
                        ks[i],
                        src.episodes
                    );
                }
                src.take = ks[i];
            }
            sources.push(src);
        }
        let float_type = output_float(&sources, opts.float32)?;
        let task = resolve_task(&sources, opts.task.as_deref(), opts.threshold)?;
        let total: usize = sources.iter().map(|s| s.take).sum();
        if total == 0 {
            bail!("{}: no episodes to write (every input was empty or took 0)", opts.inputs[0].display());
        }

        bar.set_length((total * task.t) as u64);
        let schema = schema(float_type, &task);
        let mut writer = TableWriter::create(&opts.output, schema.clone())?;
        let units = row_group_units(&sources, task.t, opts.row_group_rows);
        let window = rayon::current_num_threads().max(1) * 2;
        for chunk in units.chunks(window) {
            let batches: Vec<RecordBatch> = chunk
                .par_iter()
                .map(|u| build_batch(&sources[u.source], u, &schema, float_type, opts.allow_nonfinite))
                .collect::<Result<_>>()?;
            writer.write_row_groups(&batches)?;
            bar.inc(batches.iter().map(|b| b.num_rows() as u64).sum());
            for u in chunk {
                let src = &sources[u.source];
                for a in &src.arrays {
                    let per_episode = a.data.len() / src.episodes;
                    maps[u.source].release(&a.data[u.start * per_episode..u.end * per_episode]);
                }
            }
        }

        let hashes = hashes.join().expect("hashing thread panicked");
        let mut footer = Footer::new(&task, float_type, total, opts.command.clone());
        footer.sources = sources
            .iter()
            .zip(hashes)
            .map(|(s, sha256)| SourceFile {
                path: s.path.display().to_string(),
                sha256,
                format: "wgcsl-pickle".into(),
                episodes_in_file: s.episodes,
                episodes_taken: s.take,
            })
            .collect();
        let bytes = writer.finish(&serde_json::to_value(&footer)?)?;
        Ok(ConvertSummary { task, float_type, episodes: total, rows: total * footer.t, bytes, skipped_keys })
    })
}

/// SHA-256 of a mapped file, releasing each part from memory once hashed.
fn sha256_releasing(map: &MappedFile) -> String {
    let mut h = Sha256::new();
    for part in map.bytes().chunks(16 << 20) {
        h.update(part);
        map.release(part);
    }
    hex(&h.finalize())
}

pub(crate) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Parse one pickle and check it is a WGCSL buffer: a dict with `o`, `ag`, `u`, `g`.
/// Returns the source and the names of keys that were skipped.
fn read_wgcsl<'a>(path: &'a Path, bytes: &'a [u8]) -> Result<(Source<'a>, Vec<String>)> {
    let at = path.display();
    let mut pickle = Pickle::parse(bytes).map_err(|e| anyhow::anyhow!("{at}: {e}"))?;
    let Obj::Dict(entries) = pickle.get(pickle.root()).clone() else {
        bail!(
            "{at}: the pickle holds a {}, expected a dict with keys o, ag, u, g (a WGCSL buffer)",
            pickle.get(pickle.root()).type_name()
        );
    };
    let mut found: [Option<NdArray<'a>>; 4] = [None, None, None, None];
    let mut skipped = Vec::new();
    for (k, v) in entries {
        let Some(name) = pickle.as_text(k).map(|s| s.into_owned()) else {
            skipped.push(format!("non-string key of type {}", pickle.get(k).type_name()));
            continue;
        };
        let Some(slot) = KEYS.iter().position(|&key| key == name) else {
            skipped.push(format!("key '{name}'"));
            continue;
        };
        match pickle.take(v) {
            Obj::Array(a) => found[slot] = Some(a),
            other => bail!("{at}: key '{name}' is a {}, not a numpy array", other.type_name()),
        }
    }
    let missing: Vec<&str> = KEYS.iter().zip(&found).filter(|(_, a)| a.is_none()).map(|(k, _)| *k).collect();
    if !missing.is_empty() {
        bail!("{at}: missing key '{}' (a WGCSL buffer has o, ag, u, g)", missing.join("', '"));
    }
    let arrays = found.map(|a| a.expect("checked above"));
    for (key, a) in KEYS.iter().zip(&arrays) {
        if a.dtype.kind != DTypeKind::Float || a.dtype.size < 4 {
            bail!("{at}: key '{key}' holds {} values; WGCSL arrays must be float32 or float64", a.dtype.name());
        }
        if a.shape.len() != 3 {
            bail!("{at}: key '{key}' has shape {}; expected 3 dimensions (episodes, steps, values)", a.shape_text());
        }
    }
    let n: Vec<usize> = arrays.iter().map(|a| a.shape[0]).collect();
    if n.iter().any(|&x| x != n[0]) {
        bail!("{at}: episode count differs across keys: o has {}, ag {}, u {}, g {}", n[0], n[1], n[2], n[3]);
    }
    if n[0] == 0 {
        bail!("{at}: the file has no episodes (N = 0)");
    }
    let steps: Vec<usize> = arrays.iter().map(|a| a.shape[1]).collect();
    let t = steps[0];
    if steps[1] != t {
        bail!("{at}: steps differ: o has {t} steps per episode, ag has {}", steps[1]);
    }
    if t < 2 {
        bail!("{at}: episodes have {t} steps; at least 2 observations are needed for a transition");
    }
    for k in [2, 3] {
        if steps[k] != t - 1 {
            bail!(
                "{at}: key '{}' has {} steps per episode; expected T-1 = {} (o has T = {t} observations)",
                KEYS[k],
                steps[k],
                t - 1
            );
        }
    }
    let (ag_dim, g_dim) = (arrays[1].shape[2], arrays[3].shape[2]);
    if ag_dim != g_dim {
        bail!("{at}: goal dimension differs: ag has {ag_dim} values per step, g has {g_dim}");
    }
    let episodes = n[0];
    Ok((Source { path, arrays, episodes, take: episodes }, skipped))
}

fn output_float(sources: &[Source], float32: bool) -> Result<FloatType> {
    if float32 {
        return Ok(FloatType::Float32);
    }
    let size = sources[0].o().dtype.size;
    for s in sources {
        for (key, a) in KEYS.iter().zip(&s.arrays) {
            if a.dtype.size != size {
                bail!(
                    "{}: key '{key}' is {} but '{}' key 'o' is {}: mixed float types; pass --float32 to store all as float32",
                    s.path.display(),
                    a.dtype.name(),
                    sources[0].path.display(),
                    sources[0].o().dtype.name()
                );
            }
        }
    }
    Ok(if size == 4 { FloatType::Float32 } else { FloatType::Float64 })
}

/// Pick the task: the named one (dimensions must match), a custom one (`--threshold`), or the
/// single built-in task whose dimensions match the data.
fn resolve_task(sources: &[Source], name: Option<&str>, threshold: Option<f64>) -> Result<Task> {
    let first = &sources[0];
    let dims = |s: &Source| (s.o().shape[1], s.dim(0), s.dim(1), s.dim(2));
    let (t, obs, goal, act) = dims(first);
    for s in &sources[1..] {
        if dims(s) != dims(first) {
            let (t2, o2, g2, a2) = dims(s);
            bail!(
                "{}: dimension mismatch with {}: T {t2} vs {t}, obs {o2} vs {obs}, goal {g2} vs {goal}, act {a2} vs {act}",
                s.path.display(),
                first.path.display()
            );
        }
    }
    if let Some(th) = threshold
        && !(th.is_finite() && th > 0.0)
    {
        bail!("--threshold must be a positive number, got {th}");
    }
    let at = first.path.display();
    let mut task = match name {
        Some(name) => match Task::known(name) {
            Some(task) => {
                for (key, have, want, what) in [
                    ("o", obs, task.obs_dim, "observations"),
                    ("ag", goal, task.goal_dim, "goals"),
                    ("u", act, task.act_dim, "actions"),
                ] {
                    if have != want {
                        bail!(
                            "{at}: dimension mismatch: key '{key}' has {have} values per step but {} {what} have {want}",
                            task.name
                        );
                    }
                }
                if t != task.t {
                    bail!("{at}: episodes have {t} steps but {} has T = {}", task.name, task.t);
                }
                task
            }
            None => match threshold {
                Some(th) => Task::custom(name, t, obs, goal, act, th),
                None => bail!(
                    "{at}: task '{name}' is not built in (known: {}); pass --threshold to give its success threshold",
                    Task::known_names().join(", ")
                ),
            },
        },
        None => {
            let matches = Task::matching(t, obs, goal, act);
            match matches.as_slice() {
                [one] => one.clone(),
                [] => bail!(
                    "{at}: no built-in task has T {t}, obs {obs}, goal {goal}, act {act}; pass --task NAME --threshold X"
                ),
                many => bail!(
                    "{at}: the dimensions fit {}; pass --task to choose",
                    many.iter().map(|t| t.name.as_str()).collect::<Vec<_>>().join(", ")
                ),
            }
        }
    };
    if let Some(th) = threshold {
        task.threshold = th;
    }
    Ok(task)
}

/// A row group: episodes [start, end) of one source, numbered from `first_episode` in the table.
struct Unit {
    source: usize,
    start: usize,
    end: usize,
    first_episode: usize,
}

fn row_group_units(sources: &[Source], t: usize, row_group_rows: usize) -> Vec<Unit> {
    let per_group = (row_group_rows / t).max(1);
    let mut units = Vec::new();
    let mut next = 0;
    for (i, s) in sources.iter().enumerate() {
        for start in (0..s.take).step_by(per_group) {
            let end = (start + per_group).min(s.take);
            units.push(Unit { source: i, start, end, first_episode: next + start });
        }
        next += s.take;
    }
    units
}

fn build_batch(
    src: &Source,
    u: &Unit,
    schema: &SchemaRef,
    out: FloatType,
    allow_nonfinite: bool,
) -> Result<RecordBatch> {
    let t = src.o().shape[1];
    let n = u.end - u.start;
    let rows = n * t;
    let episode = Int64Array::from_iter_values((0..rows).map(|r| (u.first_episode + r / t) as i64));
    let step = Int32Array::from_iter_values((0..rows).map(|r| (r % t) as i32));
    let mut columns: Vec<ArrayRef> = vec![Arc::new(episode), Arc::new(step)];
    // Table column order: obs (o), achieved_goal (ag), desired_goal (g), action (u).
    for key_index in [0, 1, 3, 2] {
        let padded = key_index >= 2;
        let col = vector_column(src, key_index, u.start, u.end, t, padded, out, allow_nonfinite)?;
        columns.push(col);
    }
    Ok(RecordBatch::try_new(schema.clone(), columns)?)
}

/// Episodes [e0, e1) of one array as a FixedSizeList column. `padded` arrays (u, g) have T − 1
/// steps per episode and get a null row on the last step.
#[allow(clippy::too_many_arguments)]
fn vector_column(
    src: &Source,
    key_index: usize,
    e0: usize,
    e1: usize,
    t: usize,
    padded: bool,
    out: FloatType,
    allow_nonfinite: bool,
) -> Result<ArrayRef> {
    let a = &src.arrays[key_index];
    let (steps, dim) = (a.shape[1], a.shape[2]);
    let size = a.dtype.size;
    let bytes = &a.data[e0 * steps * dim * size..e1 * steps * dim * size];
    let values: ArrayRef = match (size, out) {
        (8, FloatType::Float64) => copy_episodes::<Float64Type>(bytes, steps * dim, padded, dim),
        (4, FloatType::Float32) => copy_episodes::<Float32Type>(bytes, steps * dim, padded, dim),
        (4, FloatType::Float64) => {
            gather::<Float64Type>(bytes, 4, steps, dim, padded, |c| f32::from_le_bytes(c.try_into().unwrap()) as f64)
        }
        _ => gather::<Float32Type>(bytes, 8, steps, dim, padded, |c| f64::from_le_bytes(c.try_into().unwrap()) as f32),
    };
    if !allow_nonfinite {
        check_finite(src, key_index, e0, t, dim, out, &values)?;
    }
    let rows = (e1 - e0) * t;
    let nulls = padded.then(|| NullBuffer::new(BooleanBuffer::collect_bool(rows, |r| r % t != t - 1)));
    let item = Arc::new(Field::new("item", out.arrow(), false));
    Ok(Arc::new(FixedSizeListArray::try_new(item, dim as i32, values, nulls)?))
}

/// Same float type in and out: copy whole episodes as bytes (the source is native-endian but
/// may be unaligned, so it cannot be reinterpreted in place).
fn copy_episodes<T: ArrowPrimitiveType>(bytes: &[u8], per_episode: usize, padded: bool, dim: usize) -> ArrayRef {
    let size = std::mem::size_of::<T::Native>();
    let episodes = bytes.len() / (per_episode * size).max(1);
    let pad = if padded { dim } else { 0 };
    let mut buf = arrow_buffer::MutableBuffer::with_capacity(episodes * (per_episode + pad) * size);
    for ep in bytes.chunks_exact(per_episode * size) {
        buf.extend_from_slice(ep);
        buf.extend_zeros(pad * size);
    }
    let values = ScalarBuffer::<T::Native>::from(arrow_buffer::Buffer::from(buf));
    Arc::new(PrimitiveArray::<T>::new(values, None))
}

/// Different float types: convert element by element.
fn gather<T: ArrowPrimitiveType>(
    bytes: &[u8],
    size: usize,
    steps: usize,
    dim: usize,
    padded: bool,
    conv: impl Fn(&[u8]) -> T::Native,
) -> ArrayRef {
    let per_episode = steps * dim * size;
    let episodes = bytes.len() / per_episode.max(1);
    let mut v: Vec<T::Native> = Vec::with_capacity(episodes * (steps + padded as usize) * dim);
    for ep in bytes.chunks_exact(per_episode) {
        v.extend(ep.chunks_exact(size).map(&conv));
        if padded {
            v.extend(std::iter::repeat_n(T::Native::default(), dim));
        }
    }
    Arc::new(PrimitiveArray::<T>::new(ScalarBuffer::from(v), None))
}

#[allow(clippy::too_many_arguments)]
fn check_finite(
    src: &Source,
    key_index: usize,
    e0: usize,
    t: usize,
    dim: usize,
    out: FloatType,
    values: &ArrayRef,
) -> Result<()> {
    let as_f64: Box<dyn Fn(usize) -> f64> = match values.data_type() {
        DataType::Float64 => {
            let v = values.as_any().downcast_ref::<PrimitiveArray<Float64Type>>().unwrap().values().clone();
            if v.iter().all(|x| x.is_finite()) {
                return Ok(());
            }
            Box::new(move |i| v[i])
        }
        _ => {
            let v = values.as_any().downcast_ref::<PrimitiveArray<Float32Type>>().unwrap().values().clone();
            if v.iter().all(|x| x.is_finite()) {
                return Ok(());
            }
            Box::new(move |i| v[i] as f64)
        }
    };
    let len = values.len();
    let i = (0..len).find(|&i| !as_f64(i).is_finite()).expect("a non-finite value exists");
    let row = i / dim;
    let (episode, step, index) = (e0 + row / t, row % t, i % dim);
    let a = &src.arrays[key_index];
    // Report the source value: a finite float64 that overflowed float32 says so.
    let size = a.dtype.size;
    let src_index = ((episode * a.shape[1] + step) * dim + index) * size;
    let original = if size == 8 {
        f64::from_le_bytes(a.data[src_index..src_index + 8].try_into().unwrap())
    } else {
        f32::from_le_bytes(a.data[src_index..src_index + 4].try_into().unwrap()) as f64
    };
    let what = if original.is_finite() {
        format!("value {original:e} overflows {}", out.name())
    } else {
        format!("non-finite value {original}")
    };
    bail!(
        "{}: {what} in key '{}' at episode {episode}, step {step}, index {index}; pass --allow-nonfinite to keep it",
        src.path.display(),
        KEYS[key_index]
    )
}
