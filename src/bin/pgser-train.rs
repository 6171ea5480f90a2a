//! `pgser-train`: train, evaluate and benchmark agents. Parses flags and calls the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use pgser::agent::{AgentConfig, Backend, checkpoint};
use pgser::task::Task;
use pgser::train::{self, TrainConfig};
use pgser::{cli, eval, progress};

#[derive(Parser)]
#[command(
    name = "pgser-train",
    version,
    long_version = pgser::cli::LONG_VERSION.as_str(),
    about = "Train goal-conditioned TD3 / TD3+BC agents on pgser tables, evaluate them in MuJoCo",
    args_conflicts_with_subcommands = true,
    after_help = "Examples:\n  pgser-train --data traj.parquet --algo td3bc --swap none -o baseline.ckpt\n  \
        pgser-train --data traj.parquet --algo td3bc --swap random --updates 1000000 -o q.ckpt   # PGSER step 1\n  \
        pgser-train --data traj.parquet -o run.ckpt --resume        # continue an interrupted run\n  \
        pgser-train --data traj.parquet --seeds 0,1,2,3,4 -o runs/  # 5 seeds as one stack: runs/s0.ckpt ..\n  \
        pgser-train eval --ckpt run.ckpt --episodes 50 --seed 1000000 --json\n\n\
        Writes run.ckpt (safetensors), run.ckpt.resume (optimizer, targets, random streams) and\n\
        run.ckpt.metrics.jsonl (losses and evaluations), each atomically."
)]
struct Args {
    #[command(subcommand)]
    command: Option<Command>,
    /// Trajectory table to train on (from `pgser-etl convert` or `collect`).
    #[arg(long, required = true)]
    data: Option<PathBuf>,
    /// Checkpoint to write.
    #[arg(short, long, required = true)]
    output: Option<PathBuf>,
    /// Continue the interrupted run whose checkpoint is --output (same settings and data).
    #[arg(long)]
    resume: bool,
    /// Train one agent per seed at once, as one stack of networks (the seeds of a grid cell):
    /// --output is then a folder that gets OUT/s<SEED>.ckpt for each. Same results as separate
    /// runs with --seed, in a fraction of the time.
    #[arg(long, value_delimiter = ',', num_args = 1.., conflicts_with = "seed")]
    seeds: Vec<u64>,
    /// Print a JSON summary as the last line of stdout.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    run: Run,
    #[command(flatten)]
    config: TrainConfig,
}

/// Where and on how many threads to compute.
#[derive(clap::Args, Clone, Copy)]
struct Run {
    /// Backend of the networks.
    #[arg(long, value_enum, default_value = "cpu", global = true)]
    device: Backend,
    /// Worker threads (default: all cores). Results depend on the seed, not on this.
    #[arg(long, global = true)]
    threads: Option<usize>,
}

