//! Row groups of the trajectory table, built from the four WGCSL arrays.
//!
//! `convert` (arrays parsed from pickles) and `collect` (arrays simulated a chunk at a time)
//! both hand their episodes to [`TrajectoryWriter`] as an [`EpisodeArrays`], so one code path
//! decides a table's bytes: the same episodes make the same table whichever command wrote it.
//! Row groups hold whole episodes; a window of them is built and encoded in parallel and
//! appended in order, so the bytes never depend on the thread count.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Result, bail};
use arrow_array::types::{Float32Type, Float64Type};
use arrow_array::{
    ArrayRef, ArrowPrimitiveType, FixedSizeListArray, Int32Array, Int64Array, PrimitiveArray, RecordBatch,
};
use arrow_buffer::{BooleanBuffer, NullBuffer, ScalarBuffer};
use arrow_schema::{DataType, Field, SchemaRef};
use rayon::prelude::*;

use super::extra::{self, ExtraArray, Passthrough};
use super::{FloatType, Footer, schema};
use crate::table::TableWriter;
use crate::task::Task;

/// The WGCSL keys, in the order [`EpisodeArrays::arrays`] holds them.
pub const KEYS: [&str; 4] = ["o", "ag", "u", "g"];

/// One WGCSL array `[episodes, steps, dim]`: little-endian, C-order float32 or float64 bytes
/// (borrowed from a mapped file, hence possibly unaligned: read with `from_le_bytes`), or, for
/// the observations of an image table ([`WriterOptions::image_shape`]), uint8 image bytes.
#[derive(Debug, Clone, Copy)]
pub struct FloatArray<'a> {
    pub data: &'a [u8],
    /// Bytes per value: 4 or 8 (1: an image's bytes).
    pub size: usize,
    pub steps: usize,
    pub dim: usize,
}

/// The four arrays of N episodes: o `[N,T,obs]`, ag `[N,T,goal]`, u `[N,T−1,act]`, g `[N,T−1,goal]`.
#[derive(Debug, Clone)]
pub struct EpisodeArrays<'a> {
    /// The source's other arrays, kept as passthrough columns (in the writer's order).
    pub extras: Vec<ExtraArray<'a>>,
    /// Names the data in error messages: a file path, or what was simulated.
    pub origin: String,
    /// What the source calls o, ag, u and g, for error messages: [`KEYS`] for WGCSL's pickles and
    /// what pgser simulates, `observations` and `actions` for OGBench's files, and so on. An
    /// error names the array as its user wrote it.
    pub keys: [&'static str; 4],
    /// o, ag, u, g.
    pub arrays: [FloatArray<'a>; 4],
    pub episodes: usize,
}

impl EpisodeArrays<'_> {
    /// Observations per episode.
    pub fn t(&self) -> usize {
        self.arrays[0].steps
    }
}

/// Whole episodes per row group for a target row count (at least one). `collect` cuts its
/// chunks on this too, so its row groups fall where `convert`'s do for the same episodes.
pub fn episodes_per_group(row_group_rows: usize, t: usize) -> usize {
    (row_group_rows / t).max(1)
}

/// Whole episodes per row group of an image table: [`episodes_per_group`], and at most
/// [`IMAGE_GROUP_BYTES`] of images of `image_bytes` each (at least one episode).
pub fn image_episodes_per_group(row_group_rows: usize, t: usize, image_bytes: usize) -> usize {
    episodes_per_group(row_group_rows, t).min(IMAGE_GROUP_BYTES / (t * image_bytes).max(1)).max(1)
}

