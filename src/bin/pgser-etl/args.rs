//! `pgser-etl`'s flags: every command and its options as clap reads them (`main.rs` calls the
//! library with them).

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use pgser::agent::Backend;
use pgser::{convert, minari, pipeline, score};

#[derive(Parser)]
#[command(
    name = "pgser-etl",
    version,
    long_version = pgser::cli::LONG_VERSION.as_str(),
    about = "pgser data jobs: convert, collect, score, pipeline, report, fig5, study, table2, query, export, verify, inspect"
)]
pub struct Args {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Convert WGCSL-style pickles (without executing them), a Minari dataset or an OGBench file into a Parquet trajectory table, every array kept.
    #[command(after_help = "Examples:\n  pgser-etl convert expert.pkl -o traj.parquet --task FetchPush\n  \
        pgser-etl convert expert.pkl random.pkl --episodes 500,2000 -o mix.parquet --task FetchPush\n  \
        pgser-etl convert point.pkl -o point.parquet --task PointReach --threshold 0.05\n  \
        pgser-etl convert ~/.minari/datasets/fetchreach-expert-v0 -o traj.parquet\n  \
        pgser-etl convert pointmaze-medium-navigate-v0.npz -o traj.parquet\n  \
        pgser-etl convert buffer.pkl -o traj.parquet --task FetchPush --drop debug_info\n\n\
        Every array of a pickle or OGBench file that is not o, ag, u, g (observations, actions), and every key of a \
        Minari dataset's infos (as infos/KEY), becomes a column of \
        its own (info_is_success, qpos, qvel, …), with its dtype and shape in the footer, so that export gives the \
        source back whole; one a column cannot hold is refused by name (--drop KEY leaves it out). See docs/tables.md.\n\n\
        A Minari dataset (HDF5 or Arrow storage) must be goal-conditioned (a Dict observation with observation, \
        achieved_goal, desired_goal) with episodes of one length: n steps become T = n+1 rows (where n+1 is the task's T+1, as \
        gymnasium's time limit records Fetch episodes, the last step is dropped; --exact-length refuses). The task is \
        --task, else the id of the dataset's env_spec (FetchReach-v4 is FetchReach). See docs/minari.md.")]
    Convert(convert::ConvertOptions),
    /// Simulate episodes in a Fetch, hand or PointMaze environment (expert, trained, random or OGBench's oracle) into a table, pickle or OGBench file.
    #[command(
        after_help = "Examples:\n  pgser-etl collect --task FetchPush --policy expert --episodes 500 --seed 0 -o expert.parquet\n  \
        pgser-etl collect --task FetchPush --policy random --episodes 2000 --seed 1000 -o random.pkl\n  \
        pgser-etl collect --task FetchReach --policy expert --noise 0.1 --episodes 50 --seed 0 -o noisy.pkl\n  \
        pgser-etl collect --task HandManipulateBlockRotateZ --policy random --episodes 2000 --seed 1000 -o random.parquet\n  \
        pgser-etl collect --task HandManipulateBlockRotateZ --policy checkpoint:data/experts/block_z.ckpt --episodes 500 -o expert.parquet\n  \
        pgser-etl collect --task pointmaze-medium-navigate-v0 --policy oracle --episodes 1000 -o pointmaze-medium-navigate-v0.npz\n\n\
        Episode i resets with seed S+i, as a newly made gymnasium env's reset(seed=S+i) does. --policy oracle makes \
        OGBench's PointMaze datasets by their recipe (docs/ogbench.md): the dataset name gives the maze, navigate or \
        stitch and the episode length; episode i seeds numpy's generator with S+i; a .npz output gets its -val.npz \
        beside it."
    )]
    Collect {
        /// Task: FetchReach, FetchPush, FetchPickAndPlace, FetchSlide (optionally -v4),
        /// HandManipulateBlockRotateZ or HandManipulateEggRotate (optionally -v1); with --policy
        /// oracle an OGBench PointMaze dataset (pointmaze-medium-navigate-v0, pointmaze-large-stitch-v0).
        #[arg(long)]
        task: String,
        /// Who acts: `expert` (the scripted Fetch experts), `random` (uniform actions),
        /// `checkpoint:FILE` (agent 0's actor of a pgser checkpoint of the same task), or `oracle`
        /// (OGBench's PointMaze data recipe).
        #[arg(long)]
        policy: String,
        /// Number of episodes.
        #[arg(long)]
        episodes: usize,
        /// Episode i resets the environment with seed S+i; policy noise comes from (S, i).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output: .parquet (trajectory table) or .pkl (WGCSL pickle); with --policy oracle .npz
        /// (OGBench's dataset file, and its -val.npz) or .parquet; written atomically.
        #[arg(short, long)]
        output: PathBuf,
        /// Standard deviation of Gaussian noise added to expert, checkpoint or oracle actions (then
        /// clipped to [-1, 1]) [default: 0; oracle: 0.5, OGBench's]
        #[arg(long)]
        noise: Option<f64>,
        /// Probability of a uniform random action instead of the expert's or checkpoint's, per step.
        #[arg(long, default_value_t = 0.0)]
        epsilon: f64,
        /// Store float32 vectors in the table (default float64, as WGCSL pickles).
        #[arg(long)]
        float32: bool,
        /// Target rows per row group (row groups always hold whole episodes).
        #[arg(long, default_value_t = 65_536)]
        row_group_rows: usize,
    },
    /// Goal-swap every transition of a trajectory table and score each row with a critic (Alg. 2).
    #[command(after_help = "Examples:\n  pgser-etl score --q pretrain.ckpt --data traj.parquet -o scored.parquet\n  \
        pgser-etl score --q pretrain.ckpt --data traj.parquet -o scored.parquet --swaps 8 --seed 1 --include-original\n\n\
        Each transition (s, a, s') gets K goals drawn uniformly from the achieved goals of the whole table \
        (goal_episode, goal_step), reward R(next_achieved_goal, goal) and q = min(Q1, Q2)(s, goal, a). With \
        --include-original its own desired goal comes first, marked goal_step = -1. The output depends on the \
        inputs, --seed and --chunk-episodes, not on the thread count.\n\n\
        A table folder scored to an output without .parquet gives a scored folder: one scored shard per shard \
        (goals from every shard), then its manifest. Shards already scored with the same inputs and settings are \
        kept; --shard I scores one, as a task of a cluster's array job:\n  \
        pgser-etl score --q q.ckpt --data pm100m/ -o scored/ --shard 7\n  \
        pgser-etl score --q q.ckpt --data pm100m/ -o scored/")]
    Score {
        /// The pre-trained checkpoint (`pgser-train -o model.ckpt`) whose twin critics score the rows.
        #[arg(long = "q", value_name = "CKPT")]
        checkpoint: PathBuf,
        /// Trajectory table (`pgser-etl convert` / `collect`) of the same task.
        #[arg(long)]
        data: PathBuf,
        /// Output transition table (written atomically).
        #[arg(short, long)]
        output: PathBuf,
        /// Swapped goals per transition.
        #[arg(long, default_value_t = score::DEFAULT_SWAPS)]
        swaps: usize,
        /// Seed of the goal draws (chunk c draws from the stream spawned from (seed, c)).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Also write each transition with its own desired goal (goal_episode = episode, goal_step = -1).
        #[arg(long)]
        include_original: bool,
        /// Where the critic runs.
        #[arg(long, value_enum, default_value = "cpu")]
        device: Backend,
        /// Episodes per chunk: the unit of parallel work, of random streams and of row groups
        /// [default: as many as make about 12.5k rows].
        #[arg(long)]
        chunk_episodes: Option<usize>,
        /// Draw goals from K achieved goals sampled uniformly from the whole table (drawn from --seed), not
        /// from all of them: holds K goals instead of the table's (8 GB at a billion PointMaze rows)
        /// [default: every achieved goal].
        #[arg(long, value_name = "K")]
        goal_sample: Option<usize>,
        /// Worker threads (0: RAYON_NUM_THREADS, else one per core). Does not change the output.
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// With a table folder scored into a folder (-o without .parquet): score only shard I (0-based), as
        /// one task of a cluster's array job; a run without --shard then scores what is missing and writes
        /// the manifest.
        #[arg(long, value_name = "I")]
        shard: Option<usize>,
        /// Also print the summary as one JSON line on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Run an experiment file of pipelines/: data, Q pre-training, scoring, report, agents, results.
    #[command(subcommand)]
    Pipeline(PipelineCommand),
    /// PGSER end to end on 20 expert FetchReach episodes (about 4 minutes on 2 cores): what `make demo` runs.
    #[command(after_help = "Examples:\n  pgser-etl demo\n  pgser-etl demo ~/pgser-demo --threads 2\n\n\
        Writes the demo's pipeline file (demo.toml) and the pickle it reads into DIR, both carried inside pgser, then runs \
        it there: the pre-trained Q, the scored swaps, TD3+BC baseline / -swap / -mem over 3 seeds, Fig. 5, Table 1 and \
        the results table with Welch's t-tests, and the random policy for scale. A second run repeats only what changed; \
        `pgser-etl pipeline run DIR/demo.toml` runs the same file after you edit it.")]
    Demo {
        /// The folder for the pipeline file, its data and every output (created if absent).
        #[arg(default_value = "pgser-demo")]
        dir: PathBuf,
        /// Where the networks run.
        #[arg(long, value_enum, default_value = "cpu")]
        device: Backend,
        /// Worker threads (default: all cores). Results do not depend on it.
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Fig. 5 and Table 1: how well the scoring critic's Q separates own goals from swapped ones.
    #[command(after_help = "Examples:\n  pgser-etl report scored.parquet -o report/\n  \
        pgser-etl report scored.parquet -o report/ --positive-episodes 500 --seed 1 --json\n\n\
        Positives: the transitions of the first N episodes of the scored table's source with their own goals, \
        scored with the checkpoint its footer names (N defaults to the episodes taken from the first source \
        file, the expert one in `convert expert.pkl random.pkl`). Negatives: as many goal-swapped rows of the \
        table. Writes DIR/fig5_q_hist.png, DIR/table1.md and DIR/table1.json. Beneath Table 1: for each --share \
        setting, the share of the -mem sampler's draws whose Q lies above the positives' median, against uniform \
        drawing's.")]
    Report {
        /// A transition table from `pgser-etl score`.
        scored: PathBuf,
        /// Output folder (created if missing).
        #[arg(short, long)]
        output: PathBuf,
        /// Positives come from the first N episodes of the source trajectory table.
        #[arg(long)]
        positive_episodes: Option<usize>,
        /// Seed of the subsamples and of the train/test split.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// At most this many samples per class.
        #[arg(long, default_value_t = 20_000)]
        max_samples: usize,
        /// At most this many training rows for the SVC (its training time grows as n² or faster).
        #[arg(long, default_value_t = 2_000)]
        svm_max_train: usize,
        /// A priority setting KIND[:ALPHA[:EPS]] (q:1, q:3, rank:1, uniform) whose share of draws
        /// above the own-goal median Q to report; repeat for several [default: rank:1, pgser-train's].
        #[arg(long = "share", value_parser = parse_share)]
        shares: Vec<pgser::sampler::priority::PriorityConfig>,
        /// Print the report as JSON instead of the markdown table.
        #[arg(long)]
        json: bool,
    },
    /// Fig. 5 and Table 1 across tasks: a panel per task from several reports' table1.json.
    #[command(
        after_help = "Example:\n  pgser-etl fig5 out/fetch_*_grid_cpu/report out/hand_*_grid_cpu/report -o fig5/\n\n\
        Each input is a table1.json of `pgser-etl report` (a pipeline's report step), or the folder holding it. \
        Panels follow the paper's task order, three to a row. Two reports of one task with the same numbers \
        (a task whose grid was split in two pipelines, one per learner) are drawn once; with other numbers, refused. Writes DIR/fig5_all.png and DIR/table1_all.md \
        (each classifier's accuracy with the paper's negatives and with the controlled ones, per task, and beneath it \
        the paper's own Table 1 accuracy for that classifier, compiled in from assets/paper_table1.csv)."
    )]
    Fig5 {
        /// Reports: table1.json files or their folders.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Output folder (created if missing).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// A study across pipelines: arms that differ in one thing (Q's budget, the priority), in one table and one figure.
    #[command(after_help = "Example:\n  pgser-etl study pipelines/fetch_push_qbudget_study.toml\n\n\
        The file lists [[arm]]s, each a pipeline's results folder (its results.csv) and the variant or named arm to \
        take from it, optionally the report of the Q it sampled with (table1.json) and the priority it drew with. \
        Arms with x are the study's points, joined by series; arms without are references, each point tested \
        against each (Welch, two-sided, over seed means). Writes OUT/study.md, study.csv and study.png.")]
    Study {
        /// The study file (TOML).
        file: PathBuf,
        /// Print the rows as JSON instead of the markdown table.
        #[arg(long)]
        json: bool,
    },
    /// The paper's Table 2 across tasks: several pipelines' results.csv in one table, the paper's values beside.
    #[command(
        after_help = "Examples:\n  pgser-etl table2 results/fetch_*_grid_cpu/results.csv results/hand_*_grid_cpu/results.csv -o table2/\n  \
        pgser-etl table2 out/fetch_push/results/results.csv -o table2/ --reference my_table2.csv\n  \
        pgser-etl table2 results/*_grid_cpu/results.csv -o table2/ --chosen results/*_priority_*_cpu/results.csv\n\n\
        Rows TD3BC-mem, TD3BC-swap, TD3BC, TD3-mem, TD3-swap, TD3, each three times: mean +- std over the seeds' \
        means, the same over all evaluation episodes pooled, and the paper's value with its marks; a column per \
        task of the paper (FetchReach, FetchPush, FetchPick, FetchSlide, HandBlock-Z, HandEgg-Rotate). A task with \
        no results is marked 'not run'; a cell given twice, a task or row the paper does not have, or a task with \
        only some of its six agents is an error. Welch's t-test marks mem and swap against the baseline and mem \
        against swap, over seed means (the marks of the first row) and over pooled episodes (the second); the \
        pooled spread comes from the results.csv or the scores.csv beside it, and is n/a for results that kept \
        neither. A line per task says whether mem >= swap >= baseline holds here and in the paper, and where \
        each test agrees with the paper's marks. Writes DIR/table2.md and DIR/table2.csv. With --chosen, a second \
        section gives the -mem arm those files train (--chosen-arm, --chosen-setting) per task and learner, marked \
        against the baseline and swap trained beside it, its share of draws above the own-goal median Q, and the \
        counts against the paper for both settings; its cells also go to DIR/table2_chosen.csv."
    )]
    Table2 {
        /// results.csv files (a pipeline's out folder has one under results/).
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Output folder (created if missing).
        #[arg(short, long)]
        output: PathBuf,
        /// The paper's values (CSV: task,agent,mean,std[,significant_vs_baseline,significant_vs_swap];
        /// '#' lines name the source). Default: the copy compiled in, from the paper's Table 2.
        #[arg(long)]
        reference: Option<PathBuf>,
        /// Print a JSON summary instead of the markdown table.
        #[arg(long)]
        json: bool,
        /// results.csv files of pipelines that train one more -mem arm beside their own baseline and swap
        /// (pipelines/*_priority_*_cpu.toml): Table 2 gains that setting's rows, its share of draws above the
        /// own-goal median (from the table1.json beside each file), and its counts against the paper.
        #[arg(long, num_args = 1..)]
        chosen: Vec<PathBuf>,
        /// The arm's name in the --chosen files (their variant column).
        #[arg(long, default_value = "mem_rank", requires = "chosen")]
        chosen_arm: String,
        /// The arm's priority setting, KIND[:ALPHA] (q:3, rank:1), which names its rows and finds its share.
        #[arg(long, default_value = "rank:1", requires = "chosen")]
        chosen_setting: String,
    },
    /// Run SQL over pgser tables and CSV files (polars' SQL on lazy scans); print or write the result.
    #[command(
        after_help = "Each FILE is a table named by its file stem (scored.parquet is `scored`), or by NAME=FILE. \
        Vector columns (obs, goal, …) are arrays. The result goes to \
        stdout as CSV, or with -o to a file in the format its name or --csv/--json/--parquet says.\n\n\
        Examples:\n  \
        # mean Q and reward per goal episode of a scored table (the swapped rows only)\n  \
        pgser-etl query \"SELECT goal_episode, AVG(q) AS mean_q, AVG(reward) AS mean_reward, COUNT(*) AS n \
        FROM scored WHERE goal_step >= 0 GROUP BY goal_episode ORDER BY goal_episode\" scored.parquet\n  \
        # success rate per task over all runs of a results table (pgser-train runs, Table 2)\n  \
        pgser-etl query \"SELECT task, SUM(success_mean * seeds) / SUM(seeds) AS success_rate, SUM(seeds) AS runs \
        FROM results GROUP BY task ORDER BY task\" results/fetch_push_cpu/results.csv\n  \
        # episodes of a trajectory table by their last step, to Parquet\n  \
        pgser-etl query \"SELECT episode, achieved_goal FROM traj WHERE step = 49\" traj.parquet -o last.parquet\n  \
        # rows with their own goal and with a swapped one, as JSON Lines\n  \
        pgser-etl query \"SELECT goal_step = -1 AS original, COUNT(*) AS n FROM s GROUP BY original\" \
        s=scored.parquet --json"
    )]
    Query {
        /// One SQL statement (polars' SQL dialect: SELECT, WHERE, GROUP BY, JOIN, ORDER BY, LIMIT, …).
        sql: String,
        /// Input tables: FILE (.parquet or .csv) or NAME=FILE.
        #[arg(required = true, value_name = "FILE")]
        inputs: Vec<String>,
        /// Output file (written atomically; nothing is left when the query fails).
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Write CSV (the default on stdout).
        #[arg(long, group = "format")]
        csv: bool,
        /// Write JSON Lines, one object per row.
        #[arg(long, group = "format")]
        json: bool,
        /// Write Parquet (needs -o).
        #[arg(long, group = "format")]
        parquet: bool,
    },
    /// Write a trajectory table out as a Minari dataset (Arrow storage), a WGCSL pickle or an OGBench file, with its source's other arrays.
    #[command(
        after_help = "Examples:\n  pgser-etl export traj.parquet --format minari -o ~/.minari/datasets/fetchreach-expert-v0\n  \
        pgser-etl export traj.parquet --format wgcsl -o expert.pkl\n  \
        pgser-etl export traj.parquet --format ogbench -o pointmaze-medium-navigate-v0.npz\n  \
        pgser-etl export og.parquet --format wgcsl -o og.pkl --drop last_action\n\n\
        A Minari dataset is a folder named by its dataset id (NAME-vN); `minari.load_dataset(\"NAME-vN\")` opens \
        it when MINARI_DATASETS_PATH is its parent folder. Its Arrow storage holds each episode's observations \
        (Dict: observation, achieved_goal, desired_goal), actions, the rewards, terminations and truncations a \
        Minari dataset's table kept (else rewards recomputed from the goals, the task's sparse reward, no \
        terminations and a truncation on the last step), and the table's per-step passthrough columns as its \
        infos (infos/KEY as KEY). A WGCSL pickle holds float64 arrays \
        (a float32 table widens exactly; a table converted from float32 pickles gives float32 back), and every \
        passthrough column as the array it was. An OGBench file holds observations, actions and terminals, and \
        the source's other per-row arrays (qpos, qvel, …) in their dtypes; a table from an OGBench file comes back \
        bit for bit, in its layout. What a format cannot hold (a per-transition array in an OGBench file, each \
        episode's last action in a WGCSL pickle) is refused by name: --drop NAME leaves it out. The output must \
        not exist; it appears whole or not at all."
    )]
    Export {
        /// A trajectory table (`pgser-etl convert` / `collect`).
        table: PathBuf,
        /// What to write.
        #[arg(long, value_enum)]
        format: minari::ExportFormat,
        /// The dataset folder (minari: its name is the dataset id, NAME-vN), pickle (wgcsl) or
        /// .npz file (ogbench: named after the dataset, NAME.npz) to create.
        #[arg(short, long)]
        output: PathBuf,
        /// Leave out a passthrough column (an array of the source that is not pgser's), or
        /// `last_action` (each episode's last action, which OGBench files have): the explicit choice
        /// where the format cannot hold it, which export otherwise refuses, naming it. Repeat for several.
        #[arg(long = "drop", value_name = "NAME")]
        drop: Vec<String>,
    },
    /// Check pgser files for corruption: a table's column chunks and a checkpoint's (or resume
    /// state's) tensors against the checksums written with them. One line per file; exit 1 if
    /// any is corrupt, naming its first corrupt row group and column, or tensor.
    #[command(after_help = "Examples:\n  pgser-etl verify out/fetch_push/*.parquet out/fetch_push/agents/*.ckpt\n  \
        pgser-etl verify traj.parquet q.ckpt q.ckpt.resume --json\n\n\
        Files written without checksums (an older pgser, another tool) are decoded in full and reported as \
        unverified: their values cannot be checked.")]
    Verify {
        /// Tables (.parquet) and checkpoints or resume states (safetensors).
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// One JSON object per file instead of a line.
        #[arg(long)]
        json: bool,
    },
    /// Show a table's schema, footer, counts, success rate and column statistics.
    #[command(after_help = "Example:\n  pgser-etl inspect traj.parquet --per-dim")]
    Inspect {
        file: PathBuf,
        /// Statistics for every vector component, not only per column.
        #[arg(long)]
        per_dim: bool,
        /// Print the summary as JSON.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
pub enum PipelineCommand {
    /// Run the steps of a pipeline file in order, skipping those already up to date.
    #[command(after_help = "Examples:\n  pgser-etl pipeline run pipelines/demo.toml\n  \
        pgser-etl pipeline run pipelines/fetch_push.toml --until score     # data and scored swaps only\n  \
        pgser-etl pipeline run pipelines/fetch_push.toml --dry-run         # what would run, and its cost\n  \
        pgser-etl pipeline run pipelines/demo.toml --jobs 2                # independent steps side by side\n  \
        pgser-etl pipeline run pipelines/fetch_push.toml --executor slurm --partition gpu --gpus-per-task 1 \\\n      \
        --device wgpu --sbatch-arg=--time=12:00:00 --array-parallelism 8  # as Slurm jobs\n\n\
        Before any step runs, the settings, input pickles, out folder and --device are checked, and the\n\
        cost of the steps to run is printed (updates, a wall time timed on this machine, disk).\n\
        A step is skipped when its record in OUT/.pipeline/ matches the sha256 of its parameters and\n\
        inputs (and pgser's version) and its outputs are unchanged; rerun after a crash or an edit and\n\
        only what changed runs (an interrupted training step continues from its last checkpoint).\n\n\
        --executor slurm submits each step that is not up to date as an sbatch job depending (afterok)\n\
        on the jobs writing its inputs, the agent grid as one job array (one element per stack of\n\
        `[agents] batch` cells), each job running `pgser-etl pipeline step`. Logs: OUT/.pipeline/logs/.\n\
        A training job sent SIGTERM (time limit, preemption, scancel --signal=TERM) saves its checkpoint\n\
        and fails; run again and it continues. See `pgser-etl pipeline status`.")]
    Run {
        /// The pipeline file (TOML; paths in it are relative to its folder).
        file: PathBuf,
        /// Stop after this step (names as printed, e.g. `score`, `report`, `agent td3bc_mem_s0`).
        #[arg(long)]
        until: Option<String>,
        /// Print which steps are up to date and which would run, and what they would cost, and run nothing.
        #[arg(long)]
        dry_run: bool,
        /// Skip the second or two of timing updates, episodes and scoring on this machine: the
        /// cost then says updates and disk but no wall time.
        #[arg(long)]
        no_measure: bool,
        /// Where the networks run.
        #[arg(long, value_enum, default_value = "cpu")]
        device: Backend,
        /// Worker threads (default: all cores). Results do not depend on it.
        #[arg(long)]
        threads: Option<usize>,
        /// Print the run's report as one JSON line on stdout.
        #[arg(long)]
        json: bool,
        /// Where the steps run: here, or as Slurm jobs submitted with sbatch.
        #[arg(long, value_enum, default_value = "local")]
        executor: pipeline::Executor,
        /// Local: run up to N independent steps (agent stacks, the report) at once, splitting
        /// --threads between them. Outputs do not depend on it.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
        jobs: u64,
        /// Slurm: the partition of every job.
        #[arg(long)]
        partition: Option<String>,
        /// Slurm: one more sbatch argument for every job (repeatable): --sbatch-arg=--time=4:00:00.
        #[arg(long = "sbatch-arg", value_name = "ARG", allow_hyphen_values = true)]
        sbatch_args: Vec<String>,
        /// Slurm: at most N elements of the agent array run at once (--array=…%N).
        #[arg(long, value_name = "N")]
        array_parallelism: Option<usize>,
        /// Slurm: GPUs for each training and scoring job.
        #[arg(long, value_name = "N")]
        gpus_per_task: Option<usize>,
        /// Slurm: wait for the jobs, then print the same summary as a local run (exit 1 if a
        /// step failed); without it, print the job ids and return.
        #[arg(long)]
        wait: bool,
    },
    /// Run named steps of a pipeline file as `pipeline run` would at their turn (what each Slurm job runs).
    #[command(after_help = "Example:\n  pgser-etl pipeline step pipelines/demo.toml pretrain\n  \
        pgser-etl pipeline step pipelines/demo.toml 'agent td3bc_mem_s0' 'agent td3bc_mem_s1'\n\n\
        Each step is skipped when up to date, takes its lock in OUT/.pipeline/locks/ first (a second\n\
        runner waits, then finds it up to date), and a training step continues from its checkpoint.\n\
        Agent cells of one stack train as one stack. Their inputs must exist. On SIGTERM a training\n\
        step saves its checkpoint at the next update and exits 1; running it again continues it.\n\n\
        With --shard I (the score step over a table folder, `[data] table`): scores only shard I into\n\
        the scored folder, under its own lock, and records nothing; `pipeline step FILE score` then\n\
        scores what is missing, writes the manifest and records the step. What each element of the\n\
        score step's Slurm job array runs.")]
    Step {
        /// The pipeline file.
        file: PathBuf,
        /// Step names as `pipeline run` prints them (`pretrain`, `agent td3bc_mem_s0`, …).
        #[arg(required = true)]
        steps: Vec<String>,
        /// Score only shard I (0-based) of the table folder β (one step, `score`, named).
        #[arg(long, value_name = "I")]
        shard: Option<usize>,
        /// Where the networks run.
        #[arg(long, value_enum, default_value = "cpu")]
        device: Backend,
        /// Worker threads (default: all cores this process may use). Results do not depend on it.
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Where each step of a pipeline stands: up to date, pending, running, failed, stopped or not started.
    #[command(after_help = "Example:\n  pgser-etl pipeline status pipelines/fetch_push.toml\n\n\
        From the step records, the step locks and, for steps submitted with --executor slurm, squeue.\n\
        A failed step's line names its log. A training step that saved part of its run (running, or\n\
        stopped: the next run continues it) says how far it got and its last evaluation, e.g.\n\
        \"agent td3_mem_s4: running (process 6655 on vm) — 7.5k of 30.0k updates saved; last\n\
        evaluation at 7.5k: paper score 21.20, success 0.54\".")]
    Status {
        /// The pipeline file.
        file: PathBuf,
        /// Print the states as one JSON line on stdout.
        #[arg(long)]
        json: bool,
    },
}

fn parse_share(s: &str) -> Result<pgser::sampler::priority::PriorityConfig, String> {
    pgser::report::parse_setting(s).map_err(|e| e.to_string())
}
