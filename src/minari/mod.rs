//! Minari datasets (Farama's offline-RL format, the successor of D4RL) in and out of pgser.
//!
//! A Minari dataset is a folder `ID/data/` with a `metadata.json` (counts, spaces, the
//! environment's spec) and its episodes in one of two storages: HDF5, Minari's default
//! (`main_data.hdf5`, a group `episode_{i}` per episode), or Arrow (`{i}/part-0.arrow`, an IPC
//! file per episode). pgser reads goal-conditioned datasets, whose observation is a Dict with
//! `observation`, `achieved_goal` and `desired_goal`, and writes Arrow-storage datasets
//! ([`export`]). docs/minari.md is the user's side of this.
//!
//! An episode of n steps has n + 1 observations and n actions, exactly a WGCSL episode of
//! T = n + 1 (o and ag: T rows, u and g: T − 1). So the episodes become the same four arrays a
//! pickle holds and go through the same [`TrajectoryWriter`]: a table made from a Minari dataset
//! is made by the code path that makes every other table. The desired goal of the last
//! observation has no row in a pgser table (WGCSL keeps T − 1 goals); goal-conditioned
//! environments keep the goal fixed through an episode, and episodes where it changed on the
//! last step are counted in the summary.
//!
//! Minari's storages keep every episode apart, so there is no single array to memory-map as for a
//! pickle: `convert` reads a window of episodes at a time (the rows of a few row groups per
//! thread) and writes them before reading on, so its memory does not grow with the dataset.

mod arrow_storage;
mod export;
#[cfg(feature = "hdf5")]
mod hdf5_storage;
mod infos;
mod metadata;
mod space;

use std::path::Path;

use anyhow::{Result, bail};
use indicatif::ProgressBar;

pub use export::{ExportFormat, ExportOptions, ExportSummary, export};
pub use metadata::{Metadata, Storage, data_folder, read_metadata, sha256_folder};
pub use space::{BoxSpace, Spaces};

use crate::task::Task;
use crate::trajectory::{
    ConvertOptions, ConvertPlan, ConvertSummary, EpisodeArrays, ExtraArray, FloatArray, FloatType, Footer, Passthrough,
    Per, SourceFile, TrajectoryWriter, WriterOptions,
};

/// The Dict observation's keys pgser needs, in the order [`Episode::arrays`] holds them (after
/// which come the actions).
pub const OBS_KEYS: [&str; 3] = ["observation", "achieved_goal", "desired_goal"];

/// Minari's names of the arrays pgser reads as o, ag, u and g, as error messages give them.
pub const ARRAY_KEYS: [&str; 4] =
    ["observations/observation", "observations/achieved_goal", "actions", "observations/desired_goal"];

/// One episode of n steps as read from storage: observation, achieved_goal and desired_goal
/// (n + 1 rows each) and actions (n rows), as little-endian bytes of the spaces' float types.
pub(crate) struct Episode {
    pub steps: usize,
    pub arrays: [Vec<u8>; 4],
    /// The episode's infos, a row per observation (or per step), each key's bytes.
    pub infos: Vec<infos::Info>,
    /// Its rewards, terminations and truncations as recorded (those it has), a row per step.
    pub outcomes: Vec<infos::Info>,
    /// The Dict observation's other keys ([`Metadata::extra_obs`], in that order), a row per
    /// observation.
    pub obs_extras: Vec<infos::Info>,
    /// Every passthrough column the episode holds (`infos/KEY`, `observations/KEY`, `rewards`, …),
    /// those `--drop` names too, which the readers leave unread: what checks that every episode
    /// has the same columns.
    pub present: Vec<String>,
}

/// Where a passthrough column of a Minari dataset comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Info,
    Outcome,
    Obs,
}

/// What a Minari episode records of each step besides its observation and action: kept as
/// passthrough columns under these names, so that `export` gives them back as recorded rather
/// than recomputed.
pub const OUTCOMES: [&str; 3] = ["rewards", "terminations", "truncations"];

/// Reads the episodes of one storage; both check every array against the spaces, naming the
/// episode and key of a fault.
enum Reader {
    Arrow(arrow_storage::Reader),
    #[cfg(feature = "hdf5")]
    Hdf5(hdf5_storage::Reader),
}

