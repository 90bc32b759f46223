# SPDX-License-Identifier: BSD-3-Clause
"""The snapshot renderer from Python (the test command runs under xvfb-run; without a display the
renderer starts its own Xvfb, which one test checks in a child process)."""

import os
import subprocess
import sys

import numpy as np
import pytest

import iwlomap

pytestmark = pytest.mark.skipif(not iwlomap.HAS_VIEWER or not os.environ.get("DISPLAY"),
                                reason="no viewer layer or no X display")


def test_render_returns_an_image_and_writes_a_png(tmp_path):
    v = iwlomap.viewer
    o = v.SnapshotOptions()
    o.width, o.height = 200, 160
    o.camera = v.CameraPreset.kTop
    o.color_by = v.ColorBy.kRgb
    o.color_bar = False
    o.lighting = False
    o.background = (0.0, 0.0, 0.0)
    voxels = np.array([[-9.5, -9.5, 0, 1], [9.5, 9.5, 0, 1], [5.5, 0.5, 0, 1]], dtype=np.float64)
    o.voxel_rgb = np.array([[255, 255, 255], [255, 255, 255], [10, 200, 30]], dtype=np.uint8)
    image = v.render(voxels, 1.0, o)
    assert image.shape == (160, 200, 3) and image.dtype == np.uint8
    # The green voxel is drawn in its colour (x = 5.5 m -> column 100 + 5.5 * 7.2).
    assert np.abs(image[80 - 4, 100 + 39].astype(int) - [10, 200, 30]).max() <= 3
    v.write_png(image, tmp_path / "a.png")
    assert (tmp_path / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    m = iwlomap.ProbabilityUpdater(1.0)
    m.batch_update_iwlo(voxels[:, :3], np.full(3, 255.0), np.ones(3, bool))
    o.color_by = v.ColorBy.kHeight
    assert v.render_map(m, o, 0.5).shape == (160, 200, 3)
    with pytest.raises(ValueError, match="4\\)"):
        v.render(voxels[:, :3], 1.0, o)
    o.width = 8
    with pytest.raises(ValueError, match="width"):
        v.render(voxels, 1.0, o)


def test_render_without_a_display_uses_a_private_virtual_x_server(tmp_path):
    script = (
        "import numpy as np, iwlomap\n"
        "o = iwlomap.viewer.SnapshotOptions(); o.width, o.height = 120, 90\n"
        "image = iwlomap.viewer.render(np.array([[0.0, 0, 0, 1], [3, 3, 0, 1]]), 1.0, o)\n"
        "assert (image != image[0, 0]).any(), 'blank image'\n"
        f"iwlomap.viewer.write_png(image, {str(tmp_path / 'headless.png')!r})\n")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "IWLOMAP_XVFB")}
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "headless.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    env["IWLOMAP_XVFB"] = "/nonexistent/Xvfb"
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode != 0 and "xvfb-run" in run.stderr and "not found" in run.stderr



def test_sensor_track_and_marks_are_options():
    """sensor_positions, axes, scale_bar and z_down go through to the renderer: the track is drawn
    dark where the map has no voxel, and turning the marks off leaves the corner empty."""
    v = iwlomap.viewer
    voxels = np.array([[x + 0.5, y + 0.5, 0.0, 1.0] for x in range(-10, 0) for y in range(-10, 10)])
    o = v.SnapshotOptions()
    o.width, o.height = 200, 200
    o.camera = v.CameraPreset.kTop
    o.color_bar = False
    o.lighting = False
    o.background = (1.0, 1.0, 1.0)
    o.axes = False
    o.scale_bar = False
    plain = v.render(voxels, 1.0, o)
    assert (plain[150:, :40] == 255).all(), "no marks: the lower-left corner is background"
    o.sensor_positions = np.array([[9.5, 0.0, 0.0]])
    assert o.sensor_positions.shape == (1, 3)
    o.axes = True
    o.z_down = True
    marked = v.render(voxels, 1.0, o)
    assert marked[100, 190].sum() < 150, "a dark marker at the sensor (right edge, middle)"
    assert (marked[150:, :40] != 255).any(), "the axes triad in the lower-left corner"
    with pytest.raises(ValueError):
        o.sensor_positions = np.zeros((2, 2))
