//! `pgser-train batches`: the first batches of a run's stream ([`super::stream`]) as a table,
//! one row per sampled transition. What a trainer trains on is otherwise invisible; written
//! out, it can be inspected, queried, plotted, or compared with another sampler (the Python
//! module's tests compare `pgser.Sampler` with it).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Result;
use arrow_array::{ArrayRef, Float32Array, Int32Array, Int64Array, RecordBatch};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use serde::Serialize;

use super::stream::{BatchSource, StreamConfig};
use super::view::Budget;
use crate::table::{SCHEMA_VERSION, TableWriter, f32_vectors};
use crate::task::Task;

/// The footer's `kind` of a batches table.
pub const KIND: &str = "batches";
/// Batches per row group: a row group is then a few MB, whatever the batch size.
const GROUP_ROWS: usize = 65_536;

/// The footer of a batches table (schemas/batches.json).
#[derive(Debug, Clone, Serialize)]
pub struct Footer {
    pub schema_version: u32,
    pub kind: String,
    pub task: String,
    pub obs_dim: usize,
    pub goal_dim: usize,
    pub act_dim: usize,
    pub batch_size: usize,
    pub batches: u64,
    pub rows: u64,
    /// The data the batches were drawn from, as given, and its sha256.
    pub data: String,
    pub data_sha256: String,
    /// The stream's settings as `pgser-train` names them (swap, her_ratio, aug_ratio, priority…).
    pub settings: serde_json::Value,
    pub seed: u64,
    pub command: String,
    pub pgser_version: String,
}

/// What `batches` reports.
#[derive(Debug, Clone, Serialize)]
pub struct DumpSummary {
    pub output: PathBuf,
    pub batches: u64,
    pub rows: u64,
    pub bytes: u64,
}

pub fn schema(task: &Task) -> SchemaRef {
    let vector = |name: &str, dim: usize| {
        let item = Arc::new(Field::new("item", DataType::Float32, false));
        Field::new(name, DataType::FixedSizeList(item, dim as i32), false)
    };
    Arc::new(Schema::new(vec![
        Field::new("batch", DataType::Int64, false),
        Field::new("episode", DataType::Int64, false),
        Field::new("step", DataType::Int32, false),
        Field::new("scored_row", DataType::Int64, false),
        vector("obs", task.obs_dim),
        vector("goal", task.goal_dim),
        vector("action", task.act_dim),
        Field::new("reward", DataType::Float32, false),
        vector("next_obs", task.obs_dim),
        Field::new("weight", DataType::Float32, false),
    ]))
}

/// Writes batches 0..`count` of the stream `cfg` draws from `data` to `out` (atomically: a
/// failure leaves no file).
/// `budget` is `--memory-budget`: β within it (an out-of-core pool when it does not fit).
pub fn write_batches(
    data: &Path,
    cfg: &StreamConfig,
    budget: Budget,
    count: u64,
    out: &Path,
    command: &str,
) -> Result<DumpSummary> {
    crate::output::check_not_an_input(out, &[data.to_path_buf()])?;
    let source = BatchSource::open_within(data, cfg, budget)?;
    let task = source.task().clone();
    let mut stream = source.start(cfg)?;
    let schema = schema(&task);
    let mut writer = TableWriter::create(out, schema.clone())?;
    let per_group = (GROUP_ROWS / cfg.batch_size).max(1) as u64;
    let mut rows = 0u64;
    let mut b = 0u64;
    while b < count {
        let mut cols = Columns::default();
        for _ in 0..per_group.min(count - b) {
            let (batch, ids) = stream.next_batch()?;
            cols.batch.extend(std::iter::repeat_n(b as i64, batch.n));
            cols.episode.extend(ids.episode.iter().map(|&e| e as i64));
            cols.step.extend(ids.step.iter().map(|&s| s as i32));
            cols.scored_row.extend_from_slice(&ids.scored_row);
            cols.obs.extend_from_slice(&batch.obs);
            cols.goal.extend_from_slice(&batch.goal);
            cols.action.extend_from_slice(&batch.action);
            cols.reward.extend_from_slice(&batch.reward);
            cols.next_obs.extend_from_slice(&batch.next_obs);
            if batch.weight.is_empty() {
                cols.weight.extend(std::iter::repeat_n(1.0f32, batch.n));
            } else {
                cols.weight.extend_from_slice(&batch.weight);
            }
            rows += batch.n as u64;
            b += 1;
        }
        writer.write_row_groups(&[cols.record_batch(&schema, &task)?])?;
    }
    let footer = Footer {
        schema_version: SCHEMA_VERSION,
        kind: KIND.to_string(),
        task: task.name.clone(),
        obs_dim: task.obs_dim,
        goal_dim: task.goal_dim,
        act_dim: task.act_dim,
        batch_size: cfg.batch_size,
        batches: count,
        rows,
        data: data.display().to_string(),
        data_sha256: crate::trajectory::folder::digest(data)?,
        settings: settings(cfg, budget)?,
        seed: cfg.seed,
        command: command.to_string(),
        pgser_version: env!("CARGO_PKG_VERSION").to_string(),
    };
    let bytes = writer.finish(&serde_json::to_value(&footer)?)?;
    Ok(DumpSummary { output: out.to_path_buf(), batches: count, rows, bytes })
}

/// The stream's settings as the footer records them; a budget only when one was given, so
/// tables written without one keep their bytes.
fn settings(cfg: &StreamConfig, budget: Budget) -> Result<serde_json::Value> {
    let mut v = serde_json::to_value(cfg)?;
    if let Budget::Bytes { bytes, draws_per_row } = budget {
        v["memory_budget"] = bytes.into();
        if draws_per_row != 1 {
            v["draws_per_row"] = draws_per_row.into();
        }
    }
    Ok(v)
}

/// One row group's columns, filled batch by batch.
#[derive(Default)]
struct Columns {
    batch: Vec<i64>,
    episode: Vec<i64>,
    step: Vec<i32>,
    scored_row: Vec<i64>,
    obs: Vec<f32>,
    goal: Vec<f32>,
    action: Vec<f32>,
    reward: Vec<f32>,
    next_obs: Vec<f32>,
    weight: Vec<f32>,
}

impl Columns {
    fn record_batch(self, schema: &SchemaRef, task: &Task) -> Result<RecordBatch> {
        let columns: Vec<ArrayRef> = vec![
            Arc::new(Int64Array::from(self.batch)),
            Arc::new(Int64Array::from(self.episode)),
            Arc::new(Int32Array::from(self.step)),
            Arc::new(Int64Array::from(self.scored_row)),
            f32_vectors(self.obs, task.obs_dim)?,
            f32_vectors(self.goal, task.goal_dim)?,
            f32_vectors(self.action, task.act_dim)?,
            Arc::new(Float32Array::from(self.reward)),
            f32_vectors(self.next_obs, task.obs_dim)?,
            Arc::new(Float32Array::from(self.weight)),
        ];
        Ok(RecordBatch::try_new(schema.clone(), columns)?)
    }
}
