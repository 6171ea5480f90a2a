//! `pgser-etl convert` of one OGBench file: its members streamed a window of episodes at a time
//! into the trajectory writer, within a bound on the bytes held whatever the thread count.

use std::io::Read;
use std::path::Path;

use anyhow::{Context, Result};
use indicatif::ProgressBar;

use super::window::Window;
use super::{Dataset, Layout, float_type, npz, take};
use crate::trajectory::{
    ConvertOptions, ConvertPlan, ConvertSummary, FloatType, Footer, Passthrough, SourceFile, TrajectoryWriter,
    WriterOptions,
};

/// The most bytes of a file's rows (every member) `convert` reads at once, whatever the thread
/// count: a window holds this once as read, once laid out as the table's rows and about twice
/// as Arrow columns and their encoding, so convert's memory is a small multiple of it
/// (BENCHMARKS.md, "Convert's memory"). Shards converted side by side share it
/// ([`convert_within`]).
pub const WINDOW_BYTES: usize = 256 << 20;

/// `pgser-etl convert DATASET.npz -o traj.parquet`: a window of episodes at a time, observations
/// and actions (and a regular file's next observations) streamed side by side, so memory holds a
/// window, not the dataset.
pub fn convert(opts: &ConvertOptions, path: &Path, bar: &ProgressBar) -> Result<ConvertSummary> {
    convert_within(opts, path, bar, WINDOW_BYTES)
}

/// The bytes of one row group of a table of `plan`'s episodes as read from the source (every
/// member), written with `row_group_rows` (an image table's groups capped by bytes:
/// [`TrajectoryWriter`]).
pub fn group_bytes(plan: &ConvertPlan, row_group_rows: usize) -> usize {
    let t = plan.task.t;
    let per_group = if plan.image_shape.is_empty() {
        crate::trajectory::episodes_per_group(row_group_rows, t)
    } else {
        crate::trajectory::image_episodes_per_group(row_group_rows, t, plan.task.obs_dim)
    };
    per_group * t * plan.row_bytes.max(1)
}

