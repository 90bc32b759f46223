#!/usr/bin/env python3
# SPDX-License-Identifier: BSD-3-Clause
"""Maps the three Oculus sonar pings of the shared data from Python: each ping's image is projected
into IWLO observations at the sonar's pose and integrated; writes the occupied voxels.

The pings' poses are unknown (the sonar was still): every ping is at the origin, looking along +x.

usage: map_oculus.py [--data DIR] [--out DIR] [--resolution M]
"""

import argparse
import math
import pathlib

import numpy as np

import iwlomap

HERE = pathlib.Path(__file__).resolve().parent


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(HERE / ".." / ".." / ".." / "shared" / "data"),
                        help="the shared data folder (holds oculus_sonar_3pings/)")
    parser.add_argument("--out", default=".", help="folder for map_oculus.pcd")
    parser.add_argument("--resolution", type=float, default=0.01, help="voxel edge in metres (default 0.01)")
    args = parser.parse_args()

    pings = iwlomap.read_oculus_pings(pathlib.Path(args.data, "oculus_sonar_3pings", "three_pings_8bit.raw"))
    m = iwlomap.ProbabilityUpdater(args.resolution)  # the reference (sonar) parameters
    projector = iwlomap.SonarImageProjector(args.resolution, iwlomap.SonarProjectorParams())
    pose = np.eye(4)  # sonar frame = map frame
    for ping in pings:
        geometry = ping.geometry(vertical_aperture=math.radians(20.0), min_range=0.05)
        obs = projector.integrate(m, ping.image, geometry, pose)
        print(f"ping {ping.ping_id}: {ping.beams} beams x {ping.range_bins} bins, {obs.beams_with_return} beams "
              f"with an echo, {obs.occupied_samples} occupied and {obs.free_samples} free samples")
    occupied = m.get_occupied_voxels(m.get_params().occupied_threshold)
    print(f"{len(pings)} pings: {m.get_num_known_voxels()} known voxels, {len(occupied)} occupied voxels at "
          f"{args.resolution} m")
    out = pathlib.Path(args.out)
    iwlomap.write_pcd(out / "map_oculus.pcd", occupied[:, :3], occupied[:, 3])
    print(f"wrote {out / 'map_oculus.pcd'}")


if __name__ == "__main__":
    main()
