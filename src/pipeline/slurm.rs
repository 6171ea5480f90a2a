//! `pgser-etl pipeline run FILE --executor slurm`: the step graph handed to the cluster's own
//! scheduler rather than to one of ours. Every step that is not up to date becomes an `sbatch`
//! job that depends (`afterok`) on the jobs writing its inputs; the agent grid becomes one job
//! array, one element per stack of cells (`[agents] batch`; `batch = 1` makes one element per
//! cell), throttled with `%N` as CleanRL's and submitit's sweeps do. A failed job cancels those
//! that read its outputs (`--kill-on-invalid-dep=yes`) instead of leaving them pending forever.
//!
//! Each job runs `srun pgser-etl pipeline step FILE STEP…`, the very code of a local run
//! (`exec::run_unit`: locks, records, skip, resume), so a job whose step another run finished
//! does nothing, and a resubmission after a failure runs only what did not finish. `srun` makes
//! the step a job step, which `scancel --signal=TERM` reaches (a plain batch script is not
//! signalled); a training step then saves its checkpoint (`train::stop`).
//!
//! Jobs run in the submitting folder with the pipeline file's path as given, so they plan the
//! same paths as a local run and write the same bytes. Logs: `OUT/.pipeline/logs/STEP-JOB.log`
//! (`agents-JOB_ELEMENT.log` for the grid). Every job is appended to `OUT/.pipeline/slurm.jsonl`,
//! which `pipeline status` reads with `squeue`.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

use super::exec::Outcome;
use super::lock::StepLock;
use super::state::{self, Hashes};
use super::{Action, Pipeline, RunReport, ScoreStep, Step, check, cost, stack_of};
use crate::agent::Backend;

/// `--executor slurm`'s settings.
#[derive(Debug, Clone)]
pub struct SlurmOptions {
    pub until: Option<String>,
    pub device: Backend,
    /// Threads each step uses (`pipeline step --threads`); None: the CPUs Slurm gives it.
    pub threads: Option<usize>,
    pub partition: Option<String>,
    /// More `sbatch` arguments, given to every job (`--time=4:00:00`, `--cpus-per-task=8`, …).
    pub sbatch_args: Vec<String>,
    /// At most this many elements of the agent array run at once.
    pub array_parallelism: Option<usize>,
    /// GPUs for each training and scoring job.
    pub gpus_per_task: Option<usize>,
}

/// One submitted job, as `OUT/.pipeline/slurm.jsonl` keeps it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Job {
    pub id: String,
    /// The steps of each element: one element for a step's job, one per stack for the agent
    /// array, one per β shard (each `["score"]`) for the score step's shard array.
    pub elements: Vec<Vec<String>>,
    pub array: bool,
    /// An array over a table folder's shards: element k scores shard k of its step
    /// (`pipeline step FILE score --shard k`) and records nothing; the step's own job, submitted
    /// after it, writes the manifest and the record. Absent (false) in every other job.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub shards: bool,
}

impl Job {
    /// The log of element `k`.
    pub fn log(&self, out: &Path, k: usize) -> PathBuf {
        let dir = out.join(".pipeline/logs");
        if self.shards {
            dir.join(format!("{}_shards-{}_{k}.log", self.elements[0][0].replace(' ', "_"), self.id))
        } else if self.array {
            dir.join(format!("agents-{}_{k}.log", self.id))
        } else {
            dir.join(format!("{}-{}.log", self.elements[0][0].replace(' ', "_"), self.id))
        }
    }

    /// The Slurm id of element `k` as `squeue -r` prints it.
    pub fn element_id(&self, k: usize) -> String {
        if self.array { format!("{}_{k}", self.id) } else { self.id.clone() }
    }
}

/// What a submission did: the jobs, and the steps (plan order) up to where it goes.
pub struct Submission {
    pub jobs: Vec<Job>,
    /// The steps up to `--until`, with whether each was submitted.
    pub submitted: Vec<(String, bool)>,
    /// What the submitted steps will cost (updates, disk; not timed here).
    pub cost: super::Cost,
}

