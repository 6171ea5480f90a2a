//! `pgser-etl demo [DIR]`: PGSER end to end on FetchReach, from the binary alone.
//!
//! `make demo` and a user who has only the wheel (`pip install pgser-….whl && pgser-etl demo`)
//! run the same thing: `pipelines/demo.toml` (20 scripted-expert FetchReach episodes; the
//! pre-trained Q, the scored swaps, TD3+BC baseline / -swap / -mem over 3 seeds, Fig. 5, Table 1
//! and the results table), then the random policy for scale. Both the pipeline file and the
//! pickle it reads are compiled into the binary (`include_str!`, `include_bytes!`: 400 KB), so
//! there is one source of each, the clone's, and the wheel needs no data files of its own: the
//! demo writes them into DIR beside its outputs, where a user can read, edit and rerun them with
//! `pgser-etl pipeline run DIR/demo.toml`.
//!
//! The pickle is the committed one rather than the scripted expert collecting episodes anew, so
//! that the wheel's demo trains on the bytes `make demo`'s published numbers came from.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use super::{Pipeline, RunOptions, RunReport};
use crate::eval;
use crate::output::AtomicFile;

/// The demo's pipeline file as committed; `write` points its paths into the demo folder.
pub const PIPELINE: &str = include_str!("../../pipelines/demo.toml");
/// The pickle it reads: the 50 scripted-expert episodes of `data/` (the pipeline takes 20).
pub const PICKLE: &[u8] = include_bytes!("../../data/fetch_reach_expert_50.pkl");
pub const PICKLE_NAME: &str = "fetch_reach_expert_50.pkl";
/// Episodes of the random policy printed for scale, and their seed (what `make demo` printed).
const RANDOM_EPISODES: usize = 50;

/// What the results table shows and why; printed after it.
pub const EXPLAIN: &str = "\
What Table 2 shows: the data is 20 expert FetchReach episodes and nothing else. Every goal the
baseline trains on is one its own trajectory reaches, so its critic sees almost only rewards
of 0, learns nothing about which action reaches which goal, and the agent scores about 0, below
random actions. The -swap and -mem agents also train on goals swapped in from other episodes,
which these actions do not reach: that is what takes them to 47-48 of 50 (goal swapping,
Alg. 1). -mem, which draws its swapped rows by the rank of their Q, is not significantly better
than -swap here, as every swapped row is expert data; the gain from prioritizing the swaps is
about large expert + random data: pipelines/fetch_*.toml in the repository run that, and its
RESULTS.md reports it. Why this data: the comments of demo.toml.
";

/// The demo's pipeline text for a folder that holds its pickle: the committed file with its
/// data path and out folder replaced, line by line (an error if either line has moved, so a
/// change to `pipelines/demo.toml` cannot silently leave the demo reading the clone).
pub fn pipeline_text() -> Result<String> {
    let mut replaced = [false; 2];
    let lines: Vec<String> = PIPELINE
        .lines()
        .map(|l| {
            if l.starts_with("pickles = ") {
                replaced[0] = true;
                format!("pickles = [\"{PICKLE_NAME}\"]")
            } else if l.starts_with("out = ") {
                replaced[1] = true;
                "out = \".\"".to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    if replaced != [true, true] {
        bail!("pipelines/demo.toml: no `pickles = ` or `out = ` line at the start of a line, which the demo rewrites");
    }
    Ok(lines.join("\n") + "\n")
}

/// Writes `dir/demo.toml` and `dir/PICKLE_NAME` (creating `dir`), each only when absent or
/// different, so a rerun in the same folder leaves them, and the pipeline's steps, as they are.
pub fn write(dir: &Path) -> Result<PathBuf> {
    if dir.exists() && !dir.is_dir() {
        bail!("{}: not a folder (the demo writes its pipeline, data and outputs into a folder)", dir.display());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the demo folder", dir.display()))?;
    let toml = dir.join("demo.toml");
    for (path, bytes) in [(toml.clone(), pipeline_text()?.into_bytes()), (dir.join(PICKLE_NAME), PICKLE.to_vec())] {
        if std::fs::read(&path).is_ok_and(|b| b == bytes) {
            continue;
        }
        let f = AtomicFile::create(&path)?;
        std::io::Write::write_all(&mut f.handle()?, &bytes)
            .with_context(|| format!("{}: write failed", path.display()))?;
        f.commit()?;
    }
    Ok(toml)
}

/// Runs the demo in `dir`: its pipeline (a rerun repeats nothing that is up to date), then the
/// random policy on the pipeline's task for scale, as a line for the terminal.
pub fn run(dir: &Path, o: &RunOptions, log: &(dyn Fn(&str) + Sync)) -> Result<(RunReport, String)> {
    let p = Pipeline::load(&write(dir)?)?;
    let report = super::run(&p, o, log)?;
    let t = crate::env::task(&p.task)?;
    let random = eval::evaluate(&t.name, &eval::RandomPolicy::new(t.act_dim, 0), RANDOM_EPISODES, 0)?;
    Ok((report, format!("random policy: {}", random.summary(&t.name))))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_demo_pipeline_is_the_committed_one_with_its_paths_in_the_demo_folder() {
        let dir = tempfile::tempdir().unwrap();
        let toml = write(dir.path()).unwrap();
        let p = Pipeline::load(&toml).unwrap();
        let committed = Pipeline::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/demo.toml"))).unwrap();
        assert_eq!(p.name, committed.name);
        assert_eq!(p.task, committed.task);
        assert_eq!(p.out, crate::pipeline::normalize(dir.path()));
        match &p.data {
            crate::pipeline::Data::Pickles { inputs, .. } => {
                assert_eq!(inputs, &[crate::pipeline::normalize(&dir.path().join(PICKLE_NAME))])
            }
            other => panic!("the demo reads its pickle, not {other:?}"),
        }
        assert_eq!(std::fs::read(dir.path().join(PICKLE_NAME)).unwrap(), PICKLE);
        // Only the two rewritten lines differ from the committed file.
        let written = std::fs::read_to_string(&toml).unwrap();
        let differ: Vec<(&str, &str)> = PIPELINE.lines().zip(written.lines()).filter(|(a, b)| a != b).collect();
        assert_eq!(differ.len(), 2, "{differ:?}");
        // A second write changes nothing (same modification time).
        let before = std::fs::metadata(&toml).unwrap().modified().unwrap();
        write(dir.path()).unwrap();
        assert_eq!(std::fs::metadata(&toml).unwrap().modified().unwrap(), before);
    }

    #[test]
    fn a_demo_folder_that_is_a_file_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("taken");
        std::fs::write(&f, b"x").unwrap();
        let e = write(&f).unwrap_err().to_string();
        assert!(e.contains("taken") && e.contains("not a folder"), "{e}");
    }
}
