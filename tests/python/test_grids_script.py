"""scripts/grids.sh, the background runner of the Table 2 grids: `times` sums each grid's wall
time over the runs its log records (the figure issue notes report), and leaves out a run the
machine stopped under (no end line) rather than guessing its length; `stop` with nothing
running says so and succeeds. Run on a log written here, in a GRID_ROOT of its own."""

import os
import subprocess

import pytest

from conftest import REPO

SCRIPT = REPO / "scripts" / "grids.sh"

LOG = """\
== 2026-01-01T00:00:00Z pipelines/a.toml
pipeline a: [6/37] agent td3_baseline_s0: running with 14 more in one stack
pgser-etl: error: pipeline a: stopped by SIGTERM at update 100 of 300
== 2026-01-01T01:30:00Z pipelines/a.toml: ended, rc 1
== 2026-01-01T02:00:00Z pipelines/a.toml
== 2026-01-01T02:10:30Z pipelines/a.toml: ended, rc 0
== 2026-01-01T03:00:00Z pipelines/b.toml
== 2026-01-02T04:00:00Z pipelines/b.toml
== 2026-01-02T04:05:59Z pipelines/b.toml: ended, rc 0
== 2026-01-02T04:06:00Z all grids up to date
"""


def grids(root, *args):
    env = dict(os.environ, GRID_ROOT=str(root))
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, env=env)


def test_times_sums_each_grids_runs_and_skips_those_without_an_end(tmp_path):
    (tmp_path / "grids.log").write_text(LOG)
    p = grids(tmp_path, "times")
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == [
        # 1 h 30 min + 10 min 30 s
        "pipelines/a.toml: 1 h 40 min over 2 run(s)",
        # the first run has no end line (the next start came first): not counted
        "pipelines/b.toml: 0 h 05 min over 2 run(s); 1 run(s) without an end line, not counted",
    ]


def test_times_without_a_log_is_an_error(tmp_path):
    p = grids(tmp_path, "times")
    assert p.returncode == 1
    assert f"no log at {tmp_path}/grids.log" in p.stderr


def test_stop_with_nothing_running(tmp_path):
    p = grids(tmp_path, "stop")
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "(no grid running)"


FAKE_ETL = r"""#!/bin/bash
# pgser-etl as far as `grids.sh collect` uses it: `pipeline status FILE` says the results step is
# up to date for a file marked "# finished"; table2 and fig5 record their arguments.
case "$1 $2" in
  "pipeline status")
    if grep -q '^# finished' "$3"; then s="up to date"; else s="not started"; fi
    echo "pipeline x: [37/37] results: $s" ;;
  "pipeline step")
    # A step drawn again, each output replaced by rename: the report's histogram and Table 1 (as
    # $TABLE1_JSON says), or the results step's curves and table (as $RESULTS_CSV says). The step
    # is recorded, with the folder it ran in, so a test can tell where it ran.
    out="$(dirname "$3")/$(sed -n 's/^out *= *"\(.*\)"/\1/p' "$3")"
    echo "$4 $PWD" >> "$GRID_ROOT/steps"
    if [ "$4" = report ]; then
      echo redrawn > "$out/report/h.tmp" && mv "$out/report/h.tmp" "$out/report/fig5_q_hist.png"
      if [ -n "${TABLE1_JSON:-}" ]; then echo "$TABLE1_JSON" > "$out/report/t.tmp" && mv "$out/report/t.tmp" "$out/report/table1.json"; fi
    else
      echo redrawn > "$out/curves_A.png.tmp" && mv "$out/curves_A.png.tmp" "$out/curves_A.png"
      if [ -n "${RESULTS_CSV:-}" ]; then echo "$RESULTS_CSV" > "$out/r.tmp" && mv "$out/r.tmp" "$out/results.csv"; fi
    fi ;;
  "table2 --help") printf '  --chosen <CHOSEN>...\n  --chosen-arm <CHOSEN_ARM>\n' ;;
  table2*|fig5*) echo "$*" >> "$GRID_ROOT/calls" ;;
esac
"""


def pinned_fake(tmp_path):
    """A GRID_ROOT whose pinned build is FAKE_ETL, and a results folder beside it."""
    root, results = tmp_path / "grids", tmp_path / "results"
    fake = root / "bin-fake"
    fake.mkdir(parents=True)
    (fake / "pgser-etl").write_text(FAKE_ETL)
    (fake / "pgser-etl").chmod(0o755)
    (root / "bin").symlink_to(fake)
    return root, results


