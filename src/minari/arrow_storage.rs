//! Minari's Arrow storage: `data/{i}/` holds episode i as Arrow IPC files (pyarrow's dataset
//! writer names them `part-0.arrow`) next to a `metadata.json`.
//!
//! Every column has n + 1 rows for an episode of n steps: `observations` (a struct of the Dict's
//! keys, each a fixed-size list), and `actions`, `rewards`, `terminations`, `truncations`, whose
//! last row is padding (Minari drops it when it reads). pgser reads observations and actions;
//! rewards are recomputed from the goals, like every pgser table's. The writer makes exactly
//! this layout, one record batch per file, which is what Minari's reader expects.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type};
use arrow_array::{
    Array, ArrayRef, BooleanArray, FixedSizeListArray, Float32Array, Float64Array, RecordBatch, StructArray,
};
use arrow_schema::{DataType, Field, Fields, Schema};

use super::infos::{self, Info};
use super::{BoxSpace, Episode, Metadata, OBS_KEYS, Spaces};
use crate::dtype::Dtype;

pub struct Reader {
    data: PathBuf,
    spaces: Spaces,
    total: usize,
    /// The Dict observation's other keys.
    extra_obs: Vec<String>,
    /// The columns `--drop` names, never read ([`infos::from_arrow`]).
    drop: Vec<String>,
}

impl Reader {
    pub fn new(meta: &Metadata, drop: &[String]) -> Reader {
        let extra_obs = meta.extra_obs.iter().map(|(k, _)| k.clone()).collect();
        Reader {
            data: meta.data.clone(),
            spaces: meta.spaces.clone(),
            total: meta.total_episodes,
            extra_obs,
            drop: drop.to_vec(),
        }
    }

    /// Episode i's observations (n + 1 rows) and actions (n rows).
    pub fn episode(&mut self, i: usize) -> Result<Episode> {
        let dir = self.data.join(i.to_string());
        if !dir.is_dir() {
            bail!(
                "{}: episode {i} is missing: no folder {i}/ (metadata.json says total_episodes {})",
                self.data.display(),
                self.total
            );
        }
        let files = episode_files(&dir)?;
        if files.is_empty() {
            bail!("{}: episode {i} has no Arrow file", dir.display());
        }
        let mut arrays: [Vec<u8>; 4] = Default::default();
        let mut infos: Vec<Info> = Vec::new();
        let mut outcomes: Vec<Info> = Vec::new();
        let mut obs_extras: Vec<Info> = Vec::new();
        let mut present: Vec<String> = Vec::new();
        let mut rows = 0;
        for path in &files {
            let at = format!("{} (episode {i})", path.display());
            let bytes = crate::output::read_input(path)?;
            check_ipc_bounds(&at, &bytes)?;
            let reader = arrow_ipc::reader::FileReader::try_new(std::io::Cursor::new(bytes), None)
                .map_err(|e| anyhow::anyhow!("{at}: not an Arrow IPC file ({e})"))?;
            for batch in reader {
                let batch = batch.map_err(|e| anyhow::anyhow!("{at}: cannot read a record batch ({e})"))?;
                let obs = batch
                    .column_by_name("observations")
                    .and_then(|c| c.as_struct_opt())
                    .with_context(|| format!("{at}: no `observations` struct column"))?;
                for (k, key) in OBS_KEYS.iter().enumerate() {
                    let col = obs.column_by_name(key).with_context(|| format!("{at}: no `observations.{key}`"))?;
                    append(&at, &format!("observations.{key}"), col, &self.spaces.obs[k], rows, &mut arrays[k])?;
                }
                if !self.extra_obs.is_empty() {
                    let mut fields = Vec::new();
                    let mut columns = Vec::new();
                    for k in &self.extra_obs {
                        let (i, f) = obs.fields().find(k).with_context(|| format!("{at}: no `observations.{k}`"))?;
                        fields.push(f.clone());
                        columns.push(obs.column(i).clone());
                    }
                    let s = StructArray::try_new(Fields::from(fields), columns, None)?;
                    note(&mut present, &s, Some("observations"));
                    infos::extend(&at, &mut obs_extras, infos::from_arrow(&at, &s, Some("observations"), &self.drop)?)?;
                }
                let actions = batch.column_by_name("actions").with_context(|| format!("{at}: no `actions` column"))?;
                append(&at, "actions", actions, &self.spaces.action, rows, &mut arrays[3])?;
                if let Some(col) = batch.column_by_name("infos").and_then(|c| c.as_struct_opt()) {
                    note(&mut present, col, Some("infos"));
                    infos::extend(&at, &mut infos, infos::from_arrow(&at, col, Some("infos"), &self.drop)?)?;
                }
                // Rewards, terminations, truncations: scalar columns, read as infos are.
                let recorded: Vec<(Arc<Field>, ArrayRef)> = super::OUTCOMES
                    .iter()
                    .filter_map(|k| {
                        let c = batch.column_by_name(k)?;
                        Some((Arc::new(Field::new(*k, c.data_type().clone(), true)), c.clone()))
                    })
                    .collect();
                if !recorded.is_empty() {
                    let (fields, columns): (Vec<_>, Vec<_>) = recorded.into_iter().unzip();
                    let s = StructArray::try_new(Fields::from(fields), columns, None)?;
                    note(&mut present, &s, None);
                    infos::extend(&at, &mut outcomes, infos::from_arrow(&at, &s, None, &self.drop)?)?;
                }
                rows += batch.num_rows();
            }
        }
        if rows == 0 {
            bail!("{}: episode {i} has no rows", dir.display());
        }
        // The actions' last row is the storage's padding.
        let act_row = self.spaces.action.dim * self.spaces.action.size;
        arrays[3].truncate((rows - 1) * act_row);
        // Their last row, like the actions', is the storage's padding.
        for o in &mut outcomes {
            let row = o.bytes.len() / o.rows.max(1);
            o.rows -= 1;
            o.bytes.truncate(o.rows * row);
        }
        Ok(Episode { steps: rows - 1, arrays, infos, outcomes, obs_extras, present })
    }
}

