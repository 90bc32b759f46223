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
    """Every known voxel as rows (key x, y, z, log-odds, count) sorted by key, float64 (exact for
    int32 keys and counts): equal tables mean maps equal bit for bit."""
    keys, log_odds, counts = m.get_voxels()
    table = np.column_stack([keys.astype(np.float64), log_odds, counts.astype(np.float64)])
    return table[np.lexsort((keys[:, 2], keys[:, 1], keys[:, 0]))]
