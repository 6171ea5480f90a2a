//! Passthrough columns: every array of a source that is not one of pgser's four (o, ag, u, g)
//! kept as a column of the trajectory table under its own name, with its dtype and shape, so that
//! `export` can give the source back whole.
//!
//! Why: a table is meant to be the one copy a user keeps. WGCSL buffers carry `info_is_success`,
//! OGBench files `qpos` and `qvel` (its oracle representations and renderings need them), and a
//! user's own buffers whatever they added; dropping them at `convert` loses data without a word,
//! where polars, pyarrow and Minari keep what they do not understand.
//!
//! An array is laid out by how often it has a value ([`Per`]): once per observation (T rows per
//! episode, every row set), once per transition (T − 1: the last step's row null, as `action` is),
//! or once per episode (on step 0, the other rows null). One value is a scalar column, or a
//! fixed-size list of the value's elements in C order when it has a shape. The footer's
//! `passthrough` list says, per column, the source's key, the files it came from, the numpy dtype
//! as the source stored it (byte order included) and the shape of one value; the column holds the
//! values little-endian, as Arrow does, and an export writes them back in the source's order.
//! pgser's own readers never read these columns: the sampler draws what it drew before.
//!
//! Here the record and its checks; [`column`] builds and reads the Arrow columns, [`policy`]
//! decides what a table keeps and what an export can write.

mod column;
mod policy;

use std::sync::Arc;

use anyhow::{Result, bail};
use arrow_schema::{DataType, Field};
use serde::{Deserialize, Serialize};

use crate::dtype::Dtype;

pub use column::{append_source_bytes, column, to_little_endian};
pub use policy::{LAST_ACTION, kept_for, merge};

/// How often a passthrough array has a value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Per {
    /// One per observation: T rows per episode.
    Step,
    /// One per transition: T − 1 rows per episode, null on the last step.
    Transition,
    /// One per episode, on step 0 (null on the others).
    Episode,
}

impl Per {
    /// Values per episode for episodes of T observations.
    pub fn rows(self, t: usize) -> usize {
        match self {
            Per::Step => t,
            Per::Transition => t - 1,
            Per::Episode => 1,
        }
    }

    /// Whether step `step` of an episode of T observations has a value.
    pub fn has(self, step: usize, t: usize) -> bool {
        match self {
            Per::Step => true,
            Per::Transition => step < t - 1,
            Per::Episode => step == 0,
        }
    }

    /// The layout of an array with `lead` values per episode (its dimension after the episodes):
    /// T, T − 1, or anything else as one value per episode whose shape starts with `lead`.
    pub fn of(lead: Option<usize>, t: usize) -> Per {
        match lead {
            Some(l) if l == t => Per::Step,
            Some(l) if l + 1 == t => Per::Transition,
            _ => Per::Episode,
        }
    }
}

/// The footer's record of one passthrough column. Every one is checked as it is made, by
/// [`Passthrough::new`] from a source or by deserializing a footer read back from a file: a
/// footer whose checksum holds can still say what no column holds (another tool's edit, a
/// newer pgser's type), and a reader meeting it later would have nothing to map it to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "Record")]
pub struct Passthrough {
    /// The table's column: the source's key as it wrote it.
    pub column: String,
    /// The source files it came from (`sources[].path`), in order.
    pub files: Vec<String>,
    pub per: Per,
    /// numpy's dtype as the source stored it (`<f8`, `>f4`, `|b1`).
    pub dtype: Dtype,
    /// The shape of one value (`[]` for a scalar; `[1]` for WGCSL's `info_is_success`).
    pub shape: Vec<usize>,
    /// A Minari observation key's subspace, as the dataset's metadata.json has it (Gymnasium's
    /// JSON), so that an export to Minari puts it back in the observation space. Absent else.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub space: Option<String>,
}

/// A passthrough record as a footer holds it, before it is checked.
#[derive(Deserialize)]
struct Record {
    column: String,
    files: Vec<String>,
    per: Per,
    dtype: String,
    shape: Vec<usize>,
    #[serde(default)]
    space: Option<String>,
}

impl TryFrom<Record> for Passthrough {
    type Error = String;

    fn try_from(r: Record) -> Result<Passthrough, String> {
        let dtype = holdable(&r.dtype).map_err(|e| format!("passthrough column `{}` {e}", r.column))?;
        let p = Passthrough { column: r.column, files: r.files, per: r.per, dtype, shape: r.shape, space: r.space };
        match p.fault() {
            Some(e) => Err(format!("passthrough column `{}` {e}", p.column)),
            None => Ok(p),
        }
    }
}

/// The dtype of `descr` if a column can hold it, else what is wrong with it.
fn holdable(descr: &str) -> Result<Dtype, String> {
    Dtype::parse(descr).filter(|d| d.arrow().is_some()).ok_or_else(|| {
        format!("holds {descr} values, which a table column cannot keep (bool, int, uint, float32 and float64 can)")
    })
}