/// Adds the columns struct `s`'s fields become (of `group`) to `present`, once each.
fn note(present: &mut Vec<String>, s: &StructArray, group: Option<&str>) {
    for f in s.fields() {
        let column = infos::column_name(group, f.name());
        if !present.contains(&column) {
            present.push(column);
        }
    }
}

/// Checks what arrow-ipc's reader takes on trust: every record batch (and dictionary) block of the
/// footer lies inside the file, and every buffer its message names lies inside the block's body.
/// arrow-ipc 60 slices a buffer with an assert, so a corrupt offset panicked instead of failing
/// (found by fuzzing, `fuzz/minari`; the input is in tests/fixtures/fuzz/minari/). What does not
/// parse as an IPC file is left to the reader, which names the fault itself.
fn check_ipc_bounds(at: &str, bytes: &[u8]) -> Result<()> {
    let n = bytes.len();
    // The file ends with the footer, its i32 length and the 6-byte magic.
    let Some(len) = n.checked_sub(10).map(|i| i32::from_le_bytes(bytes[i..i + 4].try_into().unwrap())) else {
        return Ok(());
    };
    let Some(start) = usize::try_from(len).ok().and_then(|l| (n - 10).checked_sub(l)) else { return Ok(()) };
    let Ok(footer) = arrow_ipc::root_as_footer(&bytes[start..n - 10]) else { return Ok(()) };
    let schema = footer.schema().and_then(|s| arrow_ipc::convert::try_fb_to_schema(s).ok());
    let blocks = footer.dictionaries().into_iter().flatten().chain(footer.recordBatches().into_iter().flatten());
    for (b, block) in blocks.enumerate() {
        let fault = |what: String| anyhow::anyhow!("{at}: IPC block {b}: {what}: the file is corrupt");
        let (offset, meta, body) = (block.offset(), i64::from(block.metaDataLength()), block.bodyLength());
        let end = [offset, meta, body].iter().all(|&x| x >= 0).then(|| offset.checked_add(meta)?.checked_add(body));
        if end.flatten().is_none_or(|e| e > n as i64) || meta < 8 {
            bail!(fault(format!("offset {offset}, metadata {meta} and body {body} bytes do not fit a {n}-byte file")));
        }
        // The message: a continuation marker (0xFFFFFFFF) and its i32 length before it, or the
        // length alone in files of before Arrow 0.15. Parsed over the whole block, body included,
        // as arrow-ipc parses it: a narrower slice would refuse a message arrow-ipc accepts (its
        // flatbuffer may point into the body), and let its buffers through unchecked.
        let m = &bytes[offset as usize..(offset + meta + body) as usize];
        let m = if m[..4] == [0xff; 4] { &m[8..] } else { &m[4..] };
        let Ok(message) = arrow_ipc::root_as_message(m) else { continue };
        let batch = message.header_as_record_batch().or_else(|| message.header_as_dictionary_batch()?.data());
        for (k, buf) in batch.and_then(|r| r.buffers()).into_iter().flatten().enumerate() {
            let (o, l) = (buf.offset(), buf.length());
            if o < 0 || l < 0 || o.checked_add(l).is_none_or(|e| e > body) {
                bail!(fault(format!("buffer {k} at {o} of {l} bytes lies outside the {body}-byte body")));
            }
        }
        // A record batch's nodes follow the schema's fields depth first (a dictionary batch's
        // follow its value type, not checked: Minari writes none).
        if let (Some(nodes), Some(schema)) = (message.header_as_record_batch().and_then(|r| r.nodes()), &schema) {
            check_nodes(schema.fields(), &mut nodes.iter()).map_err(fault)?;
        }
    }
    Ok(())
}

