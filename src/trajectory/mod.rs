//! The trajectory table (docs/tables.md): one row per observation, episodes contiguous and ordered
//! by (episode, step). `desired_goal` is null on the last step, where WGCSL's `g` (T − 1 entries
//! per episode) has nothing, and so is `action`, unless the source had an action there (OGBench's
//! files: the footer's `last_action`). [`Episodes`] loads a table for training.

mod batch;
mod convert;
pub mod extra;
pub mod folder;
pub mod read;

use std::sync::Arc;

use anyhow::{Result, anyhow, bail};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use serde::{Deserialize, Serialize};

use crate::table::{FOOTER_KEY, SCHEMA_VERSION};
use crate::task::{GoalMetric, Task};

pub use batch::{
    EpisodeArrays, FloatArray, IMAGE_GROUP_BYTES, KEYS, TrajectoryWriter, WriterOptions, episodes_per_group,
    image_episodes_per_group,
};
pub use convert::{ConvertOptions, ConvertPlan, ConvertSummary, check as check_convert, convert};
pub(crate) use convert::{describe, task_for};
pub use extra::{ExtraArray, Passthrough, Per};
pub use read::Episodes;

/// The float type of a table's vector columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FloatType {
    Float32,
    Float64,
}

impl FloatType {
    pub fn arrow(self) -> DataType {
        match self {
            FloatType::Float32 => DataType::Float32,
            FloatType::Float64 => DataType::Float64,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            FloatType::Float32 => "float32",
            FloatType::Float64 => "float64",
        }
    }
}

/// A FixedSizeList<float>[dim] column; the list items themselves are never null.
pub fn vector_field(name: &str, float: FloatType, dim: usize, nullable: bool) -> Field {
    let item = Arc::new(Field::new("item", float.arrow(), false));
    Field::new(name, DataType::FixedSizeList(item, dim as i32), nullable)
}

/// The `obs` column of image observations: each row one image's bytes (`obs_dim` of them, C
/// order), as Parquet's FIXED_LEN_BYTE_ARRAY. Why not a fixed-size list of uint8, as a
/// passthrough array of bytes is: a list carries a repetition and a definition level for every
/// byte (12,288 per OGBench image), which every reader decodes, where a fixed-size binary value
/// has none and decodes as a copy; and any Parquet reader gives it back as one `bytes` per row
/// (`np.frombuffer(...).reshape(n, 64, 64, 3)`).
pub fn image_field(name: &str, bytes: usize) -> Field {
    Field::new(name, DataType::FixedSizeBinary(bytes as i32), false)
}

/// The trajectory schema: `obs` float vectors, or with `image` uint8 images ([`image_field`]).
pub fn schema(float: FloatType, task: &Task, image: bool) -> SchemaRef {
    let obs = if image { image_field("obs", task.obs_dim) } else { vector_field("obs", float, task.obs_dim, false) };
    Arc::new(Schema::new(vec![
        Field::new("episode", DataType::Int64, false),
        Field::new("step", DataType::Int32, false),
        obs,
        vector_field("achieved_goal", float, task.goal_dim, false),
        vector_field("desired_goal", float, task.goal_dim, true),
        vector_field("action", float, task.act_dim, true),
    ]))
}

/// [`Footer::state_only`] for a table whose observations have `image_shape` (empty: states).
pub fn state_only(at: &str, image_shape: &[usize], what: &str) -> Result<()> {
    if !image_shape.is_empty() {
        bail!(
            "{at}: observations are {} uint8 images (a visual dataset), and {what} takes state observations (float \
             vectors); convert, export --format ogbench, inspect, verify and pgser.Sampler(layout=\"ogbench\") read \
             image tables",
            shape_text(image_shape)
        );
    }
    Ok(())
}

/// `64×64×3`.
pub fn shape_text(shape: &[usize]) -> String {
    shape.iter().map(usize::to_string).collect::<Vec<_>>().join("×")
}

