//! `pgser-etl collect`: simulate episodes in pgser's environments and write them as a
//! trajectory table (`.parquet`, docs/tables.md) or a WGCSL pickle (`.pkl`, docs/domain.md).
//!
//! Episodes are simulated in parallel a chunk at a time, so memory holds one chunk however many
//! episodes are asked for. Nothing depends on the thread count: episode i resets with seed
//! S + i from a newly made environment (`GoalEnv::restart`; Python reproduces it with
//! `gym.make(id).reset(seed=S+i)`, or `env.reset(seed=S+i)` for Fetch), its policy draws from a
//! generator of its own (`policy`), and chunks are written in order. The parquet path
//! goes through the same [`TrajectoryWriter`] as `convert`, so a `.pkl` from here converts to
//! the very table `.parquet` gets.
//!
//! WGCSL layout: T observations and T − 1 actions per episode. `o[i,0]` is the reset
//! observation; for t < T − 1, `u[i,t]` is the action taken, `g[i,t]` the desired goal it was
//! taken for, and `o[i,t+1]`, `ag[i,t+1]` what the step returned. u holds the action as the
//! environment applied it: clipped to [−1, 1] and rounded to float32 (the action space's
//! dtype), so replaying u as float32 in gymnasium reproduces the episode.

pub mod ogbench;
pub mod policy;

use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use indicatif::ProgressBar;
use rayon::prelude::*;

use self::policy::{EpisodePolicy, PolicyKind, PolicySpec};
use crate::dtype::Dtype;
use crate::env::{self, GoalEnv};
use crate::output::AtomicFile;
use crate::pickle::write::{ArrayOut, write_dict};
use crate::task::Task;
use crate::trajectory::{self, EpisodeArrays, FloatArray, FloatType, Footer, KEYS, TrajectoryWriter, WriterOptions};

#[derive(Debug, Clone)]
pub struct CollectOptions {
    /// Task name or gymnasium id (FetchPush, FetchPush-v4).
    pub task: String,
    pub policy: PolicySpec,
    pub episodes: usize,
    /// Episode i resets with seed + i.
    pub seed: u64,
    /// `.parquet` (trajectory table) or `.pkl` (WGCSL pickle).
    pub output: PathBuf,
    /// Store float32 vectors in the table (pickles are always float64).
    pub float32: bool,
    /// Target rows per row group of the table; row groups always hold whole episodes.
    pub row_group_rows: usize,
    /// The command line, recorded in the table's footer.
    pub command: String,
}

#[derive(Debug, Clone)]
pub struct CollectSummary {
    pub task: Task,
    pub episodes: usize,
    /// Environment steps taken (episodes × (T − 1)).
    pub steps: usize,
    /// Episodes whose last step reached the goal.
    pub successes: usize,
    /// Mean over episodes of the summed rewards (in [−(T − 1), 0]).
    pub mean_return: f64,
    pub bytes: u64,
    pub seconds: f64,
}

/// Episodes simulated per chunk, at least: enough to keep every thread busy.
const MIN_CHUNK: usize = 256;

/// Checks everything `collect` checks before it creates its output (the output's type, the
/// counts, the environment and its assets, the policy), and creates nothing: a pipeline calls
/// it before any of its steps run.
pub fn check(opts: &CollectOptions) -> Result<Task> {
    if opts.policy.kind == PolicyKind::Oracle {
        return Ok(ogbench::check(opts)?.1);
    }
    Ok(prepare(opts)?.1.task().clone())
}

/// Whether the output is a pickle, and a first environment of the task.
fn prepare(opts: &CollectOptions) -> Result<(bool, Box<dyn GoalEnv + Send>)> {
    let at = opts.output.display();
    let pickle = match opts.output.extension().and_then(|e| e.to_str()) {
        Some("parquet") => false,
        Some("pkl") => true,
        _ => bail!("{at}: unknown output type; name it .parquet (trajectory table) or .pkl (WGCSL pickle)"),
    };
    if pickle && opts.float32 {
        bail!("{at}: WGCSL pickles are float64; --float32 applies to .parquet outputs");
    }
    if opts.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    if opts.seed.checked_add(opts.episodes as u64 - 1).is_none() {
        bail!("--seed {} + {} episodes overflows the 64-bit seed range", opts.seed, opts.episodes);
    }
    let first = env::make(&opts.task)?;
    // Fails early (no file created) for a policy the task has no expert for.
    EpisodePolicy::new(opts.policy.clone(), &first.task().name, opts.seed, 0)?;
    Ok((pickle, first))
}

