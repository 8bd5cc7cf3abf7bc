#!/usr/bin/env bash
# The end-to-end figures of the orchestrator: runs scripts/run.sh (every service a local
# process, the simulated cell) on pick_layout_1..3 and prints, per layout, the items picked
# as the output file reports them and as the simulator's ground truth has them, whether the
# output file matches the truth everywhere, the score (beside the perfect score), the task
# clock (robot time) and the wall time.
#
#   benchmarks/orchestrator/run_layouts.sh [--detectors N] [--bin DIR]
#       [--orchestrator-flag F]... [layouts...]
#
# Layouts default to 1 2 3. --bin DIR runs the servers already built in DIR (run.sh's --bin):
# copy build/bin there first to go on editing and building while the layouts run.
set -euo pipefail
cd "$(dirname "$0")/../.."
detectors=1
bin_args=()
layouts=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --detectors) detectors=$2; shift 2 ;;
    --bin) bin_args+=(--bin "$(cd "$2" && pwd)"); shift 2 ;;
    --orchestrator-flag) bin_args+=(--orchestrator-flag "$2"); shift 2 ;;
    *) layouts+=("$1"); shift ;;
  esac
done
[[ ${#layouts[@]} -gt 0 ]] || layouts=(1 2 3)
out=runs/bench-$(date +%Y%m%d-%H%M%S)
printf '%-8s %-8s %-8s %-7s %-7s %-13s %-10s\n' layout reported true "output" score "task clock" "wall"
for n in "${layouts[@]}"; do
  start=$(date +%s)
  scripts/run.sh --no-install --task "data/apc2016/tasks/pick_layout_$n.json" \
    --detectors "$detectors" "${bin_args[@]}" --out "$out/layout_$n" > "$out-layout_$n.log" 2>&1 || true
  wall=$(( $(date +%s) - start ))
  report=$out/layout_$n/report.json
  if [[ -f $report ]]; then
    python3 - "$report" "$n" "$wall" "$out/layout_$n" <<'PY'
import json, os, sys
r = json.load(open(sys.argv[1]))
folder = sys.argv[4]
picked = sum(1 for i in r["items"] if i["picked"])
true_picked, matches = "?", "?"
if os.path.exists(f"{folder}/truth.json") and os.path.exists(f"{folder}/output.json"):
    truth = json.load(open(f"{folder}/truth.json"))
    output = json.load(open(f"{folder}/output.json"))
    where = {}
    for state in truth.get("items", []):
        c = state.get("container", "CONTAINER_UNSPECIFIED")
        key = "tote" if c == "CONTAINER_TOTE" else (
            "bin_" + c[-1] if c.startswith("CONTAINER_BIN_") else c.lower())
        where.setdefault(key, []).append(state["item"]["name"])
    tote = sorted(where.get("tote", []))
    targets = [i["item"] for i in r["items"]]
    true_picked = sum(1 for t in set(targets) if t in tote)
    same = sorted(output["tote_contents"]) == tote and all(
        sorted(items) == sorted(where.get(b, [])) for b, items in output["bin_contents"].items())
    matches = "matches" if same else "WRONG"
print(f'{sys.argv[2]:<8} {picked:>2} / {len(r["items"]):<3} {true_picked!s:<8} {matches:<7} {r["score"]:<7} {r["duration_s"]:>6.0f} s      {sys.argv[3]} s')
PY
  else
    echo "$n        (no report: see $out-layout_$n.log)"
  fi
done
echo "reports: $out/layout_*/report.html"
