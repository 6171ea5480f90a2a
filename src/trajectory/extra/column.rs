//! Passthrough arrays as Arrow columns and back: a source's values (little-endian, C order) laid
//! out on the table's rows by their [`Per`], and a column's values given back in the source's
//! byte order for an export.

use std::borrow::Cow;
use std::sync::Arc;

use anyhow::{Result, bail};
use arrow_array::{Array, ArrayRef, BooleanArray, FixedSizeListArray, make_array};
use arrow_buffer::{BooleanBuffer, Buffer, MutableBuffer, NullBuffer};
use arrow_data::ArrayData;
use arrow_schema::{DataType, Field};

use super::{ExtraArray, Passthrough, Per};
use crate::dtype::{Dtype, Kind};

/// Episodes [e0, e1) of `a` as a column of (e1 − e0)·T rows: the values on the steps that have
/// one, nulls (and zeros beneath them) on the others.
pub fn column(a: &ExtraArray, t: usize, e0: usize, e1: usize) -> Result<ArrayRef> {
    let p = &a.spec;
    let dtype = p.dtype;
    let (value, size, per_ep) = (p.len(), dtype.size, p.per.rows(t));
    let rows = (e1 - e0) * t;
    let src = &a.data[e0 * per_ep * value * size..e1 * per_ep * value * size];
    let mut buf = MutableBuffer::with_capacity(rows * value * size);
    let row_bytes = value * size;
    for ep in src.chunks_exact(per_ep * row_bytes) {
        match p.per {
            Per::Step => buf.extend_from_slice(ep),
            Per::Transition => {
                buf.extend_from_slice(ep);
                buf.extend_zeros(row_bytes);
            }
            Per::Episode => {
                buf.extend_from_slice(ep);
                buf.extend_zeros((t - 1) * row_bytes);
            }
        }
    }
    let values: ArrayRef = match p.value_type() {
        DataType::Boolean => {
            let bytes: &[u8] = buf.as_slice();
            Arc::new(BooleanArray::new(BooleanBuffer::collect_bool(rows * value, |i| bytes[i] != 0), None))
        }
        dt => make_array(ArrayData::builder(dt).len(rows * value).add_buffer(Buffer::from(buf)).build()?),
    };
    let nulls =
        (p.per != Per::Step).then(|| NullBuffer::new(BooleanBuffer::collect_bool(rows, |r| p.per.has(r % t, t))));
    if p.shape.is_empty() {
        return Ok(make_array(values.into_data().into_builder().nulls(nulls).build()?));
    }
    let item = Arc::new(Field::new("item", values.data_type().clone(), false));
    Ok(Arc::new(FixedSizeListArray::try_new(item, value as i32, values, nulls)?))
}

/// Rows [r0, r1) of a passthrough column, table rows `first_row + r`, appended to `out` as the
/// source stored them (its byte order; only the steps that have a value). A null where a value
/// belongs, or a value where none does, is an error naming the row.
pub fn append_source_bytes(
    out: &mut Vec<u8>,
    p: &Passthrough,
    col: &ArrayRef,
    first_row: usize,
    t: usize,
    at: &str,
) -> Result<()> {
    let dtype = p.dtype;
    let value = p.len();
    let (values, offset): (ArrayRef, usize) = if p.shape.is_empty() {
        (col.clone(), 0)
    } else {
        let list = col.as_any().downcast_ref::<FixedSizeListArray>().expect("checked by type");
        (list.values().clone(), list.value_offset_at(0))
    };
    let data = values.to_data();
    for r in 0..col.len() {
        let row = first_row + r;
        let has = p.per.has(row % t, t);
        if col.is_null(r) == has {
            let what =
                if has { "is null where the source had a value" } else { "has a value where the source had none" };
            bail!("{at}: row {row} (episode {}, step {}): `{}` {what}", row / t, row % t, p.column);
        }
        if !has {
            continue;
        }
        let start = offset + r * value;
        match dtype.kind {
            Kind::Bool => {
                let bools = values.as_any().downcast_ref::<BooleanArray>().expect("checked by type");
                out.extend((start..start + value).map(|i| u8::from(bools.value(i))));
            }
            _ => {
                let size = dtype.size;
                let bytes = &data.buffers()[0].as_slice()
                    [(data.offset() + start) * size..(data.offset() + start + value) * size];
                let at = out.len();
                out.extend_from_slice(bytes);
                dtype.reorder(&mut out[at..]);
            }
        }
    }
    Ok(())
}

/// `src` (the source's bytes, in its byte order) little-endian, as a column holds them.
pub fn to_little_endian(src: Cow<'_, [u8]>, dtype: Dtype) -> Cow<'_, [u8]> {
    if !dtype.big_endian {
        return src;
    }
    let mut owned = src.into_owned();
    dtype.reorder(&mut owned);
    Cow::Owned(owned)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_column_holds_each_layout_and_gives_the_source_bytes_back() {
        let t = 4;
        for (per, descr, shape) in [
            (Per::Step, ">f4", vec![2]),
            (Per::Transition, "<i8", vec![1]),
            (Per::Episode, "|b1", vec![3]),
            (Per::Transition, "|u1", vec![]),
            (Per::Episode, "<f8", vec![2, 2]),
        ] {
            let spec = Passthrough::new("f.pkl", "x", Dtype::parse(descr).unwrap(), per, shape).unwrap();
            let dtype = spec.dtype;
            let episodes = 3;
            let n = episodes * spec.episode_bytes(t);
            // Source bytes in the source's order: bools 0/1, others any pattern.
            let source: Vec<u8> = (0..n)
                .map(|i| if dtype.kind == Kind::Bool { (i % 3 == 1) as u8 } else { (i * 37 + 11) as u8 })
                .collect();
            let le = to_little_endian(source.clone().into(), dtype);
            let a = ExtraArray { spec: spec.clone(), data: le };
            // Episodes 1..3 as one batch, then back.
            let col = column(&a, t, 1, 3).unwrap();
            assert_eq!(col.len(), 2 * t);
            assert_eq!(col.data_type(), spec.field().data_type(), "{descr}");
            let mut back = Vec::new();
            append_source_bytes(&mut back, &spec, &col, t, t, "table").unwrap();
            assert_eq!(back, source[n / 3..], "{per:?} {descr}");
            // A column read as another layout is refused by row.
            let other = Passthrough { per: if per == Per::Step { Per::Episode } else { Per::Step }, ..spec.clone() };
            let e = append_source_bytes(&mut Vec::new(), &other, &col, t, t, "table").unwrap_err().to_string();
            assert!(e.starts_with("table: row "), "{e}");
        }
    }
}