pub fn collect(opts: &CollectOptions, bar: &ProgressBar) -> Result<CollectSummary> {
    if opts.policy.kind == PolicyKind::Oracle {
        return ogbench::collect(opts, bar);
    }
    let started = Instant::now();
    let at = opts.output.display();
    let (pickle, first) = prepare(opts)?;
    let task = first.task().clone();
    let pool = EnvPool { task: task.name.clone(), idle: Mutex::new(vec![first]) };

    let float = if opts.float32 { FloatType::Float32 } else { FloatType::Float64 };
    let mut sink = if pickle {
        Sink::Pickle(PickleSink::create(&opts.output)?)
    } else {
        Sink::Table(Box::new(TrajectoryWriter::create(
            &opts.output,
            &task,
            float,
            WriterOptions::new(opts.row_group_rows),
        )?))
    };
    // Whole row groups per chunk keep the table's row groups where `convert` puts them.
    let per_group = trajectory::episodes_per_group(opts.row_group_rows, task.t);
    let chunk = per_group * MIN_CHUNK.div_ceil(per_group);
    bar.set_length(opts.episodes as u64);
    let (mut successes, mut return_sum) = (0, 0.0);
    for start in (0..opts.episodes).step_by(chunk) {
        let range = start..(start + chunk).min(opts.episodes);
        let c = simulate(&pool, opts, &task, range, bar)?;
        successes += c.successes;
        return_sum += c.return_sum;
        let origin = format!("{at} (simulated {})", task.name);
        match &mut sink {
            Sink::Table(w) => w.append(&c.arrays(&task, origin), 0, c.episodes)?,
            Sink::Pickle(p) => p.append(&c)?,
        }
    }

    let bytes = match sink {
        Sink::Table(w) => {
            let mut footer = Footer::new(&task, float, opts.episodes, opts.command.clone());
            footer.policy = Some(opts.policy.kind.describe());
            footer.seed = Some(opts.seed);
            w.finish(&footer)?
        }
        Sink::Pickle(p) => p.finish(&task, opts.episodes)?,
    };
    Ok(CollectSummary {
        episodes: opts.episodes,
        steps: opts.episodes * (task.t - 1),
        successes,
        mean_return: return_sum / opts.episodes as f64,
        bytes,
        seconds: started.elapsed().as_secs_f64(),
        task,
    })
}

enum Sink {
    Table(Box<TrajectoryWriter>),
    Pickle(PickleSink),
}

/// Environments for worker threads: creating one loads and compiles the MuJoCo model, so each
/// is reused across episodes. Which one runs an episode does not matter: a seeded reset
/// restores every piece of simulator state.
struct EnvPool {
    task: String,
    idle: Mutex<Vec<Box<dyn GoalEnv + Send>>>,
}

impl EnvPool {
    fn with<R>(&self, f: impl FnOnce(&mut dyn GoalEnv) -> R) -> Result<R> {
        let taken = self.idle.lock().expect("env pool poisoned").pop();
        let mut env = match taken {
            Some(e) => e,
            None => env::make(&self.task)?,
        };
        let r = f(env.as_mut());
        self.idle.lock().expect("env pool poisoned").push(env);
        Ok(r)
    }
}

/// A chunk of simulated episodes: the four arrays as little-endian float64 bytes.
struct Chunk {
    episodes: usize,
    /// o, ag, u, g.
    data: [Vec<u8>; 4],
    successes: usize,
    return_sum: f64,
}

impl Chunk {
    fn arrays(&self, task: &Task, origin: String) -> EpisodeArrays<'_> {
        let dims = layout(task);
        let arrays =
            std::array::from_fn(|k| FloatArray { data: &self.data[k], size: 8, steps: dims[k].0, dim: dims[k].1 });
        EpisodeArrays { origin, keys: KEYS, arrays, episodes: self.episodes, extras: Vec::new() }
    }
}

/// (steps, values per step) of o, ag, u, g.
fn layout(task: &Task) -> [(usize, usize); 4] {
    let t = task.t;
    [(t, task.obs_dim), (t, task.goal_dim), (t - 1, task.act_dim), (t - 1, task.goal_dim)]
}

