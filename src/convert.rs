//! `pgser-etl convert`: any dataset a trajectory table can be made from → that table.
//!
//! Three readers make trajectory tables from other people's files: WGCSL pickles
//! ([`crate::trajectory::convert`], beside the table writer it feeds), Minari datasets
//! ([`crate::minari`], which builds on that writer) and OGBench's `.npz` files ([`crate::ogbench`]). This module only chooses between them by
//! the kind of input, and every caller (the CLI, a pipeline's `convert` step and its dry-run
//! check) comes through it.
//!
//! Why the choice lives here and not in either reader: `minari` builds on `trajectory`, so a
//! dispatch inside `trajectory` had to call up into the reader above it, and a newcomer reading the
//! pickle reader found the Minari one behind it. Above both, each reader knows only its own format,
//! and a third format is one more arm here.

use std::path::Path;

use anyhow::{Result, bail};
use indicatif::ProgressBar;

pub use crate::trajectory::{ConvertOptions, ConvertPlan, ConvertSummary};
use crate::{minari, ogbench, trajectory};

/// What `convert` would write, read and validated as `convert` does, without writing anything.
pub fn check(opts: &ConvertOptions) -> Result<ConvertPlan> {
    match input(opts)? {
        Input::Minari(_) | Input::Pickles if opts.full_goal => {
            bail!("--full-goal: OGBench files only (a pickle or Minari dataset holds its own goals)")
        }
        Input::Minari(dir) => minari::check(opts, dir),
        Input::Ogbench(file) => ogbench::check(opts, file),
        Input::Pickles => trajectory::check_convert(opts),
    }
}

/// Convert `opts.inputs` into the trajectory table `opts.output`.
pub fn convert(opts: &ConvertOptions, bar: &ProgressBar) -> Result<ConvertSummary> {
    match input(opts)? {
        Input::Minari(_) | Input::Pickles if opts.full_goal => {
            bail!("--full-goal: OGBench files only (a pickle or Minari dataset holds its own goals)")
        }
        Input::Minari(dir) => minari::convert(opts, dir, bar),
        Input::Ogbench(file) => ogbench::convert(opts, file, bar),
        Input::Pickles => trajectory::convert(opts, bar),
    }
}

/// `pgser-etl export`: a trajectory table out as another tool's dataset: a Minari folder or a
/// WGCSL pickle ([`minari::export`]), or an OGBench file ([`ogbench::export_npz`], which streams
/// the table). Chosen here, above both writers, as `convert` chooses between the readers.
pub fn export(opts: &minari::ExportOptions) -> Result<minari::ExportSummary> {
    match opts.format {
        minari::ExportFormat::Ogbench => {
            let f = ogbench::export_npz(&opts.table, &opts.output, &opts.drop)?;
            Ok(minari::ExportSummary { task: f.task, episodes: f.episodes, t: f.t })
        }
        _ => minari::export(opts),
    }
}

/// The kinds of input `convert` reads.
enum Input<'a> {
    /// One or more WGCSL pickle files.
    Pickles,
    /// A Minari dataset folder (`data/` with `main_data.hdf5` or Arrow storage, `metadata.json`).
    Minari(&'a Path),
    /// An OGBench dataset file (`pointmaze-medium-navigate-v0.npz`).
    Ogbench(&'a Path),
}

/// A folder is a Minari dataset and a `.npz` file an OGBench dataset, each converted on its own;
/// other files are pickles.
fn input(opts: &ConvertOptions) -> Result<Input<'_>> {
    let npz = |p: &Path| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz"));
    if let Some(i) = opts.inputs.iter().position(|p| npz(p)) {
        if opts.inputs.len() > 1 {
            bail!(
                "{}: an OGBench dataset among {} inputs: convert takes pickles, or one dataset (an OGBench .npz file, \
                 a Minari folder)",
                opts.inputs[i].display(),
                opts.inputs.len()
            );
        }
        return Ok(Input::Ogbench(&opts.inputs[0]));
    }
    match opts.inputs.iter().position(|p| p.is_dir()) {
        None => Ok(Input::Pickles),
        Some(_) if opts.inputs.len() == 1 => Ok(Input::Minari(&opts.inputs[0])),
        Some(i) => bail!(
            "{}: a folder (a Minari dataset) among {} inputs: convert takes pickles, or one Minari dataset folder",
            opts.inputs[i].display(),
            opts.inputs.len()
        ),
    }
}
