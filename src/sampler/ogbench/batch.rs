//! One batch of the OGBench-layout stream: named columns, in the order the class they follow
//! has its dict's keys, each with the dtype that class's numpy code gives it.
//!
//! Four classes share this shape (OGBench's and Horizon Reduction's `GCDataset` and
//! `HGCDataset`) and hold different keys, so a batch is a list of keys rather than a struct of
//! fields: the Python dict is built by walking it, and a test asks for a key by name. Beside
//! the class's own keys a batch carries where each row and each goal came from (provenance
//! columns, marked as such so `provenance=False` can leave them out of the dict).

use super::GoalKind;

/// One key's values, `n` rows of them.
#[derive(Debug, Clone, PartialEq)]
pub enum Column {
    /// float32 rows of `dim` values, row-major; `dim` None: one value a row, a 1-D array.
    F32 { dim: Option<usize>, values: Vec<f32> },
    /// float64, one a row: numpy's `.astype(float)` masks and rewards, Horizon Reduction's
    /// discounted n-step rewards.
    F64(Vec<f64>),
    /// int64, one a row: subgoal steps, offsets, and the provenance columns' episodes and steps.
    I64(Vec<i64>),
    /// A drawn goal's kind, one a row (uint8 codes in Python: [`GoalKind::code`]).
    Kind(Vec<GoalKind>),
    /// uint8 images, each of `shape` ([H, W, C], C·frame_stack channels when stacked), row-major.
    U8 { shape: Vec<usize>, values: Vec<u8> },
}

/// A named column, and whether it is provenance (pgser's account of where a row came from, not
/// a key of the class it follows).
#[derive(Debug, Clone, PartialEq)]
pub struct Key {
    pub name: String,
    pub column: Column,
    pub provenance: bool,
}

/// One batch of `n` rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OgbenchBatch {
    pub n: usize,
    pub keys: Vec<Key>,
}

impl OgbenchBatch {
    pub(super) fn push(&mut self, name: &str, column: Column) {
        self.keys.push(Key { name: name.to_string(), column, provenance: false });
    }

    pub(super) fn push_provenance(&mut self, name: &str, column: Column) {
        self.keys.push(Key { name: name.to_string(), column, provenance: true });
    }

    pub fn get(&self, name: &str) -> Option<&Column> {
        self.keys.iter().find(|k| k.name == name).map(|k| &k.column)
    }

    /// The names of the batch's keys, in order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.keys.iter().map(|k| k.name.as_str())
    }

    /// A float32 key's values, and its row width (1 for a 1-D key); None if the batch has no
    /// such float32 key.
    pub fn f32(&self, name: &str) -> Option<(&[f32], usize)> {
        match self.get(name)? {
            Column::F32 { dim, values } => Some((values, dim.unwrap_or(1))),
            _ => None,
        }
    }

    pub fn f64(&self, name: &str) -> Option<&[f64]> {
        match self.get(name)? {
            Column::F64(v) => Some(v),
            _ => None,
        }
    }

    pub fn i64(&self, name: &str) -> Option<&[i64]> {
        match self.get(name)? {
            Column::I64(v) => Some(v),
            _ => None,
        }
    }

    /// An image key's bytes and each row's shape; None if the batch has no such image key.
    pub fn u8(&self, name: &str) -> Option<(&[u8], &[usize])> {
        match self.get(name)? {
            Column::U8 { shape, values } => Some((values, shape)),
            _ => None,
        }
    }

    pub fn kinds(&self, name: &str) -> Option<&[GoalKind]> {
        match self.get(name)? {
            Column::Kind(v) => Some(v),
            _ => None,
        }
    }

    /// Row `i` of a float32 key (a batch's vectors by row, for tests and audits).
    pub fn row(&self, name: &str, i: usize) -> Option<&[f32]> {
        let (v, dim) = self.f32(name)?;
        v.get(i * dim..(i + 1) * dim)
    }
}
