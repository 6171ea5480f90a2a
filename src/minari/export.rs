//! `pgser-etl export TABLE --format minari|wgcsl -o PATH`: a trajectory table back out as a
//! Minari dataset (Arrow storage) or a WGCSL pickle, so data pgser made or converted can go to
//! tools that read those.
//!
//! Both read the table through the checks every pgser reader makes, in float64 (exact for a
//! float32 table), and appear atomically: the pickle through [`AtomicFile`], the dataset as a
//! hidden folder beside `PATH` renamed into place when complete. An existing `PATH` is refused,
//! never overwritten: a dataset folder is many files, and half-replacing one is worse than failing.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use arrow_array::Array;
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type};
use arrow_schema::DataType;
use serde_json::json;

use super::arrow_storage::{self, EpisodeOut};
use super::{BoxSpace, Spaces};
use crate::dtype::Dtype;
use crate::output::AtomicFile;
use crate::pickle::write::{ArrayOut, write_dict};
use crate::task::{GoalMetric, Task};
use crate::trajectory::extra::{append_source_bytes, kept_for};
use crate::trajectory::read::{check_all_read, check_keys, open_checked};
use crate::trajectory::{FloatType, Footer, Passthrough, Per};

/// The Minari version whose dataset layout the export writes (and `minari.load_dataset` checks
/// against the versions it supports).
const MINARI_VERSION: &str = "0.5.4";

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    /// A Minari dataset folder (Arrow storage), named by its dataset id `NAME-vN`.
    Minari,
    /// A WGCSL pickle (dict of float64 arrays o, ag, u, g; protocol 3).
    Wgcsl,
    /// An OGBench dataset file `NAME.npz` (observations, actions, terminals): written by
    /// src/ogbench/export.rs, which `convert::export`, the layer above, chooses for it. A table
    /// folder exports as a folder of its shards (`NAME-i.npz`, `NAME-val.npz`).
    Ogbench,
}

#[derive(Debug, Clone)]
pub struct ExportOptions {
    pub table: PathBuf,
    pub format: ExportFormat,
    pub output: PathBuf,
    /// Passthrough columns (or `last_action`, each episode's last action) to leave out: the
    /// explicit choice where the format cannot hold them, which the export otherwise refuses.
    pub drop: Vec<String>,
}

#[derive(Debug, Clone)]
pub struct ExportSummary {
    pub task: String,
    pub episodes: usize,
    /// Observations per episode.
    pub t: usize,
}

/// A trajectory table in memory as float64: o, ag (`[N, T, ·]`), g, u (`[N, T−1, ·]`), and the
/// passthrough columns to write, each as its source's bytes.
struct Table {
    footer: Footer,
    arrays: [Vec<f64>; 4],
    extras: Vec<(Passthrough, Vec<u8>)>,
}

pub fn export(opts: &ExportOptions) -> Result<ExportSummary> {
    let out = &opts.output;
    if out.symlink_metadata().is_ok() {
        bail!("{}: already exists; export never overwrites (remove it or choose another path)", out.display());
    }
    crate::output::check_not_an_input(out, std::slice::from_ref(&opts.table))?;
    let dataset_id = match opts.format {
        ExportFormat::Minari => Some(dataset_id(out)?),
        ExportFormat::Wgcsl => None,
        ExportFormat::Ogbench => {
            bail!("{}: OGBench files are written by pgser's convert::export, not the Minari writer", out.display())
        }
    };
    let footer = crate::table::read_footer(&opts.table)?;
    let footer = Footer::from_json(&opts.table.display().to_string(), footer)?;
    // WGCSL keeps any array whose first dimension is the episodes; a Minari dataset keeps what
    // has a row per observation, in each episode's `infos`.
    let (extras, _) = match dataset_id {
        Some(_) => kept_for(&footer, &opts.table, "Minari dataset", &opts.drop, minari_holds, false)?,
        None => kept_for(&footer, &opts.table, "WGCSL pickle", &opts.drop, |_| true, false)?,
    };
    if dataset_id.is_some() {
        let infos: Vec<&Passthrough> = extras.iter().filter(|p| !is_outcome(p) && obs_key(p).is_none()).collect();
        let names: Vec<&str> = infos.iter().map(|p| info_key(&p.column)).collect();
        if let Some((i, n)) = names.iter().enumerate().find(|(i, n)| names[..*i].contains(n)) {
            bail!(
                "{}: passthrough columns {} and {} would both be the Minari info {n:?}; pass --drop with one of them",
                opts.table.display(),
                infos[names.iter().position(|m| m == n).expect("found")].column,
                infos[i].column
            );
        }
    }
    let table = read_table(&opts.table, &extras)?;
    match dataset_id {
        Some(id) => write_minari(&table, &opts.table, out, &id)?,
        None => write_wgcsl(&table, out)?,
    }
    let f = &table.footer;
    Ok(ExportSummary { task: f.task.clone(), episodes: f.episodes, t: f.t })
}