impl Reader {
    /// A reader that leaves the columns `drop` names unread.
    fn open(meta: &Metadata, drop: &[String]) -> Result<Reader> {
        match meta.storage {
            Storage::Arrow => Ok(Reader::Arrow(arrow_storage::Reader::new(meta, drop))),
            #[cfg(feature = "hdf5")]
            Storage::Hdf5 => Ok(Reader::Hdf5(hdf5_storage::Reader::open(meta, drop)?)),
            #[cfg(not(feature = "hdf5"))]
            Storage::Hdf5 => bail!(
                "{}: a Minari dataset in HDF5 storage, and this pgser was built without HDF5 support \
                 (--no-default-features): build it with the default features (`make build`, which compiles \
                 HDF5 from source), or save the dataset with Minari's Arrow storage",
                meta.data.display()
            ),
        }
    }

    fn episode(&mut self, i: usize) -> Result<Episode> {
        match self {
            Reader::Arrow(r) => r.episode(i),
            #[cfg(feature = "hdf5")]
            Reader::Hdf5(r) => r.episode(i),
        }
    }
}

/// A dataset opened for reading, its episodes streamed a window at a time: memory holds one
/// window of episodes, never the dataset (Minari datasets run to millions of steps).
struct Source {
    meta: Metadata,
    reader: Reader,
    /// Episode 0, read to learn T; the first window starts with it.
    first: Option<Episode>,
    /// Bytes per value of o, ag, u, g.
    sizes: [usize; 4],
    /// Episodes to take.
    episodes: usize,
    t: usize,
    /// Steps left out at the end of each episode (0 or 1) so that episodes fit the task's T.
    dropped: usize,
    /// Episodes whose last observation's desired goal differs from the step before's.
    goal_changed_last: usize,
    /// The infos keys kept as passthrough columns (`infos/KEY`), the rewards, terminations and
    /// truncations, and the Dict observation's other keys (`observations/KEY`): where it comes
    /// from and its record ([`Source::keep_infos`]).
    infos: Vec<(Kind, Passthrough)>,
    /// The columns `--drop` names and whether an episode read so far holds each: one no episode
    /// taken holds is refused once all are read.
    drops: Vec<(String, bool)>,
}

/// One window of episodes as the four WGCSL arrays: o, ag, u, g: `[N, T, obs]`, `[N, T, goal]`,
/// `[N, T−1, act]`, `[N, T−1, goal]`.
#[derive(Default)]
struct Window {
    arrays: [Vec<u8>; 4],
    /// The kept infos keys' rows, in [`Source::infos`]' order.
    extras: Vec<Vec<u8>>,
    episodes: usize,
}

impl Source {
    /// Reads the metadata and episode 0 (for T); checks the count to take. The columns `drop`
    /// names are left unread.
    fn open(dir: &Path, take: Option<usize>, drop: &[String]) -> Result<Source> {
        let meta = read_metadata(dir)?;
        let at = meta.data.display().to_string();
        if meta.total_episodes == 0 {
            bail!("{at}: the dataset has no episodes (total_episodes 0)");
        }
        let episodes = match take {
            Some(k) if k > meta.total_episodes => {
                bail!("{at}: --episodes asks for {k} episodes but the dataset has {}", meta.total_episodes)
            }
            Some(0) => bail!("{at}: no episodes to write (--episodes 0)"),
            Some(k) => k,
            None => meta.total_episodes,
        };
        let s = &meta.spaces;
        let sizes = [s.obs[0].size, s.obs[1].size, s.action.size, s.obs[2].size];
        let mut reader = Reader::open(&meta, drop)?;
        let first = reader.episode(0)?;
        if first.steps == 0 {
            bail!("{at}: episode 0 has no steps; a pgser episode needs at least one action");
        }
        let t = first.steps + 1;
        Ok(Source {
            meta,
            reader,
            first: Some(first),
            sizes,
            episodes,
            t,
            dropped: 0,
            goal_changed_last: 0,
            infos: Vec::new(),
            drops: drop.iter().map(|d| (d.clone(), false)).collect(),
        })
    }

