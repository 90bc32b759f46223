# SPDX-License-Identifier: BSD-3-Clause
"""iwlomap: intensity-weighted log-odds occupancy maps for sonar and lidar point clouds.

The names are those of the C++ API (``ProbabilityUpdater``, ``OutofcoreTileMapper``,
``make_backend``, ``IwloParams``, ...). Points are numpy arrays of shape (N, 3) in metres in the
map frame, intensities (N,), flags (N,) bool; results come back as numpy arrays. Bad arguments
raise ValueError, file and tile-directory problems OSError (with the path), the rest RuntimeError.
Calls release the GIL while the library works.
"""

from ._iwlomap import *  # noqa: F401,F403
from ._iwlomap import __version__, iwlo  # noqa: F401
from . import _iwlomap
from .pcd import read_pcd, write_pcd  # noqa: F401
from .ply import read_ply, write_ply  # noqa: F401

if _iwlomap.HAS_VIEWER:
    from ._iwlomap import viewer  # noqa: F401

__all__ = [name for name in dir(_iwlomap) if not name.startswith("_")] + ["read_pcd", "write_pcd", "read_ply", "write_ply"]
