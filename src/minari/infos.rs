//! Minari's `infos`: the per-step info dicts an episode recorded (`DataCollector(record_infos=True)`),
//! one array per key with a row per observation (the reset's info, then each step's). `convert`
//! keeps each as a passthrough column `infos/KEY` ([`crate::trajectory::extra`]) and `export
//! --format minari` writes every per-step passthrough column back into the episodes' `infos`.
//!
//! Both storages hold the same thing: HDF5 a group `infos` of datasets, Arrow a struct column
//! `infos` whose fields are scalars or fixed-size lists, a field's `shape` metadata giving a value's
//! shape when it has more than one dimension (Minari's own writer sets it). Nested dicts are not
//! read: they are refused by name, and `--drop infos/KEY` leaves one out.

use std::collections::HashMap;
use std::sync::Arc;

use anyhow::{Result, bail};
use arrow_array::{Array, ArrayRef, BooleanArray, FixedSizeListArray, StructArray, make_array};
use arrow_buffer::{BooleanBuffer, Buffer};
use arrow_data::ArrayData;
use arrow_schema::{DataType, Field, Fields};

use crate::dtype::Dtype;

/// One key of an episode's infos: its numpy dtype, the shape of one row's value, its rows and
/// their bytes (little-endian, C order).
#[derive(Debug, Clone, PartialEq)]
pub struct Info {
    pub key: String,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    pub rows: usize,
    pub bytes: Vec<u8>,
}

/// `values[start..start + len]` of a primitive or boolean array as little-endian bytes (bools as
/// 0/1), or None where one is null.
fn value_bytes(values: &ArrayRef, start: usize, len: usize) -> Option<Vec<u8>> {
    if (start..start + len).any(|i| values.is_null(i)) {
        return None;
    }
    if let Some(b) = values.as_any().downcast_ref::<BooleanArray>() {
        return Some((start..start + len).map(|i| u8::from(b.value(i))).collect());
    }
    let size = values.data_type().primitive_width()?;
    let data = values.to_data();
    let at = (data.offset() + start) * size;
    Some(data.buffers()[0].as_slice()[at..at + len * size].to_vec())
}

/// The passthrough column a field of struct `group` (`infos`, `observations`; None for a
/// top-level column such as `rewards`) becomes: the name `--drop` takes.
pub fn column_name(group: Option<&str>, key: &str) -> String {
    group.map_or_else(|| key.to_string(), |g| format!("{g}/{key}"))
}

/// A struct of one record batch of an Arrow episode (its `infos`, the Dict observation's other
/// keys, or the rewards, terminations and truncations gathered as one): every field but those
/// `drop` names ([`column_name`] of `group`), its rows' bytes. A field left out is never looked
/// at, so `--drop` is the way past one no column can keep. `at` names the file in errors.
pub fn from_arrow(at: &str, infos: &StructArray, group: Option<&str>, drop: &[String]) -> Result<Vec<Info>> {
    let mut out = Vec::new();
    for (field, col) in infos.fields().iter().zip(infos.columns()) {
        let key = field.name();
        let column = column_name(group, key);
        if drop.contains(&column) {
            continue;
        }
        let shown = group.map_or_else(|| key.to_string(), |g| format!("{g}.{key}"));
        let cannot = |what: &str| {
            anyhow::anyhow!(
                "{at}: `{shown}` is {what}, which a table column cannot keep; pass --drop {column} to convert without it"
            )
        };
        let (values, start, width, shape) = match col.data_type() {
            DataType::FixedSizeList(_, size) => {
                let list = col.as_any().downcast_ref::<FixedSizeListArray>().expect("a fixed-size list");
                let size = *size as usize;
                // Minari records a value's shape in the field's metadata ("2,2"); one dimension else.
                let shape = match field.metadata().get("shape") {
                    Some(s) => s
                        .split(',')
                        .filter(|d| !d.trim().is_empty())
                        .map(|d| d.trim().parse::<usize>().map_err(|_| cannot(&format!("of shape {s:?}"))))
                        .collect::<Result<Vec<_>>>()?,
                    None => vec![size],
                };
                if shape.iter().product::<usize>() != size {
                    bail!("{at}: `{shown}` holds lists of {size} values but its shape metadata says {shape:?}");
                }
                if (0..list.len()).any(|r| list.is_null(r)) {
                    return Err(cannot("null in a row"));
                }
                (list.values().clone(), list.value_offset_at(0), size, shape)
            }
            _ => (col.clone(), 0, 1, vec![]),
        };
        let dtype = Dtype::from_arrow(values.data_type()).ok_or_else(|| cannot(&values.data_type().to_string()))?;
        let bytes = value_bytes(&values, start, col.len() * width).ok_or_else(|| cannot("null in a row"))?;
        out.push(Info { key: key.clone(), dtype, shape, rows: col.len(), bytes });
    }
    Ok(out)
}

/// `more` (a later record batch's infos of the same episode) appended to `infos`.
pub fn extend(at: &str, infos: &mut Vec<Info>, more: Vec<Info>) -> Result<()> {
    if infos.is_empty() {
        *infos = more;
        return Ok(());
    }
    if more.len() != infos.len() {
        bail!("{at}: the record batches of an episode have different infos keys");
    }
    for (a, b) in infos.iter_mut().zip(more) {
        if (a.key.as_str(), a.dtype, &a.shape) != (b.key.as_str(), b.dtype, &b.shape) {
            bail!("{at}: `infos.{}` differs between the record batches of an episode", a.key);
        }
        a.rows += b.rows;
        a.bytes.extend(b.bytes);
    }
    Ok(())
}

/// The `infos` struct column of an exported episode: each `(key, dtype, shape, bytes of `rows`
/// rows)`, a scalar field or a fixed-size list with Minari's `shape` metadata.
pub fn to_arrow(infos: &[(String, Dtype, Vec<usize>, Vec<u8>)], rows: usize) -> Result<(Field, ArrayRef)> {
    let mut fields = Vec::new();
    let mut columns: Vec<ArrayRef> = Vec::new();
    for (key, dtype, shape, bytes) in infos {
        let value_type = dtype.arrow().expect("a passthrough dtype");
        let width: usize = shape.iter().product();
        let n = rows * width.max(1);
        // Arrow holds values little-endian: a big-endian source's bytes are turned around.
        let mut le = bytes.clone();
        dtype.reorder(&mut le);
        let values: ArrayRef = match value_type {
            DataType::Boolean => Arc::new(BooleanArray::new(BooleanBuffer::collect_bool(n, |i| le[i] != 0), None)),
            ref t => make_array(ArrayData::builder(t.clone()).len(n).add_buffer(Buffer::from_vec(le)).build()?),
        };
        if shape.is_empty() {
            fields.push(Field::new(key, value_type, true));
            columns.push(values);
        } else {
            let item = Arc::new(Field::new("item", value_type, true));
            let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
            let field = Field::new(key, DataType::FixedSizeList(item.clone(), width as i32), true)
                .with_metadata(HashMap::from([("shape".to_string(), dims.join(","))]));
            fields.push(field);
            columns.push(Arc::new(FixedSizeListArray::try_new(item, width as i32, values, None)?));
        }
    }
    let fields = Fields::from(fields);
    let array = StructArray::try_new(fields.clone(), columns, None)?;
    Ok((Field::new("infos", DataType::Struct(fields), true), Arc::new(array)))
}
