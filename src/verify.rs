//! `pgser-etl verify FILE…`: is a pgser file intact? For files kept for months on shared
//! cluster file systems, where a flipped bit is otherwise read as another valid number.
//!
//! - A table (trajectory, transition, batches: any Parquet file): every column chunk against the
//!   CRC-32s in its footer ([`crate::table::Checksums`]), then every row group decoded. The first
//!   corrupt chunk is named by row group, column and bytes.
//! - A checkpoint or resume state (safetensors): its metadata and every tensor against the CRC-32s
//!   in its metadata ([`crate::agent::checkpoint::Crc32s`]); the first corrupt tensor is named.
//!
//! Files without checksums (an older pgser, another writer) are decoded in full, which catches
//! what breaks their structure, and reported as not verifiable: their values cannot be checked.

use std::io::Read;
use std::path::Path;

use anyhow::{Context, Result, bail};
use serde::Serialize;

use crate::agent::checkpoint;

/// What `verify` found in one file.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub path: String,
    /// "table" or "checkpoint".
    pub format: String,
    /// The footer's `kind` for a pgser table, the metadata's `format` for a checkpoint.
    pub kind: Option<String>,
    /// Whether checksums were there and matched (false: there were none).
    pub verified: bool,
    /// What was checked: column chunks (tables) or tensors (checkpoints), and their bytes.
    pub parts: usize,
    pub bytes: u64,
}

impl Report {
    /// One line for the terminal.
    pub fn line(&self) -> String {
        let what =
            self.kind.as_deref().map(|k| format!("{} ({k})", self.format)).unwrap_or_else(|| self.format.clone());
        let unit = if self.format.starts_with("table") { "column chunks" } else { "tensors" };
        if self.verified {
            format!("ok {}: {what}, {} {unit} ({} bytes) match their checksums", self.path, self.parts, self.bytes)
        } else {
            format!(
                "unverified {}: {what}, decoded in full but it has no checksums (written by an older pgser or another tool), so its values cannot be verified",
                self.path
            )
        }
    }
}

/// Checks one file, or a table folder; an error names the file and the first corrupt part.
pub fn verify(path: &Path) -> Result<Report> {
    if path.is_dir() {
        return folder(path);
    }
    let at = path.display();
    let mut magic = [0u8; 4];
    crate::output::open_input(path)?
        .read_exact(&mut magic)
        .with_context(|| format!("{at}: too short to be a pgser table or checkpoint"))?;
    if &magic == b"PAR1" { table(path) } else { safetensors(path) }
}

fn table(path: &Path) -> Result<Report> {
    let at = path.display();
    let (builder, verifier) = crate::table::open_checked(path, None)?;
    let footer = crate::table::footer_text(builder.metadata().file_metadata());
    let footer = footer.and_then(|t| serde_json::from_str::<serde_json::Value>(t).ok());
    let kind = footer.as_ref().and_then(|f| f["kind"].as_str().map(str::to_string));
    // A trajectory footer must also say what its readers can act on (its passthrough columns'
    // dtypes and shapes): one whose checksum holds can still say what none of them could read.
    if let Some(f) = footer.filter(|_| kind.as_deref() == Some(crate::trajectory::KIND)) {
        crate::trajectory::Footer::from_json(&at.to_string(), f)?;
    }
    let groups = builder.metadata().num_row_groups();
    let rows = builder.metadata().file_metadata().num_rows();
    let mut read = 0i64;
    for (i, batch) in builder.build().with_context(|| format!("{at}: cannot read"))?.enumerate() {
        let batch = batch.with_context(|| format!("{at}: batch {i} (of {groups} row groups) does not decode"))?;
        read += batch.num_rows() as i64;
    }
    if read != rows {
        bail!("{at}: {read} rows decode but the file's metadata says {rows}");
    }
    let (parts, bytes) = verifier.extent();
    Ok(Report { path: at.to_string(), format: "table".into(), kind, verified: verifier.verifiable(), parts, bytes })
}

/// A table folder: its manifest against its shards (`TableFolder::open`), each shard's bytes
/// against the manifest's SHA-256, then each shard as a table; the validation table too.
fn folder(dir: &Path) -> Result<Report> {
    let f = crate::trajectory::folder::TableFolder::open(dir)?;
    let (mut parts, mut bytes, mut verified) = (0, 0, true);
    for (s, path) in f.manifest.shards.iter().zip(f.shard_paths()) {
        let sha256 = crate::output::sha256_file(&path)?;
        if sha256 != s.sha256 {
            bail!(
                "{}: its SHA-256 is not the manifest's ({}): the shard changed or is corrupt",
                path.display(),
                dir.display()
            );
        }
        let r = table(&path)?;
        parts += r.parts;
        bytes += r.bytes;
        verified &= r.verified;
    }
    if let Some(v) = f.validation()? {
        let r = folder(&v.dir)?;
        parts += r.parts;
        bytes += r.bytes;
        verified &= r.verified;
    }
    Ok(Report {
        path: dir.display().to_string(),
        format: format!("table folder of {} shards", f.manifest.shards.len()),
        kind: Some(crate::trajectory::KIND.into()),
        verified,
        parts,
        bytes,
    })
}

fn safetensors(path: &Path) -> Result<Report> {
    let at = path.display();
    let bytes = crate::output::read_input(path)?;
    let verified = checkpoint::verify(path, &bytes)?;
    let st = safetensors::SafeTensors::deserialize(&bytes).with_context(|| format!("{at}: not a safetensors file"))?;
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes)?;
    let kind = header.metadata().as_ref().and_then(|m| m.get("format").cloned());
    let tensor_bytes = st.tensors().iter().map(|(_, t)| t.data().len() as u64).sum();
    Ok(Report {
        path: at.to_string(),
        format: "checkpoint".into(),
        kind,
        verified,
        parts: st.len(),
        bytes: tensor_bytes,
    })
}
