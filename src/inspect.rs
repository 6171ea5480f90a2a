//! `pgser-etl inspect`: what is in a pgser table (or any Parquet file of numeric columns).
//!
//! The footer and schema come from the Parquet metadata; the statistics from one lazy polars
//! scan run on its streaming engine, which reads the file in batches: memory stays flat on
//! tables larger than RAM. Each numeric column and each component of a vector column gets a
//! count, mean, variance (polars merges batches with Chan et al.'s parallel formula, accurate
//! where a running sum of squares would cancel), min and max; a column's overall moments are
//! its components' merged the same way ([`Moments::merge`]).

use std::path::Path;

use anyhow::{Context, Result, anyhow};
use arrow_schema::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use polars::error::PolarsResult;
use polars::prelude::{Column, DataType as PlType, Expr, LazyFrame, col, lit};
use serde::Serialize;

use crate::query::{collect, first_line, scan_parquet};
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
    /// From a count, mean, population variance, min and max (None where polars has no value:
    /// no rows).
    fn from_stats(count: u64, mean: Option<f64>, var: Option<f64>, min: Option<f64>, max: Option<f64>) -> Self {
        match (count, mean, var, min, max) {
            (n, Some(mean), Some(var), Some(min), Some(max)) if n > 0 => {
                Moments { count: n, mean, m2: var * n as f64, min, max }
            }
            _ => Self::default(),
        }
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
    /// A table folder: its shards (statistics are over all of them).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shards: Option<usize>,
    /// The `pgser` footer, less its checksums (summarised in `checksums`).
    pub footer: Option<serde_json::Value>,
    /// "N column chunks (B bytes) verified", or why nothing could be.
    pub checksums: String,
    pub columns: Vec<ColumnSummary>,
    /// Trajectory tables: episodes and the share whose final achieved goal meets the goal.
    pub episodes: Option<u64>,
    pub final_success: Option<u64>,
    pub success_rate: Option<f64>,
}

pub fn inspect(path: &Path) -> Result<Summary> {
    if trajectory::folder::is_folder(path) {
        return inspect_folder(path);
    }
    let at = path.display();
    let file = crate::output::open_input(path)?;
    let bytes = file.metadata()?.len();
    let builder =
        ParquetRecordBatchReaderBuilder::try_new(file).with_context(|| format!("{at}: not a Parquet file"))?;
    let meta = builder.metadata().clone();
    // Every chunk's bytes against the footer's checksums, before statistics are computed from them.
    let verifier = crate::table::Verifier::new(path, &meta)?;
    verifier.check_all()?;
    let footer = crate::table::footer_text(meta.file_metadata())
        .map(|t| serde_json::from_str(t).with_context(|| format!("{at}: the `{FOOTER_KEY}` footer is not valid JSON")))
        .transpose()?;
    let traj: Option<trajectory::Footer> = footer
        .as_ref()
        .filter(|f: &&serde_json::Value| f["kind"] == trajectory::KIND)
        .map(|f| trajectory::Footer::from_json(&at.to_string(), f.clone()))
        .transpose()?;
    let schema = builder.schema().clone();
    let rows = meta.file_metadata().num_rows() as u64;
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
    let fail = |e: polars::error::PolarsError| anyhow!("{at}: cannot compute statistics: {}", first_line(&e));
    if rows > 0 {
        let stats = column_stats(scan_parquet(path)?, &schema).map_err(fail)?;
        for (c, (nulls, dims)) in columns.iter_mut().zip(stats) {
            c.nulls = nulls;
            c.per_dim = dims;
        }
    }
    let success = match traj.as_ref().filter(|_| rows > 0) {
        Some(f) => Some(final_success(scan_parquet(path)?, f.task()).map_err(fail)?),
        None => traj.as_ref().map(|_| (0, 0)),
    };
    for c in &mut columns {
        c.per_dim.iter().for_each(|m| c.all.merge(m));
        c.std = c.all.std();
    }
    let (episodes, final_success) = success.unzip();
    Ok(Summary {
        path: path.display().to_string(),
        bytes,
        rows,
        row_groups: meta.num_row_groups(),
        shards: None,
        footer: footer.map(|mut f: serde_json::Value| {
            f.as_object_mut().map(|m| m.remove(crate::table::CHECKSUMS_KEY));
            f
        }),
        checksums: if verifier.verifiable() {
            let (chunks, bytes) = verifier.extent();
            format!("{chunks} column chunks ({bytes} bytes) verified")
        } else {
            "none: written without checksums (an older pgser or another tool), so it cannot be verified".into()
        },
        columns,
        episodes,
        final_success,
        success_rate: episodes.zip(final_success).map(|(e, s)| if e == 0 { 0.0 } else { s as f64 / e as f64 }),
    })
}