/// Shell-quotes `s` for the job script.
fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// Runs a Slurm command; its stdout, or an error with its stderr.
fn slurm(program: &str, args: &[String], stdin: Option<&str>) -> Result<String> {
    let mut child = Command::new(program)
        .args(args)
        .stdin(if stdin.is_some() { Stdio::piped() } else { Stdio::null() })
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("{program}: cannot run it (is this a machine that may submit Slurm jobs?)"))?;
    if let Some(text) = stdin {
        child.stdin.take().expect("piped").write_all(text.as_bytes()).with_context(|| format!("{program}: stdin"))?;
    }
    let out = child.wait_with_output().with_context(|| format!("{program}: did not finish"))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr).trim().replace('\n', " ");
        bail!("{program} {}: {err} ({})", args.join(" "), out.status);
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Submits the steps of `p` (read from `file`, a path as the jobs will open it from this folder)
/// that are not up to date; `log` gets the cost and one line per job.
pub fn submit(p: &Pipeline, file: &Path, o: &SlurmOptions, log: &dyn Fn(&str)) -> Result<Submission> {
    let steps = super::plan(p)?;
    let last = super::last_step(&steps, o.until.as_deref())?;
    // The jobs check their device where they run; this machine may have no GPU.
    let data = check::check(p, &steps[..=last], Backend::Cpu)?;
    let mut hashes = Hashes::default();
    let forecast = state::forecast(&p.out, &steps[..=last], &mut hashes)?;
    // Not measured: this machine is not where the steps run.
    let cost = cost::estimate(p, &steps[..=last], &forecast, &data, false, Backend::Cpu)?;
    for line in cost::render(&cost).lines() {
        log(line);
    }
    let runs: Vec<usize> = (0..=last).filter(|&i| forecast[i].runs).collect();
    let submitted = (0..=last).map(|i| (steps[i].name.clone(), forecast[i].runs)).collect();
    if runs.is_empty() {
        log("every step is up to date; nothing to submit");
        return Ok(Submission { jobs: vec![], submitted, cost });
    }
    let logs = p.out.join(".pipeline/logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("{}: cannot create", logs.display()))?;
    let here = std::env::current_dir().context("the current folder")?;
    let exe = std::env::current_exe().context("the path of pgser-etl")?;
    let mut command =
        format!("{} pipeline step {}", quote(&exe.display().to_string()), quote(&file.display().to_string()));
    command += &format!(" --device {}", o.device.name());
    if let Some(t) = o.threads {
        command += &format!(" --threads {t}");
    }
    let sbatch = Sbatch { p, o, here: &here, logs: &logs, send: &|args, script| slurm("sbatch", args, Some(script)) };
    let jobs = submit_steps(p, &steps, &runs, &command, &sbatch, log)?;
    Ok(Submission { jobs, submitted, cost })
}

/// Submits `runs` (indices into the plan `steps`, in plan order) through `sbatch`, each job
/// running `command STEP…`, each depending on the jobs that write its inputs; returns the jobs,
/// each also appended to `OUT/.pipeline/slurm.jsonl`.
fn submit_steps(
    p: &Pipeline,
    steps: &[Step],
    runs: &[usize],
    command: &str,
    sbatch: &Sbatch,
    log: &dyn Fn(&str),
) -> Result<Vec<Job>> {
    // The agent cells to run, by stack: the array's elements.
    let mut stacks: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for &i in runs {
        if let Some(id) = stack_of(&steps[i]) {
            stacks.entry(id).or_default().push(i);
        }
    }
    let writer: HashMap<&PathBuf, usize> =
        steps.iter().enumerate().flat_map(|(i, s)| s.outputs.iter().map(move |o| (o, i))).collect();
    let mut job_of: HashMap<usize, String> = HashMap::new();
    let mut jobs = Vec::new();
    let mut array_done = false;
    for &i in runs {
        let members: Vec<usize> = match stack_of(&steps[i]) {
            Some(_) if array_done => continue,
            Some(_) => stacks.values().flatten().copied().collect(),
            None => vec![i],
        };
        let mut after: BTreeSet<String> = members
            .iter()
            .flat_map(|&m| steps[m].inputs.iter())
            .filter_map(|input| writer.get(input).and_then(|w| job_of.get(w)).cloned())
            .collect();
        let uses_device = members
            .iter()
            .any(|&m| matches!(steps[m].action, Action::Train { .. } | Action::Score { .. } | Action::Online { .. }));
        let array = stack_of(&steps[i]).is_some();
        let name = &steps[i].name;
        // The score step over a table folder: first one job array, element k scoring shard k;
        // then the step's own job (below), after every element, writes the manifest and records
        // the step. The steps reading the scored folder wait for that one.
        if let Action::Score(ScoreStep { shards, .. }) = &steps[i].action
            && !shards.is_empty()
        {
            let elements: Vec<Vec<String>> = shards.iter().map(|_| vec![name.clone()]).collect();
            let script = format!(
                "#!/bin/sh\n# pgser pipeline {}: step {name} over {} shards of a table folder, one per element; \
                 written by `pgser-etl pipeline run --executor slurm`.\n\
                 exec srun --ntasks=1 {command} {} --shard \"$SLURM_ARRAY_TASK_ID\"\n",
                p.name,
                shards.len(),
                quote(name)
            );
            let tag = format!("{}_shards", name.replace(' ', "_"));
            let id = sbatch.submit(&tag, &after, Some(shards.len()), uses_device, &script)?;
            let job = Job { id: id.clone(), elements, array: true, shards: true };
            append_job(&p.out, &job)?;
            log(&format!("{name}: job array {id} of {} shard(s){}", shards.len(), after_text(&after)));
            jobs.push(job);
            after.insert(id);
        }
        let tag = if array { "agents".to_string() } else { name.replace(' ', "_") };
        let elements: Vec<Vec<String>> = if array {
            stacks.values().map(|m| m.iter().map(|&j| steps[j].name.clone()).collect()).collect()
        } else {
            vec![vec![name.clone()]]
        };
        let mut script = format!(
            "#!/bin/sh\n# pgser pipeline {}: {}; written by `pgser-etl pipeline run --executor slurm`.\n",
            p.name,
            if array { "the agent grid, one stack of cells per element".to_string() } else { format!("step {name}") }
        );
        if array {
            script += "case \"$SLURM_ARRAY_TASK_ID\" in\n";
            for (k, names) in elements.iter().enumerate() {
                let q: Vec<String> = names.iter().map(|n| quote(n)).collect();
                script += &format!("{k}) set -- {} ;;\n", q.join(" "));
            }
            script += "*) echo \"no element $SLURM_ARRAY_TASK_ID in this array\" >&2; exit 1 ;;\nesac\n";
            script += &format!("exec srun --ntasks=1 {command} \"$@\"\n");
        } else {
            script += &format!("exec srun --ntasks=1 {command} {}\n", quote(name));
        }
        let id = sbatch.submit(&tag, &after, array.then_some(elements.len()), uses_device, &script)?;
        let job = Job { id: id.clone(), elements, array, shards: false };
        append_job(&p.out, &job)?;
        if array {
            log(&format!("agents: job array {id} of {} stack(s) of cells{}", job.elements.len(), after_text(&after)));
            array_done = true;
        } else {
            log(&format!("{name}: job {id}{}", after_text(&after)));
        }
        for &m in &members {
            job_of.insert(m, id.clone());
        }
        jobs.push(job);
    }
    Ok(jobs)
}

/// " after 12, 13", or nothing without dependencies.
fn after_text(after: &BTreeSet<String>) -> String {
    if after.is_empty() {
        String::new()
    } else {
        format!(" after {}", after.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", "))
    }
}

