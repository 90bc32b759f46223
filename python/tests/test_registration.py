# SPDX-License-Identifier: BSD-3-Clause
"""Registration from Python: the coarse matcher, the ScanMatcher and the RegisteredMapper."""

import numpy as np
import pytest

import iwlomap


def yaw_pose(x, y, z, yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    p = np.eye(4)
    p[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    p[:3, 3] = [x, y, z]
    return p


@pytest.fixture(scope="module")
def courtyard():
    origin, points, intensities = iwlomap.make_synthetic_scan()
    m = iwlomap.ProbabilityUpdater(0.2)
    m.set_params(iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar))
    m.set_hit_accumulation(True)
    m.insert_scan(origin, points, intensities)
    _, again, _ = iwlomap.make_synthetic_scan(seed=2)
    return m, origin, again[::4] - origin


@pytest.mark.skipif(not iwlomap.HAS_REGISTRATION, reason="built without the registration layer")
def test_coarse_branch_and_bound_equals_exhaustive(courtyard):
    m, origin, scan = courtyard
    window = iwlomap.SearchWindow3D(linear_xy=0.4, linear_z=0.2, angular_yaw=np.radians(2.0))
    initial = yaw_pose(origin[0] + 0.25, origin[1] - 0.1, origin[2], np.radians(1.0))
    c = iwlomap.CorrelativeScanMatcher3D.for_scan(m, scan[::8], initial, window, 3)
    fast = c.match(scan[::8], initial, window)
    slow = c.match_exhaustive(scan[::8], initial, window)
    assert fast.found and fast.score_sum == slow.score_sum and np.array_equal(fast.pose, slow.pose)
    assert slow.nodes_visited == slow.candidates
    with pytest.raises(ValueError):
        iwlomap.SearchWindow3D(linear_xy=0.0)


@pytest.mark.skipif(not iwlomap.HAS_REGISTRATION, reason="built without the registration layer")
def test_scan_matcher_recovers_the_pose(courtyard):
    m, origin, scan = courtyard
    truth = yaw_pose(*origin, 0.0)
    matcher = iwlomap.ScanMatcher(m)
    r = matcher.match(scan, yaw_pose(origin[0] + 0.4, origin[1] - 0.3, origin[2] + 0.1, np.radians(5.0)))
    assert r.converged, r.reason
    assert np.linalg.norm(r.pose[:3, 3] - truth[:3, 3]) < 0.03
    assert r.covariance.shape == (6, 6) and r.unobservable.shape == (6, 0)
    far = matcher.match(scan, yaw_pose(origin[0] + 300, origin[1], origin[2], 0.0))
    assert not far.converged and "coarse" in far.reason and far.pose[0, 3] == pytest.approx(origin[0] + 300)
    with pytest.raises(ValueError, match="rotation"):
        matcher.match(scan, np.diag([2.0, 1.0, 1.0, 1.0]))
    options = iwlomap.ScanMatcherOptions()
    options.coarse = False
    options.icp.max_iterations = 50
    assert iwlomap.ScanMatcher(m, options).match(scan, truth).converged


@pytest.mark.skipif(not iwlomap.HAS_REGISTRATION, reason="built without the registration layer")
def test_registered_mapper_corrects_a_drift(courtyard):
    _, origin, scan = courtyard
    results = []
    for mode in (iwlomap.ExecutionMode.kSequential, iwlomap.ExecutionMode.kParallel):
        m = iwlomap.ProbabilityUpdater(0.2)
        m.set_params(iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar))
        m.set_hit_accumulation(True)
        rm = iwlomap.RegisteredMapper(m, mode)
        for k in range(3):  # the same place, the navigation drifting 0.1 m and 1 degree a scan
            rm.integrate(yaw_pose(origin[0] + 0.1 * k, origin[1], origin[2], np.radians(k)), scan,
                         np.full(len(scan), 100.0))
        out = rm.sync()
        assert [s.registered for s in out] == [False, True, True]
        for s in out[1:]:
            assert np.linalg.norm(s.integrated_pose[:3, 3] - origin) < 0.03, s.match.reason
        results.append([s.integrated_pose for s in out])
        assert rm.correction().shape == (4, 4)
    for a, b in zip(*results):
        assert np.array_equal(a, b)


@pytest.mark.skipif(not iwlomap.HAS_REGISTRATION, reason="built without the registration layer")
def test_registered_sonar_mapper_by_submaps():
    # A sonar 1 m above a flat floor, pitched 30 degrees down, moving along x: each beam's echo
    # where its lowest ray meets the floor. The mechanics: submaps of 3 pings, the same poses and
    # map in both modes, options checked.
    bearings = np.linspace(-0.4, 0.4, 24)
    geometry = iwlomap.SonarGeometry(bearings=bearings, range_resolution=0.02, max_range=4.0,
                                     vertical_aperture=np.radians(20.0))
    image = np.zeros((200, len(bearings)), dtype=np.uint8)
    image[int(1.0 / np.sin(np.radians(40.0)) / 0.02), :] = 200

    def pose(x):
        p = np.eye(4)
        c, s = np.cos(np.radians(-30.0)), np.sin(np.radians(-30.0))
        level = np.diag([1.0, -1.0, -1.0])  # sonar +Z down, map +z up
        pitch = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        p[:3, :3] = level @ pitch
        p[:3, 3] = [x, 0.0, 1.0]
        return p

    outputs = []
    for mode in (iwlomap.ExecutionMode.kSequential, iwlomap.ExecutionMode.kParallel):
        m = iwlomap.ProbabilityUpdater(0.05)
        options = iwlomap.RegisteredSonarMapperOptions()
        options.pings_per_submap = 3
        assert options.matcher.icp.planar and not options.matcher.coarse
        rm = iwlomap.RegisteredSonarMapper(m, iwlomap.SonarImageProjector(0.05, iwlomap.SonarProjectorParams()),
                                           mode, options)
        for k in range(7):
            rm.integrate(pose(0.05 * k), image, geometry)
        submaps = rm.sync()
        assert [s.pings for s in submaps] == [3, 3, 1]
        assert [s.first_ping for s in submaps] == [0, 3, 6]
        assert not submaps[0].registered  # nothing to register against yet
        assert all(p.shape == (4, 4) for s in submaps for p in s.integrated_poses)
        assert m.get_num_known_voxels() > 0 and rm.correction().shape == (4, 4)
        outputs.append(([p for s in submaps for p in s.integrated_poses], m.get_occupied_voxels(0.5)))
    for a, b in zip(outputs[0][0], outputs[1][0]):
        assert np.array_equal(a, b)
    assert np.array_equal(outputs[0][1], outputs[1][1])

    options = iwlomap.RegisteredSonarMapperOptions()
    options.pings_per_submap = 0
    with pytest.raises(ValueError, match="pings_per_submap"):
        iwlomap.RegisteredSonarMapper(iwlomap.ProbabilityUpdater(0.05),
                                      iwlomap.SonarImageProjector(0.05, iwlomap.SonarProjectorParams()),
                                      iwlomap.ExecutionMode.kSequential, options)
    rm = iwlomap.RegisteredSonarMapper(iwlomap.ProbabilityUpdater(0.05),
                                       iwlomap.SonarImageProjector(0.05, iwlomap.SonarProjectorParams()))
    with pytest.raises(ValueError, match="dtype"):
        rm.integrate(pose(0.0), image.astype(np.int64), geometry)
    with pytest.raises(ValueError):
        rm.integrate(pose(0.0), image, iwlomap.SonarGeometry(bearings=bearings[:-1], range_resolution=0.02,
                                                            max_range=4.0))
