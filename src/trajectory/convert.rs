//! WGCSL pickles → trajectory table: the pickle reader of `pgser-etl convert`. The module that
//! picks this reader or the Minari one for an input sits above both (`src/convert/`); the
//! options, plan and summary types here are shared by both readers.
//!
//! Every input is memory-mapped and parsed by the safe pickle reader; all keys, shapes, dtypes
//! and dimensions are validated before the output is created. Then episodes stream out in row
//! groups of whole episodes, built and encoded in parallel windows, so memory stays near one
//! copy of the inputs (the mapped pages) plus a few row groups.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use indicatif::ProgressBar;
use sha2::{Digest, Sha256};

use super::batch::{EpisodeArrays, FloatArray, KEYS, TrajectoryWriter, WriterOptions};
use super::extra::{self, ExtraArray, Passthrough, Per};
use super::{FloatType, Footer, SourceFile};
use crate::dtype::Kind;
use crate::output::hex;
use crate::pickle::repr::shell_word;
use crate::pickle::{MappedFile, NdArray, Obj, Pickle};
use crate::task::Task;

/// `pgser-etl convert`'s settings (its flags: the CLI parses them into this), and
/// `pgser.convert`'s keyword arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct ConvertOptions {
    /// Input pickles (dicts with o [N,T,obs], ag [N,T,goal], u [N,T-1,act], g [N,T-1,goal]), or one
    /// Minari dataset folder (ID/ or ID/data/), or one OGBench dataset file (NAME.npz), or OGBench
    /// shards (a folder of NAME-i.npz, or several .npz files), which make a table folder.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Output Parquet file (written atomically); for shards, the table folder (one Parquet file per
    /// shard, each written atomically, and manifest.json; a convert run again keeps finished shards).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Task name (FetchReach, FetchPush, …); inferred from dimensions when unambiguous.
    #[arg(long)]
    pub task: Option<String>,
    /// Success threshold on the goal distance; required for tasks pgser does not know.
    #[arg(long)]
    pub threshold: Option<f64>,
    /// Take the first k episodes of each input, one count per input: `--episodes 500,2000`.
    #[arg(long, value_delimiter = ',')]
    pub episodes: Option<Vec<usize>>,
    /// Store float32 vectors even when the source is float64.
    #[arg(long)]
    pub float32: bool,
    /// Keep NaN and ±Inf values instead of refusing the file.
    #[arg(long)]
    pub allow_nonfinite: bool,
    /// A Minari dataset whose episodes are one step longer than the task's T (gymnasium's
    /// time limit: 50 steps, 51 observations for Fetch): refuse it instead of dropping each
    /// episode's last step.
    #[arg(long)]
    pub exact_length: bool,
    /// Target rows per row group (row groups always hold whole episodes).
    #[arg(long, default_value_t = 65_536)]
    pub row_group_rows: usize,
    /// OGBench files: the goal is the whole observation, as OGBench's evaluation goals are,
    /// instead of the environment's goal map (x, y; the cubes' positions); --threshold, on the
    /// observation's Euclidean distance, is then required.
    #[arg(long)]
    pub full_goal: bool,
    /// Leave the source's array KEY out of the table (repeat for several). Every array that is not
    /// one of pgser's four is otherwise kept as a column of its own, so that export gives the
    /// source back whole; one that a table cannot hold is refused by name. A pickle's key that is
    /// not a string is named as Python's repr writes it: --drop 1, --drop '(1, 2)', --drop
    /// "b'\\xff'" (bytes that are UTF-8 are the text they spell, as Python 2 wrote str keys).
    #[arg(long = "drop", value_name = "KEY")]
    pub drop: Vec<String>,
    /// The command line, recorded in the footer (set by the caller, not a flag).
    #[arg(skip)]
    pub command: String,
}

#[derive(Debug, Clone)]
pub struct ConvertSummary {
    pub task: Task,
    pub float_type: FloatType,
    pub episodes: usize,
    pub rows: usize,
    pub bytes: u64,
    /// "file: key" for the keys `--drop` left out.
    pub skipped_keys: Vec<String>,
    /// The passthrough columns the table keeps: "column (per step, <f8 [1])".
    pub kept: Vec<String>,
    /// Other things the user should know about the conversion, one line each.
    pub notes: Vec<String>,
}