/// What every job of one submission shares: the pipeline, the options, the folder it runs in
/// and where its logs go.
struct Sbatch<'a> {
    p: &'a Pipeline,
    o: &'a SlurmOptions,
    here: &'a Path,
    logs: &'a Path,
    /// Runs `sbatch ARGS` with the script on stdin; its stdout (`ID` or `ID;CLUSTER`).
    send: &'a dyn Fn(&[String], &str) -> Result<String>,
}

impl Sbatch<'_> {
    /// Submits `script` as job `pgser-NAME-TAG` (an array of `array` elements, throttled by
    /// `--array-parallelism`, when given) depending (afterok) on `after`; returns its id.
    fn submit(
        &self,
        tag: &str,
        after: &BTreeSet<String>,
        array: Option<usize>,
        uses_device: bool,
        script: &str,
    ) -> Result<String> {
        let o = self.o;
        let mut args: Vec<String> = vec![
            "--parsable".into(),
            format!("--job-name=pgser-{}-{tag}", self.p.name),
            format!("--chdir={}", self.here.display()),
            "--kill-on-invalid-dep=yes".into(),
            // A requeued job (preemption, `--requeue`) adds to the log of its first attempt.
            "--open-mode=append".into(),
        ];
        let log_name = if array.is_some() { format!("{tag}-%A_%a.log") } else { format!("{tag}-%j.log") };
        args.push(format!("--output={}", self.here.join(self.logs).join(log_name).display()));
        if !after.is_empty() {
            let ids: Vec<&str> = after.iter().map(|s| s.as_str()).collect();
            args.push(format!("--dependency=afterok:{}", ids.join(":")));
        }
        if let Some(part) = &o.partition {
            args.push(format!("--partition={part}"));
        }
        if let (Some(g), true) = (o.gpus_per_task, uses_device) {
            args.push(format!("--gpus-per-task={g}"));
        }
        if let Some(n) = array {
            let throttle = o.array_parallelism.map(|n| format!("%{n}")).unwrap_or_default();
            args.push(format!("--array=0-{}{throttle}", n - 1));
        }
        args.extend(o.sbatch_args.iter().cloned());
        let id = (self.send)(&args, script)?;
        let id = id.trim().split(';').next().unwrap_or_default().to_string();
        if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
            bail!("sbatch printed {id:?} where a job id was expected");
        }
        Ok(id)
    }
}

