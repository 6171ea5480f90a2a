//! Minari's HDF5 storage (its default): `data/main_data.hdf5` holds a group `episode_{i}` per
//! episode, with datasets `observations/{key}` (n + 1 rows for a Dict observation), `actions`,
//! `rewards`, `terminations`, `truncations` (n rows) and an `infos` group.
//!
//! Read through the HDF5 C library (hdf5-metno, compiled from the source hdf5-metno-src carries
//! into pgser itself): HDF5 is a large format (B-trees, chunking, filters, several object header
//! versions) that h5py writes in whatever form its library version picks, and only the reference
//! library reads all of them. Compiled with the cargo feature `hdf5` only (on by default), so a
//! build with `--no-default-features` needs no CMake and no C compiler (docs/minari.md).

use std::path::PathBuf;

use anyhow::{Result, anyhow, bail};
use hdf5::types::{FloatSize, IntSize, TypeDescriptor};
use hdf5_metno as hdf5;

use super::infos::Info;
use super::{BoxSpace, Episode, Metadata, OBS_KEYS, Spaces};
use crate::dtype::Dtype;

pub struct Reader {
    path: PathBuf,
    file: hdf5::File,
    spaces: Spaces,
    total: usize,
    /// The Dict observation's other keys.
    extra_obs: Vec<String>,
    /// The columns `--drop` names, never read: `--drop` is the way past one no column can keep.
    drop: Vec<String>,
}

/// An HDF5 error as one line (the library's messages may hold line breaks).
fn one_line(e: hdf5::Error) -> String {
    e.to_string().split_whitespace().collect::<Vec<_>>().join(" ")
}

impl Reader {
    pub fn open(meta: &Metadata, drop: &[String]) -> Result<Reader> {
        let path = meta.data.join("main_data.hdf5");
        if !path.is_file() {
            bail!("{}: no main_data.hdf5, though metadata.json says data_format 'hdf5'", meta.data.display());
        }
        let file = hdf5::File::open(&path)
            .map_err(|e| anyhow!("{}: not a readable HDF5 file ({})", path.display(), one_line(e)))?;
        let extra_obs = meta.extra_obs.iter().map(|(k, _)| k.clone()).collect();
        Ok(Reader {
            path,
            file,
            spaces: meta.spaces.clone(),
            total: meta.total_episodes,
            extra_obs,
            drop: drop.to_vec(),
        })
    }