/// A table folder as one table: every shard's chunks checked against its checksums, statistics
/// over all shards in one scan (`query::scan_folder`, episodes numbered across the folder), the
/// manifest's footer (the shards' shared one with the folder's totals).
fn inspect_folder(dir: &Path) -> Result<Summary> {
    let at = dir.display();
    let folder = trajectory::folder::TableFolder::open(dir)?;
    let paths = folder.shard_paths();
    let (mut bytes, mut row_groups, mut chunks, mut checked) = (0, 0, 0, 0);
    let mut schema = None;
    for path in &paths {
        let file = crate::output::open_input(path)?;
        bytes += file.metadata()?.len();
        let builder = ParquetRecordBatchReaderBuilder::try_new(file)
            .with_context(|| format!("{}: not a Parquet file", path.display()))?;
        row_groups += builder.metadata().num_row_groups();
        let verifier = crate::table::Verifier::new(path, builder.metadata())?;
        verifier.check_all()?;
        let (c, b) = verifier.extent();
        (chunks, checked) = (chunks + c, checked + b);
        schema.get_or_insert_with(|| builder.schema().clone());
    }
    let schema = schema.expect("a folder has shards");
    let footer = folder.footer().clone();
    let fail = |e: polars::error::PolarsError| anyhow!("{at}: cannot compute statistics: {}", first_line(&e));
    let mut columns: Vec<ColumnSummary> = schema
        .fields()
        .iter()
        .zip(column_stats(crate::query::scan_folder(dir)?, &schema).map_err(fail)?)
        .map(|(f, (nulls, per_dim))| {
            let mut all = Moments::default();
            per_dim.iter().for_each(|m| all.merge(m));
            ColumnSummary {
                name: f.name().clone(),
                data_type: type_text(f.data_type()),
                nulls,
                std: all.std(),
                all,
                per_dim,
            }
        })
        .collect();
    columns.iter_mut().for_each(|c| c.std = c.all.std());
    let (episodes, ok) = final_success(crate::query::scan_folder(dir)?, footer.task()).map_err(fail)?;
    let mut json = serde_json::to_value(&footer)?;
    json.as_object_mut().map(|m| m.remove(crate::table::CHECKSUMS_KEY));
    Ok(Summary {
        path: dir.display().to_string(),
        bytes,
        rows: folder.manifest.rows as u64,
        row_groups,
        shards: Some(paths.len()),
        footer: Some(json),
        checksums: format!("{chunks} column chunks ({checked} bytes) verified, in {} shards", paths.len()),
        columns,
        episodes: Some(episodes),
        final_success: Some(ok),
        success_rate: Some(if episodes == 0 { 0.0 } else { ok as f64 / episodes as f64 }),
    })
}

fn type_text(t: &DataType) -> String {
    match t {
        DataType::FixedSizeList(item, n) => {
            format!("fixed_size_list<{}>[{n}]", type_text(item.data_type()))
        }
        DataType::FixedSizeBinary(n) => format!("fixed_size_binary[{n}]"),
        other => other.to_string().to_lowercase(),
    }
}

/// The vector size of a numeric column (1 for a scalar) or of a FixedSizeList of numbers; None
/// for columns without statistics (strings, booleans, …).
fn numeric_dims(t: &DataType) -> Option<usize> {
    let numeric = |t: &DataType| matches!(t, DataType::Float64 | DataType::Float32 | DataType::Int64 | DataType::Int32);
    match t {
        DataType::FixedSizeList(item, n) if numeric(item.data_type()) => Some(*n as usize),
        t if numeric(t) => Some(1),
        _ => None,
    }
}

/// Per column, its null count and per-component moments (nulls skipped; none for columns
/// without statistics), in one streaming pass over the file.
fn column_stats(scan: LazyFrame, schema: &arrow_schema::Schema) -> PolarsResult<Vec<(u64, Vec<Moments>)>> {
    const STATS: [&str; 5] = ["count", "mean", "var", "min", "max"];
    let mut exprs: Vec<Expr> = Vec::new();
    for (i, f) in schema.fields().iter().enumerate() {
        let c = col(f.name().as_str());
        exprs.push(c.clone().is_null().sum().cast(PlType::UInt64).alias(format!("{i}:nulls")));
        let dims = numeric_dims(f.data_type()).unwrap_or(0);
        for d in 0..dims {
            let v = if matches!(f.data_type(), DataType::FixedSizeList(..)) {
                c.clone().arr().get(lit(d as i64), false)
            } else {
                c.clone()
            }
            .cast(PlType::Float64);
            let [n, mean, var, min, max] = STATS.map(|s| format!("{i}:{d}:{s}"));
            exprs.push(v.clone().count().cast(PlType::UInt64).alias(n));
            exprs.push(v.clone().mean().alias(mean));
            exprs.push(v.clone().var(0).alias(var));
            exprs.push(v.clone().min().alias(min));
            exprs.push(v.max().alias(max));
        }
    }
    let df = collect(scan.select(exprs))?;
    let u = |name: String| -> PolarsResult<u64> { Ok(df.column(&name)?.u64()?.get(0).unwrap_or(0)) };
    let x = |name: String| -> PolarsResult<Option<f64>> { Ok(df.column(&name)?.f64()?.get(0)) };
    let mut out = Vec::with_capacity(schema.fields().len());
    for (i, f) in schema.fields().iter().enumerate() {
        let dims = (0..numeric_dims(f.data_type()).unwrap_or(0))
            .map(|d| {
                let [n, mean, var, min, max] = STATS.map(|s| format!("{i}:{d}:{s}"));
                Ok(Moments::from_stats(u(n)?, x(mean)?, x(var)?, x(min)?, x(max)?))
            })
            .collect::<PolarsResult<Vec<Moments>>>()?;
        out.push((u(format!("{i}:nulls"))?, dims));
    }
    Ok(out)
}

