#!/usr/bin/env bash
# Prints the Debian packages that hold the shared libraries the given executables load, one
# per line: the runtime image installs exactly these instead of the -dev packages the build
# needs (a fraction of the size).
#
#   deploy/docker/runtime-packages.sh build/bin/picking-*
set -euo pipefail
[[ $# -gt 0 ]] || { echo "usage: runtime-packages.sh EXECUTABLE..." >&2; exit 2; }
libs=$(ldd "$@" 2>/dev/null | awk '$2 == "=>" && $3 ~ /^\// { print $3 }' | sort -u)
[[ -n "$libs" ]] || { echo "runtime-packages.sh: no shared libraries found in $*" >&2; exit 1; }
missing=$(ldd "$@" 2>/dev/null | awk '/not found/ { print $1 }' | sort -u)
[[ -z "$missing" ]] || { echo "runtime-packages.sh: unresolved libraries: $missing" >&2; exit 1; }
{
# Files a server reads that no library pulls in: the viewer serves Debian's three.js.
for exe in "$@"; do
  [[ $(basename "$exe") == picking-viewer ]] && echo libjs-three
done
for lib in $libs; do
  # Debian 12 merges /lib into /usr/lib; dpkg records a library under either path.
  real=$(readlink -f "$lib")
  for path in "$lib" "$real" "${real#/usr}" "/usr${lib#/usr}"; do
    if owner=$(dpkg -S "$path" 2>/dev/null); then
      echo "${owner%%:*}"
      continue 2
    fi
  done
  echo "runtime-packages.sh: no package holds $lib" >&2
  exit 1
done
} | sort -u
