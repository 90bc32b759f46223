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
