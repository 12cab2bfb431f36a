#!/usr/bin/env bash
# The README's test command: installs, builds, runs every test (ctest, both cores).
set -euo pipefail
cd "$(dirname "$0")/.."
deploy/build.sh
ctest --test-dir build -j "$(nproc)" --output-on-failure --timeout 900
