//! `pgser-etl inspect`: what is in a pgser table (or any Parquet file of numeric columns).
//!
//! Reads row groups as a stream, so it runs in constant memory on files of any size. Column
//! statistics are merged per batch with Chan et al.'s parallel variance formula, which stays
//! accurate where a running sum of squares would cancel.

use std::borrow::Cow;
use std::fs::File;
use std::path::Path;

use anyhow::{Context, Result};
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type, Int32Type, Int64Type};
use arrow_array::{Array, ArrayRef, RecordBatch};
use arrow_schema::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use serde::Serialize;

use crate::table::FOOTER_KEY;
use crate::trajectory;

/// Count, mean, sum of squared deviations, min and max of a set of values.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Moments {
    pub count: u64,
    pub mean: f64,
    #[serde(skip)]
    m2: f64,
    pub min: f64,
    pub max: f64,
}

impl Default for Moments {
    fn default() -> Self {
        Moments { count: 0, mean: 0.0, m2: 0.0, min: f64::INFINITY, max: f64::NEG_INFINITY }
    }
}

impl Moments {
    pub fn of(values: impl Iterator<Item = f64> + Clone) -> Self {
        let (mut n, mut sum, mut min, mut max) = (0u64, 0.0, f64::INFINITY, f64::NEG_INFINITY);
        for v in values.clone() {
            n += 1;
            sum += v;
            min = min.min(v);
            max = max.max(v);
        }
        if n == 0 {
            return Self::default();
        }
        let mean = sum / n as f64;
        let m2 = values.map(|v| (v - mean) * (v - mean)).sum();
        Moments { count: n, mean, m2, min, max }
    }

    pub fn merge(&mut self, o: &Moments) {
        if o.count == 0 {
            return;
        }
        let n = self.count + o.count;
        let d = o.mean - self.mean;
        self.mean += d * o.count as f64 / n as f64;
        self.m2 += o.m2 + d * d * (self.count as f64) * (o.count as f64) / n as f64;
        self.count = n;
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }

    /// Population standard deviation.
    pub fn std(&self) -> f64 {
        if self.count == 0 { 0.0 } else { (self.m2 / self.count as f64).sqrt() }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct ColumnSummary {
    pub name: String,
    pub data_type: String,
    pub nulls: u64,
    pub all: Moments,
    pub std: f64,
    /// One entry per vector component (one for scalar columns).
    pub per_dim: Vec<Moments>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub path: String,
    pub bytes: u64,
    pub rows: u64,
    pub row_groups: usize,
    pub footer: Option<serde_json::Value>,
    pub columns: Vec<ColumnSummary>,
    /// Trajectory tables: episodes and the share whose final achieved goal meets the goal.
    pub episodes: Option<u64>,
    pub final_success: Option<u64>,
    pub success_rate: Option<f64>,
}

pub fn inspect(path: &Path) -> Result<Summary> {
    let at = path.display();
    let file = File::open(path).with_context(|| format!("{at}: cannot open"))?;
    let bytes = file.metadata()?.len();
    let builder =
        ParquetRecordBatchReaderBuilder::try_new(file).with_context(|| format!("{at}: not a Parquet file"))?;
    let meta = builder.metadata().clone();
    let footer = meta
        .file_metadata()
        .key_value_metadata()
        .and_then(|kv| kv.iter().find(|e| e.key == FOOTER_KEY))
        .and_then(|e| e.value.as_deref())
        .map(|t| serde_json::from_str(t).with_context(|| format!("{at}: the `{FOOTER_KEY}` footer is not valid JSON")))
        .transpose()?;
    let traj: Option<trajectory::Footer> = footer
        .as_ref()
        .filter(|f: &&serde_json::Value| f["kind"] == trajectory::KIND)
        .map(|f| serde_json::from_value(f.clone()).with_context(|| format!("{at}: malformed trajectory footer")))
        .transpose()?;
    let schema = builder.schema().clone();
    let mut columns: Vec<ColumnSummary> = schema
        .fields()
        .iter()
        .map(|f| ColumnSummary {
            name: f.name().clone(),
            data_type: type_text(f.data_type()),
            nulls: 0,
            all: Moments::default(),
            std: 0.0,
            per_dim: Vec::new(),
        })
        .collect();
    let mut success = traj.as_ref().map(|f| SuccessCounter::new(f.task()));
    let reader = builder.with_batch_size(65_536).build().with_context(|| format!("{at}: cannot read"))?;
    for batch in reader {
        let batch = batch.with_context(|| format!("{at}: cannot read a row group"))?;
        for (c, col) in columns.iter_mut().zip(batch.columns()) {
            c.nulls += col.null_count() as u64;
            if let Some(dims) = column_moments(col) {
                if c.per_dim.is_empty() {
                    c.per_dim = vec![Moments::default(); dims.len()];
                }
                c.per_dim.iter_mut().zip(&dims).for_each(|(a, b)| a.merge(b));
            }
        }
        if let Some(s) = success.as_mut() {
            s.add(&batch).with_context(|| format!("{at}: cannot compute success"))?;
        }
    }
    for c in &mut columns {
        c.per_dim.iter().for_each(|m| c.all.merge(m));
        c.std = c.all.std();
    }
    let (episodes, final_success) = success.map(|s| (s.episodes, s.successes)).unzip();
    Ok(Summary {
        path: path.display().to_string(),
        bytes,
        rows: meta.file_metadata().num_rows() as u64,
        row_groups: meta.num_row_groups(),
        footer,
        columns,
        episodes,
        final_success,
        success_rate: episodes.zip(final_success).map(|(e, s)| if e == 0 { 0.0 } else { s as f64 / e as f64 }),
    })
}

fn type_text(t: &DataType) -> String {
    match t {
        DataType::FixedSizeList(item, n) => {
            format!("fixed_size_list<{}>[{n}]", type_text(item.data_type()))
        }
        other => other.to_string().to_lowercase(),
    }
}

/// Per-component moments of a numeric or FixedSizeList-of-numeric column (nulls skipped).
fn column_moments(col: &ArrayRef) -> Option<Vec<Moments>> {
    let (values, dim, valid): (ArrayRef, usize, Option<&arrow_buffer::NullBuffer>) = match col.data_type() {
        DataType::FixedSizeList(_, n) => {
            let l = col.as_fixed_size_list();
            (l.values().clone(), *n as usize, l.nulls())
        }
        _ => (col.clone(), 1, None),
    };
    let flat = as_f64(&values)?;
    let scalar_nulls = if dim == 1 && valid.is_none() { values.nulls() } else { valid };
    let rows = flat.len() / dim.max(1);
    let keep = |r: &usize| scalar_nulls.is_none_or(|n| n.is_valid(*r));
    Some((0..dim).map(|d| Moments::of((0..rows).filter(keep).map(|r| flat[r * dim + d]))).collect())
}

/// Final-step success of each episode: the last achieved goal against the last desired goal
/// (the one on step T − 2; step T − 1 has none), with the task's metric and threshold.
struct SuccessCounter {
    task: crate::task::Task,
    episodes: u64,
    successes: u64,
    /// Desired goal seen on the latest non-null row, carried across batch boundaries.
    last_goal: Vec<f64>,
}

impl SuccessCounter {
    fn new(task: crate::task::Task) -> Self {
        SuccessCounter { task, episodes: 0, successes: 0, last_goal: Vec::new() }
    }

    fn add(&mut self, batch: &RecordBatch) -> Result<()> {
        let t = self.task.t as i32;
        let step = batch.column_by_name("step").context("no step column")?.as_primitive::<Int32Type>();
        let ag = vectors(batch.column_by_name("achieved_goal").context("no achieved_goal column")?)?;
        let g_col = batch.column_by_name("desired_goal").context("no desired_goal column")?;
        let g = vectors(g_col)?;
        let dim = self.task.goal_dim;
        for r in 0..batch.num_rows() {
            if g_col.is_valid(r) {
                self.last_goal = g[r * dim..(r + 1) * dim].to_vec();
            }
            if step.value(r) == t - 1 {
                self.episodes += 1;
                if self.task.success(&ag[r * dim..(r + 1) * dim], &self.last_goal) {
                    self.successes += 1;
                }
            }
        }
        Ok(())
    }
}

/// The flat values of a FixedSizeList<float> column as f64.
fn vectors(col: &ArrayRef) -> Result<Cow<'_, [f64]>> {
    let values = col.as_fixed_size_list().values();
    match values.data_type() {
        DataType::Float64 | DataType::Float32 => Ok(as_f64(values).expect("numeric")),
        other => anyhow::bail!("vector column of {other}"),
    }
}

/// Numeric values as f64: borrowed when they already are, converted otherwise; None for
/// columns that are not numeric.
fn as_f64(values: &ArrayRef) -> Option<Cow<'_, [f64]>> {
    Some(match values.data_type() {
        DataType::Float64 => Cow::Borrowed(values.as_primitive::<Float64Type>().values().as_ref()),
        DataType::Float32 => values.as_primitive::<Float32Type>().values().iter().map(|&v| v as f64).collect(),
        DataType::Int64 => values.as_primitive::<Int64Type>().values().iter().map(|&v| v as f64).collect(),
        DataType::Int32 => values.as_primitive::<Int32Type>().values().iter().map(|&v| v as f64).collect(),
        _ => return None,
    })
}

