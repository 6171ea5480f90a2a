//! Progress bars for long jobs. indicatif draws nothing when stderr is not a terminal, so
//! logs and CI output stay clean without a flag.

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
