#!/usr/bin/env bash
# Brings the picking cell up with docker-compose.yml under podman, runs a short pick task
# through the compose file's one-shot `task` service, checks the results it wrote, and tears
# everything down (also on failure).
#
#   tests/compose/compose_test.sh BUILD_DIR
#
# The runtime image is made from BUILD_DIR's binaries; the base image debian:bookworm-slim is
# made with debootstrap when podman does not have it (no registry is reachable here).
set -euo pipefail
build=$(realpath "${1:?usage: compose_test.sh BUILD_DIR}")
here=$(cd "$(dirname "$0")" && pwd)
top=$(cd "$here/../.." && pwd)
work=$(mktemp -d /tmp/picking-compose.XXXXXX)
project=picking-test-$$
log() { echo "[compose_test $(date +%H:%M:%S)] $*"; }

# --- podman, as this kind of machine runs it: runc, fixed ulimits, netavark ---------------
export CONTAINERS_CONF=$here/containers.conf
need=()
for p in podman runc netavark aardvark-dns iptables debootstrap docker-compose podman-compose; do
  dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
done
if [[ ${#need[@]} -gt 0 ]]; then
  log "installing ${need[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi
if ! podman info >/dev/null 2>&1; then
  echo "compose_test: podman cannot run on this machine:" >&2
  podman info 2>&1 | tail -3 >&2
  exit 1
fi
# Inside an unprivileged container (a CI runner that is itself a container) podman answers
# but cannot start containers: say so rather than fail somewhere later.
if podman image exists localhost/debian:bookworm-slim &&
   ! podman run --rm --network host localhost/debian:bookworm-slim true >"$work/probe.log" 2>&1; then
  echo "compose_test: this machine cannot start containers: $(tail -1 "$work/probe.log")" >&2
  echo "compose_test: (exclude the test with CTEST_ARGS='-LE containers' on such a machine)" >&2
  exit 1
fi
if ! podman image exists localhost/debian:bookworm-slim; then
  log "making the base image debian:bookworm-slim with debootstrap"
  root=$work/rootfs
  debootstrap --variant=minbase bookworm "$root" >"$work/debootstrap.log" 2>&1 || {
    tail -5 "$work/debootstrap.log" >&2; exit 1; }
  tar -C "$root" -c . | podman import - localhost/debian:bookworm-slim >/dev/null
  rm -rf "$root"
fi

# --- the runtime image from this build's binaries -----------------------------------------
log "staging the image context from $build/bin"
"$top/deploy/docker/stage-prebuilt.sh" "$build" "$work/context"
log "building localhost/picking:latest"
podman build --network host -q -f "$top/deploy/docker/Dockerfile.prebuilt" \
  -t localhost/picking:latest "$work/context" >"$work/image-build.log" 2>&1 || {
  tail -20 "$work/image-build.log" >&2; exit 1; }
log "image size: $(podman image inspect localhost/picking:latest --format '{{.Size}}' |
  awk '{ printf "%.0f MB", $1 / 1e6 }')"

# --- docker-compose through podman's Docker-compatible socket -----------------------------
sock=$work/podman.sock
podman system service --time=0 "unix://$sock" >"$work/podman-service.log" 2>&1 &
service_pid=$!
export DOCKER_HOST=unix://$sock
for _ in $(seq 100); do [[ -S $sock ]] && break; sleep 0.1; done
# podman-compose reads the same file: the commands it would run give three detector
# replicas under the one network alias and every server its health check (the simulator,
# robot, gripper, scanner, three detectors, planner, orchestrator and viewer: 10).
dry=$(cd "$top" && podman-compose -p "$project-dry" --dry-run up -d 2>/dev/null | grep '^podman run')
# (its dry run still creates the named volumes)
podman volume ls -q | grep "^$project-dry_" | xargs -r podman volume rm >/dev/null
[[ $(grep -c -- '--network-alias detector ' <<<"$dry") == 3 ]] || {
  echo "compose_test: podman-compose would not start three detector replicas" >&2; exit 1; }
[[ $(grep -c -- '--healthcheck-command' <<<"$dry") == 10 ]] || {
  echo "compose_test: podman-compose would not give every server its health check" >&2; exit 1; }

files=(-f "$top/docker-compose.yml")
compose() { docker-compose --project-directory "$top" "${files[@]}" -p "$project" "$@"; }
teardown() {
  set +e
  if [[ -n ${keep_logs:-} ]]; then compose logs --no-color >"$work/compose.log" 2>&1; fi
  compose down -v --timeout 15 >/dev/null 2>&1
  kill "$service_pid" 2>/dev/null
  wait "$service_pid" 2>/dev/null
  if [[ -n ${keep_logs:-} ]]; then
    echo "compose_test: logs of every service:" >&2
    tail -n 60 "$work/compose.log" >&2
  fi
  rm -rf "$work"
}
trap teardown EXIT

# A short task: pick_layout_1's contents with a work order of one item, written where the
# task container sees it (its results folder).
make_task() {
  /usr/bin/python3 - "$top/data/apc2016/tasks/pick_layout_1.json" "$1" <<'PY'
import json, sys
task = json.load(open(sys.argv[1]))
task["work_order"] = [w for w in task["work_order"] if w["item"] == "kleenex_tissue_box"]
json.dump(task, open(sys.argv[2], "w"), indent=1)
PY
}

# Every server's health check, asked until it passes (without systemd, podman runs them only
# when asked).
wait_healthy() {
  local service id ok
  for service in simulator robot gripper scanner detector planner orchestrator viewer; do
    for id in $(compose ps -q "$service"); do
      ok=0
      for _ in $(seq 120); do
        if podman healthcheck run "$id" >/dev/null 2>&1; then ok=1; break; fi
        sleep 1
      done
      [[ $ok == 1 ]] || { echo "compose_test: $service ($id) never became healthy" >&2; exit 1; }
    done
  done
}

# The results the task service wrote: the output file, the score and the final state.
check_results() {
  /usr/bin/python3 - "$1" <<'PY'
import json, os, sys
out = sys.argv[1]
output = json.load(open(os.path.join(out, "output.json")))
assert set(output) >= {"bin_contents", "tote_contents"}, output.keys()
task = json.load(open(os.path.join(out, "task.json")))
assert task["state"] == "succeeded", task["state"]
score = open(os.path.join(out, "score.txt")).read().splitlines()
assert score and score[-1].endswith("\ttotal"), score
print("compose_test: task %s %s, score %s, %d items in the tote" %
      (task["task_id"], task["state"], score[-1].split("\t")[0], len(output["tote_contents"])))
PY
}

# The viewer, published on the host, shows the finished task through the orchestrator (over
# mutual TLS in the second run) with its score, and serves its page.
check_viewer() {
  /usr/bin/python3 - "$1" "$out" <<'PY'
import json, os, sys, time, urllib.request
viewer, out = sys.argv[1], sys.argv[2]
task = json.load(open(os.path.join(out, "task.json")))
view = None
for _ in range(120):
    try:
        view = json.load(urllib.request.urlopen(viewer + "/api/view", timeout=5))
        if view["task"] and view["task"]["state"] == "succeeded":
            break
    except OSError:
        pass
    time.sleep(1)
assert view and view["task"] and view["task"]["state"] == "succeeded", view and view["status"]
assert view["task"]["task_id"] == task["task_id"], (view["task"]["task_id"], task["task_id"])
assert view["status"]["robot"] == "connected", view["status"]
page = urllib.request.urlopen(viewer + "/", timeout=5).read().decode()
assert "viewer.js" in page
urllib.request.urlopen(viewer + "/three/three.min.js", timeout=5).read()
print("compose_test: the viewer shows task %s %s, score %d" %
      (view["task"]["task_id"], view["task"]["state"], view["task"]["score"]))
PY
}

# Brings the cell up with the compose files in `files`, runs the short task through the task
# service, checks its results and that detection reached more than one replica, tears down.
run_cell() {
  local name=$1
  out=$work/out-$name
  mkdir -p "$out"
  make_task "$out/short_task.json"
  export PICKING_OUT=$out PICKING_TASK=/out/short_task.json PICKING_DETECTOR_BUDGET_SCALE=10
  PICKING_VIEWER_PORT=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  export PICKING_VIEWER_PORT
  log "$name: docker-compose up"
  keep_logs=1
  compose up -d --no-build >"$work/up.log" 2>&1 || { cat "$work/up.log" >&2; exit 1; }
  local task_container detectors status serving id
  task_container=$(compose ps -q task)
  [[ -n $task_container ]] || { echo "compose_test: no task container" >&2; exit 1; }
  detectors=$(compose ps -q detector | wc -l)
  [[ $detectors == 3 ]] || { echo "compose_test: $detectors detector replicas, expected 3" >&2; exit 1; }
  log "$name: waiting for every server's health check"
  wait_healthy
  if [[ $name == mutual-tls ]]; then
    # A client without a certificate is refused (exit status 3), one with it is served.
    id=$(compose ps -q orchestrator)
    if podman exec "$id" picking list --address 127.0.0.1:50051 >/dev/null 2>&1; then
      echo "compose_test: the orchestrator served a client without a certificate" >&2; exit 1
    fi
    podman exec "$id" picking list --address 127.0.0.1:50051 --tls-ca /certs/ca.pem \
      --tls-cert /certs/orchestrator.pem --tls-key /certs/orchestrator.key >/dev/null || {
      echo "compose_test: the orchestrator refused a client with its certificate" >&2; exit 1; }
  fi
  log "$name: every server is healthy; waiting for the task"
  status=$(timeout 1500 podman wait "$task_container") || {
    echo "compose_test: the task did not end within 25 min" >&2; exit 1; }
  podman logs "$task_container" 2>&1 | tail -n 6
  [[ $status == 0 ]] || { echo "compose_test: the task service exited with $status" >&2; exit 1; }
  check_results "$out"
  check_viewer "http://127.0.0.1:$PICKING_VIEWER_PORT"
  # Detection went through the one name "detector" to more than one replica (round_robin).
  serving=0
  for id in $(compose ps -q detector); do
    if podman logs "$id" 2>&1 | grep -q 'DetectorService/\(Detect\|Verify\)'; then
      serving=$((serving + 1))
    fi
  done
  log "$name: $serving of 3 detector replicas served detection calls"
  [[ $serving -ge 2 ]] || { echo "compose_test: the calls were not spread over the replicas" >&2; exit 1; }
  keep_logs=
  compose down -v --timeout 15 >/dev/null 2>&1
}

run_cell plaintext

# The same cell with mutual TLS (deploy/compose/tls.yml): certificates made now, the keys
# readable by the image's user; every server refuses a client without a certificate.
export PICKING_CERTS=$work/certs
"$top/scripts/make-certs.sh" "$PICKING_CERTS" >/dev/null
chown 10001 "$PICKING_CERTS"/*.key
files+=(-f "$top/deploy/compose/tls.yml")
run_cell mutual-tls
log "passed"
