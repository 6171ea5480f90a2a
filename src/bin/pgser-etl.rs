//! `pgser-etl`: data jobs. Parses flags and calls the library; nothing else lives here.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use pgser::{cli, inspect, progress, trajectory};

#[derive(Parser)]
#[command(
    name = "pgser-etl",
    version,
    long_version = pgser::cli::LONG_VERSION.as_str(),
    about = "pgser data jobs: convert, inspect"
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert WGCSL-style pickles into a Parquet trajectory table, without executing them.
    #[command(after_help = "Examples:\n  pgser-etl convert expert.pkl -o traj.parquet --task FetchPush\n  \
        pgser-etl convert expert.pkl random.pkl --episodes 500,2000 -o mix.parquet --task FetchPush\n  \
        pgser-etl convert point.pkl -o point.parquet --task PointReach --threshold 0.05")]
    Convert {
        /// Input pickles: dicts with o [N,T,obs], ag [N,T,goal], u [N,T-1,act], g [N,T-1,goal].
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Output Parquet file (written atomically).
        #[arg(short, long)]
        output: PathBuf,
        /// Task name (FetchReach, FetchPush, …); inferred from dimensions when unambiguous.
        #[arg(long)]
        task: Option<String>,
        /// Success threshold on the goal distance; required for tasks pgser does not know.
        #[arg(long)]
        threshold: Option<f64>,
        /// Take the first k episodes of each input, one count per input: `--episodes 500,2000`.
        #[arg(long, value_delimiter = ',')]
        episodes: Option<Vec<usize>>,
        /// Store float32 vectors even when the source is float64.
        #[arg(long)]
        float32: bool,
        /// Keep NaN and ±Inf values instead of refusing the file.
        #[arg(long)]
        allow_nonfinite: bool,
        /// Target rows per row group (row groups always hold whole episodes).
        #[arg(long, default_value_t = 65_536)]
        row_group_rows: usize,
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

fn main() -> ExitCode {
    let args = Args::parse();
    cli::main_with("pgser-etl", || match args.command {
        Command::Convert { inputs, output, task, threshold, episodes, float32, allow_nonfinite, row_group_rows } => {
            let opts = trajectory::ConvertOptions {
                inputs,
                output,
                task,
                threshold,
                episodes,
                float32,
                allow_nonfinite,
                row_group_rows,
                command: cli::command_line(),
            };
            let bar = progress::bar("convert", "rows");
            let s = trajectory::convert(&opts, &bar)?;
            bar.finish_and_clear();
            for k in &s.skipped_keys {
                eprintln!("pgser-etl: note: skipped {k} (not part of the WGCSL format)");
            }
            eprintln!(
                "wrote {}: {} episodes, {} rows, task {}, {} ({:.1} MB)",
                opts.output.display(),
                s.episodes,
                s.rows,
                s.task.name,
                s.float_type.name(),
                s.bytes as f64 / 1e6
            );
            Ok(())
        }
        Command::Inspect { file, per_dim, json } => {
            let s = inspect::inspect(&file)?;
            if json {
                println!("{}", serde_json::to_string(&s)?);
            } else {
                print!("{}", inspect::render(&s, per_dim));
            }
            Ok(())
        }
    })
}
