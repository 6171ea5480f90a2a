//! The checkpoint file (docs/checkpoint.md): one safetensors file that PyTorch, numpy or any safetensors
//! reader can open, plus a `.resume` file beside it with the rest of the training state.
//!
//! Layout of `model.ckpt` (float32 tensors):
//! - `actor.{0,2,4,6}.weight` `[out, in]` and `.bias` `[out]`, likewise `critic1.*`, `critic2.*`
//!   (DDPG's one critic is `critic1.*`, and it has no `critic2`):
//!   the names and shapes a PyTorch `nn.Sequential(Linear, ReLU, Linear, ..)` uses, so
//!   `load_state_dict` works after stripping the prefix; the actor's output goes through tanh;
//! - `normalizer.{obs,goal}_{mean,std}`;
//! - metadata: `format`, `config` (AgentConfig JSON), `task` (Task JSON), `updates`, and what
//!   the trainer adds (`train`: its config and data source).
//!
//! `model.ckpt.resume` holds the target networks, Adam's moments and step counts, and the random
//! streams' states, so that `--resume` reaches the same weights as a run never interrupted.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use safetensors::tensor::{Dtype, SafeTensors};

use super::{Adam, Agent, AgentConfig, Member, Mlp, Normalizer, member_of, net_sizes, transpose};
use crate::nprandom::NpRandom;
use crate::output::AtomicFile;
use crate::task::Task;

pub const FORMAT: &str = "pgser-agent";

/// Named float32 tensors being assembled for one file.
#[derive(Default)]
struct Tensors {
    entries: Vec<(String, Vec<usize>, Vec<u8>)>,
}

impl Tensors {
    fn push(&mut self, name: String, shape: Vec<usize>, values: &[f32]) {
        self.entries.push((name, shape, values.iter().flat_map(|v| v.to_le_bytes()).collect()));
    }

    /// Weights go out as PyTorch's `[out, in]`; ours are `[in, out]`.
    fn push_member(&mut self, prefix: &str, member: &Member) {
        for (l, (w, b)) in member.iter().enumerate() {
            let (fan_in, fan_out) = (w.len() / b.len(), b.len());
            self.push(format!("{prefix}.{}.weight", 2 * l), vec![fan_out, fan_in], &transpose(w, fan_in, fan_out));
            self.push(format!("{prefix}.{}.bias", 2 * l), vec![fan_out], b);
        }
    }

    /// Adam's moments of one member, flat per parameter in `Mlp::tensors()` order.
    fn push_moments(&mut self, prefix: &str, (m, v): &(Member, Member)) {
        let flat = |mem: &Member| mem.iter().flat_map(|(w, b)| [w.clone(), b.clone()]).collect::<Vec<_>>();
        for (k, (m, v)) in flat(m).iter().zip(&flat(v)).enumerate() {
            self.push(format!("{prefix}.m.{k}"), vec![m.len()], m);
            self.push(format!("{prefix}.v.{k}"), vec![v.len()], v);
        }
    }

    /// Writes the file beside `path`, not yet in place: the caller commits it.
    fn stage(self, path: &Path, metadata: BTreeMap<String, String>) -> Result<AtomicFile> {
        let bytes = self.encode(&metadata)?;
        let out = AtomicFile::create(path)?;
        std::io::Write::write_all(&mut out.handle()?, &bytes)
            .with_context(|| format!("{}: write failed", path.display()))?;
        Ok(out)
    }

