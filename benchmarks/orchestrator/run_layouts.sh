#!/usr/bin/env bash
# The end-to-end figures of the orchestrator: runs scripts/run.sh (every service a local
# process, the simulated cell) on pick_layout_1..3 and prints, per layout, the items picked,
# the score (beside the perfect score), the task clock (robot time) and the wall time.
#
#   benchmarks/orchestrator/run_layouts.sh [--detectors N] [layouts...]   # default: 1 2 3
set -euo pipefail
cd "$(dirname "$0")/../.."
detectors=1
layouts=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --detectors) detectors=$2; shift 2 ;;
    *) layouts+=("$1"); shift ;;
  esac
done
[[ ${#layouts[@]} -gt 0 ]] || layouts=(1 2 3)
out=runs/bench-$(date +%Y%m%d-%H%M%S)
printf '%-8s %-8s %-7s %-13s %-10s\n' layout picked score "task clock" "wall"
for n in "${layouts[@]}"; do
  start=$(date +%s)
  scripts/run.sh --no-install --task "data/apc2016/tasks/pick_layout_$n.json" \
    --detectors "$detectors" --out "$out/layout_$n" > "$out-layout_$n.log" 2>&1 || true
  wall=$(( $(date +%s) - start ))
  report=$out/layout_$n/report.json
  if [[ -f $report ]]; then
    python3 - "$report" "$n" "$wall" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
picked = sum(1 for i in r["items"] if i["picked"])
print(f'{sys.argv[2]:<8} {picked:>2} / {len(r["items"]):<3} {r["score"]:<7} {r["duration_s"]:>6.0f} s      {sys.argv[3]} s')
PY
  else
    echo "$n        (no report: see $out-layout_$n.log)"
  fi
done
echo "reports: $out/layout_*/report.html"
