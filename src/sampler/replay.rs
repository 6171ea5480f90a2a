//! The online replay buffer of `pgser-train online`: whole episodes, as HER (baselines) and MRN
//! keep them, sampled with the same HER "future" relabelling as the offline sampler.
//!
//! An episode of the online loop is T environment steps: T + 1 observations and achieved goals,
//! T actions and desired goals. That is the trajectory table's layout with T + 1 rows per
//! episode, so the buffer is held as an [`Episodes`] of that length and sampled by
//! [`sampler::sample`](super::sample) itself (row t relabelled, with probability `her_ratio`, to
//! the achieved goal of a uniform step in t + 1 ..= T of its episode: MRN's
//! `sample_her_transitions`), and saved for `--resume` as a trajectory table any pgser tool
//! can read.
//!
//! Storage follows MRN's `ReplayBuffer._get_storage_idx`: episodes fill the buffer in order;
//! once it is full, each new episode overwrites a uniformly drawn old one (not the oldest).

use std::path::Path;

use anyhow::{Result, bail};

use super::{SamplerConfig, Swap, sample};
use crate::agent::Batch;
use crate::nprandom::NpRandom;
use crate::output::AtomicFile;
use crate::task::Task;
use crate::trajectory::{
    EpisodeArrays, Episodes, FloatArray, FloatType, Footer, KEYS, TrajectoryWriter, WriterOptions,
};

/// Rows per row group of a saved buffer (whole episodes), as `convert` and `collect` default to.
const ROW_GROUP_ROWS: usize = 65_536;

/// Episodes of T environment steps, held as a trajectory table of T + 1 rows per episode.
pub struct Replay {
    pub data: Episodes,
    /// The most episodes held.
    pub capacity: usize,
}

/// The layout of `task`'s online episodes: its T steps make T + 1 observations.
pub fn episode_task(task: &Task) -> Task {
    Task { t: task.t + 1, ..task.clone() }
}

impl Replay {
    /// An empty buffer for `task`'s episodes, holding at most `capacity` of them.
    pub fn new(task: &Task, capacity: usize) -> Replay {
        Replay { data: empty(task), capacity }
    }

    /// Episodes held.
    pub fn len(&self) -> usize {
        self.data.n
    }

    pub fn is_empty(&self) -> bool {
        self.data.n == 0
    }

    /// Adds `new`'s episodes (same layout): appended while there is room, then each over a
    /// uniformly drawn slot among those held before this call (MRN's storage rule, with its
    /// draws from `rng`).
    pub fn store(&mut self, new: &Episodes, rng: &mut NpRandom) {
        let held = self.data.n;
        let room = self.capacity - held.min(self.capacity);
        for e in 0..new.n {
            let slot = if e < room {
                held + e
            } else if held < self.capacity {
                rng.below(held)
            } else {
                rng.below(self.capacity)
            };
            self.put(slot, new, e);
        }
    }

    /// Copies episode `e` of `src` into `slot` (`slot` = `len()` appends).
    fn put(&mut self, slot: usize, src: &Episodes, e: usize) {
        let d = &mut self.data;
        let (t, task) = (d.t, &d.task);
        let parts: [(&mut Vec<f32>, &Vec<f32>, usize); 4] = [
            (&mut d.obs, &src.obs, t * task.obs_dim),
            (&mut d.ag, &src.ag, t * task.goal_dim),
            (&mut d.g, &src.g, (t - 1) * task.goal_dim),
            (&mut d.u, &src.u, (t - 1) * task.act_dim),
        ];
        for (dst, from, len) in parts {
            let values = &from[e * len..(e + 1) * len];
            if slot == dst.len() / len {
                dst.extend_from_slice(values);
            } else {
                dst[slot * len..(slot + 1) * len].copy_from_slice(values);
            }
        }
        d.n = d.n.max(slot + 1);
    }

