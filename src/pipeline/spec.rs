//! The pipeline file: one TOML document per experiment (see `pipelines/README.md`).
//!
//! Paths in the file are relative to the file's folder, so a pipeline means the same thing
//! whatever directory it is run from. Training settings are `pgser-train` flag names in
//! snake_case (`batch_size`, `lr`, `her_ratio`, `priority_alpha`, …) layered as defaults ←
//! `[train]` ← `[pretrain]` or `[agents]` ← the grid cell (algo, seed, variant); an unknown
//! name is an error, so a typo cannot silently fall back to a default.

use std::path::{Path, PathBuf};

pub use crate::output::normalize;

use anyhow::{Context, Result, bail};
use clap::Parser;
use serde::Deserialize;

use crate::agent::Algo;
use crate::train::TrainConfig;
use crate::train::online::OnlineConfig;

/// The three variants of the paper's Table 2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Variant {
    /// No goal swapping (HER only).
    Baseline,
    /// Random goal swapping on the fly (Alg. 1).
    Swap,
    /// Prioritized goal-swapping experience replay from the scored table (Alg. 2).
    Mem,
}

impl Variant {
    pub fn name(self) -> &'static str {
        match self {
            Variant::Baseline => "baseline",
            Variant::Swap => "swap",
            Variant::Mem => "mem",
        }
    }
}

/// One arm of the grid: a variant, under its own name when `[agents.arms.NAME]` gives it settings
/// of its own (an ablation: `-mem` at another `priority_alpha`, with `priority = "rank"`, …).
/// The three plain variants are arms named after themselves with no settings.
#[derive(Debug, Clone, PartialEq)]
pub struct Arm {
    /// What the cell ids, records and results call it: `mem`, or the arm's own name.
    pub name: String,
    pub variant: Variant,
    /// Training settings of this arm, applied over `[agents]`'s.
    pub train: toml::Table,
}

/// A parsed pipeline file with its paths resolved.
#[derive(Debug, Clone)]
pub struct Pipeline {
    pub name: String,
    pub task: String,
    /// Where every output goes (`out = "…"`, relative to the pipeline file).
    pub out: PathBuf,
    pub data: Data,
    /// `[train]`: settings shared by the pre-training and every agent.
    pub train: toml::Table,
    /// `[pretrain]`: the Q of Alg. 2 step 1 (TD3+BC with random swapping unless overridden).
    pub pretrain: toml::Table,
    /// `[pretrain] checkpoint`: a Q trained elsewhere, scored with instead of pre-training one
    /// (keyed by its bytes and its path, which the scored table names). When the file is absent the `pretrain` step trains
    /// one into `out/q.ckpt` as `[pretrain]` says, as `expert_checkpoint` does for the expert.
    pub q_checkpoint: Option<PathBuf>,
    pub score: ScoreSpec,
    pub report: ReportSpec,
    pub agents: Agents,
    /// `[expert]`: how the `expert` step trains the expert (`pgser-train online` settings) when
    /// `[data] expert_checkpoint` names a file that is absent.
    pub expert: OnlineConfig,
}