#[derive(Subcommand)]
enum Command {
    /// Evaluate a checkpoint's policy in its task's environment.
    #[command(after_help = "Examples:\n  pgser-train eval --ckpt run.ckpt --episodes 50 --seed 1000000 --json\n  \
        pgser-train eval --ckpt out/agents/td3bc_mem_s*.ckpt --episodes 250 --json\n  \
        pgser-train eval --random --task FetchPush --episodes 50\n\n\
        Several checkpoints are evaluated one after another on the same episodes, one line each (with --json, \
        one JSON object each, naming its checkpoint). OGBench's mazes cycle through their 5 tasks by episode and \
        report each task's success: --episodes 250 is OGBench's protocol (5 x 50).")]
    #[command(group = clap::ArgGroup::new("policy").required(true).args(["ckpt", "random"]))]
    Eval {
        /// Checkpoint(s) whose actor to run.
        #[arg(long, num_args = 1..)]
        ckpt: Vec<PathBuf>,
        /// Run uniform random actions instead (the baseline), in --task.
        #[arg(long, requires = "task")]
        random: bool,
        /// Task for --random.
        #[arg(long)]
        task: Option<String>,
        #[arg(long, default_value_t = 50)]
        episodes: usize,
        /// Episode i is reset with seed S+i.
        #[arg(long, default_value_t = 1_000_000)]
        seed: u64,
        #[arg(long)]
        json: bool,
    },
    /// Train an expert online: DDPG + HER with MRN's settings in a pgser environment
    /// (docs/online.md). Writes OUT, OUT.resume, OUT.metrics.jsonl (one line per epoch) and
    /// OUT.buffer.parquet (the replay buffer, for --resume).
    #[command(after_help = "Examples:\n  \
        pgser-train online --task HandManipulateBlockRotateZ -o out/experts/block_z/expert.ckpt\n  \
        pgser-train online --task HandManipulateBlockRotateZ -o out/experts/block_z/expert.ckpt --resume\n  \
        pgser-train online --task FetchReach --epochs 5 --cycles 10 --episodes-per-cycle 2 -o reach.ckpt --json")]
    Online {
        /// Checkpoint to write (the other files go beside it).
        #[arg(short, long)]
        output: PathBuf,
        /// Continue the run whose checkpoint is --output (same settings; --epochs may grow).
        #[arg(long)]
        resume: bool,
        #[command(flatten)]
        cfg: train::online::OnlineConfig,
        /// Print a JSON summary as the last line of stdout.
        #[arg(long)]
        json: bool,
    },
    /// Write the first batches a run would train on as a table (one row per sampled transition):
    /// the same flags and seed as the run give the same batches.
    #[command(
        after_help = "Examples:\n  pgser-train batches --data traj.parquet --swap random --count 10 -o batches.parquet\n  \
        pgser-train batches --data scored.parquet --is-beta 0.4 --seed 3 --count 100 -o mem.parquet"
    )]
    Batches {
        /// Trajectory or scored table, as `--data` of a run.
        #[arg(long)]
        data: PathBuf,
        /// Batches to write.
        #[arg(long, default_value_t = 10)]
        count: u64,
        /// Table to write.
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        config: TrainConfig,
        #[arg(long)]
        json: bool,
    },
    /// Time the prioritized sampler alone on a scored table (from disk, or --in-memory).
    #[command(
        after_help = "Example:\n  pgser-train bench-sampler --data scored.parquet --batch-size 256 --batches 2000 --json"
    )]
    BenchSampler {
        #[arg(long)]
        data: PathBuf,
        #[arg(long, default_value_t = 256)]
        batch_size: usize,
        #[arg(long, default_value_t = 2000)]
        batches: u64,
        #[arg(long)]
        in_memory: bool,
        #[command(flatten)]
        priority: pgser::sampler::priority::PriorityConfig,
        /// Time the whole batch stream of a stack instead (what the host does per update on a
        /// GPU): --agents cells, each drawing β's rows (HER, --swap) and, from a scored table,
        /// --aug-ratio of its rows by priority, as row numbers with their rewards.
        #[arg(long)]
        stream: bool,
        /// With --stream: cells in the stack.
        #[arg(long, default_value_t = 1)]
        agents: usize,
        /// With --stream: also build the batches on the host (what the CPU engine trains on).
        #[arg(long)]
        gather: bool,
        /// With --stream and a scored table: the share of each batch drawn by priority.
        #[arg(long, default_value_t = 0.5)]
        aug_ratio: f64,
        #[command(flatten)]
        sampler: pgser::sampler::SamplerConfig,
        #[arg(long)]
        json: bool,
    },
    /// Compile the CUDA engine's kernels (`--device cuda`) with NVRTC, here, with or without a
    /// GPU: the NVRTC version and each kernel's registers and spills; with --cubin, the image,
    /// for a GPU machine without NVRTC (PGSER_CUDA_CUBIN=FILE).
    #[command(
        after_help = "Examples:\n  pgser-train cuda-kernels\n  pgser-train cuda-kernels --arch sm_90 --cubin kernels_sm90.cubin --json"
    )]
    CudaKernels {
        /// Target: sm_XY (a cubin for compute capability X.Y).
        #[arg(long, default_value = "sm_90")]
        arch: String,
        /// Write the cubin here.
        #[arg(long)]
        cubin: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Time the update alone on random batches (what `make bench` compares with PyTorch); with
    /// --agents A, A agents trained at once as one stack (agent-updates/s = A × updates/s).
    #[command(after_help = "Examples:\n  pgser-train bench --task FetchPush --batch-size 512 --updates 300 --json\n  \
                            pgser-train bench --agents 10 --updates 50 --threads 2")]
    Bench {
        #[arg(long, default_value = "FetchPush")]
        task: String,
        /// Agents trained at once, each on its own batches (seeds 0..A).
        #[arg(long, default_value_t = 1)]
        agents: usize,
        #[arg(long, default_value_t = 512)]
        batch_size: usize,
        #[arg(long, default_value_t = 300)]
        updates: u64,
        #[arg(long, default_value_t = 20)]
        warmup: u64,
        #[command(flatten)]
        agent: AgentConfig,
        #[arg(long)]
        json: bool,
    },
}

