#!/usr/bin/env bash
# The runtime stage of both images: installs the packages listed in the given file (from
# runtime-packages.sh), and creates the unprivileged user the servers run as, with the
# folders they write (task journals, detector model caches, scanner calibrations).
set -euo pipefail
packages=${1:?usage: install-runtime.sh PACKAGES.txt}
apt-get update -qq
# shellcheck disable=SC2046
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(cat "$packages")
rm -rf /var/lib/apt/lists/* /var/cache/apt/archives/*.deb
useradd --uid 10001 --user-group --no-create-home --home-dir /var/lib/picking picking
install -d -o picking -g picking /var/lib/picking /var/lib/picking/tasks \
  /var/lib/picking/cache /var/lib/picking/calibration
