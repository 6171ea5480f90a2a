//! `pgser-etl table2` (the paper's Table 2 across tasks) and `fig5`'s Table 1 beside the paper's:
//! the layout and tests on hand-made results, the committed reference's 36 values and marks
//! beside the committed grids, a reference that lacks a value (marked) or holds a bad one
//! (refused), and the spread of evaluation episodes pooled over seeds, recomputed from hand-made
//! per-episode and per-run scores with known answers.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use pgser::report;

/// A results.csv as a pipeline wrote it before it kept the episodes' spread, for the given
/// (algo, variant, seeds, mean, std) rows.
fn results_csv(path: &Path, task: &str, rows: &[(&str, &str, usize, f64, f64)]) -> PathBuf {
    let mut s = String::from(
        "task,algo,variant,seeds,paper_score_mean,paper_score_std,success_mean,p_vs_baseline,p_vs_swap,\
         p_one_sided_vs_baseline,p_one_sided_vs_swap\n",
    );
    for (algo, variant, n, m, sd) in rows {
        s += &format!("{task},{algo},{variant},{n},{m},{sd},0.5,,,,\n");
    }
    std::fs::write(path, s).unwrap();
    path.to_path_buf()
}

/// The six agents of one task: mem > swap > baseline for TD3+BC (clearly), swap > mem for TD3.
fn six(shift: f64) -> Vec<(&'static str, &'static str, usize, f64, f64)> {
    vec![
        ("td3bc", "baseline", 5, 10.0 + shift, 1.0),
        ("td3bc", "swap", 5, 20.0 + shift, 1.0),
        ("td3bc", "mem", 5, 30.0 + shift, 1.0),
        ("td3", "baseline", 5, 10.0 + shift, 2.0),
        ("td3", "swap", 5, 25.0 + shift, 2.0),
        ("td3", "mem", 5, 24.0 + shift, 2.0),
    ]
}

fn table2(inputs: &[&Path], out: &Path, extra: &[&str]) -> std::process::Output {
    etl().arg("table2").args(inputs).arg("-o").arg(out).args(extra).output().unwrap()
}

/// The cells of a markdown row that starts with `| {row} |`.
fn cells(md: &str, row: &str) -> Vec<String> {
    let l = md.lines().find(|l| l.starts_with(&format!("| {row} |"))).unwrap_or_else(|| panic!("no row {row}: {md}"));
    l.trim_matches('|').split('|').skip(1).map(|c| c.trim().to_string()).collect()
}

/// A one-line refusal that names what `want` lists and writes nothing.
fn refused(o: &std::process::Output, out: &Path, want: &[&str]) {
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    for w in want {
        assert!(err.contains(w), "{err} should contain {w}");
    }
    assert!(!out.exists(), "nothing may be written: {err}");
}