/// One input's four arrays, validated, and its other arrays.
struct Source<'a> {
    path: &'a Path,
    /// o, ag, u, g in native C order.
    arrays: [NdArray<'a>; 4],
    /// The other arrays, kept as passthrough columns (little-endian, C order).
    extras: Vec<ExtraArray<'a>>,
    episodes: usize,
    take: usize,
}

impl Source<'_> {
    fn o(&self) -> &NdArray<'_> {
        &self.arrays[0]
    }
    fn dim(&self, k: usize) -> usize {
        self.arrays[k].shape[2]
    }

    /// The arrays as the table writer takes them.
    fn view(&self) -> EpisodeArrays<'_> {
        let arrays = std::array::from_fn(|k| {
            let a = &self.arrays[k];
            FloatArray { data: &a.data, size: a.dtype.size, steps: a.shape[1], dim: a.shape[2] }
        });
        let extras = self
            .extras
            .iter()
            .map(|e| ExtraArray { spec: e.spec.clone(), data: std::borrow::Cow::Borrowed(&e.data[..]) })
            .collect();
        EpisodeArrays { origin: self.path.display().to_string(), keys: KEYS, arrays, episodes: self.episodes, extras }
    }
}

/// What `convert` would write, found by reading and validating its inputs as `convert` does
/// (keys, dtypes, shapes, the task's dimensions, the episode counts) without writing anything.
/// The arrays are memory-mapped and only their pickle headers parsed, so this reads a few pages
/// of each file, not its data: a pipeline calls it before any of its steps run.
#[derive(Debug, Clone)]
pub struct ConvertPlan {
    pub task: Task,
    pub float_type: FloatType,
    /// The shape of an image observation (`[64, 64, 3]`); empty for float observations.
    pub image_shape: Vec<usize>,
    /// Bytes of one row of the source, every array it streams (observations, actions, the
    /// passthrough members): what a window of rows holds (OGBench's files; 0 where unknown).
    pub row_bytes: usize,
    /// Episodes in each input, and taken from it.
    pub episodes_in_file: Vec<usize>,
    pub episodes_taken: Vec<usize>,
}

pub fn check(opts: &ConvertOptions) -> Result<ConvertPlan> {
    let maps = open_inputs(opts)?;
    let Sources { sources, float_type, task, .. } = read_sources(opts, &maps)?;
    Ok(ConvertPlan {
        task,
        float_type,
        image_shape: Vec::new(),
        row_bytes: 0,
        episodes_in_file: sources.iter().map(|s| s.episodes).collect(),
        episodes_taken: sources.iter().map(|s| s.take).collect(),
    })
}

fn open_inputs(opts: &ConvertOptions) -> Result<Vec<MappedFile>> {
    if opts.inputs.is_empty() {
        bail!("convert needs at least one input pickle");
    }
    crate::output::check_not_an_input(&opts.output, &opts.inputs)?;
    if let Some(ks) = &opts.episodes
        && ks.len() != opts.inputs.len()
    {
        bail!("--episodes has {} values for {} input files: give one count per input", ks.len(), opts.inputs.len());
    }
    opts.inputs.iter().map(|p| MappedFile::open(p).with_context(|| format!("{}: cannot open", p.display()))).collect()
}

/// What the inputs make, validated: everything `convert` writes, found before any output exists.
struct Sources<'a> {
    sources: Vec<Source<'a>>,
    /// "file: key" for each key `--drop` left out.
    skipped_keys: Vec<String>,
    float_type: FloatType,
    task: Task,
    /// The passthrough columns, in the first source's order (each source's extras sorted to it).
    extras: Vec<Passthrough>,
}