/// Appends `job` to `OUT/.pipeline/slurm.jsonl`, under a lock (two submissions may append).
fn append_job(out: &Path, job: &Job) -> Result<()> {
    let _lock = StepLock::acquire(out, ".slurm-jobs", &|_| {})?;
    let path = out.join(".pipeline/slurm.jsonl");
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("{}: cannot open", path.display()))?;
    writeln!(f, "{}", serde_json::to_string(job)?).with_context(|| format!("{}: write failed", path.display()))
}

/// Every job submitted for the pipeline writing to `out`, oldest first.
pub fn jobs(out: &Path) -> Result<Vec<Job>> {
    let path = out.join(".pipeline/slurm.jsonl");
    let Ok(text) = std::fs::read_to_string(&path) else { return Ok(vec![]) };
    text.lines()
        .enumerate()
        .map(|(i, l)| {
            serde_json::from_str(l).with_context(|| format!("{}: line {} is not a job", path.display(), i + 1))
        })
        .collect()
}

/// The jobs Slurm still holds (pending, running, completing), by element id → state; None
/// where `squeue` cannot be run (not a Slurm machine).
pub fn queue() -> Option<HashMap<String, String>> {
    let args: Vec<String> = ["--me", "--noheader", "--array", "--format=%i %T"].map(String::from).to_vec();
    let text = slurm("squeue", &args, None).ok()?;
    Some(
        text.lines()
            .filter_map(|l| l.split_once(' ').map(|(id, state)| (id.to_string(), state.trim().to_string())))
            .collect(),
    )
}

/// Waits until none of `sub`'s jobs is queued or running, then reports every step as a local
/// run would, from the records: `ran`/`resumed` by these jobs, `up to date` (before, or by
/// another run), `failed` (with its log) or `not run` (cancelled as it reads a failed step).
pub fn wait(p: &Pipeline, sub: &Submission, log: &dyn Fn(&str)) -> Result<RunReport> {
    let t0 = Instant::now();
    let mut announced = 0;
    loop {
        let q = queue().context("squeue: cannot run it, so the jobs cannot be followed")?;
        let left = sub.jobs.iter().filter(|j| q.keys().any(|k| k == &j.id || k.starts_with(&format!("{}_", j.id))));
        let left = left.count();
        if left == 0 {
            break;
        }
        let secs = t0.elapsed().as_secs();
        if secs >= announced {
            log(&format!("waiting for {left} Slurm job(s) ({secs} s)"));
            announced = secs.max(1) * 4;
        }
        // Quick at first (a tiny pipeline takes seconds), gentle on the controller later.
        std::thread::sleep(Duration::from_millis((500 + 100 * secs).min(15_000)));
    }
    let steps = super::plan(p)?;
    let ours: BTreeSet<&str> = sub.jobs.iter().map(|j| j.id.as_str()).collect();
    let mut hashes = Hashes::default();
    let mut outcomes = Vec::new();
    let n = steps.len();
    for (i, (name, submitted)) in sub.submitted.iter().enumerate() {
        let step = &steps[i];
        debug_assert_eq!(&step.name, name);
        let o = outcome(p, step, *submitted, &ours, sub, &mut hashes)?;
        let how = match &o.log {
            Some(l) => format!("{} (log {})", o.status, l.display()),
            None if o.seconds > 0.0 => format!("{} in {:.1} s", o.status, o.seconds),
            None => o.status.clone(),
        };
        log(&format!("[{}/{n}] {name}: {how}", i + 1));
        outcomes.push(o);
    }
    Ok(super::report_of(p, &steps[..sub.submitted.len()], outcomes, sub.cost.clone()))
}

