#!/usr/bin/env python3
# SPDX-License-Identifier: BSD-3-Clause
"""Hostile inputs against the iwlomap tool, counted.

Mutates valid clouds and disk maps and runs the tool on each, then checks what a user must be able
to rely on:
  - no crash (a signal), no hang (--timeout), exit code 0, 1 or 2;
  - a failure is one line on stderr and leaves no output file;
  - a cloud that is not valid PCD (a row with too few or too many values, a non-number, a
    partial number, a duplicated header line, a binary body of the wrong size) is refused: exit 1,
    never mapped as if it were something else;
  - a run on a disk map with one damaged tile fails and leaves every file of the map byte for
    byte as it was.
Prints a table of counts per mutator and exits 1 when any check failed.

usage: attack.py TOOL WORKDIR [--runs N] [--maps N] [--seed S] [--timeout SECONDS]
Short run (the test command, ctest Tool.Attack): --runs 120 --maps 6. Long run: --runs 5000 --maps 200.
"""
import argparse
import hashlib
import os
import random
import shutil
import subprocess
import sys

HEADER = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
          "WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 1.5 1 0 0 0\nPOINTS {n}\nDATA ascii\n")


def ascii_cloud(rng, n):
    rows = ["%.3f %.3f %.3f %d" % (rng.uniform(-8, 8), rng.uniform(-8, 8), rng.uniform(0, 4), rng.randint(0, 255))
            for _ in range(n)]
    return HEADER.format(n=n) + "\n".join(rows) + "\n"


# ---- mutators: each returns (bytes, must_be_refused) ----

def row_too_few(rng, text):
    lines = text.split("\n")
    i = rng.randrange(11, len(lines) - 1)
    lines[i] = " ".join(lines[i].split()[:rng.randint(1, 3)])
    return "\n".join(lines).encode(), True


def row_too_many(rng, text):
    lines = text.split("\n")
    i = rng.randrange(11, len(lines) - 1)
    lines[i] += " 7"
    return "\n".join(lines).encode(), True


def row_not_a_number(rng, text):
    lines = text.split("\n")
    i = rng.randrange(11, len(lines) - 1)
    values = lines[i].split()
    values[rng.randrange(len(values))] = rng.choice(["abc", "1,5", "1.5abc", "--1", "0x", "1e", "nan1"])
    lines[i] = " ".join(values)
    return "\n".join(lines).encode(), True


def duplicate_header_line(rng, text):
    lines = text.split("\n")
    i = rng.randrange(1, 10)
    lines.insert(i + 1, lines[i])
    return "\n".join(lines).encode(), True


def binary_wrong_size(rng, binary):
    cut = rng.choice([-1, -3, -4, -16, 1, 5])
    return (binary[:cut] if cut < 0 else binary + b"\0" * cut), True


def flip_bytes(rng, data):
    b = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
    return bytes(b), False


def truncate(rng, data):
    return data[:rng.randrange(len(data))], False


def insert_bytes(rng, data):
    i = rng.randrange(len(data))
    return data[:i] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 32))) + data[i:], False


def run(cmd, timeout):
    try:
        p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, timeout=timeout)
        return p.returncode, p.stderr.decode(errors="replace")
    except subprocess.TimeoutExpired:
        return "hang", ""


