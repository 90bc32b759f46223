# SPDX-License-Identifier: BSD-3-Clause
"""Progress callbacks from Python: insert_scan() and export_octomap() report their stages, a
callback that raises cancels a scan while rays are cast, and a call into the map from the
callback raises RuntimeError instead of deadlocking."""
import os
import tempfile

import numpy as np
import pytest

import iwlomap


def fan(n=20000, seed=3):
    rng = np.random.default_rng(seed)
    angles = rng.uniform(-np.pi, np.pi, n)
    pts = np.column_stack([8.0 * np.cos(angles), 8.0 * np.sin(angles), rng.uniform(-1.0, 1.0, n)])
    return np.zeros(3), pts, np.full(n, 200.0)


def test_insert_scan_reports_rays_then_voxels():
    origin, pts, inten = fan()
    m = iwlomap.ProbabilityUpdater(0.1)
    heard = []
    m.set_progress_callback(lambda stage, done, total: heard.append((stage, done, total)))
    m.insert_scan(origin, pts, inten)
    stages = [s for s, _, _ in heard]
    assert stages[0] == "casting rays" and stages[-1] == "updating voxels"
    rays = [(d, t) for s, d, t in heard if s == "casting rays"]
    assert rays[0] == (0, len(pts)) and rays[-1] == (len(pts), len(pts))
    assert len(rays) >= 4, "the rays stage reports within the scan"
    assert all(a[0] < b[0] for a, b in zip(rays, rays[1:]))
    m.set_progress_callback(None)
    before = len(heard)
    m.insert_scan(origin, pts, inten)
    assert len(heard) == before


def test_raising_callback_cancels_the_scan():
    origin, pts, inten = fan()
    m = iwlomap.ProbabilityUpdater(0.1)

    def cancel(stage, done, total):
        if stage == "casting rays" and done > 0:
            raise KeyboardInterrupt("stop")

    m.set_progress_callback(cancel)
    with pytest.raises(KeyboardInterrupt):
        m.insert_scan(origin, pts, inten)
    assert m.get_num_known_voxels() == 0


def test_call_into_the_map_from_the_callback_raises():
    origin, pts, inten = fan()
    m = iwlomap.ProbabilityUpdater(0.1)
    m.set_progress_callback(lambda stage, done, total: m.get_num_known_voxels())
    with pytest.raises(RuntimeError):
        m.insert_scan(origin, pts, inten)
    assert m.get_num_known_voxels() == 0, "the call was refused while rays were cast: nothing changed"


@pytest.mark.skipif(not hasattr(iwlomap, "export_octomap"), reason="built without the OctoMap layer")
def test_export_reports_and_cancels_without_a_file():
    origin, pts, inten = fan()
    m = iwlomap.ProbabilityUpdater(0.1)
    m.insert_scan(origin, pts, inten)
    with tempfile.TemporaryDirectory() as d:
        heard = []
        iwlomap.export_octomap(m, os.path.join(d, "a.bt"), progress=lambda s, done, t: heard.append((s, done, t)))
        assert heard[0][0] == "writing the file" and heard[-1][1] == heard[-1][2]

        def cancel(stage, done, total):
            if done > 0:
                raise ValueError("no")

        with pytest.raises(ValueError):
            iwlomap.export_octomap(m, os.path.join(d, "b.bt"), progress=cancel)
        assert sorted(os.listdir(d)) == ["a.bt"]
