//! Reading a scored transition table (the output of `pgser-etl score`): one file, or a scored
//! folder's shards as one table. Each shard's metadata is parsed once at open
//! ([`ShardFile`]); every read decodes only chunks it has read once and checked against the
//! footer's checksums. The samplers that schedule these reads are in `sampler::scored` (held
//! whole or streamed) and `sampler::pool` (beside β's blocks).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int32Type, Int64Type};
use arrow_array::{Array, RecordBatch};
use parquet::arrow::arrow_reader::{RowSelection, RowSelector};

use crate::table::ShardFile;
use crate::task::Task;
use crate::trajectory::Episodes;

/// One scored row's transition (episode, step) in β and its goal's (goal_episode, goal_step), −1
/// for the transition's own desired goal. Every batch row is one: β's own rows (original, HER,
/// swapped on the fly) and the scored table's prioritized ones (which store exactly these four
/// columns).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RowKey {
    pub episode: u32,
    pub step: u32,
    pub goal_episode: u32,
    /// −1: the transition's own desired goal.
    pub goal_step: i32,
}

/// The columns that name a row's transition and goal.
const COLUMNS: [&str; 4] = ["episode", "step", "goal_episode", "goal_step"];

/// The scored rows of a block of β ([`ScoredTable::read_goals`]): each row's stored goal, its q,
/// and (when asked for) its goal's table-wide (episode, step).
pub struct BlockGoals {
    pub goal: Vec<f32>,
    pub q: Vec<f32>,
    pub at: Vec<[u32; 2]>,
}

/// A scored transition table (one file, or a scored folder's shards as one table): its footer and
/// the shape of its row groups.
pub struct ScoredTable {
    /// The file or the scored folder.
    pub path: PathBuf,
    pub footer: crate::score::Footer,
    pub task: Task,
    pub gamma: f64,
    pub rows: usize,
    /// First row of each row group (numbered across the files), plus the total at the end.
    pub group_starts: Vec<usize>,
    /// The files in order, with their parsed metadata.
    files: Vec<ScoredFile>,
    /// Row group → (file, its row group within the file).
    group_at: Vec<(u32, u32)>,
    /// The trajectory table the rows were made from.
    source: PathBuf,
}

/// One file of a scored table. Its Parquet metadata is parsed once: every block reads many row
/// groups, and re-parsing the footer of a large file per row group would cost as much as the
/// reads. Each read checks the chunks it decodes ([`ShardFile::read`]).
struct ScoredFile {
    file: ShardFile,
    /// The table's number of the file's first row.
    first_row: usize,
}

/// The columns the in-memory samplers read from every row (q, and the keys that name each
/// row's transition and goal): [`ScoredTable::check_whole`] checks them.
const WHOLE: [&str; 5] = ["q", "episode", "step", "goal_episode", "goal_step"];

impl ScoredTable {
    /// The scored table at `path` (a file whose footer says so, or a scored folder), or None when
    /// `path` is something else (a trajectory table or folder, left to its own reader).
    pub fn open_if_scored(path: &Path) -> Result<Option<ScoredTable>> {
        match crate::table::read_footer(path) {
            Ok(f) if f["kind"] == crate::score::KIND => Ok(Some(ScoredTable::open(path)?)),
            _ if crate::score::folder::is_scored_folder(path) => Ok(Some(ScoredTable::open(path)?)),
            _ => Ok(None),
        }
    }