    /// Which of episode 0's infos keys become passthrough columns, once T is known: all but those
    /// `--drop` names (`infos/KEY`, left unread), each a row per observation (per step) or per
    /// action (per transition); what a column cannot keep is refused by name. Every other episode
    /// must hold the same columns ([`Source::read`]).
    fn keep_infos(&mut self) -> Result<()> {
        let at = self.meta.data.display().to_string();
        let first = self.first.as_ref().expect("before the first window");
        let mut kept = Vec::new();
        let all = first.infos.iter().map(|info| (Kind::Info, info, format!("infos/{}", info.key)));
        let outcomes = first.outcomes.iter().map(|o| (Kind::Outcome, o, o.key.clone()));
        let obs = first.obs_extras.iter().map(|o| (Kind::Obs, o, format!("observations/{}", o.key)));
        for (kind, info, column) in obs.chain(all).chain(outcomes) {
            // With its last step dropped (a time limit's extra step), an episode no longer ends
            // where its recorded terminations and truncations say: those, and the rewards with
            // them, are made anew by an export, as for any table.
            if kind == Kind::Outcome && self.dropped > 0 {
                continue;
            }
            let per = if info.rows == first.steps + 1 {
                Per::Step
            } else if info.rows == first.steps {
                Per::Transition
            } else {
                bail!(
                    "{at}: episode 0's `{column}` has {} rows for {} steps (a row per observation or per step expected); \
                     pass --drop {column} to convert without it",
                    info.rows,
                    first.steps
                );
            };
            let mut p = Passthrough::new(&at, &column, info.dtype, per, info.shape.clone())?;
            if kind == Kind::Obs {
                if per != Per::Step {
                    bail!(
                        "{at}: episode 0's `{column}` has {} rows for {} steps; pass --drop {column}",
                        info.rows,
                        first.steps
                    );
                }
                let space =
                    self.meta.extra_obs.iter().find(|o| o.0 == info.key).map(|o| o.1.clone()).unwrap_or_default();
                // Arrow storage flattens a Box's values: its shape is the space's.
                if let Some(shape) = space::box_shape(&space).filter(|s| s.iter().product::<usize>() == p.len()) {
                    p.shape = shape;
                }
                p.space = Some(space);
            }
            kept.push((kind, p));
        }
        let present = first.present.clone();
        self.infos = kept;
        self.note_drops(&present);
        Ok(())
    }

    /// Marks the `--drop` columns an episode holds.
    fn note_drops(&mut self, present: &[String]) {
        for (d, seen) in &mut self.drops {
            *seen |= present.contains(d);
        }
    }

    /// The columns left out by `--drop`, once every episode taken is read; a `--drop` of a column
    /// no episode holds is refused (a misspelt key would otherwise pass unnoticed).
    fn dropped(&self) -> Result<Vec<String>> {
        if let Some((d, _)) = self.drops.iter().find(|(_, seen)| !seen) {
            bail!(
                "--drop {d}: {} has no infos key, observation key or recorded outcome {d:?} in the {} episodes taken",
                self.meta.data.display(),
                self.episodes
            );
        }
        Ok(self.drops.iter().map(|(d, _)| d.clone()).collect())
    }

    /// Reads episodes `range` into `w` (replacing what it held), checking each has T − 1 steps
    /// (plus the dropped one).
    fn read(&mut self, range: std::ops::Range<usize>, w: &mut Window) -> Result<()> {
        let at = self.meta.data.display().to_string();
        let steps = self.t - 1 + self.dropped;
        let sp = &self.meta.spaces;
        let row = |b: &BoxSpace| b.dim * b.size;
        let (obs_row, ag_row, goal_row, act_row) = (row(&sp.obs[0]), row(&sp.obs[1]), row(&sp.obs[2]), row(&sp.action));
        // The rows kept: the first T observations and T − 1 actions of each episode.
        let t = self.t;
        w.arrays.iter_mut().for_each(Vec::clear);
        w.extras = vec![Vec::new(); self.infos.len()];
        w.episodes = range.len();
        for i in range {
            let ep = match self.first.take().filter(|_| i == 0) {
                Some(first) => first,
                None => self.reader.episode(i)?,
            };
            if ep.steps != steps {
                bail!(
                    "{at}: episode {i} has {} steps where episode 0 has {steps}: a pgser table holds episodes of \
                     one length (T = {} observations); --episodes {i} takes the episodes before it",
                    ep.steps,
                    self.t
                );
            }
            // A column episode 0 lacks has no place in the table: refused by name, as one it has
            // and this episode lacks is below (the outcomes of a dropped last step are left out
            // whole).
            let skip = |c: &String| OUTCOMES.contains(&c.as_str()) && self.dropped > 0;
            if let Some(c) = ep.present.iter().find(|c| {
                !skip(c) && !self.infos.iter().any(|(_, p)| &p.column == *c) && !self.drops.iter().any(|d| &d.0 == *c)
            }) {
                bail!(
                    "{at}: episode {i} has `{c}`, which episode 0 lacks: a table's episodes all have the same columns; \
                     pass --drop {c} to convert without it"
                );
            }
            self.note_drops(&ep.present);
            for ((kind, p), out) in self.infos.iter().zip(&mut w.extras) {
                let info = match kind {
                    Kind::Outcome => ep.outcomes.iter().find(|i| i.key == p.column),
                    Kind::Info => ep.infos.iter().find(|i| format!("infos/{}", i.key) == p.column),
                    Kind::Obs => ep.obs_extras.iter().find(|i| format!("observations/{}", i.key) == p.column),
                };
                let want_rows = if p.per == Per::Step { ep.steps + 1 } else { ep.steps };
                let Some(info) = info.filter(|i| {
                    i.dtype == p.dtype
                        && (i.shape == p.shape || (*kind == Kind::Obs && i.shape.iter().product::<usize>() == p.len()))
                        && i.rows == want_rows
                }) else {
                    let what = if info.is_none() { "is missing" } else { "is not episode 0's" };
                    bail!(
                        "{at}: episode {i}'s `{}` {what} ({} of shape {:?}, {want_rows} rows): a table's episodes all have \
                         the same columns; pass --drop {} to convert without it",
                        p.column,
                        p.dtype,
                        p.shape,
                        p.column
                    );
                };
                let row = info.bytes.len() / info.rows.max(1);
                out.extend_from_slice(&info.bytes[..p.per.rows(t) * row]);
            }
            let [obs, ag, dg, act] = ep.arrays;
            let (goals, last) = dg[..t * goal_row].split_at((t - 1) * goal_row);
            self.goal_changed_last += usize::from(last != &goals[goals.len() - goal_row..]);
            w.arrays[0].extend_from_slice(&obs[..t * obs_row]);
            w.arrays[1].extend_from_slice(&ag[..t * ag_row]);
            w.arrays[2].extend_from_slice(&act[..(t - 1) * act_row]);
            w.arrays[3].extend_from_slice(goals);
        }
        Ok(())
    }

