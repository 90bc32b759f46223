#!/usr/bin/env python3
# SPDX-License-Identifier: BSD-3-Clause
"""The Python overhead of insert_scan: a 65,536-point scan (the synthetic courtyard, 64 x 1024)
into a fresh RAM map at 0.1 m (bench_core's parameters, one thread), called from Python with numpy arrays and from C++ on Eigen inputs
already built, interleaved in one process; medians and the overhead in per cent.

usage: PYTHONPATH=build/python python3 benchmarks/bench_python.py [--rounds N] [--resolution M]
"""

import argparse
import statistics
import time

import iwlomap
import _iwlomap_bench  # build/python/, built with the benchmarks; never installed


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--resolution", type=float, default=0.1)
    args = parser.parse_args()
    origin, points, intensities = iwlomap.make_synthetic_scan()  # 64 rings x 1024 columns
    params = iwlomap.IwloParams(intensity_threshold=0.0)  # as bench_core: every return a hit
    python_s, cpp_s = [], []
    for r in range(args.rounds + 1):  # round 0 warms up and is not counted
        order = ("python", "cpp") if r % 2 else ("cpp", "python")
        for who in order:
            if who == "cpp":
                t = _iwlomap_bench.insert_scan_seconds(args.resolution, params, origin, points, intensities)
            else:
                m = iwlomap.ProbabilityUpdater(args.resolution)
                m.set_params(params)
                t0 = time.perf_counter()
                m.insert_scan(origin, points, intensities)
                t = time.perf_counter() - t0
                del m
            if r > 0:
                (cpp_s if who == "cpp" else python_s).append(t)
    py_ms, cpp_ms = 1e3 * statistics.median(python_s), 1e3 * statistics.median(cpp_s)
    print(f"insert_scan, {len(points)} points, fresh map at {args.resolution} m, {args.rounds} rounds interleaved")
    print(f"  C++ call (Eigen inputs ready)   median {cpp_ms:8.2f} ms  (min {1e3 * min(cpp_s):.2f})")
    print(f"  Python call (numpy inputs)      median {py_ms:8.2f} ms  (min {1e3 * min(python_s):.2f})")
    print(f"  Python overhead                 {100.0 * (py_ms - cpp_ms) / cpp_ms:+.2f} % of the C++ call "
          f"(min vs min {100.0 * (min(python_s) - min(cpp_s)) / min(cpp_s):+.2f} %)")


if __name__ == "__main__":
    main()