    /// Opens a scored file, or a scored folder (`score::folder`) as the one table of its shards.
    pub fn open(path: &Path) -> Result<ScoredTable> {
        let (footer, paths, source) = if crate::score::folder::is_scored_folder(path) {
            let folder = crate::score::folder::ScoredFolder::open(path)?;
            let source = folder.source_table();
            (folder.manifest.footer.clone(), folder.shard_paths(), source)
        } else {
            let footer = crate::score::read_footer(path)?;
            let source = footer.source_table(path);
            (footer, vec![path.to_path_buf()], source)
        };
        let mut group_starts = vec![0usize];
        let mut files = Vec::with_capacity(paths.len());
        let mut group_at = Vec::new();
        for (i, p) in paths.into_iter().enumerate() {
            let first_row = *group_starts.last().unwrap();
            let file = ShardFile::open(&p)?;
            for (g, n) in file.group_rows()?.into_iter().enumerate() {
                group_starts.push(group_starts.last().unwrap() + n);
                group_at.push((i as u32, g as u32));
            }
            // Nothing table-wide is read here: each read checks the chunks it decodes; the
            // samplers that hold the table check it first (`check_whole`).
            files.push(ScoredFile { file, first_row });
        }
        let rows = *group_starts.last().unwrap();
        if rows == 0 {
            bail!("{}: the table has no rows", path.display());
        }
        if rows != footer.rows {
            bail!("{}: {rows} rows where the footer says {}", path.display(), footer.rows);
        }
        Ok(ScoredTable {
            path: path.to_path_buf(),
            task: footer.task(),
            gamma: footer.gamma,
            footer,
            rows,
            group_starts,
            files,
            group_at,
            source,
        })
    }

    /// Checks the chunks of every row group's columns that the in-memory samplers read (q and
    /// the keys), in parallel: what a sampler that holds the whole table calls before reading it.
    pub fn check_whole(&self) -> Result<()> {
        for f in &self.files {
            f.file.check(&WHOLE)?;
        }
        Ok(())
    }

    /// The trajectory table β this one was made from, and its recorded sha256.
    pub fn trajectory(&self) -> (PathBuf, String) {
        (self.source.clone(), self.footer.source.sha256.clone())
    }

    /// The `q` column, streamed, file after file.
    pub fn read_q(&self) -> Result<Vec<f32>> {
        let mut q: Vec<f32> = Vec::with_capacity(self.rows);
        for ScoredFile { file, .. } in &self.files {
            let at = file.path().display();
            let before = q.len();
            // A row group at a time: what a read holds is one group's chunk of q.
            for g in 0..file.metadata().num_row_groups() {
                for batch in file.read(&[g], &["q"], None, 65_536)? {
                    let batch = batch.with_context(|| format!("{at}: row group {g}: cannot read column q"))?;
                    let col = batch.column_by_name("q").with_context(|| format!("{at}: no column q"))?;
                    let col =
                        col.as_primitive_opt::<Float32Type>().with_context(|| format!("{at}: q is not float32"))?;
                    q.extend(col.values().iter());
                }
            }
            for (i, v) in q[before..].iter().enumerate() {
                if !v.is_finite() {
                    bail!("{at}: row {i}: q is {v}");
                }
            }
        }
        Ok(q)
    }

