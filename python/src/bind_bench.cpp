// SPDX-License-Identifier: BSD-3-Clause
// iwlomap._iwlomap._bench: the C++ side of benchmarks/bench_python.py, so the Python call and the
// C++ call are timed in one process, interleaved. Not part of the package's API.

#include "bindings.h"
#include "numpy_io.h"

#include <iwlomap/probability_updater.h>

#include <chrono>

namespace iwlomap::python {

void bind_bench(py::module_& m) {
  py::module_ b = m.def_submodule("_bench", "Timing hooks of benchmarks/bench_python.py (not API).");
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
