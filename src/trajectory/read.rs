//! Loading a trajectory table (docs/tables.md) into memory for training.
//!
//! Training samples transitions uniformly and relabels goals from any later step of the same
//! episode (HER "future"), so it needs random access to every episode: the whole table is held
//! as float32 (the networks' type; WGCSL's float64 pickles carry no precision the networks use),
//! episode-major. A 2500-episode FetchPush table is ≈ 17 MB that way.
//!
//! Row groups are streamed a few episodes at a time and every row is checked on the way in —
//! dense episodes, ordered steps, nulls only where WGCSL has no entry, finite values — so a bad
//! table fails here with the file, row, episode and step named, not as a NaN loss hours later.

use std::path::Path;

use anyhow::{Context, Result, bail};
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type, Int32Type, Int64Type};
use arrow_array::{Array, ArrayRef, RecordBatch};
use arrow_schema::{DataType, Schema};
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{ParquetRecordBatchReader, ParquetRecordBatchReaderBuilder};

use super::{FloatType, Footer, KIND};
use crate::table::{FOOTER_KEY, SCHEMA_VERSION};
use crate::task::Task;

/// Episodes per record batch read: big enough to amortise decoding, small enough that the
/// Arrow copy next to the f32 arrays stays a few MB.
const BATCH_EPISODES: usize = 64;
/// The most floats reserved up front per array (256 MiB): the footer's counts are checked
/// against the Parquet metadata, but both can lie, so beyond this the Vecs grow as data arrives.
const MAX_RESERVE: usize = 1 << 26;
/// The vector columns in the order `Episodes` holds them; the last two have T − 1 rows per
/// episode that training reads. Step T − 1's row is null, or, in a table whose footer says
/// `last_action`, holds the action the source had there (OGBench's files), which a transition
/// never uses: it is read past, and kept for `export`.
const VECTORS: [&str; 4] = ["obs", "achieved_goal", "desired_goal", "action"];
const EXPECTED: &str = "a trajectory table from `pgser-etl convert` or `pgser-etl collect` is expected";

/// A trajectory table in memory, as float32, episode-major.
pub struct Episodes {
    /// The table's `pgser` footer (kind "trajectory").
    pub footer: Footer,
    /// `footer.task()`: dimensions, T, goal metric and threshold.
    pub task: Task,
    /// Episodes.
    pub n: usize,
    /// Observations per episode (T); actions per episode T − 1.
    pub t: usize,
    /// `[n, t, obs_dim]`
    pub obs: Vec<f32>,
    /// `[n, t, goal_dim]` achieved goals.
    pub ag: Vec<f32>,
    /// `[n, t − 1, goal_dim]` desired goals (the rows with step < T − 1).
    pub g: Vec<f32>,
    /// `[n, t − 1, act_dim]` actions.
    pub u: Vec<f32>,
    /// An image table's observations, `[n, t, obs_dim]` bytes (`footer.image_shape` each), where
    /// `obs` is empty; empty for state observations. Only [`Episodes::load_with_images`] fills it.
    pub images: Vec<u8>,
}

impl std::fmt::Debug for Episodes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Episodes {{ task: {}, n: {}, t: {} }}", self.task.name, self.n, self.t)
    }
}

impl Episodes {
    /// Read and check a whole trajectory table, one file or a table folder (its shards appended
    /// in the manifest's order, episodes numbered across the folder); errors are one line naming
    /// the file and where.
    pub fn load(path: &Path) -> Result<Episodes> {
        Self::load_as(path, false)
    }

    /// [`Episodes::load`] for a reader of image observations too (OGBench's layout of the
    /// samplers): an image table's observations are kept as their bytes, in `images`.
    pub fn load_with_images(path: &Path) -> Result<Episodes> {
        Self::load_as(path, true)
    }

