# SPDX-License-Identifier: BSD-3-Clause
# Off-screen snapshots (present when iwlomap.HAS_VIEWER; through $DISPLAY, else a private Xvfb).
import enum
import os
from typing import Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

from . import IMapperBackend

class CameraPreset(enum.Enum):
    kIso = ...
    kTop = ...
    kFront = ...
    kSide = ...

class ColorBy(enum.Enum):
    kProbability = ...
    kHeight = ...
    kFixed = ...
    kRgb = ...

class VoxelShape(enum.Enum):
    kCubes = ...
    kPoints = ...

class DisplayError(RuntimeError): ...

class SnapshotOptions:
    width: int
    height: int
    camera: CameraPreset
    perspective: bool
    color_by: ColorBy
    fixed_color: Tuple[float, float, float]
    color_min: Optional[float]
    color_max: Optional[float]
    voxel_rgb: npt.NDArray[np.uint8]
    color_bar: bool
    shape: VoxelShape
    point_size: float
    background: Tuple[float, float, float]
    lighting: bool
    title: str
    color_bar_title: str
    z_down: bool
    axes: bool
    scale_bar: bool
    sensor_positions: npt.NDArray[np.float64]
    def __init__(self) -> None: ...
    def validate(self) -> None: ...

def render(voxels: npt.ArrayLike, resolution: float, options: SnapshotOptions = ...) -> npt.NDArray[np.uint8]: ...
def render_map(map: IMapperBackend, options: SnapshotOptions = ..., min_probability: float = -1.0
               ) -> npt.NDArray[np.uint8]: ...
def write_png(image: npt.ArrayLike, path: Union[str, os.PathLike[str]]) -> None: ...
def check_display() -> None: ...
