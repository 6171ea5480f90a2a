//! β as a draw sees it: whole episodes it can draw transitions and future goals from, and a way
//! to draw a goal from anywhere in the table.
//!
//! Two things are a view. [`InMemory`] is the whole table held as [`Episodes`]: every episode is
//! resident, and a random goal is an (episode, step) uniform over all its observations. The
//! out-of-core pool (`pool.rs`) holds only some episodes at a time, within a memory budget, and
//! draws random goals from a reservoir fed from the whole table. Samplers written against
//! `View` (pgser's own batches, OGBench's layout) run on either unchanged, so a table larger than
//! memory needs no second sampler.
//!
//! Episode numbers a view hands out (`0..episodes()`) are positions among the resident episodes;
//! [`View::episode_number`] turns one into the table-wide number (in shard order across a
//! folder) that a batch reports as where a row came from.

use std::sync::Arc;

use anyhow::Result;

use crate::nprandom::NpRandom;
use crate::task::Task;
use crate::trajectory::Episodes;

/// Where a random goal came from, and where its vectors can be read in the view that drew it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RandomGoal {
    /// The table-wide episode number of the goal's observation.
    pub episode: u64,
    /// Its step, in `0..t()`.
    pub step: u32,
    /// The view's own handle on the goal's data (a flat row, or a reservoir slot).
    pub slot: u64,
}

/// β as a draw sees it (see the module doc).
pub trait View: Send + Sync {
    fn task(&self) -> &Task;
    /// Resident episodes, numbered `0..episodes()`.
    fn episodes(&self) -> usize;
    /// Observations per episode (T); an episode has T − 1 transitions.
    fn t(&self) -> usize;
    /// o[e, s], s < T.
    fn obs(&self, e: usize, s: usize) -> &[f32];
    /// ag[e, s], s < T.
    fn ag(&self, e: usize, s: usize) -> &[f32];
    /// The desired goal g[e, s], s < T − 1.
    fn goal(&self, e: usize, s: usize) -> &[f32];
    /// u[e, s], s < T − 1.
    fn action(&self, e: usize, s: usize) -> &[f32];
    /// The table-wide number of resident episode `e`.
    fn episode_number(&self, e: usize) -> u64;
    /// An observation drawn uniformly from the whole table (every episode of every shard, every
    /// step `0..T`), as a goal source.
    fn random_goal(&self, rng: &mut NpRandom) -> RandomGoal;
    /// The achieved goal of a source `random_goal` returned.
    fn goal_ag(&self, g: RandomGoal) -> &[f32];
    /// The observation of a source `random_goal` returned.
    fn goal_obs(&self, g: RandomGoal) -> &[f32];
    /// The shape of an image observation, [H, W, C], when the table's observations are images
    /// (then `obs` and `goal_obs` are empty and `image` and `goal_image` hold them); empty for
    /// state observations. Only OGBench's layout opens image tables.
    fn image_shape(&self) -> &[usize];
    /// o[e, s]'s bytes, s < T, of an image table (empty for state observations).
    fn image(&self, e: usize, s: usize) -> &[u8];
    /// The image `back` steps before a source `random_goal` returned, clamped to its episode's
    /// first step (the frames OGBench stacks before a goal; `back` 0 is the goal's own image). A
    /// pool's reservoir keeps the frames its layout was opened with (`Layout::with_frames`):
    /// `back` is less than that.
    fn goal_image(&self, g: RandomGoal, back: usize) -> &[u8];
    /// Called before each batch with the number of transitions it will draw: a pool counts
    /// them and takes in the blocks its loader has read when their turn comes (after as many
    /// draws as the leaving block has transitions), so what is resident depends on the draws
    /// made, never on timing, and never changes in the middle of a batch.
    fn refresh(&mut self, rows: usize) -> Result<()> {
        let _ = rows;
        Ok(())
    }
}

/// The whole table in memory: every episode resident.
impl View for Episodes {
    fn task(&self) -> &Task {
        &self.task
    }
    fn episodes(&self) -> usize {
        self.n
    }
    fn t(&self) -> usize {
        self.t
    }
    fn obs(&self, e: usize, s: usize) -> &[f32] {
        if self.obs.is_empty() { &[] } else { Episodes::obs(self, e, s) }
    }
    fn ag(&self, e: usize, s: usize) -> &[f32] {
        Episodes::ag(self, e, s)
    }
    fn goal(&self, e: usize, s: usize) -> &[f32] {
        Episodes::goal(self, e, s)
    }
    fn action(&self, e: usize, s: usize) -> &[f32] {
        Episodes::action(self, e, s)
    }
    fn episode_number(&self, e: usize) -> u64 {
        e as u64
    }
    /// `swap::random_goal`: one draw of `below(n · t)`, as the in-memory sampler has always made it.
    fn random_goal(&self, rng: &mut NpRandom) -> RandomGoal {
        let (e, s) = crate::swap::random_goal(self.n, self.t, rng);
        RandomGoal { episode: e as u64, step: s as u32, slot: (e * self.t + s) as u64 }
    }
    fn goal_ag(&self, g: RandomGoal) -> &[f32] {
        Episodes::ag(self, g.episode as usize, g.step as usize)
    }
    fn goal_obs(&self, g: RandomGoal) -> &[f32] {
        View::obs(self, g.episode as usize, g.step as usize)
    }
    fn image_shape(&self) -> &[usize] {
        &self.footer.image_shape
    }
    fn image(&self, e: usize, s: usize) -> &[u8] {
        if self.images.is_empty() { &[] } else { Episodes::image(self, e, s) }
    }
    fn goal_image(&self, g: RandomGoal, back: usize) -> &[u8] {
        View::image(self, g.episode as usize, (g.step as usize).saturating_sub(back))
    }
}