/// How `step` ended after its job (if `submitted`) has left the queue.
fn outcome(
    p: &Pipeline,
    step: &Step,
    submitted: bool,
    ours: &BTreeSet<&str>,
    sub: &Submission,
    hashes: &mut Hashes,
) -> Result<Outcome> {
    let key = hashes.key(step)?;
    if key.as_ref().is_some_and(|k| state::up_to_date(&p.out, step, k, hashes)) {
        let r = state::read(&p.out, step).expect("an up-to-date step has a record");
        return Ok(match r.job.as_deref() {
            Some(j) if submitted && ours.contains(j) => {
                Outcome { status: r.status.unwrap_or_else(|| "ran".into()), seconds: r.seconds, log: None }
            }
            _ => Outcome { status: "up to date".into(), seconds: 0.0, log: None },
        });
    }
    Ok(match failed_log(&p.out, &sub.jobs, &step.name) {
        Some(l) => Outcome { status: "failed".into(), seconds: 0.0, log: Some(l) },
        None => Outcome { status: "not run".into(), seconds: 0.0, log: None },
    })
}

/// The log that says why step `name` did not finish, among `jobs` that have left the queue: its
/// own (latest) job's, else — that job cancelled before it started, as a job it waited for
/// failed — the first failed element's of its shard array.
pub fn failed_log(out: &Path, jobs: &[Job], name: &str) -> Option<PathBuf> {
    let holds = |j: &&Job| j.elements.iter().any(|e| e.iter().any(|s| s == name));
    let own = jobs.iter().rev().filter(|j| !j.shards).find(holds).and_then(|j| {
        let k = j.elements.iter().position(|e| e.iter().any(|s| s == name))?;
        Some(j.log(out, k))
    });
    if let Some(l) = own.filter(|l| l.exists()) {
        return Some(l);
    }
    let array = jobs.iter().rev().filter(|j| j.shards).find(holds)?;
    let states = element_states(out, array, None);
    states.iter().position(|s| s == "failed").map(|k| array.log(out, k))
}

/// Where each element of a shard array stands: `pending` or `running` while Slurm holds it
/// (`queue`, by element id), else `done` when its log ends its work with the line
/// [`super::step_shard`] writes on success (`score shard K of N: ran …` or `… up to date`),
/// `failed` when it has a log without that line, and `not started` without a log (cancelled
/// before it began). The log, not `sacct`, since many clusters keep no job accounting.
pub fn element_states(out: &Path, job: &Job, queue: Option<&HashMap<String, String>>) -> Vec<String> {
    let n = job.elements.len();
    (0..n)
        .map(|k| {
            if let Some(state) = queue.and_then(|q| q.get(&job.element_id(k))) {
                return if state == "PENDING" { "pending" } else { "running" }.to_string();
            }
            let Ok(text) = std::fs::read_to_string(job.log(out, k)) else { return "not started".to_string() };
            let head = format!("{} shard {k} of {n}: ", job.elements[k][0]);
            let finished = text
                .lines()
                .any(|l| l.split_once(&head).is_some_and(|(_, rest)| rest.starts_with("ran") || rest == "up to date"));
            if finished { "done" } else { "failed" }.to_string()
        })
        .collect()
}

#[cfg(test)]
mod tests {
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
        assert_eq!(
            (jobs[2].shards, jobs[2].array, jobs[2].elements.clone()),
            (false, false, vec![vec!["score".into()]])
        );
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
}