    /// The safetensors bytes, written here rather than by `safetensors::serialize`: that one
    /// takes the metadata as a `HashMap` and so writes its keys in a different order in every
    /// process, and a pipeline that rebuilds a lost checkpoint must get the same bytes back
    /// (otherwise every step downstream of it reruns). Tensors go in name order, metadata keys
    /// sorted, the header padded with spaces to 8 bytes as the format asks.
    fn encode(mut self, metadata: &BTreeMap<String, String>) -> Result<Vec<u8>> {
        self.entries.sort_by(|a, b| a.0.cmp(&b.0));
        let mut metadata = metadata.clone();
        let sums = Crc32s::of(&metadata, self.entries.iter().map(|(n, _, b)| (n.as_str(), b.as_slice())));
        metadata.insert(CRC_KEY.to_string(), serde_json::to_string(&sums)?);
        let mut header = String::from("{");
        if !metadata.is_empty() {
            header.push_str("\"__metadata__\":{");
            let pairs: Vec<String> = metadata
                .iter()
                .map(|(k, v)| Ok(format!("{}:{}", serde_json::to_string(k)?, serde_json::to_string(v)?)))
                .collect::<Result<_, serde_json::Error>>()?;
            header.push_str(&pairs.join(","));
            header.push('}');
        }
        let mut offset = 0;
        for (name, shape, bytes) in &self.entries {
            if bytes.len() != shape.iter().product::<usize>() * 4 {
                bail!("tensor {name}: {} bytes for shape {shape:?}", bytes.len());
            }
            if header.len() > 1 {
                header.push(',');
            }
            let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
            header.push_str(&format!(
                "{}:{{\"dtype\":\"F32\",\"shape\":[{}],\"data_offsets\":[{offset},{}]}}",
                serde_json::to_string(name)?,
                dims.join(","),
                offset + bytes.len()
            ));
            offset += bytes.len();
        }
        header.push('}');
        while header.len() % 8 != 0 {
            header.push(' ');
        }
        let mut out = Vec::with_capacity(8 + header.len() + offset);
        out.extend_from_slice(&(header.len() as u64).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        for (_, _, bytes) in &self.entries {
            out.extend_from_slice(bytes);
        }
        Ok(out)
    }
}

/// The metadata key of [`Crc32s`].
pub const CRC_KEY: &str = "pgser_crc32";

/// CRC-32s of a checkpoint's contents, kept in its own metadata: one of the other metadata
/// entries (canonical JSON of the sorted map) and one per tensor's bytes. A flipped bit in a
/// tensor is otherwise a valid float, loaded and used without complaint; checked on every load,
/// it is an error that names the tensor. (The header's shapes and offsets are checked by the
/// safetensors parser.)
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Crc32s {
    pub metadata: u32,
    pub tensors: BTreeMap<String, u32>,
}

impl Crc32s {
    fn of<'a>(metadata: &BTreeMap<String, String>, tensors: impl Iterator<Item = (&'a str, &'a [u8])>) -> Crc32s {
        let mut meta = metadata.clone();
        meta.remove(CRC_KEY);
        let canonical = serde_json::to_string(&meta).expect("a map of strings serializes");
        Crc32s {
            metadata: crc32fast::hash(canonical.as_bytes()),
            tensors: tensors.map(|(n, b)| (n.to_string(), crc32fast::hash(b))).collect(),
        }
    }
}

/// Checks a safetensors file's contents against its [`Crc32s`]: `Ok(true)` when they match,
/// `Ok(false)` when it has none (written by an older pgser or another tool), an error naming
/// the first corrupt part otherwise.
pub fn verify(path: &Path, bytes: &[u8]) -> Result<bool> {
    let at = path.display();
    let st = SafeTensors::deserialize(bytes).with_context(|| format!("{at}: not a safetensors file"))?;
    let (_, header) = SafeTensors::read_metadata(bytes).with_context(|| format!("{at}: not a safetensors file"))?;
    let meta: BTreeMap<String, String> = header.metadata().clone().unwrap_or_default().into_iter().collect();
    let Some(text) = meta.get(CRC_KEY) else { return Ok(false) };
    let want: Crc32s = serde_json::from_str(text)
        .with_context(|| format!("{at}: metadata {CRC_KEY} is not readable: the file is corrupt"))?;
    let mut names: Vec<String> = st.names().into_iter().map(str::to_string).collect();
    names.sort();
    let got = Crc32s::of(&meta, names.iter().map(|n| (n.as_str(), st.tensor(n).expect("listed").data())));
    if got.metadata != want.metadata {
        bail!(
            "{at}: metadata checksum mismatch (crc32 {:08x}, written {:08x}): the file is corrupt",
            got.metadata,
            want.metadata
        );
    }
    for (name, crc) in &got.tensors {
        match want.tensors.get(name) {
            Some(w) if w == crc => {}
            Some(w) => {
                bail!("{at}: tensor {name}: checksum mismatch (crc32 {crc:08x}, written {w:08x}): the file is corrupt")
            }
            None => bail!("{at}: tensor {name} has no checksum: the file is corrupt"),
        }
    }
    if let Some(name) = want.tensors.keys().find(|n| !got.tensors.contains_key(*n)) {
        bail!("{at}: tensor {name} is missing: the file is corrupt");
    }
    Ok(true)
}

