//! `pgser-etl` and `pgser-train` in one executable, for the wheel: it is pgser-train when called
//! under that name (the wheel's `pgser-train` command executes it with argv[0] = `pgser-train`),
//! and pgser-etl otherwise, so that a pipeline's Slurm jobs, which run `current_exe()`, get
//! pgser-etl. The two binaries' sources are included as they are: nothing here but the choice.

#[path = "../src/bin/pgser-etl/main.rs"]
mod etl;
#[path = "../src/bin/pgser-train.rs"]
mod train;

use std::process::ExitCode;

fn main() -> ExitCode {
    let called = std::env::args_os().next().unwrap_or_default();
    let name = std::path::Path::new(&called).file_name().and_then(|n| n.to_str()).unwrap_or_default();
    if name.starts_with("pgser-train") { train::main() } else { etl::main() }
}
