# SPDX-License-Identifier: BSD-3-Clause
"""Every error class: bad arguments are ValueError naming what was wrong, files OSError with the path,
the rest RuntimeError; nothing crashes the interpreter."""

import numpy as np
import pytest

import iwlomap


@pytest.fixture
def m():
    return iwlomap.ProbabilityUpdater(0.1)


@pytest.mark.parametrize("points, words", [
    (np.zeros((5, 2)), "(5, 2)"),
    (np.zeros((5, 3, 1)), "(5, 3, 1)"),
    (np.zeros(3), "(3,)"),
    (np.zeros((5, 3), dtype=np.complex128), "complex128"),
    (np.array([["a", "b", "c"]]), "<U1"),
    (np.zeros((5, 3), dtype=bool), "bool"),
    (None, "None"),
    ("points", "numpy array"),
])
def test_bad_points_raise_value_error_naming_the_problem(m, points, words):
    with pytest.raises(ValueError) as e:
        m.insert_scan([0, 0, 0], points, np.zeros(5))
    assert words in str(e.value) and "points" in str(e.value)


def test_bad_companions_raise_value_error(m):
    p = np.zeros((4, 3))
    with pytest.raises(ValueError, match="expected 4 values"):
        m.insert_scan([0, 0, 0], p, np.zeros(3))
    with pytest.raises(ValueError, match="origin.*\\(2,\\)"):
        m.insert_scan([0, 0], p, np.zeros(4))
    with pytest.raises(ValueError, match="is_occupied.*float64"):
        m.batch_update_iwlo(p, np.zeros(4), np.zeros(4))
    with pytest.raises(ValueError, match="flag 1 is 2"):
        m.batch_update_iwlo(p, np.zeros(4), np.array([0, 2, 0, 0]))
    with pytest.raises(ValueError, match="weights"):
        m.batch_update_iwlo(p, np.zeros(4), np.ones(4, bool), np.ones(5))


def test_library_argument_errors_are_value_errors(m):
    with pytest.raises(ValueError):
        iwlomap.ProbabilityUpdater(-1.0)
    with pytest.raises(ValueError):
        m.set_occupied_threshold(1.5)
    with pytest.raises(ValueError):
        m.set_num_threads(-1)
    with pytest.raises(ValueError):  # a key beyond int32 (std::out_of_range in C++)
        m.batch_update_iwlo(np.array([[1e12, 0, 0]]), np.array([200.0]), np.array([True]))
    with pytest.raises(ValueError):
        iwlomap.iwlo.log_odds(1.5)
    with pytest.raises(ValueError):
        iwlomap.make_backend("NoSuchBackend")


def test_non_finite_input_never_crashes(m):
    p = np.full((3, 3), np.nan)
    m.insert_scan([0, 0, 0], p, np.full(3, np.nan))
    assert m.get_num_skipped_points() == 3
    with pytest.raises(ValueError):
        m.insert_scan([np.nan, 0, 0], np.zeros((1, 3)), np.zeros(1))
    with pytest.raises(ValueError, match="not finite"):
        m.query([np.nan, 0, 0])


def test_file_errors_are_os_errors_with_the_path(tmp_path):
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("x")
    with pytest.raises(OSError) as e:
        iwlomap.OutofcoreTileMapper(not_a_dir / "tiles", 0.1)
    assert isinstance(e.value, iwlomap.StorageError) and str(not_a_dir) in e.value.filename
    d = tmp_path / "tiles"
    first = iwlomap.OutofcoreTileMapper(d, 0.1)
    with pytest.raises(iwlomap.StorageError) as e:  # the directory is locked by `first`
        iwlomap.OutofcoreTileMapper(d, 0.1)
    assert e.value.filename is not None
    del first
    with pytest.raises(OSError):
        iwlomap.OutofcoreTileMapper.open_read_only(tmp_path / "missing")
    garbage = tmp_path / "garbage.raw"
    garbage.write_bytes(b"\x53\x4f" + bytes(200))
    with pytest.raises(iwlomap.OculusFormatError) as e:
        iwlomap.read_oculus_pings(garbage)
    assert isinstance(e.value, OSError) and e.value.filename == str(garbage)
    with pytest.raises(OSError) as e:
        iwlomap.read_oculus_pings(tmp_path / "missing.raw")
    assert e.value.filename == str(tmp_path / "missing.raw")


def test_read_pcd_errors(tmp_path):
    with pytest.raises(OSError):
        iwlomap.read_pcd(tmp_path / "missing.pcd")
    bad = tmp_path / "bad.pcd"
    bad.write_bytes(b"VERSION 0.7\nFIELDS a b\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nPOINTS 1\nDATA ascii\n1 2\n")
    with pytest.raises(ValueError, match="no 'x' field"):
        iwlomap.read_pcd(bad)
    short = tmp_path / "short.pcd"
    short.write_bytes(b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 9\nPOINTS 9\nDATA binary\n" + bytes(12))
    with pytest.raises(ValueError, match="need 108"):
        iwlomap.read_pcd(short)
    p = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    iwlomap.write_pcd(tmp_path / "ok.pcd", p, [7.0, 8.0], origin=(1, 2, 3))
    c = iwlomap.read_pcd(tmp_path / "ok.pcd")
    assert np.array_equal(c.points, p) and c.intensities.tolist() == [7.0, 8.0] and c.origin.tolist() == [1, 2, 3]


def test_other_errors_are_runtime_errors(tmp_path):
    # A backend that does not implement an optional feature says so.
    if iwlomap.HAS_OCTOMAP:
        ro_dir = tmp_path / "ro"
        iwlomap.OutofcoreTileMapper(ro_dir, 0.1).flush()
        ro = iwlomap.OutofcoreTileMapper.open_read_only(ro_dir)
        with pytest.raises(RuntimeError):
            ro.clear()
