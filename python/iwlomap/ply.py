# SPDX-License-Identifier: BSD-3-Clause
"""Reading and writing PLY point clouds with numpy alone.

read_ply() takes ``format ascii``, ``binary_little_endian`` and ``binary_big_endian`` files whose
``vertex`` element has scalar properties (char/int8 ... double/float64); elements before it are
skipped (in a binary file they must not hold lists), those after it are ignored. The intensity is
the property ``intensity``, else ``Intensity``, ``scalar_intensity`` or ``scalar_Intensity``
(CloudCompare's names). A PLY file has no sensor origin: the cloud's origin is (0, 0, 0).
"""

import os

import numpy as np

from .pcd import PcdCloud, xyzi_records

_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _header(data, path):
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' first line or no 'end_header')")
    body = data.find(b"\n", end)
    if body < 0:
        raise ValueError(f"{path}: nothing after 'end_header'")
    fmt, elements = None, []
    for number, raw in enumerate(data[:end].decode("ascii", errors="replace").splitlines()[1:], start=2):
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) == 3:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            elements.append({"name": words[1], "count": int(words[2]), "props": []})
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _TYPES:
            elements[-1]["props"].append((words[2], _TYPES[words[1]]))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1]["props"].append((words[4], None))  # a list: only skippable in ASCII
        else:
            raise ValueError(f"{path}: header line {number} is not understood: {raw.strip()!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"{path}: format {fmt!r} is not supported (ascii, binary_little_endian, binary_big_endian)")
    return fmt, elements, body + 1


def read_ply(path):
    """Reads the vertices of a PLY file (see the module note) into a PcdCloud (origin (0, 0, 0)).
    Raises OSError naming the file when it cannot be read and ValueError naming the file and the
    problem (no x/y/z, an unknown type, a row with another number of values, fewer bytes than
    promised)."""
    path = os.fspath(path)
    with open(path, "rb") as f:
        data = f.read()
    fmt, elements, pos = _header(data, path)
    vertex = next((e for e in elements if e["name"] == "vertex"), None)
    if vertex is None:
        raise ValueError(f"{path}: no 'vertex' element")
    names = [n for n, _ in vertex["props"]]
    for axis in ("x", "y", "z"):
        if axis not in names:
            raise ValueError(f"{path}: the vertex element has no '{axis}' property")
    if any(t is None for _, t in vertex["props"]):
        raise ValueError(f"{path}: the vertex element holds a list property")
    n = vertex["count"]
    if fmt == "ascii":
        lines = data[pos:].decode("ascii", errors="replace").splitlines()
        lines = [line for line in lines if line.strip()]
        skip = sum(e["count"] for e in elements[:elements.index(vertex)])
        rows = lines[skip:skip + n]
        if len(rows) < n:
            raise ValueError(f"{path}: {len(rows)} vertex lines, the header promises {n}")
        table = np.empty((n, len(names)), dtype=np.float64)
        for i, row in enumerate(rows):
            values = row.split()
            if len(values) != len(names):
                raise ValueError(f"{path}: vertex {i} holds {len(values)} values, the header declares {len(names)}")
            try:
                table[i] = [float(v) for v in values]
            except ValueError:
                raise ValueError(f"{path}: vertex {i} holds a value that is not a number: {row.strip()!r}") from None
        fields = {name: table[:, k] for k, name in enumerate(names)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        for e in elements[:elements.index(vertex)]:
            if any(t is None for _, t in e["props"]):
                raise ValueError(f"{path}: element '{e['name']}' before the vertices holds a list (binary)")
            pos += e["count"] * np.dtype([(p, order + t) for p, t in e["props"]]).itemsize
        dtype = np.dtype([(name, order + t) for name, t in vertex["props"]])
        if len(data) - pos < n * dtype.itemsize:
            raise ValueError(f"{path}: {max(len(data) - pos, 0)} bytes of vertices, {n} need {n * dtype.itemsize}")
        records = np.frombuffer(data, dtype=dtype, count=n, offset=pos)
        fields = {name: np.array(records[name]) for name in names}
    return PcdCloud(fields, n, 1, [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])


def write_ply(path, points, intensities=None):
    """Writes points (N, 3) and optional intensities (N,) as a binary little-endian PLY (float32
    properties x y z [intensity]), as the iwlomap tool reads it."""
    names, rec = xyzi_records(points, intensities)
    header = "ply\nformat binary_little_endian 1.0\ncomment written by iwlomap\n" + \
        f"element vertex {len(rec)}\n" + "".join(f"property float {n}\n" for n in names) + "end_header\n"
    with open(os.fspath(path), "wb") as f:
        f.write(header.encode("ascii"))
        f.write(rec.tobytes())
