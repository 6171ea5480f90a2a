//! `pgser-etl collect --task pointmaze-medium-navigate-v0 --policy oracle`: OGBench's PointMaze
//! datasets made here, as OGBench's data generator (`generate_locomaze.py`, run with the flags of
//! its `commands.sh`) makes them, written as OGBench's `.npz` files or as a trajectory table.
//!
//! The recipe ([`Recipe`]: the dataset name gives the maze, the kind, the episode length M):
//! - **navigate**: start in a random free cell, with a random junction cell ("vertex" cell: not a
//!   straight corridor) as the goal; on reaching it, a new random junction, until M rows.
//! - **stitch**: start in a random free cell, goal a random cell exactly 4 moves away (itself if
//!   none), M = 201 rows: no episode crosses a maze, so the evaluation tasks need stitching.
//! - every step: the unit direction (`d / (‖d‖ + 1e-6)`) to OGBench's oracle subgoal (the centre
//!   of the next cell on a shortest path to the goal's cell, or of the goal's own cell once in it),
//!   plus N(0, σ²) noise per value (σ = 0.5), clipped to [−1, 1], applied in float64. Episodes
//!   never end at a goal (`terminate_at_goal=False`).
//!
//! Randomness: the generator draws everything from numpy's global generator and never seeds it.
//! Here episode i draws from `np.random.seed(S + i)` (start and goal cells, start and goal noise,
//! action noise, teleports, new goals, in the generator's order), so episodes are independent of
//! the thread that simulates them, and `tests/py/make_ogbench_fixtures.py --seed-per-episode`
//! reproduces a file with ogbench's own environment. The `.npz`'s `-val` file holds the next
//! episodes (S + N …, a tenth as many), as OGBench's split of one run into train and val.
//!
//! What is written: `observations` (the position before each step), `actions`, `terminals`
//! (true on each episode's last row), `qpos`, `qvel` (before the step), as OGBench stores them
//! (float32, bool). One difference: OGBench's reset leaves a random velocity that the first step
//! zeroes before it acts; pgser's reset leaves none, so each episode's first `qvel` row is 0 here.
//! A `.parquet` output is the table that `pgser-etl convert` makes of the `.npz` (T = M rows per
//! episode; goal = position; each transition's desired goal is its episode's last position).