    fn load_as(path: &Path, images: bool) -> Result<Episodes> {
        let mut out = None;
        let mut bytes = Vec::new();
        let footer = if super::folder::is_folder(path) {
            // Opening checks that every shard's footer agrees with the manifest's.
            let folder = super::folder::TableFolder::open(path)?;
            let whole = folder.footer().clone();
            for file in folder.shard_paths() {
                append_file(&file, &mut out, &mut bytes, images, Some(whole.episodes))?;
            }
            whole
        } else {
            append_file(path, &mut out, &mut bytes, images, None)?
        };
        let [obs, ag, g, u] = out.expect("at least one file read");
        Ok(Episodes { task: footer.task(), n: footer.episodes, t: footer.t, footer, obs, ag, g, u, images: bytes })
    }

    /// o[ep, step]'s bytes, step < T, of an image table read with its images.
    pub fn image(&self, ep: usize, step: usize) -> &[u8] {
        debug_assert!(step < self.t);
        let d = self.footer.obs_dim;
        &self.images[(ep * self.t + step) * d..][..d]
    }

    /// o[ep, step], step < T.
    pub fn obs(&self, ep: usize, step: usize) -> &[f32] {
        debug_assert!(step < self.t);
        let d = self.footer.obs_dim;
        &self.obs[(ep * self.t + step) * d..][..d]
    }

    /// ag[ep, step], step < T.
    pub fn ag(&self, ep: usize, step: usize) -> &[f32] {
        debug_assert!(step < self.t);
        let d = self.footer.goal_dim;
        &self.ag[(ep * self.t + step) * d..][..d]
    }

    /// g[ep, step], step < T − 1.
    pub fn goal(&self, ep: usize, step: usize) -> &[f32] {
        debug_assert!(step < self.t - 1);
        let d = self.footer.goal_dim;
        &self.g[(ep * (self.t - 1) + step) * d..][..d]
    }

    /// u[ep, step], step < T − 1.
    pub fn action(&self, ep: usize, step: usize) -> &[f32] {
        debug_assert!(step < self.t - 1);
        let d = self.footer.act_dim;
        &self.u[(ep * (self.t - 1) + step) * d..][..d]
    }

    /// Transitions (o, u, o′): T − 1 per episode.
    pub fn transitions(&self) -> usize {
        self.n * (self.t - 1)
    }

    /// (episode, step) of transition `i` in `0..transitions()`, for uniform sampling.
    pub fn transition(&self, i: usize) -> (usize, usize) {
        (i / (self.t - 1), i % (self.t - 1))
    }
}

/// Reads the file `path` and appends its rows to `out`, which the first file makes, with room for
/// `episodes` (a folder's total; else the file's own); with `images`, an image table's
/// observations go to `bytes` (and `out`'s observations stay empty). Returns the file's footer.
fn append_file(
    path: &Path,
    out: &mut Option<[Vec<f32>; 4]>,
    bytes: &mut Vec<u8>,
    images: bool,
    episodes: Option<usize>,
) -> Result<Footer> {
    let at = path.display().to_string();
    let (footer, reader) = if images {
        open_images(path, &VECTORS, BATCH_EPISODES)?
    } else {
        open_checked(path, &VECTORS, BATCH_EPISODES)?
    };
    let t = footer.t;
    let dims = [footer.obs_dim, footer.goal_dim, footer.goal_dim, footer.act_dim];
    let steps = [t, t, t - 1, t - 1];
    let n = episodes.unwrap_or(footer.episodes);
    let image = footer.is_image();
    let out = out.get_or_insert_with(|| {
        std::array::from_fn(|k| {
            let n = if image && k == 0 { 0 } else { n };
            Vec::with_capacity(n.saturating_mul(steps[k]).saturating_mul(dims[k]).min(MAX_RESERVE))
        })
    });
    if image && bytes.is_empty() {
        bytes.reserve(n.saturating_mul(t).saturating_mul(dims[0]).min(4 * MAX_RESERVE));
    }
    let mut row = 0;
    for batch in reader {
        let batch = batch.with_context(|| format!("{at}: cannot read the rows after row {row}"))?;
        check_keys(&at, &batch, row, &footer)?;
        for (k, v) in out.iter_mut().enumerate() {
            let col = batch.column_by_name(VECTORS[k]).expect("projected");
            if image && k == 0 {
                append_images(bytes, col, dims[0], row, t).map_err(|e| anyhow::anyhow!("{at}: {e}"))?;
                continue;
            }
            append(v, col, VECTORS[k], dims[k], steps[k] < t, row, t).map_err(|e| anyhow::anyhow!("{at}: {e}"))?;
        }
        row += batch.num_rows();
    }
    check_all_read(&at, row, &footer)?;
    Ok(footer)
}

