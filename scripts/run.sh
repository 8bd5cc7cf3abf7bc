#!/usr/bin/env bash
# Runs the picking cell on this machine with the simulated backends: installs what is
# missing, builds what is not built, starts every service as a local process, runs a task
# with the live progress display, and leaves the output file, the score and the report in an
# output folder it names at the end. Ctrl-C stops everything.
#
#   scripts/run.sh                                   # pick_layout_1
#   scripts/run.sh --task data/apc2016/tasks/pick_layout_2.json --detectors 2
#   scripts/run.sh --time-scale 1                    # the arm at real speed
#   scripts/run.sh --client '/usr/bin/python3 clients/python/task_client.py \
#       --address {address} --task {task}'          # another client runs the task
#
# Options:
#   --task FILE       APC 2016 task file (default data/apc2016/tasks/pick_layout_1.json)
#   --stow            the stow task data/apc2016/tasks/stow_layout_1.json (a task file
#                     without a work order is a stow task)
#   --detectors N     detector replicas (default 1)
#   --time-scale X    how much faster than real time the simulated arm moves (default 10)
#   --seed N          layout seed of the simulator (default 7)
#   --settled         items dropped and settled by physics (stacked, leaning) instead of
#                     side by side (the simulator's layout_mode=settled)
#   --out DIR         output folder (default runs/<date-time>)
#   --no-install      do not install missing packages
#   --bin DIR         use the servers already built in DIR (nothing is installed or built)
#   --detector-budget-scale X  the detector's --time_budget_scale (default 1; more time
#                     for each detection on a loaded machine)
#   --orchestrator-flag F  pass F to picking-orchestrator (e.g. --pick.table=in_doubt;
#                     repeatable)
#   --viewer-port N   serve the live view of the task on this port (default: a free one;
#                     run.sh prints the page's address)
#   --client CMD      run CMD (a shell command) instead of `picking run TASK`, with {address}
#                     replaced by the orchestrator's HOST:PORT, {task} by the task file's
#                     path, {out} by the output folder and {viewer} by the page's
#                     http://HOST:PORT; its exit status is run.sh's
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

task=data/apc2016/tasks/pick_layout_1.json
detectors=1
time_scale=10
seed=7
layout_mode=tidy
out=""
install=1
bin=""
budget_scale=1
client=""
orch_flags=()
viewer_port=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --task) task=$2; shift 2 ;;
    --stow) task=data/apc2016/tasks/stow_layout_1.json; shift ;;
    --detectors) detectors=$2; shift 2 ;;
    --time-scale) time_scale=$2; shift 2 ;;
    --seed) seed=$2; shift 2 ;;
    --settled) layout_mode=settled; shift ;;
    --out) out=$2; shift 2 ;;
    --no-install) install=0; shift ;;
    --bin) bin=$2; install=0; shift 2 ;;
    --detector-budget-scale) budget_scale=$2; shift 2 ;;
    --client) client=$2; shift 2 ;;
    --viewer-port) viewer_port=$2; shift 2 ;;
    --orchestrator-flag) orch_flags+=("$2"); shift 2 ;;
    -h|--help) awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "$0"; exit 0 ;;
    *) echo "run.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
[[ -r "$task" ]] || { echo "run.sh: cannot read task file $task" >&2; exit 2; }
[[ "$detectors" =~ ^[1-9][0-9]*$ ]] || { echo "run.sh: --detectors must be >= 1" >&2; exit 2; }
[[ -z "$viewer_port" || "$viewer_port" =~ ^[1-9][0-9]*$ ]] || {
  echo "run.sh: --viewer-port must be a port number" >&2; exit 2; }
[[ -z "$bin" || -x "$bin/picking-orchestrator" ]] || {
  echo "run.sh: no picking-orchestrator in --bin $bin" >&2; exit 2; }

task=$(realpath "$task")
out=${out:-runs/$(date +%Y%m%d-%H%M%S)}
mkdir -p "$out/logs"
out=$(realpath "$out")

if [[ $install == 1 ]]; then scripts/install-deps.sh; fi
if [[ -z "$bin" ]]; then
  build_dir=${BUILD_DIR:-build}
  export CCACHE_DIR=${CCACHE_DIR:-$HOME/.cache/ccache}
  targets=(picking picking-simulator picking-robot picking-gripper picking-scanner
           picking-detector picking-planner picking-orchestrator picking-viewer)
  if [[ ! -f "$build_dir/build.ninja" ]]; then
    cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release \
      ${CMAKE_ARGS:-} > "$out/logs/cmake.log"
  fi
  echo "building the servers (a second run reuses the build) ..."
  cmake --build "$build_dir" -j "$(nproc)" --target "${targets[@]}" > "$out/logs/build.log" || {
    tail -30 "$out/logs/build.log" >&2; exit 1; }
  bin=$root/$build_dir/bin
fi
bin=$(realpath "$bin")

