# SPDX-License-Identifier: BSD-3-Clause
"""Maps built in Python equal the tool's, the samples run, the stubs and help tell the truth."""

import os
import pathlib
import re
import subprocess
import sys

import numpy as np
import pytest

import iwlomap

ROOT = pathlib.Path(__file__).resolve().parents[2]


def ouster_frames(data_dir):
    frames = sorted((data_dir / "ouster_os1_128_3frames").glob("frame_*_world.pcd"))
    if not frames:
        pytest.skip("no Ouster frames")
    return frames


def test_ouster_frames_match_the_tool_bit_for_bit(data_dir, tool, tmp_path):
    frames = ouster_frames(data_dir)
    m = iwlomap.ProbabilityUpdater(0.2)
    m.set_params(iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar))
    for f in frames:
        c = iwlomap.read_pcd(f)
        m.insert_scan(c.origin, c.points, c.intensities)
    out = tmp_path / "tool.pcd"
    cmd = [tool, "map", *map(str, frames), "--sensor", "lidar", "--resolution", "0.2", "-q", "-o", str(out)]
    if iwlomap.HAS_OCTOMAP:
        cmd += ["--octomap", str(tmp_path / "tool.ot")]
    subprocess.run(cmd, check=True)
    theirs = iwlomap.read_pcd(out)
    mine = m.get_occupied_voxels(0.7)
    assert len(mine) > 10000
    a = np.column_stack([mine[:, :3].astype(np.float32), mine[:, 3].astype(np.float32)])
    b = np.column_stack([theirs.points.astype(np.float32), theirs.intensities.astype(np.float32)])
    assert np.array_equal(a[np.lexsort(a.T[::-1])], b[np.lexsort(b.T[::-1])])
    if iwlomap.HAS_OCTOMAP:  # the full map (every log-odds) byte for byte
        iwlomap.export_octomap(m, tmp_path / "python.ot")
        assert (tmp_path / "python.ot").read_bytes() == (tmp_path / "tool.ot").read_bytes()


@pytest.mark.parametrize("sample", ["map_ouster.py", "map_oculus.py"])
def test_samples_run(sample, data_dir, tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    r = subprocess.run([sys.executable, str(ROOT / "samples" / "python" / sample), "--data", str(data_dir),
                        "--out", str(tmp_path)], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "occupied voxels" in r.stdout
    assert (tmp_path / (pathlib.Path(sample).stem + ".pcd")).stat().st_size > 0


def test_stubs_cover_every_public_name():
    stub = (pathlib.Path(iwlomap.__file__).parent / "__init__.pyi").read_text()
    # Top-level classes, functions, names and imported submodules.
    declared = {a or b or c for a, b, c in
                re.findall(r"^(?:class|def) (\w+)|^(\w+)\s*[:=]|^from \. import (\w+)", stub, re.M)}
    public = {n for n in dir(iwlomap._iwlomap) if not n.startswith("_")} | {"read_pcd", "write_pcd"}
    missing = public - declared
    assert not missing, f"not in __init__.pyi: {sorted(missing)}"
    backend_methods = {n for n in dir(iwlomap.IMapperBackend) if not n.startswith("_")}
    for name in backend_methods:
        assert re.search(rf"def {name}\(", stub), f"IMapperBackend.{name} not in __init__.pyi"


def test_help_tells_units_and_frames():
    doc = iwlomap.ProbabilityUpdater.insert_scan.__doc__
    assert "metres" in doc and "map frame" in doc
    assert "(N, 4)" in iwlomap.IMapperBackend.get_occupied_voxels.__doc__
