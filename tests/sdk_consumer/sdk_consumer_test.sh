#!/usr/bin/env bash
# The SDK as a robot's own CMake project gets it: `cmake --install` of the SDK component into a
# fresh prefix, then tests/sdk_consumer configured against that prefix alone
# (find_package(imucal CONFIG)), built, and run on a parameter set that `imucal simulate --truth`
# wrote. Both consumers (imucal::sdk, and imucal::sdk_client booting from its cache with the
# server down) must print the samples `imucal apply` writes, number for number. The installed
# package must not reach core's compiled library, Ceres, or the source tree.
#   sdk_consumer_test.sh BUILD_DIR IMUCAL_BINARY [SANITIZERS]
set -euo pipefail
build="$(cd "$1" && pwd)"
imucal="$2"
sanitize="${3:-}"
here="$(cd "$(dirname "$0")" && pwd)"
src="$(cd "$here/../.." && pwd)"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
fail() { echo "sdk_consumer_test: $*" >&2; exit 1; }

# 1. Install the SDK component only (the libraries, headers and package config).
cmake --install "$build" --prefix "$tmp/prefix" --component sdk >"$tmp/install.log"
cfg="$tmp/prefix/lib/cmake/imucal"
[ -f "$cfg/imucalConfig.cmake" ] && [ -f "$cfg/imucalConfigVersion.cmake" ] ||
  fail "no package config in $cfg"
for h in client/sdk/corrector.h client/sdk/client.h core/correction.h core/params.h \
         formats/params_json.h util/units.h imucal/v1/imucal.grpc.pb.h; do
  [ -f "$tmp/prefix/include/$h" ] || fail "header $h not installed"
done
if ls "$tmp/prefix/lib" | grep -q 'imucal_core'; then fail "core's library installed with the SDK"; fi
if cat "$cfg"/*.cmake | grep -v '^ *#' | grep -qi 'ceres'; then
  fail "the package config links Ceres"
fi
if grep -q "$src\|$build" "$cfg"/*.cmake; then fail "the package config points into $src"; fi

# 2. A robot's project against that prefix alone.
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
link=()
[ -n "$sanitize" ] && link=("-DCMAKE_EXE_LINKER_FLAGS=-fsanitize=$sanitize")
cmake -S "$here" -B "$tmp/consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_PREFIX_PATH="$tmp/prefix" "${launcher[@]}" "${link[@]}" >"$tmp/configure.log" 2>&1 ||
  { cat "$tmp/configure.log"; fail "the consumer did not configure"; }
cmake --build "$tmp/consumer" >"$tmp/build.log" 2>&1 ||
  { cat "$tmp/build.log"; fail "the consumer did not build"; }

# 3. A parameter set with a temperature effect, a capture, and what `imucal apply` makes of it.
"$imucal" simulate --out "$tmp/capture.csv" --truth "$tmp/params.json" --seed 29 \
  --effect accel:y:temperature:0.005 --effect gyro:z:temperature:0.0002 >/dev/null
"$imucal" apply --params "$tmp/params.json" "$tmp/capture.csv" "$tmp/applied.csv" >/dev/null
# The capture's rows as `t ax ay az gx gy gz temp`, by column name.
python3 - "$tmp/capture.csv" >"$tmp/samples.txt" <<'PY'
import csv, sys
rows = [l for l in open(sys.argv[1]) if not l.startswith('#')]
for r in csv.DictReader(rows):
    print(*(r[k] for k in ('t', 'ax', 'ay', 'az', 'gx', 'gy', 'gz', 'temp')))
PY
"$tmp/consumer/apply_params" "$tmp/params.json" <"$tmp/samples.txt" >"$tmp/sdk.txt"
# Port 1 on loopback: nobody listens, so the robot boots from the cache it was given.
"$tmp/consumer/boot_from_cache" "$tmp/params.json" "$tmp/params.cache" 127.0.0.1:1 \
  <"$tmp/samples.txt" >"$tmp/client.txt" 2>"$tmp/client.err" ||
  { cat "$tmp/client.err"; fail "boot_from_cache failed"; }

# 4. Number for number: each consumer's samples against apply's CSV (to the digits it writes),
# and corrected: not the raw readings.
python3 - "$tmp/applied.csv" "$tmp/samples.txt" "$tmp/sdk.txt" "$tmp/client.txt" <<'PY'
import csv, sys
applied_path, raw_path = sys.argv[1], sys.argv[2]
keys = ('t', 'ax', 'ay', 'az', 'gx', 'gy', 'gz')
applied = [[r[k] for k in keys]
           for r in csv.DictReader(l for l in open(applied_path) if not l.startswith('#'))]
raw = [l.split()[:7] for l in open(raw_path)]
for path in sys.argv[3:]:
    got = [l.split() for l in open(path)]
    if len(got) != len(applied):
        sys.exit(f"{path}: {len(got)} samples, apply wrote {len(applied)}")
    worst = 0.0
    for i, (a, g) in enumerate(zip(applied, got)):
        for k, (text, value) in enumerate(zip(a, g)):
            digits = len(text.split('.')[1]) if '.' in text and 'e' not in text.lower() else 15
            tol = 0.51 * 10.0 ** -digits + 1e-12 * abs(float(text))
            err = abs(float(text) - float(value))
            if err > tol:
                sys.exit(f"{path}: sample {i} {keys[k]}: {value}, apply wrote {text}")
            worst = max(worst, err)
    moved = max(abs(float(g) - float(r)) for gr, rr in zip(got, raw) for g, r in zip(gr[1:], rr[1:]))
    if moved < 1e-3:
        sys.exit(f"{path}: the samples came out as they went in (largest change {moved})")
    print(f"{path.split('/')[-1]}: {len(got)} samples as `imucal apply` wrote them "
          f"(largest difference {worst:.2g}; largest correction {moved:.3g})")
PY
echo "sdk_consumer_test: the installed SDK, found by a robot's CMake project, applies as imucal apply"