/// A safetensors file read back: its tensors by name and its metadata.
struct Loaded {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl Loaded {
    fn open(path: &Path) -> Result<Loaded> {
        let bytes = crate::output::read_input(path)?;
        verify(path, &bytes)?;
        Ok(Loaded { path: path.to_path_buf(), bytes })
    }

    fn metadata(&self) -> Result<HashMap<String, String>> {
        let (_, meta) = SafeTensors::read_metadata(&self.bytes)?;
        Ok(meta.metadata().clone().unwrap_or_default())
    }

    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
        let st = SafeTensors::deserialize(&self.bytes)?;
        let view = st.tensor(name).map_err(|_| anyhow::anyhow!("{}: tensor {name} is missing", self.path.display()))?;
        if view.dtype() != Dtype::F32 || view.shape() != shape {
            bail!(
                "{}: tensor {name} is {:?} {:?}, expected F32 {shape:?}",
                self.path.display(),
                view.dtype(),
                view.shape()
            );
        }
        Ok(view.data().chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect())
    }

    /// A member of layer sizes `sizes` from `{prefix}.{k}.weight|bias`, transposed back to
    /// `[in, out]`.
    fn member(&self, prefix: &str, sizes: &[usize]) -> Result<Member> {
        sizes
            .windows(2)
            .enumerate()
            .map(|(l, io)| {
                let w = self.tensor(&format!("{prefix}.{}.weight", 2 * l), &[io[1], io[0]])?;
                Ok((transpose(&w, io[1], io[0]), self.tensor(&format!("{prefix}.{}.bias", 2 * l), &[io[1]])?))
            })
            .collect()
    }

    /// Adam's moments written by `push_moments` for a member of layer sizes `sizes`.
    fn moments(&self, prefix: &str, sizes: &[usize]) -> Result<(Member, Member)> {
        let read = |which: &str| -> Result<Member> {
            sizes
                .windows(2)
                .enumerate()
                .map(|(l, io)| {
                    let w = self.tensor(&format!("{prefix}.{which}.{}", 2 * l), &[io[0] * io[1]])?;
                    Ok((w, self.tensor(&format!("{prefix}.{which}.{}", 2 * l + 1), &[io[1]])?))
                })
                .collect()
        };
        Ok((read("m")?, read("v")?))
    }

    fn meta_json<T: serde::de::DeserializeOwned>(&self, meta: &HashMap<String, String>, key: &str) -> Result<T> {
        let text = meta.get(key).with_context(|| format!("{}: metadata key {key} is missing", self.path.display()))?;
        serde_json::from_str(text).with_context(|| format!("{}: metadata key {key} is not valid", self.path.display()))
    }
}

/// Writes agent `i` of the stack as a model file. `extra` metadata (the trainer's config, data
/// source) is kept as given.
pub fn save(agent: &Agent, i: usize, path: &Path, extra: &BTreeMap<String, String>) -> Result<()> {
    stage(agent, i, path, extra)?.commit()
}

/// `save`, written beside `path` but not yet moved into place, so that a trainer can put a
/// checkpoint, its resume state and its metrics in place one right after the other.
pub fn stage(agent: &Agent, i: usize, path: &Path, extra: &BTreeMap<String, String>) -> Result<AtomicFile> {
    assert!(!agent.is_stale(), "a checkpoint written from a stack without its last updates (Agent::sync missed)");
    let mut t = Tensors::default();
    let critics = agent.critics.tensors();
    t.push_member("actor", &agent.actor.member(i));
    let k = agent.config.algo.critics();
    for c in 0..k {
        t.push_member(&format!("critic{}", c + 1), &member_of(&critics, k * i + c));
    }
    let n = &agent.norms[i];
    t.push("normalizer.obs_mean".into(), vec![n.obs_mean.len()], &n.obs_mean);
    t.push("normalizer.obs_std".into(), vec![n.obs_std.len()], &n.obs_std);
    t.push("normalizer.goal_mean".into(), vec![n.goal_mean.len()], &n.goal_mean);
    t.push("normalizer.goal_std".into(), vec![n.goal_std.len()], &n.goal_std);
    let mut meta = extra.clone();
    meta.insert("format".into(), FORMAT.into());
    meta.insert("config".into(), serde_json::to_string(&agent.config)?);
    meta.insert("task".into(), serde_json::to_string(&agent.task)?);
    meta.insert("normalizer_clip".into(), n.clip.to_string());
    meta.insert("updates".into(), agent.updates.to_string());
    meta.insert("pgser_version".into(), env!("CARGO_PKG_VERSION").into());
    t.stage(path, meta)
}