/// Minari finds a dataset by its id, the folder's name, which must parse as `NAME-vN`.
fn dataset_id(out: &Path) -> Result<String> {
    let name = out.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let valid = name.rsplit_once("-v").is_some_and(|(base, version)| {
        !base.is_empty()
            && base.chars().all(|c| c.is_alphanumeric() || c == '-' || c == '_')
            && !version.is_empty()
            && version.chars().all(|c| c.is_ascii_digit())
    });
    if !valid {
        bail!(
            "{}: a Minari dataset folder is named by its dataset id, NAME-vN (letters, digits, - and _, then a \
             version: fetchreach-expert-v0), which `minari.load_dataset` finds under MINARI_DATASETS_PATH",
            out.display()
        );
    }
    Ok(name)
}

fn read_table(path: &Path, extras: &[Passthrough]) -> Result<Table> {
    let at = path.display().to_string();
    let names = ["obs", "achieved_goal", "desired_goal", "action"];
    let columns: Vec<&str> = names.iter().copied().chain(extras.iter().map(|p| p.column.as_str())).collect();
    let (footer, reader) = open_checked(path, &columns, 64)?;
    let t = footer.t;
    let mut arrays: [Vec<f64>; 4] = Default::default();
    let mut extra_bytes: Vec<Vec<u8>> = vec![Vec::new(); extras.len()];
    let mut row = 0;
    for batch in reader {
        let batch = batch.with_context(|| format!("{at}: cannot read the rows after row {row}"))?;
        check_keys(&at, &batch, row, &footer)?;
        for (k, name) in names.iter().enumerate() {
            let list = batch.column_by_name(name).expect("projected").as_fixed_size_list();
            let dim = list.value_length() as usize;
            let (values, offset) = (list.values(), list.value_offset_at(0));
            let values: std::borrow::Cow<[f64]> = match values.data_type() {
                DataType::Float32 => values.as_primitive::<Float32Type>().values().iter().map(|&v| v as f64).collect(),
                _ => std::borrow::Cow::Borrowed(values.as_primitive::<Float64Type>().values()),
            };
            for r in 0..batch.num_rows() {
                let step = (row + r) % t;
                if k >= 2 && step == t - 1 {
                    continue; // desired goals and actions have T − 1 rows
                }
                if list.is_null(r) {
                    bail!("{at}: row {} (episode {}, step {step}): `{name}` is null", row + r, (row + r) / t);
                }
                arrays[k].extend_from_slice(&values[offset + r * dim..offset + (r + 1) * dim]);
            }
        }
        for (p, out) in extras.iter().zip(&mut extra_bytes) {
            let col = batch.column_by_name(&p.column).expect("projected");
            append_source_bytes(out, p, col, row, t, &at)?;
        }
        row += batch.num_rows();
    }
    check_all_read(&at, row, &footer)?;
    Ok(Table { footer, arrays, extras: extras.iter().cloned().zip(extra_bytes).collect() })
}

