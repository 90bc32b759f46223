#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# Configures and builds iwlomap into BUILD_DIR (default: build), Release, with everything on.
# Extra arguments go to the CMake configure step. Compiles through ccache when it is installed
# (IWLOMAP_CCACHE=0 turns it off; scripts/ccache.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/ccache.sh
BUILD_DIR=${BUILD_DIR:-build}
JOBS=${JOBS:-$(nproc)}
cmake -S . -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE="${BUILD_TYPE:-Release}" "${CCACHE_ARGS[@]}" "$@"
cmake --build "$BUILD_DIR" -j "$JOBS"