/// Where a table's episodes came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceFile {
    pub path: String,
    pub sha256: String,
    pub format: String,
    pub episodes_in_file: usize,
    pub episodes_taken: usize,
    /// Steps left out at the end of each episode to fit the task's T (a Minari dataset recorded
    /// under gymnasium's time limit has one more than WGCSL's episodes); absent when none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub steps_dropped: usize,
    /// Bytes per value of observation, achieved goal, desired goal and action as the source
    /// stored them, where one differs from the table's float type (a Minari dataset's float32
    /// actions beside float64 observations): what `export` writes them back as. Absent otherwise.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub float_bytes: Vec<usize>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// The `pgser` footer of a trajectory table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Footer {
    pub schema_version: u32,
    pub kind: String,
    pub task: String,
    #[serde(rename = "T")]
    pub t: usize,
    pub obs_dim: usize,
    pub goal_dim: usize,
    pub act_dim: usize,
    pub goal_metric: GoalMetric,
    pub success_threshold: f64,
    /// The float type of the vector columns: every one but `obs` in an image table.
    pub float_type: FloatType,
    /// Where observations are images (OGBench's visual datasets: 64 × 64 × 3): the shape of one,
    /// whose `obs_dim` bytes each `obs` row holds as uint8 in C order ([`image_field`]). Empty
    /// (absent) for state observations, float vectors of `float_type`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub image_shape: Vec<usize>,
    pub episodes: usize,
    pub rows: usize,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sources: Vec<SourceFile>,
    /// For collected data: the policy and seed that produced it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub policy: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// The source's arrays that are not pgser's four, each a column of its own
    /// ([`extra`]); absent when none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub passthrough: Vec<Passthrough>,
    /// `action` holds each episode's last action on step T − 1, where the source had one
    /// (OGBench's files); absent (false) when that row is null.
    #[serde(default, skip_serializing_if = "is_false")]
    pub last_action: bool,
    pub command: String,
    pub pgser_version: String,
}

pub const KIND: &str = "trajectory";

impl Footer {
    pub fn new(task: &Task, float_type: FloatType, episodes: usize, command: String) -> Self {
        Footer {
            schema_version: SCHEMA_VERSION,
            kind: KIND.to_string(),
            task: task.name.clone(),
            t: task.t,
            obs_dim: task.obs_dim,
            goal_dim: task.goal_dim,
            act_dim: task.act_dim,
            goal_metric: task.metric,
            success_threshold: task.threshold,
            float_type,
            image_shape: Vec::new(),
            episodes,
            rows: episodes * task.t,
            sources: Vec::new(),
            policy: None,
            seed: None,
            passthrough: Vec::new(),
            last_action: false,
            command,
            pgser_version: env!("CARGO_PKG_VERSION").to_string(),
        }
    }

    /// A trajectory footer read back from the file `at` (the `pgser` key's JSON). Every reader
    /// of a table's footer comes through here: a footer whose checksum holds can still say what
    /// pgser never writes (another tool's edit, a newer pgser), and what it says of the
    /// passthrough columns is checked here (each record as it deserializes: [`Passthrough`]),
    /// before any reader maps a column by it. A fault names the file and the column; a footer
    /// of another kind of table is refused as that.
    pub fn from_json(at: &str, json: serde_json::Value) -> Result<Footer> {
        match json.get("kind").and_then(|k| k.as_str()) {
            Some(KIND) => {}
            Some(kind) => bail!("{at}: a {kind} table, not a trajectory table"),
            None => bail!("{at}: the `{FOOTER_KEY}` footer names no table kind"),
        }
        let f: Footer =
            serde_json::from_value(json).map_err(|e| anyhow!("{at}: the trajectory footer is corrupt: {e}"))?;
        let columns = &f.passthrough;
        if let Some((_, p)) =
            columns.iter().enumerate().find(|(i, p)| columns[..*i].iter().any(|q| q.column == p.column))
        {
            bail!("{at}: the trajectory footer is corrupt: it lists the passthrough column `{}` twice", p.column);
        }
        if !f.image_shape.is_empty()
            && f.image_shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d)) != Some(f.obs_dim)
        {
            bail!(
                "{at}: the trajectory footer is corrupt: images of shape {:?} are not obs_dim = {} bytes",
                f.image_shape,
                f.obs_dim
            );
        }
        Ok(f)
    }

    /// Whether observations are images ([`Footer::image_shape`]).
    pub fn is_image(&self) -> bool {
        !self.image_shape.is_empty()
    }

    /// Refuses an image table where `what` needs state observations (float vectors): training,
    /// scoring and the samplers read observations as floats, and a 12,288-value "state" of bytes
    /// is no observation a pgser agent was built for.
    pub fn state_only(&self, at: &str, what: &str) -> Result<()> {
        state_only(at, &self.image_shape, what)
    }

    /// The task this table was written for, with the threshold recorded in the file.
    pub fn task(&self) -> Task {
        Task {
            name: self.task.clone(),
            t: self.t,
            obs_dim: self.obs_dim,
            goal_dim: self.goal_dim,
            act_dim: self.act_dim,
            threshold: self.success_threshold,
            metric: self.goal_metric,
        }
    }
}
