# SPDX-License-Identifier: BSD-3-Clause
import os
import pathlib

import numpy as np
import pytest

import iwlomap


@pytest.fixture(scope="session")
def data_dir():
    d = pathlib.Path(os.environ.get("IWLOMAP_SHARED_DATA_DIR", pathlib.Path(__file__).parents[2] / ".." / "shared" / "data"))
    if not d.is_dir():
        pytest.skip(f"no recorded data at {d}")
    return d


@pytest.fixture(scope="session")
def tool():
    t = os.environ.get("IWLOMAP_TOOL_BINARY")
    if not t or not os.path.exists(t):
        pytest.skip("the iwlomap tool is not built (IWLOMAP_TOOL_BINARY)")
    return t


@pytest.fixture(scope="session")
def scan():
    """A small synthetic courtyard scan: (origin, points, intensities)."""
    return iwlomap.make_synthetic_scan(rings=16, columns=256)


def voxel_table(m):
    """Every known voxel as a sorted structured array (key, log-odds, count): equal tables mean
    maps equal bit for bit."""
    keys, log_odds, counts = m.get_voxels()
    t = np.empty(len(counts), dtype=[("x", "i4"), ("y", "i4"), ("z", "i4"), ("l", "f8"), ("n", "u4")])
    t["x"], t["y"], t["z"] = keys[:, 0], keys[:, 1], keys[:, 2]
    t["l"], t["n"] = log_odds, counts
    return np.sort(t, order=["x", "y", "z"])