    fn view<'a>(&self, w: &'a Window) -> EpisodeArrays<'a> {
        let s = &self.meta.spaces;
        let dims = [s.obs[0].dim, s.obs[1].dim, s.action.dim, s.obs[2].dim];
        let steps = [self.t, self.t, self.t - 1, self.t - 1];
        let arrays = std::array::from_fn(|k| FloatArray {
            data: &w.arrays[k],
            size: self.sizes[k],
            steps: steps[k],
            dim: dims[k],
        });
        let extras = self
            .infos
            .iter()
            .zip(&w.extras)
            .map(|((_, p), data)| ExtraArray { spec: p.clone(), data: std::borrow::Cow::Borrowed(&data[..]) })
            .collect();
        EpisodeArrays {
            origin: self.meta.data.display().to_string(),
            keys: ARRAY_KEYS,
            arrays,
            episodes: w.episodes,
            extras,
        }
    }

    /// float64 when any array is (float32 widens exactly), float32 when all are or `--float32`.
    fn float_type(&self, float32: bool) -> FloatType {
        if float32 || self.sizes.iter().all(|&s| s == 4) { FloatType::Float32 } else { FloatType::Float64 }
    }

    /// `--task`, else the env spec's id, else what pgser's export recorded, else the dimensions.
    ///
    /// An episode one step longer than the task's (T + 1 observations) is what gymnasium's time
    /// limit records for a Fetch task (`minari.DataCollector(gym.make("FetchReach-v4"))`: 50
    /// steps, 51 observations; WGCSL's episodes, which pgser's tasks follow, have 50
    /// observations). Unless `exact_length`, its last step is dropped to fit (`dropped`, said in
    /// the summary's notes and the footer's source entry).
    fn task(&mut self, name: Option<&str>, threshold: Option<f64>, exact_length: bool) -> Result<Task> {
        let name = name.or(self.meta.env_id.as_deref()).or(self.meta.pgser_task.as_ref().map(|r| r.0.as_str()));
        if let Some(known) = name.and_then(Task::known)
            && known.t + 1 == self.t
            && !exact_length
            && self.dropped == 0
        {
            (self.t, self.dropped) = (known.t, 1);
        }
        let s = &self.meta.spaces;
        let dims = (self.t, s.obs[0].dim, s.obs[1].dim, s.action.dim);
        let keys = ["observation", "achieved_goal", "actions"];
        let at = self.meta.data.display().to_string();
        let unit = "observations (Minari steps + 1)";
        let recorded = self.meta.pgser_task.as_ref();
        let name = name.or(self.meta.env_id.as_deref()).or(recorded.map(|r| r.0.as_str()));
        let custom = name.is_some_and(|n| Task::known(n).is_none());
        // A custom task pgser exported keeps its threshold and metric without flags.
        let from_export = recorded.filter(|r| custom && threshold.is_none() && Some(r.0.as_str()) == name);
        let threshold = threshold.or(from_export.map(|r| r.1));
        let mut task = crate::trajectory::task_for(&at, dims, keys, unit, name, threshold)?;
        if let Some(r) = from_export {
            task.metric = r.2;
        }
        Ok(task)
    }
}