/// Opens `path` as a trajectory table: footer, row count and all six columns checked, `columns`
/// (plus episode and step, always) projected, batches of `batch_episodes` whole episodes.
/// Both the in-memory load and `score`'s streaming reader start here. The observations of an
/// image table are refused here ([`Footer::state_only`]): every caller reads them as floats but
/// [`open_images`]'s.
pub(crate) fn open_checked(
    path: &Path,
    columns: &[&str],
    batch_episodes: usize,
) -> Result<(Footer, ParquetRecordBatchReader)> {
    let (footer, reader) = open_images(path, columns, batch_episodes)?;
    if columns.contains(&"obs") {
        footer.state_only(
            &path.display().to_string(),
            "the in-memory reader (of training, score, the samplers and export to Minari)",
        )?;
    }
    Ok((footer, reader))
}

/// [`open_checked`] for a reader of image observations' bytes too (`export`): an image table's
/// `obs` projected as its FixedSizeBinary column.
pub(crate) fn open_images(
    path: &Path,
    columns: &[&str],
    batch_episodes: usize,
) -> Result<(Footer, ParquetRecordBatchReader)> {
    let at = path.display().to_string();
    let file = crate::output::open_input(path)?;
    let builder =
        ParquetRecordBatchReaderBuilder::try_new(file).with_context(|| format!("{at}: not a Parquet file"))?;
    let footer = trajectory_footer(&at, crate::table::footer_text(builder.metadata().file_metadata()))?;
    let file_rows = builder.metadata().file_metadata().num_rows();
    if usize::try_from(file_rows).ok() != Some(footer.rows) {
        bail!(
            "{at}: the file holds {file_rows} rows but its footer says {} ({} episodes × T = {})",
            footer.rows,
            footer.episodes,
            footer.t
        );
    }
    let dims = [footer.obs_dim, footer.goal_dim, footer.goal_dim, footer.act_dim];
    let indices = check_schema(&at, builder.schema(), &footer, dims)?;
    let names = ["episode", "step"].into_iter().chain(VECTORS);
    // Passthrough columns asked for by name: listed in the footer, and of the type it says.
    let mut extra = Vec::new();
    for &c in columns.iter().filter(|c| !VECTORS.contains(c) && !matches!(**c, "episode" | "step")) {
        let p = footer
            .passthrough
            .iter()
            .find(|p| p.column == c)
            .with_context(|| format!("{at}: no column `{c}` among the table's passthrough columns"))?;
        let i = builder.schema().index_of(c).map_err(|_| {
            anyhow::anyhow!("{at}: the footer lists the passthrough column `{c}` but the file has no such column")
        })?;
        let (got, want) = (builder.schema().field(i).data_type(), p.field().data_type().clone());
        if *got != want {
            bail!("{at}: `{c}` is {got}, but the footer says {} values of shape {:?} ({want})", p.dtype, p.shape);
        }
        extra.push((i, c));
    }
    // The bytes of every column chunk read, against the footer's checksums, before decoding.
    let mut read: Vec<&str> =
        names.clone().filter(|n| matches!(*n, "episode" | "step") || columns.contains(n)).collect();
    read.extend(extra.iter().map(|&(_, c)| c));
    let verifier = crate::table::Verifier::new(path, builder.metadata())?;
    verifier.check(&verifier.columns_of(&read))?;
    let keep = indices.into_iter().zip(names).filter(|(_, n)| matches!(*n, "episode" | "step") || columns.contains(n));
    let mask =
        ProjectionMask::roots(builder.parquet_schema(), keep.map(|(i, _)| i).chain(extra.iter().map(|&(i, _)| i)));
    let reader = builder
        .with_projection(mask)
        .with_batch_size(batch_episodes.max(1).saturating_mul(footer.t))
        .build()
        .with_context(|| format!("{at}: cannot read"))?;
    Ok((footer, reader))
}