/// The pickle's o, ag, u, g in float64 (WGCSL's type), or in the table's float type when the
/// table was converted from WGCSL pickles (so a float32 buffer comes back float32); then every
/// passthrough array, `[N, T, …]`, `[N, T − 1, …]` or `[N, …]` as its layout says, in its dtype.
fn write_wgcsl(table: &Table, out: &Path) -> Result<()> {
    let f = &table.footer;
    let (n, t) = (f.episodes, f.t);
    let from_wgcsl = f.sources.first().is_some_and(|s| s.format == "wgcsl-pickle");
    let f32s = from_wgcsl && f.float_type == FloatType::Float32;
    let file = AtomicFile::create(out)?;
    let mut w = std::io::BufWriter::with_capacity(8 << 20, file.handle()?);
    // Pickle key order o, ag, u, g (what `collect` writes); the table holds o, ag, g, u.
    let layout =
        [(0, "o", t, f.obs_dim), (1, "ag", t, f.goal_dim), (3, "u", t - 1, f.act_dim), (2, "g", t - 1, f.goal_dim)];
    let mut arrays: Vec<ArrayOut> = layout
        .iter()
        .map(|&(k, key, steps, dim)| {
            let values = &table.arrays[k];
            ArrayOut {
                key,
                dtype: if f32s { Dtype::F32 } else { Dtype::F64 },
                shape: vec![n, steps, dim],
                data: Box::new(move |w: &mut dyn std::io::Write| {
                    for chunk in values.chunks(1 << 16) {
                        let bytes: Vec<u8> = if f32s {
                            chunk.iter().flat_map(|&v| (v as f32).to_le_bytes()).collect()
                        } else {
                            chunk.iter().flat_map(|v| v.to_le_bytes()).collect()
                        };
                        w.write_all(&bytes)?;
                    }
                    Ok(())
                }),
            }
        })
        .collect();
    for (p, bytes) in &table.extras {
        let mut shape = vec![n];
        if p.per != Per::Episode {
            shape.push(p.per.rows(t));
        }
        shape.extend(&p.shape);
        arrays.push(ArrayOut { key: &p.column, dtype: p.dtype, shape, data: Box::new(move |w| w.write_all(bytes)) });
    }
    let fail = || format!("{}: write failed", out.display());
    write_dict(&mut w, &mut arrays).with_context(fail)?;
    drop(arrays);
    w.into_inner().map_err(|e| e.into_error()).with_context(fail)?;
    file.commit()
}

/// The Gymnasium registration of pgser's built-in tasks (gymnasium-robotics 1.4.2), so an
/// exported dataset's `recover_environment()` makes the environment its episodes came from.
fn env_spec(task: &Task) -> Option<serde_json::Value> {
    let (id, entry, kwargs) = match task.name.as_str() {
        "FetchReach" => ("FetchReach-v4", "fetch.reach:MujocoFetchReachEnv", json!({"reward_type": "sparse"})),
        "FetchPush" => ("FetchPush-v4", "fetch.push:MujocoFetchPushEnv", json!({"reward_type": "sparse"})),
        "FetchPickAndPlace" => (
            "FetchPickAndPlace-v4",
            "fetch.pick_and_place:MujocoFetchPickAndPlaceEnv",
            json!({"reward_type": "sparse"}),
        ),
        "FetchSlide" => ("FetchSlide-v4", "fetch.slide:MujocoFetchSlideEnv", json!({"reward_type": "sparse"})),
        "HandManipulateBlockRotateZ" => (
            "HandManipulateBlockRotateZ-v1",
            "shadow_dexterous_hand.manipulate_block:MujocoHandBlockEnv",
            json!({"target_position": "ignore", "target_rotation": "z", "reward_type": "sparse"}),
        ),
        "HandManipulateEggRotate" => (
            "HandManipulateEggRotate-v1",
            "shadow_dexterous_hand.manipulate_egg:MujocoHandEggEnv",
            json!({"target_position": "ignore", "target_rotation": "xyz", "reward_type": "sparse"}),
        ),
        _ => return None,
    };
    Some(json!({
        "id": id,
        "entry_point": format!("gymnasium_robotics.envs.{entry}"),
        "reward_threshold": null,
        "nondeterministic": false,
        "max_episode_steps": task.t - 1,
        "order_enforce": true,
        "disable_env_checker": false,
        "kwargs": kwargs,
        "additional_wrappers": [],
        "vector_entry_point": null,
    }))
}

