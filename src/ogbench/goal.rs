//! The goal map φ of OGBench's environments: which observation values are the goal, and when it
//! is reached, as OGBench's own success test has it.
//!
//! - Locomotion mazes (pointmaze, antmaze, humanoidmaze): the observation starts with the agent's
//!   x, y; success is a distance of at most `goal_tol` (1.0 for the point, 0.5 for the ant and the
//!   humanoid).
//! - Cube (cube-single … cube-quadruple): the observation is 19 values of the arm and gripper,
//!   then 9 per cube: its position (x, y, z) centred on (0.425, 0, 0) and scaled by 10, its
//!   quaternion, and the cosine and sine of its yaw (`CubeEnv.compute_observation`). The goal is
//!   the cubes' positions (what OGBench's `oraclerep` datasets hold), and it is reached when every
//!   cube is within 0.04 m of its target (`_compute_successes`), i.e. 0.4 in the observation's
//!   scaled units: [`GoalMetric::EachObject`].
//!
//! - Puzzle (puzzle-3x3 … puzzle-4x6): the goal is the buttons' states, the file's
//!   `button_states` member (OGBench's oracle representation of a puzzle, `add_oracle_reps`), as
//!   floats; it is reached when every button is in its target state (`_compute_successes`): 0/1
//!   values within 0.5 of their targets, [`GoalMetric::EachValue`]. It is not part of the
//!   observation, so the goal map names the member ([`GoalMap::member`]).
//!
//! - Scene (scene-play …): 19 arm and gripper values, 9 per cube as in the cube scenes, then 4
//!   per button (its state one-hot, its position, its velocity), then the drawer's position ×18
//!   and velocity, the window's position ×15 and velocity (`SceneEnv.compute_observation`). The
//!   goal is OGBench's oracle representation (`compute_oracle_observation`): the cubes'
//!   positions, each button's state (the one-hot's second value: 1 when the state is 1), the
//!   drawer's and the window's positions, read from the observation, so the regular layout keeps
//!   its goals too; each part is reached within its own tolerance ([`GoalMetric::Scene`]).
//!
//! - Visual datasets (`visual-antmaze-*`, `visual-cube-*`, `visual-puzzle-*`, `visual-scene-*`):
//!   observations are images, so the goal is the oracle representation read from the file's
//!   state ([`member_map`]): the agent's x, y from `qpos`, the cubes' positions from `qpos`
//!   centred and scaled as a state observation has them, the buttons' states, and a scene's
//!   cube, buttons, drawer and window from `qpos` and `button_states` both.
//!
//! OGBench evaluates with full-observation goals (`info["goal"]` is the goal state's whole
//! observation); φ of that observation is the goal a pgser agent takes (examples/ogbench_eval.py).
//! `convert --full-goal` makes the whole observation the goal instead ([`GoalMap::full`]), with
//! the user's threshold.

use std::ops::Range;

use anyhow::{Context, Result, bail};

use crate::task::GoalMetric;

/// Values of the arm and gripper before the cubes in a cube observation, and values per cube.
const CUBE_PROPRIO: usize = 19;
const CUBE_VALUES: usize = 9;
/// A scene observation's values per button (its state one-hot over 2 states, position,
/// velocity) and after the buttons (drawer position and velocity, window position and velocity).
const BUTTON_VALUES: usize = 4;
const SCENE_TAIL: usize = 4;

#[derive(Debug, Clone, PartialEq)]
pub struct GoalMap {
    /// The observation's goal values, in order; with `member`, that member's row.
    pub ranges: Vec<Range<usize>>,
    pub threshold: f64,
    pub metric: GoalMetric,
    /// The file's members the goal is read from, where it is not part of the observation (a
    /// puzzle's `button_states`, a visual environment's `qpos`, a visual scene's both); empty:
    /// the goal is observation values.
    pub members: Vec<String>,
    /// Per range, the index in `members` of the member it reads; empty: the first.
    pub range_member: Vec<usize>,
    /// Per goal value, (centre, scale): the value is (x − centre) · scale, as OGBench's oracle
    /// representation of a cube is its position centred on the workspace and scaled by 10.
    /// Empty: the values as they are.
    pub affine: Vec<(f64, f64)>,
}