/// Where β comes from.
#[derive(Debug, Clone)]
pub enum Data {
    /// WGCSL pickles, converted in order taking the first `episodes[i]` of each (GoFAR's mix;
    /// the expert file first, which is what the report takes as positives), leaving out the keys
    /// `drop` names (`convert --drop`: what a table cannot keep, such as a dict of settings).
    Pickles { inputs: Vec<PathBuf>, episodes: Option<Vec<usize>>, drop: Vec<String> },
    /// Simulated: `expert` episodes of the expert (seeds seed…) and `random` of uniform actions
    /// (seeds seed + expert …), written as pickles and converted. The expert is the task's
    /// scripted one (Fetch), or with `checkpoint` a trained actor (the hand tasks, which have no
    /// scripted expert): that file when it exists, else the one the `expert` step trains.
    Collect { expert: usize, random: usize, seed: u64, noise: f64, checkpoint: Option<PathBuf> },
    /// OGBench's recipe for the dataset the task names (`task = "pointmaze-medium-stitch-v0"`):
    /// `episodes` of its oracle (seeds seed…), written as the dataset's `.npz` and converted.
    Oracle { episodes: usize, seed: u64, noise: f64 },
    /// An existing trajectory table (`[data] table`), used as β as it is: a single `.parquet`
    /// file or a table folder (Parquet shards and `manifest.json`, `trajectory/folder.rs`). There
    /// is no convert step; over a folder the score step writes a scored folder, one scored shard
    /// per β shard, which a cluster scores as one job array (`slurm.rs`).
    Table { path: PathBuf },
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScoreSpec {
    #[serde(default = "default_swaps")]
    pub swaps: usize,
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub include_original: bool,
    #[serde(default)]
    pub chunk_episodes: Option<usize>,
    /// `--goal-sample K`: goals from K achieved goals sampled from the whole table.
    #[serde(default)]
    pub goal_sample: Option<usize>,
}

fn default_swaps() -> usize {
    crate::score::DEFAULT_SWAPS
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReportSpec {
    /// Episodes of β taken as positives in Fig. 5 / Table 1 (default: the first source's).
    #[serde(default)]
    pub positive_episodes: Option<usize>,
    #[serde(default)]
    pub seed: u64,
}

/// `[agents]`: the grid algos × arms × seeds, and training settings for all of them.
#[derive(Debug, Clone)]
pub struct Agents {
    pub algos: Vec<Algo>,
    /// `variants`, in the file's order: the plain variants and the named arms of `[agents.arms]`.
    pub variants: Vec<Arm>,
    pub seeds: Vec<u64>,
    /// Agents trained at once as one stack of networks (`[agents] batch`, default: all the
    /// cells of a learner). 1 trains them one after another.
    pub batch: Option<usize>,
    pub train: toml::Table,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    name: String,
    task: String,
    out: String,
    data: DataFile,
    #[serde(default)]
    train: toml::Table,
    #[serde(default)]
    pretrain: toml::Table,
    #[serde(default = "default_score")]
    score: ScoreSpec,
    #[serde(default)]
    report: ReportSpec,
    agents: toml::Table,
    #[serde(default)]
    expert: Option<toml::Table>,
}

fn default_score() -> ScoreSpec {
    ScoreSpec { swaps: default_swaps(), seed: 0, include_original: false, chunk_episodes: None, goal_sample: None }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DataFile {
    #[serde(default)]
    pickles: Vec<String>,
    episodes: Option<Vec<usize>>,
    expert: Option<usize>,
    random: Option<usize>,
    oracle: Option<usize>,
    /// Optional here (0 by default) only so that `table` can refuse it by name.
    seed: Option<u64>,
    noise: Option<f64>,
    expert_checkpoint: Option<String>,
    #[serde(default)]
    drop: Vec<String>,
    table: Option<String>,
}

impl DataFile {
    /// The keys given besides `table`, in the file's documented order: a table is β as it is, so
    /// each of them would be silently ignored.
    fn besides_table(&self) -> Vec<&'static str> {
        let given = [
            ("pickles", !self.pickles.is_empty()),
            ("episodes", self.episodes.is_some()),
            ("drop", !self.drop.is_empty()),
            ("expert", self.expert.is_some()),
            ("random", self.random.is_some()),
            ("seed", self.seed.is_some()),
            ("noise", self.noise.is_some()),
            ("expert_checkpoint", self.expert_checkpoint.is_some()),
            ("oracle", self.oracle.is_some()),
        ];
        given.into_iter().filter(|(_, g)| *g).map(|(k, _)| k).collect()
    }
}

/// The first entry of `list` that an earlier one equals.
fn repeated<T: PartialEq>(list: &[T]) -> Option<&T> {
    list.iter().enumerate().find(|(i, x)| list[..*i].contains(x)).map(|(_, x)| x)
}

impl Pipeline {
    pub fn load(path: &Path) -> Result<Pipeline> {
        let at = path.display();
        let text = crate::output::read_input_text(path)?;
        Pipeline::parse(&text, path).with_context(|| format!("{at}"))
    }

    /// Parses `text` as the pipeline file at `path` (paths resolve against its folder).
    pub fn parse(text: &str, path: &Path) -> Result<Pipeline> {
        let f: File =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("{}", e.to_string().trim().replace('\n', " ")))?;
        let dir = path.parent().unwrap_or(Path::new(""));
        let resolve = |p: &str| normalize(&dir.join(p));
        if crate::env::task(&f.task).is_err() {
            bail!(
                "task {:?} is not one pgser can evaluate ({}, or an OGBench PointMaze dataset: {}-navigate-v0, …)",
                f.task,
                crate::task::Task::known_names().join(", "),
                crate::env::pointmaze::TASKS[0].trim_end_matches("-v0")
            );
        }
        if f.name.is_empty() || !f.name.chars().all(|c| c.is_ascii_alphanumeric() || "-_".contains(c)) {
            bail!("name {:?}: use letters, digits, - and _ only", f.name);
        }
        let d = f.data;
        if let Some(table) = &d.table {
            let others = d.besides_table();
            if !others.is_empty() {
                bail!(
                    "[data] table is an existing table used as β as it is; it cannot be combined with {} (give \
                     either `table` alone or the data to make)",
                    others.iter().map(|k| format!("`{k}`")).collect::<Vec<_>>().join(", ")
                );
            }
            if table.is_empty() {
                bail!("[data] table = \"\": give the path of a .parquet trajectory table or a table folder");
            }
        }
        let seed = d.seed.unwrap_or(0);
        if !d.drop.is_empty() && d.pickles.is_empty() {
            bail!(
                "[data] drop leaves keys of the given `pickles` out; the data a pipeline makes has none to leave out"
            );
        }
        let data = match (d.pickles.is_empty(), d.expert, d.random, d.oracle) {
            _ if d.table.is_some() => Data::Table { path: resolve(d.table.as_deref().unwrap_or_default()) },
            (false, None, None, None) => {
                if let Some(e) = &d.episodes
                    && e.len() != d.pickles.len()
                {
                    bail!("[data]: {} pickles but {} episode counts", d.pickles.len(), e.len());
                }
                Data::Pickles {
                    inputs: d.pickles.iter().map(|p| resolve(p)).collect(),
                    episodes: d.episodes,
                    drop: d.drop,
                }
            }
            (true, Some(expert), Some(random), None) if d.episodes.is_none() => {
                if expert == 0 {
                    bail!("[data]: expert = 0; the report needs expert episodes as positives");
                }
                let checkpoint = d.expert_checkpoint.as_deref().map(resolve);
                Data::Collect { expert, random, seed, noise: d.noise.unwrap_or(0.0), checkpoint }
            }
            (true, None, None, Some(episodes)) if d.episodes.is_none() && d.expert_checkpoint.is_none() => {
                crate::env::pointmaze::recipe(&f.task).with_context(|| {
                    format!(
                        "[data] oracle: OGBench's oracle makes the PointMaze datasets; task {:?} names none",
                        f.task
                    )
                })?;
                if episodes == 0 {
                    bail!("[data] oracle = 0: must be at least 1 episode");
                }
                Data::Oracle { episodes, seed, noise: d.noise.unwrap_or(crate::env::pointmaze::ORACLE_NOISE) }
            }
            _ => bail!(
                "[data]: give either `pickles` (and optionally `episodes`), both `expert` and `random`, `oracle` \
                 (an OGBench dataset's episodes), or `table` (an existing trajectory table or table folder)"
            ),
        };
        if f.expert.is_some() && !matches!(data, Data::Collect { checkpoint: Some(_), .. }) {
            bail!("[expert] trains a missing [data] expert_checkpoint; without expert_checkpoint it means nothing");
        }
        let expert = online_config(&f.task, &f.expert.unwrap_or_default()).context("[expert]")?;

        let mut agents = f.agents;
        let algos: Vec<Algo> = take(&mut agents, "algos")?.unwrap_or(vec![Algo::Td3bc]);
        let arms: toml::Table = take(&mut agents, "arms")?.unwrap_or_default();
        let names: Vec<String> =
            take(&mut agents, "variants")?.unwrap_or_else(|| ["baseline", "swap", "mem"].map(String::from).to_vec());
        let seeds: Vec<u64> = take(&mut agents, "seeds")?.unwrap_or(vec![0]);
        let batch: Option<usize> = take(&mut agents, "batch")?;
        if batch == Some(0) {
            bail!("[agents] batch = 0: must be at least 1 (1 trains the agents one after another)");
        }
        if algos.is_empty() || names.is_empty() || seeds.is_empty() {
            bail!("[agents]: algos, variants and seeds must not be empty");
        }
        // A repeated entry would name two cells of the grid alike: both would claim one agent's
        // files and record (found by fuzzing the pipeline file).
        if let Some(a) = repeated(&algos) {
            bail!("[agents] algos: {:?} is listed twice; each cell of the grid is one agent", a.name());
        }
        if let Some(v) = repeated(&names) {
            bail!("[agents] variants: {v:?} is listed twice; each cell of the grid is one agent");
        }
        if let Some(s) = repeated(&seeds) {
            bail!("[agents] seeds: {s} is listed twice; each cell of the grid is one agent");
        }
        let variants = arms_of(&names, arms)?;
        let mut pretrain = f.pretrain;
        let q_checkpoint = match pretrain.remove("checkpoint") {
            None => None,
            Some(toml::Value::String(c)) => Some(resolve(&c)),
            Some(v) => bail!("[pretrain] checkpoint = {v}: must be a path (a string)"),
        };
        let p = Pipeline {
            name: f.name,
            task: f.task,
            out: resolve(&f.out),
            data,
            train: f.train,
            pretrain,
            q_checkpoint,
            score: f.score,
            report: f.report,
            agents: Agents { algos, variants, seeds, batch, train: agents },
            expert,
        };
        // Fail now, not after an hour of training, on a misspelt setting.
        p.pretrain_config()?;
        for arm in &p.agents.variants {
            p.agent_config(p.agents.algos[0], arm, p.agents.seeds[0])?;
        }
        Ok(p)
    }

    /// The pre-training run's settings: TD3+BC with random swapping (Alg. 2 step 1) unless the
    /// file says otherwise.
    pub fn pretrain_config(&self) -> Result<TrainConfig> {
        let mut base = toml::Table::new();
        base.insert("algo".into(), "td3bc".into());
        base.insert("swap".into(), "random".into());
        train_config(&[&base, &self.train, &self.pretrain]).context("[pretrain]")
    }

    /// One grid cell's settings: `[train]` ← `[agents]` ← the arm's ← the cell's algo, seed and
    /// the swapping its variant means.
    pub fn agent_config(&self, algo: Algo, arm: &Arm, seed: u64) -> Result<TrainConfig> {
        let mut cell = toml::Table::new();
        cell.insert("algo".into(), serde_json::to_value(algo)?.as_str().unwrap_or_default().into());
        cell.insert("seed".into(), toml::Value::Integer(seed as i64));
        cell.insert("swap".into(), if arm.variant == Variant::Swap { "random" } else { "none" }.into());
        let section = if arm.train.is_empty() { "[agents]".to_string() } else { format!("[agents.arms.{}]", arm.name) };
        train_config(&[&self.train, &self.agents.train, &arm.train, &cell]).context(section)
    }
}

/// The arms `names` lists, each a plain variant or a key of `[agents.arms]` (a table with a
/// `variant` and training settings). An arm that no name lists is an error, as a misspelt key
/// would be: its cells would silently not run.
fn arms_of(names: &[String], mut arms: toml::Table) -> Result<Vec<Arm>> {
    let mut out = Vec::new();
    for name in names {
        let arm = match arms.remove(name) {
            Some(toml::Value::Table(mut t)) => {
                if matches!(name.as_str(), "baseline" | "swap" | "mem") {
                    bail!("[agents.arms.{name}]: an arm cannot take a variant's name; call it e.g. \"{name}_2\"");
                }
                if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
                    bail!("[agents.arms.{name:?}]: an arm's name is letters, digits and _ only (it names files)");
                }
                let variant: Variant = match t.remove("variant") {
                    Some(v) => v.try_into().with_context(|| format!("[agents.arms.{name}] variant"))?,
                    None => bail!("[agents.arms.{name}]: give its variant (baseline, swap or mem)"),
                };
                if let Some(k) = ["algo", "seed", "swap"].iter().find(|k| t.contains_key(**k)) {
                    bail!("[agents.arms.{name}] {k}: set by the grid (algos, seeds) and the variant, not by an arm");
                }
                Arm { name: name.clone(), variant, train: t }
            }
            Some(v) => bail!("[agents.arms] {name} = {v}: must be a table ([agents.arms.{name}])"),
            None => {
                let variant: Variant = toml::Value::String(name.clone()).try_into().map_err(|_| {
                    anyhow::anyhow!(
                        "[agents] variants: {name:?} is neither baseline, swap, mem nor an arm of [agents.arms]"
                    )
                })?;
                Arm { name: name.clone(), variant, train: toml::Table::new() }
            }
        };
        out.push(arm);
    }
    if let Some(name) = arms.keys().next() {
        bail!("[agents.arms.{name}] is not listed in [agents] variants, so it would never train");
    }
    Ok(out)
}

