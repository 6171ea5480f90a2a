//! `pgser-etl export TABLE --format ogbench -o NAME.npz`: a trajectory table as an OGBench
//! dataset file, which `ogbench.make_env_and_datasets(NAME, dataset_path="NAME.npz")` loads.
//!
//! The file is what OGBench's data generator writes (`np.savez_compressed`): `observations`
//! (float32), `actions` (float32) and `terminals` (bool, true on each episode's last row), one
//! row per observation. A pgser episode has one action fewer than observations; OGBench's last
//! row of an episode has an action that its loader drops, which is written as zeros. `qpos`,
//! `qvel` are not in a pgser table and are not written, so `add_info=True` and the singletask
//! relabelling, which read them, do not apply. The table is read twice, a batch at a time (once
//! for the observations, once for the actions), so memory does not grow with it, and the file
//! appears whole or not at all.

use std::path::Path;

use anyhow::{Context, Result, bail};
use arrow_array::Array;
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type};
use arrow_schema::DataType;

use super::npz::{Dtype, NpzWriter};
use crate::output::AtomicFile;
use crate::trajectory::Footer;
use crate::trajectory::read::{check_all_read, check_keys, open_checked};

/// Writes `table` as the OGBench dataset file `out`; returns the table's footer.
pub fn export_npz(table: &Path, out: &Path) -> Result<Footer> {
    if out.extension().and_then(|e| e.to_str()) != Some("npz") {
        bail!(
            "{}: an OGBench dataset is a .npz file named after the dataset (pointmaze-medium-navigate-v0.npz)",
            out.display()
        );
    }
    let (footer, _) = open_checked(table, &["obs"], 64)?;
    let (n, t) = (footer.rows, footer.t);
    let file = AtomicFile::create(out)?;
    let mut w = NpzWriter::new(std::io::BufWriter::new(file.handle()?), true);
    for (key, column, dim) in [("observations", "obs", footer.obs_dim), ("actions", "action", footer.act_dim)] {
        w.start(key, Dtype::F32, &[n, dim])?;
        let zeros = vec![0u8; dim * 4];
        stream_f32(table, column, |row, values| {
            w.write(values)?;
            // A pgser episode's actions stop one row short: OGBench's last row's action is zeros.
            if column == "action" && row % t == t - 2 {
                w.write(&zeros)?;
            }
            Ok(())
        })
        .with_context(|| format!("{}: {key}", out.display()))?;
    }
    w.start("terminals", Dtype::Bool, &[n])?;
    let terminals: Vec<u8> = (0..n).map(|r| u8::from(r % t == t - 1)).collect();
    w.write(&terminals)?;
    use std::io::Write;
    w.finish()?.flush().with_context(|| format!("{}: write failed", out.display()))?;
    file.commit()?;
    Ok(footer)
}

/// Calls `each(row, bytes)` with every row of `column` (a vector column; desired goals and
/// actions have T − 1 rows per episode, so their episodes' last rows are skipped) as
/// little-endian float32 bytes, in table order.
fn stream_f32(table: &Path, column: &str, mut each: impl FnMut(usize, &[u8]) -> Result<()>) -> Result<()> {
    let at = table.display().to_string();
    let (footer, reader) = open_checked(table, &[column], 64)?;
    let t = footer.t;
    let short = column == "action" || column == "desired_goal";
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
            if short && step == t - 1 {
                continue;
            }
            bytes.clear();
            let range = offset + r * dim..offset + (r + 1) * dim;
            match values.data_type() {
                DataType::Float32 => {
                    for v in &values.as_primitive::<Float32Type>().values()[range] {
                        bytes.extend_from_slice(&v.to_le_bytes());
                    }
                }
                _ => {
                    for v in &values.as_primitive::<Float64Type>().values()[range] {
                        bytes.extend_from_slice(&(*v as f32).to_le_bytes());
                    }
                }
            }
            each(row + r, &bytes)?;
        }
        row += batch.num_rows();
    }
    check_all_read(&at, row, &footer)
}