/// Reads a model file written by `save`: a stack of one agent (online networks and normalizer;
/// targets start as copies, optimizers fresh) and the file's metadata.
pub fn load(path: &Path, device: Device) -> Result<(Agent, HashMap<String, String>)> {
    let f = Loaded::open(path)?;
    let meta = f.metadata()?;
    if meta.get("format").map(String::as_str) != Some(FORMAT) {
        bail!("{}: not a pgser agent checkpoint (metadata format is not {FORMAT})", path.display());
    }
    let config: AgentConfig = f.meta_json(&meta, "config")?;
    let task: Task = f.meta_json(&meta, "task")?;
    let clip: f32 = f.meta_json(&meta, "normalizer_clip")?;
    let norm = Normalizer {
        obs_mean: f.tensor("normalizer.obs_mean", &[task.obs_dim])?,
        obs_std: f.tensor("normalizer.obs_std", &[task.obs_dim])?,
        goal_mean: f.tensor("normalizer.goal_mean", &[task.goal_dim])?,
        goal_std: f.tensor("normalizer.goal_std", &[task.goal_dim])?,
        clip,
    };
    let (actor_sizes, critic_sizes) = net_sizes(&config, &task);
    let actor = f.member("actor", &actor_sizes)?;
    let critics = (1..=config.algo.critics())
        .map(|c| f.member(&format!("critic{c}"), &critic_sizes))
        .collect::<Result<Vec<_>>>()?;
    let mut agent = Agent::new(config, task, norm, 0, device.clone());
    agent.actor = Mlp::from_members(&[actor], &device);
    agent.critics = Mlp::from_members(&critics, &device);
    agent.actor_target = agent.actor.copy();
    agent.critics_target = agent.critics.copy();
    agent.actor_opt = Adam::new(agent.config.lr(), &agent.actor);
    agent.critics_opt = Adam::new(agent.config.lr(), &agent.critics);
    agent.updates = f.meta_json(&meta, "updates")?;
    Ok((agent, meta))
}

/// Where a checkpoint's companion file (its resume state, an online run's replay buffer) waits
/// while the checkpoint is put in place: `FILE.next`.
pub fn pending_path(path: &Path) -> PathBuf {
    crate::output::with_suffix(path, ".next")
}

/// Puts a staged checkpoint and its staged companions (resume state, replay buffer) in place so
/// that a crash at any instant leaves files that load together. Each companion is first moved to
/// its `pending_path`, the checkpoint then replaces the old one, and the companions last replace
/// theirs. Killed before the checkpoint's rename, the old checkpoint is in place with its own
/// companions; killed after it, the new checkpoint's companions are the pending ones, which the
/// readers take when the ones in place are of another update (`load_resume`, the online
/// trainer's buffer). The next save replaces whatever pending file a crash left.
pub fn commit_with(model: AtomicFile, companions: Vec<AtomicFile>) -> Result<()> {
    let mut moves = Vec::with_capacity(companions.len());
    for c in companions {
        let (dest, pending) = (c.dest().to_path_buf(), pending_path(c.dest()));
        c.commit_as(&pending)?;
        moves.push((pending, dest));
    }
    model.commit()?;
    for (pending, dest) in moves {
        std::fs::rename(&pending, &dest)
            .with_context(|| format!("{}: cannot move the finished file into place", dest.display()))?;
    }
    Ok(())
}

/// Where the resume state of `path` lives.
pub fn resume_path(path: &Path) -> PathBuf {
    crate::output::with_suffix(path, ".resume")
}

