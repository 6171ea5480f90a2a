//! The out-of-core pool: β streamed from a table's row groups within a memory budget.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Result, bail};

use super::view::{InMemory, View};
use crate::trajectory::Episodes;

/// Opens `path` within `budget` bytes: the whole table when it fits.
pub fn open(path: &Path, budget: u64, _seed: u64) -> Result<Box<dyn View>> {
    let data = Episodes::load(path)?;
    let bytes = 4 * (data.obs.len() + data.ag.len() + data.g.len() + data.u.len()) as u64;
    if bytes > budget {
        bail!("{}: {bytes} bytes do not fit a memory budget of {budget}", path.display());
    }
    Ok(Box::new(InMemory(Arc::new(data))))
}
