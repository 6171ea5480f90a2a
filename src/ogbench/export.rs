//! `pgser-etl export TABLE --format ogbench -o NAME.npz`: a trajectory table as an OGBench
//! dataset file, which `ogbench.make_env_and_datasets(NAME, dataset_path="NAME.npz")` loads.
//!
//! The file is what OGBench's data generator writes (`np.savez_compressed`): `observations` and
//! `actions`, one row per observation, `terminals` (bool, true on each episode's last row), and
//! whatever else the table's source had (`qpos`, `qvel`, `oracle_reps`, …), kept as passthrough
//! columns and written back in their dtype. An episode's last action is the one the source had
//! where the table kept it (a table converted from an OGBench file), else zeros, which OGBench's
//! loader drops. A table converted from a file of OGBench's regular layout (`load_dataset()`'s
//! arrays saved: a row per transition, `next_observations`) is written back in that layout, its
//! `next_observations` the observations shifted by a row unless the table kept the source's own
//! (a passthrough column of that name). Observations and actions are float32, OGBench's type,
//! unless the table came from an OGBench file: then each is written in the source's own float
//! type (the footer's `float_bytes`, else the table's). The table is read once per array, a batch at a time, so memory does not grow
//! with it, and the file appears whole or not at all.

use std::path::Path;

use anyhow::{Context, Result, bail};
use arrow_array::Array;
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type};
use arrow_schema::DataType;

use super::npz::NpzWriter;
use crate::dtype::Dtype;
use crate::output::AtomicFile;
use crate::trajectory::extra::{append_source_bytes, kept_for};
use crate::trajectory::read::{check_all_read, check_keys, open_checked, open_images};
use crate::trajectory::{FloatType, Footer, Per};

/// Writes `table` as the OGBench dataset file `out`, less the passthrough columns `drop` names
/// (and each episode's last action, with `last_action`); returns the table's footer.
pub fn export_npz(table: &Path, out: &Path, drop: &[String]) -> Result<Footer> {
    if out.extension().and_then(|e| e.to_str()) != Some("npz") {
        bail!(
            "{}: an OGBench dataset is a .npz file named after the dataset (pointmaze-medium-navigate-v0.npz)",
            out.display()
        );
    }
    crate::output::check_not_an_input(out, std::slice::from_ref(&table.to_path_buf()))?;
    let (footer, _) = open_images(table, &["obs"], 64)?;
    let source = footer.sources.first().map(|s| s.format.as_str()).filter(|f| f.starts_with("ogbench-npz"));
    let regular = source == Some("ogbench-npz-regular");
    // A row per observation holds what is per step; a row per transition what is per transition.
    let per = if regular { Per::Transition } else { Per::Step };
    let layout = if regular { "regular-layout OGBench file" } else { "OGBench file" };
    let (extras, last_action) = kept_for(&footer, table, layout, drop, |p| p.per == per, !regular)?;
    let (n, t) = (footer.episodes, footer.t);
    let rows = if regular { n * (t - 1) } else { n * t };
    // Each array in its source's float type: observations (and with them the goals) and actions
    // may differ (float32 observations beside float64 actions); the table holds the wider.
    let table_size = if footer.float_type == FloatType::Float64 { 8 } else { 4 };
    let [obs_size, act_size] = match (source, footer.sources.first()) {
        (Some(_), Some(s)) if s.float_bytes.len() == 4 => [s.float_bytes[0], s.float_bytes[3]],
        (Some(_), _) => [table_size; 2],
        _ => [4; 2],
    };
    let float = |size: usize| if size == 8 { Dtype::F64 } else { Dtype::F32 };
    let file = AtomicFile::create(out)?;
    let mut w = NpzWriter::new(std::io::BufWriter::new(file.handle()?), true);
    let fail = |key: &str| format!("{}: {key}", out.display());
    // Which steps of an episode each array has a row for.
    let all = |_: usize| true;
    let but_last = |s: usize| s < t - 1;
    let but_first = |s: usize| s > 0;
    // Observations: float rows, or uint8 images of the footer's shape, as the file had them.
    let obs_shape: Vec<usize> = if footer.is_image() { footer.image_shape.clone() } else { vec![footer.obs_dim] };
    let obs_dtype = if footer.is_image() { Dtype::U8 } else { float(obs_size) };
    let obs_stream = |steps: &dyn Fn(usize) -> bool, w: &mut NpzWriter<_>| -> Result<()> {
        if footer.is_image() {
            stream_images(table, steps, |v| w.write(v))
        } else {
            stream_floats(table, "obs", obs_size, steps, |_, v| w.write(v))
        }
    };
    w.start("observations", obs_dtype, &[&[rows][..], &obs_shape].concat())?;
    let obs_steps: &dyn Fn(usize) -> bool = if regular { &but_last } else { &all };
    obs_stream(obs_steps, &mut w).with_context(|| fail("observations"))?;
    w.start("actions", float(act_size), &[rows, footer.act_dim])?;
    let zeros = vec![0u8; footer.act_dim * act_size];
    let act_steps: &dyn Fn(usize) -> bool = if last_action { &all } else { &but_last };
    stream_floats(table, "action", act_size, act_steps, |step, v| {
        w.write(v)?;
        // Without the source's last actions, OGBench's last row of an episode gets zeros.
        if !regular && !last_action && step == t - 2 {
            w.write(&zeros)?;
        }
        Ok(())
    })
    .with_context(|| fail("actions"))?;
    if !regular && !extras.iter().any(|p| p.column == "terminals") {
        w.start("terminals", Dtype::BOOL, &[rows])?;
        let terminals: Vec<u8> = (0..rows).map(|r| u8::from(r % t == t - 1)).collect();
        w.write(&terminals)?;
    }
    for p in &extras {
        let mut shape = vec![rows];
        shape.extend(&p.shape);
        w.start(&p.column, p.dtype, &shape)?;
        stream_passthrough(table, p, |bytes| w.write(bytes)).with_context(|| fail(&p.column))?;
    }
    // The source's own next observations, where the table kept them, were written above.
    if regular && !extras.iter().any(|p| p.column == "next_observations") {
        w.start("next_observations", obs_dtype, &[&[rows][..], &obs_shape].concat())?;
        obs_stream(&but_first, &mut w).with_context(|| fail("next_observations"))?;
    }
    use std::io::Write;
    w.finish()?.flush().with_context(|| format!("{}: write failed", out.display()))?;
    file.commit()?;
    Ok(footer)
}

