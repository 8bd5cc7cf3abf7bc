#!/usr/bin/env bash
# The README's main command, scripts/run.sh, on the servers of this build: a short pick task
# to its end (the output folder holds the output file, the score and the report, and no
# server outlives it), then a run stopped with Ctrl-C (SIGINT) while the task runs (every
# server stops, nothing is left behind).
#
#   tests/clients/run_sh_test.sh BIN_DIR WORK_DIR
set -euo pipefail
bin=$(realpath "${1:?usage: run_sh_test.sh BIN_DIR WORK_DIR}")
work=${2:?usage: run_sh_test.sh BIN_DIR WORK_DIR}
top=$(cd "$(dirname "$0")/../.." && pwd)
task=$top/tests/data/tasks/pick_layout_1_tissue_box.json
fail() { echo "run_sh_test: $*" >&2; exit 1; }
# Every server run.sh starts has its output folder in its command line (the orchestrator's
# tasks_dir): any process still naming the folder outlived run.sh.
survivors() { pgrep -f -- "--tasks_dir=$1/tasks" || true; }

rm -rf "$work" && mkdir -p "$work"
out=$work/finished
"$top/scripts/run.sh" --bin "$bin" --task "$task" --detector-budget-scale 10 --out "$out" \
  >"$work/finished.log" 2>&1 || { tail -30 "$work/finished.log" >&2; fail "run.sh failed"; }
grep -q "^output folder: $out" "$work/finished.log" || fail "run.sh did not name its output folder"
for f in output.json score.txt task.json report.html report.json progress.txt logs/orchestrator.log; do
  [[ -s $out/$f ]] || fail "$f missing in the output folder"
done
grep -q '"kleenex_tissue_box"' "$out/output.json" || fail "output.json does not list the item"
tail -1 "$out/score.txt" | grep -Eq '^[0-9]+	total$' || fail "score.txt has no total"
[[ -z $(survivors "$out") ]] || fail "servers outlived run.sh: $(survivors "$out")"

# Ctrl-C while the task runs: run.sh stops every server within their shutdown grace.
out=$work/interrupted
# A command started with & by a script ignores SIGINT (and bash cannot trap a signal ignored
# on entry): start run.sh with SIGINT at its default, as a terminal's foreground job has it.
/usr/bin/python3 -c 'import os, signal, sys
signal.signal(signal.SIGINT, signal.SIG_DFL)
os.execv(sys.argv[1], sys.argv[1:])' "$top/scripts/run.sh" --bin "$bin" --task "$task" \
  --detector-budget-scale 10 --out "$out" >"$work/interrupted.log" 2>&1 &
run_pid=$!
for _ in $(seq 600); do
  grep -q '^task ' "$out/progress.txt" 2>/dev/null && break
  kill -0 "$run_pid" 2>/dev/null || fail "run.sh ended before the task started"
  sleep 0.5
done
grep -q '^task ' "$out/progress.txt" || fail "the task did not start within 300 s"
[[ -n $(survivors "$out") ]] || fail "no servers running while the task runs"
kill -INT "$run_pid"
status=0
wait "$run_pid" || status=$?
[[ $status == 130 ]] || fail "run.sh ended with $status after Ctrl-C, expected 130"
grep -q "stopping the services" "$work/interrupted.log" || fail "run.sh did not stop the services"
[[ -z $(survivors "$out") ]] || fail "servers outlived Ctrl-C: $(survivors "$out")"
echo "run_sh_test: passed"