fn take<T: serde::de::DeserializeOwned>(t: &mut toml::Table, key: &str) -> Result<Option<T>> {
    match t.remove(key) {
        None => Ok(None),
        Some(v) => Ok(Some(v.try_into().with_context(|| format!("[agents] {key}"))?)),
    }
}

/// `TrainConfig`'s own settings that its JSON leaves out when unset, so that runs from before
/// they existed keep their bytes and keys.
const OPTIONAL_TRAIN_KEYS: [&str; 3] = ["memory_budget", "draws_per_row", "shard_window"];

/// `TrainConfig` from the CLI's defaults with `layers` applied in order. Keys are the flags'
/// snake_case names, found in whichever group (agent, sampler, priority) holds them.
pub fn train_config(layers: &[&toml::Table]) -> Result<TrainConfig> {
    #[derive(Parser)]
    struct Defaults {
        #[command(flatten)]
        c: TrainConfig,
    }
    let defaults = Defaults::try_parse_from(["pgser-train"]).context("the training defaults")?.c;
    let mut json = serde_json::to_value(&defaults)?;
    let obj = json.as_object_mut().expect("a struct");
    for layer in layers {
        for (key, value) in layer.iter() {
            let value = serde_json::to_value(value)?;
            let group =
                obj.iter().find(|(_, g)| g.as_object().is_some_and(|g| g.contains_key(key))).map(|(n, _)| n.clone());
            match group {
                Some(g) => {
                    obj[&g].as_object_mut().expect("a group").insert(key.clone(), value);
                }
                None if obj.get(key).is_some_and(|v| !v.is_object()) => {
                    obj.insert(key.clone(), value);
                }
                // A training setting its JSON leaves out when unset (`memory_budget`).
                None if OPTIONAL_TRAIN_KEYS.contains(&key.as_str()) => {
                    obj.insert(key.clone(), value);
                }
                // An agent setting its JSON leaves out at the default (`arithmetic`, `action_l2`).
                None if agent_flag(key) => {
                    obj["agent"].as_object_mut().expect("the agent's settings").insert(key.clone(), value);
                }
                None => bail!("unknown training setting {key:?} (use pgser-train's flag names in snake_case)"),
            }
        }
    }
    serde_json::from_value(json).map_err(|e| anyhow::anyhow!("a training setting has the wrong type: {e}"))
}