/// How a [`TrajectoryWriter`] writes a table: what its caller (`convert` of each format,
/// `collect`, the online trainer's buffer) decides beyond the task and the float type.
#[derive(Debug, Clone)]
pub struct WriterOptions {
    /// Target rows per row group: each gets `row_group_rows / T` whole episodes (at least one).
    pub row_group_rows: usize,
    /// Keep NaN and ±Inf values instead of refusing them.
    pub allow_nonfinite: bool,
    /// The source's passthrough arrays, in the order each [`EpisodeArrays::extras`] gives them.
    pub extras: Vec<Passthrough>,
    /// An action on every episode's last step (`u` of T steps, not T − 1), as OGBench's files
    /// have one, kept on step T − 1.
    pub last_action: bool,
    /// Observations are uint8 images of this shape (`obs` holds `obs_dim` bytes a row: the
    /// footer's `image_shape`); empty for float observations.
    pub image_shape: Vec<usize>,
}

impl WriterOptions {
    /// Row groups of `row_group_rows`; finite values only, no passthrough columns, no last
    /// actions, float observations.
    pub fn new(row_group_rows: usize) -> WriterOptions {
        WriterOptions {
            row_group_rows,
            allow_nonfinite: false,
            extras: Vec::new(),
            last_action: false,
            image_shape: Vec::new(),
        }
    }
}

/// The most image bytes a row group of an image table holds (whole episodes, at least one):
/// 65,536 rows of 12 kB images would be a 805 MB row group, which every reader (a sampler's
/// block, a convert window) holds at once. 32 MiB is two 1001-step episodes of OGBench's
/// 64 × 64 × 3 images, and still large enough that a column chunk's pages amortize their reads.
pub const IMAGE_GROUP_BYTES: usize = 32 << 20;

/// Streams episodes into a trajectory table file (written atomically on `finish`).
pub struct TrajectoryWriter {
    table: TableWriter,
    schema: SchemaRef,
    task: Task,
    float: FloatType,
    allow_nonfinite: bool,
    per_group: usize,
    episodes: usize,
    /// The passthrough columns, after the six of every table.
    extras: Vec<Passthrough>,
    /// Whether `action` holds each episode's last action on step T − 1 (OGBench's files have it).
    last_action: bool,
    /// The shape of an image observation; empty for float observations.
    image_shape: Vec<usize>,
}

impl TrajectoryWriter {
    /// A table of `task`'s episodes in `float` at `dest`, written as `options` say.
    pub fn create(dest: &Path, task: &Task, float: FloatType, options: WriterOptions) -> Result<Self> {
        let WriterOptions { row_group_rows, allow_nonfinite, extras, last_action, image_shape } = options;
        let image = !image_shape.is_empty();
        let mut fields: Vec<arrow_schema::FieldRef> = schema(float, task, image).fields().iter().cloned().collect();
        fields.extend(extras.iter().map(|p| Arc::new(p.field())));
        let schema = Arc::new(arrow_schema::Schema::new(fields));
        let table = TableWriter::create(dest, schema.clone())?;
        let per_group = if image {
            image_episodes_per_group(row_group_rows, task.t, task.obs_dim)
        } else {
            episodes_per_group(row_group_rows, task.t)
        };
        Ok(Self {
            table,
            schema,
            task: task.clone(),
            float,
            allow_nonfinite,
            per_group,
            episodes: 0,
            extras,
            last_action,
            image_shape,
        })
    }

    /// Episodes per row group.
    pub fn episodes_per_group(&self) -> usize {
        self.per_group
    }

    /// Episodes appended so far.
    pub fn episodes(&self) -> usize {
        self.episodes
    }

    /// Append episodes [start, end) of `src`, numbered on from those already written, in row
    /// groups of [`episodes_per_group`](Self::episodes_per_group) counted from `start` (the
    /// last may be shorter). Callers that append a large source piecewise pass multiples of
    /// the group size as `start`, so the file does not depend on how they cut it.
    pub fn append(&mut self, src: &EpisodeArrays, start: usize, end: usize) -> Result<()> {
        self.check_shape(src)?;
        assert!(start <= end && end <= src.episodes, "append: episodes {start}..{end} of {}", src.episodes);
        let groups: Vec<(usize, usize)> =
            (start..end).step_by(self.per_group).map(|s| (s, (s + self.per_group).min(end))).collect();
        let next = self.episodes;
        let image = !self.image_shape.is_empty();
        let batches: Vec<RecordBatch> = groups
            .par_iter()
            .map(|&(e0, e1)| {
                let out = Out { float: self.float, image, allow_nonfinite: self.allow_nonfinite };
                build_batch(src, e0, e1, next + (e0 - start), &self.schema, out)
            })
            .collect::<Result<_>>()?;
        self.table.write_row_groups(&batches)?;
        self.episodes += end - start;
        Ok(())
    }