fn read_sources<'a>(opts: &'a ConvertOptions, maps: &'a [MappedFile]) -> Result<Sources<'a>> {
    // A table is made of these four: there is no table without one of them.
    if let Some(k) = opts.drop.iter().find(|k| KEYS.contains(&k.as_str())) {
        bail!(
            "--drop {k}: '{k}' is one of the four arrays a trajectory table is made of (o, ag, u, g); only the \
             others can be left out"
        );
    }
    let mut skipped_keys = Vec::new();
    let mut sources = Vec::with_capacity(maps.len());
    for (i, (path, map)) in opts.inputs.iter().zip(maps).enumerate() {
        let (mut src, skipped) = read_wgcsl(path, map.bytes(), &opts.drop)?;
        skipped_keys.extend(skipped.into_iter().map(|k| format!("{}: {k}", path.display())));
        if let Some(ks) = &opts.episodes {
            if ks[i] > src.episodes {
                bail!("{}: --episodes asks for {} episodes but the file has {}", path.display(), ks[i], src.episodes);
            }
            src.take = ks[i];
        }
        sources.push(src);
    }
    let float_type = output_float(&sources, opts.float32)?;
    let task = resolve_task(&sources, opts.task.as_deref(), opts.threshold)?;
    let total: usize = sources.iter().map(|s| s.take).sum();
    if total == 0 {
        bail!("{}: no episodes to write (every input was empty or took 0)", opts.inputs[0].display());
    }
    // A key is left out by its name ("file: key 'name'") or, not being a string, by its repr
    // ("file: key 1"), which never starts with a quote.
    let dropped = |k: &str| {
        let by_repr = !k.starts_with(['\'', '"']) && skipped_keys.iter().any(|s| s.ends_with(&format!(": key {k}")));
        by_repr || skipped_keys.iter().any(|s| s.ends_with(&format!(": key '{k}'")))
    };
    if let Some(k) = opts.drop.iter().find(|k| !dropped(k)) {
        bail!("--drop {k}: no input has a key '{k}' to leave out");
    }
    // Every source's passthrough arrays, in the first source's order.
    let specs: Vec<(String, Vec<Passthrough>)> = sources
        .iter()
        .map(|s| (s.path.display().to_string(), s.extras.iter().map(|e| e.spec.clone()).collect()))
        .collect();
    let extras = extra::merge(&specs)?;
    for s in &mut sources {
        s.extras.sort_by_key(|e| extras.iter().position(|p| p.column == e.spec.column));
    }
    Ok(Sources { sources, skipped_keys, float_type, task, extras })
}

pub fn convert(opts: &ConvertOptions, bar: &ProgressBar) -> Result<ConvertSummary> {
    let maps = open_inputs(opts)?;
    // Hash the inputs on a thread of their own while we parse, validate and write.
    std::thread::scope(|scope| {
        let hashing = scope.spawn(|| maps.iter().map(sha256_releasing).collect::<Vec<_>>());
        let written = (|| {
            let Sources { sources, skipped_keys, float_type, task, extras } = read_sources(opts, &maps)?;
            let total: usize = sources.iter().map(|s| s.take).sum();
            let kept = extras.iter().map(describe).collect();

            bar.set_length((total * task.t) as u64);
            let options = WriterOptions {
                allow_nonfinite: opts.allow_nonfinite,
                extras,
                ..WriterOptions::new(opts.row_group_rows)
            };
            let mut writer = TrajectoryWriter::create(&opts.output, &task, float_type, options)?;
            // A window of row groups per call keeps every thread busy; whole groups per window
            // keep the row groups where they would be in one call.
            let window = writer.episodes_per_group() * rayon::current_num_threads().max(1) * 2;
            for (src, map) in sources.iter().zip(&maps) {
                let view = src.view();
                for start in (0..src.take).step_by(window) {
                    let end = (start + window).min(src.take);
                    writer.append(&view, start, end)?;
                    crate::progress::advance(bar, ((end - start) * task.t) as u64)?;
                    for a in &src.arrays {
                        let per_episode = a.data.len() / src.episodes;
                        map.release(&a.data[start * per_episode..end * per_episode]);
                    }
                }
            }
            anyhow::Ok((sources, skipped_keys, kept, float_type, task, total, writer))
        })();
        // Joined on every path, errors included: a scoped thread whose handle is dropped unjoined
        // is waited for only until its closure returns, and its OS thread is still exiting after
        // `convert` has returned (LeakSanitizer saw its thread record: fuzz/wgcsl).
        let hashes = hashing.join().expect("hashing thread panicked");
        let (sources, skipped_keys, kept, float_type, task, total, writer) = written?;
        let mut footer = Footer::new(&task, float_type, total, opts.command.clone());
        footer.sources = sources
            .iter()
            .zip(hashes)
            .map(|(s, sha256)| SourceFile {
                path: s.path.display().to_string(),
                sha256,
                format: "wgcsl-pickle".into(),
                episodes_in_file: s.episodes,
                episodes_taken: s.take,
                steps_dropped: 0,
                float_bytes: Vec::new(),
            })
            .collect();
        let bytes = writer.finish(&footer)?;
        Ok(ConvertSummary {
            task,
            float_type,
            episodes: total,
            rows: total * footer.t,
            bytes,
            skipped_keys,
            kept,
            notes: vec![],
        })
    })
}