/// Whether `key` is one of the agent's flags: those whose JSON leaves them out at their default
/// (so that runs from before they existed keep their bytes and keys) are found here.
fn agent_flag(key: &str) -> bool {
    use clap::Args;
    crate::agent::AgentConfig::augment_args(clap::Command::new("agent"))
        .get_arguments()
        .any(|a| a.get_id().as_str() == key)
}

/// `pgser-train online`'s settings for `task`: its defaults (MRN's) with `table` applied. Keys
/// are the flags' snake_case names; the task is the pipeline's.
fn online_config(task: &str, table: &toml::Table) -> Result<OnlineConfig> {
    #[derive(Parser)]
    struct Defaults {
        #[command(flatten)]
        c: OnlineConfig,
    }
    let defaults = Defaults::try_parse_from(["pgser-train", "--task", task]).context("the online defaults")?.c;
    let mut json = serde_json::to_value(&defaults)?;
    let obj = json.as_object_mut().expect("a struct");
    for (key, value) in table {
        if key == "task" || !obj.contains_key(key) {
            bail!(
                "unknown setting {key:?} (use pgser-train online's flag names in snake_case; the task is the pipeline's)"
            );
        }
        obj.insert(key.clone(), serde_json::to_value(value)?);
    }
    let cfg: OnlineConfig =
        serde_json::from_value(json).map_err(|e| anyhow::anyhow!("a setting has the wrong type: {e}"))?;
    // Not settings of the run (they change no result): save every 10 minutes, as the CLI does.
    Ok(OnlineConfig { save_minutes: defaults.save_minutes, max_minutes: None, ..cfg })
}

#[cfg(test)]
mod tests;