/// [`convert`] reading at most `window_bytes` of the file's rows at a time (at least one row
/// group): a folder's shards, converted side by side, each get their share of
/// [`WINDOW_BYTES`].
pub fn convert_within(
    opts: &ConvertOptions,
    path: &Path,
    bar: &ProgressBar,
    window_bytes: usize,
) -> Result<ConvertSummary> {
    crate::output::check_not_an_input(&opts.output, &opts.inputs)?;
    let mut d = Dataset::open(path, opts.task.as_deref(), opts.full_goal, &opts.drop)?;
    let episodes = take(opts, &d)?;
    let task = d.task(opts.threshold)?;
    let next_kept = d.keep_next_observations()?;
    let float = float_type(&d, opts.float32);
    let sha256 = crate::output::sha256_file(path)?;
    let specs: Vec<Passthrough> = d.extras.iter().map(|(_, p)| p.clone()).collect();
    let kept = specs.iter().map(crate::trajectory::describe).collect();
    // The distributed files' rows are observations, each with an action: an episode's last one
    // is kept on its last step (the regular layout's rows are transitions, and have none).
    let last_action = d.layout != Layout::Regular;
    let options = WriterOptions {
        allow_nonfinite: opts.allow_nonfinite,
        extras: specs,
        last_action,
        image_shape: d.image_shape(),
        ..WriterOptions::new(opts.row_group_rows)
    };
    let mut writer = TrajectoryWriter::create(&opts.output, &task, float, options)?;
    // Two row groups a thread to encode, but no more than `window_bytes` of the file's rows
    // held (a whole number of row groups, at least one): image episodes are 12 MB each.
    let per_group = writer.episodes_per_group();
    let episode_bytes = (d.t() * d.row_bytes()).max(1);
    let groups = (rayon::current_num_threads().max(1) * 2).min(window_bytes / (per_group * episode_bytes)).max(1);
    let window = per_group * groups;
    bar.set_length(episodes as u64);
    let at = path.display().to_string();
    // Observations, actions, the regular layout's next observations and every passthrough
    // member, streamed side by side (one open of the archive each).
    let mut keys = vec!["observations".to_string(), "actions".to_string()];
    if d.layout == Layout::Regular {
        keys.push("next_observations".into());
    }
    let core = keys.len();
    // next_observations, kept as a passthrough column too, streams twice: once for each
    // episode's last observation, once as itself.
    keys.extend(d.extras.iter().map(|(m, _)| m.key.clone()));
    let mut run = |readers: &mut [&mut dyn Read]| -> Result<()> {
        let (core_readers, extra_readers) = readers.split_at_mut(core);
        let [obs, act, rest @ ..] = core_readers else { unreachable!("two core readers at least") };
        let mut next: Option<&mut dyn Read> = rest.first_mut().map(|n| &mut **n as &mut dyn Read);
        let mut w = Window::new(&d);
        for start in (0..episodes).step_by(window) {
            let k = window.min(episodes - start);
            w.read(*obs, *act, &mut next, extra_readers, k)
                .with_context(|| format!("{at}: episodes {start}..{}", start + k))?;
            writer.append(&w.view(&at, k), 0, k)?;
            crate::progress::advance(bar, k as u64)?;
        }
        Ok(())
    };
    npz::with_members(path, &keys, &mut Vec::new(), &mut run)?;
    let mut footer = Footer::new(&task, float, episodes, opts.command.clone());
    footer.sources = vec![SourceFile {
        path: at.clone(),
        sha256,
        format: d.layout.format_name().into(),
        episodes_in_file: d.episodes,
        episodes_taken: episodes,
        steps_dropped: 0,
        float_bytes: {
            // o, ag, g, u as the footer orders them: the goals are parts of the observations
            // (images' goals are float32 oracle representations).
            let (o, g, u) = (d.observations.dtype.size, d.goal_value_bytes(), d.actions.dtype.size);
            let table = if float == FloatType::Float32 { 4 } else { 8 };
            if o == table && g == table && u == table { Vec::new() } else { vec![o, g, g, u] }
        },
    }];
    let bytes = writer.finish(&footer)?;
    // Each range after the array it is of, named where it changes: `qpos[14:17] + [21:24]`.
    let of = |i: usize| if d.goal.from_members() { d.goal.member_of(i) } else { "observations" };
    let mut ranges = (0..d.goal.ranges.len())
        .map(|i| {
            let r = &d.goal.ranges[i];
            let name = if i == 0 || of(i) != of(i - 1) { of(i) } else { "" };
            format!("{name}[{}:{}]", r.start, r.end)
        })
        .collect::<Vec<_>>()
        .join(" + ");
    if !d.goal.affine.is_empty() {
        ranges.push_str(", centred and scaled as OGBench's oracle representation");
    }
    let mut notes = vec![format!(
        "{at}: OGBench's {} (environment {}): goal = {ranges}, success within {}{}; each transition's desired \
         goal is its episode's last (the data have no goals)",
        d.name,
        d.env,
        task.threshold,
        match d.goal.metric {
            crate::task::GoalMetric::EachObject => " for every cube",
            crate::task::GoalMetric::EachValue => " for every value",
            crate::task::GoalMetric::Scene => {
                " for every part, each over its own tolerance (cubes 0.4, buttons 0.5, drawer 0.72, window 0.6)"
            }
            _ => "",
        }
    )];
    if let Some(why) = next_kept {
        notes.push(format!(
            "{at}: next_observations are more than the observations shifted by a row ({why}): kept whole as a \
             passthrough column, which export writes back"
        ));
    }
    if last_action {
        notes.push(format!(
            "{at}: each episode's last action has no next state: kept on its last step for export, never trained on, \
             as OGBench's loader drops it"
        ));
    }
    Ok(ConvertSummary {
        task,
        float_type: float,
        episodes,
        rows: episodes * footer.t,
        bytes,
        skipped_keys: d.dropped.iter().map(|k| format!("{at}: {k}")).collect(),
        kept,
        notes,
    })
}
