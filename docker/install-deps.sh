#!/usr/bin/env bash
# Installs every build, test and benchmark dependency of hapticpd from Debian
# bookworm packages. Idempotent: packages already present are left alone and
# `apt-get update` runs once, only when something is missing.
# Runs as root, or through sudo when not root. Never reads standard input.
set -euo pipefail

PACKAGES=(
  build-essential cmake ninja-build ccache pkg-config git
  libgrpc++-dev libgrpc-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  python3-grpcio python3-protobuf  # client/python (the Python client) and its tests
  libeigen3-dev libopenmesh-dev libspdlog-dev libfmt-dev
  libgtest-dev libgmock-dev libbenchmark-dev libcli11-dev nlohmann-json3-dev
  libsqlite3-dev libssl-dev  # the server's state directory (server/store.h)
  libfcl-dev libccd-dev libbullet-dev  # the test oracles and hapticpd-bench (peers, accuracy, cold); not hapticpd
  clang libclang-rt-14-dev  # the `fuzz` preset: clang and its libFuzzer/ASan runtimes
  libboost-dev libjs-three  # `hapticpd view`: Boost.Beast (HTTP + WebSocket) and three.js for its page
  chromium-headless-shell   # tests/browser (label `browser`) and tests/bench/bench_view.mjs
  haproxy                   # tests/scale (label `scale`): the balancer of docker/haproxy.cfg
  docker-compose            # tests/deploy: `docker-compose config` of docker/compose.yaml (no engine)
)

# Node.js and npm for tests/browser (puppeteer-core, `npm ci` at build time):
# Debian's nodejs and npm only where no `node` is installed. A node from
# elsewhere (e.g. NodeSource) brings its own npm, and Debian's npm package
# conflicts with it.
if ! command -v node >/dev/null 2>&1; then
  PACKAGES+=(nodejs npm)
elif ! command -v npm >/dev/null 2>&1; then
  PACKAGES+=(npm)
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "install-deps.sh: not root and sudo is not available; run it as root" >&2
    exit 1
  fi
fi

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps.sh: all ${#PACKAGES[@]} packages already installed"
  exit 0
fi

echo "install-deps.sh: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}" </dev/null
