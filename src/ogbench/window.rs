//! One window of an OGBench file's episodes, read from the streams of its members side by side
//! and laid out as a trajectory table's rows: what `convert` appends a window at a time, so that
//! memory holds a window, not the dataset.

use std::io::Read;

use anyhow::{Context, Result};

use super::goal::{GoalMap, MemberRows};
use super::{ARRAY_KEYS, Dataset, Layout};
use crate::trajectory::{EpisodeArrays, ExtraArray, FloatArray, Passthrough};

/// One window of episodes as the four WGCSL arrays, in the file's float types (u with each
/// episode's last action where the file has one), and the passthrough members' rows.
pub(super) struct Window {
    t: usize,
    goal: GoalMap,
    layout: Layout,
    obs: (usize, usize),
    act: (usize, usize),
    /// Bytes per goal value ([`Dataset::goal_value_bytes`]).
    goal_size: usize,
    arrays: [Vec<u8>; 4],
    raw_obs: Vec<u8>,
    raw_act: Vec<u8>,
    raw_next: Vec<u8>,
    /// Each passthrough member's spec and bytes per file row, and the window's rows of it.
    extras: Vec<(Passthrough, usize, Vec<u8>)>,
    /// The passthrough members the goal is read from (a puzzle's `button_states`, a visual
    /// scene's `qpos` and `button_states`), by their index, in the goal map's order; empty: the
    /// goal is observation values.
    goal_members: Vec<usize>,
}

impl Window {
    pub(super) fn new(d: &Dataset) -> Window {
        Window {
            t: d.t(),
            goal: d.goal.clone(),
            layout: d.layout,
            obs: (d.observations.row_len(), d.observations.dtype.size),
            act: (d.actions.row_len(), d.actions.dtype.size),
            goal_size: d.goal_value_bytes(),
            arrays: Default::default(),
            raw_obs: Vec::new(),
            raw_act: Vec::new(),
            raw_next: Vec::new(),
            extras: d.extras.iter().map(|(m, p)| (p.clone(), m.row_len() * m.dtype.size, Vec::new())).collect(),
            goal_members: d
                .goal
                .members
                .iter()
                .map(|k| d.extras.iter().position(|(m, _)| &m.key == k).expect("a goal member is a passthrough member"))
                .collect(),
        }
    }

    /// Reads the next `k` episodes from the streams.
    pub(super) fn read(
        &mut self,
        obs: &mut dyn Read,
        act: &mut dyn Read,
        next: &mut Option<&mut dyn Read>,
        extras: &mut [&mut dyn Read],
        k: usize,
    ) -> Result<()> {
        let (t, (od, os), (ad, asz)) = (self.t, self.obs, self.act);
        let file_rows = if self.layout == Layout::Regular { t - 1 } else { t };
        self.raw_obs.resize(k * file_rows * od * os, 0);
        self.raw_act.resize(k * file_rows * ad * asz, 0);
        obs.read_exact(&mut self.raw_obs).context("observations are cut short")?;
        act.read_exact(&mut self.raw_act).context("actions are cut short")?;
        if let Some(n) = next.as_mut() {
            self.raw_next.resize(self.raw_obs.len(), 0);
            n.read_exact(&mut self.raw_next).context("next_observations are cut short")?;
        }
        for ((p, row_bytes, buf), r) in self.extras.iter_mut().zip(extras.iter_mut()) {
            buf.resize(k * file_rows * *row_bytes, 0);
            r.read_exact(buf).with_context(|| format!("{} is cut short", p.column))?;
        }
        let (orow, arow, grow) = (od * os, ad * asz, self.goal.goal_dim() * self.goal_size);
        self.arrays.iter_mut().for_each(Vec::clear);
        for e in 0..k {
            let o = &self.raw_obs[e * file_rows * orow..(e + 1) * file_rows * orow];
            let a = &self.raw_act[e * file_rows * arow..(e + 1) * file_rows * arow];
            let start = self.arrays[0].len();
            self.arrays[0].extend_from_slice(o);
            if self.layout == Layout::Regular {
                // The episode's last observation is its last row's next observation.
                let n = &self.raw_next[e * file_rows * orow..(e + 1) * file_rows * orow];
                self.arrays[0].extend_from_slice(&n[(file_rows - 1) * orow..]);
            }
            let mut ag = Vec::with_capacity(t * grow);
            if self.goal_members.is_empty() {
                self.goal.map_bytes(&self.arrays[0][start..], od, os, &mut ag);
            } else {
                // The members' rows (one per observation: the regular layout is refused for them).
                let rows: Vec<MemberRows<'_>> = self
                    .goal_members
                    .iter()
                    .map(|&i| {
                        let (p, row_bytes, buf) = &self.extras[i];
                        let bytes = &buf[e * file_rows * row_bytes..(e + 1) * file_rows * row_bytes];
                        MemberRows { bytes, dtype: p.dtype, row_len: p.shape.iter().product() }
                    })
                    .collect();
                self.goal.member_goal_rows(&rows, self.goal_size, &mut ag);
            }
            let last = ag[(t - 1) * grow..].to_vec();
            self.arrays[1].extend_from_slice(&ag);
            // Every row's action: T of them where rows are observations (the last one kept on the
            // last step), T − 1 where rows are transitions.
            self.arrays[2].extend_from_slice(a);
            for _ in 0..t - 1 {
                self.arrays[3].extend_from_slice(&last);
            }
        }
        Ok(())
    }

    pub(super) fn view<'a>(&'a self, at: &str, k: usize) -> EpisodeArrays<'a> {
        let (t, (od, os), (ad, asz)) = (self.t, self.obs, self.act);
        let g = self.goal.goal_dim();
        let act_steps = if self.layout == Layout::Regular { t - 1 } else { t };
        let gs = self.goal_size;
        let spec = [(t, od, os), (t, g, gs), (act_steps, ad, asz), (t - 1, g, gs)];
        let arrays = std::array::from_fn(|i| FloatArray {
            data: &self.arrays[i],
            size: spec[i].2,
            steps: spec[i].0,
            dim: spec[i].1,
        });
        let extras = self
            .extras
            .iter()
            .map(|(p, _, buf)| ExtraArray { spec: p.clone(), data: std::borrow::Cow::Borrowed(&buf[..]) })
            .collect();
        EpisodeArrays { origin: at.to_string(), keys: ARRAY_KEYS, arrays, episodes: k, extras }
    }
}
