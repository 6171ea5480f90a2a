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

use std::sync::Arc;

use anyhow::{Result, bail};
use arrow_array::{Array, ArrayRef, BooleanArray, FixedSizeListArray, make_array};
use arrow_buffer::{BooleanBuffer, Buffer, MutableBuffer, NullBuffer};
use arrow_data::ArrayData;
use arrow_schema::{DataType, Field};
use serde::{Deserialize, Serialize};

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

/// A numpy element type: kind (`b` bool, `i`, `u`, `f`), bytes, and the byte order the source
/// stored it in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Elem {
    pub kind: char,
    pub size: usize,
    pub big_endian: bool,
}

impl Elem {
    /// numpy's `descr`: `<f4`, `>i8`, `|b1`, `|u1`.
    pub fn descr(self) -> String {
        let order = if self.size == 1 {
            '|'
        } else if self.big_endian {
            '>'
        } else {
            '<'
        };
        format!("{order}{}{}", self.kind, self.size)
    }

    /// The element type of a `descr` that a column can hold.
    pub fn parse(descr: &str) -> Option<Elem> {
        let (big_endian, rest) = match descr.as_bytes().first()? {
            b'>' => (true, &descr[1..]),
            b'<' | b'|' | b'=' => (false, &descr[1..]),
            _ => (false, descr),
        };
        let kind = rest.chars().next()?;
        let size: usize = rest[1..].parse().ok()?;
        let e = Elem { kind, size, big_endian: big_endian && size > 1 };
        e.arrow().is_some().then_some(e)
    }

    /// The Arrow type of its values; None for types a column does not hold (float16, complex,
    /// strings, objects).
    pub fn arrow(self) -> Option<DataType> {
        Some(match (self.kind, self.size) {
            ('b', 1) => DataType::Boolean,
            ('i', 1) => DataType::Int8,
            ('i', 2) => DataType::Int16,
            ('i', 4) => DataType::Int32,
            ('i', 8) => DataType::Int64,
            ('u', 1) => DataType::UInt8,
            ('u', 2) => DataType::UInt16,
            ('u', 4) => DataType::UInt32,
            ('u', 8) => DataType::UInt64,
            ('f', 4) => DataType::Float32,
            ('f', 8) => DataType::Float64,
            _ => return None,
        })
    }
}

/// The footer's record of one passthrough column.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Passthrough {
    /// The table's column: the source's key as it wrote it.
    pub column: String,
    /// The source files it came from (`sources[].path`), in order.
    pub files: Vec<String>,
    pub per: Per,
    /// numpy's dtype as the source stored it (`<f8`, `>f4`, `|b1`).
    pub dtype: String,
    /// The shape of one value (`[]` for a scalar; `[1]` for WGCSL's `info_is_success`).
    pub shape: Vec<usize>,
    /// A Minari observation key's subspace, as the dataset's metadata.json has it (Gymnasium's
    /// JSON), so that an export to Minari puts it back in the observation space. Absent else.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub space: Option<String>,
}

/// Names a passthrough column cannot take: the table's own.
pub const RESERVED: [&str; 6] = ["episode", "step", "obs", "achieved_goal", "desired_goal", "action"];

impl Passthrough {
    pub fn elem(&self) -> Elem {
        Elem::parse(&self.dtype).expect("checked when made")
    }

    /// Elements in one value.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes of one episode's values as the source holds them.
    pub fn episode_bytes(&self, t: usize) -> usize {
        self.per.rows(t) * self.len() * self.elem().size
    }

    /// The Arrow field of its column.
    pub fn field(&self) -> Field {
        let value = self.elem().arrow().expect("checked when made");
        if self.shape.is_empty() {
            Field::new(&self.column, value, true)
        } else {
            let item = Arc::new(Field::new("item", value, false));
            Field::new(&self.column, DataType::FixedSizeList(item, self.len() as i32), true)
        }
    }