/// After the last batch: `rows` read must be what the footer promised.
pub(crate) fn check_all_read(at: &str, rows: usize, f: &Footer) -> Result<()> {
    if rows != f.rows { Err(rows_read_error(at, rows, f)) } else { Ok(()) }
}

/// The file ended (or ran on) at `rows` where the footer promised `f.rows`.
pub(crate) fn rows_read_error(at: &str, rows: usize, f: &Footer) -> anyhow::Error {
    anyhow::anyhow!("{at}: {rows} rows read but the footer says {} ({} episodes × T = {})", f.rows, f.episodes, f.t)
}

/// The `pgser` footer, required to be a trajectory footer that agrees with itself.
fn trajectory_footer(at: &str, text: Option<&str>) -> Result<Footer> {
    let text = text.with_context(|| format!("{at}: no `{FOOTER_KEY}` footer, so not a pgser table; {EXPECTED}"))?;
    let json: serde_json::Value =
        serde_json::from_str(text).with_context(|| format!("{at}: the `{FOOTER_KEY}` footer is not valid JSON"))?;
    match json.get("kind").and_then(|k| k.as_str()) {
        Some(KIND) => {}
        Some(kind) => bail!("{at}: a {kind} table, not a trajectory table; {EXPECTED}"),
        None => bail!("{at}: the `{FOOTER_KEY}` footer names no table kind; {EXPECTED}"),
    }
    let f = Footer::from_json(at, json)?;
    if f.schema_version != SCHEMA_VERSION {
        bail!("{at}: table schema version {}; this pgser reads version {SCHEMA_VERSION}", f.schema_version);
    }
    if f.t < 2 {
        bail!("{at}: the footer says T = {}; an episode needs at least two observations", f.t);
    }
    if f.episodes == 0 {
        bail!("{at}: the footer says the table holds no episodes");
    }
    if f.episodes.checked_mul(f.t) != Some(f.rows) {
        bail!("{at}: the footer says {} rows, not {} episodes × T = {}", f.rows, f.episodes, f.t);
    }
    Ok(f)
}

/// Check the six columns' types against the footer; returns their root indices.
fn check_schema(at: &str, schema: &Schema, f: &Footer, dims: [usize; 4]) -> Result<Vec<usize>> {
    let index = |name: &str| {
        schema.index_of(name).map_err(|_| {
            anyhow::anyhow!(
                "{at}: no `{name}` column (a trajectory table has episode, step, {}); {EXPECTED}",
                VECTORS.join(", ")
            )
        })
    };
    let mut indices = Vec::with_capacity(6);
    for (name, want) in [("episode", DataType::Int64), ("step", DataType::Int32)] {
        let i = index(name)?;
        let got = schema.field(i).data_type();
        if *got != want {
            bail!("{at}: `{name}` is {got}, not {want}");
        }
        indices.push(i);
    }
    let dim_names = ["obs_dim", "goal_dim", "goal_dim", "act_dim"];
    for ((name, dim), dim_name) in VECTORS.into_iter().zip(dims).zip(dim_names) {
        let i = index(name)?;
        if name == "obs" && f.is_image() {
            let want = DataType::FixedSizeBinary(dim as i32);
            if *schema.field(i).data_type() != want {
                bail!(
                    "{at}: `obs` is {}, but the footer says {} uint8 images ({want})",
                    schema.field(i).data_type(),
                    super::shape_text(&f.image_shape)
                );
            }
            indices.push(i);
            continue;
        }
        let DataType::FixedSizeList(item, size) = schema.field(i).data_type() else {
            bail!("{at}: `{name}` is {}, not a fixed-size list of floats", schema.field(i).data_type());
        };
        let float = match item.data_type() {
            DataType::Float32 => FloatType::Float32,
            DataType::Float64 => FloatType::Float64,
            other => bail!("{at}: `{name}` holds {other}, not float32 or float64"),
        };
        if *size as usize != dim {
            bail!("{at}: `{name}` holds lists of {size} values but the footer says {dim_name} = {dim}");
        }
        if float != f.float_type {
            bail!("{at}: `{name}` holds {} but the footer says {}", float.name(), f.float_type.name());
        }
        indices.push(i);
    }
    Ok(indices)
}