    fn check_shape(&self, src: &EpisodeArrays) -> Result<()> {
        let t = &self.task;
        let act_steps = if self.last_action { t.t } else { t.t - 1 };
        let want = [(t.t, t.obs_dim), (t.t, t.goal_dim), (act_steps, t.act_dim), (t.t - 1, t.goal_dim)];
        let image = !self.image_shape.is_empty();
        for (k, ((name, a), (steps, dim))) in src.keys.iter().zip(&src.arrays).zip(want).enumerate() {
            let bytes = src.episodes * steps * dim * a.size;
            let sized = if image && k == 0 { a.size == 1 } else { matches!(a.size, 4 | 8) };
            if (a.steps, a.dim) != (steps, dim) || !sized || a.data.len() != bytes {
                bail!(
                    "{}: `{name}` is {} episodes × {} × {} values of {} bytes in {} bytes; {} needs {steps} × {dim}",
                    src.origin,
                    src.episodes,
                    a.steps,
                    a.dim,
                    a.size,
                    a.data.len(),
                    t.name
                );
            }
        }
        let names = |v: &mut dyn Iterator<Item = &Passthrough>| v.map(|p| p.column.clone()).collect::<Vec<_>>();
        if names(&mut src.extras.iter().map(|e| &e.spec)) != names(&mut self.extras.iter()) {
            bail!(
                "{}: passthrough arrays {:?} where the table has {:?}",
                src.origin,
                names(&mut src.extras.iter().map(|e| &e.spec)),
                names(&mut self.extras.iter())
            );
        }
        for e in &src.extras {
            let want = src.episodes * e.spec.episode_bytes(t.t);
            if e.data.len() != want {
                bail!(
                    "{}: `{}` has {} bytes; {} episodes of it need {want}",
                    src.origin,
                    e.spec.column,
                    e.data.len(),
                    src.episodes
                );
            }
        }
        Ok(())
    }

    /// Write the footer and move the file into place. Returns its size in bytes. The footer
    /// gets the passthrough columns' records and the last-action flag from the writer.
    pub fn finish(self, footer: &Footer) -> Result<u64> {
        debug_assert_eq!(footer.episodes, self.episodes);
        let footer = self.complete(footer);
        self.table.finish(&serde_json::to_value(footer)?)
    }

    /// Write the footer, leaving the file for the caller to commit (`TableWriter::finish_staged`).
    pub fn finish_staged(self, footer: &Footer) -> Result<crate::output::AtomicFile> {
        debug_assert_eq!(footer.episodes, self.episodes);
        let footer = self.complete(footer);
        self.table.finish_staged(&serde_json::to_value(footer)?)
    }

    /// The caller's footer with what the writer knows: the passthrough columns' records, the
    /// last-action flag and the image shape.
    fn complete(&self, footer: &Footer) -> Footer {
        Footer {
            passthrough: self.extras.clone(),
            last_action: self.last_action,
            image_shape: self.image_shape.clone(),
            ..footer.clone()
        }
    }
}

/// How a batch's columns are written: the vectors' float type, whether observations are image
/// bytes, and whether non-finite floats are kept.
#[derive(Clone, Copy)]
struct Out {
    float: FloatType,
    image: bool,
    allow_nonfinite: bool,
}

