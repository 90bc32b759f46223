#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# The whole test suite from a fresh clone: installs the packages, builds everything (Release) and
# runs every test under a virtual X server (the render tests need one). With CI=true, or with
# --sanitize, it also builds and runs the suite with AddressSanitizer + UBSan (the tool included),
# runs each fuzz target for 20 s (scripts/fuzz.sh), and runs the tests of the threaded code
# (background jobs, the asynchronous and the registered mapper, multi-threaded scans) with
# ThreadSanitizer.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh

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

BUILD_DIR=build-test bash scripts/build.sh -DIWLOMAP_BUILD_TESTS=ON -DIWLOMAP_BUILD_BENCHMARKS=ON
(cd build-test && "${XVFB[@]}" ctest --output-on-failure -j 2)
echo "== API reference (zero Doxygen warnings) =="
bash scripts/docs.sh

if [ "$SANITIZE" = 1 ]; then
  echo "== AddressSanitizer + UndefinedBehaviorSanitizer build =="
  # The tool too: its tests feed it malformed files and hostile option values.
  BUILD_DIR=build-asan BUILD_TYPE=RelWithDebInfo bash scripts/build.sh -DIWLOMAP_BUILD_TESTS=ON \
    -DIWLOMAP_SANITIZE=ON -DIWLOMAP_WITH_VIEWER=OFF
  (cd build-asan && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 \
    ctest --output-on-failure -j 2 -E "Consumer")
  echo "== Fuzz targets, a short run of each (long runs: docs/reliability.md) =="
  bash scripts/fuzz.sh 20
  echo "== ThreadSanitizer build (threaded code) =="
  # Without the PCL layer: PCL's io library loads OpenNI2, whose start-up code the sanitizer reports.
  BUILD_DIR=build-tsan BUILD_TYPE=RelWithDebInfo bash scripts/build.sh -DIWLOMAP_BUILD_TESTS=ON \
    -DIWLOMAP_TSAN=ON -DIWLOMAP_BUILD_SAMPLES=OFF -DIWLOMAP_WITH_VIEWER=OFF -DIWLOMAP_WITH_FILTERS=OFF
  (cd build-tsan && ctest --output-on-failure -j 2 -R "BackgroundJob|Optimizer|PoseGraphMapper.Terminate|AsyncMapper|Threads|RegisteredMapper|RegisteredSonarMapper.Same")
fi