/// Checks the field nodes arrow-ipc casts to `usize` and multiplies unchecked: a negative length
/// or null count, and a fixed-size list whose length times its size overflows (arrow-data 60
/// panics on that product; found by fuzzing, `fuzz/minari`). Stops at a nesting it does not
/// walk, since the nodes after it can no longer be matched to fields.
fn check_nodes<'a>(
    fields: &Fields,
    nodes: &mut impl Iterator<Item = &'a arrow_ipc::FieldNode>,
) -> Result<bool, String> {
    for field in fields {
        let Some(node) = nodes.next() else { return Ok(false) };
        let (len, nulls, name) = (node.length(), node.null_count(), field.name());
        if len < 0 || nulls < 0 || nulls > len {
            return Err(format!("field `{name}` has length {len} with {nulls} nulls"));
        }
        let walked = match field.data_type() {
            DataType::FixedSizeList(child, size) => {
                if len.checked_mul(i64::from(*size)).is_none() {
                    return Err(format!("field `{name}`: {len} lists of {size} values overflow"));
                }
                check_nodes(&Fields::from(vec![child.clone()]), nodes)?
            }
            DataType::List(child) | DataType::LargeList(child) | DataType::Map(child, _) => {
                check_nodes(&Fields::from(vec![child.clone()]), nodes)?
            }
            DataType::Struct(children) => check_nodes(children, nodes)?,
            t if t.is_nested() || matches!(t, DataType::RunEndEncoded(..)) => false,
            _ => true,
        };
        if !walked {
            return Ok(false);
        }
    }
    Ok(true)
}