def test_collect_copies_finished_grids_and_remakes_table2_and_fig5(tmp_path):
    root, results = pinned_fake(tmp_path)
    files = []
    for name, done in [("a_grid_cpu", True), ("b_grid_cpu", False)]:
        f = tmp_path / f"{name}.toml"
        f.write_text(("# finished\n" if done else "") + f'name = "{name}"\nout = "../out/{name}"\n')
        files.append(str(f))
        out = root / "out" / name
        (out / "report").mkdir(parents=True)
        for rel in ["results.csv", "results.md", "curves_A.png", "report/fig5_q_hist.png",
                    "report/table1.json", "report/table1.md", "q.ckpt"]:
            (out / rel).write_text(f"{name} {rel}")
    # An earlier grid whose own report was lost, with the report of a remade Q beside it.
    (results / "c_grid_cpu" / "q_remade_abc").mkdir(parents=True)
    (results / "c_grid_cpu" / "results.csv").write_text("c")
    (results / "c_grid_cpu" / "q_remade_abc" / "table1.json").write_text("{}")

    # No checkout build to draw with: the pinned build draws the tables across tasks.
    env = dict(os.environ, GRID_ROOT=str(root), GRID_RESULTS=str(results),
               GRID_RENDER_ETL=str(tmp_path / "absent"))
    p = subprocess.run(["bash", str(SCRIPT), "collect", *files], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == [
        f"a_grid_cpu: collected into {results}/a_grid_cpu",
        "b_grid_cpu: not finished, not collected",
        f"tables across tasks drawn by {root}/bin-fake/pgser-etl",
    ]
    got = sorted(f.name for f in (results / "a_grid_cpu").iterdir())
    assert got == ["curves_A.png", "fig5_q_hist.png", "results.csv", "results.md", "table1.json", "table1.md"]
    assert (results / "a_grid_cpu" / "table1.json").read_text() == "a_grid_cpu report/table1.json"
    assert not (results / "b_grid_cpu").exists()
    assert (root / "calls").read_text().splitlines() == [
        f"table2 {results}/a_grid_cpu/results.csv {results}/c_grid_cpu/results.csv -o {results}/table2",
        f"fig5 {results}/a_grid_cpu {results}/c_grid_cpu/q_remade_abc -o {results}/fig5",
    ]


def test_collect_gives_table2_the_chosen_rows_of_its_own_tasks_only(tmp_path):
    """Issue 57's *_priority_* results join Table 2 as --chosen rows; step 3's PointMaze files,
    named alike, are left out (their task has no grid in the table), and a file without the
    chosen arm is not passed at all."""
    root, results = pinned_fake(tmp_path)
    header = "task,algo,variant,seeds,paper_score_mean\n"
    for name, body in [("fetch_push_priority_td3bc_cpu", "FetchPush,td3bc,mem_rank,5,27.1\n"),
                       ("pointmaze_medium_stitch_priority_td3_cpu", "pointmaze-medium-stitch-v0,td3,mem_rank,5,15.2\n"),
                       ("fetch_reach_priority_td3_cpu", "FetchReach,td3,mem_q3,5,48.4\n")]:
        (results / name).mkdir(parents=True)
        (results / name / "results.csv").write_text(header + body)
    (results / "a_grid_cpu").mkdir()
    (results / "a_grid_cpu" / "results.csv").write_text(header + "FetchPush,td3bc,baseline,5,7.7\nFetchPush,td3,baseline,5,19.9\n")
    (results / "b_grid_cpu").mkdir()
    (results / "b_grid_cpu" / "results.csv").write_text(header + "FetchReach,td3bc,baseline,5,48.4\nFetchReach,td3,baseline,5,48.4\n")
    env = dict(os.environ, GRID_ROOT=str(root), GRID_RESULTS=str(results),
               GRID_RENDER_ETL=str(tmp_path / "absent"))
    p = subprocess.run(["bash", str(SCRIPT), "collect"], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert "pointmaze_medium_stitch_priority_td3_cpu: pointmaze-medium-stitch-v0 is not a task of " \
        "Table 2's grids: left out of it" in p.stdout.splitlines()
    assert (root / "calls").read_text().splitlines()[0] == (
        f"table2 {results}/a_grid_cpu/results.csv {results}/b_grid_cpu/results.csv -o {results}/table2 "
        f"--chosen-arm mem_rank --chosen-setting rank:1 --chosen {results}/fetch_push_priority_td3bc_cpu/results.csv")


def test_collect_gives_table2_the_chosen_arm_it_is_told(tmp_path):
    """The arm that picks the --chosen files is the one table2 is given (--chosen-arm), with its
    setting: mem_q3 passes the file that trains mem_q3 and not the one with mem_rank alone; an arm
    without its setting is refused before anything is drawn."""
    root, results = pinned_fake(tmp_path)
    header = "task,algo,variant,seeds,paper_score_mean\n"
    for name, body in [("fetch_push_priority_td3bc_cpu", "FetchPush,td3bc,mem_rank,5,27.1\n"),
                       ("fetch_reach_priority_td3_cpu", "FetchReach,td3,mem_q3,5,48.4\n")]:
        (results / name).mkdir(parents=True)
        (results / name / "results.csv").write_text(header + body)
    (results / "a_grid_cpu").mkdir()
    (results / "a_grid_cpu" / "results.csv").write_text(
        header + "".join(f"{t},{a},baseline,5,1\n" for t in ["FetchPush", "FetchReach"] for a in ["td3", "td3bc"]))
    env = dict(os.environ, GRID_ROOT=str(root), GRID_RESULTS=str(results), GRID_RENDER_ETL=str(tmp_path / "absent"),
               GRID_CHOSEN_ARM="mem_q3", GRID_CHOSEN_SETTING="q:3")
    p = subprocess.run(["bash", str(SCRIPT), "collect"], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert (root / "calls").read_text().splitlines()[0] == (
        f"table2 {results}/a_grid_cpu/results.csv -o {results}/table2 --chosen-arm mem_q3 --chosen-setting q:3 "
        f"--chosen {results}/fetch_reach_priority_td3_cpu/results.csv")
    (root / "calls").unlink()
    del env["GRID_CHOSEN_SETTING"]
    p = subprocess.run(["bash", str(SCRIPT), "collect"], capture_output=True, text=True, env=env)
    assert p.returncode == 2
    assert p.stderr.strip() == "grids.sh: GRID_CHOSEN_ARM=mem_q3 needs GRID_CHOSEN_SETTING, its KIND:ALPHA (q:3, rank:1)"
    assert not (root / "calls").exists()


def newer_build_layout(tmp_path):
    """A finished grid on a pinned build, and a newer build to draw with."""
    root, results = tmp_path / "grids", tmp_path / "results"
    pinned, newer = root / "bin-old", tmp_path / "release"
    for d in (pinned, newer):
        d.mkdir(parents=True)
        (d / "pgser-etl").write_text(FAKE_ETL.replace('"$GRID_ROOT/calls"', f'"$GRID_ROOT/calls.{d.name}"'))
        (d / "pgser-etl").chmod(0o755)
    (root / "bin").symlink_to(pinned)
    f = tmp_path / "a_grid_cpu.toml"
    f.write_text('# finished\nname = "a_grid_cpu"\nout = "../out/a_grid_cpu"\n')
    out = root / "out" / "a_grid_cpu"
    (out / "report").mkdir(parents=True)
    for rel in ["results.csv", "results.md", "curves_A.png", "report/fig5_q_hist.png",
                "report/table1.json", "report/table1.md"]:
        (out / rel).write_text(rel)
    env = dict(os.environ, GRID_ROOT=str(root), GRID_RESULTS=str(results),
               GRID_RENDER_ETL=str(newer / "pgser-etl"))
    return root, results, newer, out, f, env


def test_collect_draws_curves_and_tables_across_tasks_with_the_checkouts_build(tmp_path):
    """The grid's status still comes from the pinned build; its curves and the report's Q
    histogram (the results and report steps run again on a linked copy of out/) and table2 and
    fig5 are drawn by the newer build, so a collect never puts an older drawing back over a
    committed redraw."""
    root, results, newer, out, f, env = newer_build_layout(tmp_path)
    p = subprocess.run(["bash", str(SCRIPT), "collect", str(f)], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == [
        f"a_grid_cpu: curves and Q histogram drawn by {newer}/pgser-etl",
        f"a_grid_cpu: collected into {results}/a_grid_cpu",
        f"tables across tasks drawn by {newer}/pgser-etl",
    ]
    assert (results / "a_grid_cpu" / "curves_A.png").read_text() == "redrawn\n"
    assert (results / "a_grid_cpu" / "fig5_q_hist.png").read_text() == "redrawn\n"
    assert (results / "a_grid_cpu" / "results.csv").read_text() == "results.csv"
    assert (results / "a_grid_cpu" / "table1.json").read_text() == "report/table1.json"
    # Both steps ran, from the root of a copy laid out like the grid's (pipelines/, out/NAME), so
    # the paths Table 1 records are the grid's own; the copy is gone afterwards.
    steps = [line.split(" ", 1) for line in (root / "steps").read_text().splitlines()]
    assert [s for s, _ in steps] == ["report", "results"]
    assert steps[0][1] == steps[1][1] and not os.path.exists(steps[0][1])
    # The grid's own out/ is untouched.
    assert (out / "curves_A.png").read_text() == "curves_A.png"
    assert (out / "report" / "fig5_q_hist.png").read_text() == "report/fig5_q_hist.png"
    assert (root / "calls.release").read_text().splitlines() == [
        f"table2 {results}/a_grid_cpu/results.csv -o {results}/table2",
        f"fig5 {results}/a_grid_cpu -o {results}/fig5",
    ]
    assert not (root / "calls.bin-old").exists()


@pytest.mark.parametrize("var, rel", [("RESULTS_CSV", "results.csv"), ("TABLE1_JSON", "report/table1.json")])
def test_collect_stops_when_the_newer_build_computes_other_numbers(tmp_path, var, rel):
    """The newer build only draws: where its results table or Table 1 differs from the grid's by
    a byte, collect stops before anything across tasks is drawn, and the grid's file is kept."""
    root, results, newer, out, f, env = newer_build_layout(tmp_path)
    env[var] = "other numbers"
    p = subprocess.run(["bash", str(SCRIPT), "collect", str(f)], capture_output=True, text=True, env=env)
    assert p.returncode == 1
    name = rel.rsplit("/", 1)[-1]
    assert f"a_grid_cpu: {newer}/pgser-etl computes another {name} than the grid's" in p.stderr
    assert (out / rel).read_text() == rel
    assert not (root / "calls.release").exists()


def test_collect_compares_an_older_results_csv_on_its_own_columns(tmp_path):
    """A grid run by a build older than the pooled episodes' columns: the newer build's results.csv
    has more columns, appended after the old ones, and collect compares the old ones only."""
    root, results, newer, out, f, env = newer_build_layout(tmp_path)
    env["RESULTS_CSV"] = "results.csv,pooled"
    p = subprocess.run(["bash", str(SCRIPT), "collect", str(f)], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert (results / "a_grid_cpu" / "results.csv").read_text() == "results.csv"
    env["RESULTS_CSV"] = "other,pooled"
    p = subprocess.run(["bash", str(SCRIPT), "collect", str(f)], capture_output=True, text=True, env=env)
    assert p.returncode == 1 and "computes another results.csv than the grid's" in p.stderr


def test_usage_prints_the_whole_header(tmp_path):
    p = grids(tmp_path)
    assert p.returncode == 2
    lines = p.stdout.splitlines()
    assert lines[0].startswith("The Table 2 grids")
    assert lines[-1] == "finish inside one session on such a machine is split in two files, one per learner."
    assert not any(line.startswith(("set ", "cd ")) for line in lines)


def split_task_layout(tmp_path):
    """Task T split over two grids, one per learner: the TD3 half collected in an earlier session
    (its out/ gone with that machine), the TD3+BC half run here; and a whole task U beside them."""
    root, results = pinned_fake(tmp_path)
    head = "task,algo,variant,seeds\n"
    rows = lambda task, algo: "".join(f"{task},{algo},{v},5\n" for v in ["baseline", "swap", "mem"])
    for name, text in [("t_td3_grid_cpu", head + rows("T", "td3")),
                       ("u_grid_cpu", head + rows("U", "td3") + rows("U", "td3bc"))]:
        (results / name).mkdir(parents=True)
        (results / name / "results.csv").write_text(text)
        (results / name / "table1.json").write_text(f'{{\n  "task": "{name[0].upper()}",\n  "positives": 1\n}}\n')
        (results / name / "table1.md").write_text(f"Q report of {name[0].upper()}\n")
    f = tmp_path / "t_td3bc_grid_cpu.toml"
    f.write_text('name = "t_td3bc_grid_cpu"\nout = "../out/t_td3bc_grid_cpu"\n')
    out = root / "out" / "t_td3bc_grid_cpu"
    (out / "report").mkdir(parents=True)
    (out / "data").mkdir()
    for rel, text in [("results.csv", head + rows("T", "td3bc")), ("results.md", ""), ("curves_A.png", ""),
                      ("report/fig5_q_hist.png", ""), ("report/table1.md", "Q report of T\n"),
                      ("report/table1.json", '{\n  "task": "T",\n  "positives": 1\n}\n'),
                      ("data/expert.pkl", "e"), ("data/random.pkl", "r")]:
        (out / rel).write_text(text)
    env = dict(os.environ, GRID_ROOT=str(root), GRID_RESULTS=str(results),
               GRID_RENDER_ETL=str(tmp_path / "absent"))
    return root, results, f, out, env


def test_collect_joins_a_split_task_to_table2_once_both_learners_are_in(tmp_path):
    root, results, f, out, env = split_task_layout(tmp_path)
    # The TD3+BC half still running: T's one half stays out of Table 2, U goes in.
    p = subprocess.run(["bash", str(SCRIPT), "collect", str(f)], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == [
        "t_td3bc_grid_cpu: not finished, not collected",
        "t_td3_grid_cpu: T has one learner so far: left out of Table 2",
        f"tables across tasks drawn by {root}/bin-fake/pgser-etl",
    ]
    assert (root / "calls").read_text().splitlines() == [
        f"table2 {results}/u_grid_cpu/results.csv -o {results}/table2",
        f"fig5 {results}/t_td3_grid_cpu {results}/u_grid_cpu -o {results}/fig5",
    ]
    # Finished: both halves go into Table 2, and T's one Q is drawn once.
    (root / "calls").unlink()
    f.write_text("# finished\n" + f.read_text())
    p = subprocess.run(["bash", str(SCRIPT), "collect", str(f)], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == [
        f"t_td3bc_grid_cpu: collected into {results}/t_td3bc_grid_cpu",
        "t_td3bc_grid_cpu: the same Q report as t_td3_grid_cpu, drawn once",
        f"tables across tasks drawn by {root}/bin-fake/pgser-etl",
    ]
    assert (root / "calls").read_text().splitlines() == [
        f"table2 {results}/t_td3_grid_cpu/results.csv {results}/t_td3bc_grid_cpu/results.csv "
        f"{results}/u_grid_cpu/results.csv -o {results}/table2",
        f"fig5 {results}/t_td3_grid_cpu {results}/u_grid_cpu -o {results}/fig5",
    ]
    # The pickles the numbers came from, by sha256 (of "e" and "r").
    assert (results / "t_td3bc_grid_cpu" / "data.sha256").read_text().splitlines() == [
        "3f79bb7b435b05321651daefd374cdc681dc06faa65e374e38337b88ca046dea  data/expert.pkl",
        "454349e422f05297191ead13e21d3db520e5abef52055e4964b82fb213f593a1  data/random.pkl",
    ]


def test_collect_draws_the_first_halfs_q_where_the_halves_ran_on_two_machines(tmp_path):
    """The hand tasks' data differ between machines, so two halves run in two sessions on two
    machines can report two Qs: both go into Table 2, Fig. 5 draws the first, and collect says so."""
    root, results, f, out, env = split_task_layout(tmp_path)
    f.write_text("# finished\n" + f.read_text())
    (out / "report" / "table1.md").write_text("Q report of another Q\n")
    p = subprocess.run(["bash", str(SCRIPT), "collect", str(f)], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert ("t_td3bc_grid_cpu: its Q report differs from t_td3_grid_cpu's (another machine's data or Q): "
            "Fig. 5 draws t_td3_grid_cpu's") in p.stdout.splitlines()
    assert (root / "calls").read_text().splitlines()[1] == (
        f"fig5 {results}/t_td3_grid_cpu {results}/u_grid_cpu -o {results}/fig5")


def test_a_plain_start_leaves_out_the_grids_already_collected(tmp_path):
    """On a machine that kept nothing, `start` must not spend hours remaking grids whose results
    are committed; with all of them in, it starts nothing (and needs no pinned build to say so)."""
    results = tmp_path / "results"
    names = [line.split("/")[-1].removesuffix(".toml") for line in
             (REPO / "scripts" / "grids.sh").read_text().split('DEFAULT_GRIDS="', 1)[1].split('"', 1)[0].split()]
    assert len(names) >= 2
    for name in names:
        (results / name).mkdir(parents=True)
        (results / name / "results.csv").write_text("x")
    env = dict(os.environ, GRID_ROOT=str(tmp_path / "grids"), GRID_RESULTS=str(results))
    p = subprocess.run(["bash", str(SCRIPT), "start"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == [f"{n}: already in {results}/, not started" for n in names] + [
        f"grids.sh: every grid is in {results}/: nothing to start"]
    # One left: it is the one asked of the pinned build (none here, so that is the error).
    (results / names[-1] / "results.csv").unlink()
    p = subprocess.run(["bash", str(SCRIPT), "start"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert p.returncode == 1
    assert f"{names[-1]}: already in" not in p.stdout
    assert "no pinned build" in p.stderr
