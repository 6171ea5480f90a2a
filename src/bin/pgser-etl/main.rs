//! `pgser-etl`: data jobs. Parses flags and calls the library; nothing else lives here.

use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use pgser::collect::policy::{PolicyKind, PolicySpec};
use pgser::{cli, collect, convert, inspect, minari, pipeline, progress, query, report, score};

mod args;

use args::{Args, Command, PipelineCommand};

/// Prints a run's report: its tables and summary, or one JSON line.
fn print_report(r: &pipeline::RunReport, json: bool) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string(r)?);
    } else {
        for t in [&r.table1, &r.results].into_iter().flatten() {
            println!("{}", std::fs::read_to_string(t).with_context(|| format!("{}: cannot read", t.display()))?);
        }
        print!("{}", pipeline::render(r));
    }
    Ok(())
}

pub(crate) fn main() -> ExitCode {
    let args = Args::parse();
    cli::main_with("pgser-etl", || {
        // The commands that train: SIGTERM saves at the next update boundary and stops
        // (`pgser::train::stop`). A process-wide handler is the binary's choice, not the library's.
        if matches!(
            args.command,
            Command::Pipeline(PipelineCommand::Run { .. } | PipelineCommand::Step { .. }) | Command::Demo { .. }
        ) {
            pgser::train::stop::install()?;
        }
        run(args.command)
    })
}

fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Convert(mut opts) => {
            opts.command = cli::command_line();
            let bar = progress::bar("convert", "rows");
            let s = convert::convert(&opts, &bar)?;
            bar.finish_and_clear();
            for k in &s.skipped_keys {
                eprintln!("pgser-etl: note: left out {k} (--drop)");
            }
            if !s.kept.is_empty() {
                eprintln!("pgser-etl: note: kept as columns of their own: {}", s.kept.join(", "));
            }
            for note in &s.notes {
                eprintln!("pgser-etl: note: {note}");
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
        Command::Collect { task, policy, episodes, seed, output, noise, epsilon, float32, row_group_rows } => {
            let kind = PolicyKind::parse(&policy)?;
            let noise = noise.unwrap_or(kind.default_noise());
            let opts = collect::CollectOptions {
                task,
                policy: PolicySpec { kind, noise, epsilon },
                episodes,
                seed,
                output,
                float32,
                row_group_rows,
                command: cli::command_line(),
            };
            let bar = progress::bar("collect", "episodes");
            let s = collect::collect(&opts, &bar)?;
            bar.finish_and_clear();
            eprintln!(
                "wrote {}: {} episodes of {} ({} policy), final-step success {:.3} ({}/{}), mean return {:.2}, \
                 {:.1} MB; {:.0} episodes/s, {:.0} steps/s",
                opts.output.display(),
                s.episodes,
                s.task.name,
                policy,
                s.successes as f64 / s.episodes as f64,
                s.successes,
                s.episodes,
                s.mean_return,
                s.bytes as f64 / 1e6,
                s.episodes as f64 / s.seconds,
                s.steps as f64 / s.seconds
            );
            Ok(())
        }
        Command::Score {
            checkpoint,
            data,
            output,
            swaps,
            seed,
            include_original,
            device,
            chunk_episodes,
            goal_sample,
            threads,
            shard,
            json,
        } => {
            let opts = score::ScoreOptions {
                checkpoint,
                data,
                output,
                swaps,
                seed,
                include_original,
                device,
                chunk_episodes,
                goal_sample,
                threads,
                shard,
                command: cli::command_line(),
            };
            let bar = progress::bar("score", "transitions");
            let s = score::score(&opts, &bar)?;
            bar.finish_and_clear();
            eprintln!(
                "wrote {}: {} rows ({} transitions × {}{}){}, q min/mean/max {:.3}/{:.3}/{:.3}, {:.1} MB; {:.2} s, \
                 {:.0} rows/s on {} threads",
                s.output.display(),
                s.rows,
                s.transitions,
                s.swaps,
                if s.include_original { " swaps + original" } else { " swaps" },
                s.goal_sample.map_or(String::new(), |k| format!(", goals from a sample of {k}")),
                s.q_min,
                s.q_mean,
                s.q_max,
                s.bytes as f64 / 1e6,
                s.seconds,
                s.rows_per_sec,
                s.threads
            );
            if json {
                println!("{}", serde_json::to_string(&s)?);
            }
            Ok(())
        }
        Command::Pipeline(PipelineCommand::Run {
            file,
            until,
            dry_run,
            no_measure,
            device,
            threads,
            json,
            executor,
            jobs,
            partition,
            sbatch_args,
            array_parallelism,
            gpus_per_task,
            wait,
        }) => {
            let slurm_only = [
                ("--partition", partition.is_some()),
                ("--sbatch-arg", !sbatch_args.is_empty()),
                ("--array-parallelism", array_parallelism.is_some()),
                ("--gpus-per-task", gpus_per_task.is_some()),
                ("--wait", wait),
            ];
            let p = pipeline::Pipeline::load(&file)?;
            let log = |line: &str| eprintln!("pipeline {}: {line}", p.name);
            if executor == pipeline::Executor::Slurm && !dry_run {
                anyhow::ensure!(jobs == 1, "--jobs is for --executor local; Slurm runs independent steps at once");
                let o = pipeline::slurm::SlurmOptions {
                    until,
                    device,
                    threads,
                    partition,
                    sbatch_args,
                    array_parallelism,
                    gpus_per_task,
                };
                let sub = pipeline::slurm::submit(&p, &file, &o, &log)?;
                if !wait {
                    for j in &sub.jobs {
                        println!("{}", if json { serde_json::to_string(j)? } else { j.id.clone() });
                    }
                    return Ok(());
                }
                let r = pipeline::slurm::wait(&p, &sub, &log)?;
                print_report(&r, json)?;
                return pipeline::finished(&r);
            }
            // `--executor slurm --dry-run` says which steps would be submitted; its flags are fine.
            let local = executor == pipeline::Executor::Local;
            if let Some((flag, _)) = slurm_only.iter().find(|(_, given)| *given && local) {
                anyhow::bail!("{flag} is for --executor slurm");
            }
            if let Some(n) = threads {
                rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
            }
            let o = pipeline::RunOptions { until, dry_run, device, measure: !no_measure, jobs: jobs as usize, threads };
            let r = pipeline::run(&p, &o, &log)?;
            print_report(&r, json)
        }
        Command::Demo { dir, device, threads } => {
            if let Some(n) = threads {
                rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
            }
            let o = pipeline::RunOptions { until: None, dry_run: false, device, measure: true, jobs: 1, threads };
            let (r, random) = pipeline::demo::run(&dir, &o, &|line| eprintln!("demo: {line}"))?;
            print_report(&r, false)?;
            pipeline::finished(&r)?;
            println!("for scale: {random}\n");
            print!("{}", pipeline::demo::EXPLAIN);
            Ok(())
        }
        Command::Pipeline(PipelineCommand::Step { file, steps, device, threads, shard }) => {
            if let Some(n) = threads {
                rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
            }
            let p = pipeline::Pipeline::load(&file)?;
            let log = |line: &str| eprintln!("pipeline {}: {line}", p.name);
            match (shard, steps.as_slice()) {
                (None, _) => drop(pipeline::step(&p, &steps, device, &log)?),
                (Some(i), [name]) => drop(pipeline::step_shard(&p, name, i, device, &log)?),
                (Some(i), _) => anyhow::bail!("--shard {i} scores a shard of one step: name that step alone (score)"),
            }
            Ok(())
        }
        Command::Pipeline(PipelineCommand::Status { file, json }) => {
            let p = pipeline::Pipeline::load(&file)?;
            let states = pipeline::status(&p)?;
            if json {
                println!("{}", serde_json::to_string(&states)?);
            } else {
                print!("{}", pipeline::render_status(&p, &states));
            }
            Ok(())
        }
        Command::Report { scored, output, positive_episodes, seed, max_samples, svm_max_train, shares, json } => {
            let defaults = report::QReportOptions::default();
            let opts = report::QReportOptions {
                scored,
                out_dir: output,
                positive_episodes,
                max_samples,
                svm_max_train,
                seed,
                priorities: if shares.is_empty() { defaults.priorities.clone() } else { shares },
                ..defaults
            };
            let r = report::q_report(&opts)?;
            if json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                print!("{}", report::table1_markdown(&r));
                println!("\nFig. 5: {}", r.fig5.display());
            }
            Ok(())
        }
        Command::Study { file, json } => {
            let s = report::study(&file)?;
            if json {
                println!("{}", serde_json::to_string(&s)?);
            } else {
                print_file(&s.markdown)?;
                eprintln!("wrote {}, {} and {}", s.markdown.display(), s.csv.display(), s.figure.display());
            }
            Ok(())
        }
        Command::Fig5 { inputs, output } => {
            let f = report::fig5_all(&report::Fig5Options { inputs, out_dir: output })?;
            print_file(&f.table1)?;
            eprintln!("wrote {} ({} panels) and {}", f.figure.display(), f.tasks.len(), f.table1.display());
            if !f.missing.is_empty() {
                eprintln!("no report for {}", f.missing.join(", "));
            }
            Ok(())
        }
        Command::Table2 { inputs, output, reference, json, chosen, chosen_arm, chosen_setting } => {
            let chosen = (!chosen.is_empty())
                .then(|| -> anyhow::Result<_> {
                    let setting = report::parse_setting(&chosen_setting)?;
                    Ok(report::ChosenOptions { inputs: chosen, arm: chosen_arm, setting })
                })
                .transpose()?;
            let t = report::table2(&report::Table2Options { inputs, reference, out_dir: output, chosen })?;
            if json {
                println!("{}", serde_json::to_string(&t)?);
            } else {
                print_file(&t.markdown)?;
                eprintln!("wrote {} and {}", t.markdown.display(), t.csv.display());
            }
            Ok(())
        }
        Command::Query { sql, inputs, output, csv, json, parquet } => {
            let format = [(csv, query::Format::Csv), (json, query::Format::Json), (parquet, query::Format::Parquet)]
                .into_iter()
                .find_map(|(on, f)| on.then_some(f));
            let rows = query::query(&query::QueryOptions { sql, inputs, format, output: output.clone() })?;
            if let Some(out) = output {
                eprintln!("wrote {}: {rows} rows", out.display());
            }
            Ok(())
        }
        Command::Export { table, format, output, drop } => {
            let s = convert::export(&minari::ExportOptions { table, format, output: output.clone(), drop })?;
            eprintln!("wrote {}: {} episodes of {} (T = {})", output.display(), s.episodes, s.task, s.t);
            Ok(())
        }
        Command::Verify { files, json } => {
            let mut corrupt = 0;
            for file in &files {
                match pgser::verify::verify(file) {
                    Ok(r) if json => println!("{}", serde_json::to_string(&r)?),
                    Ok(r) => println!("{}", r.line()),
                    Err(e) => {
                        corrupt += 1;
                        let line = format!("{e:#}").replace('\n', " ");
                        if json {
                            println!("{}", serde_json::json!({"path": file, "error": line}));
                        } else {
                            println!("CORRUPT {line}");
                        }
                    }
                }
            }
            if corrupt > 0 {
                anyhow::bail!("{corrupt} of {} files failed verification", files.len());
            }
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
    }
}

/// Prints a table the command wrote (its markdown) to stdout.
fn print_file(path: &std::path::Path) -> anyhow::Result<()> {
    print!("{}", std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))?);
    Ok(())
}
