#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# The main job from a fresh clone: installs the packages, builds iwlomap (Release), generates the
# bundled default input (a synthetic lidar scan of a courtyard) and maps it. Results go to out/:
#   out/scan.pcd       the input scan (sensor origin in VIEWPOINT)
#   out/occupied.pcd   the occupied voxels (centres, intensity = occupancy probability)
#   out/map.bt         the map as an OctoMap file (octovis, RViz, OctoMap's tools)
#   out/snapshot.png   a picture of the occupied voxels, rendered off screen
# Pass your own .pcd/.ply files to map them instead: scripts/demo.sh FILE... (same options as
# 'iwlomap map', e.g. --resolution 0.2 --sensor lidar --max-range 60).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
BUILD_DIR=build bash scripts/build.sh -DIWLOMAP_BUILD_TESTS=OFF >/dev/null
TOOL=build/samples/iwlomap
mkdir -p out
if [ $# -eq 0 ]; then
  "$TOOL" generate -o out/scan.pcd
  set -- out/scan.pcd --resolution 0.1 --sensor lidar
fi
# The snapshot is rendered off screen; VTK needs an X server, so a virtual one is used when
# there is no display.
# The snapshot needs no screen: without $DISPLAY the renderer starts its own Xvfb.
"$TOOL" map "$@" -o out/occupied.pcd --octomap out/map.bt --snapshot out/snapshot.png
"$TOOL" info out/occupied.pcd
