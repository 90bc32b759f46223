// SPDX-License-Identifier: BSD-3-Clause
// Long runs: trajectory files (core) and, with the SLAM layer, the pose-graph mapper (submaps,
// loop closure, the background optimizer).

#include "bindings.h"
#include "numpy_io.h"

#include <iwlomap/synthetic_world.h>
#include <iwlomap/trajectory_io.h>
#ifdef IWLOMAP_PYTHON_SLAM
#include <iwlomap/slam/pose_graph_mapper.h>
#include <iwlomap/slam/sonar_pose_graph_mapper.h>
#endif

#include <pybind11/stl.h>

#include <cstdint>
#include <vector>

namespace iwlomap::python {

namespace {

std::vector<Eigen::Isometry3d> poses_from(const py::handle& obj) {
  std::vector<Eigen::Isometry3d> out;
  for (const py::handle item : obj) out.push_back(pose_from(item, "poses"));
  return out;
}

py::list poses_to_list(const std::vector<Eigen::Isometry3d>& poses) {
  py::list out;
  for (const Eigen::Isometry3d& p : poses) out.append(pose_to_numpy(p));
  return out;
}

Eigen::Matrix<double, 6, 6> information_from(const py::handle& obj) {
  const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(obj);
  if (!a || a.ndim() != 2 || a.shape(0) != 6 || a.shape(1) != 6)
    throw std::invalid_argument("iwlomap: information must be a (6, 6) array");
  Eigen::Matrix<double, 6, 6> m;
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) m(r, c) = a.at(r, c);
  return m;
}

StreetLoopOptions street_of(double block_x, double block_y, double street_width, std::uint32_t seed) {
  StreetLoopOptions o;
  o.block_x = block_x;
  o.block_y = block_y;
  o.street_width = street_width;
  o.seed = seed;
  return o;
}

TrajectoryFormat format_of(const std::string& path, const std::string& format) {
  if (format.empty()) return trajectory_format_of(path);
  if (format == "tum") return TrajectoryFormat::kTum;
  if (format == "kitti") return TrajectoryFormat::kKitti;
  throw std::invalid_argument("iwlomap: trajectory format '" + format + "': expected 'tum' or 'kitti'");
}

}  // namespace