pub(crate) fn main() -> ExitCode {
    let args = Args::parse();
    cli::main_with("pgser-train", || {
        if let Some(n) = args.run.threads {
            rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
        }
        let device = args.run.device.device()?;
        match args.command {
            Some(Command::Eval { ckpt, random, task, episodes, seed, json }) => {
                let runs: Vec<(eval::EvalReport, String, String)> = if random {
                    let name = task.expect("clap requires --task with --random");
                    let t = pgser::env::task(&name)?;
                    let policy = eval::RandomPolicy::new(t.act_dim, seed);
                    vec![(eval::evaluate(&t.name, &policy, episodes, seed)?, "random policy".to_string(), t.name)]
                } else {
                    let mut runs = Vec::with_capacity(ckpt.len());
                    for c in &ckpt {
                        let (agent, _) = checkpoint::load(c, device.clone())?;
                        let report = eval::evaluate(&agent.task.name, &agent, episodes, seed)?;
                        runs.push((report, c.display().to_string(), agent.task.name));
                    }
                    runs
                };
                for (report, what, task) in runs {
                    if json {
                        let mut v = serde_json::to_value(&report)?;
                        if !random {
                            v["checkpoint"] = serde_json::Value::String(what);
                        }
                        println!("{v}");
                        continue;
                    }
                    println!("{what}: {}", report.summary(&task));
                }
            }
            Some(Command::Online { output, resume, cfg, json }) => {
                // SIGTERM saves at the next cycle boundary and stops (a long run killed by a
                // time limit or `kill` loses nothing).
                train::stop::install()?;
                let bar = progress::bar("online", "cycles");
                let s =
                    train::online::train_online(&cfg, &output, resume, args.run.device, &cli::command_line(), &bar)?;
                let eval = s.eval.as_ref().map_or(String::new(), |e| {
                    format!(
                        "; eval over {} episodes: success {:.3}, return {:.2}",
                        e.episodes, e.success_rate, e.return_mean
                    )
                });
                let stopped = if s.finished { "" } else { " (stopped by --max-minutes; continue with --resume)" };
                eprintln!(
                    "{}: {} cycles, epoch {}{stopped} ({} updates, {} env steps): {:.0} env steps/s, {:.1} updates/s{eval}",
                    s.checkpoint.display(),
                    s.cycles,
                    s.epochs,
                    s.updates,
                    s.env_steps,
                    s.env_steps_per_sec,
                    s.updates_per_sec
                );
                if json {
                    println!("{}", serde_json::to_string(&s)?);
                }
            }
            Some(Command::Batches { data, count, output, config, json }) => {
                let cmd = cli::command_line();
                let r = pgser::sampler::dump::write_batches(
                    &data,
                    &config.stream(),
                    config.budget(),
                    count,
                    &output,
                    &cmd,
                )?;
                if json {
                    println!("{}", serde_json::to_string(&r)?);
                } else {
                    println!("{}: {} batches, {} rows, {} bytes", r.output.display(), r.batches, r.rows, r.bytes);
                }
            }
            Some(Command::BenchSampler {
                data,
                batch_size,
                batches,
                in_memory,
                priority,
                stream: true,
                agents,
                gather,
                aug_ratio,
                sampler,
                json,
            }) => {
                let cfg = pgser::sampler::stream::StreamConfig {
                    sampler,
                    batch_size,
                    aug_ratio,
                    priority,
                    aug_in_memory: in_memory,
                    seed: 0,
                };
                let r = train::bench_stream(&data, &cfg, agents.max(1), batches.max(1), gather)?;
                if json {
                    println!("{}", serde_json::to_string(&r)?);
                } else {
                    println!(
                        "{}: {} cells × batches of {}{} on {} threads: {:.0} stack updates/s, {:.0} agent-updates/s, {:.2e} rows/s",
                        data.display(),
                        r.agents,
                        r.batch_size,
                        if r.gather { ", built on the host" } else { " as row numbers" },
                        r.threads,
                        r.updates_per_sec,
                        r.agent_updates_per_sec,
                        r.rows_per_sec
                    );
                }
            }
            Some(Command::BenchSampler { data, batch_size, batches, in_memory, priority, json, .. }) => {
                let r = train::bench_sampler(&data, &priority, batch_size, batches.max(2), in_memory)?;
                if json {
                    println!("{}", serde_json::to_string(&r)?);
                } else {
                    println!(
                        "{}: {} rows, {} batches of {} from {}: {:.0} samples/s (setup {:.2} s)",
                        data.display(),
                        r.rows,
                        r.batches,
                        r.batch_size,
                        if r.in_memory { "memory" } else { "disk" },
                        r.samples_per_sec,
                        r.setup_seconds
                    );
                }
            }
            Some(Command::CudaKernels { arch, cubin, json }) => {
                let r = pgser::agent::cuda::nvrtc::report(&arch, cubin.as_deref())?;
                if json {
                    println!("{}", serde_json::to_string(&r)?);
                } else {
                    let what = if r.arch.starts_with("sm_") { "a cubin" } else { "PTX" };
                    println!("NVRTC {} for {}: {what} of {} bytes", r.nvrtc, r.arch, r.cubin_bytes);
                    for (k, regs, stores, loads) in &r.kernels {
                        println!("  {k}: {regs} registers, spills {stores} B stored / {loads} B loaded");
                    }
                }
            }
            Some(Command::Bench { task, agents, batch_size, updates, warmup, agent, json }) => {
                let task = Task::known(&task).ok_or_else(|| anyhow::anyhow!("{task}: unknown task"))?;
                if agents == 0 {
                    anyhow::bail!("--agents must be at least 1");
                }
                let r = train::bench_agents(&task, &agent, batch_size, updates, warmup, args.run.device, agents)?;
                if json {
                    println!("{}", serde_json::to_string(&r)?);
                } else {
                    println!(
                        "{} {:?} batch {} on {} ({} threads), {} agent(s) in {} stack(s): {:.1} updates/s, {:.1} agent-updates/s",
                        r.task,
                        r.algo,
                        r.batch_size,
                        r.backend,
                        r.threads,
                        r.agents,
                        r.shards,
                        r.updates_per_sec,
                        r.agent_updates_per_sec
                    );
                }
            }
            None => {
                let (data, out) = (args.data.expect("required"), args.output.expect("required"));
                let bar = progress::bar("training", "updates");
                let cells: Vec<train::Cell> = if args.seeds.is_empty() {
                    vec![train::Cell { data, out, cfg: args.config.clone(), resume: args.resume }]
                } else {
                    std::fs::create_dir_all(&out)
                        .map_err(|e| anyhow::anyhow!("{}: cannot create the output folder: {e}", out.display()))?;
                    args.seeds
                        .iter()
                        .map(|&seed| train::Cell {
                            data: data.clone(),
                            out: out.join(format!("s{seed}.ckpt")),
                            cfg: TrainConfig { seed, ..args.config.clone() },
                            resume: args.resume,
                        })
                        .collect()
                };
                let commands = vec![cli::command_line(); cells.len()];
                let summaries = train::train_stack(&cells, args.run.device, &commands, &bar)?;
                for s in &summaries {
                    if let Some(e) = &s.eval {
                        eprintln!(
                            "{}: {} updates ({:.1}/s); eval over {} episodes: return {:.2} ± {:.2}, success {:.3}, paper score {:.2}",
                            s.checkpoint.display(),
                            s.updates,
                            s.updates_per_sec,
                            e.episodes,
                            e.return_mean,
                            e.return_std,
                            e.success_rate,
                            e.paper_score
                        );
                    }
                }
                if args.json {
                    match summaries.as_slice() {
                        [one] if args.seeds.is_empty() => println!("{}", serde_json::to_string(one)?),
                        all => println!("{}", serde_json::to_string(all)?),
                    }
                }
            }
        }
        Ok(())
    })
}
