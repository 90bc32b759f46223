#!/usr/bin/env python3
# SPDX-License-Identifier: BSD-3-Clause
"""Fails on an include that looks up or sideways between iwlomap's layers and floors.

The rules (docs/design.md, "Layers and floors"):
- Layers: a layer includes the public headers of the core and of the layers listed for it in
  LAYERS, never those of another layer. The programs (samples, examples, benchmarks, python,
  tests) sit on top and may include any layer.
- Floors of the core: a source file of src/FOLDER includes only headers of its own floor or the
  floors below (FLOORS); a public header sits on the floor of the source file of the same name,
  or on the one PUBLIC_FLOORS gives.
- Private headers: the core's private headers (src/...) are included by the core, by the tests
  (through the iwlomap_internal target) and, for the backends that live in other layers, only the
  headers of the backend kit (BACKEND_KIT) by the layers named there.
- Tests and benchmarks compile no source file of each other: shared code lives in tests/support/
  or in a library.
Usage: scripts/check_floors.py [ROOT]   (exit 1 and one line per violation when any is found)
"""
import os
import re
import sys

ROOT = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), ".."))

# Layer -> the layers whose public headers it may include (the core is always allowed).
LAYERS = {
    "core": set(),
    "octomap": set(),
    "filters": set(),
    "viewer": set(),
    "registration": set(),
    "slam": {"registration"},
    "mpi": set(),
}
PROGRAMS = {"samples", "examples", "benchmarks", "python", "tests"}
# The layers whose public headers sit in a folder of their name (include/iwlomap/<layer>/); the
# core's headers sit directly in include/iwlomap/.
LAYER_HEADER_DIRS = {"filters", "viewer", "registration", "slam", "mpi", "octomap"}
# Deprecated forwarding headers of layers directly under iwlomap/ (their old paths), by layer.
FLAT_HEADERS = {"octree_mapper.h": "octomap", "correlative_scan_matcher.h": "registration"}

# Floors of the core, bottom first.
FLOORS = {"model": 0, "storage": 1, "integrate": 2, "backends": 3,
          "async": 4, "grids": 4, "io": 4, "sonar": 4, "sim": 4}
# Public headers without a source file of the same name.
PUBLIC_FLOORS = {"version.h": 0, "voxel_state.h": 0, "ray_caster.h": 0, "stop_token.h": 0, "hit_statistics.h": 0,
                 "scan_phases.h": 0, "map_memory.h": 1, "background_job.h": 4, "optimizer.h": 4}

# The core's private headers that the backends of other layers build on, and those layers.
BACKEND_KIT_LAYERS = {"octomap", "mpi"}
BACKEND_KIT = {
    "backends/pimpl.h", "backends/backend_access.h",
    "backends/disk/file_io.h", "backends/disk/map_directory.h", "backends/disk/map_manifest.h",
    "backends/disk/tile_file.h",
    "integrate/absolute_log_odds.h", "integrate/batch_input.h", "integrate/hit_accumulator.h",
    "integrate/phase_clock.h", "integrate/progress_report.h", "integrate/scan_apply.h", "integrate/scan_scratch.h", "integrate/updater.h",
    "integrate/voxel_update.h",
    "model/checks.h", "model/probability_above.h",
    "storage/block_grid.h", "storage/free_memory.h", "storage/grid_reads.h",
}

INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]([^>"]+)[>"]')
SOURCE_EXT = (".h", ".hpp", ".cpp", ".cc")


def public_floor(name):
    if name in PUBLIC_FLOORS:
        return PUBLIC_FLOORS[name]
    stem = name[:-2]
    for folder, floor in FLOORS.items():
        base = os.path.join(ROOT, "src", folder)
        for dirpath, _, files in os.walk(base):
            if stem + ".cpp" in files:
                return floor
    return None


def layer_of(rel):
    top = rel.split("/", 1)[0]
    if top in ("src", "include"):
        return "core"
    return top


def files():
    for top in ["src", "include"] + sorted(LAYERS) + sorted(PROGRAMS):
        base = os.path.join(ROOT, top)
        for dirpath, dirnames, names in os.walk(base):
            dirnames[:] = [d for d in dirnames if not d.startswith("build")]
            for n in sorted(names):
                if n.endswith(SOURCE_EXT):
                    yield os.path.relpath(os.path.join(dirpath, n), ROOT)


def main():
    errors = []
    floor_cache = {}
    for rel in files():
        layer = layer_of(rel)
        parts = rel.split("/")
        own_floor = None
        if parts[0] == "src" and len(parts) > 2:
            own_floor = FLOORS.get(parts[1])
        elif parts[0] == "include":
            own_floor = floor_cache.setdefault(parts[-1], public_floor(parts[-1]))
        with open(os.path.join(ROOT, rel), encoding="utf-8", errors="replace") as f:
            for number, line in enumerate(f, 1):
                m = INCLUDE.match(line)
                if not m:
                    continue
                inc = m.group(1)
                where = f"{rel}:{number}: includes {inc}"
                target_parts = inc.split("/")
                if target_parts[0] == "iwlomap":
                    # A public header.
                    if len(target_parts) == 3 and target_parts[1] in LAYER_HEADER_DIRS:
                        target_layer = target_parts[1]
                    elif len(target_parts) == 2 and target_parts[1] in FLAT_HEADERS:
                        target_layer = FLAT_HEADERS[target_parts[1]]
                    elif len(target_parts) == 2:
                        target_layer = "core"
                    else:
                        continue
                    if layer in PROGRAMS or target_layer in ("core", layer):
                        if layer == "core" and target_layer == "core" and own_floor is not None:
                            floor = floor_cache.setdefault(target_parts[1], public_floor(target_parts[1]))
                            if floor is not None and floor > own_floor:
                                errors.append(f"{where}: floor {floor} above this file's floor {own_floor}")
                        continue
                    if target_layer not in LAYERS.get(layer, set()):
                        errors.append(f"{where}: layer {layer} may not include layer {target_layer}")
                    continue
                # A private header of the core, named from src/ (iwlomap_internal) or by a path.
                if ".." in target_parts and "src" in target_parts:
                    errors.append(f"{where}: reaches into another folder's src/ by a relative path")
                    continue
                if target_parts[0] in FLOORS and len(target_parts) > 1:
                    if layer == "core":
                        if own_floor is not None and FLOORS[target_parts[0]] > own_floor:
                            errors.append(f"{where}: floor {FLOORS[target_parts[0]]} above this file's "
                                          f"floor {own_floor}")
                        elif own_floor is None and parts[0] == "include":
                            errors.append(f"{where}: a public header includes a private one")
                    elif layer == "tests":
                        pass
                    elif layer in BACKEND_KIT_LAYERS and inc in BACKEND_KIT:
                        pass
                    else:
                        errors.append(f"{where}: private header of the core outside the backend kit")
    errors += cross_compiled_sources()
    for e in errors:
        print(e)
    if errors:
        print(f"check_floors: {len(errors)} include(s) against the layers and floors (docs/design.md)")
        return 1
    print("check_floors: every include looks down")
    return 0


def cross_compiled_sources():
    """Source files of benchmarks/ named by tests' CMake files, and the other way round."""
    out = []
    pairs = [("tests", "benchmarks"), ("benchmarks", "tests")]
    for user, owner in pairs:
        for dirpath, _, names in os.walk(os.path.join(ROOT, user)):
            for n in names:
                if n != "CMakeLists.txt":
                    continue
                path = os.path.join(dirpath, n)
                with open(path, encoding="utf-8") as f:
                    for number, line in enumerate(f, 1):
                        if line.lstrip().startswith("#"):
                            continue
                        for m in re.finditer(r"\$\{PROJECT_SOURCE_DIR\}/" + owner + r"/[\w./]+\.cpp", line):
                            out.append(f"{os.path.relpath(path, ROOT)}:{number}: compiles {m.group(0)} "
                                       f"of {owner}/")
    return out


if __name__ == "__main__":
    sys.exit(main())
