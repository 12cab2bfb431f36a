#!/usr/bin/env bash
# Installs the Debian packages imucal builds and runs with. Idempotent; works on a bare Debian 12
# machine (as root, or with sudo). Nothing is downloaded from outside Debian's archive.
#   install-deps.sh         what building and running everything needs, tests included
#   install-deps.sh --run   what building and running imucald and imucal needs (deploy/demo.sh)
set -euo pipefail
packages=(
  g++ cmake ninja-build pkg-config
  ccache  # the plain, sanitizer and fuzzer trees share objects; a repeat CI run is served from it
  libceres-dev libeigen3-dev libabsl-dev nlohmann-json3-dev libboost-math-dev
  libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler libsqlite3-dev
  libtomlplusplus-dev  # imucald's configuration file (TOML)
  libcli11-dev  # every executable's command-line flags (util/flags.h)
  libyaml-cpp-dev  # metadata.yaml of ROS 2 bags, the YAML exports
  libzstd-dev liblz4-dev zlib1g-dev  # MCAP chunks (zstd, LZ4 frame) and their CRC-32
  libpq-dev  # the PostgreSQL store (storage/pg_db.h)
  prometheus-cpp-dev  # imucald's Prometheus metrics (server/metrics.h)
  libmicrohttpd-dev  # the metrics' HTTP endpoint (server/metrics_http.h)
  libssl-dev openssl  # TLS and token hashing (libcrypto); the openssl CLI makes deploy/demo.sh's certificates
)
if [ "${1:-}" != "--run" ]; then
  packages+=(
    libgtest-dev libgmock-dev libbenchmark-dev tmux
    python3  # tests/tools: the independent ROS 2 bag and EuRoC writers (standard library only)
    clang libclang-rt-dev  # deploy/test.sh: libFuzzer targets (tests/fuzz)
    zsh  # tests: the zsh completion script is checked by zsh itself
    zstd lz4  # tests/tools/write_mcap.py compresses its chunks with the command-line tools
    librsvg2-bin  # tests: the SVG plots rendered to PNG (rsvg-convert)
    postgresql  # deploy/pg-throwaway.sh: the throwaway cluster the PostgreSQL tests run against
  )
fi
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"
echo "install-deps: installing ${missing[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
