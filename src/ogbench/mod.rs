//! OGBench's datasets (Park et al., ICLR 2025; the `ogbench` package) in and out of pgser.
//!
//! An OGBench dataset is one `.npz` file (`np.savez_compressed`) named after the dataset,
//! `pointmaze-medium-navigate-v0.npz`, with a `-val.npz` beside it: `observations` and `actions`
//! (float32, one row per step), `terminals` (bool, true on each episode's last row), and `qpos`,
//! `qvel` (and `button_states` for the manipulation scenes). Episodes are contiguous and of one
//! length M; there are no rewards and no goals. An episode of M rows is a pgser episode of T = M
//! observations and T − 1 transitions, exactly a WGCSL episode. Each episode's last row has an
//! action but no next state: OGBench's own loader drops it; pgser keeps it on the episode's last
//! step (`last_action`), where no sampler reads it, so that `export` gives it back. Every other
//! member (terminals, qpos, qvel, …) is kept beside the table as a passthrough column in its own
//! dtype ([`crate::trajectory::extra`]), and `export` writes it back; `--drop KEY` leaves one out.
//! Observations and actions keep their own float types too: a table holds the wider, and the
//! footer's source entry records each one's (`float_bytes`) for `export`.
//!
//! Files saved from what `ogbench.load_dataset` returns are read too: compact
//! (`compact_dataset=True`: every row kept, `valids` 0 on each episode's last row) and regular
//! (each episode's last row dropped, its observation kept as the last row's
//! `next_observations`). All three layouts of one dataset give one table. A regular file whose
//! `next_observations` are not, bit for bit, the observation after each row in its episode (a
//! user's own array) keeps them whole as a passthrough column, which `export` writes back instead
//! of the table's observations.
//!
//! The goal is the agent's position, as OGBench's success test uses it: `achieved_goal` is the
//! observation's first two values (x, y) in the locomotion mazes (pointmaze, antmaze,
//! humanoidmaze, whose observations start with the agent's x, y), and success is a distance of
//! at most OGBench's `goal_tol` (1.0 for the point, 0.5 for the ant and humanoid). The data have
//! no goals: each transition's `desired_goal` is its episode's last position (its own hindsight
//! goal); pgser's samplers relabel from there (HER) and swap goals between episodes (PGSER).
//! docs/ogbench.md is the user's side of this.

mod convert;
mod export;
pub mod goal;
pub mod npz;
mod window;

use std::io::Read;
use std::path::Path;

use anyhow::{Context, Result, bail};

pub use convert::{WINDOW_BYTES, convert, convert_within, group_bytes};
pub use export::export_npz;
pub use goal::{GoalMap, goal_map};
use npz::Member;

use crate::dtype::Dtype;
use crate::task::Task;
use crate::trajectory::{ConvertOptions, ConvertPlan, FloatType, Passthrough, Per};

/// OGBench's names of the arrays pgser reads as o, ag, u and g, as error messages give them: the
/// goals are parts of the observations.
pub const ARRAY_KEYS: [&str; 4] = ["observations", "observations", "actions", "observations"];

/// Which of OGBench's layouts a file holds (the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// The distributed files: `terminals` (bool) on each episode's last row.
    Dataset,
    /// `load_dataset(compact_dataset=True)`'s arrays: `valids` 0 on each episode's last row.
    Compact,
    /// `load_dataset()`'s arrays: each episode's last row dropped, `next_observations` holds it.
    Regular,
}

impl Layout {
    fn format_name(self) -> &'static str {
        match self {
            Layout::Dataset => "ogbench-npz",
            Layout::Compact => "ogbench-npz-compact",
            Layout::Regular => "ogbench-npz-regular",
        }
    }
}

/// A dataset file as its name and headers describe it, with its episodes found.
pub struct Dataset {
    pub path: std::path::PathBuf,
    /// The dataset's name (`pointmaze-medium-navigate-v0`; a `-val` file names its dataset).
    pub name: String,
    /// The environment OGBench evaluates it in (`pointmaze-medium-v0`).
    pub env: String,
    pub layout: Layout,
    pub observations: Member,
    pub actions: Member,
    /// Rows per episode in the file (M: M − 1 for the regular layout) and the episode count.
    pub rows_per_episode: usize,
    pub episodes: usize,
    /// The other members (terminals, qpos, qvel, …), kept as passthrough columns, in file order.
    pub extras: Vec<(Member, Passthrough)>,
    /// The regular layout's `next_observations`, and where among `extras` it goes (file order)
    /// when [`Dataset::keep_next_observations`] finds it is more than the observations shifted.
    pub next_observations: Option<(Member, usize)>,
    /// The members `--drop` leaves out.
    pub dropped: Vec<String>,
    /// Which observation values are the goal, and when it is reached ([`goal`]).
    pub goal: GoalMap,
}

