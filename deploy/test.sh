#!/usr/bin/env bash
# The README's test command: installs, builds, runs every test (ctest, both cores), then the
# robustness checks of docs/robustness.md:
#   1. ASan + UBSan (halt on the first error) in build-asan: every test but those labelled
#      `asan_skip` (the three slowest: accuracy twice, capture classes; and the SDK package check),
#      against the code that handles bytes, the store, the server and the clients instrumented
#      (CMakeLists.txt IMUCAL_SANITIZE; the rest is the plain tree's objects, from ccache);
#   2. the server and store tests under ThreadSanitizer in build-tsan;
#   3. each libFuzzer target (clang, from install-deps.sh) for FUZZ_SECONDS (default 20) from
#      its seed corpus; the fuzzers also run the still detector under ASan.
# IMUCAL_SANITIZERS=0 skips 1-3 (the plain tests only). Benchmarks are not built in 1-3.
# The trees share objects through ccache: paths are taken relative to the checkout, so the
# sanitizer trees' uninstrumented objects are the plain tree's (a cold run stays under an hour
# on 2 cores).
set -euo pipefail
cd "$(dirname "$0")/.."
root="$(pwd)"
jobs="$(nproc)"
export CCACHE_BASEDIR="$root" CCACHE_NOHASHDIR=1
step() { printf '\n== %s (%ds since start)\n' "$1" "$SECONDS"; }

step "build and test (build/)"
deploy/build.sh
ctest --test-dir build -j "$jobs" --output-on-failure --timeout 900

if [ "${IMUCAL_SANITIZERS:-1}" = "0" ]; then
  exit 0
fi
# 1. ASan + UBSan. The plain tree's flags (RelWithDebInfo) so the uninstrumented objects are its.
step "ASan+UBSan build and test (build-asan/)"
cmake -S . -B build-asan -G Ninja -DIMUCAL_BUILD_BENCH=OFF -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DIMUCAL_SANITIZE=address,undefined >/dev/null
cmake --build build-asan -j "$jobs"
ASAN_OPTIONS="halt_on_error=1:detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1" \
UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1" \
  ctest --test-dir build-asan -j "$jobs" --output-on-failure --timeout 1800 -LE '^asan_skip$'

# 2. TSan: the server tests (gRPC handlers, reactors, the hub, and the in-process servers of the
# auth, log and config tests) and the store's (its group-commit thread). Suppressions for
# third-party code only, documented in the file.
step "TSan build and server tests (build-tsan/)"
cmake -S . -B build-tsan -G Ninja -DIMUCAL_BUILD_BENCH=OFF -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DIMUCAL_SANITIZE=thread >/dev/null
cmake --build build-tsan -j "$jobs" --target server_test validation_test store_test sqlite_db_test \
  auth_matrix_test log_test config_test
TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$root/tests/tsan.supp" \
  ctest --test-dir build-tsan -j "$jobs" --output-on-failure --timeout 1800 \
  -R '^(ServerTest|ValidationTest|ParamCrcCacheTest|ActiveParamCacheTest|StatusUtilTest|StreamRegistryTest|StoreTest|BatchTest|SqliteDbTest|SqliteStatusTest|AuthRules|AuthTest|LogTest|RpcLogTest|ConfigTest)\.'

# 3. Fuzzers: each target for FUZZ_SECONDS from its seeds; a crash fails the run and leaves
# the input in build-fuzz/crashes/<target>/ (keep it in tests/fuzz/regressions/<target>/).
step "fuzzers (build-fuzz/)"
cmake -S . -B build-fuzz -G Ninja -DCMAKE_CXX_COMPILER=clang++ -DIMUCAL_BUILD_FUZZERS=ON \
  -DIMUCAL_BUILD_TESTS=OFF -DIMUCAL_BUILD_BENCH=OFF >/dev/null
cmake --build build-fuzz -j "$jobs" --target imucal_fuzzers
for target in capture_csv imutk columns euroc rosbag2_cdr rosbag2_metadata mcap sample_batch; do
  work="build-fuzz/runs/$target"
  rm -rf "$work"
  mkdir -p "$work" "build-fuzz/crashes/$target"
  "build-fuzz/tests/fuzz/fuzz_$target" -max_total_time="${FUZZ_SECONDS:-20}" -max_len=4096 \
    -print_final_stats=1 -artifact_prefix="build-fuzz/crashes/$target/" \
    "$work" "tests/fuzz/corpus/$target" >"$work.log" 2>&1 || {
    tail -40 "$work.log"
    echo "fuzz_$target found a crash: see build-fuzz/crashes/$target/" >&2
    exit 1
  }
  printf '%-16s %s\n' "$target" "$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$work.log")"
done
step "all tests, sanitizers and fuzzers passed"