    /// Episode i's observations (n + 1 rows) and actions (n rows).
    pub fn episode(&mut self, i: usize) -> Result<Episode> {
        let at = self.path.display().to_string();
        let name = format!("episode_{i}");
        let group = self.file.group(&name).map_err(|_| {
            anyhow!("{at}: episode {i} is missing: no group {name} (metadata.json says total_episodes {})", self.total)
        })?;
        let mut arrays: [Vec<u8>; 4] = Default::default();
        let mut rows = [0; 4];
        for (k, key) in OBS_KEYS.iter().enumerate() {
            let key = format!("observations/{key}");
            (rows[k], arrays[k]) = read(&at, &name, &group, &key, &self.spaces.obs[k])?;
        }
        (rows[3], arrays[3]) = read(&at, &name, &group, "actions", &self.spaces.action)?;
        if rows[1] != rows[0] || rows[2] != rows[0] || rows[3] + 1 != rows[0] {
            bail!(
                "{at}: {name} has {} observation, {} achieved_goal, {} desired_goal rows and {} actions; an \
                 episode of n steps has n + 1 observations and n actions",
                rows[0],
                rows[1],
                rows[2],
                rows[3]
            );
        }
        let mut present = Vec::new();
        let infos = match group.group("infos") {
            Ok(g) => read_infos(&at, &name, &g, &self.drop, &mut present)?,
            Err(_) => Vec::new(),
        };
        // Rewards, terminations and truncations: a row per step, kept as they were recorded.
        let recorded: Vec<&str> = super::OUTCOMES.iter().copied().filter(|k| group.link_exists(k)).collect();
        present.extend(recorded.iter().map(|k| k.to_string()));
        let outcomes = recorded
            .iter()
            .filter(|k| !self.drop.iter().any(|d| d == *k))
            .map(|k| read_any(&at, &name, &group, k, k))
            .collect::<Result<Vec<_>>>()?;
        // The Dict observation's other keys, as metadata.json lists them.
        present.extend(self.extra_obs.iter().map(|k| format!("observations/{k}")));
        let obs_extras = self
            .extra_obs
            .iter()
            .filter(|k| !self.drop.contains(&format!("observations/{k}")))
            .map(|k| {
                let mut info =
                    read_any(&at, &name, &group, &format!("observations/{k}"), &format!("observations/{k}"))?;
                info.key = k.clone();
                Ok(info)
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Episode { steps: rows[3], arrays, infos, outcomes, obs_extras, present })
    }
}

/// The datasets of an episode's `infos` group, in name order, each as its rows' bytes, but those
/// `drop` names (`infos/KEY`), which are never read; every key's column goes into `present`.
fn read_infos(
    at: &str,
    episode: &str,
    group: &hdf5::Group,
    drop: &[String],
    present: &mut Vec<String>,
) -> Result<Vec<Info>> {
    let mut names = group.member_names().map_err(|e| anyhow!("{at}: {episode}/infos: {}", one_line(e)))?;
    names.sort();
    present.extend(names.iter().map(|key| format!("infos/{key}")));
    names
        .iter()
        .filter(|key| !drop.contains(&format!("infos/{key}")))
        .map(|key| read_any(at, &format!("{episode}/infos"), group, key, &format!("infos/{key}")))
        .collect()
}

/// Dataset `key` of `group` (any shape, any bool, int, uint or float type) as its rows' bytes;
/// `column` is the name `--drop` takes, which a refusal gives.
pub(super) fn read_any(at: &str, within: &str, group: &hdf5::Group, key: &str, column: &str) -> Result<Info> {
    let where_ = format!("{at}: {within}/{key}");
    let cannot = |what: String| {
        anyhow!("{where_} is {what}, which a table column cannot keep; pass --drop {column} to convert without it")
    };
    let ds = group.dataset(key).map_err(|_| cannot("a group (a nested dict)".into()))?;
    let shape = ds.shape();
    if shape.is_empty() {
        return Err(cannot("a scalar".into()));
    }
    let d = ds.dtype().and_then(|t| t.to_descriptor()).map_err(|e| anyhow!("{where_}: {}", one_line(e)))?;
    let failed = |e: hdf5::Error| anyhow!("{where_}: cannot read ({})", one_line(e));
    macro_rules! raw {
        ($t:ty) => {
            ds.read_raw::<$t>().map_err(failed)?.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>()
        };
    }
    let (dtype, bytes) = match d {
        TypeDescriptor::Boolean => {
            (Dtype::BOOL, ds.read_raw::<bool>().map_err(failed)?.iter().map(|&b| u8::from(b)).collect())
        }
        TypeDescriptor::Integer(IntSize::U1) => (Dtype::I8, raw!(i8)),
        TypeDescriptor::Integer(IntSize::U2) => (Dtype::I16, raw!(i16)),
        TypeDescriptor::Integer(IntSize::U4) => (Dtype::I32, raw!(i32)),
        TypeDescriptor::Integer(IntSize::U8) => (Dtype::I64, raw!(i64)),
        TypeDescriptor::Unsigned(IntSize::U1) => (Dtype::U8, raw!(u8)),
        TypeDescriptor::Unsigned(IntSize::U2) => (Dtype::U16, raw!(u16)),
        TypeDescriptor::Unsigned(IntSize::U4) => (Dtype::U32, raw!(u32)),
        TypeDescriptor::Unsigned(IntSize::U8) => (Dtype::U64, raw!(u64)),
        TypeDescriptor::Float(FloatSize::U4) => (Dtype::F32, raw!(f32)),
        TypeDescriptor::Float(FloatSize::U8) => (Dtype::F64, raw!(f64)),
        other => return Err(cannot(format!("of {other} values"))),
    };
    Ok(Info { key: key.to_string(), dtype, shape: shape[1..].to_vec(), rows: shape[0], bytes })
}

/// One dataset of an episode group as little-endian bytes: its rows, checked to be
/// `[rows, space.dim]` values of the space's float type.
fn read(at: &str, episode: &str, group: &hdf5::Group, key: &str, space: &BoxSpace) -> Result<(usize, Vec<u8>)> {
    let where_ = format!("{at}: {episode}/{key}");
    let ds = group.dataset(key).map_err(|_| anyhow!("{where_} is missing"))?;
    let shape = ds.shape();
    if shape.len() != 2 || shape[1] != space.dim {
        bail!("{where_} has shape {shape:?}; the space says [rows, {}]", space.dim);
    }
    let descriptor = ds.dtype().and_then(|t| t.to_descriptor()).map_err(|e| anyhow!("{where_}: {}", one_line(e)))?;
    let size = match descriptor {
        TypeDescriptor::Float(FloatSize::U4) => 4,
        TypeDescriptor::Float(FloatSize::U8) => 8,
        other => bail!("{where_} holds {other} values; the space says {}", space.dtype()),
    };
    if size != space.size {
        bail!("{where_} holds float{} values but the space says {}", size * 8, space.dtype());
    }
    let failed = |e: hdf5::Error| anyhow!("{where_}: cannot read ({})", one_line(e));
    let bytes: Vec<u8> = if size == 4 {
        ds.read_raw::<f32>().map_err(failed)?.iter().flat_map(|v| v.to_le_bytes()).collect()
    } else {
        ds.read_raw::<f64>().map_err(failed)?.iter().flat_map(|v| v.to_le_bytes()).collect()
    };
    Ok((shape[0], bytes))
}