impl Dataset {
    /// The shape of one image observation (`[64, 64, 3]`), where observations are images
    /// (uint8 `[N, H, W, C]`); empty for float rows.
    pub fn image_shape(&self) -> Vec<usize> {
        if self.observations.dtype == Dtype::U8 { self.observations.shape[1..].to_vec() } else { Vec::new() }
    }

    /// Bytes of one row of the file, every member a convert streams: what a window of its rows
    /// holds as read.
    pub fn row_bytes(&self) -> usize {
        let member = |m: &Member| m.row_len() * m.dtype.size;
        let next = self.next_observations.as_ref().map_or(0, |(m, _)| member(m));
        member(&self.observations)
            + member(&self.actions)
            + next
            + self.extras.iter().map(|(m, _)| member(m)).sum::<usize>()
    }

    /// Bytes per value of the goal rows the table gets: the observation's float for a goal of
    /// observation values, float32 for one read from a member (OGBench's oracle representations
    /// are float32) of an image dataset.
    pub fn goal_value_bytes(&self) -> usize {
        if self.observations.dtype == Dtype::U8 { 4 } else { self.observations.dtype.size }
    }
}

/// OGBench's dataset types: the word a dataset's name has beside its environment's
/// (`cube-double-play-v0` is a `play` dataset of `cube-double-v0`).
pub const DATASET_TYPES: [&str; 5] = ["navigate", "stitch", "explore", "play", "noisy"];

/// `pointmaze-medium-navigate-v0` → `pointmaze-medium-v0`, `scene-play-v0` → `scene-v0`: OGBench
/// names a dataset NAME-TYPE-vN and drops the type (the second-to-last word, one of
/// [`DATASET_TYPES`]) to name its environment. None for a name of no dataset type (an
/// environment's own name, `visual-cube-single-v0`, or a user's file).
pub fn env_name(dataset: &str) -> Option<String> {
    let words: Vec<&str> = dataset.split('-').collect();
    let n = words.len();
    if n < 3 || !words[n - 1].starts_with('v') || !DATASET_TYPES.contains(&words[n - 2]) {
        return None;
    }
    let mut env = words[..n - 2].to_vec();
    env.push(words[n - 1]);
    Some(env.join("-"))
}

/// The dataset a file's stem names: a validation file and a shard of a dataset in Horizon
/// Reduction's layout (`NAME-val`, `NAME-17`) name their dataset without their suffix.
pub fn dataset_of_stem(stem: &str) -> &str {
    match stem.rsplit_once('-') {
        Some((name, "val")) => name,
        Some((name, i)) if !i.is_empty() && i.bytes().all(|b| b.is_ascii_digit()) => name,
        _ => stem,
    }
}