/// The files of an episode folder that pyarrow's dataset reader reads: not `metadata.json`,
/// nor hidden or `_`-prefixed ones (its `ignore_prefixes`), in name order.
fn episode_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("{}: cannot list", dir.display()))? {
        let path = entry.with_context(|| format!("{}: cannot list", dir.display()))?.path();
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if path.is_file() && name != "metadata.json" && !name.starts_with(['.', '_']) {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// Append one column's rows to `out` as little-endian bytes, checking it against its space:
/// fixed-size lists of `space.dim` floats of the space's type, no nulls.
fn append(at: &str, key: &str, col: &ArrayRef, space: &BoxSpace, first_row: usize, out: &mut Vec<u8>) -> Result<()> {
    let Some(list) = col.as_fixed_size_list_opt() else {
        bail!("{at}: `{key}` is {}, not a fixed-size list", col.data_type());
    };
    let want = if space.size == 4 { DataType::Float32 } else { DataType::Float64 };
    if list.value_length() as usize != space.dim || list.value_type() != want {
        bail!(
            "{at}: `{key}` holds lists of {} {} but the space says {} {}",
            list.value_length(),
            list.value_type(),
            space.dim,
            space.dtype()
        );
    }
    if let Some(r) = (0..list.len()).find(|&r| list.is_null(r)) {
        bail!("{at}: `{key}` is null in row {}", first_row + r);
    }
    let values = list.values();
    let (start, len) = (list.value_offset_at(0), list.len() * space.dim);
    if let Some(j) = (start..start + len).find(|&j| values.is_null(j)) {
        bail!("{at}: `{key}` has a null value in row {}", first_row + (j - start) / space.dim);
    }
    match values.data_type() {
        DataType::Float32 => out.extend(
            values.as_primitive::<Float32Type>().values()[start..start + len].iter().flat_map(|v| v.to_le_bytes()),
        ),
        _ => out.extend(
            values.as_primitive::<Float64Type>().values()[start..start + len].iter().flat_map(|v| v.to_le_bytes()),
        ),
    }
    Ok(())
}

/// One exported episode of T observations, its values as float64 (exact for float32 tables),
/// cast to each space's float type when written.
pub struct EpisodeOut {
    /// observation, achieved_goal, desired_goal: T rows each, row-major.
    pub obs: [Vec<f64>; 3],
    /// T − 1 rows.
    pub actions: Vec<f64>,
    /// T − 1 rewards.
    pub rewards: Vec<f32>,
    /// The episode's infos, T rows each: (key, numpy dtype, shape of a row's value, bytes).
    pub infos: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
    /// Rewards, terminations or truncations as the source recorded them, T − 1 rows each (name,
    /// numpy dtype, bytes): written instead of the recomputed rewards and the time-limit ending.
    pub outcomes: Vec<(String, Dtype, Vec<u8>)>,
    /// The Dict observation's other keys, T rows each: (key, numpy dtype, a value's shape, bytes).
    pub obs_extras: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
}

/// The schema of an exported episode file, as Minari's Arrow storage writes it.
pub fn schema(spaces: &Spaces) -> Arc<Schema> {
    Arc::new(Schema::new(vec![
        Field::new("observations", DataType::Struct(obs_fields(spaces)), true),
        Field::new("actions", list_type(&spaces.action), true),
        Field::new("rewards", DataType::Float32, true),
        Field::new("terminations", DataType::Boolean, true),
        Field::new("truncations", DataType::Boolean, true),
    ]))
}

/// The Dict's keys in Gymnasium's order (sorted), each a list of its Box's floats.
fn obs_fields(spaces: &Spaces) -> Fields {
    let mut keys: Vec<(usize, &str)> = OBS_KEYS.iter().copied().enumerate().collect();
    keys.sort_by_key(|k| k.1);
    keys.iter().map(|&(k, name)| Field::new(name, list_type(&spaces.obs[k]), true)).collect()
}

fn list_type(space: &BoxSpace) -> DataType {
    let item = if space.size == 4 { DataType::Float32 } else { DataType::Float64 };
    DataType::FixedSizeList(Arc::new(Field::new("item", item, true)), space.dim as i32)
}

/// Write one episode as `dir/part-0.arrow`: one record batch of T rows, the step columns padded
/// with a last row of zeros (false), as Minari pads them; the episode ends truncated (time limit).
pub fn write_episode(dir: &Path, spaces: &Spaces, ep: EpisodeOut) -> Result<()> {
    let mut schema = schema(spaces);
    let t = ep.obs[0].len() / spaces.obs[0].dim;
    // Infos last, as Minari's writer puts them, when the episode has any.
    let infos = (!ep.infos.is_empty()).then(|| infos::to_arrow(&ep.infos, t)).transpose()?;
    if let Some((field, _)) = &infos {
        let mut fields: Vec<Field> = schema.fields().iter().map(|f| f.as_ref().clone()).collect();
        fields.push(field.clone());
        schema = Arc::new(Schema::new(fields));
    }
    let DataType::Struct(fields) = schema.field(0).data_type().clone() else { unreachable!("a struct") };
    let by_name = |name: &str| OBS_KEYS.iter().position(|k| *k == name).expect("an observation key");
    let mut obs: Vec<(Field, ArrayRef)> = fields
        .iter()
        .map(|f| {
            let k = by_name(f.name());
            (f.as_ref().clone(), list(&spaces.obs[k], &ep.obs[k]))
        })
        .collect();
    // The Dict's other keys, each a list of its values flattened, as Minari encodes a Box; the
    // Dict's keys in Gymnasium's (sorted) order.
    for (key, descr, shape, bytes) in &ep.obs_extras {
        let width = shape.iter().product::<usize>().max(1);
        let (_, array) = infos::to_arrow(&[(key.clone(), *descr, vec![width], bytes.clone())], t)?;
        let column = array.as_struct().column(0).clone();
        obs.push((Field::new(key, column.data_type().clone(), true), column));
    }
    obs.sort_by(|a, b| a.0.name().cmp(b.0.name()));
    let (obs_fields, columns): (Vec<Field>, Vec<ArrayRef>) = obs.into_iter().unzip();
    let observations = StructArray::try_new(Fields::from(obs_fields), columns, None)?;
    let mut top: Vec<Field> = schema.fields().iter().map(|f| f.as_ref().clone()).collect();
    top[0] = Field::new("observations", observations.data_type().clone(), true);
    schema = Arc::new(Schema::new(top));
    let mut actions = ep.actions;
    actions.extend(std::iter::repeat_n(0.0, spaces.action.dim));
    let mut rewards = ep.rewards;
    rewards.push(0.0);
    let truncations = BooleanArray::from_iter((0..t).map(|r| Some(r + 2 == t)));
    // A recorded outcome, padded with a last row of zeros as Minari pads it, in its own type.
    let recorded = |name: &str| -> Result<Option<ArrayRef>> {
        let Some((_, descr, bytes)) = ep.outcomes.iter().find(|o| o.0 == name) else { return Ok(None) };
        let mut padded = bytes.clone();
        padded.extend(std::iter::repeat_n(0u8, bytes.len() / (t - 1).max(1)));
        let (_, array) = infos::to_arrow(&[(name.to_string(), *descr, vec![], padded)], t)?;
        Ok(Some(array.as_struct().column(0).clone()))
    };
    let rewards: ArrayRef = recorded("rewards")?.unwrap_or_else(|| Arc::new(Float32Array::from(rewards)));
    let terminations: ArrayRef =
        recorded("terminations")?.unwrap_or_else(|| Arc::new(BooleanArray::from(vec![false; t])));
    let truncations: ArrayRef = recorded("truncations")?.unwrap_or_else(|| Arc::new(truncations));
    let mut fields: Vec<Field> = schema.fields().iter().map(|f| f.as_ref().clone()).collect();
    for (f, a) in fields.iter_mut().zip([None, None, Some(&rewards), Some(&terminations), Some(&truncations)]) {
        if let Some(a) = a {
            *f = Field::new(f.name(), a.data_type().clone(), true);
        }
    }
    let schema = Arc::new(Schema::new(fields));
    let batch = RecordBatch::try_new(
        schema.clone(),
        <Vec<ArrayRef>>::from([
            Arc::new(observations) as ArrayRef,
            list(&spaces.action, &actions),
            rewards,
            terminations,
            truncations,
        ])
        .into_iter()
        .chain(infos.map(|(_, array)| array))
        .collect(),
    )?;
    let path = dir.join("part-0.arrow");
    let fail = || format!("{}: write failed", path.display());
    let file = File::create(&path).with_context(|| format!("{}: cannot create", path.display()))?;
    let mut w = arrow_ipc::writer::FileWriter::try_new(std::io::BufWriter::new(file), &schema).with_context(fail)?;
    w.write(&batch).with_context(fail)?;
    w.finish().with_context(fail)?;
    Ok(())
}

/// Rows of a Box space's values as a fixed-size list column of its float type.
fn list(space: &BoxSpace, values: &[f64]) -> ArrayRef {
    let DataType::FixedSizeList(item, size) = list_type(space) else { unreachable!("a list type") };
    let values: ArrayRef = if space.size == 4 {
        Arc::new(Float32Array::from_iter_values(values.iter().map(|&v| v as f32)))
    } else {
        Arc::new(Float64Array::from(values.to_vec()))
    };
    Arc::new(FixedSizeListArray::new(item, size, values, None))
}
