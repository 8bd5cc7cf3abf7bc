#!/usr/bin/env bash
# Installs every Debian 12 package that building and testing the picking system needs.
# Only missing packages are installed; nothing is asked. Run as root or with sudo.
set -euo pipefail

packages=(
  # toolchain
  build-essential cmake ninja-build pkg-config ccache git ca-certificates
  # RPC
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
  # TLS: the key and certificate checks (libssl-dev), certificates for tests (openssl)
  libssl-dev openssl
  # maths, vision, geometry, planning
  libeigen3-dev libopencv-dev libopencv-contrib-dev libpcl-dev liboctomap-dev libfcl-dev
  libembree-dev
  # rigid-body physics: the simulator's settled layouts (Bullet 3.24)
  libbullet-dev
  # cameras (GenICam through Aravis, and its fake GigE Vision camera for tests)
  libaravis-dev aravis-tools
  # configuration formats
  nlohmann-json3-dev libyaml-cpp-dev
  # the viewer: its HTTP server and three.js for its page
  libcpp-httplib-dev libjs-three
  # tests and benchmarks
  libgtest-dev libgmock-dev libbenchmark-dev
  # the peers the benchmarks compare against read their sample data from here
  opencv-doc
  # the Python client example and its test (Debian's python3, not a PATH-first build)
  python3 python3-grpcio python3-grpc-tools python3-pkg-resources
  # the offline check of the Kubernetes manifests (deploy/k8s/test/validate.py)
  python3-yaml python3-jsonschema
  # style check
  clang-format
)
# The browser the viewer's page test drives (headless, through the DevTools protocol); an
# image that only builds the servers leaves it out with PICKING_NO_BROWSER=1.
[[ ${PICKING_NO_BROWSER:-0} == 1 ]] || packages+=(chromium python3-websocket)
# The Node.js client example and its test. Only when missing: a Node.js from elsewhere
# (e.g. NodeSource's, which bundles npm) conflicts with Debian's npm package.
command -v node >/dev/null || packages+=(nodejs)
command -v npm >/dev/null || packages+=(npm)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps: need root or sudo to install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
echo "install-deps: installing ${#missing[@]} packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
