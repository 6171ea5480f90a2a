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

mod shards;

/// What `convert` would write, read and validated as `convert` does, without writing anything.
pub fn check(opts: &ConvertOptions) -> Result<ConvertPlan> {
    match input(opts)? {
        Input::Minari(_) | Input::Pickles if opts.full_goal => {
            bail!("--full-goal: OGBench files only (a pickle or Minari dataset holds its own goals)")
        }
        Input::Minari(dir) => minari::check(opts, dir),
        Input::Ogbench(file) => ogbench::check(opts, file),
        Input::Shards(files) => shards::check(opts, &files),
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
        Input::Shards(files) => shards::convert(opts, &files, bar),
        Input::Pickles => trajectory::convert(opts, bar),
    }
}

/// `pgser-etl export`: a trajectory table out as another tool's dataset: a Minari folder or a
/// WGCSL pickle ([`minari::export`]), or an OGBench file ([`ogbench::export_npz`], which streams
/// the table). Chosen here, above both writers, as `convert` chooses between the readers.
pub fn export(opts: &minari::ExportOptions) -> Result<minari::ExportSummary> {
    if crate::trajectory::folder::is_folder(&opts.table) {
        return shards::export(opts);
    }
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
    /// OGBench shards (a folder of `.npz` files, or several of them): a table folder.
    Shards(Vec<std::path::PathBuf>),
}

/// A folder is a Minari dataset, or OGBench shards when `.npz` files lie in it; one `.npz` file
/// is an OGBench dataset and several are shards; other files are pickles.
fn input(opts: &ConvertOptions) -> Result<Input<'_>> {
    let npz = |p: &Path| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz"));
    if let Some(i) = opts.inputs.iter().position(|p| npz(p)) {
        if let Some(other) = opts.inputs.iter().find(|p| !npz(p)) {
            bail!(
                "{}: not an .npz file among the OGBench shards ({}): convert takes pickles, or one dataset (an OGBench \
                 .npz file or folder of shards, a Minari folder)",
                other.display(),
                opts.inputs[i].display()
            );
        }
        if opts.inputs.len() > 1 {
            return Ok(Input::Shards(opts.inputs.clone()));
        }
        return Ok(Input::Ogbench(&opts.inputs[0]));
    }
    if let [dir] = opts.inputs.as_slice()
        && let Some(files) = shards::in_folder(dir)?
    {
        return Ok(Input::Shards(files));
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