impl Dataset {
    /// Opens the file; its environment comes from its name, or from `task` (`--task
    /// pointmaze-medium-v0`) for a file named otherwise; with `full_goal` the goal is the whole
    /// observation ([`GoalMap::full`]).
    pub fn open(path: &Path, task: Option<&str>, full_goal: bool, drop: &[String]) -> Result<Dataset> {
        let at = path.display();
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
        let name = dataset_of_stem(stem).to_string();
        let env = match (task, env_name(&name)) {
            (Some(t), _) => t.to_string(),
            (None, Some(env)) => env,
            (None, None) => bail!(
                "{at}: an OGBench dataset is named after itself (pointmaze-medium-navigate-v0.npz), and {stem:?} names \
                 no environment: give it with --task (pointmaze-medium-v0)"
            ),
        };
        let members = npz::members(path)?;
        let get = |key: &str| members.iter().find(|m| m.key == key);
        let need =
            |key: &str| get(key).cloned().with_context(|| format!("{at}: no {key} array: not an OGBench dataset"));
        let observations = need("observations")?;
        let actions = need("actions")?;
        // A visual dataset's observations are uint8 images [N, H, W, C] (OGBench's 64 × 64 × 3).
        let image = observations.dtype == Dtype::U8 && observations.shape.len() >= 3;
        for m in [&observations, &actions] {
            if (m.key == "observations" && image) || (m.shape.len() == 2 && matches!(m.dtype, Dtype::F32 | Dtype::F64))
            {
                continue;
            }
            bail!(
                "{at}: {}: {} values of shape {:?}; pgser reads float rows [N, dim]{}",
                m.key,
                m.dtype.name(),
                m.shape,
                if m.key == "observations" { ", or uint8 images [N, H, W, C]" } else { "" }
            );
        }
        if image && observations.shape.iter().skip(1).any(|&d| d == 0) {
            bail!("{at}: observations: images of shape {:?} hold no pixels", &observations.shape[1..]);
        }
        if image && full_goal {
            bail!("{at}: --full-goal: observations are images, which no distance on pixels makes a goal of");
        }
        let layout = match (get("next_observations"), get("valids")) {
            (Some(_), _) => Layout::Regular,
            (None, Some(_)) => Layout::Compact,
            (None, None) => Layout::Dataset,
        };
        let keys = goal::goal_members(&env);
        let goal = if full_goal {
            GoalMap::full(observations.row_len())
        } else if !keys.is_empty() {
            let mut widths = Vec::with_capacity(keys.len());
            for &key in keys {
                let m = get(key).with_context(|| {
                    format!("{at}: {env}'s goal is its {key} (OGBench's oracle representation), and the file has none")
                })?;
                if layout == Layout::Regular {
                    bail!(
                        "{at}: {env}'s goal is its {key}, which the regular layout (load_dataset's) holds for \
                         transitions only, not for each episode's last state: convert the dataset file itself"
                    );
                }
                if drop.iter().any(|k| k == key) {
                    bail!("--drop {key}: {env}'s goal is its {key}; it cannot be left out");
                }
                if m.shape.len() != 2 || m.rows() != observations.rows() || m.dtype == Dtype::F16 {
                    bail!(
                        "{at}: {key}: {} values of shape {:?}; {env}'s goal is one row of integers, bools or floats per \
                         row of observations ({})",
                        m.dtype.name(),
                        m.shape,
                        observations.rows()
                    );
                }
                widths.push(m.row_len());
            }
            goal::member_map(&env, &widths).with_context(|| format!("{at}"))?
        } else if image {
            bail!(
                "{at}: observations are images, and {env} is no environment whose goal pgser reads from the dataset's \
                 state (visual-antmaze, visual-humanoidmaze, visual-cube, visual-puzzle, visual-scene)"
            )
        } else {
            goal_map(&env, observations.row_len()).with_context(|| format!("{at}"))?
        };
        let n = observations.rows();
        for m in members.iter().filter(|m| m.key != "observations") {
            if m.rows() != n && ["actions", "terminals", "valids", "next_observations"].contains(&m.key.as_str()) {
                bail!("{at}: {} has {} rows and observations {n}", m.key, m.rows());
            }
        }
        if let Some(next) = get("next_observations")
            && (next.shape != observations.shape || next.dtype != observations.dtype)
        {
            bail!(
                "{at}: next_observations ({:?} {:?}) and observations ({:?} {:?}) differ in shape or dtype: pgser reads \
                 the one as the other shifted by a row",
                next.dtype,
                next.shape,
                observations.dtype,
                observations.shape
            );
        }
        let ends = episode_ends(path, layout, n)?;
        let rows_per_episode = ends[0] + 1;
        for (e, w) in ends.windows(2).enumerate() {
            if w[1] - w[0] != rows_per_episode {
                bail!(
                    "{at}: episode {} has {} rows where episode 0 has {rows_per_episode}: a pgser table holds episodes of one length",
                    e + 1,
                    w[1] - w[0]
                );
            }
        }
        // Every member but the three the table's columns are made of is kept as it is, the
        // episode ends (terminals, valids) included: one value per row of the file, so per
        // observation, or per transition in the regular layout (whose rows are transitions).
        let per = if layout == Layout::Regular { Per::Transition } else { Per::Step };
        let (mut extras, mut dropped) = (Vec::new(), Vec::new());
        let mut next_observations = None;
        for m in members.iter().filter(|m| !["observations", "actions"].contains(&m.key.as_str())) {
            if m.key == "next_observations" {
                next_observations = Some((m.clone(), extras.len()));
                continue;
            }
            if drop.contains(&m.key) {
                dropped.push(m.key.clone());
                continue;
            }
            if m.shape.is_empty() || m.rows() != n {
                bail!(
                    "{at}: {} has shape {:?}, not one row per row of observations ({n}), so no column can keep it; pass \
                     --drop {} to convert without it",
                    m.key,
                    m.shape,
                    m.key
                );
            }
            let spec = Passthrough::new(&at.to_string(), &m.key, m.stored_dtype(), per, m.shape[1..].to_vec())?;
            extras.push((m.clone(), spec));
        }
        if let Some(k) = drop.iter().find(|k| !dropped.contains(k)) {
            bail!(
                "--drop {k}: {at} has no array {k:?} to leave out (observations, actions and next_observations are the table itself)"
            );
        }
        let min = if layout == Layout::Regular { 1 } else { 2 };
        if rows_per_episode < min {
            bail!("{at}: episodes of {rows_per_episode} rows: a pgser episode needs at least one transition");
        }
        Ok(Dataset {
            path: path.to_path_buf(),
            name,
            env,
            layout,
            observations,
            actions,
            rows_per_episode,
            episodes: ends.len(),
            extras,
            next_observations,
            dropped,
            goal,
        })
    }