/// The human-readable report.
pub fn render(s: &Summary, per_dim: bool) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "file: {} ({:.1} MB, {} rows in {} row groups)",
        s.path,
        s.bytes as f64 / 1e6,
        s.rows,
        s.row_groups
    );
    let _ = writeln!(o, "schema:");
    for c in &s.columns {
        let _ = writeln!(o, "  {:<20} {}", c.name, c.data_type);
    }
    match &s.footer {
        Some(f) => {
            let _ = writeln!(o, "footer `{FOOTER_KEY}`:");
            for line in compact_json(f).lines() {
                let _ = writeln!(o, "  {line}");
            }
        }
        None => {
            let _ = writeln!(o, "footer: none (not written by pgser)");
        }
    }
    if let (Some(e), Some(ok), Some(rate)) = (s.episodes, s.final_success, s.success_rate) {
        let f = s.footer.as_ref().expect("trajectory tables have a footer");
        let _ = writeln!(
            o,
            "episodes: {e}  T: {}  dims: obs {} goal {} act {}  task: {}",
            f["T"],
            f["obs_dim"],
            f["goal_dim"],
            f["act_dim"],
            f["task"].as_str().unwrap_or("?")
        );
        let _ = writeln!(o, "final-step success rate: {rate:.4} ({ok}/{e}, threshold {})", f["success_threshold"]);
    }
    if let Some(f) = s.footer.as_ref().filter(|f| f["kind"] == crate::score::KIND) {
        let original = if f["include_original"] == true { " + the original goal" } else { "" };
        let _ = writeln!(
            o,
            "transitions: {} of {} episodes, {} swapped goals each{original}; task: {}",
            f["transitions"],
            f["episodes"],
            f["swaps"],
            f["task"].as_str().unwrap_or("?")
        );
        let q = |k: &str| f["q"][k].as_f64().unwrap_or(f64::NAN);
        let _ =
            writeln!(o, "q min/mean/max: {:.4} / {:.4} / {:.4} (gamma {})", q("min"), q("mean"), q("max"), f["gamma"]);
    }
    let _ = writeln!(
        o,
        "{:<20} {:>10} {:>8} {:>13} {:>13} {:>13} {:>13}",
        "column", "values", "nulls", "mean", "std", "min", "max"
    );
    for c in &s.columns {
        let m = &c.all;
        let _ = writeln!(
            o,
            "{:<20} {:>10} {:>8} {:>13.6} {:>13.6} {:>13.6} {:>13.6}",
            c.name, m.count, c.nulls, m.mean, c.std, m.min, m.max
        );
        if per_dim && c.per_dim.len() > 1 {
            for (d, m) in c.per_dim.iter().enumerate() {
                let name = format!("  [{d}]");
                let _ = writeln!(
                    o,
                    "{:<20} {:>10} {:>8} {:>13.6} {:>13.6} {:>13.6} {:>13.6}",
                    name,
                    m.count,
                    "",
                    m.mean,
                    m.std(),
                    m.min,
                    m.max
                );
            }
        }
    }
    o
}

/// Pretty JSON with arrays of scalars on one line (a histogram is one line, not a hundred).
fn compact_json(v: &serde_json::Value) -> String {
    fn go(v: &serde_json::Value, indent: usize, o: &mut String) {
        use serde_json::Value;
        let pad = |n: usize| "  ".repeat(n);
        match v {
            Value::Object(m) if !m.is_empty() => {
                o.push_str("{\n");
                for (i, (k, x)) in m.iter().enumerate() {
                    o.push_str(&format!("{}{}: ", pad(indent + 1), Value::String(k.clone())));
                    go(x, indent + 1, o);
                    o.push_str(if i + 1 < m.len() { ",\n" } else { "\n" });
                }
                o.push_str(&format!("{}}}", pad(indent)));
            }
            Value::Array(a) if a.iter().any(|x| x.is_object() || x.is_array()) => {
                o.push_str("[\n");
                for (i, x) in a.iter().enumerate() {
                    o.push_str(&pad(indent + 1));
                    go(x, indent + 1, o);
                    o.push_str(if i + 1 < a.len() { ",\n" } else { "\n" });
                }
                o.push_str(&format!("{}]", pad(indent)));
            }
            other => o.push_str(&other.to_string()),
        }
    }
    let mut o = String::new();
    go(v, 0, &mut o);
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merged_moments_equal_direct() {
        let xs: Vec<f64> = (0..1000).map(|i| 1e6 + (i as f64 * 0.37).sin()).collect();
        let direct = Moments::of(xs.iter().copied());
        let mut merged = Moments::default();
        for chunk in xs.chunks(77) {
            merged.merge(&Moments::of(chunk.iter().copied()));
        }
        assert_eq!(merged.count, 1000);
        assert!((merged.mean - direct.mean).abs() < 1e-9);
        assert!((merged.std() - direct.std()).abs() < 1e-9);
        assert_eq!((merged.min, merged.max), (direct.min, direct.max));
    }
}
