#!/bin/sh
# Shows that the crash and out-of-disk tests test the atomic write: builds pgser with the
# test-only feature `mutant-direct-write` (every output written in place, as a naive writer
# would: src/output.rs) and runs each of those tests against it. Each must FAIL; one that
# passes is reported as a test that cannot see a direct write, and the script exits 1.
# Run it as `make mutants`; the next ordinary `cargo build` relinks the real binaries.
set -u
cargo=${CARGO:-cargo}
features="--features mutant-direct-write"
# binary:test — every test whose point is that an output appears whole or not at all. (The
# sweeping tests are not here: a direct writer has no temporary files to sweep. Nor is
# bad_inputs::failed_run_keeps_previous_output, whose error comes before any write.)
tests="
lib:output::tests::uncommitted_output_leaves_nothing
lib:agent::tests::a_save_killed_between_its_renames_leaves_a_pair_that_loads
bad_inputs:a_file_size_limit_mid_write_fails_in_one_line_and_keeps_the_old_output
bad_inputs:a_file_size_limit_in_report_and_minari_export_fails_cleanly
minari:bad_datasets_fail_in_one_line_and_leave_nothing
crash:killed_at_any_moment_nothing_is_partial_and_the_rerun_is_byte_identical
crash:killed_score_and_collect_leave_nothing_a_rerun_keeps
crash:killed_training_resumes_to_the_uninterrupted_state
"
$cargo test --release --no-run --lib --test bad_inputs --test crash --test minari $features || exit 2
missed=0
log=$(mktemp)
trap 'rm -f "$log"' EXIT
for t in $tests; do
  bin=${t%%:*}; name=${t#*:}
  if [ "$bin" = lib ]; then sel="--lib"; else sel="--test $bin"; fi
  start=$(date +%s)
  if $cargo test --release $features $sel -- --exact "$name" > "$log" 2>&1; then
    echo "MISSED  $bin::$name passes against direct writes"; missed=1
  else
    why=$(grep -m1 -E "panicked|assertion" -A1 "$log" | tail -1 | cut -c1-150)
    echo "caught  $bin::$name fails against direct writes ($(( $(date +%s) - start )) s): $why"
  fi
done
exit $missed