impl GoalMap {
    /// The whole observation as the goal (`convert --full-goal`), Euclidean; its threshold must
    /// be given (NaN until then).
    pub fn full(obs_dim: usize) -> GoalMap {
        // One range: the goal is the whole observation (a Vec of ranges, not a range of values).
        #[allow(clippy::single_range_in_vec_init)]
        let ranges = vec![0..obs_dim];
        GoalMap::of_observations(ranges, f64::NAN, GoalMetric::Euclidean)
    }

    /// Observation values `ranges` as the goal.
    fn of_observations(ranges: Vec<Range<usize>>, threshold: f64, metric: GoalMetric) -> GoalMap {
        GoalMap { ranges, threshold, metric, members: Vec::new(), range_member: Vec::new(), affine: Vec::new() }
    }

    /// Values `ranges` of one member's rows as the goal, each value affine-mapped by `affine`.
    fn of_member(
        key: &str,
        ranges: Vec<Range<usize>>,
        threshold: f64,
        metric: GoalMetric,
        affine: Vec<(f64, f64)>,
    ) -> GoalMap {
        GoalMap { ranges, threshold, metric, members: vec![key.to_string()], range_member: Vec::new(), affine }
    }

    /// A member's whole row of `width` values as the goal (a puzzle's `button_states`).
    pub fn member(key: &str, width: usize, threshold: f64, metric: GoalMetric) -> GoalMap {
        // One range: the member's whole row.
        #[allow(clippy::single_range_in_vec_init)]
        let ranges = vec![0..width];
        GoalMap::of_member(key, ranges, threshold, metric, Vec::new())
    }

    /// Whether the goal is read from members of the file rather than from observations.
    pub fn from_members(&self) -> bool {
        !self.members.is_empty()
    }

    /// The member range `i` reads.
    pub fn member_of(&self, i: usize) -> &str {
        &self.members[self.range_member.get(i).copied().unwrap_or(0)]
    }

    pub fn goal_dim(&self) -> usize {
        self.ranges.iter().map(Range::len).sum()
    }

    /// φ of observation rows of `size`-byte values (one row of `obs_dim` values each): the goal
    /// rows, appended to `out` (not for a member's goal: [`GoalMap::member_goal_rows`]).
    pub fn map_bytes(&self, rows: &[u8], obs_dim: usize, size: usize, out: &mut Vec<u8>) {
        for row in rows.chunks_exact(obs_dim * size) {
            for r in &self.ranges {
                out.extend_from_slice(&row[r.start * size..r.end * size]);
            }
        }
    }

    /// φ of one observation.
    pub fn map(&self, obs: &[f64]) -> Vec<f64> {
        self.ranges.iter().flat_map(|r| obs[r.clone()].iter().copied()).collect()
    }
}

/// The families pgser maps, for error messages.
pub const FAMILIES: [&str; 6] = ["pointmaze", "antmaze", "humanoidmaze", "cube", "scene", "puzzle"];

/// An environment's family (`cube` for `visual-cube-double-v0`), and whether it is a visual one
/// (its observations images, `visual-` before its name).
fn family(env: &str) -> (&str, bool) {
    let (name, visual) = match env.strip_prefix("visual-") {
        Some(rest) => (rest, true),
        None => (env, false),
    };
    (name.split('-').next().unwrap_or_default(), visual)
}

