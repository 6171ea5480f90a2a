//! OGBench shards → a table folder ([`crate::trajectory::folder`]): `pgser-etl convert DIR -o OUT`, where
//! DIR holds Horizon Reduction's or OGBench's shards (`NAME-0.npz` … `NAME-999.npz`, and
//! `NAME-val.npz`), or `convert A.npz B.npz … -o OUT`.
//!
//! Each shard is converted on its own by the OGBench reader into `OUT/NAME-i.parquet` (written
//! atomically), several at once; the manifest is written last. A shard already in OUT whose
//! footer records the same source bytes (SHA-256) and the same command is kept, so a convert
//! killed at any moment, run again, redoes only the shards it had not finished. Before any
//! output, every shard's headers and episode ends are read and checked to agree (task, T,
//! dimensions, float type); after, their footers (passthrough columns too). `-val.npz` shards
//! make the validation table, `OUT/val/`, as OGBench keeps them apart.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use indicatif::ProgressBar;
use rayon::prelude::*;

use crate::ogbench;
use crate::trajectory::folder::{Manifest, VALIDATION, shard_footer};
use crate::trajectory::{ConvertOptions, ConvertPlan, ConvertSummary};

/// The `.npz` files of `dir` when it holds any (a folder of shards); None for any other
/// folder (a Minari dataset) or a file.
pub(super) fn in_folder(dir: &Path) -> Result<Option<Vec<PathBuf>>> {
    if !dir.is_dir() {
        return Ok(None);
    }
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("{}: cannot list", dir.display()))? {
        let path = entry.with_context(|| format!("{}: cannot list", dir.display()))?.path();
        if path.is_file() && path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz")) {
            files.push(path);
        }
    }
    Ok((!files.is_empty()).then_some(files))
}

/// `NAME-i` → (NAME, i); `NAME-val` and other names → None.
fn shard_index(stem: &str) -> Option<(&str, u64)> {
    let (name, i) = stem.rsplit_once('-')?;
    (!i.is_empty() && i.bytes().all(|b| b.is_ascii_digit())).then(|| Some((name, i.parse().ok()?))).flatten()
}

