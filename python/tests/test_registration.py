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