/// `convert`'s plan for a Minari dataset, from its metadata and first episode: the task, the
/// float type and the counts. The other episodes are checked as `convert` reads them (a fault
/// there leaves no output either).
pub fn check(opts: &ConvertOptions, dir: &Path) -> Result<ConvertPlan> {
    let take = take_option(opts)?;
    let mut source = Source::open(dir, take, &opts.drop)?;
    let task = source.task(opts.task.as_deref(), opts.threshold, opts.exact_length)?;
    source.keep_infos()?;
    Ok(ConvertPlan {
        task,
        float_type: source.float_type(opts.float32),
        image_shape: Vec::new(),
        row_bytes: 0,
        episodes_in_file: vec![source.meta.total_episodes],
        episodes_taken: vec![source.episodes],
    })
}

fn take_option(opts: &ConvertOptions) -> Result<Option<usize>> {
    match opts.episodes.as_deref() {
        None => Ok(None),
        Some([k]) => Ok(Some(*k)),
        Some(ks) => bail!("--episodes has {} values for 1 input: give one count", ks.len()),
    }
}

/// `pgser-etl convert DIR -o out.parquet` for a Minari dataset folder, a window of episodes at a
/// time (the rows of a few row groups per thread), so memory does not grow with the dataset.
pub fn convert(opts: &ConvertOptions, dir: &Path, bar: &ProgressBar) -> Result<ConvertSummary> {
    crate::output::check_not_an_input(&opts.output, &opts.inputs)?;
    let take = take_option(opts)?;
    let mut source = Source::open(dir, take, &opts.drop)?;
    let task = source.task(opts.task.as_deref(), opts.threshold, opts.exact_length)?;
    let float_type = source.float_type(opts.float32);
    // Hashed before the table's temporary file exists, which may be in the dataset's folder.
    let sha256 = sha256_folder(&source.meta.data)?;
    source.keep_infos()?;
    let specs: Vec<Passthrough> = source.infos.iter().map(|(_, p)| p.clone()).collect();
    let kept = specs.iter().map(crate::trajectory::describe).collect();
    let options = WriterOptions {
        allow_nonfinite: opts.allow_nonfinite,
        extras: specs,
        ..WriterOptions::new(opts.row_group_rows)
    };
    let mut writer = TrajectoryWriter::create(&opts.output, &task, float_type, options)?;
    let window = writer.episodes_per_group() * rayon::current_num_threads().max(1) * 2;
    bar.set_length(source.episodes as u64);
    let mut w = Window::default();
    for start in (0..source.episodes).step_by(window) {
        let end = (start + window).min(source.episodes);
        source.read(start..end, &mut w)?;
        writer.append(&source.view(&w), 0, w.episodes)?;
        crate::progress::advance(bar, w.episodes as u64)?;
    }
    let dropped_infos = source.dropped()?;
    let mut footer = Footer::new(&task, float_type, source.episodes, opts.command.clone());
    footer.sources = vec![SourceFile {
        path: dir.display().to_string(),
        sha256,
        format: source.meta.storage.format_name().into(),
        episodes_in_file: source.meta.total_episodes,
        episodes_taken: source.episodes,
        steps_dropped: source.dropped,
        float_bytes: {
            // o, ag, g, u as the footer orders them; Source::sizes holds o, ag, u, g.
            let s = [source.sizes[0], source.sizes[1], source.sizes[3], source.sizes[2]];
            let table = if float_type == FloatType::Float32 { 4 } else { 8 };
            if s.iter().all(|&b| b == table) { Vec::new() } else { s.to_vec() }
        },
    }];
    let bytes = writer.finish(&footer)?;
    let skipped_keys = dropped_infos.iter().map(|k| format!("{}: {k}", dir.display())).collect();
    let mut notes = Vec::new();
    if source.dropped > 0 {
        notes.push(format!(
            "{}: episodes have {} steps and {} has T = {} observations ({} steps): dropped each episode's last \
             step to fit (gymnasium's time limit records one step more than WGCSL's episodes; --exact-length refuses instead), and with it the recorded rewards, terminations and truncations, which no longer end the episodes (export makes them anew)",
            dir.display(),
            task.t,
            task.name,
            task.t,
            task.t - 1
        ));
    }
    if source.goal_changed_last > 0 {
        notes.push(format!(
            "{}: the last observation's desired goal (no row in a pgser table) differs from the step before's \
             in {} episodes",
            dir.display(),
            source.goal_changed_last
        ));
    }
    Ok(ConvertSummary {
        task,
        float_type,
        episodes: source.episodes,
        rows: source.episodes * footer.t,
        bytes,
        skipped_keys,
        kept,
        notes,
    })
}