    /// `n` transitions, each relabelled to a future achieved goal of its episode with
    /// probability `relabel_rate`, rewards recomputed for the goal it ends up with.
    pub fn sample(&self, relabel_rate: f64, rng: &mut NpRandom, n: usize, out: &mut Batch) {
        sample_her(&self.data, relabel_rate, rng, n, out);
    }

    /// Writes the buffer as a trajectory table at `path`, not yet in place (the caller commits
    /// it with the checkpoint it belongs to). `note` goes into the footer's `policy` field, which
    /// `load` checks, so a buffer is never continued with a checkpoint it does not belong to.
    pub fn stage(&self, path: &Path, note: &str, command: &str) -> Result<AtomicFile> {
        let mut footer = Footer::new(&self.data.task, FloatType::Float32, self.data.n, command.to_string());
        footer.policy = Some(note.to_string());
        stage_table(&self.data, path, ROW_GROUP_ROWS, &footer)
    }

    /// The buffer `stage` wrote, checked: `task`'s episodes, no more than `capacity`, and the
    /// footer note `note`.
    pub fn load(path: &Path, task: &Task, capacity: usize, note: &str) -> Result<Replay> {
        let at = path.display();
        if !path.exists() {
            bail!("{at}: the replay buffer of this checkpoint is missing (it is needed to resume)");
        }
        let data = Episodes::load(path)?;
        let want = episode_task(task);
        if (data.task.name.as_str(), data.t, data.task.obs_dim, data.task.goal_dim, data.task.act_dim)
            != (want.name.as_str(), want.t, want.obs_dim, want.goal_dim, want.act_dim)
        {
            bail!(
                "{at}: a buffer of {} episodes of {} rows, not of {} with {} rows",
                data.task.name,
                data.t,
                want.name,
                want.t
            );
        }
        if data.footer.policy.as_deref() != Some(note) {
            bail!(
                "{at}: the buffer is from another point of the run ({}) than its checkpoint ({note})",
                data.footer.policy.as_deref().unwrap_or("no note")
            );
        }
        if data.n > capacity {
            bail!("{at}: {} episodes, more than the buffer's capacity {capacity}", data.n);
        }
        Ok(Replay { data, capacity })
    }
}

/// `n` HER transitions of `data` (episodes in the online layout): the offline sampler with no
/// goal swapping and `relabel_rate` as its HER ratio.
pub fn sample_her(data: &Episodes, relabel_rate: f64, rng: &mut NpRandom, n: usize, out: &mut Batch) {
    let her = SamplerConfig { swap: Swap::None, swap_ratio: 0.0, her_ratio: relabel_rate };
    sample(data, &her, rng, n, out);
}

/// No episodes yet, in the online layout of `task`.
pub fn empty(task: &Task) -> Episodes {
    let task = episode_task(task);
    Episodes {
        footer: Footer::new(&task, FloatType::Float32, 0, String::new()),
        n: 0,
        t: task.t,
        obs: Vec::new(),
        ag: Vec::new(),
        g: Vec::new(),
        u: Vec::new(),
        images: Vec::new(),
        task,
    }
}