    /// For the regular layout: whether any row's `next_observations` is not, bit for bit, the
    /// observation after it in its episode (or is stored in another byte order); if so, keeps the
    /// whole array as a passthrough column (per transition, in file order), so that `export`
    /// gives it back rather than the observations shifted, and returns why (the first such row,
    /// by episode and row within it). The table's last observation of an episode is its last
    /// row's next observation either way. Reads both arrays once, a window of episodes at a time.
    pub fn keep_next_observations(&mut self) -> Result<Option<String>> {
        let Some((next, at_extra)) = self.next_observations.clone() else { return Ok(None) };
        let at = self.path.display().to_string();
        let rows = self.rows_per_episode;
        let row = self.observations.row_len() * self.observations.dtype.size;
        let per_window = ((64 << 20) / (rows * row).max(1)).max(1);
        let mut first = None;
        let keys = ["observations".to_string(), "next_observations".to_string()];
        npz::with_members(&self.path, &keys, &mut Vec::new(), &mut |readers| {
            let [obs, nxt] = readers else { unreachable!("two readers") };
            let (mut o, mut n) = (Vec::new(), Vec::new());
            for start in (0..self.episodes).step_by(per_window) {
                let k = per_window.min(self.episodes - start);
                o.resize(k * rows * row, 0);
                n.resize(k * rows * row, 0);
                obs.read_exact(&mut o).with_context(|| format!("{at}: observations are cut short"))?;
                nxt.read_exact(&mut n).with_context(|| format!("{at}: next_observations are cut short"))?;
                for e in 0..k {
                    let base = e * rows * row;
                    let shifted = (0..rows - 1).find(|i| {
                        let r = base + i * row;
                        n[r..r + row] != o[r + row..r + 2 * row]
                    });
                    if let Some(i) = shifted {
                        first = Some((start + e, i));
                        return Ok(());
                    }
                }
            }
            Ok(())
        })?;
        let why = match first {
            Some((e, i)) => format!("episode {e}'s row {i} is not the observation after it"),
            None if next.stored_big_endian != self.observations.stored_big_endian => {
                "they are stored in another byte order than observations".to_string()
            }
            None => return Ok(None),
        };
        let spec = Passthrough::new(&at, &next.key, next.stored_dtype(), Per::Transition, next.shape[1..].to_vec())?;
        self.extras.insert(at_extra, (next, spec));
        Ok(Some(why))
    }

    /// Observations per episode in the table (T).
    pub fn t(&self) -> usize {
        if self.layout == Layout::Regular { self.rows_per_episode + 1 } else { self.rows_per_episode }
    }

    /// The task: OGBench's environment, T from the data, the goal map's goal and metric, and the
    /// success threshold (`--threshold`, else OGBench's).
    pub fn task(&self, threshold: Option<f64>) -> Result<Task> {
        if self.goal.threshold.is_nan() && threshold.is_none() {
            bail!(
                "{}: --full-goal: give --threshold (OGBench's success is measured on its goal map, not on the whole \
                 observation, so no threshold on it is OGBench's)",
                self.path.display()
            );
        }
        let dims = (self.t(), self.observations.row_len(), self.goal.goal_dim(), self.actions.row_len());
        let keys = ["observations", "the goal", "actions"];
        let at = self.path.display().to_string();
        let mut task = crate::trajectory::task_for(
            &at,
            dims,
            keys,
            "rows",
            Some(&self.env),
            threshold.or(Some(self.goal.threshold)),
        )?;
        task.metric = self.goal.metric;
        Ok(task)
    }
}