/// Episodes [e0, e1) of `src` as one record batch, numbered from `first_episode`.
fn build_batch(
    src: &EpisodeArrays,
    e0: usize,
    e1: usize,
    first_episode: usize,
    schema: &SchemaRef,
    out: Out,
) -> Result<RecordBatch> {
    let t = src.t();
    let rows = (e1 - e0) * t;
    let episode = Int64Array::from_iter_values((0..rows).map(|r| (first_episode + r / t) as i64));
    let step = Int32Array::from_iter_values((0..rows).map(|r| (r % t) as i32));
    let mut columns: Vec<ArrayRef> = vec![Arc::new(episode), Arc::new(step)];
    // Table column order: obs (o), achieved_goal (ag), desired_goal (g), action (u).
    for key_index in [0, 1, 3, 2] {
        columns.push(if key_index == 0 && out.image {
            image_column(&src.arrays[0], e0, e1)?
        } else {
            vector_column(src, key_index, e0, e1, out.float, out.allow_nonfinite)?
        });
    }
    for e in &src.extras {
        columns.push(extra::column(e, t, e0, e1)?);
    }
    Ok(RecordBatch::try_new(schema.clone(), columns)?)
}

/// Episodes [e0, e1) of one array as a FixedSizeList column. u and g have T − 1 steps per
/// episode and get a null row on the last step.
fn vector_column(
    src: &EpisodeArrays,
    key_index: usize,
    e0: usize,
    e1: usize,
    out: FloatType,
    allow_nonfinite: bool,
) -> Result<ArrayRef> {
    let a = &src.arrays[key_index];
    let (t, steps, dim, size) = (src.t(), a.steps, a.dim, a.size);
    let padded = steps < t;
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
        check_finite(src, key_index, e0, out, &values)?;
    }
    let rows = (e1 - e0) * t;
    let nulls = padded.then(|| NullBuffer::new(BooleanBuffer::collect_bool(rows, |r| r % t != t - 1)));
    let item = Arc::new(Field::new("item", out.arrow(), false));
    Ok(Arc::new(FixedSizeListArray::try_new(item, dim as i32, values, nulls)?))
}

/// Episodes [e0, e1) of image observations (one byte a value) as a FixedSizeBinary column, a
/// row per image, the bytes copied once.
fn image_column(a: &FloatArray, e0: usize, e1: usize) -> Result<ArrayRef> {
    let per_episode = a.steps * a.dim;
    let bytes = arrow_buffer::Buffer::from(&a.data[e0 * per_episode..e1 * per_episode]);
    Ok(Arc::new(arrow_array::FixedSizeBinaryArray::try_new(a.dim as i32, bytes, None)?))
}

/// Same float type in and out: copy whole episodes as bytes (the source may be unaligned, so
/// it cannot be reinterpreted in place).
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

