use std::cell::RefCell;

use super::*;
use crate::pipeline::Data;
use crate::trajectory::folder::{FORMAT, MANIFEST, Manifest, Shard, VERSION};
use crate::trajectory::{FloatType, Footer};

/// A pipeline over a table folder of `n` FetchReach shards (`reach-I.parquet`, 4 episodes
/// each) in `dir`: only the manifest is written, all that planning reads.
fn folder_pipeline(dir: &Path, n: usize, agents: &str) -> Pipeline {
    let folder = dir.join("reach");
    std::fs::create_dir_all(&folder).unwrap();
    let task = crate::task::Task::known("FetchReach").unwrap();
    let shards: Vec<Shard> = (0..n)
        .map(|i| Shard {
            file: format!("reach-{i}.parquet"),
            rows: 4 * task.t,
            episodes: 4,
            first_episode: 4 * i,
            bytes: 1,
            sha256: String::new(),
        })
        .collect();
    let footer = Footer::new(&task, FloatType::Float32, 4 * n, "test".into());
    let m = Manifest {
        format: FORMAT.into(),
        version: VERSION,
        rows: 4 * n * task.t,
        episodes: 4 * n,
        footer,
        shards,
        validation: false,
        settings: None,
    };
    m.write(&folder).unwrap();
    assert!(folder.join(MANIFEST).is_file());
    let text = format!(
        "name = \"f\"\ntask = \"FetchReach\"\nout = \"out\"\n[data]\ntable = \"reach\"\n\
         [report]\npositive_episodes = 4\n[agents]\nseeds = [0, 1]\nupdates = 10\n{agents}"
    );
    Pipeline::parse(&text, &dir.join("f.toml")).unwrap()
}

/// β a table folder: no convert step, β read where it is, the score step writing the scored
/// folder `out/scored/` by β's shard names; the -mem agents read the folder, the report its
/// first shard, and both are keyed by the folder (its manifest).
#[test]
fn a_table_folder_is_beta_as_it_is_and_scored_into_a_folder_of_its_shards() {
    let dir = tempfile::tempdir().unwrap();
    let p = folder_pipeline(dir.path(), 3, "");
    let steps = super::super::plan(&p).unwrap();
    let names: Vec<&str> = steps.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names[..2], ["pretrain", "score"], "{names:?}");
    let beta = dir.path().join("reach");
    let scored = dir.path().join("out/scored");
    assert_eq!(steps[0].inputs, std::slice::from_ref(&beta));
    let score = &steps[1];
    assert_eq!(score.outputs, std::slice::from_ref(&scored));
    assert_eq!(score.params["table"], serde_json::json!(beta));
    let Action::Score(ScoreStep { opts, shards }) = &score.action else { panic!("score scores") };
    assert_eq!((&opts.data, &opts.output, opts.shard), (&beta, &scored, None));
    assert_eq!(shards, &["reach-0.parquet", "reach-1.parquet", "reach-2.parquet"]);
    for s in steps.iter().filter(|s| s.name.starts_with("agent ")) {
        let Action::Train { data, .. } = &s.action else { panic!("agents train") };
        let want = if s.name.contains("_mem_") { &scored } else { &beta };
        assert_eq!(data, want, "{}", s.name);
    }
    let report = steps.iter().find(|s| s.name == "report").unwrap();
    let Action::Report(r) = &report.action else { panic!("the report reports") };
    assert_eq!(r.scored, scored.join("reach-0.parquet"));
    assert!(report.inputs.contains(&scored) && report.inputs.contains(&beta), "{:?}", report.inputs);

    // A single table: scored into one file, as before; a folder without its manifest refused.
    let single = Pipeline { data: Data::Table { path: dir.path().join("t.parquet") }, ..p.clone() };
    let steps = super::super::plan(&single).unwrap();
    let Action::Score(ScoreStep { opts, shards }) = &steps[1].action else { panic!("score scores") };
    assert_eq!((opts.output.clone(), shards.len()), (dir.path().join("out/scored.parquet"), 0));
    std::fs::remove_file(beta.join(MANIFEST)).unwrap();
    let e = format!("{:#}", super::super::plan(&p).err().expect("a folder without a manifest"));
    assert!(e.contains("[data] table") && e.contains("manifest.json"), "{e}");
}

