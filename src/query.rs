//! `pgser-etl query`: SQL over pgser's tables and CSV files (results.csv), through polars' SQL
//! context on lazy scans.
//!
//! Each input is registered as a table named by its file stem (`scored.parquet` → `scored`) or
//! by `NAME=PATH`. Scans are lazy and the query runs on polars' streaming engine, so only the
//! columns and row groups the query needs are read, in batches: an aggregate over a table
//! larger than RAM works. The result is collected before any output file is created, and the
//! file is written atomically ([`crate::output`]), so a bad query leaves nothing behind.
//!
//! Errors are one line: polars' messages carry a multi-line plan dump after the first line,
//! which says what matters (the unknown column and the valid ones, or where the SQL fails).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use polars::prelude::*;
use polars::sql::SQLContext;

use crate::output::{AtomicFile, check_not_an_input};

/// How the result is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Comma-separated, with a header (the default on stdout).
    Csv,
    /// JSON Lines: one object per row; vectors as arrays, NaN and ±Inf as null.
    Json,
    /// A Parquet file (needs `-o`).
    Parquet,
}

impl Format {
    /// The format an output file's extension names.
    fn of(path: &Path) -> Result<Format> {
        match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("csv") => Ok(Format::Csv),
            Some("json" | "jsonl" | "ndjson") => Ok(Format::Json),
            Some("parquet" | "pq") => Ok(Format::Parquet),
            _ => bail!(
                "{}: cannot tell the output format from the name: give --csv, --json or --parquet",
                path.display()
            ),
        }
    }
}

pub struct QueryOptions {
    pub sql: String,
    /// `PATH` or `NAME=PATH`.
    pub inputs: Vec<String>,
    /// Output format; with `output` and none given, taken from the file name; CSV on stdout.
    pub format: Option<Format>,
    /// Output file (written atomically); stdout when None.
    pub output: Option<PathBuf>,
}

/// One input: the SQL table name and its file.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub name: String,
    pub path: PathBuf,
}

/// The inputs as tables: `NAME=PATH` where NAME is an identifier, else named by the file stem.
/// Two inputs with one name are refused (a query would silently see only one of them).
pub fn tables(inputs: &[String]) -> Result<Vec<Table>> {
    let mut out: Vec<Table> = Vec::new();
    for arg in inputs {
        let t = match arg.split_once('=') {
            Some((name, path)) if is_identifier(name) => Table { name: name.to_string(), path: PathBuf::from(path) },
            _ => {
                let path = PathBuf::from(arg);
                let name = path
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .with_context(|| format!("{arg}: no file name to name the table by; write NAME={arg}"))?
                    .to_string();
                Table { name, path }
            }
        };
        if let Some(other) = out.iter().find(|o| o.name == t.name) {
            bail!(
                "{} and {} would both be table `{}`: name one with NAME=PATH",
                other.path.display(),
                t.path.display(),
                t.name
            );
        }
        out.push(t);
    }
    Ok(out)
}

fn is_identifier(s: &str) -> bool {
    let mut c = s.chars();
    c.next().is_some_and(|f| f.is_ascii_alphabetic() || f == '_') && c.all(|x| x.is_ascii_alphanumeric() || x == '_')
}

/// A lazy scan of one input by its extension: Parquet (see [`scan_parquet`]) once every column
/// chunk matches its checksum ([`crate::table::open_checked`]: polars decodes the file's pages
/// unchecked, so a flipped bit would otherwise come back as another number), or CSV with a
/// header and types inferred from every row (a results.csv has p columns that are empty on
/// most rows).
pub fn scan(path: &Path) -> Result<LazyFrame> {
    let at = path.display();
    if crate::trajectory::folder::is_folder(path) {
        return scan_folder(path);
    }
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("parquet" | "pq") => {
            // polars reads what it is given: the checksums are checked here, before it does.
            crate::table::open_checked(path, None)?;
            scan_parquet(path)
        }
        Some("csv") => {
            let p = source(path)?;
            LazyCsvReader::new(p)
                .with_has_header(true)
                .with_infer_schema_length(None)
                .with_glob(false)
                .finish()
                .map_err(|e| anyhow!("{at}: {}", first_line(&e)))
        }
        _ => bail!("{at}: not a .parquet or .csv file"),
    }
}

/// A lazy scan of a table folder as one table: its shards in the manifest's order, each checked
/// against its checksums first, with `episode` numbered across the folder (each shard file keeps
/// its own numbering from 0, and the manifest gives where it starts).
pub fn scan_folder(dir: &Path) -> Result<LazyFrame> {
    let folder = crate::trajectory::folder::TableFolder::open(dir)?;
    let mut scans = Vec::with_capacity(folder.manifest.shards.len());
    for (shard, path) in folder.manifest.shards.iter().zip(folder.shard_paths()) {
        crate::table::open_checked(&path, None)?;
        let first = shard.first_episode as i64;
        scans.push(scan_parquet(&path)?.with_column(col("episode") + lit(first)));
    }
    polars::prelude::concat(scans, polars::prelude::UnionArgs::default())
        .map_err(|e| anyhow!("{}: {}", dir.display(), first_line(&e)))
}

/// A lazy scan of a Parquet file, whatever its name: pgser's vector columns become Array
/// columns. Nothing is read until the scan is collected.
pub fn scan_parquet(path: &Path) -> Result<LazyFrame> {
    let p = source(path)?;
    LazyFrame::scan_parquet(p, ScanArgsParquet { glob: false, ..Default::default() })
        .map_err(|e| anyhow!("{}: {}", path.display(), first_line(&e)))
}

