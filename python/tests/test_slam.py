# SPDX-License-Identifier: BSD-3-Clause
"""Long runs from Python: the pose-graph mapper around a small synthetic street block, trajectory
files."""

import numpy as np
import pytest

import iwlomap


def test_trajectory_files_round_trip(tmp_path):
    poses = []
    for k in range(3):
        p = np.eye(4)
        c, s = np.cos(0.3 * k), np.sin(0.3 * k)
        p[:2, :2] = [[c, -s], [s, c]]
        p[:3, 3] = [k, 2.0 * k, 0.5]
        poses.append(p)
    for name in ("poses.tum", "poses.kitti"):
        iwlomap.write_trajectory(tmp_path / name, poses, stamps=[0.0, 0.1, 0.2] if name.endswith("tum") else [])
        back, stamps = iwlomap.read_trajectory(tmp_path / name)
        assert len(back) == 3
        for a, b in zip(poses, back):
            assert np.allclose(a, b, atol=1e-8)
        if name.endswith("tum"):
            assert stamps == pytest.approx([0.0, 0.1, 0.2])
    with pytest.raises(OSError):
        iwlomap.write_trajectory(tmp_path / "missing" / "x.tum", poses)
    with pytest.raises(ValueError):
        iwlomap.write_trajectory(tmp_path / "x.tum", poses, format="csv")


@pytest.mark.skipif(not iwlomap.HAS_SLAM, reason="built without the SLAM layer")
def test_pose_graph_mapper_closes_a_loop():
    world = iwlomap.SyntheticWorld.street_loop(70.0, 50.0)
    truth = iwlomap.SyntheticWorld.street_loop_trajectory(70.0, 50.0, step=5.0)
    truth += truth[:2]  # on past the start: the loop closes
    o = iwlomap.PoseGraphMapperOptions()
    o.params = iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar)
    o.scans_per_submap = 8
    o.max_range = 30.0
    o.matcher.max_range = 30.0
    o.closure_matcher.max_range = 30.0
    mapper = iwlomap.PoseGraphMapper(iwlomap.ExecutionMode.kParallel, o)
    nav = [truth[0]]
    for k in range(1, len(truth)):  # navigation: 2 % too long and 1 degree per 10 m
        step = np.linalg.inv(truth[k - 1]) @ truth[k]
        d = np.linalg.norm(step[:3, 3])
        step[:3, 3] *= 1.02
        a = np.radians(0.1 * d)
        turn = np.eye(4)
        turn[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        nav.append(nav[-1] @ turn @ step)
    for k, pose in enumerate(truth):
        points, intensities = world.scan(pose, rings=16, columns=360, max_range=30.0, seed=k + 1)
        report = mapper.add_scan(nav[k], points, intensities if k % 2 else None)
        assert report.index == k
    mapper.finish()
    summary = mapper.summary()
    assert summary.scans == len(truth)
    assert summary.registered >= 0.95 * len(truth)
    assert summary.closures_found >= 1
    poses = mapper.poses()
    error = np.sqrt(np.mean([np.sum((p[:3, 3] - t[:3, 3]) ** 2) for p, t in zip(poses, truth)]))
    nav_error = np.sqrt(np.mean([np.sum((p[:3, 3] - t[:3, 3]) ** 2) for p, t in zip(nav, truth)]))
    assert error < 0.2 < nav_error
    assert mapper.map().get_occupied_voxels(0.7).shape[0] > 1000
    with pytest.raises(ValueError):
        mapper.add_loop_closure(0, 999, np.eye(4), np.eye(6))
    with pytest.raises(ValueError):
        mapper.add_scan(np.eye(4), np.zeros((4, 2)))


@pytest.mark.skipif(not iwlomap.HAS_SLAM, reason="built without the SLAM layer")
def test_sonar_pose_graph_mapper_cuts_submaps_at_turns_and_maps_at_the_end():
    # A sonar 1 m above a flat floor, pitched 30 degrees down: 6 pings along +x, then 4 back along
    # -x. Submaps of at most 4 pings, cut where the heading turns: [4, 2] then [4]. A flat floor
    # seen from two headings closes no loop, so every ping is mapped at its navigation pose.
    bearings = np.linspace(-0.4, 0.4, 24)
    geometry = iwlomap.SonarGeometry(bearings=bearings, range_resolution=0.02, max_range=4.0,
                                     vertical_aperture=np.radians(20.0))
    image = np.zeros((200, len(bearings)), dtype=np.uint8)
    image[int(1.0 / np.sin(np.radians(40.0)) / 0.02), :] = 200

    def pose(x, heading):
        p = np.eye(4)
        c, s = np.cos(np.radians(-30.0)), np.sin(np.radians(-30.0))
        level = np.diag([1.0, -1.0, -1.0])  # sonar +Z down, map +z up
        pitch = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        ch, sh = np.cos(heading), np.sin(heading)
        yaw = np.array([[ch, -sh, 0], [sh, ch, 0], [0, 0, 1]])
        p[:3, :3] = yaw @ level @ pitch
        p[:3, 3] = [x, 0.0, 1.0]
        return p

    navigation = [pose(0.1 * k, 0.0) for k in range(6)] + [pose(0.5 - 0.1 * k, np.pi) for k in range(4)]
    m = iwlomap.ProbabilityUpdater(0.05)
    options = iwlomap.SonarPoseGraphMapperOptions()
    options.pings_per_submap = 4
    gm = iwlomap.SonarPoseGraphMapper(m, iwlomap.SonarImageProjector(0.05, iwlomap.SonarProjectorParams()), options)
    for p in navigation:
        gm.integrate(p, image, geometry)
    assert m.get_num_known_voxels() == 0  # nothing is mapped before finish()
    gm.finish()
    assert [s.pings for s in gm.submaps()] == [4, 2, 4]
    assert [s.first_ping for s in gm.submaps()] == [0, 4, 6]
    summary = gm.summary()
    assert summary.pings == 10 and summary.submaps == 3 and summary.closures_found == 0
    assert summary.observations > 0 and m.get_num_known_voxels() > 0
    for a, b in zip(gm.poses(), navigation):
        assert np.allclose(a, b, atol=1e-12)
    with pytest.raises(RuntimeError, match="finish"):
        gm.finish()
    options.pings_per_submap = 0
    with pytest.raises(ValueError, match="pings_per_submap"):
        iwlomap.SonarPoseGraphMapper(m, iwlomap.SonarImageProjector(0.05, iwlomap.SonarProjectorParams()), options)
