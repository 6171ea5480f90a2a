#!/usr/bin/env bash
# The Table 2 grids (pipelines/*_grid_cpu.toml) as a background job that survives stops: hours of
# CPU each, more than a day for all, so they run on one pinned build, at low priority, and every
# start continues each grid from its last checkpoint (finished steps are skipped, a training stack
# resumes from its last save: pipelines/README.md).
#
#   scripts/grids.sh pin              copy this checkout's release build, with the MuJoCo library,
#                                     assets and ziggurat tables it reads, to $GRID_ROOT/bin-COMMIT
#   scripts/grids.sh start [FILE...]  run the grids one after another on the pinned build, at nice 19,
#                                     in the background (nothing happens if they are already running);
#                                     with no FILE, the grids whose results are not yet in results/
#   scripts/grids.sh status           where each grid stands (pipeline status), and whether it runs
#   scripts/grids.sh stop             stop the running grid; its stack saves where it is first
#   scripts/grids.sh times            wall time per grid, summed over its runs in the log
#   scripts/grids.sh collect [FILE...]
#                                     copy each finished grid's results and report to results/NAME/,
#                                     then remake results/table2 (with the chosen priority's rows of
#                                     results/*_priority_*: --chosen; the arm $GRID_CHOSEN_ARM, default
#                                     mem_rank, of the setting $GRID_CHOSEN_SETTING, default rank:1, as
#                                     table2's --chosen-arm and --chosen-setting) and results/fig5 from all of them
#                                     (figures drawn by target/release when built, else the pinned build;
#                                     the numbers are always the grid's). A task split over two grids,
#                                     one per learner, joins Table 2 once both are in (Fig. 5 draws
#                                     the first half's Q report, and says whether the other agrees);
#                                     data.sha256 beside the results names the pickles they came from
#
# Why a copy: a grid's agents must all train on one build (a rebuild between two stacks would mix
# engines), and `cargo build` replaces target/release under a running grid. Where: $GRID_ROOT,
# by default .grids/ in the checkout (ignored by git), and out/ is a link to $GRID_ROOT/out. The
# checkout is what a machine keeps between sessions when it keeps anything: /var/tmp, the first
# home of the grids, was emptied between sessions twice (taking a HandBlock-Z run with it each
# time), and the second time the checkout, with its ignored target/, was kept. The copy finds
# its MuJoCo library, assets and tables through the environment (LD_LIBRARY_PATH, PGSER_ASSETS,
# PGSER_ZIGGURAT), not through the paths baked into the build. On 2026-11-26 the machine came back
# as a new checkout (a third HandBlock-Z run lost, at 30k of its last 40k stack): a grid that must
# finish inside one session on such a machine is split in two files, one per learner.
set -euo pipefail
export LC_COLLATE=C  # globs list results/ in one order on every machine
cd "$(dirname "$0")/.."
GRID_ROOT=${GRID_ROOT:-$PWD/.grids}
# The order of the chain started on 2026-11-26 (FetchSlide first: its data was already collected),
# so that a plain `start` continues it.
DEFAULT_GRIDS="pipelines/fetch_slide_grid_cpu.toml pipelines/fetch_pick_and_place_grid_cpu.toml
  pipelines/hand_egg_rotate_grid_cpu.toml pipelines/hand_block_z_td3_grid_cpu.toml
  pipelines/hand_block_z_td3bc_grid_cpu.toml"
RESULTS_DIR=${GRID_RESULTS:-results}
# The chosen priority's arm in the *_priority_* results and its setting (issue 57: rank α = 1), given
# to table2 as they are: the files passed with --chosen are the ones that have this arm. Another arm
# needs its own setting, so one is not taken without the other.
CHOSEN_ARM=${GRID_CHOSEN_ARM:-mem_rank}
CHOSEN_SETTING=${GRID_CHOSEN_SETTING:-rank:1}

grid_name() { sed -n 's/^name *= *"\(.*\)"/\1/p' "$1"; }

pinned() {
  [ -L "$GRID_ROOT/bin" ] || { echo "grids.sh: no pinned build in $GRID_ROOT: run scripts/grids.sh pin" >&2; exit 1; }
  readlink -f "$GRID_ROOT/bin"
}