use std::io::{BufWriter, Seek, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use indicatif::ProgressBar;
use rayon::prelude::*;

use super::{CollectOptions, CollectSummary, Spools};
use crate::dtype::Dtype;
use crate::env::GoalEnv;
use crate::env::pointmaze::{self, DatasetKind, PointMazeEnv, Recipe};
use crate::ogbench::npz::NpzWriter;
use crate::task::Task;
use crate::trajectory::{
    EpisodeArrays, ExtraArray, FloatArray, FloatType, Footer, Passthrough, Per, TrajectoryWriter, WriterOptions,
};

/// The arrays of OGBench's dataset files, in the order the generator writes them.
const MEMBERS: [(&str, Dtype); 5] = [
    ("observations", Dtype::F32),
    ("actions", Dtype::F32),
    ("terminals", Dtype::BOOL),
    ("qpos", Dtype::F32),
    ("qvel", Dtype::F32),
];

/// The recipe and the environment's task of an OGBench dataset name, or why `--policy oracle`
/// does not apply.
pub fn recipe(task: &str) -> Result<(Recipe, Task)> {
    match (pointmaze::recipe(task), pointmaze::task(task)) {
        (Some(r), Some(env)) => Ok((r, Task::custom(&env.name, r.rows, 2, 2, 2, pointmaze::GOAL_TOL))),
        (None, Some(_)) => bail!(
            "--task {task}: the oracle makes OGBench's datasets; name one, pointmaze-<maze>-navigate-v0 or \
             pointmaze-<maze>-stitch-v0"
        ),
        _ => bail!(
            "--task {task}: the oracle makes OGBench's PointMaze datasets (pointmaze-{{medium,large,giant,teleport}}-\
             {{navigate,stitch}}-v0)"
        ),
    }
}

/// Checks the output's type and the counts; creates nothing.
pub fn check(opts: &CollectOptions) -> Result<(Recipe, Task)> {
    let at = opts.output.display();
    let (r, task) = recipe(&opts.task)?;
    match opts.output.extension().and_then(|e| e.to_str()) {
        Some("npz") | Some("parquet") => {}
        _ => bail!("{at}: unknown output type; name it .npz (OGBench's dataset file) or .parquet (trajectory table)"),
    }
    if opts.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    if opts.policy.epsilon > 0.0 {
        bail!("--epsilon: OGBench's oracle data have Gaussian action noise only (--noise)");
    }
    let last = opts.seed.checked_add((opts.episodes + val_episodes(opts.episodes)) as u64);
    if last.is_none_or(|l| l > u32::MAX as u64 + 1) {
        bail!(
            "--seed {} + {} episodes: episode i seeds numpy's generator with S + i, which must stay below 2^32",
            opts.seed,
            opts.episodes
        );
    }
    Ok((r, task))
}

/// Episodes of the `-val` file: a tenth of the dataset's, as OGBench splits one run, and at
/// least one, since OGBench's loader needs the file.
fn val_episodes(episodes: usize) -> usize {
    (episodes / 10).max(1)
}

/// One episode's rows, as OGBench stores them (little-endian bytes).
#[derive(Default)]
struct Rows {
    /// observations, actions, terminals, qpos, qvel.
    members: [Vec<u8>; 5],
    /// The sparse return under the goal being pursued (−1 per step not at it), and whether the
    /// last row's step reached it.
    ret: f64,
    final_success: bool,
}

/// Episode `seed` of the recipe, simulated in `env`.
fn episode(env: &mut PointMazeEnv, r: &Recipe, noise: f64, seed: u32) -> Rows {
    env.seed(seed as u64);
    let (cells, vertices) = (env.free_cells(), env.vertex_cells());
    let pick = |env: &mut PointMazeEnv, from: &[pointmaze::Cell]| from[env.rng().randint(from.len() as u32) as usize];
    let start = pick(env, &cells);
    let goal = match r.kind {
        DatasetKind::Navigate => pick(env, &vertices),
        DatasetKind::Stitch => {
            let near = env.cells_at_distance(start, 4);
            if near.is_empty() { start } else { pick(env, &near) }
        }
    };
    let mut ob = env.reset_cells(start, goal).observation;
    let name = env.task().name.clone();
    let mut rows = Rows::default();
    let put = |out: &mut Vec<u8>, v: [f64; 2]| v.iter().for_each(|x| out.extend_from_slice(&(*x as f32).to_le_bytes()));
    for step in 0..r.rows {
        let (xy, qvel) = (env.xy(), env.qvel());
        let sub = pointmaze::oracle_subgoal(&name, xy, env.goal()).expect("a simulated maze");
        let d = [sub[0] - xy[0], sub[1] - xy[1]];
        let norm = (d[0] * d[0] + d[1] * d[1]).sqrt() + 1e-6;
        let rng = env.rng();
        let action = d.map(|v| (v / norm + rng.normal(0.0, noise)).clamp(-1.0, 1.0));
        let s = env.step_f64(action);
        if s.success && r.kind == DatasetKind::Navigate {
            let next = pick(env, &vertices);
            env.set_goal_cell(next);
        }
        rows.ret += s.reward;
        rows.final_success = s.success;
        let m = &mut rows.members;
        put(&mut m[0], [ob[0], ob[1]]);
        put(&mut m[1], action);
        m[2].push(u8::from(step == r.rows - 1));
        put(&mut m[3], xy);
        put(&mut m[4], qvel);
        ob = s.obs.observation;
    }
    rows
}

/// Episodes `range` (seeds S + i), in parallel; each worker makes its environment once.
fn simulate(
    opts: &CollectOptions,
    r: &Recipe,
    noise: f64,
    range: Range<usize>,
    bar: &ProgressBar,
) -> Result<Vec<Rows>> {
    range
        .into_par_iter()
        .map_init(
            || PointMazeEnv::new(&opts.task),
            |env, i| {
                let env = env.as_mut().map_err(|e| anyhow::anyhow!("{e:#}"))?;
                let rows = episode(env, r, noise, (opts.seed + i as u64) as u32);
                bar.inc(1);
                Ok(rows)
            },
        )
        .collect()
}

/// Episodes simulated per chunk: memory holds a chunk's rows, whatever the count.
const CHUNK: usize = 256;

pub fn collect(opts: &CollectOptions, bar: &ProgressBar) -> Result<CollectSummary> {
    let started = Instant::now();
    let (r, task) = check(opts)?;
    let noise = opts.policy.noise;
    let npz = opts.output.extension().is_some_and(|e| e == "npz");
    let val = val_episodes(opts.episodes);
    bar.set_length((opts.episodes + if npz { val } else { 0 }) as u64);
    let (mut return_sum, mut successes) = (0.0, 0usize);
    let mut tally = |chunk: &[Rows]| {
        return_sum += chunk.iter().map(|e| e.ret).sum::<f64>();
        successes += chunk.iter().filter(|e| e.final_success).count();
    };
    let bytes = if npz {
        let val_path = val_file(&opts.output);
        let mut train = NpzSpool::create(&opts.output)?;
        let mut valid = NpzSpool::create(&val_path)?;
        for (spool, range) in [(&mut train, 0..opts.episodes), (&mut valid, opts.episodes..opts.episodes + val)] {
            for start in range.clone().step_by(CHUNK) {
                let chunk = simulate(opts, &r, noise, start..(start + CHUNK).min(range.end), bar)?;
                if range.start == 0 {
                    tally(&chunk);
                }
                spool.append(&chunk)?;
            }
        }
        // The val file first: OGBench's loader needs it beside the dataset, so the dataset
        // appears only when both are whole.
        let v = valid.finish(val * r.rows)?;
        let t = train.finish(opts.episodes * r.rows)?;
        t + v
    } else {
        // The table `convert` makes of the .npz: terminals, qpos and qvel as passthrough columns,
        // each episode's last action on its last step.
        let origin = format!("{} (simulated {})", opts.output.display(), opts.task);
        let specs = MEMBERS[2..]
            .iter()
            .map(|&(key, dtype)| {
                let shape = if dtype == Dtype::BOOL { vec![] } else { vec![2] };
                Passthrough::new(&origin, key, dtype, Per::Step, shape)
            })
            .collect::<Result<Vec<_>>>()?;
        let options =
            WriterOptions { extras: specs.clone(), last_action: true, ..WriterOptions::new(opts.row_group_rows) };
        let mut w = TrajectoryWriter::create(&opts.output, &task, FloatType::Float32, options)?;
        for start in (0..opts.episodes).step_by(CHUNK) {
            let chunk = simulate(opts, &r, noise, start..(start + CHUNK).min(opts.episodes), bar)?;
            tally(&chunk);
            let arrays = table_arrays(&chunk);
            w.append(&view(&arrays, &specs, origin.clone(), chunk.len(), r.rows), 0, chunk.len())?;
        }
        let mut footer = Footer::new(&task, FloatType::Float32, opts.episodes, opts.command.clone());
        footer.policy = Some(format!("oracle:{} noise {noise}", opts.task));
        footer.seed = Some(opts.seed);
        w.finish(&footer)?
    };
    Ok(CollectSummary {
        episodes: opts.episodes,
        steps: opts.episodes * r.rows,
        successes,
        mean_return: return_sum / opts.episodes as f64,
        bytes,
        seconds: started.elapsed().as_secs_f64(),
        task,
    })
}

/// `NAME.npz` → `NAME-val.npz`, where `make_env_and_datasets(dataset_path=...)` looks for it.
pub fn val_file(path: &Path) -> PathBuf {
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
    path.with_file_name(format!("{stem}-val.npz"))
}

/// The table arrays of a chunk, as `convert` makes them from the `.npz` rows: o = the
/// observations, ag = their x, y, u = every action (the last on the last step), g = the last
/// position; then terminals, qpos and qvel.
fn table_arrays(chunk: &[Rows]) -> [Vec<u8>; 7] {
    let mut a: [Vec<u8>; 7] = Default::default();
    for e in chunk {
        let (o, u) = (&e.members[0], &e.members[1]);
        a[0].extend_from_slice(o);
        a[1].extend_from_slice(o);
        a[2].extend_from_slice(u);
        let t = o.len() / 8;
        let last = &o[(t - 1) * 8..];
        for _ in 0..t - 1 {
            a[3].extend_from_slice(last);
        }
        for k in 2..5 {
            a[k + 2].extend_from_slice(&e.members[k]);
        }
    }
    a
}

fn view<'a>(
    a: &'a [Vec<u8>; 7],
    specs: &[Passthrough],
    origin: String,
    episodes: usize,
    t: usize,
) -> EpisodeArrays<'a> {
    let steps = [t, t, t, t - 1];
    let arrays = std::array::from_fn(|k| FloatArray { data: &a[k], size: 4, steps: steps[k], dim: 2 });
    let extras = specs
        .iter()
        .zip(&a[4..])
        .map(|(p, data)| ExtraArray { spec: p.clone(), data: std::borrow::Cow::Borrowed(&data[..]) })
        .collect();
    EpisodeArrays { origin, keys: crate::ogbench::ARRAY_KEYS, arrays, episodes, extras }
}

