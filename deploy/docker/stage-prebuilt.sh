#!/usr/bin/env bash
# Fills the build context of Dockerfile.prebuilt from a build folder: the stripped server
# binaries and CLI, the bundled data, and the list of runtime packages they need.
#
#   deploy/docker/stage-prebuilt.sh BUILD_DIR CONTEXT_DIR
set -euo pipefail
build=${1:?usage: stage-prebuilt.sh BUILD_DIR CONTEXT_DIR}
context=${2:?usage: stage-prebuilt.sh BUILD_DIR CONTEXT_DIR}
here=$(cd "$(dirname "$0")" && pwd)
top=$(cd "$here/../.." && pwd)
rm -rf "$context"
mkdir -p "$context/bin"
for exe in "$build"/bin/picking "$build"/bin/picking-*; do
  [[ -x "$exe" && -f "$exe" ]] || continue
  strip -o "$context/bin/$(basename "$exe")" "$exe"
done
[[ -x "$context/bin/picking-orchestrator" ]] || {
  echo "stage-prebuilt.sh: no server binaries in $build/bin (build first)" >&2; exit 1; }
cp -r "$top/data" "$context/data"
cp "$here/install-runtime.sh" "$context/"
"$here/runtime-packages.sh" "$context"/bin/* > "$context/runtime-packages.txt"
