//! The GPU backend against the CPU one: the same commands with `--device wgpu` and `--device
//! cpu` must give the same networks and the same Q-scores up to float round-off. Built only with
//! `--features wgpu` (Cargo.toml: `required-features`), so `make test`, whose build has no wgpu,
//! does not run it; `make test-wgpu` does, on whatever adapter wgpu finds: a GPU, or Mesa's
//! software Vulkan driver (lavapipe), which the target installs where it can. Why it is not part
//! of `make test`: a release build with wgpu takes 16+ minutes more on 2 cores (BENCHMARKS.md).
//!
//! Tolerance: the two backends sum in different orders (tiled GPU kernels vs gemm), so bits
//! differ; measured on lavapipe after 20 updates at hidden 32, batch 32: 2.8e-7 absolute /
//! 1.6e-6 relative at most. The bound below is 10-30× that, far below any change a bug in a
//! kernel, a layout or an optimizer step would make (those move weights by 1e-3 and more).
mod common;

use common::*;
use std::path::Path;
use std::process::{Command, Output};

const TOLERANCE: f32 = 1e-5;

fn train(args: &[&str], device: &str) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(args)
        .args(["--device", device])
        .env("XDG_RUNTIME_DIR", runtime_dir())
        .output()
        .unwrap();
    assert!(out.status.success(), "pgser-train {args:?} --device {device} failed:\n{}", text(&out.stderr));
    out
}

/// Vulkan loaders warn (and some drivers fail) without a runtime directory; CI shells have none.
fn runtime_dir() -> String {
    std::env::var("XDG_RUNTIME_DIR").unwrap_or_else(|_| std::env::temp_dir().display().to_string())
}

/// Every value of `a` within TOLERANCE of `b`, scaled by |b| above 1; the worst pair is reported.
fn assert_close(what: &str, a: &[f32], b: &[f32]) {
    assert_eq!(a.len(), b.len(), "{what}: lengths differ");
    let (worst, i) = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() / y.abs().max(1.0))
        .zip(0..)
        .fold((0.0f32, 0), |m, (d, i)| if d > m.0 { (d, i) } else { m });
    assert!(worst <= TOLERANCE, "{what}: value {i} is {} on wgpu, {} on cpu", a[i], b[i]);
    assert!(a.iter().all(|x| x.is_finite()), "{what}: not finite on wgpu");
}

#[test]
fn stacked_agents_on_wgpu_end_with_the_weights_they_have_on_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let (_, scored) = reach_tables(dir.path());
    // A stack of three (the batched matmuls of a grid) of -mem agents: the original data and the
    // prioritized swaps of a scored table.
    let runs = |device: &str| {
        let out = dir.path().join(device);
        let args = [
            "--data",
            scored.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--seeds",
            "0,1,2",
            "--updates",
            "20",
            "--batch-size",
            "32",
            "--hidden",
            "32",
            "--eval-episodes",
            "0",
        ];
        (train(&args, device), out)
    };
    let (gpu, on_gpu) = runs("wgpu");
    let (_, on_cpu) = runs("cpu");
    // The adapter is named, so a run meant for a GPU cannot land on a software one unnoticed.
    assert!(text(&gpu.stderr).contains("--device wgpu: running on "), "{}", text(&gpu.stderr));
    for seed in 0..3 {
        let ckpt = |d: &Path| d.join(format!("s{seed}.ckpt"));
        let (a, b) = (checkpoint_weights(&ckpt(&on_gpu)), checkpoint_weights(&ckpt(&on_cpu)));
        assert_eq!(a.len(), b.len());
        for (k, (a, b)) in a.iter().zip(&b).enumerate() {
            assert_close(&format!("seed {seed}, tensor {k}"), a, b);
        }
    }
    // Evaluation runs the actor without autodiff, all episodes' observations in one forward pass.
    // FetchReach's dynamics are smooth (no contacts), so actions 1e-7 apart give the same
    // successes and the same returns (sums of 0 / -1 rewards).
    let eval = |device: &str| {
        let ckpt = on_gpu.join("s1.ckpt");
        let out = train(&["eval", "--ckpt", ckpt.to_str().unwrap(), "--episodes", "10", "--json"], device);
        let summary = last_json(&text(&out.stdout));
        (summary["return_mean"].as_f64().unwrap(), summary["success_rate"].as_f64().unwrap())
    };
    assert_eq!(eval("wgpu"), eval("cpu"));
}

#[test]
fn scores_on_wgpu_match_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let (table, _) = reach_tables(dir.path());
    let ckpt = dir.path().join("reach.ckpt");
    let score = |device: &str| {
        let out = dir.path().join(format!("scored_{device}.parquet"));
        let o = etl()
            .args(["score", "--q", ckpt.to_str().unwrap(), "--data", table.to_str().unwrap(), "-o"])
            .arg(&out)
            .args(["--swaps", "2", "--device", device])
            .env("XDG_RUNTIME_DIR", runtime_dir())
            .output()
            .unwrap();
        assert!(o.status.success(), "score --device {device} failed: {}", text(&o.stderr));
        read_table(&out).0
    };
    let (gpu, cpu) = (score("wgpu"), score("cpu"));
    // Same columns (the footers differ in their command line and Q statistics).
    assert_eq!(gpu.schema().fields(), cpu.schema().fields());
    for (field, (a, b)) in cpu.schema().fields().iter().zip(gpu.columns().iter().zip(cpu.columns())) {
        if field.name() == "q" {
            let f = |c: &arrow_array::ArrayRef| {
                c.as_any().downcast_ref::<arrow_array::Float32Array>().unwrap().values().to_vec()
            };
            assert_close("q", &f(a), &f(b));
        } else {
            // Which swaps are drawn and everything copied from the table is the CPU's work.
            assert_eq!(a, b, "column {}", field.name());
        }
    }
}