/// qpos of a cube scene: the arm's joints, the gripper's, then 7 per cube (position, quaternion)
/// from here (`add_oracle_reps`'s `qpos_obj_start_idx`, `qpos_cube_length`).
const CUBE_QPOS: usize = 14;
const CUBE_QPOS_VALUES: usize = 7;
/// A cube observation's (and oracle representation's) cube positions: centred here, scaled by
/// 10 (`CubeEnv.compute_observation`, `add_oracle_reps`).
const CUBE_CENTRE: [f64; 3] = [0.425, 0.0, 0.0];
const CUBE_SCALE: f64 = 10.0;
/// A scene's drawer and window positions in its observation and oracle representation: qpos
/// scaled by these (`SceneEnv.compute_observation`, `add_oracle_reps`).
const DRAWER_SCALE: f64 = 18.0;
const WINDOW_SCALE: f64 = 15.0;

/// The members an environment's goal is read from, where it is not observation values: a
/// puzzle's `button_states` (visual or not), a visual maze's or cube scene's `qpos`, since its
/// observations are images, and a visual scene's `qpos` and `button_states` ([`member_map`] maps
/// them). Empty: the goal is observation values.
pub fn goal_members(env: &str) -> &'static [&'static str] {
    match family(env) {
        ("puzzle", _) => &["button_states"],
        ("antmaze" | "humanoidmaze" | "cube", true) => &["qpos"],
        ("scene", true) => &["qpos", "button_states"],
        _ => &[],
    }
}

/// The goal map over [`goal_members`]' rows, of `widths` values each (in that order), OGBench's
/// oracle representation (`add_oracle_reps`) and its success test:
/// - a puzzle's button states, every one within 0.5 of its target state (0 or 1);
/// - a visual maze's agent x, y (`qpos[0:2]`), within `goal_tol` (0.5 for the ant and the
///   humanoid; OGBench has no visual pointmaze);
/// - a visual cube scene's cube positions (`qpos[14 + 7i : 17 + 7i]`), centred and scaled as a
///   state observation has them, every cube within 0.4 (0.04 m);
/// - a visual scene's cube position (centred and scaled), its 2 buttons' states
///   (`button_states`), the drawer's position (`qpos[23]` × 18) and the window's (`qpos[24]` ×
///   15), the values and the per-part test of the state scene's goal ([`GoalMetric::Scene`]).
pub fn member_map(env: &str, widths: &[usize]) -> Result<GoalMap> {
    let keys = goal_members(env);
    if keys.is_empty() {
        bail!("{env}: its goal is observation values, not a member's");
    }
    if widths.len() != keys.len() {
        bail!("{env}: its goal is read from {}; {} widths given", keys.join(" and "), widths.len());
    }
    let need = |m: usize, n: usize, what: &str| -> Result<()> {
        if widths[m] < n {
            bail!("{env}: {} has {} values a row; {what} needs {n}", keys[m], widths[m]);
        }
        Ok(())
    };
    let cube_ranges = |cubes: usize| -> Vec<Range<usize>> {
        (0..cubes).map(|i| CUBE_QPOS + CUBE_QPOS_VALUES * i..CUBE_QPOS + CUBE_QPOS_VALUES * i + 3).collect()
    };
    let cube_affine =
        |cubes: usize| -> Vec<(f64, f64)> { (0..cubes).flat_map(|_| CUBE_CENTRE.map(|c| (c, CUBE_SCALE))).collect() };
    match family(env).0 {
        "puzzle" => Ok(GoalMap::member(keys[0], widths[0], 0.5, GoalMetric::EachValue)),
        "antmaze" | "humanoidmaze" => {
            need(0, 2, "the agent's x, y (its first 2)")?;
            #[allow(clippy::single_range_in_vec_init)]
            let ranges = vec![0..2];
            Ok(GoalMap::of_member(keys[0], ranges, 0.5, GoalMetric::Euclidean, Vec::new()))
        }
        "scene" => {
            use crate::task::SCENE_BUTTONS;
            // One cube, then a qpos value per button, then the drawer and the window
            // (`add_oracle_reps`' qpos_drawer_idx, qpos_window_idx).
            let drawer = CUBE_QPOS + CUBE_QPOS_VALUES + SCENE_BUTTONS;
            need(0, drawer + 2, "a scene of one cube, two buttons, a drawer and a window")?;
            need(1, SCENE_BUTTONS, "the scene's two buttons")?;
            let mut ranges = cube_ranges(1);
            ranges.extend([0..SCENE_BUTTONS, drawer..drawer + 1, drawer + 1..drawer + 2]);
            let mut affine = cube_affine(1);
            affine.extend([(0.0, 1.0); SCENE_BUTTONS]);
            affine.extend([(0.0, DRAWER_SCALE), (0.0, WINDOW_SCALE)]);
            Ok(GoalMap {
                ranges,
                threshold: 1.0,
                metric: GoalMetric::Scene,
                members: keys.iter().map(|k| k.to_string()).collect(),
                range_member: vec![0, 1, 0, 0],
                affine,
            })
        }
        _ => {
            let cubes = cube_count(env)
                .with_context(|| format!("{env}: a visual cube scene names its cubes (visual-cube-double-v0)"))?;
            need(0, CUBE_QPOS + CUBE_QPOS_VALUES * cubes, &format!("a scene of {cubes} cube(s)"))?;
            Ok(GoalMap::of_member(keys[0], cube_ranges(cubes), 0.4, GoalMetric::EachObject, cube_affine(cubes)))
        }
    }
}

