#!/usr/bin/env bash
# Configures and builds imucal into ./build (Release with debug info). Usage: deploy/build.sh
set -euo pipefail
cd "$(dirname "$0")/.."
"$(pwd)/deploy/install-deps.sh"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build -j "$(nproc)"
