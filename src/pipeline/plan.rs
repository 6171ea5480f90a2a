//! The plan: a pipeline file's steps, in the order they run, each with its inputs, outputs,
//! parameters and the library call it makes (`mod.rs` says how a step is found up to date and
//! run). Planning reads no data: `check.rs` and `cost.rs` work from the plan before any step runs.
//! The one exception is a table folder's manifest (`[data] table`), a few KB, whose shard names
//! name the scored shards and the Slurm array's elements.

use super::*;

/// The steps of `p`, in the order they run.
pub fn plan(p: &Pipeline) -> Result<Vec<Step>> {
    let out = &p.out;
    let cmd = |step: &str| format!("pgser pipeline {} step {step}", p.name);
    let mut steps = Vec::new();
    // β: the given table as it is, or the table the data steps make.
    let traj = match &p.data {
        Data::Table { path } => path.clone(),
        _ => data_steps(p, &mut steps)?,
    };
    // A table folder is scored into a scored folder of one shard per β shard (each scored on its
    // own, a Slurm array element each); a single table into one scored table.
    let shards = match &p.data {
        Data::Table { path } if path.is_dir() => folder_shards(path)?,
        _ => vec![],
    };
    let scored = scored_path(p);

    // The Q: the one `[pretrain] checkpoint` names when that file exists, else the `pretrain`
    // step's. The scored table's footer names the Q's path, and the report reads the Q from there,
    // so a given Q's path is part of the score step's key as well as its bytes.
    let given_q = p.q_checkpoint.as_ref().filter(|q| q.exists());
    let q = match given_q {
        Some(given) => given.clone(),
        _ => {
            let q = out.join("q.ckpt");
            steps.push(train_step("pretrain", &traj, &q, p.pretrain_config()?));
            q
        }
    };
    let s = &p.score;
    let mut params = json!({"swaps": s.swaps, "seed": s.seed, "include_original": s.include_original,
                            "chunk_episodes": s.chunk_episodes});
    if let Some(k) = s.goal_sample {
        // Only when set, so the keys of steps scored from every goal stay as they were.
        params["goal_sample"] = json!(k);
    }
    if let Some(q) = given_q {
        params["q"] = json!(q);
    }
    if let Data::Table { path } = &p.data {
        // The scored footer names β by its path (the report and the -mem agents read it from
        // there), so a table's path is part of the key as well as its bytes, as a given Q's is.
        params["table"] = json!(path);
    }
    steps.push(Step {
        name: "score".into(),
        params,
        inputs: vec![q.clone(), traj.clone()],
        // A scored folder is recorded by its manifest's digest (`state::Hashes`), which holds
        // every shard's sha256.
        outputs: vec![scored.clone()],
        action: Action::Score(ScoreStep {
            opts: score::ScoreOptions {
                checkpoint: q.clone(),
                data: traj.clone(),
                output: scored.clone(),
                swaps: s.swaps,
                seed: s.seed,
                include_original: s.include_original,
                device: Backend::Cpu,
                chunk_episodes: s.chunk_episodes,
                goal_sample: s.goal_sample,
                threads: 0,
                shard: None,
                command: cmd("score"),
            },
            shards: shards.clone(),
        }),
    });
    let mut runs = Vec::new();
    for &algo in &p.agents.algos {
        for arm in &p.agents.variants {
            for &seed in &p.agents.seeds {
                let id = format!("{}_{}_s{seed}", algo.name(), arm.name);
                let ckpt = out.join(format!("agents/{id}.ckpt"));
                let data = if arm.variant == Variant::Mem { &scored } else { &traj };
                let mut step = train_step(&format!("agent {id}"), data, &ckpt, p.agent_config(algo, arm, seed)?);
                if arm.variant == Variant::Mem {
                    // The scored table names β; training reads it too.
                    step.inputs.push(traj.clone());
                }
                steps.push(step);
                runs.push(report::Run {
                    task: p.task.clone(),
                    algo: algo.name().into(),
                    variant: arm.name.clone(),
                    seed,
                    metrics: metrics_path(&ckpt),
                });
            }
        }
    }
    let report_dir = out.join("report");
    // The report measures how sharply each -mem arm's priority draws what Q calls reachable.
    let mut priorities = Vec::new();
    for arm in p.agents.variants.iter().filter(|a| a.variant == Variant::Mem) {
        let c = p.agent_config(p.agents.algos[0], arm, p.agents.seeds[0])?.priority;
        if !priorities.contains(&c) {
            priorities.push(c);
        }
    }
    if priorities.is_empty() {
        priorities.push(Default::default());
    }
    // Over a scored folder the report reads its first shard: a transition table of its own whose
    // footer names β (the folder), holding the scored swaps of β's first episodes, where the
    // positives are. Its key reads the folder (the manifest holds the shard's sha256).
    let report_scored = match shards.first() {
        Some(first) => scored.join(first),
        None => scored.clone(),
    };
    let r = report::QReportOptions {
        scored: report_scored,
        out_dir: report_dir.clone(),
        positive_episodes: positives(p),
        seed: p.report.seed,
        priorities,
        ..report::QReportOptions::default()
    };
    steps.push(Step {
        name: "report".into(),
        params: json!({"positive_episodes": r.positive_episodes, "seed": r.seed, "test_fraction": r.test_fraction,
                       "max_samples": r.max_samples, "svm_max_train": r.svm_max_train, "priorities": r.priorities}),
        inputs: vec![scored.clone(), traj.clone(), q.clone()],
        outputs: ["fig5_q_hist.png", "table1.md", "table1.json"].iter().map(|f| report_dir.join(f)).collect(),
        action: Action::Report(r),
    });

    steps.push(Step {
        name: "results".into(),
        params: json!({"runs": runs.iter().map(|r| (&r.algo, &r.variant, r.seed)).collect::<Vec<_>>()}),
        inputs: runs.iter().map(|r| r.metrics.clone()).collect(),
        outputs: vec![
            out.join("results.md"),
            out.join("results.csv"),
            out.join("scores.csv"),
            out.join(format!("curves_{}.png", p.task)),
        ],
        action: Action::Results(runs),
    });
    assign_stacks(&mut steps, p.agents.batch.unwrap_or(usize::MAX));
    // Records are kept by step name: two steps of one name would claim each other's record.
    let mut names = std::collections::HashSet::new();
    if let Some(s) = steps.iter().find(|s| !names.insert(&s.name)) {
        bail!("two steps are both named {:?}", s.name);
    }
    Ok(steps)
}