/// An OGBench `.npz` written at the end from its members' spools (the archive stores all
/// observations before any action), compressed.
struct NpzSpool(Spools);

impl NpzSpool {
    fn create(dest: &Path) -> Result<NpzSpool> {
        Ok(NpzSpool(Spools::create(dest, MEMBERS.len())?))
    }

    fn append(&mut self, chunk: &[Rows]) -> Result<()> {
        chunk.iter().try_for_each(|e| self.0.append(e.members.iter().map(Vec::as_slice)))
    }

    fn finish(self, rows: usize) -> Result<u64> {
        let Spools { out, mut files } = self.0;
        let dest = out.dest().to_path_buf();
        let fail = || format!("{}: write failed", dest.display());
        let mut w = NpzWriter::new(BufWriter::with_capacity(8 << 20, out.handle()?), true);
        let mut buf = vec![0u8; 1 << 20];
        for ((key, dtype), f) in MEMBERS.iter().zip(&mut files) {
            let shape: &[usize] = if *dtype == Dtype::BOOL { &[rows] } else { &[rows, 2] };
            w.start(key, *dtype, shape).with_context(fail)?;
            f.rewind().with_context(fail)?;
            loop {
                let n = std::io::Read::read(f, &mut buf).with_context(fail)?;
                if n == 0 {
                    break;
                }
                w.write(&buf[..n]).with_context(fail)?;
            }
        }
        w.finish().with_context(fail)?.flush().with_context(fail)?;
        out.commit()?;
        Ok(std::fs::metadata(&dest)?.len())
    }
}
