#!/usr/bin/env python3
# SPDX-License-Identifier: BSD-3-Clause
"""A lidar map from Python: a cloud in, the occupied voxels, an OctoMap file and a few answers out.

    python3 examples/python_map.py [SCAN.pcd|SCAN.ply] OUT_DIR

Without a scan it maps iwlomap's synthetic courtyard scan. Run with the package on the path
(PYTHONPATH=build/python, or after `pip install .`). Exits non-zero when the map comes out empty.
"""

import os
import sys

import iwlomap


def main(argv):
    if len(argv) not in (2, 3):
        print(__doc__, file=sys.stderr)
        return 2
    out = argv[-1]
    os.makedirs(out, exist_ok=True)
    if len(argv) == 3:
        read = iwlomap.read_ply if argv[1].lower().endswith(".ply") else iwlomap.read_pcd
        cloud = read(argv[1])
        origin, points, intensities = cloud.origin, cloud.points, cloud.intensities  # None: all returns
    else:
        origin, points, intensities = iwlomap.make_synthetic_scan()

    m = iwlomap.ProbabilityUpdater(0.1)                                   # RAM map, 0.1 m voxels
    m.set_params(iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar))
    m.insert_scan(origin, points, intensities)                            # rays from the sensor

    occupied = m.get_occupied_voxels(m.get_params().occupied_threshold)   # (K, 4): x, y, z, p
    iwlomap.write_pcd(os.path.join(out, "occupied.pcd"), occupied[:, :3], occupied[:, 3])
    if iwlomap.HAS_OCTOMAP:
        iwlomap.export_octomap(m, os.path.join(out, "map.bt"))            # for octovis and RViz

    # Where the returns landed, asked all at once: how many are occupied voxels now?
    states = m.query(points)
    hit = states["known"] & (states["probability"] > 0.7)
    print(f"{len(points)} points -> {m.get_num_nodes()} known voxels, {len(occupied)} occupied; "
          f"{hit.sum()} of the returns lie in occupied voxels; wrote {out}")
    return 0 if len(occupied) > 0 else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
