// SPDX-License-Identifier: BSD-3-Clause
// _iwlomap_bench: the C++ side of benchmarks/bench_python.py, so that the Python call and the C++
// call are timed in one process, interleaved. A module of its own, built with the benchmarks
// (IWLOMAP_BUILD_BENCHMARKS) into the build tree's python/ folder and never installed: the iwlomap
// package ships no benchmark hook. Import iwlomap first (IwloParams is its type).

#include "numpy_io.h"

#include <iwlomap/probability_updater.h>

#include <pybind11/pybind11.h>

#include <chrono>

namespace py = pybind11;

namespace iwlomap::python {

void bind_bench(py::module_& b) {
  b.def(
      "insert_scan_seconds",
      [](double resolution, const IwloParams& params, const py::handle& origin, const py::handle& points,
         const py::handle& intensities, double max_range) {
        // The arrays become Eigen objects before the clock starts: the C++ caller's situation.
        const Eigen::Vector3d o = vector3_from(origin, "origin");
        const Eigen::MatrixXd p = points_from(points);
        const Eigen::VectorXd i = values_from(intensities, "intensities", p.rows());
        py::gil_scoped_release release;
        ProbabilityUpdater map(resolution);
        map.set_params(params);
        const auto t0 = std::chrono::steady_clock::now();
        map.insert_scan(o, p, i, max_range);
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      },
      py::arg("resolution"), py::arg("params"), py::arg("origin"), py::arg("points"), py::arg("intensities"),
      py::arg("max_range") = -1.0,
      "Seconds of one ProbabilityUpdater.insert_scan() into a fresh map, called from C++ on ready Eigen inputs.");
}

}  // namespace iwlomap::python

PYBIND11_MODULE(_iwlomap_bench, m) {
  m.doc() = "Timing hooks of benchmarks/bench_python.py (not part of the iwlomap package).";
  iwlomap::python::bind_bench(m);
}
