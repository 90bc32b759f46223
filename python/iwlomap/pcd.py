# SPDX-License-Identifier: BSD-3-Clause
"""Reading and writing PCD files with numpy alone (no PCL needed).

Covers what sensor logs, PCL and iwlomap itself write: ``DATA ascii``, ``binary`` and
``binary_compressed`` (PCL's default for large clouds; LZF) with fields of types F (4 or 8 bytes),
I and U (1, 2, 4 or 8 bytes) and COUNT 1. The intensity is the field ``intensity``, else
``Intensity``, ``scalar_intensity`` or ``scalar_Intensity`` (CloudCompare's names), as the tool reads it.
"""

import os

import numpy as np

# The names read as the intensity field, first match wins (as the C++ pointcloud2_to_xyzi()).
INTENSITY_FIELDS = ("intensity", "Intensity", "scalar_intensity", "scalar_Intensity")

_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4", ("I", 8): "<i8",
          ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8"}


class PcdCloud:
    """A cloud read by read_pcd(): ``fields`` maps each field name to an (N,) array; ``points`` is
    the (N, 3) float64 x, y, z (metres); ``intensities`` the (N,) float64 intensity field or None;
    ``origin`` the (3,) sensor origin and ``orientation`` the (w, x, y, z) quaternion of VIEWPOINT;
    ``width`` and ``height`` the organisation."""

    def __init__(self, fields, width, height, viewpoint):
        self.fields = fields
        self.width = width
        self.height = height
        self.points = np.column_stack([fields[a].astype(np.float64) for a in ("x", "y", "z")])
        name = next((n for n in INTENSITY_FIELDS if n in fields), None)
        self.intensities = fields[name].astype(np.float64) if name is not None else None
        self.origin = np.asarray(viewpoint[:3], dtype=np.float64)
        self.orientation = np.asarray(viewpoint[3:], dtype=np.float64)

    def __len__(self):
        return self.points.shape[0]


