#!/usr/bin/env bash
# The one command that proves the project works on this machine: installs what is
# missing, configures a Release build (ccache when present), builds everything and runs
# every test.
#
#   scripts/test.sh            # all tests
#   BUILD_DIR=build-asan CMAKE_ARGS="-DPICKING_SANITIZE=address,undefined" scripts/test.sh
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/install-deps.sh

build_dir=${BUILD_DIR:-build}
jobs=${JOBS:-$(nproc)}
# ccache keeps its cache outside the checkout, so a clean clone still builds fast.
export CCACHE_DIR=${CCACHE_DIR:-$HOME/.cache/ccache}
export CCACHE_MAXSIZE=${CCACHE_MAXSIZE:-5G}

cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=${BUILD_TYPE:-Release} ${CMAKE_ARGS:-}
cmake --build "$build_dir" -j "$jobs"
scripts/check-format.sh
ctest --test-dir "$build_dir" --output-on-failure -j "$jobs" ${CTEST_ARGS:-}