/// "info_is_success (<f8 [1] per transition)": a passthrough column as the convert summary
/// names it.
pub(crate) fn describe(p: &Passthrough) -> String {
    let per = match p.per {
        Per::Step => "step",
        Per::Transition => "transition",
        Per::Episode => "episode",
    };
    format!("{} ({} {:?} per {per})", p.column, p.dtype, p.shape)
}

/// SHA-256 of a mapped file, releasing each part from memory once hashed.
fn sha256_releasing(map: &MappedFile) -> String {
    let mut h = Sha256::new();
    for part in map.bytes().chunks(16 << 20) {
        h.update(part);
        map.release(part);
    }
    hex(&h.finalize())
}

/// Parse one pickle and check it is a WGCSL buffer: a dict with `o`, `ag`, `u`, `g`. Its other
/// arrays become passthrough columns, except those `drop` names; anything a table cannot hold
/// is refused by name. Returns the source and the keys dropped.
fn read_wgcsl<'a>(path: &'a Path, bytes: &'a [u8], drop: &[String]) -> Result<(Source<'a>, Vec<String>)> {
    let at = path.display();
    let mut pickle = Pickle::parse(bytes).map_err(|e| anyhow::anyhow!("{at}: {e}"))?;
    let Obj::Dict(entries) = pickle.get(pickle.root()).clone() else {
        bail!(
            "{at}: the pickle holds a {}, expected a dict with keys o, ag, u, g (a WGCSL buffer)",
            pickle.get(pickle.root()).type_name()
        );
    };
    let mut found: [Option<NdArray<'a>>; 4] = [None, None, None, None];
    let mut skipped = Vec::new();
    let mut others: Vec<(String, NdArray<'a>)> = Vec::new();
    let mut names: Vec<String> = Vec::new();
    for (k, v) in entries {
        // A str key names its column; so do bytes that are UTF-8, as Python 2 wrote str keys (a
        // pickle does not tell the two apart). Any other key is named as Python's repr writes it
        // (`1`, `b'\xff'`, `(1, 2)`), which is what --drop takes to leave it out.
        let name = pickle.as_text(k).map(Cow::into_owned);
        let Some(name) = name else {
            let repr = pickle.repr(k);
            if drop.contains(&repr) {
                skipped.push(format!("key {repr}"));
                continue;
            }
            let what = match pickle.get(k) {
                Obj::Bytes(_) => "bytes, not UTF-8 text".to_string(),
                other => format!("{}, not a string", other.type_name()),
            };
            bail!(
                "{at}: key {repr} ({what}): a table column needs a text name; pass --drop {} to convert without it",
                shell_word(&repr)
            );
        };
        if drop.contains(&name) && !KEYS.contains(&name.as_str()) {
            skipped.push(format!("key '{name}'"));
            continue;
        }
        if names.contains(&name) {
            let leave = match KEYS.contains(&name.as_str()) {
                true => String::new(),
                false => format!("; pass --drop {} to convert without both", shell_word(&name)),
            };
            bail!("{at}: key '{name}' is there twice, as a str and as bytes: a table has one column of a name{leave}");
        }
        names.push(name.clone());
        let slot = KEYS.iter().position(|&key| key == name);
        match (pickle.take(v), slot) {
            (Obj::Array(a), Some(slot)) => found[slot] = Some(a),
            (Obj::Array(a), None) => others.push((name, a)),
            (Obj::Unreadable(d), Some(_)) => {
                bail!("{at}: key '{name}' holds values of dtype {d}; WGCSL arrays must be float32 or float64")
            }
            (Obj::Unreadable(d), None) => bail!(
                "{at}: key '{name}' holds values of dtype {d}, which a table column cannot keep (bool, int, uint, float32 \
                 and float64 can); pass --drop {} to convert without it",
                shell_word(&name)
            ),
            (other, Some(_)) => bail!("{at}: key '{name}' is a {}, not a numpy array", other.type_name()),
            (other, None) => bail!(
                "{at}: key '{name}' is a {}, not a numpy array: a table keeps arrays; pass --drop {} to convert without it",
                other.type_name(),
                shell_word(&name)
            ),
        }
    }
    let missing: Vec<&str> = KEYS.iter().zip(&found).filter(|(_, a)| a.is_none()).map(|(k, _)| *k).collect();
    if !missing.is_empty() {
        bail!("{at}: missing key '{}' (a WGCSL buffer has o, ag, u, g)", missing.join("', '"));
    }
    let arrays = found.map(|a| a.expect("checked above"));
    for (key, a) in KEYS.iter().zip(&arrays) {
        if a.dtype.kind != Kind::Float || a.dtype.size < 4 {
            bail!("{at}: key '{key}' holds {} values; WGCSL arrays must be float32 or float64", a.dtype.name());
        }
        if a.shape.len() != 3 {
            bail!("{at}: key '{key}' has shape {}; expected 3 dimensions (episodes, steps, values)", a.shape_text());
        }
    }
    let n: Vec<usize> = arrays.iter().map(|a| a.shape[0]).collect();
    if n.iter().any(|&x| x != n[0]) {
        bail!("{at}: episode count differs across keys: o has {}, ag {}, u {}, g {}", n[0], n[1], n[2], n[3]);
    }
    if n[0] == 0 {
        bail!("{at}: the file has no episodes (N = 0)");
    }
    let steps: Vec<usize> = arrays.iter().map(|a| a.shape[1]).collect();
    let t = steps[0];
    if steps[1] != t {
        bail!("{at}: steps differ: o has {t} steps per episode, ag has {}", steps[1]);
    }
    if t < 2 {
        bail!("{at}: episodes have {t} steps; at least 2 observations are needed for a transition");
    }
    for k in [2, 3] {
        if steps[k] != t - 1 {
            bail!(
                "{at}: key '{}' has {} steps per episode; expected T-1 = {} (o has T = {t} observations)",
                KEYS[k],
                steps[k],
                t - 1
            );
        }
    }
    let (ag_dim, g_dim) = (arrays[1].shape[2], arrays[3].shape[2]);
    if ag_dim != g_dim {
        bail!("{at}: goal dimension differs: ag has {ag_dim} values per step, g has {g_dim}");
    }
    let episodes = n[0];
    let mut extras = Vec::with_capacity(others.len());
    for (name, a) in others {
        if a.shape.first() != Some(&episodes) {
            bail!(
                "{at}: key '{name}' has shape {}; an array kept beside o, ag, u, g has the {episodes} episodes first; pass --drop {name} to convert without it",
                a.shape_text()
            );
        }
        let per = Per::of(a.shape.get(1).copied(), t);
        let shape = a.shape[if per == Per::Episode { 1 } else { 2 }..].to_vec();
        let spec = Passthrough::new(&at.to_string(), &name, a.dtype, per, shape)?;
        extras.push(ExtraArray { spec, data: a.data });
    }
    Ok((Source { path, arrays, extras, episodes, take: episodes }, skipped))
}

fn output_float(sources: &[Source], float32: bool) -> Result<FloatType> {
    if float32 {
        return Ok(FloatType::Float32);
    }
    let size = sources[0].o().dtype.size;
    for s in sources {
        for (key, a) in KEYS.iter().zip(&s.arrays) {
            if a.dtype.size != size {
                bail!(
                    "{}: key '{key}' is {} but '{}' key 'o' is {}: mixed float types; pass --float32 to store all as float32",
                    s.path.display(),
                    a.dtype.name(),
                    sources[0].path.display(),
                    sources[0].o().dtype.name()
                );
            }
        }
    }
    Ok(if size == 4 { FloatType::Float32 } else { FloatType::Float64 })
}

/// Pick the task: the named one (dimensions must match), a custom one (`--threshold`), or the
/// single built-in task whose dimensions match the data.
fn resolve_task(sources: &[Source], name: Option<&str>, threshold: Option<f64>) -> Result<Task> {
    let first = &sources[0];
    let dims = |s: &Source| (s.o().shape[1], s.dim(0), s.dim(1), s.dim(2));
    let (t, obs, goal, act) = dims(first);
    for s in &sources[1..] {
        if dims(s) != dims(first) {
            let (t2, o2, g2, a2) = dims(s);
            bail!(
                "{}: dimension mismatch with {}: T {t2} vs {t}, obs {o2} vs {obs}, goal {g2} vs {goal}, act {a2} vs {act}",
                s.path.display(),
                first.path.display()
            );
        }
    }
    let at = first.path.display().to_string();
    task_for(&at, (t, obs, goal, act), ["key 'o'", "key 'ag'", "key 'u'"], "steps", name, threshold)
}

/// The task for data of T observations per episode and these dimensions: the named built-in
/// task (dimensions and T must match), a custom one (a name pgser does not know, with
/// `threshold`), or the single built-in task the dimensions fit. `keys` name the observation,
/// goal and action arrays in messages and `t_unit` what T counts, in the words of the input's
/// format (pickles and Minari datasets share this). `threshold` overrides a built-in task's.
pub(crate) fn task_for(
    at: &str,
    (t, obs, goal, act): (usize, usize, usize, usize),
    keys: [&str; 3],
    t_unit: &str,
    name: Option<&str>,
    threshold: Option<f64>,
) -> Result<Task> {
    if let Some(th) = threshold
        && !(th.is_finite() && th > 0.0)
    {
        bail!("--threshold must be a positive number, got {th}");
    }
    let mut task = match name {
        Some(name) => match Task::known(name) {
            Some(task) => {
                for (key, have, want, what) in [
                    (keys[0], obs, task.obs_dim, "observations"),
                    (keys[1], goal, task.goal_dim, "goals"),
                    (keys[2], act, task.act_dim, "actions"),
                ] {
                    if have != want {
                        bail!(
                            "{at}: dimension mismatch: {key} has {have} values per step but {} {what} have {want}",
                            task.name
                        );
                    }
                }
                if t != task.t {
                    bail!("{at}: episodes have {t} {t_unit} but {} has T = {}", task.name, task.t);
                }
                task
            }
            None => match threshold {
                Some(th) => Task::custom(name, t, obs, goal, act, th),
                None => bail!(
                    "{at}: task '{name}' is not built in (known: {}); pass --threshold to give its success threshold",
                    Task::known_names().join(", ")
                ),
            },
        },
        None => {
            let matches = Task::matching(t, obs, goal, act);
            match matches.as_slice() {
                [one] => one.clone(),
                [] => bail!(
                    "{at}: no built-in task has T {t}, obs {obs}, goal {goal}, act {act}; pass --task NAME --threshold X"
                ),
                many => bail!(
                    "{at}: the dimensions fit {}; pass --task to choose",
                    many.iter().map(|t| t.name.as_str()).collect::<Vec<_>>().join(", ")
                ),
            }
        }
    };
    if let Some(th) = threshold {
        task.threshold = th;
    }
    Ok(task)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pickle::write::{ArrayOut, write_dict};

    /// `--drop` of one of the four arrays says that those cannot be left out, not that the input
    /// lacks them.
    #[test]
    fn dropping_one_of_the_four_arrays_is_refused_as_such() {
        let dir = tempfile::tempdir().unwrap();
        let src = dir.path().join("buf.pkl");
        let (n, t) = (2, 3);
        let f8 = |count: usize| vec![0u8; count * 8];
        let (o, ag, u, g) = (f8(n * t * 2), f8(n * t), f8(n * (t - 1)), f8(n * (t - 1)));
        let mut arrays = vec![
            ArrayOut::from_bytes("o", vec![n, t, 2], &o),
            ArrayOut::from_bytes("ag", vec![n, t, 1], &ag),
            ArrayOut::from_bytes("u", vec![n, t - 1, 1], &u),
            ArrayOut::from_bytes("g", vec![n, t - 1, 1], &g),
        ];
        write_dict(&mut std::fs::File::create(&src).unwrap(), &mut arrays).unwrap();
        for key in KEYS {
            let opts = ConvertOptions {
                inputs: vec![src.clone()],
                output: dir.path().join("t.parquet"),
                task: Some("Tiny".into()),
                threshold: Some(0.1),
                episodes: None,
                float32: false,
                allow_nonfinite: false,
                exact_length: false,
                row_group_rows: 64,
                full_goal: false,
                drop: vec![key.to_string()],
                command: String::new(),
            };
            let e = check(&opts).unwrap_err().to_string();
            assert!(e.starts_with(&format!("--drop {key}: '{key}' is one of the four arrays")), "{e}");
        }
    }
}
