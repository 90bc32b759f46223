# SPDX-License-Identifier: BSD-3-Clause
"""Python I/O: PCD in all three encodings (binary_compressed as PCL writes it), PLY both ways,
intensities left out, queries of many points at once, and OctoMap files opened at their own
resolution."""

import os
import shutil
import subprocess

import numpy as np
import pytest

import iwlomap


def _cloud(n=5000, seed=3):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-20.0, 20.0, size=(n, 3))
    points[:, 2] *= 0.1
    return points, rng.uniform(0.0, 255.0, size=n)


def _pcl_convert(src, dst, mode):
    tool = shutil.which("pcl_convert_pcd_ascii_binary")
    assert tool, "pcl_convert_pcd_ascii_binary (Debian: pcl-tools, installed by scripts/setup.sh) is needed"
    run = subprocess.run([tool, str(src), str(dst), str(mode)], capture_output=True, text=True)
    assert run.returncode == 0 and os.path.exists(dst), run.stdout + run.stderr


@pytest.mark.parametrize("regular", [False, True])  # random values (literal runs) and a grid (back references)
def test_binary_compressed_pcd_written_by_pcl_reads_as_pcls_other_encodings(tmp_path, regular):
    points, intensities = _cloud()
    if regular:
        points = np.column_stack([np.arange(5000) % 50 * 0.5, np.arange(5000) // 50 * 0.5, np.zeros(5000)])
        intensities = np.arange(5000) % 7 * 30.0
    iwlomap.write_pcd(tmp_path / "a.pcd", points, intensities, origin=(1.0, 2.0, 3.0))
    _pcl_convert(tmp_path / "a.pcd", tmp_path / "c.pcd", 2)  # binary_compressed
    _pcl_convert(tmp_path / "a.pcd", tmp_path / "t.pcd", 0)  # ascii
    data = (tmp_path / "c.pcd").read_bytes()
    assert b"DATA binary_compressed" in data[:400]
    if regular:  # LZF found repeats: the data is less than half its expanded size
        body = data.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
        compressed, raw = np.frombuffer(data, dtype="<u4", count=2, offset=body)
        assert compressed < raw / 2
    binary, compressed, ascii_ = (iwlomap.read_pcd(tmp_path / f) for f in ("a.pcd", "c.pcd", "t.pcd"))
    assert len(compressed) == len(binary) == 5000
    np.testing.assert_array_equal(compressed.points, binary.points)
    np.testing.assert_array_equal(compressed.intensities, binary.intensities)
    np.testing.assert_allclose(ascii_.points, binary.points, rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(compressed.origin, [1.0, 2.0, 3.0])


def test_damaged_binary_compressed_pcd_is_refused_naming_the_file(tmp_path):
    points, intensities = _cloud(500)
    iwlomap.write_pcd(tmp_path / "a.pcd", points, intensities)
    _pcl_convert(tmp_path / "a.pcd", tmp_path / "c.pcd", 2)
    data = (tmp_path / "c.pcd").read_bytes()
    body = data.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    compressed = int(np.frombuffer(data, dtype="<u4", count=1, offset=body)[0])
    (tmp_path / "short.pcd").write_bytes(data[:body + 8 + compressed - 40])  # PCL pads the file: cut the data
    with pytest.raises(ValueError, match="short.pcd"):
        iwlomap.read_pcd(tmp_path / "short.pcd")
    bad = bytearray(data)
    bad[body + 8] = 0xE0  # the first control byte: a back reference before the start
    (tmp_path / "bad.pcd").write_bytes(bytes(bad))
    with pytest.raises(ValueError, match="bad.pcd.*LZF"):
        iwlomap.read_pcd(tmp_path / "bad.pcd")


def test_ply_round_trip_and_other_programs_intensity_names(tmp_path):
    points, intensities = _cloud(1000)
    iwlomap.write_ply(tmp_path / "a.ply", points, intensities)
    back = iwlomap.read_ply(tmp_path / "a.ply")
    np.testing.assert_array_equal(back.points, points.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(back.intensities, intensities.astype(np.float32).astype(np.float64))
    iwlomap.write_ply(tmp_path / "xyz.ply", points)
    assert iwlomap.read_ply(tmp_path / "xyz.ply").intensities is None
    (tmp_path / "cc.ply").write_text(
        "ply\nformat ascii 1.0\ncomment CloudCompare\nelement vertex 2\nproperty double x\nproperty double y\n"
        "property double z\nproperty float scalar_intensity\nelement face 0\nproperty list uchar int vertex_indices\n"
        "end_header\n1 2 3 40\n4 5 6 250.5\n")
    cc = iwlomap.read_ply(tmp_path / "cc.ply")
    np.testing.assert_array_equal(cc.points, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(cc.intensities, [40.0, 250.5])
    (tmp_path / "short_row.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n1 2 3\n4 5\n")
    with pytest.raises(ValueError, match="short_row.ply.*vertex 1 holds 2 values"):
        iwlomap.read_ply(tmp_path / "short_row.ply")
    tool = os.environ.get("IWLOMAP_TOOL_BINARY")
    if tool:  # the tool reads what write_ply wrote
        run = subprocess.run([tool, "info", str(tmp_path / "a.ply")], capture_output=True, text=True)
        assert run.returncode == 0 and "1000 points" in run.stdout, run.stdout + run.stderr


def test_query_of_many_points_equals_single_queries():
    points, intensities = _cloud(3000)
    m = iwlomap.ProbabilityUpdater(0.2)
    m.set_params(iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar))
    m.insert_scan(np.zeros(3), points, intensities)
    rng = np.random.default_rng(9)
    probe = np.vstack([points[:500], rng.uniform(-25.0, 25.0, size=(500, 3))])
    many = m.query(probe)
    assert set(many) == {"known", "log_odds", "probability", "count"}
    assert many["known"].dtype == np.bool_ and many["known"].shape == (1000,)
    assert 0 < many["known"].sum() < 1000
    for i, p in enumerate(probe):
        one = m.query(p)
        assert (one is not None) == many["known"][i]
        if one is None:
            assert np.isnan(many["log_odds"][i]) and np.isnan(many["probability"][i]) and many["count"][i] == 0
        else:
            assert (one.log_odds, one.probability, one.count) == \
                (many["log_odds"][i], many["probability"][i], many["count"][i])


def test_intensities_may_be_left_out_as_the_tool_reads_a_cloud_without_them():
    points, _ = _cloud(2000)
    a, b = iwlomap.ProbabilityUpdater(0.25), iwlomap.ProbabilityUpdater(0.25)
    for m in (a, b):
        m.set_params(iwlomap.sensor_preset_params(iwlomap.SensorPreset.kLidar))
    a.insert_scan(np.zeros(3), points)
    b.insert_scan(np.zeros(3), points, np.full(len(points), b.get_params().intensity_max))
    np.testing.assert_array_equal(a.get_occupied_voxels(0.5), b.get_occupied_voxels(0.5))
    assert a.get_occupied_voxels(0.5).shape[0] > 100
    a.batch_update_iwlo(points[:10], None, np.ones(10, dtype=bool))
    b.batch_update_iwlo(points[:10], np.full(10, b.get_params().intensity_max), np.ones(10, dtype=bool))
    np.testing.assert_array_equal(a.get_occupied_voxels(0.5), b.get_occupied_voxels(0.5))


@pytest.mark.skipif(not iwlomap.HAS_OCTOMAP, reason="no OctoMap layer")
def test_import_octomap_without_a_map_opens_the_file_at_its_resolution(tmp_path):
    points, intensities = _cloud(2000)
    m = iwlomap.ProbabilityUpdater(0.3)
    m.insert_scan(np.zeros(3), points, intensities)
    iwlomap.export_octomap(m, tmp_path / "m.ot")
    opened = iwlomap.import_octomap(tmp_path / "m.ot")
    assert isinstance(opened, iwlomap.ProbabilityUpdater)
    assert opened.get_resolution() == pytest.approx(0.3)
    into = iwlomap.ProbabilityUpdater(0.3)
    assert iwlomap.import_octomap(tmp_path / "m.ot", into) is None
    np.testing.assert_array_equal(opened.get_occupied_voxels(0.5), into.get_occupied_voxels(0.5))
    assert opened.get_num_known_voxels() == m.get_num_known_voxels()


def test_help_names_types_as_users_import_them():
    """help() shows array and path arguments by their kind and classes as iwlomap.X, never
    pybind11's 'handle' or the extension module's private name."""
    import pydoc
    import re

    text = pydoc.render_doc(iwlomap, renderer=pydoc.plaintext)
    for sub in (iwlomap.iwlo, getattr(iwlomap, "viewer", None)):
        if sub is not None:
            text += pydoc.render_doc(sub, renderer=pydoc.plaintext)
    assert not re.search(r"\bhandle\b", text)
    assert "_iwlomap." not in text
    assert "points: numpy.typing.ArrayLike" in text
    assert iwlomap.ProbabilityUpdater.__module__ == "iwlomap"
    assert str(iwlomap.SensorPreset.kLidar) == "SensorPreset.kLidar"
    assert iwlomap.SensorPreset.kLidar.name == "kLidar"