/// Simulate episodes `range` in parallel, each into its own slice of the chunk's arrays.
fn simulate(
    pool: &EnvPool,
    opts: &CollectOptions,
    task: &Task,
    range: Range<usize>,
    bar: &ProgressBar,
) -> Result<Chunk> {
    let n = range.len();
    let per_episode = layout(task).map(|(steps, dim)| steps * dim * 8);
    let mut data: [Vec<u8>; 4] = per_episode.map(|b| vec![0u8; b * n]);
    let [o, ag, u, g] = &mut data;
    let results: Vec<(bool, f64)> = o
        .par_chunks_mut(per_episode[0])
        .zip(ag.par_chunks_mut(per_episode[1]))
        .zip(u.par_chunks_mut(per_episode[2]))
        .zip(g.par_chunks_mut(per_episode[3]))
        .enumerate()
        .map(|(k, (((o, ag), u), g))| {
            let i = (range.start + k) as u64;
            let mut policy = EpisodePolicy::new(opts.policy.clone(), &task.name, opts.seed, i)?;
            let out = pool.with(|env| run_episode(env, &mut policy, opts.seed + i, [o, ag, u, g]))?;
            bar.inc(1);
            Ok(out)
        })
        .collect::<Result<_>>()?;
    let successes = results.iter().filter(|r| r.0).count();
    let return_sum = results.iter().map(|r| r.1).sum();
    Ok(Chunk { episodes: n, data, successes, return_sum })
}

/// One episode into `out` = [o, ag, u, g] byte slices. Returns (final-step success, return).
fn run_episode(env: &mut dyn GoalEnv, policy: &mut EpisodePolicy, seed: u64, out: [&mut [u8]; 4]) -> (bool, f64) {
    let [o, ag, u, g] = out;
    let t = env.task().t;
    let mut obs = env.restart(seed);
    put(o, 0, &obs.observation);
    put(ag, 0, &obs.achieved_goal);
    let mut action = vec![0.0; env.task().act_dim];
    let (mut success, mut ret) = (false, 0.0);
    for step in 0..t - 1 {
        policy.act(&obs, &mut action);
        for a in action.iter_mut() {
            *a = env::applied_action(*a) as f64;
        }
        put(u, step, &action);
        put(g, step, &obs.desired_goal);
        let s = env.step(&action);
        ret += s.reward;
        success = s.success;
        obs = s.obs;
        put(o, step + 1, &obs.observation);
        put(ag, step + 1, &obs.achieved_goal);
    }
    (success, ret)
}

/// Row `step` of an episode's array: `values` as little-endian float64.
fn put(array: &mut [u8], step: usize, values: &[f64]) {
    let row = &mut array[step * values.len() * 8..(step + 1) * values.len() * 8];
    for (dst, v) in row.chunks_exact_mut(8).zip(values) {
        dst.copy_from_slice(&v.to_le_bytes());
    }
}

/// An output written at the end from arrays that arrive a chunk at a time, when its format stores
/// one whole array before the next (a pickle all of o before any of ag; an `.npz` all
/// observations before any action): each array's chunks go to a scratch file of its own beside
/// the output, and the writer copies them in at the end.
struct Spools {
    out: AtomicFile,
    files: Vec<File>,
}

impl Spools {
    fn create(dest: &Path, arrays: usize) -> Result<Spools> {
        let out = AtomicFile::create(dest)?;
        let files = (0..arrays).map(|_| out.scratch()).collect::<Result<_>>()?;
        Ok(Spools { out, files })
    }

    /// The next chunk of each array, in order.
    fn append<'a>(&mut self, chunks: impl IntoIterator<Item = &'a [u8]>) -> Result<()> {
        for (f, d) in self.files.iter_mut().zip(chunks) {
            f.write_all(d).with_context(|| format!("{}: spool write failed", self.out.dest().display()))?;
        }
        Ok(())
    }
}

/// A WGCSL pickle written at the end, from its four arrays' spools.
struct PickleSink(Spools);

impl PickleSink {
    fn create(dest: &Path) -> Result<Self> {
        Ok(PickleSink(Spools::create(dest, 4)?))
    }

    fn append(&mut self, c: &Chunk) -> Result<()> {
        self.0.append(c.data.iter().map(Vec::as_slice))
    }

    fn finish(self, task: &Task, episodes: usize) -> Result<u64> {
        let Spools { out, mut files } = self.0;
        let dest = out.dest().to_path_buf();
        let fail = || format!("{}: write failed", dest.display());
        let mut w = BufWriter::with_capacity(8 << 20, out.handle()?);
        let dims = layout(task);
        let mut arrays: Vec<ArrayOut> = files
            .iter_mut()
            .zip(KEYS)
            .zip(dims)
            .map(|((f, key), (steps, dim))| ArrayOut {
                key,
                dtype: Dtype::F64,
                shape: vec![episodes, steps, dim],
                data: Box::new(move |w: &mut dyn Write| {
                    f.rewind()?;
                    std::io::copy(f, w).map(|_| ())
                }),
            })
            .collect();
        write_dict(&mut w, &mut arrays).with_context(fail)?;
        drop(arrays);
        w.into_inner().map_err(|e| e.into_error()).with_context(fail)?;
        out.commit()?;
        Ok(std::fs::metadata(&dest)?.len())
    }
}
