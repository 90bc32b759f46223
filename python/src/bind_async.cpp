// SPDX-License-Identifier: BSD-3-Clause
// Background integration: AsyncMapper.

#include "bindings.h"
#include "numpy_io.h"

#include <iwlomap/async_mapper.h>

#include <pybind11/stl.h>

namespace iwlomap::python {

void bind_async(py::module_& m) {
  readable_enum_name(py::enum_<ExecutionMode>(m, "ExecutionMode")
      .value("kSequential", ExecutionMode::kSequential)
      .value("kParallel", ExecutionMode::kParallel));
  readable_enum_name(py::enum_<QueueFullPolicy>(m, "QueueFullPolicy")
      .value("kBlock", QueueFullPolicy::kBlock)
      .value("kDropOldest", QueueFullPolicy::kDropOldest));
  // While an AsyncMapper holds a map, use the map through it: its worker thread is the map's
  // only writer, and sync() makes its state visible.
  py::class_<AsyncMapper>(m, "AsyncMapper", "Integrates scans into a map on a background thread.")
      .def(py::init<std::shared_ptr<IMapperBackend>, ExecutionMode, std::size_t, QueueFullPolicy>(), py::arg("backend"),
           py::arg("mode") = ExecutionMode::kParallel, py::arg("queue_capacity") = 4,
           py::arg("policy") = QueueFullPolicy::kBlock)
      .def(
          "integrate",
          [](AsyncMapper& a, const ArrayLike& origin, const ArrayLike& points, const ArrayLike& intensities,
             double max_range) {
            const Eigen::Vector3d o = vector3_from(origin, "origin");
            Eigen::MatrixXd p = points_from(points);
            if (intensities.is_none()) {
              py::gil_scoped_release release;  // may wait for room in the queue
              a.integrate(o, std::move(p), max_range);
              return;
            }
            Eigen::VectorXd i = values_from(intensities, "intensities", p.rows());
            py::gil_scoped_release release;  // may wait for room in the queue
            a.integrate(o, std::move(p), std::move(i), max_range);
          },
          py::arg("origin"), py::arg("points"), py::arg("intensities") = py::none(), py::arg("max_range") = -1.0,
          "Queues one scan (as IMapperBackend.insert_scan; intensities None: every point a return at the map's "
          "intensity_max); returns at once unless the queue is full.")
      .def("sync", &AsyncMapper::sync, py::call_guard<py::gil_scoped_release>(),
           "Waits until every queued scan is in the map; re-raises an error of the worker.")
      .def(
          "get_occupied_voxels",
          [](AsyncMapper& a, double min_probability) {
            Eigen::MatrixXd v;
            {
              py::gil_scoped_release release;
              v = a.get_occupied_voxels(min_probability);
            }
            return to_numpy(v);
          },
          py::arg("min_probability") = 0.5)
      .def(
          "query",
          [](AsyncMapper& a, const ArrayLike& point) {
            const Eigen::Vector3d p = vector3_from(point, "point");
            py::gil_scoped_release release;
            return a.query(p);
          },
          py::arg("point"))
      .def("get_num_nodes", &AsyncMapper::get_num_nodes, py::call_guard<py::gil_scoped_release>())
      .def("get_num_known_voxels", &AsyncMapper::get_num_known_voxels, py::call_guard<py::gil_scoped_release>())
      .def("is_running", &AsyncMapper::is_running)
      .def("dropped", &AsyncMapper::dropped)
      .def("terminate", &AsyncMapper::terminate, py::call_guard<py::gil_scoped_release>());
}

}  // namespace iwlomap::python