/// Each episode's last row, from `terminals` (the distributed files; bool, or 0/1 floats) or
/// `valids` (compact: 0 on the last row), read in chunks. A file whose last row ends no episode
/// was cut, and is refused.
fn episode_ends(path: &Path, layout: Layout, n: usize) -> Result<Vec<usize>> {
    let at = path.display();
    let (key, end_when) = match layout {
        Layout::Compact => ("valids", false),
        _ => ("terminals", true),
    };
    npz::with_member(path, key, |r, m| {
        if m.rows() != n || m.row_len() != 1 {
            bail!("{at}: {key} has shape {:?}; one value per observation ({n}) expected", m.shape);
        }
        let size = m.dtype.size;
        let mut ends = Vec::new();
        let mut buf = vec![0u8; 65_536 * size];
        let mut row = 0;
        while row < n {
            let k = (n - row).min(65_536);
            r.read_exact(&mut buf[..k * size]).with_context(|| format!("{at}: {key} is cut short at row {row}"))?;
            for (i, v) in buf[..k * size].chunks_exact(size).enumerate() {
                let flag = match m.dtype {
                    Dtype::BOOL => v[0] != 0,
                    Dtype::F32 => f32::from_le_bytes(v.try_into().expect("4 bytes")) != 0.0,
                    Dtype::F64 => f64::from_le_bytes(v.try_into().expect("8 bytes")) != 0.0,
                    _ => v.iter().any(|&b| b != 0),
                };
                if flag == end_when {
                    ends.push(row + i);
                }
            }
            row += k;
        }
        Ok(ends)
    })
    .and_then(|ends: Vec<usize>| {
        if ends.last() != Some(&(n - 1)) {
            bail!(
                "{at}: the last row ({}) ends no episode ({key}): the file is cut short or not an OGBench dataset",
                n - 1
            );
        }
        Ok(ends)
    })
}

/// `convert`'s plan for an OGBench file, from its headers and episode ends.
pub fn check(opts: &ConvertOptions, path: &Path) -> Result<ConvertPlan> {
    let d = Dataset::open(path, opts.task.as_deref(), opts.full_goal, &opts.drop)?;
    let take = take(opts, &d)?;
    Ok(ConvertPlan {
        task: d.task(opts.threshold)?,
        float_type: float_type(&d, opts.float32),
        image_shape: d.image_shape(),
        row_bytes: d.row_bytes(),
        episodes_in_file: vec![d.episodes],
        episodes_taken: vec![take],
    })
}

fn take(opts: &ConvertOptions, d: &Dataset) -> Result<usize> {
    match opts.episodes.as_deref() {
        None => Ok(d.episodes),
        Some([0]) => bail!("{}: no episodes to write (--episodes 0)", d.path.display()),
        Some([k]) if *k > d.episodes => {
            bail!("{}: --episodes asks for {k} episodes but the file has {}", d.path.display(), d.episodes)
        }
        Some([k]) => Ok(*k),
        Some(ks) => bail!("--episodes has {} values for 1 input: give one count", ks.len()),
    }
}

fn float_type(d: &Dataset, float32: bool) -> FloatType {
    if float32 || (d.goal_value_bytes() == 4 && d.actions.dtype == Dtype::F32) {
        FloatType::Float32
    } else {
        FloatType::Float64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn environments_are_named_as_ogbench_names_them() {
        assert_eq!(env_name("pointmaze-medium-navigate-v0").as_deref(), Some("pointmaze-medium-v0"));
        assert_eq!(env_name("antmaze-giant-stitch-v0").as_deref(), Some("antmaze-giant-v0"));
        assert_eq!(env_name("humanoidmaze-large-navigate-v0").as_deref(), Some("humanoidmaze-large-v0"));
        assert_eq!(env_name("traj"), None);
        assert_eq!(env_name("a-b-c"), None);
        assert_eq!(env_name("scene-play-v0").as_deref(), Some("scene-v0"));
        assert_eq!(env_name("visual-cube-single-play-v0").as_deref(), Some("visual-cube-single-v0"));
        // An environment's own name has no dataset type to drop.
        assert_eq!(env_name("visual-cube-single-v0"), None);
        assert_eq!(dataset_of_stem("humanoidmaze-giant-navigate-v0-17"), "humanoidmaze-giant-navigate-v0");
        assert_eq!(dataset_of_stem("scene-play-v0-val"), "scene-play-v0");
        assert_eq!(dataset_of_stem("scene-play-v0"), "scene-play-v0");
    }
}