/// Final-step success: (episodes, successes). An episode's last achieved goal against its last
/// desired goal (the one on step T − 2; step T − 1 has none), with the task's metric and
/// threshold. Only the last two steps of each episode are read.
fn final_success(scan: LazyFrame, task: crate::task::Task) -> PolarsResult<(u64, u64)> {
    let t = task.t as i32;
    let df = collect(scan.filter(col("step").gt_eq(lit(t - 2))).select([
        col("step").cast(PlType::Int32),
        col("achieved_goal"),
        col("desired_goal"),
    ]))?;
    let dim = task.goal_dim;
    let step: Vec<i32> = df.column("step")?.i32()?.iter().map(|s| s.unwrap_or(-1)).collect();
    let ag = flat_f64(df.column("achieved_goal")?, dim)?;
    let g_col = df.column("desired_goal")?;
    let g = flat_f64(g_col, dim)?;
    let g_valid: Vec<bool> = g_col.is_not_null().iter().map(|v| v.unwrap_or(false)).collect();
    let (mut episodes, mut successes, mut last_goal) = (0, 0, vec![f64::NAN; dim]);
    for r in 0..df.height() {
        if g_valid[r] {
            last_goal.copy_from_slice(&g[r * dim..(r + 1) * dim]);
        }
        if step[r] == t - 1 {
            episodes += 1;
            if task.success(&ag[r * dim..(r + 1) * dim], &last_goal) {
                successes += 1;
            }
        }
    }
    Ok((episodes, successes))
}

/// The flat values of a vector column (rows × dim, null rows included as NaN) as f64.
fn flat_f64(c: &Column, dim: usize) -> PolarsResult<Vec<f64>> {
    let s = c.as_materialized_series().cast(&PlType::Array(Box::new(PlType::Float64), dim))?.rechunk();
    let inner = s.array()?.get_inner();
    Ok(inner.f64()?.iter().map(|v| v.unwrap_or(f64::NAN)).collect())
}

/// The human-readable report.
pub fn render(s: &Summary, per_dim: bool) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let what = match s.shards {
        Some(n) => format!("table folder of {n} shards"),
        None => "file".to_string(),
    };
    let _ = writeln!(
        o,
        "{what}: {} ({:.1} MB, {} rows in {} row groups)",
        s.path,
        s.bytes as f64 / 1e6,
        s.rows,
        s.row_groups
    );
    let _ = writeln!(o, "checksums: {}", s.checksums);
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
        let images = match f["image_shape"].as_array() {
            Some(shape) => {
                let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
                format!(" (uint8 images {})", dims.join("×"))
            }
            None => String::new(),
        };
        let _ = writeln!(
            o,
            "episodes: {e}  T: {}  dims: obs {}{images} goal {} act {}  task: {}",
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
        let sample = match f["goal_sample"].as_u64() {
            Some(k) => format!(" (from a sample of {k} achieved goals)"),
            None => String::new(),
        };
        let _ = writeln!(
            o,
            "transitions: {} of {} episodes, {} swapped goals each{sample}{original}; task: {}",
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

    /// Two-pass moments of a set of values.
    fn moments_of(values: &[f64]) -> Moments {
        let n = values.len() as u64;
        let mean = values.iter().sum::<f64>() / n as f64;
        let m2 = values.iter().map(|v| (v - mean) * (v - mean)).sum();
        let (min, max) = values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        Moments { count: n, mean, m2, min, max }
    }

    #[test]
    fn merged_moments_equal_direct() {
        let xs: Vec<f64> = (0..1000).map(|i| 1e6 + (i as f64 * 0.37).sin()).collect();
        let direct = moments_of(&xs);
        let mut merged = Moments::default();
        for chunk in xs.chunks(77) {
            merged.merge(&moments_of(chunk));
        }
        assert_eq!(merged.count, 1000);
        assert!((merged.mean - direct.mean).abs() < 1e-9);
        assert!((merged.std() - direct.std()).abs() < 1e-9);
        assert_eq!((merged.min, merged.max), (direct.min, direct.max));
    }
}