/// The steps that make β (collect or the expert first where the data is simulated, then
/// convert), appended to `steps`; returns β's path, `out/traj.parquet`.
fn data_steps(p: &Pipeline, steps: &mut Vec<Step>) -> Result<PathBuf> {
    let out = &p.out;
    let cmd = |step: &str| format!("pgser pipeline {} step {step}", p.name);
    let traj = out.join("traj.parquet");
    let (pickles, episodes, drop) = match &p.data {
        Data::Pickles { inputs, episodes, drop } => (inputs.clone(), episodes.clone(), drop.clone()),
        Data::Collect { expert, random, seed, noise, checkpoint } => {
            // A trained expert: the given checkpoint, or when it is absent the one the `expert`
            // step trains (`pgser-train online` with `[expert]`'s settings).
            let trained = checkpoint.as_ref().map(|c| {
                if c.exists() {
                    c.clone()
                } else {
                    let ckpt = out.join("expert/expert.ckpt");
                    steps.push(Step {
                        name: "expert".into(),
                        params: json!({"task": p.task, "online": p.expert}),
                        inputs: vec![],
                        outputs: vec![ckpt.clone(), metrics_path(&ckpt)],
                        action: Action::Online { cfg: Box::new(p.expert.clone()), out: ckpt.clone() },
                    });
                    ckpt
                }
            });
            let mut files = Vec::new();
            for (kind, n, s) in
                [(PolicyKind::Expert, *expert, *seed), (PolicyKind::Random, *random, seed + *expert as u64)]
            {
                let name = format!("collect_{}", kind.name());
                let file = out.join(format!("data/{}.pkl", kind.name()));
                let noise = if kind == PolicyKind::Expert { *noise } else { 0.0 };
                let checkpoint = trained.clone().filter(|_| kind == PolicyKind::Expert);
                steps.push(Step {
                    params: json!({"task": p.task, "policy": kind.name(), "episodes": n, "seed": s, "noise": noise}),
                    name: name.clone(),
                    inputs: checkpoint.iter().cloned().collect(),
                    outputs: vec![file.clone()],
                    action: Action::Collect(CollectStep {
                        opts: collect::CollectOptions {
                            task: p.task.clone(),
                            policy: PolicySpec { kind, noise, epsilon: 0.0 },
                            episodes: n,
                            seed: s,
                            output: file.clone(),
                            float32: false,
                            row_group_rows: 65_536,
                            command: cmd(&name),
                        },
                        checkpoint,
                    }),
                });
                files.push(file);
            }
            (files, None, vec![])
        }
        Data::Oracle { episodes, seed, noise } => {
            // Named after the dataset, as OGBench's loader and `convert` expect; its -val file
            // beside it.
            let file = out.join(format!("data/{}.npz", p.task));
            let val = collect::ogbench::val_file(&file);
            steps.push(Step {
                name: "collect_oracle".into(),
                params: json!({"task": p.task, "policy": "oracle", "episodes": episodes, "seed": seed, "noise": noise}),
                inputs: vec![],
                outputs: vec![file.clone(), val],
                action: Action::Collect(CollectStep {
                    opts: collect::CollectOptions {
                        task: p.task.clone(),
                        policy: PolicySpec { kind: PolicyKind::Oracle, noise: *noise, epsilon: 0.0 },
                        episodes: *episodes,
                        seed: *seed,
                        output: file.clone(),
                        float32: false,
                        row_group_rows: 65_536,
                        command: cmd("collect_oracle"),
                    },
                    checkpoint: None,
                }),
            });
            (vec![file], None, vec![])
        }
        Data::Table { path } => return Ok(path.clone()),
    };
    // An OGBench file names its environment itself; a pickle takes the pipeline's task.
    let convert_task = (!matches!(p.data, Data::Oracle { .. })).then(|| p.task.clone());
    let mut params = json!({"task": p.task, "episodes": episodes});
    if !drop.is_empty() {
        // In the key only when given: a pipeline without it keeps the key (and table) it had.
        params["drop"] = json!(drop);
    }
    steps.push(Step {
        name: "convert".into(),
        params,
        inputs: pickles.clone(),
        outputs: vec![traj.clone()],
        action: Action::Convert(convert::ConvertOptions {
            inputs: pickles,
            output: traj.clone(),
            task: convert_task,
            threshold: None,
            episodes,
            float32: false,
            allow_nonfinite: false,
            exact_length: false,
            row_group_rows: 65_536,
            full_goal: false,
            drop,
            command: cmd("convert"),
        }),
    });

    Ok(traj)
}