/// Refuse NaN/±Inf (and float64 values that overflow float32), naming where the first is.
fn check_finite(src: &EpisodeArrays, key_index: usize, e0: usize, out: FloatType, values: &ArrayRef) -> Result<()> {
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
    let (t, a) = (src.t(), &src.arrays[key_index]);
    let dim = a.dim;
    let i = (0..values.len()).find(|&i| !as_f64(i).is_finite()).expect("a non-finite value exists");
    let row = i / dim;
    let (episode, step, index) = (e0 + row / t, row % t, i % dim);
    // Report the source value: a finite float64 that overflowed float32 says so.
    let at = ((episode * a.steps + step) * dim + index) * a.size;
    let original = if a.size == 8 {
        f64::from_le_bytes(a.data[at..at + 8].try_into().unwrap())
    } else {
        f32::from_le_bytes(a.data[at..at + 4].try_into().unwrap()) as f64
    };
    let what = if original.is_finite() {
        format!("value {original:e} overflows {}", out.name())
    } else {
        format!("non-finite value {original}")
    };
    bail!(
        "{}: {what} in key '{}' at episode {episode}, step {step}, index {index}; pass --allow-nonfinite to keep it",
        src.origin,
        src.keys[key_index]
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow_array::Array;
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

    /// Five 3-step episodes of a 1-d task; every value is episode·100 + step·10 + index.
    fn arrays() -> (Task, [Vec<u8>; 4]) {
        let task = Task::custom("Tiny", 3, 2, 1, 1, 0.1);
        let make = |steps: usize, dim: usize| -> Vec<u8> {
            (0..5)
                .flat_map(|e| (0..steps).flat_map(move |s| (0..dim).map(move |i| (e * 100 + s * 10 + i) as f64)))
                .flat_map(|v| v.to_le_bytes())
                .collect()
        };
        (task, [make(3, 2), make(3, 1), make(2, 1), make(2, 1)])
    }

    fn view<'a>(data: &'a [Vec<u8>; 4], task: &Task) -> EpisodeArrays<'a> {
        let dims = [(task.t, 2), (task.t, 1), (task.t - 1, 1), (task.t - 1, 1)];
        let arrays = std::array::from_fn(|k| FloatArray { data: &data[k], size: 8, steps: dims[k].0, dim: dims[k].1 });
        EpisodeArrays { origin: "tiny.pkl".into(), keys: KEYS, arrays, episodes: 5, extras: Vec::new() }
    }

    #[test]
    fn appends_number_episodes_in_the_order_written() {
        let (task, data) = arrays();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.parquet");
        let mut w = TrajectoryWriter::create(&path, &task, FloatType::Float32, WriterOptions::new(6)).unwrap();
        assert_eq!(w.episodes_per_group(), 2);
        w.append(&view(&data, &task), 3, 5).unwrap();
        w.append(&view(&data, &task), 0, 3).unwrap();
        assert_eq!(w.episodes(), 5);
        w.finish(&Footer::new(&task, FloatType::Float32, 5, "test".into())).unwrap();
        let reader = ParquetRecordBatchReaderBuilder::try_new(std::fs::File::open(&path).unwrap()).unwrap();
        assert_eq!(reader.metadata().num_row_groups(), 3); // [3,4], [0,1], [2]
        let (mut episodes, mut first_obs) = (Vec::new(), Vec::new());
        for b in reader.build().unwrap() {
            let b = b.unwrap();
            let ep = b.column(0).as_any().downcast_ref::<Int64Array>().unwrap();
            let obs = b.column(2).as_any().downcast_ref::<FixedSizeListArray>().unwrap();
            let vals = obs.values().as_any().downcast_ref::<PrimitiveArray<Float32Type>>().unwrap();
            for r in (0..b.num_rows()).step_by(3) {
                episodes.push(ep.value(r));
                first_obs.push(vals.value(r * 2));
            }
            let action = b.column(5);
            assert!((0..b.num_rows()).all(|r| action.is_null(r) == (r % 3 == 2)));
        }
        assert_eq!(episodes, [0, 1, 2, 3, 4]);
        assert_eq!(first_obs, [300.0, 400.0, 0.0, 100.0, 200.0]);
    }

    /// What `ogbench::ARRAY_KEYS` calls o, ag, u and g.
    const OGBENCH: [&str; 4] = ["observations", "observations", "actions", "observations"];

    #[test]
    fn arrays_of_the_wrong_shape_are_refused_by_name() {
        let (task, mut data) = arrays();
        data[2].truncate(8);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.parquet");
        let mut w = TrajectoryWriter::create(&path, &task, FloatType::Float64, WriterOptions::new(64)).unwrap();
        let e = w.append(&view(&data, &task), 0, 5).unwrap_err().to_string();
        assert!(e.starts_with("tiny.pkl: `u` is 5 episodes × 2 × 1 values of 8 bytes in 8 bytes"), "{e}");
        // In the source's own words: OGBench's files call the actions `actions`.
        let e = w.append(&EpisodeArrays { keys: OGBENCH, ..view(&data, &task) }, 0, 5).unwrap_err().to_string();
        assert!(e.contains("`actions` is 5 episodes"), "{e}");
    }
}