def digest(directory):
    out = {}
    for root, _, files in os.walk(directory):
        for f in files:
            path = os.path.join(root, f)
            with open(path, "rb") as fh:
                out[os.path.relpath(path, directory)] = hashlib.sha256(fh.read()).hexdigest()
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("tool")
    ap.add_argument("workdir")
    ap.add_argument("--runs", type=int, default=120, help="mutated clouds")
    ap.add_argument("--maps", type=int, default=6, help="damaged disk maps")
    ap.add_argument("--seed", type=int, default=20261128)
    ap.add_argument("--timeout", type=float, default=60.0)
    a = ap.parse_args()
    rng = random.Random(a.seed)
    shutil.rmtree(a.workdir, ignore_errors=True)
    os.makedirs(a.workdir)
    w = lambda name: os.path.join(a.workdir, name)

    text = ascii_cloud(rng, 300)
    rc, err = run([a.tool, "generate", "-o", w("binary.pcd"), "--rings", "8", "--columns", "64"], a.timeout)
    if rc != 0:
        print("cannot generate the binary seed: " + err)
        return 1
    with open(w("binary.pcd"), "rb") as fh:
        binary = fh.read()
    text_mutators = [row_too_few, row_too_many, row_not_a_number, duplicate_header_line]
    byte_mutators = [flip_bytes, truncate, insert_bytes]
    counts = {}
    failures = []

    def note(mutator, outcome):
        row = counts.setdefault(mutator, {"runs": 0, "exit 0": 0, "exit 1": 0, "exit 2": 0, "failed": 0})
        row["runs"] += 1
        if outcome in row:
            row[outcome] += 1

    for i in range(a.runs):
        choice = rng.randrange(4)
        if choice == 0:
            m = rng.choice(text_mutators)
            data, must_refuse = m(rng, text)
        elif choice == 1:
            m = binary_wrong_size
            data, must_refuse = m(rng, binary)
        else:
            m = rng.choice(byte_mutators)
            data, must_refuse = m(rng, text.encode() if choice == 2 else binary)
        path, out = w("in_%d.pcd" % i), w("out_%d.pcd" % i)
        with open(path, "wb") as fh:
            fh.write(data)
        rc, err = run([a.tool, "map", path, "--resolution", "0.5", "-q", "-o", out], a.timeout)
        problem = None
        if rc == "hang" or rc not in (0, 1, 2):
            problem = "crash or hang (%s)" % rc
        elif rc != 0 and (len(err.strip().splitlines()) != 1 or os.path.exists(out)):
            problem = "failure without one line, or with an output: " + err.strip()[:200]
        elif must_refuse and rc != 1:
            problem = "an invalid cloud was not refused (exit %s)" % rc
        note(m.__name__, "exit %s" % rc if rc in (0, 1, 2) else "failed")
        if problem:
            counts[m.__name__]["failed"] += 1
            keep = w("finding_%d.pcd" % i)
            shutil.copy(path, keep)
            failures.append("%s: %s (input kept as %s)" % (m.__name__, problem, keep))
        else:
            os.remove(path)
        if os.path.exists(out):
            os.remove(out)

    # Disk maps: one damaged tile; the run fails and changes no file.
    base = w("map_base")
    rc, err = run([a.tool, "map", w("binary.pcd"), "--backend", "disk", "--tiles", base, "--resolution", "0.2",
                   "--tile-size", "1.6", "--cache-tiles", "4", "-q"], a.timeout)
    if rc != 0:
        print("cannot build the disk map: " + err)
        return 1
    tiles = sorted(f for f in os.listdir(base) if f.startswith("tile_"))
    for k in range(a.maps):
        d = w("map_%d" % k)
        shutil.copytree(base, d)
        victim = os.path.join(d, rng.choice(tiles))
        with open(victim, "r+b") as fh:
            b = bytearray(fh.read())
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
            fh.seek(0)
            fh.write(b)
        before = digest(d)
        rc, err = run([a.tool, "map", w("binary.pcd"), "--backend", "disk", "--tiles", d, "-q"], a.timeout)
        note("damaged_tile", "exit %s" % rc if rc in (0, 1, 2) else "failed")
        after = digest(d)
        if rc != 1 or before != after or os.path.basename(victim) not in err:
            counts["damaged_tile"]["failed"] += 1
            failures.append("damaged_tile %s: exit %s, files %s, message: %s" %
                            (victim, rc, "unchanged" if before == after else "CHANGED", err.strip()[:200]))
        else:
            shutil.rmtree(d)

    print("| mutator | runs | exit 0 | exit 1 | exit 2 | failed checks |")
    print("|---|---:|---:|---:|---:|---:|")
    for name in sorted(counts):
        r = counts[name]
        print("| %s | %d | %d | %d | %d | %d |" % (name, r["runs"], r["exit 0"], r["exit 1"], r["exit 2"], r["failed"]))
    for f in failures:
        print("FAIL " + f)
    print("%d runs, %d failed checks" % (sum(r["runs"] for r in counts.values()), len(failures)))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