/// What a Minari dataset holds of a table's passthrough columns: those with a row per observation
/// (as infos), and the rewards, terminations and truncations a Minari dataset's table keeps (a
/// row per step, written back in their place).
fn minari_holds(p: &Passthrough) -> bool {
    p.per == Per::Step || is_outcome(p)
}

/// A Minari dataset's observation key (`observations/KEY`, with its subspace): written back into
/// the Dict observation, not the infos.
fn obs_key(p: &Passthrough) -> Option<&str> {
    p.space.as_ref().and(p.column.strip_prefix("observations/"))
}

fn is_outcome(p: &Passthrough) -> bool {
    p.per == Per::Transition && super::OUTCOMES.contains(&p.column.as_str())
}

/// The Minari info a passthrough column is written as: `infos/KEY` (what `convert` made of a
/// Minari dataset's infos) is KEY again; another column keeps its name.
fn info_key(column: &str) -> &str {
    column.strip_prefix("infos/").unwrap_or(column)
}

fn write_minari(table: &Table, source: &Path, out: &Path, id: &str) -> Result<()> {
    let f = &table.footer;
    let task = f.task();
    let (n, t) = (f.episodes, f.t);
    let size = if f.float_type == FloatType::Float32 { 4 } else { 8 };
    // A table converted from a Minari dataset whose arrays had two float types (float32 actions
    // beside float64 observations) gives each its own back; the values were widened exactly.
    let sizes = match f.sources.as_slice() {
        [s] if s.format.starts_with("minari") && s.float_bytes.len() == 4 => s.float_bytes.clone(),
        _ => vec![size; 4],
    };
    let spaces = Spaces {
        obs: [(f.obs_dim, sizes[0]), (f.goal_dim, sizes[1]), (f.goal_dim, sizes[2])]
            .map(|(dim, size)| BoxSpace { dim, size }),
        action: BoxSpace { dim: f.act_dim, size: sizes[3] },
    };
    let staging = crate::output::AtomicDir::create(out)?;
    let data = staging.path().join("data");
    let mkdir = |d: &Path| std::fs::create_dir_all(d).with_context(|| format!("{}: cannot create", d.display()));
    let row = |k: usize, dim: usize, steps: usize, e: usize| &table.arrays[k][e * steps * dim..(e + 1) * steps * dim];
    for e in 0..n {
        let (o, ag) = (row(0, f.obs_dim, t, e), row(1, f.goal_dim, t, e));
        let (g, u) = (row(2, f.goal_dim, t - 1, e), row(3, f.act_dim, t - 1, e));
        // The last observation's desired goal: the episode's goal, that of the step before.
        let mut dg = g.to_vec();
        dg.extend_from_slice(&g[g.len() - f.goal_dim..]);
        let rewards = rewards(&task, &ag[f.goal_dim..], g);
        let dir = data.join(e.to_string());
        mkdir(&dir)?;
        let slice = |p: &Passthrough, bytes: &[u8]| {
            let per = p.episode_bytes(t);
            bytes[e * per..(e + 1) * per].to_vec()
        };
        let outcomes = table
            .extras
            .iter()
            .filter(|(p, _)| is_outcome(p))
            .map(|(p, bytes)| (p.column.clone(), p.dtype, slice(p, bytes)))
            .collect();
        let obs_extras = table
            .extras
            .iter()
            .filter_map(|(p, bytes)| Some((obs_key(p)?.to_string(), p.dtype, p.shape.clone(), slice(p, bytes))))
            .collect();
        let infos = table
            .extras
            .iter()
            .filter(|(p, _)| !is_outcome(p) && obs_key(p).is_none())
            .map(|(p, bytes)| {
                let per = p.episode_bytes(t);
                (info_key(&p.column).to_string(), p.dtype, p.shape.clone(), bytes[e * per..(e + 1) * per].to_vec())
            })
            .collect();
        let ep = EpisodeOut {
            obs: [o.to_vec(), ag.to_vec(), dg],
            actions: u.to_vec(),
            rewards,
            infos,
            outcomes,
            obs_extras,
        };
        arrow_storage::write_episode(&dir, &spaces, ep)?;
        write_json(&dir.join("metadata.json"), &json!({"id": e, "total_steps": t - 1}))?;
    }
    // Fetch and hand actions lie in [-1, 1]; other tasks' bounds are not known to pgser.
    let (low, high) = if env_spec(&task).is_some() { (-1.0, 1.0) } else { (f64::NEG_INFINITY, f64::INFINITY) };
    let inf = |b: &BoxSpace| b.to_json(f64::NEG_INFINITY, f64::INFINITY);
    // Gymnasium's Dict sorts its keys.
    let mut subspaces: Vec<(String, String)> = vec![
        ("achieved_goal".into(), inf(&spaces.obs[1])),
        ("desired_goal".into(), inf(&spaces.obs[2])),
        ("observation".into(), inf(&spaces.obs[0])),
    ];
    // A Minari dataset's other observation keys, with the subspaces it had.
    for (p, _) in &table.extras {
        if let (Some(key), Some(space)) = (obs_key(p), &p.space) {
            subspaces.push((key.to_string(), space.clone()));
        }
    }
    subspaces.sort();
    let observation_space = format!(
        r#"{{"type": "Dict", "subspaces": {{{}}}}}"#,
        subspaces.iter().map(|(k, s)| format!("\"{k}\": {s}")).collect::<Vec<_>>().join(", ")
    );
    let mut meta = json!({
        "total_episodes": n,
        "total_steps": n * (t - 1),
        "data_format": "arrow",
        "observation_space": observation_space,
        "action_space": spaces.action.to_json(low, high),
        "dataset_id": id,
        "minari_version": MINARI_VERSION,
        "algorithm_name": format!("pgser-etl export of {}", source.display()),
        "pgser": {
            "task": f.task,
            "success_threshold": f.success_threshold,
            "goal_metric": f.goal_metric,
            "source": {"path": source.display().to_string(), "sha256": crate::output::sha256_file(source)?},
        },
    });
    if let Some(spec) = env_spec(&task) {
        meta["env_spec"] = serde_json::Value::String(spec.to_string());
    }
    write_json(&data.join("metadata.json"), &meta)?;
    // Renamed into place whole; `out` was checked absent, and rename refuses a non-empty folder.
    staging.commit()
}

/// Rewards as gymnasium-robotics computes them, to the bit: Fetch's `-(d > threshold)` in
/// float32 is −0.0 where the goal is reached; the hand tasks' `success − 1` is +0.0.
fn rewards(task: &Task, next_achieved: &[f64], goals: &[f64]) -> Vec<f32> {
    let mut out = vec![0f32; goals.len() / task.goal_dim];
    task.rewards(next_achieved, goals, &mut out);
    if task.metric == GoalMetric::Euclidean {
        out.iter_mut().filter(|r| **r == 0.0).for_each(|r| *r = -0.0);
    }
    out
}

fn write_json(path: &Path, value: &serde_json::Value) -> Result<()> {
    std::fs::write(path, serde_json::to_string(value)?).with_context(|| format!("{}: cannot write", path.display()))
}
