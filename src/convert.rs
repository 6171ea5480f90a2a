//! `pgser-etl convert`: any dataset a trajectory table can be made from → that table.
//!
//! Two readers make trajectory tables from other people's files: WGCSL pickles
//! ([`crate::trajectory::convert`], beside the table writer it feeds) and Minari datasets
//! ([`crate::minari`], which builds on that writer). This module only chooses between them by
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
use crate::{minari, trajectory};

/// What `convert` would write, read and validated as `convert` does, without writing anything.
pub fn check(opts: &ConvertOptions) -> Result<ConvertPlan> {
    match input(opts)? {
        Input::Minari(dir) => minari::check(opts, dir),
        Input::Pickles => trajectory::check_convert(opts),
    }
}

/// Convert `opts.inputs` into the trajectory table `opts.output`.
pub fn convert(opts: &ConvertOptions, bar: &ProgressBar) -> Result<ConvertSummary> {
    match input(opts)? {
        Input::Minari(dir) => minari::convert(opts, dir, bar),
        Input::Pickles => trajectory::convert(opts, bar),
    }
}

/// The kinds of input `convert` reads.
enum Input<'a> {
    /// One or more WGCSL pickle files.
    Pickles,
    /// A Minari dataset folder (`data/` with `main_data.hdf5` or Arrow storage, `metadata.json`).
    Minari(&'a Path),
}

/// A folder is a Minari dataset, converted on its own; files are pickles.
fn input(opts: &ConvertOptions) -> Result<Input<'_>> {
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