def read_pcd(path):
    """Reads a PCD file (see the module note) into a PcdCloud. Raises OSError naming the file when it
    cannot be read and ValueError naming the file and the problem when its content is not a PCD this
    reader takes (missing x/y/z, unknown type, fewer bytes than promised, LZF data that does not
    expand to the promised size)."""
    path = os.fspath(path)
    with open(path, "rb") as f:
        data = f.read()
    header = {}
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise ValueError(f"{path}: no DATA line in the header")
        line = data[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        header[key.upper()] = value.split()
        if key.upper() == "DATA":
            break
    try:
        names = header["FIELDS"]
        sizes = [int(s) for s in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
        width = int(header["WIDTH"][0])
        height = int(header.get("HEIGHT", ["1"])[0])
        points = int(header.get("POINTS", [str(width * height)])[0])
    except (KeyError, ValueError, IndexError) as e:
        raise ValueError(f"{path}: malformed PCD header ({e})") from None
    if not (len(names) == len(sizes) == len(types) == len(counts)):
        raise ValueError(f"{path}: FIELDS, SIZE, TYPE and COUNT differ in length")
    if any(c != 1 for c in counts):
        raise ValueError(f"{path}: fields with COUNT > 1 are not supported")
    for axis in ("x", "y", "z"):
        if axis not in names:
            raise ValueError(f"{path}: no '{axis}' field")
    try:
        dtype = np.dtype([(n, _TYPES[(t, s)]) for n, t, s in zip(names, types, sizes)])
    except KeyError:
        raise ValueError(f"{path}: unsupported field type in TYPE {types} SIZE {sizes}") from None
    viewpoint = [float(v) for v in header.get("VIEWPOINT", ["0", "0", "0", "1", "0", "0", "0"])]
    mode = header["DATA"][0].lower()
    if mode == "binary":
        if len(data) - pos < points * dtype.itemsize:
            raise ValueError(f"{path}: {len(data) - pos} bytes of data, {points} points need {points * dtype.itemsize}")
        records = np.frombuffer(data, dtype=dtype, count=points, offset=pos)
    elif mode == "ascii":
        rows = data[pos:].decode("ascii", errors="replace").split("\n")
        rows = [r for r in rows if r.strip()]
        if len(rows) < points:
            raise ValueError(f"{path}: {len(rows)} data lines, the header promises {points}")
        table = np.array([r.split()[:len(names)] for r in rows[:points]], dtype=np.float64).reshape(points, len(names))
        records = np.empty(points, dtype=dtype)
        for k, n in enumerate(names):
            records[n] = table[:, k]
    elif mode == "binary_compressed":
        records = _compressed_records(data, pos, points, names, types, sizes, dtype, path)
    else:
        raise ValueError(f"{path}: DATA {mode} is not supported (ascii, binary or binary_compressed)")
    fields = {n: np.array(records[n]) for n in names}
    return PcdCloud(fields, width, height, viewpoint)


def _compressed_records(data, pos, points, names, types, sizes, dtype, path):
    """PCL's binary_compressed body: the compressed and uncompressed sizes (uint32 each), then LZF
    data that expands to every field's values one field after the other."""
    from . import _iwlomap

    if len(data) - pos < 8:
        raise ValueError(f"{path}: binary_compressed data without its two sizes")
    compressed, raw = (int(v) for v in np.frombuffer(data, dtype="<u4", count=2, offset=pos))
    if len(data) - pos - 8 < compressed:
        raise ValueError(f"{path}: {len(data) - pos - 8} bytes of compressed data, the header of the data "
                         f"promises {compressed}")
    if raw != points * dtype.itemsize:
        raise ValueError(f"{path}: the compressed data expands to {raw} bytes, {points} points need "
                         f"{points * dtype.itemsize}")
    try:
        body = _iwlomap._lzf_decompress(data[pos + 8:pos + 8 + compressed], raw)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    records = np.empty(points, dtype=dtype)
    offset = 0
    for n, t, s in zip(names, types, sizes):
        records[n] = np.frombuffer(body, dtype=_TYPES[(t, s)], count=points, offset=offset)
        offset += points * s
    return records


def xyzi_records(points, intensities):
    """Points (N, 3) and optional intensities (N,) as little-endian float32 records x y z
    [intensity], checked; returns (field names, records). Shared by write_pcd and write_ply."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points: expected shape (N, 3), got {points.shape}")
    names = ["x", "y", "z"] + ([] if intensities is None else ["intensity"])
    rec = np.empty(points.shape[0], dtype=np.dtype([(n, "<f4") for n in names]))
    for k, n in enumerate("xyz"):
        rec[n] = points[:, k]
    if intensities is not None:
        intensities = np.asarray(intensities, dtype=np.float64)
        if intensities.shape != (points.shape[0],):
            raise ValueError(f"intensities: expected shape ({points.shape[0]},), got {intensities.shape}")
        rec["intensity"] = intensities
    return names, rec


def write_pcd(path, points, intensities=None, origin=(0.0, 0.0, 0.0)):
    """Writes points (N, 3) and optional intensities (N,) as a binary PCD (float32 fields x y z
    [intensity]) with VIEWPOINT at origin, as the iwlomap tool reads it."""
    names, rec = xyzi_records(points, intensities)
    o = [float(v) for v in origin]
    header = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {' '.join(names)}\n"
              f"SIZE {' '.join(['4'] * len(names))}\nTYPE {' '.join(['F'] * len(names))}\n"
              f"COUNT {' '.join(['1'] * len(names))}\nWIDTH {len(rec)}\nHEIGHT 1\n"
              f"VIEWPOINT {o[0]} {o[1]} {o[2]} 1 0 0 0\nPOINTS {len(rec)}\nDATA binary\n")
    with open(os.fspath(path), "wb") as f:
        f.write(header.encode("ascii"))
        f.write(rec.tobytes())