/// The cubes a cube scene's name gives (`cube-double-v0`: 2), if it names them.
fn cube_count(env: &str) -> Option<usize> {
    let name = env.strip_prefix("visual-").unwrap_or(env);
    match name.split('-').nth(1) {
        Some("single") => Some(1),
        Some("double") => Some(2),
        Some("triple") => Some(3),
        Some("quadruple") => Some(4),
        Some("octuple") => Some(8),
        _ => None,
    }
}

/// The goal map of an OGBench environment (`antmaze-large-v0`, `cube-double-v0`) whose
/// observations have `obs_dim` values.
pub fn goal_map(env: &str, obs_dim: usize) -> Result<GoalMap> {
    let family = env.split('-').next().unwrap_or_default();
    let maze = |tol: f64| -> Result<GoalMap> {
        if obs_dim < 2 {
            bail!("{env}: observations have {obs_dim} values; the goal is the first 2 (the agent's x, y)");
        }
        #[allow(clippy::single_range_in_vec_init)]
        let ranges = vec![0..2];
        Ok(GoalMap::of_observations(ranges, tol, GoalMetric::Euclidean))
    };
    match family {
        "pointmaze" => maze(1.0),
        "antmaze" | "humanoidmaze" => maze(0.5),
        "cube" => {
            let cubes = obs_dim.saturating_sub(CUBE_PROPRIO) / CUBE_VALUES;
            if cubes == 0 || CUBE_PROPRIO + cubes * CUBE_VALUES != obs_dim {
                bail!(
                    "{env}: observations have {obs_dim} values; a cube scene's have {CUBE_PROPRIO} + {CUBE_VALUES} per cube"
                );
            }
            if let Some(n) = cube_count(env).filter(|&n| n != cubes) {
                bail!(
                    "{env}: a scene of {n} cubes has {} observation values, these have {obs_dim} ({cubes} cube{})",
                    CUBE_PROPRIO + n * CUBE_VALUES,
                    if cubes == 1 { "" } else { "s" }
                );
            }
            let ranges =
                (0..cubes).map(|i| CUBE_PROPRIO + CUBE_VALUES * i..CUBE_PROPRIO + CUBE_VALUES * i + 3).collect();
            Ok(GoalMap::of_observations(ranges, 0.4, GoalMetric::EachObject))
        }
        "scene" => {
            use crate::task::SCENE_BUTTONS;
            let fixed = CUBE_PROPRIO + SCENE_BUTTONS * BUTTON_VALUES + SCENE_TAIL;
            let cubes = obs_dim.saturating_sub(fixed) / CUBE_VALUES;
            if cubes == 0 || fixed + cubes * CUBE_VALUES != obs_dim {
                bail!(
                    "{env}: observations have {obs_dim} values; a scene's have {CUBE_PROPRIO} + {CUBE_VALUES} per cube + \
                     {} for its {SCENE_BUTTONS} buttons + {SCENE_TAIL} for the drawer and the window ({} with one cube)",
                    SCENE_BUTTONS * BUTTON_VALUES,
                    fixed + CUBE_VALUES
                );
            }
            let buttons = CUBE_PROPRIO + cubes * CUBE_VALUES;
            let drawer = buttons + SCENE_BUTTONS * BUTTON_VALUES;
            let mut ranges: Vec<Range<usize>> =
                (0..cubes).map(|i| CUBE_PROPRIO + CUBE_VALUES * i..CUBE_PROPRIO + CUBE_VALUES * i + 3).collect();
            // The state one-hot's second value is the state (np.eye(2)[state]).
            ranges.extend((0..SCENE_BUTTONS).map(|b| buttons + BUTTON_VALUES * b + 1..buttons + BUTTON_VALUES * b + 2));
            ranges.extend([drawer..drawer + 1, drawer + 2..drawer + 3]);
            Ok(GoalMap::of_observations(ranges, 1.0, GoalMetric::Scene))
        }
        "puzzle" => {
            bail!("{env}: a puzzle's goal is its button states (the dataset's button_states), not observation values")
        }
        "visual" => bail!(
            "{env}: a visual environment's observations are images; its goal is read from the dataset's qpos \
             (mazes, cube scenes), button_states (puzzles) or both (scenes)"
        ),
        _ => bail!(
            "{env}: {family} datasets: pgser maps the goals of OGBench's {} (and of their visual datasets)",
            FAMILIES.join(", ")
        ),
    }
}