/// Rows `first_row..` must be (episode, step) = (row / T, row % T), with no nulls.
pub(crate) fn check_keys(at: &str, batch: &RecordBatch, first_row: usize, f: &Footer) -> Result<()> {
    let t = f.t;
    let episode = batch.column_by_name("episode").expect("projected").as_primitive::<Int64Type>();
    let step = batch.column_by_name("step").expect("projected").as_primitive::<Int32Type>();
    for r in 0..batch.num_rows() {
        let row = first_row + r;
        if row >= f.rows {
            bail!("{at}: more rows than the footer's {} ({} episodes × T = {t})", f.rows, f.episodes);
        }
        if episode.is_null(r) || step.is_null(r) {
            bail!("{at}: row {row}: `episode` or `step` is null");
        }
        let (want_e, want_s) = (row / t, row % t);
        let (e, s) = (episode.value(r), step.value(r));
        if e == want_e as i64 + 1 && s == 0 && want_s > 0 {
            bail!("{at}: row {row}: episode {want_e} ends after {want_s} steps; every episode has T = {t}");
        }
        if e != want_e as i64 {
            bail!(
                "{at}: row {row}: episode {e} (step {s}) where episode {want_e} was expected; episodes must be \
                 numbered densely 0..n−1, each one's rows contiguous and in order"
            );
        }
        if s != want_s as i32 {
            bail!(
                "{at}: row {row} (episode {e}): step {s} where {want_s} was expected; steps must run 0..T−1 = {} \
                 in order",
                t - 1
            );
        }
    }
    Ok(())
}

/// Where [`append_images`] writes an image column's bytes: a `Vec`, or the pool's own mappings.
pub(crate) trait ByteSink {
    fn push_bytes(&mut self, v: &[u8]);
}

impl ByteSink for Vec<u8> {
    fn push_bytes(&mut self, v: &[u8]) {
        self.extend_from_slice(v);
    }
}

/// Appends an image table's `obs` column (FixedSizeBinary of `dim` bytes, as `open_images`
/// checked) to `out`, every row: an image is never null. Errors name the row, episode and step;
/// the caller adds the file.
pub(crate) fn append_images(
    out: &mut impl ByteSink,
    col: &ArrayRef,
    dim: usize,
    first_row: usize,
    t: usize,
) -> Result<()> {
    let images = col.as_fixed_size_binary();
    if let Some(bad) = (0..images.len()).find(|&i| images.is_null(i)) {
        let row = first_row + bad;
        bail!("row {row} (episode {}, step {}): `obs` is null; an image is never null", row / t, row % t);
    }
    if images.value_length() as usize != dim {
        bail!("`obs` holds images of {} bytes where the footer says {dim}", images.value_length());
    }
    out.push_bytes(&images.value_data()[..images.len() * dim]);
    Ok(())
}

/// Where [`append`] writes a column's values: a `Vec`, or the out-of-core pool's own arrays
/// (`sampler/pool/buffers.rs`).
pub(crate) trait Sink {
    fn len(&self) -> usize;
    fn push_slice(&mut self, v: &[f32]);
    fn push_each(&mut self, v: impl Iterator<Item = f32>);
    /// The values from `from` on.
    fn tail(&self, from: usize) -> &[f32];
}