/// Under Slurm the score step over a folder is one job array of an element per shard, each
/// `pipeline step FILE score --shard K` after the Q's job, then the step's own job after the
/// array; what reads the scored folder (the -mem agents, the report) waits for that one.
#[test]
fn the_score_step_over_a_folder_is_a_job_array_of_its_shards_then_its_own_job() {
    let dir = tempfile::tempdir().unwrap();
    let p = folder_pipeline(dir.path(), 3, "batch = 1\n");
    let steps = super::super::plan(&p).unwrap();
    let runs: Vec<usize> = (0..steps.len()).collect();
    let o = SlurmOptions {
        until: None,
        device: Backend::Cpu,
        threads: None,
        partition: None,
        sbatch_args: vec![],
        array_parallelism: Some(2),
        gpus_per_task: None,
    };
    let sent = RefCell::new(Vec::<(Vec<String>, String)>::new());
    let send = |args: &[String], script: &str| {
        sent.borrow_mut().push((args.to_vec(), script.to_string()));
        Ok(format!("{}", 100 + sent.borrow().len()))
    };
    let logs = p.out.join(".pipeline/logs");
    let sbatch = Sbatch { p: &p, o: &o, here: dir.path(), logs: &logs, send: &send };
    std::fs::create_dir_all(&logs).unwrap();
    let jobs = submit_steps(&p, &steps, &runs, "pgser-etl pipeline step 'f.toml'", &sbatch, &|_| {}).unwrap();
    let sent = sent.into_inner();
    let ids: Vec<&str> = jobs.iter().map(|j| j.id.as_str()).collect();
    // pretrain, the shard array, score, the agent array, report, results.
    assert_eq!(ids, ["101", "102", "103", "104", "105", "106"]);
    let arg = |k: usize, flag: &str| sent[k].0.iter().find(|a| a.starts_with(flag)).cloned();
    assert_eq!(
        (jobs[1].shards, jobs[1].array, jobs[1].elements.clone()),
        (true, true, vec![vec!["score".to_string()]; 3])
    );
    assert_eq!(arg(1, "--array=").as_deref(), Some("--array=0-2%2"));
    assert_eq!(arg(1, "--dependency=").as_deref(), Some("--dependency=afterok:101"));
    assert!(sent[1].1.contains("'score' --shard \"$SLURM_ARRAY_TASK_ID\""), "{}", sent[1].1);
    assert!(arg(1, "--output=").unwrap().ends_with("score_shards-%A_%a.log"));
    assert_eq!(jobs[1].log(&p.out, 2), p.out.join(".pipeline/logs/score_shards-102_2.log"));
    // The step's own job: after the Q and every element; no array.
    assert_eq!((jobs[2].shards, jobs[2].array, jobs[2].elements.clone()), (false, false, vec![vec!["score".into()]]));
    assert_eq!(arg(2, "--dependency=").as_deref(), Some("--dependency=afterok:101:102"));
    assert_eq!(arg(2, "--array="), None);
    assert!(sent[2].1.ends_with("'score'\n") && !sent[2].1.contains("--shard"), "{}", sent[2].1);
    // The agents (baseline and swap read β alone, mem the scored folder) and the report (and
    // the Q) wait for the step's own job, not for the array.
    assert_eq!(arg(3, "--dependency=").as_deref(), Some("--dependency=afterok:103"));
    assert_eq!(arg(4, "--dependency=").as_deref(), Some("--dependency=afterok:101:103"));
    // Kept in slurm.jsonl, as `pipeline status` reads them.
    let kept = super::jobs(&p.out).unwrap();
    assert_eq!(kept.len(), 6);
    assert!(kept[1].shards && !kept[2].shards && kept[3].array && !kept[3].shards);
}

/// An element is done when its log has step_shard's closing line, failed when its log lacks
/// it, not started without a log, and pending or running while Slurm holds it; a failed
/// element is the step's failure when its own job left no log (cancelled).
#[test]
fn shard_elements_are_told_apart_by_the_queue_and_their_logs() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    std::fs::create_dir_all(out.join(".pipeline/logs")).unwrap();
    let array = Job { id: "7".into(), elements: vec![vec!["score".into()]; 5], array: true, shards: true };
    let own = Job { id: "8".into(), elements: vec![vec!["score".into()]], array: false, shards: false };
    let write = |k: usize, text: &str| std::fs::write(array.log(out, k), text).unwrap();
    write(0, "pipeline f: score shard 0 of 5: running\npipeline f: score shard 0 of 5: ran in 1.0 s\n");
    write(1, "pipeline f: score shard 1 of 5: up to date\n");
    write(2, "pipeline f: score shard 2 of 5: running\nerror: out of disk\n");
    let queue: HashMap<String, String> = [("7_3".to_string(), "RUNNING".to_string())].into();
    let states = element_states(out, &array, Some(&queue));
    assert_eq!(states, ["done", "done", "failed", "running", "not started"]);
    let both = [array.clone(), own.clone()];
    assert_eq!(failed_log(out, &both, "score"), Some(array.log(out, 2)));
    // Its own job ran and failed: its log says why.
    std::fs::write(own.log(out, 0), "error: the manifest\n").unwrap();
    assert_eq!(failed_log(out, &both, "score"), Some(own.log(out, 0)));
    assert_eq!(failed_log(out, &both, "report"), None);
}