impl GoalMap {
    /// φ of the members' rows (`rows[m]`: member m's bytes, `row_len` values of `dtype` each, as
    /// the file stores them, one row per observation): for each observation, each range of its
    /// member's row, centred and scaled where [`GoalMap::affine`] says, in float64 from the stored
    /// value (as numpy's `(qpos - centre) * scale` computes it), as goal rows of `size`-byte
    /// little-endian floats appended to `out`.
    pub fn member_goal_rows(&self, rows: &[MemberRows<'_>], size: usize, out: &mut Vec<u8>) {
        let n = rows.first().map_or(0, |m| m.bytes.len() / (m.row_len * m.dtype.size).max(1));
        let mut values = Vec::with_capacity(self.goal_dim() * 8);
        for r in 0..n {
            values.clear();
            for (i, range) in self.ranges.iter().enumerate() {
                let m = &rows[self.range_member.get(i).copied().unwrap_or(0)];
                let row = &m.bytes[r * m.row_len * m.dtype.size..][..m.row_len * m.dtype.size];
                member_rows(&row[range.start * m.dtype.size..range.end * m.dtype.size], m.dtype, 8, &mut values);
            }
            for (i, v) in values.chunks_exact(8).enumerate() {
                let mut x = f64::from_le_bytes(v.try_into().expect("8 bytes"));
                if let Some(&(centre, scale)) = self.affine.get(i) {
                    x = (x - centre) * scale;
                }
                if size == 4 {
                    out.extend_from_slice(&(x as f32).to_le_bytes());
                } else {
                    out.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
    }
}

/// One member's rows, as [`GoalMap::member_goal_rows`] reads them.
pub struct MemberRows<'a> {
    pub bytes: &'a [u8],
    pub dtype: crate::dtype::Dtype,
    /// Values a row.
    pub row_len: usize,
}

/// A member's rows of values of `dtype` (as the file stores them) as goal rows of `size`-byte
/// little-endian floats, appended to `out`: a puzzle's int64 button states as float32 or float64,
/// exactly (0 and 1, as `astype(np.float32)` gives them).
pub fn member_rows(bytes: &[u8], dtype: crate::dtype::Dtype, size: usize, out: &mut Vec<u8>) {
    use crate::dtype::Kind;
    for v in bytes.chunks_exact(dtype.size) {
        let mut le = [0u8; 8];
        le[..dtype.size].copy_from_slice(v);
        if dtype.big_endian {
            le[..dtype.size].reverse();
        }
        let x = match (dtype.kind, dtype.size) {
            (Kind::Bool, _) => f64::from(le[0] != 0),
            (Kind::Int, n) => {
                // Sign-extend the n-byte value.
                let shift = 64 - 8 * n as u32;
                ((i64::from_le_bytes(le) << shift) >> shift) as f64
            }
            (Kind::UInt, _) => u64::from_le_bytes(le) as f64,
            (Kind::Float, 4) => f64::from(f32::from_le_bytes(le[..4].try_into().expect("4 bytes"))),
            (Kind::Float, 8) => f64::from_le_bytes(le),
            // Half floats are refused where a goal member is chosen.
            (Kind::Float, _) => f64::NAN,
        };
        if size == 4 {
            out.extend_from_slice(&(x as f32).to_le_bytes());
        } else {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn member_rows_are_the_values_as_floats() {
        use crate::dtype::Dtype;
        let ints: Vec<u8> = [0i64, 1, -3].iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut out = Vec::new();
        member_rows(&ints, Dtype::I64, 4, &mut out);
        let back: Vec<f32> = out.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
        assert_eq!(back, [0.0, 1.0, -3.0]);
        let big: Vec<u8> = [-2i16, 7].iter().flat_map(|v| v.to_be_bytes()).collect();
        out.clear();
        member_rows(&big, Dtype::I16.with_big_endian(true), 8, &mut out);
        let back: Vec<f64> = out.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect();
        assert_eq!(back, [-2.0, 7.0]);
        out.clear();
        member_rows(&[1, 0], Dtype::BOOL, 4, &mut out);
        assert_eq!(out, [1.0f32.to_le_bytes(), 0.0f32.to_le_bytes()].concat());
    }

    #[test]
    #[allow(clippy::single_range_in_vec_init)]
    fn a_visual_cube_goal_is_its_qpos_centred_and_scaled() {
        use crate::dtype::Dtype;
        let g = member_map("visual-cube-double-v0", &[28]).unwrap();
        assert_eq!((g.ranges.clone(), g.member_of(1), g.threshold), (vec![14..17, 21..24], "qpos", 0.4));
        let row: Vec<f32> = (0..28).map(|i| i as f32 / 8.0).collect();
        let bytes: Vec<u8> = row.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut out = Vec::new();
        g.member_goal_rows(&[MemberRows { bytes: &bytes, dtype: Dtype::F32, row_len: 28 }], 4, &mut out);
        let got: Vec<f32> = out.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
        // numpy's (qpos - [0.425, 0, 0]) * 10 on float32 qpos, in float64, then float32.
        let want: Vec<f32> = [14, 15, 16, 21, 22, 23]
            .iter()
            .enumerate()
            .map(|(i, &j)| ((row[j] as f64 - if i % 3 == 0 { 0.425 } else { 0.0 }) * 10.0) as f32)
            .collect();
        assert_eq!(got, want);
        assert!(member_map("visual-cube-double-v0", &[27]).unwrap_err().to_string().contains("needs 28"));
        let m = member_map("visual-antmaze-large-v0", &[15]).unwrap();
        assert_eq!((m.ranges.clone(), m.threshold, m.affine.len()), (vec![0..2], 0.5, 0));
        assert!(member_map("visual-cube-v0", &[28]).is_err());
    }

    /// A visual scene's goal: its cube's qpos centred and scaled, its button states, its
    /// drawer's and window's qpos × 18 and × 15, as `add_oracle_reps` computes them.
    #[test]
    fn a_visual_scene_goal_reads_qpos_and_button_states() {
        use crate::dtype::Dtype;
        let g = member_map("visual-scene-v0", &[25, 2]).unwrap();
        assert_eq!(g.ranges, vec![14..17, 0..2, 23..24, 24..25]);
        assert_eq!(
            (g.goal_dim(), g.metric, g.member_of(1), g.member_of(2)),
            (7, GoalMetric::Scene, "button_states", "qpos")
        );
        let qpos: Vec<f32> = (0..50).map(|i| i as f32 / 16.0).collect();
        let buttons: Vec<i64> = vec![1, 0, 0, 1];
        let (qb, bb): (Vec<u8>, Vec<u8>) = (
            qpos.iter().flat_map(|v| v.to_le_bytes()).collect(),
            buttons.iter().flat_map(|v| v.to_le_bytes()).collect(),
        );
        let mut out = Vec::new();
        g.member_goal_rows(
            &[
                MemberRows { bytes: &qb, dtype: Dtype::F32, row_len: 25 },
                MemberRows { bytes: &bb, dtype: Dtype::I64, row_len: 2 },
            ],
            4,
            &mut out,
        );
        let got: Vec<f32> = out.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
        let want = |r: usize| -> Vec<f32> {
            let q = |j: usize| qpos[25 * r + j] as f64;
            [
                (q(14) - 0.425) * 10.0,
                q(15) * 10.0,
                q(16) * 10.0,
                buttons[2 * r] as f64,
                buttons[2 * r + 1] as f64,
                q(23) * 18.0,
                q(24) * 15.0,
            ]
            .map(|v| v as f32)
            .to_vec()
        };
        assert_eq!(got, [want(0), want(1)].concat());
        assert!(member_map("visual-scene-v0", &[24, 2]).unwrap_err().to_string().contains("needs 25"));
        assert!(member_map("visual-scene-v0", &[25]).is_err());
    }

    #[test]
    #[allow(clippy::single_range_in_vec_init)]
    fn maps_of_the_families() {
        assert_eq!(goal_map("pointmaze-medium-v0", 2).unwrap().ranges, vec![0..2]);
        assert_eq!(goal_map("antmaze-large-v0", 29).unwrap().threshold, 0.5);
        let c = goal_map("cube-double-v0", 37).unwrap();
        assert_eq!((c.ranges.clone(), c.goal_dim(), c.metric), (vec![19..22, 28..31], 6, GoalMetric::EachObject));
        let obs: Vec<f64> = (0..37).map(f64::from).collect();
        assert_eq!(c.map(&obs), [19.0, 20.0, 21.0, 28.0, 29.0, 30.0]);
        assert!(goal_map("cube-double-v0", 36).unwrap_err().to_string().contains("19 + 9 per cube"));
        assert!(goal_map("cube-double-v0", 28).unwrap_err().to_string().contains("a scene of 2 cubes has 37"));
        assert!(goal_map("puzzle-3x3-v0", 10).unwrap_err().to_string().contains("its button states"));
        let s = goal_map("scene-v0", 40).unwrap();
        assert_eq!(s.ranges, vec![19..22, 29..30, 33..34, 36..37, 38..39]);
        assert_eq!((s.goal_dim(), s.threshold, s.metric), (7, 1.0, GoalMetric::Scene));
        assert!(goal_map("scene-v0", 41).unwrap_err().to_string().contains("(40 with one cube)"));
        assert!(goal_map("visual-scene-v0", 40).unwrap_err().to_string().contains("or both (scenes)"));
        assert_eq!(goal_members("puzzle-4x5-v0"), ["button_states"]);
        assert_eq!(goal_members("visual-puzzle-4x5-v0"), ["button_states"]);
        assert!(goal_members("cube-double-v0").is_empty());
        assert_eq!(goal_members("visual-scene-v0"), ["qpos", "button_states"]);
        let p = member_map("puzzle-4x5-v0", &[20]).unwrap();
        assert_eq!((p.ranges.clone(), p.threshold, p.metric), (vec![0..20], 0.5, GoalMetric::EachValue));
        assert!(goal_map("visual-cube-single-v0", 28).is_err());
    }
}