/// Writes the state of agent `i` that `load` does not restore: targets, Adam, the noise stream,
/// plus `extra`.
pub fn save_resume(agent: &Agent, i: usize, path: &Path, extra: &BTreeMap<String, String>) -> Result<()> {
    stage_resume(agent, i, path, extra)?.commit()
}

/// `save_resume`, not yet moved into place (see `stage`).
pub fn stage_resume(agent: &Agent, i: usize, path: &Path, extra: &BTreeMap<String, String>) -> Result<AtomicFile> {
    assert!(!agent.is_stale(), "a resume state written from a stack without its last updates (Agent::sync missed)");
    let mut t = Tensors::default();
    let targets = agent.critics_target.tensors();
    t.push_member("actor_target", &agent.actor_target.member(i));
    t.push_moments("adam.actor", &agent.actor_opt.member(i));
    let mut meta = extra.clone();
    meta.insert("adam.actor.step".into(), agent.actor_opt.step.to_string());
    let k = agent.config.algo.critics();
    for c in 0..k {
        t.push_member(&format!("critic{}_target", c + 1), &member_of(&targets, k * i + c));
        t.push_moments(&format!("adam.critic{}", c + 1), &agent.critics_opt.member(k * i + c));
        meta.insert(format!("adam.critic{}.step", c + 1), agent.critics_opt.step.to_string());
    }
    meta.insert("format".into(), format!("{FORMAT}-resume"));
    meta.insert("updates".into(), agent.updates.to_string());
    meta.insert("noise_rng".into(), serde_json::to_string(&agent.noise_rngs[i].words())?);
    t.stage(path, meta)
}

/// Restores what `save_resume` wrote into a stack of one agent loaded from the model file of the
/// same update; returns the resume file's metadata (with the trainer's extra keys).
///
/// A resume state of another update is refused, unless the pending one beside it
/// ([`pending_path`], left by a save killed between its renames, [`commit_with`]) is of the
/// checkpoint's update: that one is then read.
pub fn load_resume(agent: &mut Agent, path: &Path) -> Result<HashMap<String, String>> {
    assert_eq!(agent.agents(), 1, "resume states are restored one agent at a time");
    let mut f = Loaded::open(path)?;
    let mut meta = f.metadata()?;
    let updates: u64 = f.meta_json(&meta, "updates")?;
    if updates != agent.updates {
        let pending = pending_path(path);
        let fits = |p: &Path| -> Option<(Loaded, HashMap<String, String>)> {
            let f = Loaded::open(p).ok()?;
            let meta = f.metadata().ok()?;
            (f.meta_json::<u64>(&meta, "updates").ok()? == agent.updates).then_some((f, meta))
        };
        let Some(found) = pending.exists().then(|| fits(&pending)).flatten() else {
            bail!(
                "{}: resume state is from update {updates} but the checkpoint is from update {}; they do not belong together",
                path.display(),
                agent.updates
            );
        };
        (f, meta) = found;
    }
    let path = f.path.clone();
    let path = path.as_path();
    let device = agent.device.clone();
    let (actor_sizes, critic_sizes) = net_sizes(&agent.config, &agent.task);
    agent.actor_target = Mlp::from_members(&[f.member("actor_target", &actor_sizes)?], &device);
    let lr = agent.config.lr();
    let (am, av) = f.moments("adam.actor", &actor_sizes)?;
    agent.actor_opt = Adam::from_members(lr, f.meta_json(&meta, "adam.actor.step")?, &[am], &[av], &device);
    let (mut targets, mut m, mut v, mut steps) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for c in 1..=agent.config.algo.critics() {
        targets.push(f.member(&format!("critic{c}_target"), &critic_sizes)?);
        let (cm, cv) = f.moments(&format!("adam.critic{c}"), &critic_sizes)?;
        m.push(cm);
        v.push(cv);
        steps.push(f.meta_json::<u64>(&meta, &format!("adam.critic{c}.step"))?);
    }
    if steps.iter().any(|&s| s != steps[0]) {
        bail!("{}: the critics' Adam steps differ ({steps:?})", path.display());
    }
    agent.critics_target = Mlp::from_members(&targets, &device);
    agent.critics_opt = Adam::from_members(lr, steps[0], &m, &v, &device);
    agent.noise_rngs = vec![NpRandom::from_words(f.meta_json(&meta, "noise_rng")?)];
    Ok(meta)
}
