#!/usr/bin/env bash
# Configures and builds imucal into ./build (Release with debug info).
#   deploy/build.sh         everything: libraries, binaries, tests, benchmarks (deploy/test.sh)
#   deploy/build.sh --run   only what runs the service: imucald and imucal, with the packages
#                           they need (deploy/demo.sh; a bare machine builds a third of the tree)
# Switching between the two reconfigures ./build; objects already built are kept.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" = "--run" ]; then
  "$(pwd)/deploy/install-deps.sh" --run
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DIMUCAL_BUILD_TESTS=OFF \
    -DIMUCAL_BUILD_BENCH=OFF >/dev/null
  cmake --build build -j "$(nproc)" --target imucald imucal
else
  "$(pwd)/deploy/install-deps.sh"
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DIMUCAL_BUILD_TESTS=ON \
    -DIMUCAL_BUILD_BENCH=ON >/dev/null
  cmake --build build -j "$(nproc)"
fi