#[test]
fn table2_assembles_the_papers_layout_with_its_values_and_tests() {
    let dir = tempfile::tempdir().unwrap();
    let push = results_csv(&dir.path().join("push.csv"), "FetchPush", &six(0.0));
    let reach = results_csv(&dir.path().join("reach.csv"), "FetchReach-v4", &six(10.0));
    let reference = dir.path().join("paper.csv");
    let mut r = String::from("# a hand-made reference\ntask,agent,mean,std\n");
    for (t, short) in [("FetchPush", 1.0), ("FetchPick", 2.0)] {
        for (i, a) in ["TD3BC-mem", "TD3BC-swap", "TD3BC", "TD3-mem", "TD3-swap", "TD3"].iter().enumerate() {
            r += &format!("{t},{a},{},{}\n", short * 10.0 + i as f64, 0.5);
        }
    }
    std::fs::write(&reference, r).unwrap();
    let out = dir.path().join("t2");
    let o = table2(&[&push, &reach], &out, &["--reference", reference.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = std::fs::read_to_string(out.join("table2.md")).unwrap();
    assert_eq!(md, text(&o.stdout));

    // Layout: the paper's six columns; per agent, in the paper's order, ours over seeds, ours over
    // pooled episodes, the paper's.
    let names: Vec<&str> = md
        .lines()
        .filter(|l| l.starts_with("| TD3"))
        .map(|l| l.split(" | ").next().unwrap().trim_start_matches("| "))
        .collect();
    let mut want = Vec::new();
    for a in ["TD3BC-mem", "TD3BC-swap", "TD3BC", "TD3-mem", "TD3-swap", "TD3"] {
        for kind in ["pgser", "pgser, episodes", "paper"] {
            want.push(format!("{a} ({kind})"));
        }
    }
    assert_eq!(names, want);
    assert!(md.contains("| agent | FetchReach | FetchPush | FetchPick | FetchSlide | HandBlock-Z | HandEgg-Rotate |"));
    // TD3BC-mem: 40 and 30 ± 1 over 5 seeds, far above baseline and swap: both marks up; swap
    // rows are marked against the baseline, as the paper's pink box.
    assert_eq!(
        cells(&md, "TD3BC-mem (pgser)"),
        ["40.00 ± 1.00 ▲b ▲s", "30.00 ± 1.00 ▲b ▲s", "not run", "not run", "not run", "not run"]
    );
    assert_eq!(cells(&md, "TD3BC-swap (pgser)")[1], "20.00 ± 1.00 ▲b");
    // TD3-mem is 1 below swap with std 2 over 5 seeds: not significant against swap.
    assert_eq!(cells(&md, "TD3-mem (pgser)")[1], "24.00 ± 2.00 ▲b");
    assert_eq!(cells(&md, "TD3 (pgser)")[1], "10.00 ± 2.00");
    // Results written before pgser kept the episodes' spread: pooled "n/a", never estimated.
    assert_eq!(cells(&md, "TD3-mem (pgser, episodes)")[..3], ["n/a", "n/a", "not run"]);
    // The paper's values where the reference has them, a dash where it does not, and the count.
    assert_eq!(cells(&md, "TD3BC-mem (paper)"), ["—", "10.00 ± 0.50", "20.00 ± 0.50", "—", "—", "—"]);
    assert_eq!(cells(&md, "TD3 (paper)")[1], "15.00 ± 0.50");
    assert!(md.contains("**The reference lacks 24 of the paper's 36 cells** (FetchReach TD3BC-mem,"), "{md}");

    // One line per measured task on the ordering, with the p of each comparison.
    let p = |a: (f64, f64), b: (f64, f64)| report::welch_from_summary((a.0, a.1, 5), (b.0, b.1, 5)).unwrap().2;
    let push_line = md.lines().find(|l| l.starts_with("- **FetchPush**")).unwrap();
    assert!(push_line.contains("TD3BC: mem ≥ swap ≥ baseline holds (30.00 / 20.00 / 10.00)"), "{push_line}");
    assert!(push_line.contains("in the paper it does not hold (10 / 11 / 12): differ"), "{push_line}");
    assert!(push_line.contains("TD3: mem ≥ swap ≥ baseline does not hold (24.00 / 25.00 / 10.00)"), "{push_line}");
    assert!(push_line.contains(&format!("mem vs swap not significant (p = {:.3})", p((24.0, 2.0), (25.0, 2.0)))));
    // A 4-column reference has no marks: no verdict on significance.
    assert!(push_line.contains("the paper: —") && !push_line.contains("agree;"), "{push_line}");
    let reach_line = md.lines().find(|l| l.starts_with("- **FetchReach**")).unwrap();
    assert!(reach_line.contains("the paper's values: —"), "{reach_line}");
    assert!(!md.contains("- **FetchSlide**"), "no ordering line for a task not run");

    // The CSV: all 36 cells, measured or not, with the p values recomputed from the summaries.
    let csv = std::fs::read_to_string(out.join("table2.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 37);
    assert!(lines[0].starts_with("task,agent,seeds,mean,std,marks,episodes,std_episodes,marks_episodes,p_vs_baseline"));
    let mem = lines.iter().find(|l| l.starts_with("FetchPush,TD3BC-mem,")).unwrap();
    let f: Vec<&str> = mem.split(',').collect();
    assert_eq!(&f[..9], ["FetchPush", "TD3BC-mem", "5", "30", "1", "▲b ▲s", "", "", ""]);
    assert_eq!(f[9].parse::<f64>().unwrap(), p((30.0, 1.0), (10.0, 1.0)));
    assert_eq!(&f[13..16], ["10", "0.5", ""]);
    assert!(f[16].ends_with("push.csv:4"), "{}", f[16]);
    assert!(lines.contains(&"FetchSlide,TD3,0,,,,,,,,,,,,,,not run"), "{csv}");
}

/// Welch's test against scipy's, not against itself: t, degrees of freedom and two-sided p of
/// `scipy.stats.ttest_ind(a, b, equal_var=False)`, and the one-sided p with
/// `alternative="greater"`, computed once with scipy 1.17.1 and written here:
///
/// ```text
/// .venv/bin/python -c 'from scipy import stats; r = stats.ttest_ind(A, B, equal_var=False); \
///     g = stats.ttest_ind(A, B, equal_var=False, alternative="greater"); \
///     print(repr(r.statistic), repr(r.df), repr(r.pvalue), repr(g.pvalue))'
/// ```
///
/// Clearly apart, overlapping, unequal sizes and spreads, and a p of 1e-18 (where 1 − cdf would
/// have lost it); the summaries' test (what table2 runs on results.csv) gives the same.
#[test]
fn welch_p_values_match_scipys() {
    #[rustfmt::skip]
    let cases: [(&[f64], &[f64], [f64; 4]); 4] = [
        (&[30.1, 28.4, 31.7, 29.9, 30.6], &[15.2, 14.1, 17.9, 16.0, 13.8],
         [16.16367997284499, 7.29560336546222, 5.595910415550308e-07, 2.797955207775154e-07]),
        (&[24.0, 26.1, 22.3, 25.4, 23.9], &[25.2, 27.0, 24.1, 26.5, 23.8],
         [-1.0718226661865242, 7.987402939755961, 0.315113280939038, 0.842443359530481]),
        (&[1.0, 2.5, 0.3, 4.2, 3.3, 2.2, 1.9], &[2.1, 2.0, 2.4],
         [0.06499616998140073, 6.650210176897376, 0.9500874378674383, 0.47504371893371916]),
        (&[100.0, 100.1, 99.9, 100.05], &[0.0, 0.1, -0.1, 0.05],
         [1656.1573424216972, 6.0, 3.2710841220606258e-18, 1.6355420610303129e-18]),
    ];
    let close = |got: f64, want: f64, what: &str| {
        assert!((got - want).abs() <= 1e-10 * want.abs(), "{what}: {got:e}, scipy {want:e}");
    };
    for (a, b, [t, df, p, greater]) in cases {
        let (got_t, got_df, got_p) = report::welch_t_test(a, b).unwrap();
        close(got_t, t, "t");
        close(got_df, df, "df");
        close(got_p, p, "p");
        close(report::welch_greater(a, b).unwrap(), greater, "one-sided p");
        let side = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
            (m, s, v.len())
        };
        close(report::welch_from_summary(side(a), side(b)).unwrap().2, p, "p from the summaries");
    }
}

/// A chosen-setting pipeline's results.csv (the arm beside its own baseline and swap, and another
/// arm to leave out) and the table1.json of its report with the shares of both settings.
fn chosen_files(dir: &Path, name: &str, task: &str, algo: &str, means: [f64; 4]) -> PathBuf {
    std::fs::create_dir_all(dir.join(name)).unwrap();
    let rows = [
        (algo, "baseline", 5, means[0], 1.0),
        (algo, "swap", 5, means[1], 1.0),
        (algo, "mem_q3", 5, means[2], 1.0),
        (algo, "mem_rank", 5, means[3], 1.0),
    ];
    let results = results_csv(&dir.join(name).join("results.csv"), task, &rows);
    let shares = r#"{"task": "X", "priority": {"threshold": -2.0, "rows": 1000, "above": 27, "uniform": 0.027,
        "settings": [{"priority": "q", "priority_alpha": 3.0, "priority_eps": 0.01, "share_above": 0.133},
                     {"priority": "rank", "priority_alpha": 1.0, "priority_eps": 0.01, "share_above": 0.736}]}}"#;
    std::fs::write(dir.join(name).join("table1.json"), shares).unwrap();
    results
}

/// `--chosen`: the arm's rows per task and learner, marked against the baseline and swap of its
/// own file (not the grid's), with its share and the grids' α = 1 cell and the paper's beside it,
/// and the counts for both settings; the other arm is left out; table2_chosen.csv holds the cells.
#[test]
fn table2_gives_the_chosen_settings_rows_against_their_own_baseline_and_swap() {
    let dir = tempfile::tempdir().unwrap();
    let grid = results_csv(&dir.path().join("grid.csv"), "FetchPush", &six(0.0));
    // TD3+BC: rank far above its swap and baseline; TD3: rank 1 below its swap (not significant).
    let bc = chosen_files(dir.path(), "push_bc", "FetchPush", "td3bc", [7.0, 15.0, 23.0, 27.0]);
    let td3 = chosen_files(dir.path(), "push_td3", "FetchPush", "td3", [20.0, 33.0, 30.0, 32.0]);
    let out = dir.path().join("t2");
    let o = table2(&[&grid], &out, &["--chosen", bc.to_str().unwrap(), td3.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = std::fs::read_to_string(out.join("table2.md")).unwrap();
    assert!(md.contains("## -mem with the chosen priority, rank α = 1"), "{md}");
    assert_eq!(
        cells(&md, "TD3BC-mem, rank α = 1 (pgser)"),
        ["not run", "27.00 ± 1.00 ▲b ▲s", "not run", "not run", "not run", "not run"]
    );
    assert_eq!(cells(&md, "TD3BC-swap beside it (pgser)")[1], "15.00 ± 1.00");
    assert_eq!(cells(&md, "TD3BC beside it (pgser)")[1], "7.00 ± 1.00");
    assert_eq!(cells(&md, "TD3-mem, rank α = 1 (pgser)")[1], "32.00 ± 1.00 ▲b");
    assert_eq!(cells(&md, "TD3BC-mem, rank α = 1: share above the own-goal median (uniform)")[1], "0.736 (0.027)");
    // The grid's own -mem (q α = 1) and the paper's, unchanged beside it.
    assert_eq!(cells(&md, "TD3BC-mem, q α = 1 (pgser, the grids)")[1], "30.00 ± 1.00 ▲b ▲s");
    assert_eq!(cells(&md, "TD3BC-mem (paper)")[1], "29.85 ± 11.57 ▲b ▲s");
    // Counts over the one task measured with each: the chosen setting's mem above swap once.
    assert!(md.contains("| rank α = 1 | 2 | 1 (2) | "), "{md}");
    assert!(md.contains("| q α = 1 (the grids) | 2 | 1 (2) | "), "{md}");
    // The other arm (mem_q3, 23 and 30) is in no row.
    assert!(!md.contains("23.00"), "{md}");
    let csv = std::fs::read_to_string(out.join("table2_chosen.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 3, "{csv}");
    let f: Vec<&str> = lines[1].split(',').collect();
    assert_eq!(&f[..7], ["FetchPush", "TD3BC", "rank α = 1", "5", "27", "1", "▲b ▲s"]);
    let p = report::welch_from_summary((27.0, 1.0, 5), (15.0, 1.0, 5)).unwrap().2;
    assert_eq!(f[8].parse::<f64>().unwrap(), p);
    // Against the grid's -mem of the same pair (30 ± 1): significantly below, so not "as well".
    assert_eq!(f[13].parse::<f64>().unwrap(), report::welch_from_summary((27.0, 1.0, 5), (30.0, 1.0, 5)).unwrap().2);
    assert_eq!(&f[14..17], ["no", "0.736", "0.027"]);
    assert!(f[17].ends_with("results.csv:5"), "{}", f[17]);
    assert!(md.contains("**rank α = 1 at least as well as q α = 1** (its `-mem` not significantly below the grid's `-mem` of the same pair, Welch over seeds; the grids ran on an older build): 1 of 2 pairs; below it: FetchPush TD3BC (p = "), "{md}");

    // Another setting by name: q α = 3 is the arm mem_q3 here, with its own share.
    let out2 = dir.path().join("t2q");
    let o = table2(
        &[&grid],
        &out2,
        &["--chosen", bc.to_str().unwrap(), "--chosen-arm", "mem_q3", "--chosen-setting", "q:3"],
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = std::fs::read_to_string(out2.join("table2.md")).unwrap();
    assert_eq!(cells(&md, "TD3BC-mem, q α = 3 (pgser)")[1], "23.00 ± 1.00 ▲b ▲s");
    assert_eq!(cells(&md, "TD3BC-mem, q α = 3: share above the own-goal median (uniform)")[1], "0.133 (0.027)");
    assert_eq!(cells(&md, "TD3-mem, q α = 3 (pgser)")[1], "not run");
}

/// A pair whose p against the grid's `-mem` cannot be computed (the arm over one seed; both sides
/// without spread) is neither "as well" nor "below": the count says how many are unknown and
/// which, and the CSV says "unknown", where a pair with no grid cell stays empty.
#[test]
fn table2_counts_a_chosen_pair_without_a_p_against_the_grid_as_unknown() {
    let dir = tempfile::tempdir().unwrap();
    // The grid's TD3-mem without spread (std 0 over its 5 seeds).
    let mut rows = six(0.0);
    rows[5].4 = 0.0;
    let grid = results_csv(&dir.path().join("grid.csv"), "FetchPush", &rows);
    let arm = |name: &str, algo: &'static str, seeds: usize, mean: f64, std: f64| {
        std::fs::create_dir_all(dir.path().join(name)).unwrap();
        let rows =
            [(algo, "baseline", 5, 10.0, 1.0), (algo, "swap", 5, 15.0, 1.0), (algo, "mem_rank", seeds, mean, std)];
        results_csv(&dir.path().join(name).join("results.csv"), "FetchPush", &rows)
    };
    // TD3+BC: the arm over one seed (well below the grid's 30, but no test can say so); TD3: the
    // arm without spread either (20 against the grid's 24).
    let (bc, td3) = (arm("bc", "td3bc", 1, 20.0, 1.0), arm("td3", "td3", 5, 20.0, 0.0));
    let out = dir.path().join("t2");
    let o = table2(&[&grid], &out, &["--chosen", bc.to_str().unwrap(), td3.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = std::fs::read_to_string(out.join("table2.md")).unwrap();
    assert!(
        md.contains(
            "the grids ran on an older build): 0 of 2 pairs (2 unknown: FetchPush TD3BC (the arm over one seed), \
             FetchPush TD3 (no spread on either side))."
        ),
        "{md}"
    );
    let csv = std::fs::read_to_string(out.join("table2_chosen.csv")).unwrap();
    let verdicts: Vec<(&str, &str, &str)> = csv
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[1], f[13], f[14])
        })
        .collect();
    assert_eq!(verdicts, [("TD3BC", "", "unknown"), ("TD3", "", "unknown")], "{csv}");

    // One pair known and below, one unknown: both said.
    let td3 = arm("td3_spread", "td3", 5, 20.0, 1.0);
    std::fs::remove_dir_all(&out).unwrap();
    let o = table2(&[&grid], &out, &["--chosen", bc.to_str().unwrap(), td3.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = std::fs::read_to_string(out.join("table2.md")).unwrap();
    assert!(
        md.contains("0 of 2 pairs (1 unknown: FetchPush TD3BC (the arm over one seed)); below it: FetchPush TD3 (p = "),
        "{md}"
    );
    let j = {
        let o = table2(
            &[&grid],
            &dir.path().join("t2j"),
            &["--json", "--chosen", bc.to_str().unwrap(), td3.to_str().unwrap()],
        );
        assert!(o.status.success(), "{}", text(&o.stderr));
        last_json(&text(&o.stdout))
    };
    let verdicts: Vec<&str> =
        j["chosen"]["cells"].as_array().unwrap().iter().map(|c| c["as_well_as_grid"].as_str().unwrap()).collect();
    assert_eq!(verdicts, ["unknown", "no"], "{j}");
}

/// The committed FetchPush runs of the chosen setting (issue 57 step 1) beside the committed
/// grid: RESULTS.md's numbers, the share its report measured, and its marks against its own
/// baseline and swap.
#[test]
fn table2_gives_the_committed_fetch_push_rank_runs_beside_the_grid() {
    let dir = tempfile::tempdir().unwrap();
    let r = |name: &str| repo().join("results").join(name).join("results.csv");
    let grid = r("fetch_push_grid_cpu");
    let (bc, td3) = (r("fetch_push_priority_td3bc_cpu"), r("fetch_push_priority_td3_cpu"));
    let o = table2(&[&grid], dir.path(), &["--chosen", bc.to_str().unwrap(), td3.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = text(&o.stdout);
    assert_eq!(cells(&md, "TD3BC-mem, rank α = 1 (pgser)")[1], "27.10 ± 1.81 ▲b ▲s");
    assert_eq!(cells(&md, "TD3BC-swap beside it (pgser)")[1], "15.70 ± 2.92");
    assert_eq!(cells(&md, "TD3-mem, rank α = 1 (pgser)")[1], "28.66 ± 1.91 ▲b ▼s");
    assert_eq!(cells(&md, "TD3-mem, rank α = 1: share above the own-goal median (uniform)")[1], "0.736 (0.027)");
    assert_eq!(cells(&md, "TD3BC-mem, q α = 1 (pgser, the grids)")[1], "16.04 ± 1.62 ▲b");
    assert!(md.contains("| rank α = 1 | 2 | 1 (2) | 2 of 2 | 5 of 6 | 1 of 2 |"), "{md}");
    assert!(md.contains("| q α = 1 (the grids), the same pairs | 2 | 0 (2) | 2 of 2 | 4 of 6 | 2 of 2 |"), "{md}");
    // TD3: 28.66 ± 1.91 against the grid's 32.04 ± 0.82, below it; TD3+BC far above.
    assert!(md.contains("1 of 2 pairs; below it: FetchPush TD3 (p = "), "{md}");
}

/// A chosen file without the swap beside its arm, a (task, learner) given twice, an arm no file
/// has, a setting that is not one: one line naming the file and the fault, and nothing written.
#[test]
fn table2_refuses_a_chosen_file_it_cannot_read_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let grid = results_csv(&dir.path().join("grid.csv"), "FetchPush", &six(0.0));
    let bc = chosen_files(dir.path(), "bc", "FetchPush", "td3bc", [7.0, 15.0, 23.0, 27.0]);
    let again = chosen_files(dir.path(), "again", "FetchPush", "td3bc", [7.0, 15.0, 23.0, 27.0]);
    let no_swap = dir.path().join("no_swap.csv");
    results_csv(&no_swap, "FetchPush", &[("td3", "baseline", 5, 1.0, 1.0), ("td3", "mem_rank", 5, 2.0, 1.0)]);
    let out = dir.path().join("t2");
    let run = |extra: &[&str]| {
        let mut args = vec!["--chosen"];
        args.extend_from_slice(extra);
        table2(&[&grid], &out, &args)
    };
    refused(&run(&[no_swap.to_str().unwrap()]), &out, &["no_swap.csv", "FetchPush td3 has no swap"]);
    refused(
        &run(&[bc.to_str().unwrap(), again.to_str().unwrap()]),
        &out,
        &["again/results.csv", "FetchPush td3bc is also in"],
    );
    refused(&run(&[bc.to_str().unwrap(), "--chosen-arm", "mem_x"]), &out, &["has no arm mem_x"]);
    refused(&run(&[bc.to_str().unwrap(), "--chosen-setting", "rank:x"]), &out, &["\"rank:x\"", "not a number"]);
}

#[test]
fn table2_refuses_duplicates_unknown_tasks_and_missing_learners_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t2");
    let check = |inputs: &[&Path], want: &[&str]| refused(&table2(inputs, &out, &[]), &out, want);
    let a = results_csv(&dir.path().join("a.csv"), "FetchPush", &six(0.0));
    let b = results_csv(&dir.path().join("b.csv"), "FetchPush", &six(0.0)[2..3]);
    // The same cell in two files: both named, with their lines.
    check(&[&a, &b], &["b.csv:2", "FetchPush TD3BC-mem", "a.csv:4"]);
    // The same cell twice in one file.
    let mut rows = six(0.0);
    rows.push(("td3", "swap", 3, 1.0, 1.0));
    let twice = results_csv(&dir.path().join("twice.csv"), "FetchSlide", &rows);
    check(&[&twice], &["twice.csv:8", "FetchSlide TD3-swap", "twice.csv:6"]);
    // A task the paper does not have.
    let other = results_csv(&dir.path().join("other.csv"), "PointReach", &six(0.0));
    check(&[&other], &["other.csv:2", "PointReach", "not in the paper's Table 2"]);
    // A learner missing: TD3+BC only (as the exploratory hand run).
    let half = results_csv(&dir.path().join("half.csv"), "HandManipulateBlockRotateZ", &six(0.0)[..3]);
    check(&[&half], &["half.csv", "HandManipulateBlockRotateZ has no TD3-mem, TD3-swap, TD3"]);
    // Not a results.csv.
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "a,b\n1,2\n").unwrap();
    check(&[&bad], &["bad.csv", "no column task"]);
}

/// The committed reference beside every committed grid: each of the paper's 36 cells prints its
/// value and marks as in the reference file, a few checked against the paper by hand here too,
/// and every task has its lines on ordering and significance against the paper.
#[test]
fn table2_prints_the_papers_36_values_and_marks_beside_the_committed_grids() {
    let reference = std::fs::read_to_string(repo().join("assets/paper_table2.csv")).unwrap();
    assert!(reference.contains("arXiv:2302.07741"), "the reference names its source");
    let rows: Vec<Vec<&str>> = reference
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 36, "the paper's Table 2 has 36 cells");

    let dir = tempfile::tempdir().unwrap();
    let grids = [
        "fetch_reach_grid_cpu",
        "fetch_push_grid_cpu",
        "fetch_pick_and_place_grid_cpu",
        "fetch_slide_grid_cpu",
        "hand_block_z_td3_grid_cpu",
        "hand_block_z_td3bc_grid_cpu",
        "hand_egg_rotate_grid_cpu",
    ]
    .map(|g| repo().join("results").join(g).join("results.csv"));
    let inputs: Vec<&Path> = grids.iter().map(PathBuf::as_path).collect();
    let o = table2(&inputs, dir.path(), &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = text(&o.stdout);
    let heads = ["FetchReach", "FetchPush", "FetchPick", "FetchSlide", "HandBlock-Z", "HandEgg-Rotate"];
    for r in &rows {
        let col = heads.iter().position(|h| *h == r[0]).unwrap_or_else(|| panic!("task {}", r[0]));
        let marks: Vec<&str> =
            [(r[4] == "yes").then_some("▲b"), (r[5] == "yes").then_some("▲s")].into_iter().flatten().collect();
        let want = format!("{} ± {} {}", r[2], r[3], marks.join(" "));
        assert_eq!(cells(&md, &format!("{} (paper)", r[1]))[col], want.trim_end(), "{r:?}");
    }
    // By hand from the paper's table: pink and bold, pink alone, neither, three decimals.
    assert_eq!(cells(&md, "TD3BC-mem (paper)")[1], "29.85 ± 11.57 ▲b ▲s");
    assert_eq!(cells(&md, "TD3BC-mem (paper)")[5], "34.07 ± 32.57 ▲b ▲s");
    assert_eq!(cells(&md, "TD3-swap (paper)")[2], "24.23 ± 15.05 ▲b");
    assert_eq!(cells(&md, "TD3-swap (paper)")[0], "47.09 ± 1.285");
    assert_eq!(cells(&md, "TD3 (paper)")[3], "1.01 ± 2.96");
    assert!(!md.contains("lacks"), "the committed reference is whole");
    // The committed grids kept no per-run spread of their episodes: n/a, never estimated.
    assert!(cells(&md, "TD3BC (pgser, episodes)").iter().all(|c| c == "n/a"), "{md}");
    // The issue's reading of these tables, as the lines say it.
    let egg = md.lines().find(|l| l.starts_with("- **HandEgg-Rotate**")).unwrap();
    assert!(egg.contains("mem vs baseline ▼ p = 0.005, the paper ▲: differ"), "{egg}");
    let push = md.lines().find(|l| l.starts_with("- **FetchPush**")).unwrap();
    assert!(push.contains("in the paper it holds (29.85 / 27.52 / 26.94): agree"), "{push}");
    assert!(push.contains("mem vs swap not significant (p = 0.577), the paper ▲: differ"), "{push}");
    assert_eq!(md.lines().filter(|l| l.starts_with("- **")).count(), 6);
    assert!(md.contains("the marks agree in 19 of 36 comparisons by the test over seeds"), "{md}");
    // mem vs baseline (counted by hand from the rows above: TD3BC Reach, Push, Slide; TD3 Push,
    // Pick) 5 of 12, mem above swap in none (the paper: 5).
    assert!(md.contains("Of the marks, mem vs baseline agrees in 5 of 12; mem is significantly above swap in 0 of 12 pairs (the paper marks 5 of them)."), "{md}");
    // The paper's marks against its own printed numbers (computed by hand with Welch's formula).
    assert!(md.contains("18 of 36 come out as it marks them with n = 10 a side"), "{md}");
    assert!(md.contains("26 of 36 with n = 500"), "{md}");
}

/// A reference that lacks a cell prints "—" there and says so; one whose rows are not whole or
/// carry a mark the paper does not have is refused, naming the file and line.
#[test]
fn table2_marks_a_missing_paper_value_and_refuses_a_bad_one() {
    let dir = tempfile::tempdir().unwrap();
    let push = results_csv(&dir.path().join("push.csv"), "FetchPush", &six(0.0));
    let committed = std::fs::read_to_string(repo().join("assets/paper_table2.csv")).unwrap();
    let variant = |name: &str, edit: &dyn Fn(&str) -> String| {
        let f = dir.path().join(name);
        std::fs::write(&f, committed.lines().map(edit).collect::<Vec<_>>().join("\n")).unwrap();
        f
    };
    let out = dir.path().join("t2");
    // FetchPush TD3BC-mem left out.
    let lacking =
        variant("lacking.csv", &|l| if l.starts_with("FetchPush,TD3BC-mem,") { String::new() } else { l.into() });
    let o = table2(&[&push], &out, &["--reference", lacking.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = text(&o.stdout);
    assert_eq!(cells(&md, "TD3BC-mem (paper)")[1], "—");
    assert_eq!(cells(&md, "TD3BC-swap (paper)")[1], "27.52 ± 16.27 ▲b");
    assert!(md.contains("**The reference lacks 1 of the paper's 36 cells** (FetchPush TD3BC-mem)"), "{md}");
    std::fs::remove_dir_all(&out).unwrap();

    let line = committed.lines().position(|l| l.starts_with("FetchPush,TD3BC-mem,")).unwrap() + 1;
    for (name, edit, want) in [
        ("empty.csv", "FetchPush,TD3BC-mem,29.85,,yes,yes", "std \"\" is not a number"),
        ("marker.csv", "FetchPush,TD3BC-mem,29.85,11.57,pink,yes", "must be yes, no or empty"),
        ("short.csv", "FetchPush,TD3BC-mem,29.85,11.57", "expected 6 fields, got 4"),
    ] {
        let f = variant(name, &|l| if l.starts_with("FetchPush,TD3BC-mem,") { edit.into() } else { l.into() });
        let o = table2(&[&push], &out, &["--reference", f.to_str().unwrap()]);
        refused(&o, &out, &[&format!("{name}:{line}"), want]);
    }
    let base = committed.lines().position(|l| l.starts_with("FetchPush,TD3BC,")).unwrap() + 1;
    let f = variant("base.csv", &|l| {
        if l.starts_with("FetchPush,TD3BC,") { "FetchPush,TD3BC,1,1,yes,".into() } else { l.into() }
    });
    let o = table2(&[&push], &out, &["--reference", f.to_str().unwrap()]);
    refused(&o, &out, &[&format!("base.csv:{base}"), "on a baseline row, which the paper does not mark"]);
}

/// Each cell's per-episode scores for the pooled-spread tests: seed 0 scores base + 0, 1, 2 and
/// seed 1 base + 3, 4, 5. By hand: seed means base + 1 and base + 4, so mean base + 2.5 and std
/// over seeds √4.5; pooled, the six values base + 0..5 have sample std √(17.5 / 5) = √3.5.
const BASES: [(&str, &str, f64); 6] = [
    ("td3bc", "baseline", 10.0),
    ("td3bc", "swap", 20.0),
    ("td3bc", "mem", 30.0),
    ("td3", "baseline", 10.0),
    ("td3", "swap", 25.0),
    ("td3", "mem", 24.0),
];

/// FetchPush's results.csv (the old columns) for [`BASES`], in `dir`.
fn pooled_results(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let rows: Vec<_> = BASES.iter().map(|(a, v, b)| (*a, *v, 2, b + 2.5, 4.5f64.sqrt())).collect();
    results_csv(&dir.join("results.csv"), "FetchPush", &rows)
}

#[test]
fn table2_pools_the_episodes_of_a_hand_made_scores_csv() {
    let dir = tempfile::tempdir().unwrap();
    // A row per episode (no episodes / episode_std columns), in the paper's task name.
    let per_episode = dir.path().join("per_episode");
    let results = pooled_results(&per_episode);
    let mut s = String::from("task,algo,variant,seed,paper_score\n");
    for (algo, variant, base) in BASES {
        for k in 0..6 {
            s += &format!("FetchPush,{algo},{variant},{},{}\n", k / 3, base + k as f64);
        }
    }
    std::fs::write(per_episode.join("scores.csv"), &s).unwrap();
    let out = dir.path().join("t2");
    let o = table2(&[&results], &out, &["--json"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = std::fs::read_to_string(out.join("table2.md")).unwrap();
    let pooled = 3.5f64.sqrt();
    // Over seeds: 2 a side; over episodes: 6 a side, where TD3-mem (26.5) is not significantly
    // below TD3-swap (27.5) and TD3BC-mem is above both.
    assert_eq!(cells(&md, "TD3BC-mem (pgser)")[1], format!("32.50 ± {:.2} ▲b ▲s", 4.5f64.sqrt()));
    assert_eq!(cells(&md, "TD3BC-mem (pgser, episodes)")[1], format!("32.50 ± {pooled:.2} ▲b ▲s"));
    assert_eq!(cells(&md, "TD3-mem (pgser, episodes)")[1], format!("26.50 ± {pooled:.2} ▲b"));
    assert_eq!(cells(&md, "TD3 (pgser, episodes)")[1], format!("12.50 ± {pooled:.2}"));
    let j = last_json(&text(&o.stdout));
    let cell = |agent: &str| j["cells"].as_array().unwrap().iter().find(|c| c["agent"] == agent).unwrap().clone();
    let mem = cell("TD3-mem");
    assert_eq!(mem["episodes"], 6);
    assert!((mem["std_episodes"].as_f64().unwrap() - pooled).abs() < 1e-12, "{mem}");
    let (_, _, p) = report::welch_from_summary((26.5, pooled, 6), (27.5, pooled, 6)).unwrap();
    assert!((mem["p_episodes_vs_swap"].as_f64().unwrap() - p).abs() < 1e-12 && p > 0.05, "{mem}");
    // The agreement lines run both tests.
    let line = md.lines().find(|l| l.starts_with("- **FetchPush**")).unwrap();
    assert!(
        line.contains(&format!("mem vs swap not significant (p = 0.684), over episodes not significant (p = {p:.3})"))
    );
    assert!(line.contains("the paper ▲: differ (over episodes: differ)"), "{line}");

    // The same episodes as a row per run (episodes, mean, std over them with n): the same answer.
    let per_run = dir.path().join("per_run");
    let results = pooled_results(&per_run);
    let mut s = String::from("task,algo,variant,seed,episodes,paper_score,episode_std\n");
    for (algo, variant, base) in BASES {
        for (seed, mean) in [(0, base + 1.0), (1, base + 4.0)] {
            s += &format!("FetchPush,{algo},{variant},{seed},3,{mean},{}\n", (2.0f64 / 3.0).sqrt());
        }
    }
    std::fs::write(per_run.join("scores.csv"), &s).unwrap();
    let out2 = dir.path().join("t2_runs");
    let o = table2(&[&results], &out2, &["--json"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let again = last_json(&text(&o.stdout));
    let mem2 = again["cells"].as_array().unwrap().iter().find(|c| c["agent"] == "TD3-mem").unwrap().clone();
    assert!((mem2["std_episodes"].as_f64().unwrap() - pooled).abs() < 1e-12, "{mem2}");

    // Scores of other runs than the results.csv's are refused, naming the first row of the cell.
    let shifted = s.replace("FetchPush,td3,swap,1,3,29,", "FetchPush,td3,swap,1,3,32,");
    assert_ne!(shifted, s);
    std::fs::write(per_run.join("scores.csv"), shifted).unwrap();
    let out3 = dir.path().join("t2_refused");
    refused(&table2(&[&results], &out3, &[]), &out3, &["scores.csv:10", "FetchPush TD3-swap", "not the same runs"]);
}

/// A pipeline's results step from metrics files keeps the spread the pooled std needs: each run's
/// final evaluation reports its episodes' std (10 episodes, std 1 in `metrics_file`), so the
/// results.csv and the scores.csv beside it give table2 the pooled spread, equal to that of the
/// episodes written out by hand (5 at the run's score − 1, 5 at + 1).
#[test]
fn results_keep_what_the_pooled_spread_needs_and_table2_reads_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut runs = Vec::new();
    for (algo, variant, base) in BASES {
        for seed in 0..2u64 {
            let score = base + 3.0 * seed as f64;
            let m = metrics_file(d, &format!("{algo}_{variant}_{seed}.metrics.jsonl"), score, 0.5);
            runs.push(report_run("FetchPush", algo, variant, seed, m));
        }
    }
    let r = report::results(&runs, &d.join("grid")).unwrap();
    let episodes: Vec<f64> =
        [30.0, 33.0].iter().flat_map(|m| (0..10).map(move |i| if i % 2 == 0 { m - 1.0 } else { m + 1.0 })).collect();
    let mean = episodes.iter().sum::<f64>() / 20.0;
    let pooled = (episodes.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 19.0).sqrt();
    let mem = r.rows.iter().find(|row| row.algo == "td3bc" && row.variant == "mem").unwrap();
    assert_eq!(mem.episodes, Some(20));
    assert!((mem.paper_score_std_episodes.unwrap() - pooled).abs() < 1e-12, "{mem:?}");

    for with_scores in [true, false] {
        if !with_scores {
            std::fs::remove_file(&r.scores).unwrap();
        }
        let out = d.join(format!("t2_{with_scores}"));
        let o = table2(&[&r.csv], &out, &[]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        let md = text(&o.stdout);
        assert_eq!(cells(&md, "TD3BC-mem (pgser, episodes)")[1], format!("31.50 ± {pooled:.2} ▲b ▲s"), "{md}");
    }
}

/// `fig5`'s Table 1 of the committed reports, with the paper's accuracy beneath each classifier.
#[test]
fn fig5_prints_the_papers_table1_beneath_pgsers() {
    let committed = std::fs::read_to_string(repo().join("assets/paper_table1.csv")).unwrap();
    assert!(committed.contains("arXiv:2302.07741"), "the reference names its source");
    let dir = tempfile::tempdir().unwrap();
    let reports = [
        "fetch_reach_grid_cpu",
        "fetch_push_grid_cpu/q_remade_f3e9ef7",
        "fetch_pick_and_place_grid_cpu",
        "fetch_slide_grid_cpu",
        "hand_block_z_td3_grid_cpu",
        "hand_egg_rotate_grid_cpu",
    ]
    .map(|r| repo().join("results").join(r));
    let o = etl().arg("fig5").args(&reports).arg("-o").arg(dir.path()).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let md = text(&o.stdout);
    // The paper's columns are FetchPush, FetchSlide, FetchPick, FetchReach, HandBlockZ,
    // HandEggRotate; pgser's follow its Table 2: Reach, Push, Pick, Slide, Block-Z, Egg-Rotate.
    for (ours, paper) in [
        ("logistic regression", ["0.770", "0.915", "0.925", "0.970", "0.880", "0.905"]),
        ("Gaussian naive Bayes", ["0.770", "0.920", "0.905", "0.965", "0.890", "0.915"]),
        ("k-NN (k=5)", ["0.785", "0.920", "0.910", "0.965", "0.885", "0.905"]),
        ("SVC (RBF, C=1, γ=1)", ["0.775", "0.920", "0.905", "0.965", "0.885", "0.905"]),
    ] {
        assert_eq!(cells(&md, &format!("{ours} (paper)")), paper, "{md}");
        assert_eq!(cells(&md, ours).len(), 6, "pgser's row is still there");
    }
    assert!(md.contains("KNN beneath k-NN (k=5)"), "{md}");
}