/// Writes `d` as a float32 trajectory table at `path` with row groups of about `row_group_rows`
/// rows (whole episodes), not yet in place (the caller commits it). What a replay buffer is saved
/// as, and how tests make tables of coded episodes.
pub fn stage_table(d: &Episodes, path: &Path, row_group_rows: usize, footer: &Footer) -> Result<AtomicFile> {
    let mut w = TrajectoryWriter::create(path, &d.task, FloatType::Float32, WriterOptions::new(row_group_rows))?;
    // A few row groups at a time, so the byte copy beside the episodes stays small; cuts fall
    // on row-group boundaries, so the file does not depend on them.
    let chunk = w.episodes_per_group() * 4;
    let (t, task) = (d.t, &d.task);
    let dims = [(t, task.obs_dim), (t, task.goal_dim), (t - 1, task.act_dim), (t - 1, task.goal_dim)];
    for start in (0..d.n).step_by(chunk.max(1)) {
        let end = (start + chunk).min(d.n);
        let bytes: Vec<Vec<u8>> = [&d.obs, &d.ag, &d.u, &d.g]
            .iter()
            .zip(dims)
            .map(|(v, (steps, dim))| {
                v[start * steps * dim..end * steps * dim].iter().flat_map(|x| x.to_le_bytes()).collect()
            })
            .collect();
        let arrays = std::array::from_fn(|k| FloatArray { data: &bytes[k], size: 4, steps: dims[k].0, dim: dims[k].1 });
        let src = EpisodeArrays {
            origin: path.display().to_string(),
            keys: KEYS,
            arrays,
            episodes: end - start,
            extras: Vec::new(),
        };
        w.append(&src, 0, end - start)?;
    }
    w.finish_staged(footer)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` episodes of FetchReach's online layout whose values say which episode they are.
    fn episodes(n: usize, first: usize) -> Episodes {
        let mut e = empty(&Task::known("FetchReach").unwrap());
        let (t, task) = (e.t, e.task.clone());
        for i in 0..n {
            let v = (first + i) as f32;
            e.obs.extend(std::iter::repeat_n(v, t * task.obs_dim));
            e.ag.extend(std::iter::repeat_n(v, t * task.goal_dim));
            e.g.extend(std::iter::repeat_n(v, (t - 1) * task.goal_dim));
            e.u.extend(std::iter::repeat_n(v / 100.0, (t - 1) * task.act_dim));
        }
        e.n = n;
        e
    }

    #[test]
    fn fills_in_order_then_overwrites_drawn_slots() {
        let task = Task::known("FetchReach").unwrap();
        let mut r = Replay::new(&task, 5);
        let mut rng = NpRandom::new(0);
        r.store(&episodes(3, 0), &mut rng);
        assert_eq!((r.len(), rng.clone()), (3, NpRandom::new(0)), "no draw while there is room");
        // 2 fit (episodes 10, 11 at slots 3, 4); the third goes over one of the 3 held before.
        r.store(&episodes(3, 10), &mut rng);
        assert_eq!(r.len(), 5);
        let first: Vec<f32> = (0..5).map(|e| r.data.obs(e, 0)[0]).collect();
        assert_eq!(&first[3..], &[10.0, 11.0]);
        assert_eq!(first[..3].iter().filter(|&&v| v == 12.0).count(), 1, "{first:?}");
        // Full: every episode replaces a drawn slot; each slot's arrays stay one episode's.
        r.store(&episodes(4, 20), &mut rng);
        for e in 0..5 {
            let v = r.data.obs(e, 0)[0];
            assert!(r.data.ag(e, 50).iter().chain(r.data.goal(e, 49)).all(|&x| x == v));
            assert!(r.data.action(e, 49).iter().all(|&x| x == v / 100.0));
        }
    }

    #[test]
    fn saved_buffers_load_back_exactly_and_only_with_their_note() {
        let task = Task::known("FetchReach").unwrap();
        let mut r = Replay::new(&task, 10);
        r.store(&episodes(7, 3), &mut NpRandom::new(1));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.parquet");
        r.stage(&path, "after cycle 7", "test").unwrap().commit().unwrap();
        let back = Replay::load(&path, &task, 10, "after cycle 7").unwrap();
        assert_eq!((back.len(), back.data.t), (7, 51));
        assert_eq!(
            (&back.data.obs, &back.data.ag, &back.data.g, &back.data.u),
            (&r.data.obs, &r.data.ag, &r.data.g, &r.data.u)
        );
        let err = Replay::load(&path, &task, 10, "after cycle 8").err().unwrap().to_string();
        assert!(err.contains("after cycle 7") && err.contains("another point"), "{err}");
    }
}