/// Names a passthrough column cannot take: the table's own.
pub const RESERVED: [&str; 6] = ["episode", "step", "obs", "achieved_goal", "desired_goal", "action"];

impl Passthrough {
    /// Elements in one value.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes of one episode's values as the source holds them.
    pub fn episode_bytes(&self, t: usize) -> usize {
        self.per.rows(t) * self.len() * self.dtype.size
    }

    /// The Arrow type of one element of a value.
    pub fn value_type(&self) -> DataType {
        self.dtype.arrow().expect("a passthrough dtype is one a column holds")
    }

    /// The Arrow field of its column.
    pub fn field(&self) -> Field {
        let value = self.value_type();
        if self.shape.is_empty() {
            Field::new(&self.column, value, true)
        } else {
            let item = Arc::new(Field::new("item", value, false));
            Field::new(&self.column, DataType::FixedSizeList(item, self.len() as i32), true)
        }
    }

    /// What keeps a record of a holdable dtype from being a column: a name of the table's own,
    /// or a value of no elements or more than an Arrow list holds.
    fn fault(&self) -> Option<String> {
        if RESERVED.contains(&self.column.as_str()) {
            return Some("has the name of one of the table's own columns".into());
        }
        let len = self.shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
        if !len.is_some_and(|n| n > 0 && n <= i32::MAX as usize) {
            return Some(format!("has values of shape {:?}, which a table column cannot keep", self.shape));
        }
        None
    }

    /// A passthrough array's record, or the one-line reason it cannot be kept. `at` names the
    /// file in the message; `--drop KEY` is the user's way to leave it out.
    pub fn new(at: &str, key: &str, dtype: Dtype, per: Per, shape: Vec<usize>) -> Result<Passthrough> {
        let drop = format!("pass --drop {key} to convert without it");
        let dtype = holdable(&dtype.descr()).map_err(|e| anyhow::anyhow!("{at}: key '{key}' {e}; {drop}"))?;
        let p = Passthrough { column: key.to_string(), files: vec![at.to_string()], per, dtype, shape, space: None };
        if let Some(e) = p.fault() {
            bail!("{at}: key '{key}' {e}; {drop}");
        }
        Ok(p)
    }
}

/// One passthrough array of a source's episodes: `data` holds every episode's values,
/// little-endian and in C order (`episodes × per.rows(T) × value`), however the source stored them.
#[derive(Debug, Clone)]
pub struct ExtraArray<'a> {
    pub spec: Passthrough,
    pub data: std::borrow::Cow<'a, [u8]>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dtype(d: &str) -> Dtype {
        Dtype::parse(d).unwrap()
    }

    #[test]
    fn what_cannot_be_kept_is_named_with_its_way_out() {
        let e = Passthrough::new("f.pkl", "half", dtype("<f2"), Per::Step, vec![]).unwrap_err().to_string();
        assert!(e.contains("key 'half' holds <f2") && e.contains("--drop half"), "{e}");
        let e = Passthrough::new("f.pkl", "obs", dtype("<f4"), Per::Step, vec![2]).unwrap_err().to_string();
        assert!(e.contains("one of the table's own columns") && e.contains("--drop obs"), "{e}");
        let e = Passthrough::new("f.pkl", "z", dtype("<f4"), Per::Step, vec![0]).unwrap_err().to_string();
        assert!(e.contains("shape [0]"), "{e}");
    }

    /// A record read back from a footer is checked as one made from a source is, whatever its
    /// dtype text, and the refusal names the column.
    #[test]
    fn a_footer_record_is_checked_as_it_is_read() {
        let p = Passthrough::new("f.pkl", "x", dtype(">i2"), Per::Transition, vec![2]).unwrap();
        let json = serde_json::to_value(&p).unwrap();
        assert_eq!(json["dtype"], ">i2");
        assert_eq!(serde_json::from_value::<Passthrough>(json.clone()).unwrap(), p);
        for (field, bad, want) in [
            ("dtype", serde_json::json!("<f2"), "passthrough column `x` holds <f2 values"),
            ("dtype", serde_json::json!("<é4"), "passthrough column `x` holds <é4 values"),
            ("dtype", serde_json::json!(""), "passthrough column `x` holds  values"),
            ("shape", serde_json::json!([0]), "passthrough column `x` has values of shape [0]"),
            ("shape", serde_json::json!([1usize << 40, 1usize << 40]), "passthrough column `x` has values of shape"),
            ("column", serde_json::json!("step"), "passthrough column `step` has the name of one of the table's own"),
        ] {
            let mut j = json.clone();
            j[field] = bad;
            let e = serde_json::from_value::<Passthrough>(j).unwrap_err().to_string();
            assert!(e.contains(want), "{field}: {e}");
        }
    }
}