pids=()
client_pid=""
cleanup() {
  trap - INT TERM EXIT
  # The client pipeline first (a signal sent to run.sh alone does not reach it).
  if [[ -n $client_pid ]]; then
    pkill -TERM -P "$client_pid" 2>/dev/null || true
    kill -TERM "$client_pid" 2>/dev/null || true
  fi
  if [[ ${#pids[@]} -gt 0 ]]; then
    echo "stopping the services ..."
    kill -TERM "${pids[@]}" 2>/dev/null || true
    # Each server stops within its shutdown grace; anything left after that is killed.
    for _ in $(seq 100); do
      alive=0
      for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && alive=1; done
      [[ $alive == 0 ]] && break
      sleep 0.1
    done
    kill -KILL "${pids[@]}" 2>/dev/null || true
    wait 2>/dev/null || true
  fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# A free TCP port on this machine (the kernel's pick, released at once for the server).
free_port() {
  /usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# Starts a server on a free port; its address lands in the variable named by $1.
start() {
  local var=$1 name=$2; shift 2
  local log=$out/logs/$name.log
  "$bin/$@" --listen=127.0.0.1:0 > "$log.stdout" 2> "$log" &
  pids+=($!)
  for _ in $(seq 3000); do
    # The whole line: HOST:PORT and its end (a line read while still being written is not).
    if grep -Eq '^listening on .+:[0-9]+$' "$log.stdout" 2>/dev/null; then
      printf -v "$var" '%s' "$(sed -n 's/^listening on //p' "$log.stdout" | head -1)"
      echo "  $name on ${!var}"
      return
    fi
    kill -0 "${pids[-1]}" 2>/dev/null || { echo "run.sh: $name did not start:" >&2; tail -5 "$log" >&2; exit 1; }
    sleep 0.1
  done
  echo "run.sh: $name did not start within 300 s (see $log)" >&2
  exit 1
}

echo "starting the cell (logs in $out/logs):"
start sim simulator picking-simulator --layout="$task" --seed="$seed" --layout_mode="$layout_mode"
start robot robot picking-robot --backend=sim --sim.address="$sim" --sim.time_scale="$time_scale"
start gripper gripper picking-gripper --backend=sim --sim.address="$sim"
start scanner scanner picking-scanner --sim.address="$sim" --calibration.dir="$out/calibration"
detector_list=""
for i in $(seq "$detectors"); do
  start det "detector-$i" picking-detector --cache_dir="$bin/../detector-cache" \
    --time_budget_scale="$budget_scale"
  detector_list=${detector_list:+$detector_list,}$det
done
start planner planner picking-planner
# The viewer's page port is chosen first: the orchestrator's report links to the page.
viewer_port=${viewer_port:-$(free_port)}
viewer_url=http://127.0.0.1:$viewer_port/
start orch orchestrator picking-orchestrator --tasks_dir="$out/tasks" \
  --scanner.address="$scanner" --detector.endpoints="$detector_list" \
  --planner.address="$planner" --robot.address="$robot" --gripper.address="$gripper" \
  --viewer.url="$viewer_url" "${orch_flags[@]}"
start viewer_grpc viewer picking-viewer --http_listen="127.0.0.1:$viewer_port" \
  --orchestrator.address="$orch" --robot.address="$robot"
echo
echo "watch the task in a browser: $viewer_url"
echo

status=0
if [[ -n "$client" ]]; then
  # The placeholders are replaced as plain text: paths and the address hold no spaces.
  command=${client//\{address\}/$orch}
  command=${command//\{task\}/$task}
  command=${command//\{out\}/$out}
  command=${command//\{viewer\}/${viewer_url%/}}
  run_client() { bash -c "$command" | tee "$out/progress.txt"; }
else
  # --out: output.json, score.txt and task.json from the orchestrator's answer.
  run_client() { "$bin/picking" run "$task" --address "$orch" --out "$out" | tee "$out/progress.txt"; }
fi
# In the background and waited for: bash runs a trap (Ctrl-C, SIGTERM) only once a foreground
# command ends, but interrupts `wait` at once.
run_client &
client_pid=$!
wait "$client_pid" || status=$?
client_pid=""
# What really happened in the simulated cell, to hold the output file against.
"$bin/picking" call "$sim" picking.simulator.v1.SimulatorService/GetGroundTruth \
  > "$out/truth.json" 2>/dev/null || rm -f "$out/truth.json"
task_dir=$(ls -d "$out"/tasks/task-* 2>/dev/null | tail -1)
if [[ -n "$task_dir" ]]; then
  cp "$task_dir/output.json" "$task_dir/report.html" "$task_dir/report.json" "$out/" 2>/dev/null || true
fi
echo
echo "output folder: $out"
echo "  output.json (the APC output file), score.txt (the score line by line), report.html and"
echo "  report.json (per item: method, grasp, attempts, times, score), truth.json (the simulated"
echo "  cell's ground truth at the end), logs/ (every server's log)"
exit $status