with_pinned() {
  local bin
  bin=$(pinned)
  LD_LIBRARY_PATH="$bin/mujoco${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" PGSER_ASSETS="$bin/assets" \
    PGSER_ZIGGURAT="$bin/numpy_ziggurat.bin" "$@"
}

# The grid pipelines running now, as "PID COMMAND" lines (none: exit status 1).
running() {
  pgrep -af "$GRID_ROOT/bin-.*/pgser-etl pipeline run"
}

link_out() {
  mkdir -p "$GRID_ROOT/out"
  if [ -e out ] && [ ! -L out ]; then
    echo "grids.sh: ./out is a folder, not a link to $GRID_ROOT/out: move it aside first" >&2; exit 1
  fi
  ln -sfn "$GRID_ROOT/out" out
}

case "${1:-}" in
  pin)
    for f in target/release/pgser-etl target/release/pgser-train .deps/mujoco/libmujoco.so.3.17.0 \
      .deps/numpy_ziggurat.bin .deps/gymnasium_robotics/assets; do
      [ -e "$f" ] || { echo "grids.sh: $f is missing: run make build first" >&2; exit 1; }
    done
    commit=$(git rev-parse --short HEAD)
    git diff --quiet HEAD -- src Cargo.toml Cargo.lock || commit="$commit-dirty"
    dest="$GRID_ROOT/bin-$commit"
    if [ ! -d "$dest" ]; then
      tmp="$dest.tmp.$$"
      mkdir -p "$tmp/mujoco"
      cp target/release/pgser-etl target/release/pgser-train "$tmp/"
      cp .deps/mujoco/libmujoco.so.3.17.0 "$tmp/mujoco/"
      ln -s libmujoco.so.3.17.0 "$tmp/mujoco/libmujoco.so"
      cp .deps/numpy_ziggurat.bin "$tmp/"
      cp -r .deps/gymnasium_robotics/assets "$tmp/assets"
      mv "$tmp" "$dest"
    fi
    ln -sfn "$dest" "$GRID_ROOT/bin"
    echo "pinned: $dest"
    ;;
  start)
    shift
    grids=$*
    if [ -z "$grids" ]; then
      # A machine that kept nothing has no out/ for the grids already collected: a plain start
      # must not spend hours remaking them (name a file to run it again).
      for g in $DEFAULT_GRIDS; do
        if [ -f "$RESULTS_DIR/$(grid_name "$g")/results.csv" ]; then
          echo "$(grid_name "$g"): already in $RESULTS_DIR/, not started"
        else grids="$grids $g"; fi
      done
      [ -n "$grids" ] || { echo "grids.sh: every grid is in $RESULTS_DIR/: nothing to start"; exit 0; }
      grids=${grids# }
    fi
    bin=$(pinned)
    if now=$(running); then
      echo "grids.sh: grids already running:"; echo "$now"; exit 0
    fi
    link_out
    log="$GRID_ROOT/grids.log"
    echo "grids on $bin: $grids (log: $log)"
    # One after another: each grid takes both cores; a grid that fails stops the chain, so that
    # its error is the last thing in the log.
    # shellcheck disable=SC2016,SC2086
    nohup nice -n 19 env LD_LIBRARY_PATH="$bin/mujoco" PGSER_ASSETS="$bin/assets" \
      PGSER_ZIGGURAT="$bin/numpy_ziggurat.bin" bash -c '
        bin=$1; shift
        for g in "$@"; do
          echo "== $(date -u +%FT%TZ) $g"
          rc=0; "$bin/pgser-etl" pipeline run "$g" --threads 2 || rc=$?
          echo "== $(date -u +%FT%TZ) $g: ended, rc $rc"
          [ "$rc" = 0 ] || exit 1
        done
        echo "== $(date -u +%FT%TZ) all grids up to date"' grids "$bin" $grids >> "$log" 2>&1 < /dev/null &
    ;;
  stop)
    # SIGTERM makes a training stack save at the update it has reached (not the last 2.5k mark),
    # so stopping loses nothing; the chain then ends instead of starting the next grid.
    pids=$(running | cut -d' ' -f1 || true)
    [ -n "$pids" ] || { echo "(no grid running)"; exit 0; }
    # shellcheck disable=SC2086
    kill -TERM $pids
    for _ in $(seq 600); do
      # shellcheck disable=SC2086
      kill -0 $pids 2>/dev/null || break
      sleep 1
    done
    # shellcheck disable=SC2086
    if kill -0 $pids 2>/dev/null; then echo "grids.sh: still saving after 10 min: pids $pids" >&2; exit 1; fi
    grep -v '^== ' "$GRID_ROOT/grids.log" | tail -n 1
    ;;
  times)
    # Wall time per grid, summed over the runs in the log: each run is a start line and, since
    # 2026-11-26, an end line. A run whose machine stopped under it has no end and is not counted.
    log="$GRID_ROOT/grids.log"
    [ -f "$log" ] || { echo "grids.sh: no log at $log" >&2; exit 1; }
    declare -A total runs open lost
    order=()
    while read -r _ ts rest; do
      case "$rest" in
        *.toml)
          g=$rest
          [ -n "${runs[$g]:-}" ] || order+=("$g")
          [ -z "${open[$g]:-}" ] || lost[$g]=$(( ${lost[$g]:-0} + 1 ))
          open[$g]=$(date -ud "$ts" +%s); runs[$g]=$(( ${runs[$g]:-0} + 1 )) ;;
        *.toml:\ ended,*)
          g=${rest%%: ended,*}
          if [ -n "${open[$g]:-}" ]; then
            total[$g]=$(( ${total[$g]:-0} + $(date -ud "$ts" +%s) - ${open[$g]} )); unset "open[$g]"
          fi ;;
      esac
    done < <(grep '^== ' "$log")
    now=$(running || true)
    for g in "${order[@]}"; do
      note=""
      if [ -n "${open[$g]:-}" ]; then
        if [[ "$now" == *"$g"* ]]; then
          total[$g]=$(( ${total[$g]:-0} + $(date -u +%s) - ${open[$g]} )); note=", running now"
        else
          lost[$g]=$(( ${lost[$g]:-0} + 1 ))
        fi
      fi
      [ -z "${lost[$g]:-}" ] || note="$note; ${lost[$g]} run(s) without an end line, not counted"
      s=${total[$g]:-0}
      printf '%s: %d h %02d min over %d run(s)%s\n' "$g" $(( s / 3600 )) $(( s % 3600 / 60 )) "${runs[$g]}" "$note"
    done
    ;;
  collect)
    # What gets committed of a finished grid (never out/ itself): its Table 2 (results.csv, .md,
    # scores.csv), training curves and the report of its Q (Fig. 5, Table 1). A grid counts as
    # finished when `pipeline status` finds its last step, results, up to date, so a grid stopped
    # half way, or one whose file changed since, is left out and says so.
    shift
    if [ -n "${GRID_CHOSEN_ARM:-}" ] && [ -z "${GRID_CHOSEN_SETTING:-}" ]; then
      echo "grids.sh: GRID_CHOSEN_ARM=$GRID_CHOSEN_ARM needs GRID_CHOSEN_SETTING, its KIND:ALPHA (q:3, rank:1)" >&2; exit 2
    fi
    results=$RESULTS_DIR
    bin=$(pinned)
    # The training curves, the Q histogram of the report and the tables across tasks are drawn by
    # this checkout's build when there is one (the newest plots, e.g. the legend placed where it
    # hides least), else by the pinned one: they only draw numbers the pinned build computed, so the
    # results table and Table 1 the newer build writes beside its figures must match the grid's
    # byte for byte. Without this, every collect would put back the pinned build's older drawing
    # over a figure committed since.
    render=${GRID_RENDER_ETL:-target/release/pgser-etl}
    [ -x "$render" ] || render="$bin/pgser-etl"
    render=$(realpath "$render")
    for g in ${*:-$DEFAULT_GRIDS}; do
      name=$(grid_name "$g")
      src="$GRID_ROOT/out/$name"
      if ! with_pinned "$bin/pgser-etl" pipeline status "$g" 2>/dev/null | grep -q '\] results: up to date$'; then
        echo "$name: not finished, not collected"; continue
      fi
      # The numbers are always the grid's own files; the figures come from $drawn: the grid's
      # out/ itself, or a copy where the newer build has drawn them again.
      drawn=$src
      # A pipeline scoring with a Q outside its out/ ([pretrain] checkpoint) has a scored table
      # whose footer finds that Q by a path relative to the grid's out/, which a copy elsewhere
      # does not have: its figures stay the ones its own build drew.
      given_q=$(sed -n '/^\[pretrain\]/,/^\[/p' "$g" | grep -c '^checkpoint *=' || true)
      # So does one whose data is a table given by path ([data] table): the copy has no such table.
      given_table=$(sed -n '/^\[data\]/,/^\[/p' "$g" | grep -c '^table *=' || true)
      if [ "$given_q" != 0 ]; then
        echo "$name: scores with a given Q: figures as its own build drew them"
      elif [ "$given_table" != 0 ]; then
        echo "$name: reads a table given by path: figures as its own build drew them"
      elif [ "$render" != "$bin/pgser-etl" ]; then
        # The report and results steps again, on a hard-linked copy of out/ (outputs are replaced
        # by rename, so the grid's own files are never written) with their records removed so
        # that they run. The copy keeps the layout the grid ran in, the file in pipelines/ and its
        # out in out/NAME, and the steps run from the copy's root, so the paths Table 1 records
        # are the grid's own (out/NAME/...) and its JSON can be compared whole.
        tmp=$(mktemp -d)
        trap 'rm -rf "$tmp"' EXIT  # also when a step or a check below fails
        mkdir "$tmp/pipelines" "$tmp/out"
        cp "$g" "$tmp/pipelines/"
        cp -al "$src" "$tmp/out/$name"
        rm -f "$tmp/out/$name/.pipeline/report.json" "$tmp/out/$name/.pipeline/results.json"
        for step in report results; do
          (cd "$tmp" && with_pinned "$render" pipeline step "pipelines/$(basename "$g")" $step --threads 1 >/dev/null)
        done
        # A grid's results.csv written before the pooled episodes' columns is compared on its own
        # columns (the newer build appends its columns after them); both sides go through `cut`,
        # so a last line without its newline compares equal.
        cols=$(head -n 1 "$src/results.csv" | awk -F, '{ print NF }')
        cmp -s <(cut -d, -f1-"$cols" "$tmp/out/$name/results.csv") <(cut -d, -f1-"$cols" "$src/results.csv") ||
          { echo "grids.sh: $name: $render computes another results.csv than the grid's" >&2; exit 1; }
        cmp -s "$tmp/out/$name/report/table1.json" "$src/report/table1.json" ||
          { echo "grids.sh: $name: $render computes another table1.json than the grid's" >&2; exit 1; }
        drawn="$tmp/out/$name"
      fi
      mkdir -p "$results/$name"
      cp "$src/results.csv" "$src/results.md" "$src/report/table1.json" "$src/report/table1.md" \
        "$drawn"/curves_*.png "$drawn/report/fig5_q_hist.png" "$results/$name/"
      # Each run's final evaluation (episodes, mean, std), which table2's pooled spread needs: the
      # grid's own, or, for a grid run by a build older than scores.csv, what the newer build read
      # from the grid's metrics files (every evaluation line has always held its episodes' std).
      for d in "$src" "$drawn"; do [ ! -f "$d/scores.csv" ] || cp "$d/scores.csv" "$results/$name/"; done
      # Which data the numbers came from: the sha256 of the collected pickles, so that results
      # of one recipe run on two machines (or a rerun) can be told apart by their data.
      if compgen -G "$src/data/*.pkl" > /dev/null; then
        (cd "$src" && sha256sum data/*.pkl) > "$results/$name/data.sha256"
      fi
      if [ "$drawn" != "$src" ]; then
        rm -rf "$tmp"
        echo "$name: curves and Q histogram drawn by $render"
      fi
      echo "$name: collected into $results/$name"
    done
    # Fig. 5 takes each grid's own report, or, where that was lost, the report of a Q remade on
    # the same data and recipe that RESULTS.md names (a q_remade_BUILD folder beside it). A task
    # split over two grids has two reports: of one Q when both halves ran on one machine (data,
    # Q and scores are deterministic there), of two when they did not (the hand tasks' data
    # differ between machines: RESULTS.md). Fig. 5 takes the first half's and says which.
    reports=()
    declare -A report_of
    for d in "$results"/*_grid_cpu; do
      r=""
      if [ -f "$d/table1.json" ]; then r=$d
      else
        for q in "$d"/q_remade_*; do if [ -f "$q/table1.json" ]; then r=$q; fi; done
      fi
      [ -n "$r" ] || continue
      task=$(sed -n 's/^ *"task": *"\(.*\)",*$/\1/p' "$r/table1.json" | head -n 1)
      first=""
      [ -z "$task" ] || first=${report_of[$task]:-}
      if [ -n "$first" ]; then
        if cmp -s "$first/table1.md" "$r/table1.md"; then
          echo "$(basename "$d"): the same Q report as $(basename "$first"), drawn once"
        else
          echo "$(basename "$d"): its Q report differs from $(basename "$first")'s (another machine's data or Q): Fig. 5 draws $(basename "$first")'s"
        fi
        continue
      fi
      [ -z "$task" ] || report_of[$task]=$r
      reports+=("$r")
    done
    # Table 2 takes a split task once both learners are in; until then its one half is left out
    # (table2 would refuse a task without both learners).
    tables=()
    for c in "$results"/*_grid_cpu/results.csv; do
      half=$(awk -F, 'FNR == 1 { next }
        FILENAME == ARGV[1] { mine[$1] = 1 }
        { has[$1 "," $2] = 1 }
        END { for (t in mine) if (!has[t ",td3"] || !has[t ",td3bc"]) print t }' "$c" "$results"/*_grid_cpu/results.csv)
      if [ -n "$half" ]; then
        echo "$(basename "$(dirname "$c")"): $half has one learner so far: left out of Table 2"
      else tables+=("$c"); fi
    done
    # Table 2's rows for the priority chosen by issue 57 (rank α = 1, RESULTS.md; $CHOSEN_ARM): each
    # *_priority_* pipeline trains it beside its own baseline and -swap (its first arm's file for
    # FetchPush, whose TD3+BC half also ran q α = 3). A build older than --chosen-arm leaves them out.
    # Step 3's files on OGBench tasks (PointMaze) are named alike but have no column in the table:
    # a chosen row joins only a task of the grids going into it.
    grid_tasks=""
    [ "${#tables[@]}" = 0 ] || grid_tasks=$(tail -q -n +2 "${tables[@]}" | cut -d, -f1 | sort -u)
    chosen=()
    for c in "$results"/*_priority_td3bc_cpu/results.csv "$results"/*_priority_td3_cpu/results.csv; do
      [ -f "$c" ] && grep -qF -- ",$CHOSEN_ARM," "$c" || continue
      task=$(sed -n 2p "$c" | cut -d, -f1)
      if grep -qxF -- "$task" <<<"$grid_tasks"; then chosen+=("$c")
      else echo "$(basename "$(dirname "$c")"): $task is not a task of Table 2's grids: left out of it"; fi
    done
    if [ "${#chosen[@]}" -gt 0 ] && with_pinned "$render" table2 --help | grep -q -- --chosen-arm; then
      chosen=(--chosen-arm "$CHOSEN_ARM" --chosen-setting "$CHOSEN_SETTING" --chosen "${chosen[@]}")
    else chosen=(); fi
    # The two tables across tasks read only committed CSV and JSON.
    echo "tables across tasks drawn by $render"
    with_pinned "$render" table2 "${tables[@]}" -o "$results/table2" "${chosen[@]}"
    [ "${#reports[@]}" = 0 ] || with_pinned "$render" fig5 "${reports[@]}" -o "$results/fig5"
    ;;
  status)
    shift
    link_out
    bin=$(pinned)
    for g in ${*:-$DEFAULT_GRIDS}; do
      echo "== $g"
      [ ! -f "$RESULTS_DIR/$(grid_name "$g")/results.csv" ] || echo "(its results are in $RESULTS_DIR/$(grid_name "$g"))"
      with_pinned "$bin/pgser-etl" pipeline status "$g" || true
    done
    running || echo "(no grid running)"
    ;;
  *)
    # The header comment, however long it grows.
    awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "$0"
    exit 2
    ;;
esac
