// SPDX-License-Identifier: BSD-3-Clause
// The OctoMap layer: the OctoMap backend and .bt/.ot files.

#include "bindings.h"
#include "numpy_io.h"

#include <iwlomap/octomap/octree_mapper.h>

#include <pybind11/stl.h>

namespace iwlomap::python {

void bind_octomap(py::module_& m) {
  py::class_<OctreeMapper, IMapperBackend, std::shared_ptr<OctreeMapper>>(
      m, "OctreeMapper", "The OctoMap backend: an OcTree run by the IWLO update (bit for bit as the RAM backend).")
      .def(py::init<double, double, double, double, double>(), py::arg("resolution") = 0.05, py::arg("prob_hit") = 0.7,
           py::arg("prob_miss") = 0.3, py::arg("prob_thres_min") = 0.12, py::arg("prob_thres_max") = 0.97)
      .def(
          "update_point",
          [](OctreeMapper& map, const ArrayLike& point, bool occupied) {
            const Eigen::Vector3d p = vector3_from(point, "point");
            unlocked(map, [&] { map.update_point(p, occupied); });
          },
          py::arg("point"), py::arg("occupied"), "One observation in OctoMap's own hit/miss model.")
      .def(
          "batch_update",
          [](OctreeMapper& map, const ArrayLike& points, const ArrayLike& flags) {
            const Eigen::MatrixXd p = points_from(points);
            const std::vector<bool> f = flags_from(flags, "occupied_flags", p.rows());
            unlocked(map, [&] { map.batch_update(p, f); });
          },
          py::arg("points"), py::arg("occupied_flags"))
      .def(
          "batch_update_with_log_odds",
          [](OctreeMapper& map, const ArrayLike& points, const ArrayLike& log_odds) {
            const Eigen::MatrixXd p = points_from(points);
            const Eigen::VectorXd l = values_from(log_odds, "log_odds", p.rows());
            unlocked(map, [&] { map.batch_update_with_log_odds(p, l); });
          },
          py::arg("points"), py::arg("log_odds"))
      .def(
          "insert_ray",
          [](OctreeMapper& map, const ArrayLike& origin, const ArrayLike& end, double max_range) {
            const Eigen::Vector3d o = vector3_from(origin, "origin"), e = vector3_from(end, "endpoint");
            unlocked(map, [&] { map.insert_ray(o, e, max_range); });
          },
          py::arg("origin"), py::arg("endpoint"), py::arg("max_range") = -1.0)
      .def(
          "set_probability_params",
          [](OctreeMapper& map, double hit, double miss) { unlocked(map, [&] { map.set_probability_params(hit, miss); }); },
          py::arg("prob_hit"), py::arg("prob_miss"))
      .def(
          "set_occupancy_thresholds",
          [](OctreeMapper& map, double lo, double hi) { unlocked(map, [&] { map.set_occupancy_thresholds(lo, hi); }); },
          py::arg("prob_thres_min"), py::arg("prob_thres_max"))
      .def("get_prob_hit", [](OctreeMapper& map) { return unlocked(map, [&] { return map.get_prob_hit(); }); })
      .def("get_prob_miss", [](OctreeMapper& map) { return unlocked(map, [&] { return map.get_prob_miss(); }); })
      .def("get_prob_thres_min", [](OctreeMapper& map) { return unlocked(map, [&] { return map.get_prob_thres_min(); }); })
      .def("get_prob_thres_max", [](OctreeMapper& map) { return unlocked(map, [&] { return map.get_prob_thres_max(); }); })
      .def("prune_tree", [](OctreeMapper& map) { return unlocked(map, [&] { return map.prune_tree(); }); })
      .def(
          "save_to_file",
          [](OctreeMapper& map, const PathLike& path) {
            const std::string file = path_from(path);
            unlocked(map, [&] { with_file_errors(file, [&] { (void)map.save_to_file(file); }); });
            return true;
          },
          py::arg("path"), "Writes the map as .bt (occupancy) or .ot (full log-odds); True (failures raise).")
      .def(
          "load_from_file",
          [](OctreeMapper& map, const PathLike& path) {
            const std::string file = path_from(path);
            unlocked(map, [&] { with_file_errors(file, [&] { (void)map.load_from_file(file); }); });
            return true;
          },
          py::arg("path"), "Replaces the map by a .bt/.ot file at its resolution; True (failures raise).");
  m.def(
      "export_octomap",
      [](IMapperBackend& map, const PathLike& path, std::optional<double> occupied_threshold,
         const py::object& progress) {
        const std::string file = path_from(path);
        const ProgressCallback cb = python_progress(progress, map);
        unlocked(map, [&] {
          with_file_errors(file, [&] {
            export_octomap(map, file, occupied_threshold ? *occupied_threshold : map.get_params().occupied_threshold, cb);
          });
        });
      },
      py::arg("map"), py::arg("path"), py::arg("occupied_threshold") = py::none(), py::arg("progress") = py::none(),
      "Writes any map as an OctoMap file: .bt (occupancy at the map's threshold, or occupied_threshold) or .ot. "
      "progress(stage, done, total), when given, hears 'writing the file' by blocks; an exception it raises cancels "
      "the export and leaves no file.");
  m.def(
      "import_octomap",
      [](const PathLike& path, IMapperBackend* map) -> py::object {
        const std::string file = path_from(path);
        if (map != nullptr) {
          unlocked(*map, [&] { with_file_errors(file, [&] { import_octomap(file, *map); }); });
          return py::none();
        }
        std::unique_ptr<ProbabilityUpdater> made;
        {
          py::gil_scoped_release release;
          with_file_errors(file, [&] { made = import_octomap(file); });
        }
        return py::cast(std::shared_ptr<ProbabilityUpdater>(std::move(made)));
      },
      py::arg("path"), py::arg("map") = nullptr,
      "Reads a .bt/.ot file into map (same resolution); without a map, returns a new ProbabilityUpdater at the "
      "file's resolution.");
}

}  // namespace iwlomap::python
