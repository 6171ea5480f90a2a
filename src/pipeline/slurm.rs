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
mod tests;
