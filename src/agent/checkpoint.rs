//! The checkpoint file (SPEC §3.3): one safetensors file that PyTorch, numpy or any safetensors
//! reader can open, plus a `.resume` file beside it with the rest of the training state.
//!
//! Layout of `model.ckpt` (float32 tensors):
//! - `actor.{0,2,4,6}.weight` `[out, in]` and `.bias` `[out]`, likewise `critic1.*`, `critic2.*`:
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

use super::{Agent, AgentConfig, Mlp, Normalizer};
use crate::env::rng::NpRandom;
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
    fn push_net(&mut self, prefix: &str, net: &Mlp) {
        for (i, (shape, values)) in net.tensors().into_iter().enumerate() {
            let name = format!("{prefix}.{}.{}", 2 * (i / 2), if i % 2 == 0 { "weight" } else { "bias" });
            if shape.len() == 2 {
                self.push(name, vec![shape[1], shape[0]], &transpose(&values, shape[0], shape[1]));
            } else {
                self.push(name, shape, &values);
            }
        }
    }

    fn write(self, path: &Path, metadata: BTreeMap<String, String>) -> Result<()> {
        let bytes = self.encode(&metadata)?;
        let out = AtomicFile::create(path)?;
        std::io::Write::write_all(&mut out.handle()?, &bytes)
            .with_context(|| format!("{}: write failed", path.display()))?;
        out.commit()
    }

    /// The safetensors bytes, written here rather than by `safetensors::serialize`: that one
    /// takes the metadata as a `HashMap` and so writes its keys in a different order in every
    /// process, and a pipeline that rebuilds a lost checkpoint must get the same bytes back
    /// (otherwise every step downstream of it reruns). Tensors go in name order, metadata keys
    /// sorted, the header padded with spaces to 8 bytes as the format asks.
    fn encode(mut self, metadata: &BTreeMap<String, String>) -> Result<Vec<u8>> {
        self.entries.sort_by(|a, b| a.0.cmp(&b.0));
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

fn transpose(values: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut out = vec![0.0; values.len()];
    for r in 0..rows {
        for c in 0..cols {
            out[c * rows + r] = values[r * cols + c];
        }
    }
    out
}

/// A safetensors file read back: its tensors by name and its metadata.
struct Loaded {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl Loaded {
    fn open(path: &Path) -> Result<Loaded> {
        let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read checkpoint", path.display()))?;
        SafeTensors::deserialize(&bytes).with_context(|| format!("{}: not a safetensors file", path.display()))?;
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

    /// Fills `net` from `{prefix}.{k}.weight|bias`, transposing back to `[in, out]`.
    fn net(&self, prefix: &str, net: &mut Mlp, device: &Device) -> Result<()> {
        let mut values = Vec::new();
        for (i, (shape, _)) in net.tensors().into_iter().enumerate() {
            let name = format!("{prefix}.{}.{}", 2 * (i / 2), if i % 2 == 0 { "weight" } else { "bias" });
            if shape.len() == 2 {
                let v = self.tensor(&name, &[shape[1], shape[0]])?;
                values.push(transpose(&v, shape[1], shape[0]));
            } else {
                values.push(self.tensor(&name, &shape)?);
            }
        }
        net.set_tensors(&values, device);
        Ok(())
    }

    fn meta_json<T: serde::de::DeserializeOwned>(&self, meta: &HashMap<String, String>, key: &str) -> Result<T> {
        let text = meta.get(key).with_context(|| format!("{}: metadata key {key} is missing", self.path.display()))?;
        serde_json::from_str(text).with_context(|| format!("{}: metadata key {key} is not valid", self.path.display()))
    }
}

/// Writes the model file. `extra` metadata (the trainer's config, data source) is kept as given.
pub fn save(agent: &Agent, path: &Path, extra: &BTreeMap<String, String>) -> Result<()> {
    let mut t = Tensors::default();
    t.push_net("actor", &agent.actor);
    t.push_net("critic1", &agent.critic1);
    t.push_net("critic2", &agent.critic2);
    let n = &agent.norm;
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
    t.write(path, meta)
}

/// Reads a model file written by `save`: the agent (online networks and normalizer; targets
/// start as copies, optimizers fresh) and the file's metadata.
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
    let mut agent = Agent::new(config, task, norm, 0, device.clone());
    f.net("actor", &mut agent.actor, &device)?;
    f.net("critic1", &mut agent.critic1, &device)?;
    f.net("critic2", &mut agent.critic2, &device)?;
    agent.actor_target = agent.actor.copy();
    agent.critic1_target = agent.critic1.copy();
    agent.critic2_target = agent.critic2.copy();
    agent.updates = f.meta_json(&meta, "updates")?;
    Ok((agent, meta))
}

/// Where the resume state of `path` lives.
pub fn resume_path(path: &Path) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(".resume");
    PathBuf::from(p)
}

/// Writes the state `load` does not restore: targets, Adam, the noise stream, plus `extra`.
pub fn save_resume(agent: &Agent, path: &Path, extra: &BTreeMap<String, String>) -> Result<()> {
    let mut t = Tensors::default();
    t.push_net("actor_target", &agent.actor_target);
    t.push_net("critic1_target", &agent.critic1_target);
    t.push_net("critic2_target", &agent.critic2_target);
    let mut meta = extra.clone();
    for (name, opt) in [("actor", &agent.actor_opt), ("critic1", &agent.critic1_opt), ("critic2", &agent.critic2_opt)] {
        let (m, v) = opt.state();
        for (k, (m, v)) in m.iter().zip(&v).enumerate() {
            t.push(format!("adam.{name}.m.{k}"), vec![m.len()], m);
            t.push(format!("adam.{name}.v.{k}"), vec![v.len()], v);
        }
        meta.insert(format!("adam.{name}.step"), opt.step.to_string());
    }
    meta.insert("format".into(), format!("{FORMAT}-resume"));
    meta.insert("updates".into(), agent.updates.to_string());
    meta.insert("noise_rng".into(), serde_json::to_string(&agent.noise_rng.words())?);
    t.write(path, meta)
}

/// Restores what `save_resume` wrote into an agent loaded from the model file of the same
/// update; returns the resume file's metadata (with the trainer's extra keys).
pub fn load_resume(agent: &mut Agent, path: &Path) -> Result<HashMap<String, String>> {
    let f = Loaded::open(path)?;
    let meta = f.metadata()?;
    let updates: u64 = f.meta_json(&meta, "updates")?;
    if updates != agent.updates {
        bail!(
            "{}: resume state is from update {updates} but the checkpoint is from update {}; they do not belong together",
            path.display(),
            agent.updates
        );
    }
    let device = agent.device.clone();
    f.net("actor_target", &mut agent.actor_target, &device)?;
    f.net("critic1_target", &mut agent.critic1_target, &device)?;
    f.net("critic2_target", &mut agent.critic2_target, &device)?;
    for (name, net, opt) in [
        ("actor", &agent.actor, &mut agent.actor_opt),
        ("critic1", &agent.critic1, &mut agent.critic1_opt),
        ("critic2", &agent.critic2, &mut agent.critic2_opt),
    ] {
        let mut m = Vec::new();
        let mut v = Vec::new();
        for (k, (shape, _)) in net.tensors().iter().enumerate() {
            let len = shape.iter().product::<usize>();
            m.push(f.tensor(&format!("adam.{name}.m.{k}"), &[len])?);
            v.push(f.tensor(&format!("adam.{name}.v.{k}"), &[len])?);
        }
        let step: u64 = f.meta_json(&meta, &format!("adam.{name}.step"))?;
        opt.set_state(step, &m, &v, &device);
    }
    agent.noise_rng = NpRandom::from_words(f.meta_json(&meta, "noise_rng")?);
    Ok(meta)
}