void bind_slam(py::module_& m) {
  py::class_<SyntheticWorld>(m, "SyntheticWorld",
                             "Boxes on a ground plane and a spinning lidar ray-cast against them (metres).")
      .def_static(
          "street_loop",
          [](double block_x, double block_y, double street_width, std::uint32_t seed) {
            return SyntheticWorld::street_loop(street_of(block_x, block_y, street_width, seed));
          },
          py::arg("block_x") = 200.0, py::arg("block_y") = 150.0, py::arg("street_width") = 14.0, py::arg("seed") = 1,
          "A city block's street loop (centreline from (0, 0) to (block_x, block_y)), seeded.")
      .def_static(
          "street_loop_trajectory",
          [](double block_x, double block_y, double street_width, std::uint32_t seed, double step, double height) {
            return poses_to_list(
                SyntheticWorld::street_loop_trajectory(street_of(block_x, block_y, street_width, seed), step, height));
          },
          py::arg("block_x") = 200.0, py::arg("block_y") = 150.0, py::arg("street_width") = 14.0, py::arg("seed") = 1,
          py::arg("step") = 3.0, py::arg("sensor_height") = 1.8,
          "Sensor poses (4, 4) every step metres once around the loop (the next would be the first).")
      .def(
          "scan",
          [](const SyntheticWorld& w, const ArrayLike& pose, int rings, int columns, double max_range, double range_noise,
             std::uint32_t seed) {
            LidarOptions l;
            l.rings = rings;
            l.columns = columns;
            l.max_range = max_range;
            l.range_noise = range_noise;
            const Eigen::Isometry3d t = pose_from(pose, "sensor_pose");
            LidarFrame f;
            {
              py::gil_scoped_release release;
              f = w.scan(t, l, seed);
            }
            return py::make_tuple(to_numpy(f.points), to_numpy(f.intensities));
          },
          py::arg("sensor_pose"), py::arg("rings") = 32, py::arg("columns") = 1024, py::arg("max_range") = 40.0,
          py::arg("range_noise") = 0.02, py::arg("seed") = 1,
          "One lidar frame: (points (N, 3) in the sensor frame, intensities (N,)).")
      .def("num_boxes", [](const SyntheticWorld& w) { return w.boxes().size(); });

  m.def(
      "write_trajectory",
      [](const PathLike& path, const ArrayLike& poses, const std::vector<double>& stamps, const std::string& format) {
        const std::string p = path_from(path);
        const std::vector<Eigen::Isometry3d> list = poses_from(poses);
        with_file_errors(p, [&] { write_trajectory(p, list, stamps, format_of(p, format)); });
      },
      py::arg("path"), py::arg("poses"), py::arg("stamps") = std::vector<double>{}, py::arg("format") = "",
      "Writes (4, 4) sensor-to-world poses as TUM (t x y z qx qy qz qw) or KITTI (12 numbers) lines; "
      "format '' takes KITTI for a name ending in .kitti, else TUM. stamps: seconds (default 0, 1, ...).");
  m.def(
      "read_trajectory",
      [](const PathLike& path, const std::string& format) {
        const std::string p = path_from(path);
        std::vector<double> stamps;
        const std::vector<Eigen::Isometry3d> poses =
            with_file_errors(p, [&] { return read_trajectory(p, format_of(p, format), &stamps); });
        return py::make_tuple(poses_to_list(poses), stamps);
      },
      py::arg("path"), py::arg("format") = "",
      "Reads a TUM or KITTI file: (list of (4, 4) poses, list of stamps; empty for KITTI).");

#ifdef IWLOMAP_PYTHON_SLAM
  namespace s = iwlomap::slam;
  readable_enum_name(py::enum_<s::RefusedScanPolicy>(m, "RefusedScanPolicy")
      .value("kIntegrateAtPrior", s::RefusedScanPolicy::kIntegrateAtPrior)
      .value("kHoldBack", s::RefusedScanPolicy::kHoldBack));
  py::class_<s::PoseGraphMapperOptions>(m, "PoseGraphMapperOptions",
                                        "Submaps, loop closure and the pose graph (metres, radians).")
      .def(py::init<>())
      .def_readwrite("resolution", &s::PoseGraphMapperOptions::resolution)
      .def_readwrite("params", &s::PoseGraphMapperOptions::params)
      .def_readwrite("max_range", &s::PoseGraphMapperOptions::max_range)
      .def_readwrite("scans_per_submap", &s::PoseGraphMapperOptions::scans_per_submap)
      .def_readwrite("matcher", &s::PoseGraphMapperOptions::matcher)
      .def_readwrite("refused", &s::PoseGraphMapperOptions::refused)
      .def_readwrite("loop_closure", &s::PoseGraphMapperOptions::loop_closure)
      .def_readwrite("closure_matcher", &s::PoseGraphMapperOptions::closure_matcher)
      .def_readwrite("closure_stride", &s::PoseGraphMapperOptions::closure_stride)
      .def_readwrite("closure_max_distance", &s::PoseGraphMapperOptions::closure_max_distance)
      .def_readwrite("rebuild_map_on_optimize", &s::PoseGraphMapperOptions::rebuild_map_on_optimize)
      .def("validate", &s::PoseGraphMapperOptions::validate);
  py::class_<s::SlamScanReport>(m, "SlamScanReport")
      .def_readonly("index", &s::SlamScanReport::index)
      .def_readonly("registered", &s::SlamScanReport::registered)
      .def_readonly("integrated", &s::SlamScanReport::integrated)
      .def_readonly("reason", &s::SlamScanReport::reason)
      .def_readonly("held_directions", &s::SlamScanReport::held_directions)
      .def_readonly("submap", &s::SlamScanReport::submap)
      .def_property_readonly("local_pose", [](const s::SlamScanReport& x) { return pose_to_numpy(x.local_pose); })
      .def_readonly("closures", &s::SlamScanReport::closures);
  py::class_<s::LoopClosure>(m, "LoopClosure")
      .def_readonly("scan", &s::LoopClosure::scan)
      .def_readonly("submap", &s::LoopClosure::submap)
      .def_property_readonly("relative", [](const s::LoopClosure& x) { return pose_to_numpy(x.relative); })
      .def_readonly("coarse_score", &s::LoopClosure::coarse_score)
      .def_readonly("inlier_fraction", &s::LoopClosure::inlier_fraction)
      .def_readonly("external", &s::LoopClosure::external)
      .def_readonly("rejected", &s::LoopClosure::rejected);
  py::class_<s::SlamSummary>(m, "SlamSummary")
      .def_readonly("scans", &s::SlamSummary::scans)
      .def_readonly("registered", &s::SlamSummary::registered)
      .def_readonly("refused", &s::SlamSummary::refused)
      .def_readonly("held_back", &s::SlamSummary::held_back)
      .def_readonly("submaps", &s::SlamSummary::submaps)
      .def_readonly("closure_attempts", &s::SlamSummary::closure_attempts)
      .def_readonly("closures_found", &s::SlamSummary::closures_found)
      .def_readonly("closures_refused_by_matcher", &s::SlamSummary::closures_refused_by_matcher)
      .def_readonly("closures_rejected_by_optimizer", &s::SlamSummary::closures_rejected_by_optimizer)
      .def_readonly("optimizations", &s::SlamSummary::optimizations);
  // Not thread-safe, as in C++: one Python thread at a time (its optimizer's worker never calls
  // back into Python).
  py::class_<s::PoseGraphMapper>(m, "PoseGraphMapper",
                                 "Mapping over long runs: submaps, loop closure, a pose graph optimized in the "
                                 "background.")
      .def(py::init([](ExecutionMode mode, const s::PoseGraphMapperOptions& o) {
             return std::make_unique<s::PoseGraphMapper>(mode, o);
           }),
           py::arg("mode") = ExecutionMode::kSequential, py::arg("options") = s::PoseGraphMapperOptions{})
      .def(
          "add_scan",
          [](s::PoseGraphMapper& g, const ArrayLike& pose, const ArrayLike& points, const py::object& intensities) {
            const Eigen::Isometry3d t = pose_from(pose, "navigation_pose");
            Eigen::MatrixXd p = points_from(points, "points_sensor");
            Eigen::VectorXd i = intensities.is_none() ? Eigen::VectorXd::Constant(p.rows(), g.options().params.intensity_max)
                                                      : values_from(intensities, "intensities", p.rows());
            py::gil_scoped_release release;
            return g.add_scan(t, std::move(p), std::move(i));
          },
          py::arg("navigation_pose"), py::arg("points_sensor"), py::arg("intensities") = py::none(),
          "Adds a scan: (N, 3) points in the sensor frame, metres; intensities (N,) or None (every point a "
          "return at intensity_max); navigation_pose (4, 4) sensor to world.")
      .def(
          "add_loop_closure",
          [](s::PoseGraphMapper& g, std::size_t scan, std::size_t submap, const ArrayLike& relative,
             const ArrayLike& information) {
            const Eigen::Isometry3d t = pose_from(relative, "relative");
            return g.add_loop_closure(scan, submap, t, information_from(information));
          },
          py::arg("scan"), py::arg("submap"), py::arg("relative"), py::arg("information"))
      .def("optimize", [](s::PoseGraphMapper& g) { g.optimize(); }, py::call_guard<py::gil_scoped_release>(),
           "Starts an optimization of the graph so far (parallel mode: on the worker, without waiting)")
      .def("write_map", [](s::PoseGraphMapper& g) { return g.write_map(); }, py::call_guard<py::gil_scoped_release>(),
           "Waits for the optimization and applies its poses; False when there was none to apply")
      .def("finish", &s::PoseGraphMapper::finish, py::call_guard<py::gil_scoped_release>(),
           "Optimizes everything, rebuilds the global map, waits and applies both")
      .def("terminate", [](s::PoseGraphMapper& g) { g.terminate(); }, py::call_guard<py::gil_scoped_release>(),
           "Stops a running optimization (its result is discarded)")
      .def("is_running", [](const s::PoseGraphMapper& g) { return g.is_running(); })
      .def("poses", [](const s::PoseGraphMapper& g) { return poses_to_list(g.poses()); },
           "Best pose of every scan so far: list of (4, 4), sensor to world")
      .def("map", &s::PoseGraphMapper::map, "The global map (see the C++ documentation)")
      .def("build_map", [](const s::PoseGraphMapper& g) { return std::shared_ptr<IMapperBackend>(g.build_map()); },
           py::call_guard<py::gil_scoped_release>(), "A new map: every scan re-integrated at poses()")
      .def("loop_closures", &s::PoseGraphMapper::loop_closures)
      .def("summary", &s::PoseGraphMapper::summary)
      .def("num_submaps", &s::PoseGraphMapper::num_submaps)
      .def("submap_first_scan", &s::PoseGraphMapper::submap_first_scan, py::arg("submap"));
  py::class_<s::SonarPoseGraphMapperOptions>(m, "SonarPoseGraphMapperOptions",
                                             "Loop closure for sonar surveys (see SonarPoseGraphMapper).")
      .def(py::init<>())
      .def_readwrite("pings_per_submap", &s::SonarPoseGraphMapperOptions::pings_per_submap)
      .def_readwrite("max_submap_turn_deg", &s::SonarPoseGraphMapperOptions::max_submap_turn_deg)
      .def_readwrite("min_submap_voxels", &s::SonarPoseGraphMapperOptions::min_submap_voxels)
      .def_readwrite("matcher", &s::SonarPoseGraphMapperOptions::matcher,
                     "ScanMatcherOptions; by default branch and bound in +-2 m and +-5 degrees, then planar ICP")
      .def_readwrite("max_fitness_rmse", &s::SonarPoseGraphMapperOptions::max_fitness_rmse,
                     "metres; negative: 1.2 voxels; 0: no limit")
      .def_readwrite("closure_max_distance", &s::SonarPoseGraphMapperOptions::closure_max_distance)
      .def_readwrite("closure_max_heading_difference_deg",
                     &s::SonarPoseGraphMapperOptions::closure_max_heading_difference_deg)
      .def_readwrite("closure_min_submap_gap", &s::SonarPoseGraphMapperOptions::closure_min_submap_gap)
      .def_readwrite("min_closure_pings", &s::SonarPoseGraphMapperOptions::min_closure_pings)
      .def("validate", &s::SonarPoseGraphMapperOptions::validate);
  py::class_<s::SonarSubmapReport>(m, "SonarSubmapReport")
      .def_readonly("first_ping", &s::SonarSubmapReport::first_ping)
      .def_readonly("pings", &s::SonarSubmapReport::pings)
      .def_readonly("occupied_voxels", &s::SonarSubmapReport::occupied_voxels)
      .def_readonly("closure_attempts", &s::SonarSubmapReport::closure_attempts)
      .def_readonly("closures", &s::SonarSubmapReport::closures)
      .def_readonly("refusals", &s::SonarSubmapReport::refusals);
  py::class_<s::SonarLoopClosure>(m, "SonarLoopClosure")
      .def_readonly("submap", &s::SonarLoopClosure::submap)
      .def_readonly("target", &s::SonarLoopClosure::target)
      .def_property_readonly("relative", [](const s::SonarLoopClosure& x) { return pose_to_numpy(x.relative); })
      .def_readonly("fitness_rmse", &s::SonarLoopClosure::fitness_rmse)
      .def_readonly("rejected", &s::SonarLoopClosure::rejected);
  py::class_<s::SonarSlamSummary>(m, "SonarSlamSummary")
      .def_readonly("pings", &s::SonarSlamSummary::pings)
      .def_readonly("submaps", &s::SonarSlamSummary::submaps)
      .def_readonly("closure_attempts", &s::SonarSlamSummary::closure_attempts)
      .def_readonly("closures_found", &s::SonarSlamSummary::closures_found)
      .def_readonly("closures_refused", &s::SonarSlamSummary::closures_refused)
      .def_readonly("closures_rejected_by_optimizer", &s::SonarSlamSummary::closures_rejected_by_optimizer)
      .def_readonly("optimizations", &s::SonarSlamSummary::optimizations)
      .def_readonly("observations", &s::SonarSlamSummary::observations);
  py::class_<s::SonarPoseGraphMapper>(m, "SonarPoseGraphMapper",
                                      "Sonar surveys that revisit their lines: submaps matched against older ones "
                                      "of the same place and heading, a pose graph, every ping mapped at its "
                                      "corrected pose by finish().")
      .def(py::init([](std::shared_ptr<IMapperBackend> map, const SonarImageProjector& projector,
                       const s::SonarPoseGraphMapperOptions& o) {
             return std::make_unique<s::SonarPoseGraphMapper>(std::move(map), projector, o);
           }),
           py::arg("map"), py::arg("projector"), py::arg("options") = s::SonarPoseGraphMapperOptions{})
      .def(
          "integrate",
          [](s::SonarPoseGraphMapper& g, const ArrayLike& nav_pose, const ArrayLike& image,
             const SonarGeometry& geometry) {
            const Eigen::Isometry3d t = pose_from(nav_pose, "nav_pose");
            const py::array a = as_array(image, "image");
            const SonarImageView view = image_view_of(a);
            py::gil_scoped_release release;
            g.integrate(t, view, geometry);  // copies the image
          },
          py::arg("nav_pose"), py::arg("image"), py::arg("geometry"),
          "Adds a ping: image (range_bins, beams) taken at nav_pose (4, 4), sonar to map frame.")
      .def("finish", [](s::SonarPoseGraphMapper& g) { g.finish(); }, py::call_guard<py::gil_scoped_release>(),
           "Closes the last submap and maps every ping at its corrected pose (once)")
      .def("poses", [](const s::SonarPoseGraphMapper& g) { return poses_to_list(g.poses()); },
           "Corrected pose of every ping so far: list of (4, 4), sonar to map")
      .def("submaps", &s::SonarPoseGraphMapper::submaps)
      .def("loop_closures", &s::SonarPoseGraphMapper::loop_closures)
      .def("summary", &s::SonarPoseGraphMapper::summary);
  m.attr("HAS_SLAM") = true;
#else
  m.attr("HAS_SLAM") = false;
#endif
}

}  // namespace iwlomap::python