fn stem(p: &Path) -> String {
    p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// The training shards in folder order (by name, then by shard number, so `-2` comes before
/// `-10`) and the validation shards (`-val`).
fn split(files: &[PathBuf]) -> Result<(Vec<PathBuf>, Vec<PathBuf>)> {
    let (val, mut train): (Vec<PathBuf>, Vec<PathBuf>) = files.iter().cloned().partition(|p| stem(p).ends_with("-val"));
    train.sort_by(|a, b| {
        let (sa, sb) = (stem(a), stem(b));
        match (shard_index(&sa), shard_index(&sb)) {
            (Some(x), Some(y)) => x.cmp(&y),
            _ => sa.cmp(&sb),
        }
    });
    if let Some(w) = train.windows(2).find(|w| stem(&w[0]) == stem(&w[1])) {
        bail!("{} and {}: two shards of one name", w[0].display(), w[1].display());
    }
    if train.is_empty() {
        bail!("{}: only validation shards (-val.npz); a table needs its training shards", files[0].display());
    }
    Ok((train, val))
}

/// The environment of a shard named `NAME-i` (or `NAME-val`), for `--task` when none is given:
/// the shard's number is not part of OGBench's dataset name.
fn task_of(task: Option<&str>, shard: &Path) -> Option<String> {
    if let Some(t) = task {
        return Some(t.to_string());
    }
    ogbench::env_name(ogbench::dataset_of_stem(&stem(shard)))
}

/// `opts` for one shard into `out`.
fn shard_opts(opts: &ConvertOptions, shard: &Path, out: &Path) -> ConvertOptions {
    ConvertOptions {
        inputs: vec![shard.to_path_buf()],
        output: out.join(format!("{}.parquet", stem(shard))),
        task: task_of(opts.task.as_deref(), shard),
        ..opts.clone()
    }
}

fn refuse_flags(opts: &ConvertOptions) -> Result<()> {
    if opts.episodes.is_some() {
        bail!("--episodes: not with shards (each shard is converted whole; take fewer shards instead)");
    }
    Ok(())
}

/// Every shard's plan, checked to agree with the first's.
fn plans(opts: &ConvertOptions, shards: &[PathBuf], out: &Path) -> Result<Vec<ConvertPlan>> {
    let plans: Vec<ConvertPlan> =
        shards.par_iter().map(|s| ogbench::check(&shard_opts(opts, s, out), s)).collect::<Result<_>>()?;
    for (p, s) in plans.iter().zip(shards).skip(1) {
        agree((&plans[0], &shards[0]), (p, s), "the shards of one table must agree")?;
    }
    Ok(plans)
}

/// Refuses shard `s` (planned as `p`) unless its environment, episode length, image shape,
/// widths and float type are those of `shards0` (planned as `first`).
fn agree((first, shard0): (&ConvertPlan, &Path), (p, s): (&ConvertPlan, &Path), why: &str) -> Result<()> {
    let (a, b, at) = (&first.task, &p.task, shard0.display());
    let differs = [
        (a.name != b.name).then(|| format!("environment {} where {at} has {}", b.name, a.name)),
        (a.t != b.t).then(|| format!("episodes of {} rows where {at} has {}", b.t, a.t)),
        (first.image_shape != p.image_shape).then(|| {
            let obs = |shape: &[usize]| match shape {
                [] => "float observations".to_string(),
                s => format!("observations uint8 images {}", crate::trajectory::shape_text(s)),
            };
            format!("{} where {at} has {}", obs(&p.image_shape), obs(&first.image_shape))
        }),
        ((a.obs_dim, a.goal_dim, a.act_dim) != (b.obs_dim, b.goal_dim, b.act_dim)).then(|| {
            format!(
                "obs {}, goal {}, act {} where {at} has obs {}, goal {}, act {}",
                b.obs_dim, b.goal_dim, b.act_dim, a.obs_dim, a.goal_dim, a.act_dim
            )
        }),
        (first.float_type != p.float_type).then(|| {
            format!(
                "{} where {at} is {} (pass --float32 to store both as float32)",
                p.float_type.name(),
                first.float_type.name()
            )
        }),
    ];
    if let Some(d) = differs.into_iter().flatten().next() {
        bail!("{}: {d}: {why}", s.display());
    }
    Ok(())
}

pub(super) fn check(opts: &ConvertOptions, files: &[PathBuf]) -> Result<ConvertPlan> {
    refuse_flags(opts)?;
    let (train, _) = split(files)?;
    let plans = plans(opts, &train, &opts.output)?;
    Ok(ConvertPlan {
        task: plans[0].task.clone(),
        float_type: plans[0].float_type,
        image_shape: plans[0].image_shape.clone(),
        row_bytes: plans[0].row_bytes,
        episodes_in_file: plans.iter().flat_map(|p| p.episodes_in_file.iter().copied()).collect(),
        episodes_taken: plans.iter().flat_map(|p| p.episodes_taken.iter().copied()).collect(),
    })
}

/// Where a convert into a folder keeps its settings while it runs (the manifest keeps them
/// after).
const SETTINGS: &str = ".convert.json";

/// What decides a shard's bytes besides its source: every setting but the paths.
fn settings(opts: &ConvertOptions) -> serde_json::Value {
    let mut drop = opts.drop.clone();
    drop.sort();
    serde_json::json!({
        "task": opts.task, "threshold": opts.threshold, "float32": opts.float32,
        "allow_nonfinite": opts.allow_nonfinite, "exact_length": opts.exact_length,
        "row_group_rows": opts.row_group_rows, "full_goal": opts.full_goal, "drop": drop,
        "pgser_version": env!("CARGO_PKG_VERSION"),
    })
}

/// The settings the last convert into `out` ran with, from its manifest or, for one that did
/// not finish, its settings file.
fn earlier_settings(out: &Path) -> Option<serde_json::Value> {
    let read = |p: PathBuf| -> Option<serde_json::Value> { serde_json::from_slice(&std::fs::read(p).ok()?).ok() };
    read(out.join(SETTINGS)).or_else(|| read(out.join(crate::trajectory::folder::MANIFEST))?.get("settings").cloned())
}

/// Whether `opts.output` (a shard's table) is already what converting `shard` would write: a
/// table whose footer names the same source bytes, made with the same settings (`same`).
fn finished(opts: &ConvertOptions, shard: &Path, same: bool) -> Result<bool> {
    if !same || !opts.output.is_file() {
        return Ok(false);
    }
    let Ok(f) = shard_footer(&opts.output) else { return Ok(false) };
    if f.sources.len() != 1 {
        return Ok(false);
    }
    Ok(f.sources[0].sha256 == crate::output::sha256_file(shard)?)
}

/// OUT made ready: created when absent; when present, a folder holding nothing but what a
/// convert into it writes (shards of these names, the manifest, `val/`, temporary files).
/// Returns whether its shards were made with `settings` (and so may be kept); the settings are
/// recorded in it before any shard is written.
fn prepare(out: &Path, shards: &[PathBuf], settings: &serde_json::Value) -> Result<bool> {
    if out.exists() && !out.is_dir() {
        bail!("{}: the output of a convert of shards is a folder, and this is a file", out.display());
    }
    if out.is_dir() {
        let ours: Vec<String> = shards.iter().map(|s| format!("{}.parquet", stem(s))).collect();
        for entry in std::fs::read_dir(out).with_context(|| format!("{}: cannot list", out.display()))? {
            let name = entry.with_context(|| format!("{}: cannot list", out.display()))?.file_name();
            let name = name.to_string_lossy();
            let known = ours.iter().any(|o| *o == name)
                || name == crate::trajectory::folder::MANIFEST
                || name == VALIDATION
                || name == SETTINGS
                || (name.starts_with('.') && name.ends_with(".tmp"));
            if !known {
                bail!(
                    "{}: holds {name}, which is none of this convert's shards: give an empty or new folder, or one a \
                     convert of the same shards wrote",
                    out.display()
                );
            }
        }
    } else {
        std::fs::create_dir(out).with_context(|| format!("{}: cannot create the output folder", out.display()))?;
    }
    let same = earlier_settings(out).as_ref() == Some(settings);
    crate::trajectory::folder::write_json(&out.join(SETTINGS), settings)?;
    // A manifest left from an earlier convert would describe other shards until the new one is
    // written: gone first, so the folder is never a table with a stale manifest.
    let manifest = out.join(crate::trajectory::folder::MANIFEST);
    if manifest.exists() {
        std::fs::remove_file(&manifest).with_context(|| format!("{}: cannot remove", manifest.display()))?;
    }
    Ok(same)
}

/// The shards converted into `out` (those already finished kept), then its manifest.
fn convert_into(
    opts: &ConvertOptions,
    (shards, plans): (&[PathBuf], Vec<ConvertPlan>),
    out: &Path,
    validation: bool,
    bar: &ProgressBar,
) -> Result<(ConvertSummary, usize)> {
    let settings = settings(opts);
    let same = prepare(out, shards, &settings)?;
    bar.set_length(plans.iter().map(|p| (p.episodes_taken[0] * p.task.t) as u64).sum());
    // Shards side by side, as many as there are threads but within ogbench::WINDOW_BYTES of
    // their rows together: each gets an equal share, at least two of its row groups, so that
    // wide shards (humanoid's 18 MB groups, an image table's 32 MiB) run fewer at a time
    // rather than each holding more, and convert's memory does not grow with the thread count.
    let threads = rayon::current_num_threads().max(1);
    let group = plans.iter().map(|p| ogbench::group_bytes(p, opts.row_group_rows)).max().unwrap_or(1).max(1);
    let side_by_side = (ogbench::WINDOW_BYTES / (2 * group)).clamp(1, threads);
    let share = ogbench::WINDOW_BYTES / side_by_side;
    let work: Vec<(&PathBuf, &ConvertPlan)> = shards.iter().zip(&plans).collect();
    let mut done: Vec<(Option<ConvertSummary>, usize)> = Vec::with_capacity(work.len());
    for wave in work.chunks(side_by_side) {
        let part: Vec<(Option<ConvertSummary>, usize)> = wave
            .par_iter()
            .map(|&(shard, plan)| {
                let o = shard_opts(opts, shard, out);
                let rows = plan.episodes_taken[0] * plan.task.t;
                let summary = if finished(&o, shard, same)? {
                    None
                } else {
                    Some(ogbench::convert_within(&o, shard, &ProgressBar::hidden(), share)?)
                };
                crate::progress::advance(bar, rows as u64)?;
                Ok((summary, rows))
            })
            .collect::<Result<_>>()?;
        done.extend(part);
    }
    let files: Vec<String> = shards.iter().map(|s| format!("{}.parquet", stem(s))).collect();
    let manifest = Manifest::of_shards(out, &files, &opts.command, validation, Some(settings))?;
    manifest.write(out)?;
    let sidecar = out.join(SETTINGS);
    std::fs::remove_file(&sidecar).with_context(|| format!("{}: cannot remove", sidecar.display()))?;
    let reused = done.iter().filter(|(s, _)| s.is_none()).count();
    let converted: Vec<&ConvertSummary> = done.iter().filter_map(|(s, _)| s.as_ref()).collect();
    let mut notes: Vec<String> = converted.first().map(|s| s.notes.clone()).unwrap_or_default();
    notes.push(format!(
        "{}: {} shards, {} converted, {reused} kept from an earlier convert with the same settings",
        out.display(),
        shards.len(),
        shards.len() - reused
    ));
    let summary = ConvertSummary {
        task: plans[0].task.clone(),
        float_type: plans[0].float_type,
        episodes: manifest.episodes,
        rows: manifest.rows,
        bytes: manifest.shards.iter().map(|s| s.bytes).sum(),
        skipped_keys: converted.iter().flat_map(|s| s.skipped_keys.iter().cloned()).collect(),
        kept: converted.first().map(|s| s.kept.clone()).unwrap_or_default(),
        notes,
    };
    Ok((summary, reused))
}

/// `pgser-etl convert DIR -o OUT`: the training shards into the table folder OUT, the
/// validation shards into OUT/val/.
pub(super) fn convert(opts: &ConvertOptions, files: &[PathBuf], bar: &ProgressBar) -> Result<ConvertSummary> {
    refuse_flags(opts)?;
    crate::output::check_not_an_input(&opts.output, files)?;
    let (train, val) = split(files)?;
    // Every shard planned, and the validation shards checked against the training ones, before
    // anything is written: a validation shard of another task would otherwise be found after
    // the training table was converted.
    let dir = opts.output.join(VALIDATION);
    let train_plans = plans(opts, &train, &opts.output)?;
    let val_plans = if val.is_empty() { Vec::new() } else { plans(opts, &val, &dir)? };
    if let Some(v) = val_plans.first() {
        let why = "the validation shards must agree with the training shards";
        agree((&train_plans[0], &train[0]), (v, &val[0]), why)?;
    }
    let (mut summary, _) = convert_into(opts, (&train, train_plans), &opts.output, !val.is_empty(), bar)?;
    if !val.is_empty() {
        let (v, _) = convert_into(opts, (&val, val_plans), &dir, false, &ProgressBar::hidden())?;
        summary.notes.push(format!(
            "{}: the validation table, {} episodes, {} rows (from {})",
            dir.display(),
            v.episodes,
            v.rows,
            val.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        ));
    }
    Ok(summary)
}

/// `pgser-etl export DIR --format ogbench -o OUT`: a table folder back as OGBench shards, each
/// shard's table exported to `OUT/NAME-i.npz` (its validation shards beside them, as Horizon
/// Reduction and OGBench keep them), so a folder converted and exported is the source folder.
pub(super) fn export(opts: &crate::minari::ExportOptions) -> Result<crate::minari::ExportSummary> {
    let folder = crate::trajectory::folder::TableFolder::open(&opts.table)?;
    if opts.format != crate::minari::ExportFormat::Ogbench {
        bail!(
            "{}: a table folder exports as OGBench shards (--format ogbench); export one of its shards for another format",
            opts.table.display()
        );
    }
    let out = &opts.output;
    if crate::output::normalize(out) == crate::output::normalize(&opts.table) || out.starts_with(&opts.table) {
        bail!("{}: the output would be inside the table folder it is made from", out.display());
    }
    if out.exists() && !out.is_dir() {
        bail!("{}: the export of a table folder is a folder of .npz shards, and this is a file", out.display());
    }
    let mut shards = folder.shard_paths();
    if let Some(v) = folder.validation()? {
        shards.extend(v.shard_paths());
    }
    if !out.is_dir() {
        std::fs::create_dir(out).with_context(|| format!("{}: cannot create the output folder", out.display()))?;
    }
    shards.par_iter().try_for_each(|shard| {
        ogbench::export_npz(shard, &out.join(format!("{}.npz", stem(shard))), &opts.drop).map(|_| ())
    })?;
    let f = folder.footer();
    Ok(crate::minari::ExportSummary { task: f.task.clone(), episodes: f.episodes, t: f.t })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_sort_by_number_and_validation_goes_apart() {
        let files: Vec<PathBuf> =
            ["d/x-v0-10.npz", "d/x-v0-val.npz", "d/x-v0-2.npz", "d/x-v0-0.npz"].iter().map(PathBuf::from).collect();
        let (train, val) = split(&files).unwrap();
        assert_eq!(train, ["d/x-v0-0.npz", "d/x-v0-2.npz", "d/x-v0-10.npz"].map(PathBuf::from));
        assert_eq!(val, [PathBuf::from("d/x-v0-val.npz")]);
        assert_eq!(shard_index("humanoidmaze-giant-navigate-v0-17"), Some(("humanoidmaze-giant-navigate-v0", 17)));
        assert_eq!(shard_index("humanoidmaze-giant-navigate-v0"), None);
        let e = split(&[PathBuf::from("d/x-val.npz")]).unwrap_err().to_string();
        assert!(e.contains("only validation shards"), "{e}");
    }

    #[test]
    fn a_shard_names_its_environment_without_its_number() {
        let p = |s: &str| PathBuf::from(s);
        assert_eq!(
            task_of(None, &p("a/humanoidmaze-giant-navigate-v0-3.npz")).as_deref(),
            Some("humanoidmaze-giant-v0")
        );
        assert_eq!(task_of(None, &p("a/pointmaze-medium-stitch-v0-val.npz")).as_deref(), Some("pointmaze-medium-v0"));
        assert_eq!(task_of(Some("x"), &p("a/y-0.npz")).as_deref(), Some("x"));
    }
}
