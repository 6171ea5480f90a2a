//! Progress bars for long jobs. indicatif draws nothing when stderr is not a terminal, so
//! logs and CI output stay clean without a flag; there, jobs of hours (a grid of agents, a
//! Slurm job's log) write a line at each milestone instead (`milestone`), so a log is never
//! silent for hours.

use indicatif::{ProgressBar, ProgressStyle};

/// A bar counting `unit`s (rows, steps, updates).
pub fn bar(message: &'static str, unit: &str) -> ProgressBar {
    let bar = ProgressBar::new(0);
    let template = format!(
        "{{msg}} [{{elapsed_precise}}] {{wide_bar}} {{human_pos}}/{{human_len}} {unit} ({{per_sec}}, eta {{eta}})"
    );
    bar.set_style(ProgressStyle::with_template(&template).expect("valid template"));
    bar.set_message(message);
    bar
}

/// A job stopped because its caller finished the bar (`advance`).
#[derive(Debug, thiserror::Error)]
#[error("interrupted")]
pub struct Cancelled;

/// Counts `n` more units done, and says whether to go on. A caller that finishes the bar while
/// the job runs (the Python module does on Ctrl-C, from the thread that waits for the job)
/// cancels it here: the job returns [`Cancelled`] at its next step, and its atomic output leaves
/// no file, as on any other error. The CLI's bars are finished only after the job returns.
pub fn advance(bar: &ProgressBar, n: u64) -> anyhow::Result<()> {
    bar.inc(n);
    if bar.is_finished() {
        return Err(Cancelled.into());
    }
    Ok(())
}

/// For logs: when the bar draws nothing (stderr is not a terminal), one line, prefixed with the
/// bar's message, at a milestone of a long job (a training run's scheduled checkpoint). On a
/// terminal the bar already shows it.
pub fn milestone(bar: &ProgressBar, line: &str) {
    if bar.is_hidden() {
        eprintln!("{}: {line}", bar.message());
    }
}

/// A line a user should see whether or not the bar draws (what a run holds, once at its start):
/// above the bar on a terminal, one log line otherwise.
pub fn note(bar: &ProgressBar, line: &str) {
    if bar.is_hidden() {
        eprintln!("{}: {line}", bar.message());
    } else {
        bar.println(line);
    }
}

/// A count in a few characters: "950", "7.5k", "31.0M".
pub fn count(n: u64) -> String {
    match n {
        0..1_000 => n.to_string(),
        1_000..1_000_000 => format!("{:.1}k", n as f64 / 1e3),
        _ => format!("{:.1}M", n as f64 / 1e6),
    }
}

/// Seconds as a person reads them: "38 s", "6.6 min", "3.0 h", "5.1 days".
pub fn duration(s: f64) -> String {
    match s {
        s if s < 90.0 => format!("{s:.0} s"),
        s if s < 5400.0 => format!("{:.1} min", s / 60.0),
        s if s < 172_800.0 => format!("{:.1} h", s / 3600.0),
        s => format!("{:.1} days", s / 86400.0),
    }
}

/// "; last evaluation (10.0k): paper score 20.12 (15.98–25.04)" from each agent's (update, score)
/// of its latest evaluation, or "success 42.0 % (…)" on a task scored by success; "" with none.
pub fn last_evaluation(last: &[(u64, f64)], by_success: bool) -> String {
    let Some(at) = last.iter().map(|&(u, _)| u).max() else { return String::new() };
    let scores: Vec<f64> = last.iter().map(|&(_, p)| p).collect();
    let mean = scores.iter().sum::<f64>() / scores.len() as f64;
    let (name, unit, digits) = if by_success { ("success", " %", 1) } else { ("paper score", "", 2) };
    let mut s = format!("; last evaluation ({}): {name} {mean:.digits$}{unit}", count(at));
    if scores.len() > 1 {
        let (lo, hi) = scores.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        s += &format!(" ({lo:.digits$}–{hi:.digits$}{unit})");
    }
    s
}

/// Bytes for people: "512 B", "3.2 MB", "1.50 GB" (powers of 1000, as `--memory-budget` takes them).
pub fn bytes(n: u64) -> String {
    let x = n as f64;
    match n {
        0..1_000 => format!("{n} B"),
        1_000..1_000_000 => format!("{:.1} kB", x / 1e3),
        1_000_000..1_000_000_000 => format!("{:.1} MB", x / 1e6),
        _ => format!("{:.2} GB", x / 1e9),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_durations_read_naturally() {
        assert_eq!(duration(38.0), "38 s");
        assert_eq!(duration(396.0), "6.6 min");
        assert_eq!(duration(3.0 * 3600.0), "3.0 h");
        assert_eq!(duration(5.1 * 86400.0), "5.1 days");
        assert_eq!((count(950), count(7_500), count(31_000_000)), ("950".into(), "7.5k".into(), "31.0M".into()));
    }

    #[test]
    fn the_progress_line_shows_the_score_the_task_is_judged_by() {
        let last = [(10_000, 20.0), (10_000, 24.0), (7_500, 16.0)];
        assert_eq!(last_evaluation(&last, false), "; last evaluation (10.0k): paper score 20.00 (16.00–24.00)");
        // OGBench's mazes: success in percent (T + return would be 150–550 there, and mean nothing).
        let last = [(20_000, 40.0), (20_000, 60.0)];
        assert_eq!(last_evaluation(&last, true), "; last evaluation (20.0k): success 50.0 % (40.0–60.0 %)");
        assert_eq!(last_evaluation(&[(500, 12.5)], true), "; last evaluation (500): success 12.5 %");
        assert_eq!(last_evaluation(&[], false), "");
    }
}
