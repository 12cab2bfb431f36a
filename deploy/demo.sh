#!/usr/bin/env bash
# The README's main job: installs, builds, then simulates a six-face calibration session,
# calibrates it, applies the result through the robot SDK and prints the error before and after.
set -euo pipefail
cd "$(dirname "$0")/.."
deploy/build.sh
./build/client/imucal demo --out-dir "${IMUCAL_DEMO_DIR:-out/demo}"