/// Calls `each(step, bytes)` with the rows of vector `column` on the steps `steps` keeps, as
/// little-endian floats of `size` bytes, in table order.
fn stream_floats(
    table: &Path,
    column: &str,
    size: usize,
    steps: &dyn Fn(usize) -> bool,
    mut each: impl FnMut(usize, &[u8]) -> Result<()>,
) -> Result<()> {
    let at = table.display().to_string();
    let (footer, reader) = open_checked(table, &[column], 64)?;
    let t = footer.t;
    let mut row = 0;
    let mut bytes = Vec::new();
    for batch in reader {
        let batch = batch.with_context(|| format!("{at}: cannot read the rows after row {row}"))?;
        check_keys(&at, &batch, row, &footer)?;
        let list = batch.column_by_name(column).expect("projected").as_fixed_size_list();
        let dim = list.value_length() as usize;
        let (values, offset) = (list.values(), list.value_offset_at(0));
        for r in 0..batch.num_rows() {
            let step = (row + r) % t;
            if !steps(step) {
                continue;
            }
            if list.is_null(r) {
                bail!("{at}: row {} (episode {}, step {step}): `{column}` is null", row + r, (row + r) / t);
            }
            bytes.clear();
            let range = offset + r * dim..offset + (r + 1) * dim;
            match (values.data_type(), size) {
                (DataType::Float32, 4) => values.as_primitive::<Float32Type>().values()[range]
                    .iter()
                    .for_each(|v| bytes.extend(v.to_le_bytes())),
                (DataType::Float32, _) => values.as_primitive::<Float32Type>().values()[range]
                    .iter()
                    .for_each(|&v| bytes.extend((v as f64).to_le_bytes())),
                (_, 4) => values.as_primitive::<Float64Type>().values()[range]
                    .iter()
                    .for_each(|&v| bytes.extend((v as f32).to_le_bytes())),
                _ => values.as_primitive::<Float64Type>().values()[range]
                    .iter()
                    .for_each(|v| bytes.extend(v.to_le_bytes())),
            }
            each(step, &bytes)?;
        }
        row += batch.num_rows();
    }
    check_all_read(&at, row, &footer)
}

/// Calls `each` with the bytes of each image observation on the steps `steps` keeps, in table
/// order.
fn stream_images(table: &Path, steps: &dyn Fn(usize) -> bool, mut each: impl FnMut(&[u8]) -> Result<()>) -> Result<()> {
    let at = table.display().to_string();
    let (footer, reader) = open_images(table, &["obs"], 4)?;
    let t = footer.t;
    let mut row = 0;
    for batch in reader {
        let batch = batch.with_context(|| format!("{at}: cannot read the rows after row {row}"))?;
        check_keys(&at, &batch, row, &footer)?;
        let images = batch.column_by_name("obs").expect("projected").as_fixed_size_binary();
        for r in 0..batch.num_rows() {
            if steps((row + r) % t) {
                each(images.value(r))?;
            }
        }
        row += batch.num_rows();
    }
    check_all_read(&at, row, &footer)
}

/// Calls `each` with the source's bytes of passthrough column `p`, a batch at a time.
fn stream_passthrough(
    table: &Path,
    p: &crate::trajectory::Passthrough,
    mut each: impl FnMut(&[u8]) -> Result<()>,
) -> Result<()> {
    let at = table.display().to_string();
    let (footer, reader) = open_checked(table, &[p.column.as_str()], 64)?;
    let mut row = 0;
    let mut bytes = Vec::new();
    for batch in reader {
        let batch = batch.with_context(|| format!("{at}: cannot read the rows after row {row}"))?;
        check_keys(&at, &batch, row, &footer)?;
        bytes.clear();
        append_source_bytes(&mut bytes, p, batch.column_by_name(&p.column).expect("projected"), row, footer.t, &at)?;
        each(&bytes)?;
        row += batch.num_rows();
    }
    check_all_read(&at, row, &footer)
}