    /// A passthrough array's record, or the one-line reason it cannot be kept. `at` names the
    /// file in the message; `--drop KEY` is the user's way to leave it out.
    pub fn new(at: &str, key: &str, descr: &str, per: Per, shape: Vec<usize>) -> Result<Passthrough> {
        let Some(elem) = Elem::parse(descr) else {
            bail!(
                "{at}: key '{key}' holds {descr} values, which a table column cannot keep (bool, int, uint, float32 \
                 and float64 can); pass --drop {key} to convert without it"
            );
        };
        if RESERVED.contains(&key) {
            bail!(
                "{at}: key '{key}' has the name of one of the table's own columns; pass --drop {key} to convert without it"
            );
        }
        let p = Passthrough {
            column: key.to_string(),
            files: vec![at.to_string()],
            per,
            dtype: elem.descr(),
            shape,
            space: None,
        };
        if p.is_empty() || p.len() > i32::MAX as usize {
            bail!(
                "{at}: key '{key}' has values of shape {:?}, which a table column cannot keep; pass --drop {key}",
                p.shape
            );
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

/// Episodes [e0, e1) of `a` as a column of (e1 − e0)·T rows: the values on the steps that have
/// one, nulls (and zeros beneath them) on the others.
pub fn column(a: &ExtraArray, t: usize, e0: usize, e1: usize) -> Result<ArrayRef> {
    let p = &a.spec;
    let elem = p.elem();
    let (value, size, per_ep) = (p.len(), elem.size, p.per.rows(t));
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
    let values: ArrayRef = match elem.arrow().expect("checked") {
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
    let elem = p.elem();
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
        match elem.kind {
            'b' => {
                let bools = values.as_any().downcast_ref::<BooleanArray>().expect("checked by type");
                out.extend((start..start + value).map(|i| u8::from(bools.value(i))));
            }
            _ => {
                let size = elem.size;
                let bytes = &data.buffers()[0].as_slice()
                    [(data.offset() + start) * size..(data.offset() + start + value) * size];
                let at = out.len();
                out.extend_from_slice(bytes);
                if elem.big_endian {
                    out[at..].chunks_exact_mut(size).for_each(<[u8]>::reverse);
                }
            }
        }
    }
    Ok(())
}

/// `src` (the source's bytes, in its byte order) little-endian, as a column holds them.
pub fn to_little_endian<'a>(src: std::borrow::Cow<'a, [u8]>, elem: Elem) -> std::borrow::Cow<'a, [u8]> {
    if !elem.big_endian {
        return src;
    }
    let mut owned = src.into_owned();
    owned.chunks_exact_mut(elem.size).for_each(<[u8]>::reverse);
    std::borrow::Cow::Owned(owned)
}

/// The passthrough arrays of several sources made into one list: the same keys, with the same
/// layout, dtype and shape, in every source (or the first difference, named, with `--drop`).
/// `files` of each record lists every source that had it.
pub fn merge(per_source: &[(String, Vec<Passthrough>)]) -> Result<Vec<Passthrough>> {
    let Some((first_at, first)) = per_source.first() else { return Ok(Vec::new()) };
    let mut merged = first.clone();
    for (at, specs) in &per_source[1..] {
        for p in specs {
            match merged.iter_mut().find(|m| m.column == p.column) {
                Some(m) if (m.per, &m.dtype, &m.shape) == (p.per, &p.dtype, &p.shape) => m.files.push(at.clone()),
                Some(m) => bail!(
                    "{at}: key '{}' is {} of shape {:?} per {:?} where {first_at} has {} of shape {:?} per {:?}; pass --drop {} \
                     to convert without it",
                    p.column,
                    p.dtype,
                    p.shape,
                    p.per,
                    m.dtype,
                    m.shape,
                    m.per,
                    p.column
                ),
                None => bail!(
                    "{at}: key '{}' is not in {first_at}: a table's episodes all have the same columns; pass --drop {} to \
                     convert without it",
                    p.column,
                    p.column
                ),
            }
        }
        if let Some(m) = merged.iter().find(|m| !specs.iter().any(|p| p.column == m.column)) {
            bail!(
                "{at}: has no key '{}', which {first_at} has: a table's episodes all have the same columns; pass --drop {} \
                 to convert without it",
                m.column,
                m.column
            );
        }
    }
    Ok(merged)
}

/// What `--drop` calls each episode's last action (OGBench's files have one on their last row;
/// the table keeps it on step T − 1).
pub const LAST_ACTION: &str = "last_action";

/// What a table holds beyond pgser's four arrays, less what `drop` leaves out, with what the
/// format cannot hold refused by name (`holds`: whether the format can hold a passthrough
/// column; `last_action`: whether it can hold the last actions). Checked before any output
/// exists. Returns the passthrough columns to write, and whether to write the last actions.
pub fn kept_for(
    footer: &super::Footer,
    table: &std::path::Path,
    format: &str,
    drop: &[String],
    holds: impl Fn(&Passthrough) -> bool,
    last_action: bool,
) -> Result<(Vec<Passthrough>, bool)> {
    let at = table.display();
    for d in drop {
        if d != LAST_ACTION && !footer.passthrough.iter().any(|p| p.column == *d) {
            let have: Vec<&str> = footer.passthrough.iter().map(|p| p.column.as_str()).collect();
            bail!(
                "--drop {d}: {at} has no passthrough column {d:?} (it has: {})",
                if have.is_empty() { "none".into() } else { have.join(", ") }
            );
        }
    }
    let mut kept = Vec::new();
    for p in footer.passthrough.iter().filter(|p| !drop.contains(&p.column)) {
        if !holds(p) {
            bail!(
                "{at}: a {format} file cannot hold the passthrough column {} ({} of shape {:?}, one per {:?}); pass --drop {} \
                 to export without it",
                p.column,
                p.dtype,
                p.shape,
                p.per,
                p.column
            );
        }
        kept.push(p.clone());
    }
    let keep_last = footer.last_action && !drop.iter().any(|d| d == LAST_ACTION);
    if keep_last && !last_action {
        bail!(
            "{at}: a {format} file cannot hold each episode's last action (the table keeps the one its source had on \
             step T − 1); pass --drop {LAST_ACTION} to export without them"
        );
    }
    Ok((kept, keep_last))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numpy_dtypes_read_and_print_as_numpy_does() {
        for d in ["<f8", ">f4", "|b1", "|u1", "|i1", "<i8", ">u2", "<u4"] {
            assert_eq!(Elem::parse(d).unwrap().descr(), d);
        }
        assert_eq!(Elem::parse("f4").unwrap().descr(), "<f4");
        assert_eq!(Elem::parse("=i4").unwrap().descr(), "<i4");
        assert_eq!(Elem::parse(">b1").unwrap().descr(), "|b1");
        for d in ["<f2", "<c16", "|O", "<U5", "|S3", "<M8[ns]", ""] {
            assert!(Elem::parse(d).is_none(), "{d}");
        }
    }

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
            let spec = Passthrough::new("f.pkl", "x", descr, per, shape).unwrap();
            let elem = spec.elem();
            let episodes = 3;
            let n = episodes * spec.episode_bytes(t);
            // Source bytes in the source's order: bools 0/1, others any pattern.
            let source: Vec<u8> =
                (0..n).map(|i| if elem.kind == 'b' { (i % 3 == 1) as u8 } else { (i * 37 + 11) as u8 }).collect();
            let le = to_little_endian(source.clone().into(), elem);
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

    #[test]
    fn what_cannot_be_kept_is_named_with_its_way_out() {
        let e = Passthrough::new("f.pkl", "names", "<U8", Per::Step, vec![]).unwrap_err().to_string();
        assert!(e.contains("key 'names' holds <U8") && e.contains("--drop names"), "{e}");
        let e = Passthrough::new("f.pkl", "obs", "<f4", Per::Step, vec![2]).unwrap_err().to_string();
        assert!(e.contains("one of the table's own columns") && e.contains("--drop obs"), "{e}");
        let e = Passthrough::new("f.pkl", "z", "<f4", Per::Step, vec![0]).unwrap_err().to_string();
        assert!(e.contains("shape [0]"), "{e}");
    }

    #[test]
    fn sources_must_agree_on_their_passthrough_arrays() {
        let p = |at: &str, key: &str, d: &str| Passthrough::new(at, key, d, Per::Transition, vec![1]).unwrap();
        let m = merge(&[("a".into(), vec![p("a", "s", "<f8")]), ("b".into(), vec![p("b", "s", "<f8")])]).unwrap();
        assert_eq!(m[0].files, ["a", "b"]);
        let e = merge(&[("a".into(), vec![p("a", "s", "<f8")]), ("b".into(), vec![p("b", "s", "<f4")])]).unwrap_err();
        assert!(e.to_string().contains("b: key 's' is <f4") && e.to_string().contains("--drop s"), "{e}");
        let e = merge(&[("a".into(), vec![p("a", "s", "<f8")]), ("b".into(), vec![])]).unwrap_err();
        assert!(e.to_string().contains("b: has no key 's'"), "{e}");
        let e = merge(&[("a".into(), vec![]), ("b".into(), vec![p("b", "s", "<f8")])]).unwrap_err();
        assert!(e.to_string().contains("b: key 's' is not in a"), "{e}");
    }
}