    /// The stored goals and q of rows `r0..r1`, which must be the scored rows of whole episodes
    /// from table-wide episode `first_episode` on, `per` rows per transition of T = `t`, in order:
    /// what the out-of-core pool holds beside a block of β (`pool.rs`). Every row's episode and step
    /// are checked against that, so a scored table that is not the block's is refused, naming the
    /// file and row. With `sources`, each row's goal (episode, step) is kept too (OGBench's layout
    /// reports where a goal came from); a row that keeps its transition's own desired goal
    /// (`goal_step` −1) is then refused, as it names no observation.
    pub fn read_goals(
        &self,
        (r0, r1): (usize, usize),
        first_episode: u64,
        t: usize,
        per: usize,
        sources: bool,
    ) -> Result<BlockGoals> {
        let gd = self.task.goal_dim;
        let (mut goal, mut q) = (Vec::with_capacity((r1 - r0) * gd), Vec::with_capacity(r1 - r0));
        let mut goal_at: Vec<[u32; 2]> = Vec::with_capacity(if sources { r1 - r0 } else { 0 });
        let names: &[&str] = if sources {
            &["episode", "step", "goal", "q", "goal_episode", "goal_step"]
        } else {
            &["episode", "step", "goal", "q"]
        };
        let first = self.group_starts.partition_point(|&s| s <= r0) - 1;
        let mut row = r0;
        for rg in first..self.group_starts.len() - 1 {
            let (start, end) = (self.group_starts[rg], self.group_starts[rg + 1]);
            if start >= r1 {
                break;
            }
            let (f, local) = self.group_at[rg];
            let ScoredFile { file, first_row } = &self.files[f as usize];
            let at = format!("{} (row group {local})", file.path().display());
            let (a, b) = (row - start, r1.min(end) - start);
            let mut selectors = Vec::new();
            if a > 0 {
                selectors.push(RowSelector::skip(a));
            }
            selectors.push(RowSelector::select(b - a));
            // Every column read is checked (the stored goal too, which the pool trains on), on
            // threads of the read's own: the pool's loader calls this and must not wait on the
            // global pool.
            let reader = file.read(&[local as usize], names, Some(RowSelection::from(selectors)), 65_536)?;
            for batch in reader {
                let batch =
                    batch.with_context(|| format!("{at}: cannot read the rows after row {}", row - first_row))?;
                let col = |name: &str| batch.column_by_name(name).with_context(|| format!("{at}: no column {name}"));
                let (Some(ep), Some(st), Some(qs)) = (
                    col("episode")?.as_primitive_opt::<Int64Type>(),
                    col("step")?.as_primitive_opt::<Int32Type>(),
                    col("q")?.as_primitive_opt::<Float32Type>(),
                ) else {
                    bail!("{at}: episode must be int64, step int32 and q float32");
                };
                for i in 0..batch.num_rows() {
                    let k = row + i - r0;
                    let want = (first_episode + (k / ((t - 1) * per)) as u64, (k / per) % (t - 1));
                    let (e, s, v) = (ep.value(i), st.value(i), qs.value(i));
                    if (e, s as i64) != (want.0 as i64, want.1 as i64) || !v.is_finite() {
                        bail!(
                            "{}: row {}: (episode {e}, step {s}, q {v}) where its original data's block holds episode {} step \
                             {} here with a finite q: the scored table does not match its original data",
                            file.path().display(),
                            row + i - first_row,
                            want.0,
                            want.1
                        );
                    }
                }
                let list = col("goal")?.as_fixed_size_list_opt().filter(|l| l.value_length() as usize == gd);
                let values = list.and_then(|l| l.values().as_primitive_opt::<Float32Type>());
                let Some(values) = values.filter(|v| v.null_count() == 0) else {
                    bail!("{at}: `goal` must be {gd} non-null float32 values per row");
                };
                let vals = &values.values()[list.expect("checked").value_offset_at(0)..][..batch.num_rows() * gd];
                if let Some(j) = vals.iter().position(|v| !v.is_finite()) {
                    bail!(
                        "{}: row {}: `goal`[{}] is {}",
                        file.path().display(),
                        row + j / gd - first_row,
                        j % gd,
                        vals[j]
                    );
                }
                if sources {
                    let (Some(ge), Some(gs)) = (
                        col("goal_episode")?.as_primitive_opt::<Int64Type>(),
                        col("goal_step")?.as_primitive_opt::<Int32Type>(),
                    ) else {
                        bail!("{at}: goal_episode must be int64 and goal_step int32");
                    };
                    for i in 0..batch.num_rows() {
                        let (e, s) = (ge.value(i), gs.value(i));
                        if !(0..=u32::MAX as i64).contains(&e) || !(0..t as i32).contains(&s) {
                            bail!(
                                "{}: row {}: goal (episode {e}, step {s}) is no observation of its original data{}",
                                file.path().display(),
                                row + i - first_row,
                                if s == -1 {
                                    " (the row keeps its transition's own desired goal: --include-original)"
                                } else {
                                    ""
                                }
                            );
                        }
                        goal_at.push([e as u32, s as u32]);
                    }
                }
                goal.extend_from_slice(vals);
                q.extend_from_slice(qs.values());
                row += batch.num_rows();
            }
        }
        if row != r1 {
            bail!(
                "{}: rows {row}..{r1} are missing: the table ends before its original data does",
                self.path.display()
            );
        }
        Ok(BlockGoals { goal, q, at: goal_at })
    }