/// The path as polars names a source; a missing file is named here, not deep in a query.
fn source(path: &Path) -> Result<PlRefPath> {
    if !path.is_file() {
        bail!("{}: no such file", path.display());
    }
    PlRefPath::try_from_path(path).map_err(|e| anyhow!("{}: {}", path.display(), first_line(&e)))
}

/// Runs `sql` over `tables` and collects the result.
pub fn run(sql: &str, tables: &[Table]) -> Result<DataFrame> {
    let mut ctx = SQLContext::new();
    for t in tables {
        ctx.register(&t.name, scan(&t.path)?);
    }
    let lf = ctx.execute(sql).map_err(|e| anyhow!("query: {}", first_line(&e)))?;
    collect(lf).map_err(|e| anyhow!("query: {}", first_line(&e)))
}

/// Collects on the streaming engine: scans are read in batches, so memory follows what the
/// query keeps (its groups, its result), not the size of the tables.
pub fn collect(lf: LazyFrame) -> PolarsResult<DataFrame> {
    lf.collect_with_engine(Engine::Streaming).map(|r| r.unwrap_single())
}

/// The first line of a polars error: the rest is the query plan up to the failure.
pub fn first_line(e: &PolarsError) -> String {
    let text = e.to_string();
    text.lines().find(|l| !l.trim().is_empty()).unwrap_or("polars error").trim().to_string()
}

/// `pgser-etl query`: runs the query and writes the result; returns its row count.
pub fn query(o: &QueryOptions) -> Result<usize> {
    let tables = tables(&o.inputs)?;
    let format = match (o.format, &o.output) {
        (Some(f), _) => f,
        (None, Some(path)) => Format::of(path)?,
        (None, None) => Format::Csv,
    };
    if o.output.is_none() && format == Format::Parquet {
        bail!("--parquet writes a file: give -o FILE");
    }
    if let Some(out) = &o.output {
        check_not_an_input(out, &tables.iter().map(|t| t.path.clone()).collect::<Vec<_>>())?;
        // Refused before running: a query can take long, and its result would be lost.
        AtomicFile::create(out)?;
    }
    let mut df = run(&o.sql, &tables)?;
    match &o.output {
        Some(out) => {
            let f = AtomicFile::create(out)?;
            write(&mut df, format, f.handle()?)
                .with_context(|| format!("{}: cannot write the result", out.display()))?;
            f.commit()?;
        }
        None => {
            write(&mut df, format, std::io::stdout().lock())?;
        }
    }
    Ok(df.height())
}

/// Writes `df` in `format` to `w`.
fn write(df: &mut DataFrame, format: Format, w: impl Write) -> Result<()> {
    match format {
        Format::Csv => CsvWriter::new(w).include_header(true).finish(df).map_err(|e| anyhow!("{}", first_line(&e))),
        Format::Parquet => ParquetWriter::new(w).finish(df).map(|_| ()).map_err(|e| anyhow!("{}", first_line(&e))),
        Format::Json => write_json_lines(df, w),
    }
}

/// JSON Lines by serde_json: polars' own JSON writer is a cargo feature of its own (simd-json and
/// polars-json) that would be built for this alone. Each object's keys are in the query's column
/// order (as in the CSV header), not sorted as a `serde_json::Map` would have them.
fn write_json_lines(df: &DataFrame, w: impl Write) -> Result<()> {
    let mut w = std::io::BufWriter::new(w);
    let names: Vec<String> = df.get_column_names().iter().map(|n| n.to_string()).collect();
    for i in 0..df.height() {
        w.write_all(b"{")?;
        for (k, (name, c)) in names.iter().zip(df.columns()).enumerate() {
            if k > 0 {
                w.write_all(b",")?;
            }
            serde_json::to_writer(&mut w, name)?;
            w.write_all(b":")?;
            serde_json::to_writer(&mut w, &json_value(&c.get(i).map_err(|e| anyhow!("{}", first_line(&e)))?)?)?;
        }
        w.write_all(b"}\n")?;
    }
    w.flush()?;
    Ok(())
}

/// One cell as JSON: numbers, strings, booleans, null, and vectors (Array and List) as arrays.
fn json_value(v: &AnyValue) -> Result<serde_json::Value> {
    use serde_json::Value as J;
    let float = |x: f64| serde_json::Number::from_f64(x).map_or(J::Null, J::Number);
    Ok(match v {
        AnyValue::Null => J::Null,
        AnyValue::Boolean(b) => J::Bool(*b),
        AnyValue::Int8(x) => J::from(*x),
        AnyValue::Int16(x) => J::from(*x),
        AnyValue::Int32(x) => J::from(*x),
        AnyValue::Int64(x) => J::from(*x),
        AnyValue::UInt8(x) => J::from(*x),
        AnyValue::UInt16(x) => J::from(*x),
        AnyValue::UInt32(x) => J::from(*x),
        AnyValue::UInt64(x) => J::from(*x),
        AnyValue::Float32(x) => float(f64::from(*x)),
        AnyValue::Float64(x) => float(*x),
        AnyValue::String(s) => J::from(*s),
        AnyValue::StringOwned(s) => J::from(s.as_str()),
        AnyValue::Array(s, _) | AnyValue::List(s) => {
            J::Array(s.iter().map(|x| json_value(&x)).collect::<Result<Vec<_>>>()?)
        }
        other => J::from(other.to_string()),
    })
}