/// The whole table in memory, shared.
#[derive(Debug, Clone)]
pub struct InMemory(pub Arc<Episodes>);

impl View for InMemory {
    fn task(&self) -> &Task {
        &self.0.task
    }
    fn episodes(&self) -> usize {
        self.0.n
    }
    fn t(&self) -> usize {
        self.0.t
    }
    fn obs(&self, e: usize, s: usize) -> &[f32] {
        View::obs(&*self.0, e, s)
    }
    fn ag(&self, e: usize, s: usize) -> &[f32] {
        self.0.ag(e, s)
    }
    fn goal(&self, e: usize, s: usize) -> &[f32] {
        self.0.goal(e, s)
    }
    fn action(&self, e: usize, s: usize) -> &[f32] {
        self.0.action(e, s)
    }
    fn episode_number(&self, e: usize) -> u64 {
        e as u64
    }
    fn random_goal(&self, rng: &mut NpRandom) -> RandomGoal {
        View::random_goal(&*self.0, rng)
    }
    fn goal_ag(&self, g: RandomGoal) -> &[f32] {
        View::goal_ag(&*self.0, g)
    }
    fn goal_obs(&self, g: RandomGoal) -> &[f32] {
        View::goal_obs(&*self.0, g)
    }
    fn image_shape(&self) -> &[usize] {
        View::image_shape(&*self.0)
    }
    fn image(&self, e: usize, s: usize) -> &[u8] {
        View::image(&*self.0, e, s)
    }
    fn goal_image(&self, g: RandomGoal, back: usize) -> &[u8] {
        View::goal_image(&*self.0, g, back)
    }
}

/// How much of β a sampler may hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Budget {
    /// The whole table in memory (today's samplers, number for number).
    #[default]
    Unbounded,
    /// At most `bytes`: the whole table when it fits, an out-of-core pool otherwise, which keeps
    /// each block resident for `draws_per_row` draws per transition it holds (1: a pass of draws
    /// reads the table once; 2 reads half as much, for samplers faster than their reading).
    Bytes { bytes: u64, draws_per_row: u32 },
    /// One shard at a time, the next (in folder order) after this many drawn rows, with every
    /// goal from the held shard: Horizon Reduction's reload scheme, emulated to measure what
    /// drawing from the whole table changes (`--shard-window`).
    ShardWindow(u64),
}

impl Budget {
    /// At most `bytes`, each block kept for one draw per transition.
    pub fn bytes(bytes: u64) -> Budget {
        Budget::Bytes { bytes, draws_per_row: 1 }
    }
}

/// A size as `--memory-budget` and `memory_budget=` take it: bytes, or a number with a unit,
/// decimal (`kB`, `MB`, `GB`, `TB`) or binary (`KiB`, `MiB`, `GiB`, `TiB`): "2GB", "1.5 GiB".
pub fn parse_bytes(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let value: f64 = num.parse().map_err(|_| format!("{s:?}: not a size (e.g. 2GB, 512MiB, 1000000000)"))?;
    let scale: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" => 1e3,
        "m" | "mb" => 1e6,
        "g" | "gb" => 1e9,
        "t" | "tb" => 1e12,
        "kib" => 1024.0,
        "mib" => 1024.0 * 1024.0,
        "gib" => 1024.0 * 1024.0 * 1024.0,
        "tib" => 1024.0f64.powi(4),
        u => return Err(format!("{s:?}: unknown unit {u:?} (B, kB, MB, GB, TB, KiB, MiB, GiB, TiB)")),
    };
    let b = value * scale;
    if !b.is_finite() || b < 1.0 || b > u64::MAX as f64 {
        return Err(format!("{s:?}: not a size of at least one byte"));
    }
    Ok(b as u64)
}

/// `memory_budget` as a pipeline's `[train]` or a checkpoint's settings give it: bytes, or a
/// size with a unit ("8GB"), as `--memory-budget` takes it.
pub fn budget_setting<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Option<u64>, D::Error> {
    #[derive(serde::Deserialize)]
    #[serde(untagged)]
    enum Size {
        Bytes(u64),
        Text(String),
    }
    match <Option<Size> as serde::Deserialize>::deserialize(d)? {
        None => Ok(None),
        Some(Size::Bytes(b)) => Ok(Some(b)),
        Some(Size::Text(t)) => parse_bytes(&t).map(Some).map_err(serde::de::Error::custom),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_in_both_unit_systems_and_bad_ones_are_named() {
        assert_eq!(parse_bytes("2GB"), Ok(2_000_000_000));
        assert_eq!(parse_bytes("1.5 GiB"), Ok(1_610_612_736));
        assert_eq!(parse_bytes("512mib"), Ok(512 << 20));
        assert_eq!(parse_bytes("1000"), Ok(1000));
        for bad in ["", "GB", "2XB", "-1GB", "0"] {
            assert!(parse_bytes(bad).is_err(), "{bad:?}");
        }
    }
}
