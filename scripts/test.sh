#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# The whole test suite from a fresh clone: installs the packages, builds everything (Release) and
# runs every test under a virtual X server (the render tests need one). With CI=true, or with
# --sanitize, it also builds the suite with Clang, AddressSanitizer + UBSan and libFuzzer's
# coverage in one build (the tool and the fuzz targets included), runs the tests there and each
# fuzz target for 20 s (scripts/fuzz.sh), and runs the tests of the threaded code (background
# jobs, the asynchronous and the registered mappers, multi-threaded scans) with ThreadSanitizer.
# Compiles through ccache (scripts/ccache.sh): a clone in any folder reuses what any clone built.
# Prints each stage's time at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/ccache.sh

SANITIZE=0
[ "${CI:-}" = "true" ] && SANITIZE=1
for a in "$@"; do
  case "$a" in
    --sanitize) SANITIZE=1 ;;
    --no-sanitize) SANITIZE=0 ;;
    -h|--help) echo "usage: scripts/test.sh [--sanitize|--no-sanitize]"; exit 0 ;;
    *) echo "test.sh: unknown option $a" >&2; exit 2 ;;
  esac
done

XVFB=(xvfb-run -a -s "-screen 0 1280x1024x24 -noreset")
# The sanitizer builds keep line tables only (-g1): enough for the sanitizers' stack traces, and
# much lighter to compile and link than full debug information.
SANITIZER_FLAGS=(-DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG")

# Each stage's wall time, printed as it ends and again at the end.
STAGES=()
stage_start() { echo "== $1 =="; STAGE_NAME=$1; STAGE_T0=$SECONDS; }
stage_end() {
  local t=$((SECONDS - STAGE_T0))
  STAGES+=("$(printf '%5d s  %s' "$t" "$STAGE_NAME")")
  echo "== $STAGE_NAME: $t s =="
}
report() {
  [ ${#STAGES[@]} -gt 0 ] || return 0
  echo "== stage times =="
  printf "%s\n" "${STAGES[@]}"
  echo "total $SECONDS s"
  if [ "$CCACHE_ON" = 1 ]; then
    ccache --print-stats 2>/dev/null | awk -F'\t' '$1 ~ /^(direct_cache_hit|preprocessed_cache_hit|cache_miss)$/ {n[$1]=$2}
      END {h=n["direct_cache_hit"]+n["preprocessed_cache_hit"]; printf "ccache: %d compiles from the cache, %d compiled\n", h, n["cache_miss"]}'
  fi
}
trap report EXIT
[ "$CCACHE_ON" = 1 ] && ccache --zero-stats >/dev/null

# The benchmarks the tests do not run stay out of the build (IWLOMAP_BENCHMARKS_IN_ALL=OFF).
stage_start "Release build (tests, samples, examples, the benchmarks the tests run)"
BUILD_DIR=build-test bash scripts/build.sh -DIWLOMAP_BUILD_TESTS=ON -DIWLOMAP_BUILD_BENCHMARKS=ON \
  -DIWLOMAP_BENCHMARKS_IN_ALL=OFF
stage_end
stage_start "Release tests"
(cd build-test && "${XVFB[@]}" ctest --output-on-failure -j 2)
stage_end
stage_start "API reference (zero Doxygen warnings)"
bash scripts/docs.sh
stage_end

if [ "$SANITIZE" = 1 ]; then
  stage_start "Clang build: AddressSanitizer + UBSan, the tests, the tool and the fuzz targets"
  # One build serves both: the library carries libFuzzer's coverage instrumentation, which the
  # tests do not use.
  CC=clang CXX=clang++ BUILD_DIR=build-asan-fuzz BUILD_TYPE=RelWithDebInfo bash scripts/build.sh \
    -DIWLOMAP_BUILD_TESTS=ON -DIWLOMAP_SANITIZE=ON -DIWLOMAP_BUILD_FUZZERS=ON -DIWLOMAP_WITH_VIEWER=OFF \
    "${SANITIZER_FLAGS[@]}"
  stage_end
  stage_start "AddressSanitizer + UBSan tests"
  # Not the consumer builds (they build iwlomap as its users do, in Release), and the registered
  # sonar mapper's mode comparison on 60 pings instead of the whole survey (the same code; the
  # whole survey runs in Release).
  (cd build-asan-fuzz && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 \
    ctest --output-on-failure -j 2 -E "Consumer|RegisteredSonarMapper.SameSubmapsAndMapInBothModes")
  stage_end
  stage_start "Fuzz targets, a short run of each (long runs: docs/reliability.md)"
  FUZZ_BUILD_DIR=build-asan-fuzz bash scripts/fuzz.sh 20
  stage_end
  stage_start "ThreadSanitizer build (the test programs of the threaded code)"
  # Without the PCL layer: PCL's io library loads OpenNI2, whose start-up code the sanitizer reports.
  # Only the programs holding the tests run below are built.
  cmake -S . -B build-tsan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DIWLOMAP_BUILD_TESTS=ON -DIWLOMAP_TSAN=ON \
    -DIWLOMAP_BUILD_SAMPLES=OFF -DIWLOMAP_WITH_VIEWER=OFF -DIWLOMAP_WITH_FILTERS=OFF "${SANITIZER_FLAGS[@]}" \
    "${CCACHE_ARGS[@]}"
  cmake --build build-tsan -j "${JOBS:-$(nproc)}" --target test_ram_scans test_background_job \
    test_optimizer test_outofcore_tile_mapper test_disk_commits test_internals test_scan_matcher test_registered_sonar_mapper \
    test_pose_graph_mapper test_backend_contract
  stage_end
  stage_start "ThreadSanitizer tests"
  (cd build-tsan && ctest --output-on-failure --no-tests=error -j 2 -R "BackgroundJob|Optimizer|PoseGraphMapper.Terminate|AsyncMapper|Threads|RegisteredMapper|RegisteredSonarMapper.SameInBothModesOnAShortRun")
  stage_end
fi
