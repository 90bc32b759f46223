#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# Builds the libFuzzer targets of tests/fuzz with Clang (ASan + UBSan) into build-fuzz and runs
# each for SECONDS (default 20, the test command's short run), as many at once as there are cores
# (FUZZ_JOBS=N changes it). The corpus of each target grows in build-fuzz/corpus/TARGET between
# runs (seeded by fuzz_make_seeds); a crash, a hang (10 s per input) or an allocation over 1 GiB
# stops the run, leaves the input in build-fuzz/findings/ and fails the script. Long runs: scripts/fuzz.sh 3600 (see docs/reliability.md).
# FUZZ_BUILD_DIR=DIR uses DIR instead of build-fuzz; a DIR configured with IWLOMAP_BUILD_FUZZERS=ON
# already (the test command's sanitizer build) is used as it is configured.
# usage: scripts/fuzz.sh [SECONDS] [TARGET...]   (targets: fuzz_cloud fuzz_tile fuzz_manifest fuzz_oculus)
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in
  -h|--help) sed -n '3,10p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
esac
SECONDS_EACH=${1:-20}
[[ "$SECONDS_EACH" =~ ^[1-9][0-9]*$ ]] || { echo "fuzz.sh: SECONDS must be a positive integer, got '$SECONDS_EACH'" >&2; exit 2; }
shift || true
TARGETS=("$@")
[ ${#TARGETS[@]} -gt 0 ] || TARGETS=(fuzz_cloud fuzz_tile fuzz_manifest fuzz_oculus)
BUILD=${FUZZ_BUILD_DIR:-build-fuzz}

bash scripts/setup.sh
source scripts/ccache.sh
if ! grep -q '^IWLOMAP_BUILD_FUZZERS:BOOL=ON' "$BUILD/CMakeCache.txt" 2>/dev/null; then
  CC=clang CXX=clang++ cmake -S . -B "$BUILD" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DIWLOMAP_BUILD_FUZZERS=ON \
    -DIWLOMAP_BUILD_TESTS=OFF -DIWLOMAP_BUILD_SAMPLES=OFF -DIWLOMAP_BUILD_EXAMPLES=OFF \
    -DIWLOMAP_WITH_VIEWER=OFF -DIWLOMAP_WITH_OCTOMAP=OFF -DIWLOMAP_WITH_FILTERS=OFF "${CCACHE_ARGS[@]}" >/dev/null
fi
cmake --build "$BUILD" -j "${JOBS:-$(nproc)}" --target fuzz_make_seeds "${TARGETS[@]}"
"$BUILD/tests/fuzz/fuzz_make_seeds" "$BUILD/corpus"

# Runs target $1 (one thread); its summary line goes to findings/$1.result. Fails on a finding.
fuzz_one() {
  local t=$1 result ok=0
  mkdir -p "$BUILD/findings/$t"
  local log="$BUILD/findings/$t.log"
  if "$BUILD/tests/fuzz/$t" "$BUILD/corpus/$t" -max_total_time="$SECONDS_EACH" -timeout=10 \
      -rss_limit_mb=2560 -malloc_limit_mb=1024 -print_final_stats=1 \
      -artifact_prefix="$BUILD/findings/$t/" >"$log" 2>&1; then
    result="no crash"
  else
    result="FAILED (input in $BUILD/findings/$t/, log $log)"
    ok=1
  fi
  local runs files bytes
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  files=$(find "$BUILD/corpus/$t" -type f | wc -l)
  bytes=$(du -sb "$BUILD/corpus/$t" | cut -f1)
  echo "$t: ${runs:-?} executions in ${SECONDS_EACH} s, corpus $files files ($bytes bytes): $result" \
    >"$BUILD/findings/$t.result"
  return $ok
}

# Each target is single-threaded: they run side by side, as many at a time as there are cores
# (FUZZ_JOBS), each for its full SECONDS.
PARALLEL=${FUZZ_JOBS:-$(nproc)}
status=0
running=()
for t in "${TARGETS[@]}"; do
  fuzz_one "$t" &
  running+=($!)
  if [ ${#running[@]} -ge "$PARALLEL" ]; then
    wait "${running[0]}" || status=1
    running=("${running[@]:1}")
  fi
done
for pid in "${running[@]}"; do wait "$pid" || status=1; done
for t in "${TARGETS[@]}"; do
  cat "$BUILD/findings/$t.result"
  grep -q "no crash$" "$BUILD/findings/$t.result" || tail -40 "$BUILD/findings/$t.log" >&2
done
exit $status
