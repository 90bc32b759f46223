#!/usr/bin/env python3
# SPDX-License-Identifier: BSD-3-Clause
"""Maps the Ouster OS-1-128 frames of the shared data from Python and writes the occupied voxels
(and, with a display, a snapshot).

usage: map_ouster.py [--data DIR] [--out DIR] [--resolution M]
"""

import argparse
import os
import pathlib
import time

import iwlomap

HERE = pathlib.Path(__file__).resolve().parent


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(HERE / ".." / ".." / ".." / "shared" / "data"),
                        help="the shared data folder (holds ouster_os1_128_3frames/)")
    parser.add_argument("--out", default=".", help="folder for map_ouster.pcd (and map_ouster.png)")
    parser.add_argument("--resolution", type=float, default=0.2, help="voxel edge in metres (default 0.2)")
    args = parser.parse_args()

    frames = sorted(pathlib.Path(args.data, "ouster_os1_128_3frames").glob("frame_*_world.pcd"))
    if not frames:
        parser.error(f"no frame_*_world.pcd in {args.data}/ouster_os1_128_3frames")
    m = iwlomap.ProbabilityUpdater(args.resolution)
    m.set_params(iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar))  # every return is a hit
    started = time.perf_counter()
    for f in frames:
        cloud = iwlomap.read_pcd(f)  # points in the world frame, VIEWPOINT = sensor pose
        m.insert_scan(cloud.origin, cloud.points, cloud.intensities)
        print(f"{f.name}: {len(cloud)} points")
    occupied = m.get_occupied_voxels(m.get_params().occupied_threshold)  # (N, 4): x, y, z, p
    print(f"{len(frames)} frames in {time.perf_counter() - started:.2f} s: {m.get_num_known_voxels()} known voxels, "
          f"{len(occupied)} occupied voxels at {args.resolution} m")
    out = pathlib.Path(args.out)
    iwlomap.write_pcd(out / "map_ouster.pcd", occupied[:, :3], occupied[:, 3])
    print(f"wrote {out / 'map_ouster.pcd'}")
    if iwlomap.HAS_VIEWER and os.environ.get("DISPLAY"):
        options = iwlomap.viewer.SnapshotOptions()
        options.title = f"{len(occupied)} occupied voxels"
        image = iwlomap.viewer.render(occupied, args.resolution, options)  # (H, W, 3) uint8
        iwlomap.viewer.write_png(image, out / "map_ouster.png")
        print(f"wrote {out / 'map_ouster.png'}")


if __name__ == "__main__":
    main()