/// Where the score step writes: `out/scored.parquet`, or over a table folder the scored folder
/// `out/scored/` (one scored shard per β shard, `score/folder.rs`).
pub(super) fn scored_path(p: &Pipeline) -> PathBuf {
    match &p.data {
        Data::Table { path } if path.is_dir() => p.out.join("scored"),
        _ => p.out.join("scored.parquet"),
    }
}

/// The shard file names of the table folder `dir`, in order, from its manifest alone (opening
/// the folder reads every shard's footer: `check.rs` does that once, before any step).
fn folder_shards(dir: &Path) -> Result<Vec<String>> {
    use crate::trajectory::folder::{FORMAT, Manifest, VERSION, read_manifest};
    let (_, files) =
        read_manifest::<Manifest>(dir, FORMAT, VERSION, "not a table folder, or a convert into it is unfinished")
            .with_context(|| format!("[data] table = {:?}", dir.display().to_string()))?;
    Ok(files)
}

/// The report's positives: `[report] positive_episodes`, or with oracle data every episode (each
/// transition's own goal is its episode's last position, which the episode reaches).
pub(super) fn positives(p: &Pipeline) -> Option<usize> {
    match p.data {
        Data::Oracle { episodes, .. } => p.report.positive_episodes.or(Some(episodes)),
        _ => p.report.positive_episodes,
    }
}

/// Puts the agent cells into stacks of at most `batch`, in plan order, each stack of cells that
/// may train together (same networks and schedule: TD3 and TD3+BC cells go to separate stacks).
fn assign_stacks(steps: &mut [Step], batch: usize) {
    let mut open: Vec<(serde_json::Value, usize, usize)> = Vec::new(); // (schedule, id, members)
    for step in steps.iter_mut().filter(|s| s.name.starts_with("agent ")) {
        let Action::Train { cfg, stack, .. } = &mut step.action else { continue };
        let key = crate::train::schedule(cfg);
        let id = match open.iter_mut().find(|(k, _, n)| *k == key && *n < batch) {
            Some((_, id, n)) => {
                *n += 1;
                *id
            }
            None => {
                open.push((key, open.len(), 1));
                open.len() - 1
            }
        };
        *stack = Some(id);
    }
}

fn train_step(name: &str, data: &Path, ckpt: &Path, cfg: TrainConfig) -> Step {
    Step {
        name: name.into(),
        params: json!({ "train": cfg }),
        inputs: vec![data.to_path_buf()],
        outputs: vec![ckpt.to_path_buf(), metrics_path(ckpt)],
        action: Action::Train { data: data.to_path_buf(), out: ckpt.to_path_buf(), cfg: Box::new(cfg), stack: None },
    }
}