impl Sink for Vec<f32> {
    fn len(&self) -> usize {
        Vec::len(self)
    }
    fn push_slice(&mut self, v: &[f32]) {
        self.extend_from_slice(v);
    }
    fn push_each(&mut self, v: impl Iterator<Item = f32>) {
        self.extend(v);
    }
    fn tail(&self, from: usize) -> &[f32] {
        &self[from..]
    }
}

/// Append the rows of one vector column to `out` as f32: every row, or with `padded` (goal,
/// action) the rows with step < T − 1, whose last-step row may be null. Rows already passed
/// [`check_keys`], so row r of the batch is table row `first_row + r`. Errors name the row,
/// episode, step and column; the caller adds the file.
pub(crate) fn append(
    out: &mut impl Sink,
    col: &ArrayRef,
    name: &str,
    dim: usize,
    padded: bool,
    first_row: usize,
    t: usize,
) -> Result<()> {
    let list = col.as_fixed_size_list();
    let values = list.values();
    let place = |r: usize| {
        let row = first_row + r;
        format!("row {row} (episode {}, step {})", row / t, row % t)
    };
    let mut r = 0;
    while r < list.len() {
        let step = (first_row + r) % t;
        if padded && step == t - 1 {
            r += 1;
            continue;
        }
        // A run of rows to take: to the end of the batch, or of the episode's steps < T − 1.
        let end = if padded { (r + t - 1 - step).min(list.len()) } else { list.len() };
        if let Some(bad) = (r..end).find(|&i| list.is_null(i)) {
            let rule = if padded { "only the last step, T − 1, may be null" } else { "it is never null" };
            bail!("{}: `{name}` is null; {rule}", place(bad));
        }
        let (a, b) = (r * dim, end * dim);
        if values.null_count() > 0
            && let Some(i) = (a..b).find(|&i| values.is_null(i))
        {
            bail!("{}: `{name}`[{}] is null", place(i / dim), i % dim);
        }
        let start = out.len();
        match values.data_type() {
            DataType::Float32 => out.push_slice(&values.as_primitive::<Float32Type>().values()[a..b]),
            _ => out.push_each(values.as_primitive::<Float64Type>().values()[a..b].iter().map(|&v| v as f32)),
        }
        if let Some(j) = out.tail(start).iter().position(|v| !v.is_finite()) {
            let i = a + j;
            let source = match values.data_type() {
                DataType::Float32 => values.as_primitive::<Float32Type>().value(i) as f64,
                _ => values.as_primitive::<Float64Type>().value(i),
            };
            let what = if source.is_finite() {
                format!("value {source:e} overflows float32")
            } else {
                format!("non-finite value {source}")
            };
            bail!("{}: {what} in `{name}`[{}]", place(i / dim), i % dim);
        }
        r = end;
    }
    Ok(())
}

#[cfg(test)]
impl Episodes {
    /// A FetchReach-shaped test table whose values say where they are: obs and achieved goals of
    /// (episode e, step s) are `(first + e)·1000 + s`, actions that over 10⁵, and desired goals
    /// `desired(first + e, s)`. Any value read back names its source row.
    pub fn coded(first: usize, n: usize, desired: impl Fn(usize, usize) -> f32) -> Episodes {
        let task = Task::known("FetchReach").unwrap();
        let t = task.t;
        let code = |e: usize, s: usize| ((first + e) * 1000 + s) as f32;
        let mut d = Episodes {
            footer: Footer::new(&task, FloatType::Float32, n, "test".into()),
            task: task.clone(),
            n,
            t,
            obs: vec![],
            ag: vec![],
            g: vec![],
            u: vec![],
            images: vec![],
        };
        for e in 0..n {
            for s in 0..t {
                d.obs.extend(std::iter::repeat_n(code(e, s), task.obs_dim));
                d.ag.extend(std::iter::repeat_n(code(e, s), task.goal_dim));
                if s + 1 < t {
                    d.g.extend(std::iter::repeat_n(desired(first + e, s), task.goal_dim));
                    d.u.extend(std::iter::repeat_n(code(e, s) / 1e5, task.act_dim));
                }
            }
        }
        d
    }
}