    /// Every row's keys, in order (16 bytes a row), checked against β's shape.
    pub fn read_keys(&self, beta: &Episodes) -> Result<Vec<RowKey>> {
        let mut all = Vec::with_capacity(self.rows);
        for rg in 0..self.group_starts.len() - 1 {
            let rows: Vec<usize> = (self.group_starts[rg]..self.group_starts[rg + 1]).collect();
            all.extend(self.read_rows(rg, &rows, beta)?);
        }
        Ok(all)
    }

    /// The keys of `rows` (sorted, unique, within row group `rg`), in that order, checked
    /// against β's shape so a row can never index outside it.
    pub fn read_rows(&self, rg: usize, rows: &[usize], beta: &Episodes) -> Result<Vec<RowKey>> {
        let (f, local) = self.group_at[rg];
        let ScoredFile { file, first_row } = &self.files[f as usize];
        let start = self.group_starts[rg];
        let mut selectors = Vec::new();
        let mut at = start;
        for &r in rows {
            if r > at {
                selectors.push(RowSelector::skip(r - at));
            }
            selectors.push(RowSelector::select(1));
            at = r + 1;
        }
        let whole = rows.len() == self.group_starts[rg + 1] - start;
        let selection = (!whole).then(|| RowSelection::from(selectors));
        let reader = file.read(&[local as usize], &COLUMNS, selection, rows.len())?;
        let mut out = Vec::with_capacity(rows.len());
        for batch in reader {
            let batch = batch.with_context(|| format!("{}: row group {local}: read failed", file.path().display()))?;
            append_keys(file.path(), &batch, beta, rows, *first_row, &mut out)?;
        }
        Ok(out)
    }
}

/// Appends a record batch's row keys to `out`; `rows` are the table rows being read, of the file
/// whose first row is the table's `first_row` (for errors, which name the file's row).
fn append_keys(
    path: &Path,
    batch: &RecordBatch,
    beta: &Episodes,
    rows: &[usize],
    first_row: usize,
    out: &mut Vec<RowKey>,
) -> Result<()> {
    let at = path.display();
    let col = |name: &str| batch.column_by_name(name).with_context(|| format!("{at}: no column {name}"));
    let (ep, st) = (col("episode")?.as_primitive_opt::<Int64Type>(), col("step")?.as_primitive_opt::<Int32Type>());
    let (gep, gst) =
        (col("goal_episode")?.as_primitive_opt::<Int64Type>(), col("goal_step")?.as_primitive_opt::<Int32Type>());
    let (Some(ep), Some(st), Some(gep), Some(gst)) = (ep, st, gep, gst) else {
        bail!("{at}: episode/goal_episode must be int64 and step/goal_step int32");
    };
    for i in 0..batch.num_rows() {
        let (e, s, ge, gs) = (ep.value(i), st.value(i), gep.value(i), gst.value(i));
        let ok = (0..beta.n as i64).contains(&e)
            && (0..beta.t as i32 - 1).contains(&s)
            && (0..beta.n as i64).contains(&ge)
            && (-1..beta.t as i32).contains(&gs);
        if !ok {
            let row = rows.get(out.len()).copied().unwrap_or_default().saturating_sub(first_row);
            bail!(
                "{at}: row {row}: (episode {e}, step {s}, goal_episode {ge}, goal_step {gs}) is outside its original data ({} episodes of {} steps)",
                beta.n,
                beta.t
            );
        }
        out.push(RowKey { episode: e as u32, step: s as u32, goal_episode: ge as u32, goal_step: gs });
    }
    Ok(())
}
