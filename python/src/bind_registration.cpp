// SPDX-License-Identifier: BSD-3-Clause
// Registration (with the registration layer): the coarse branch-and-bound matcher, the
// ScanMatcher (coarse + ICP) and the RegisteredMapper.

#include "bindings.h"
#include "numpy_io.h"

#ifdef IWLOMAP_PYTHON_REGISTRATION
#include <iwlomap/registration/correlative_scan_matcher.h>
#include <iwlomap/registration/registered_mapper.h>
#include <iwlomap/registration/registered_sonar_mapper.h>
#include <iwlomap/registration/scan_matcher.h>
#endif

#include <pybind11/stl.h>

namespace iwlomap::python {

void bind_registration(py::module_& m) {
#ifdef IWLOMAP_PYTHON_REGISTRATION
  using registration::CoarseMatch;
  using registration::CorrelativeScanMatcher3D;
  using registration::SearchWindow3D;
  const SearchWindow3D d;
  py::class_<SearchWindow3D>(m, "SearchWindow3D", "The poses searched around an initial pose (metres, radians).")
      .def(py::init([](double xy, double z, double yaw) {
             SearchWindow3D w{xy, z, yaw};
             w.validate();
             return w;
           }),
           py::kw_only(), py::arg("linear_xy") = d.linear_xy, py::arg("linear_z") = d.linear_z,
           py::arg("angular_yaw") = d.angular_yaw)
      .def_readwrite("linear_xy", &SearchWindow3D::linear_xy)
      .def_readwrite("linear_z", &SearchWindow3D::linear_z)
      .def_readwrite("angular_yaw", &SearchWindow3D::angular_yaw)
      .def("validate", &SearchWindow3D::validate);
  py::class_<CoarseMatch>(m, "CoarseMatch")
      .def_readonly("found", &CoarseMatch::found)
      .def_property_readonly("pose", [](const CoarseMatch& c) { return pose_to_numpy(c.pose); }, "(4, 4) sensor to map")
      .def_readonly("score", &CoarseMatch::score)
      .def_readonly("score_sum", &CoarseMatch::score_sum)
      .def_readonly("yaw_steps", &CoarseMatch::yaw_steps)
      .def_readonly("yaw_step", &CoarseMatch::yaw_step)
      .def_readonly("candidates", &CoarseMatch::candidates)
      .def_readonly("nodes_visited", &CoarseMatch::nodes_visited)
      .def_readonly("reason", &CoarseMatch::reason);
  py::class_<CorrelativeScanMatcher3D>(m, "CorrelativeScanMatcher3D",
                                       "Exact branch and bound over the max grids (x, y, z in voxels, yaw).")
      .def_static(
          "for_scan",
          [](IMapperBackend& map, const ArrayLike& scan, const ArrayLike& initial, const SearchWindow3D& window,
             int num_levels, int dilation) {
            const Eigen::MatrixXd s = points_from(scan, "scan_sensor");
            const Eigen::Isometry3d p = pose_from(initial, "initial");
            return unlocked(map, [&] { return CorrelativeScanMatcher3D::for_scan(map, s, p, window, num_levels, dilation); });
          },
          py::arg("map"), py::arg("scan_sensor"), py::arg("initial"), py::arg("window") = SearchWindow3D{},
          py::arg("num_levels") = 7, py::arg("dilation") = 1)
      .def(
          "match",
          [](const CorrelativeScanMatcher3D& c, const ArrayLike& scan, const ArrayLike& initial,
             const SearchWindow3D& window, double min_score) {
            const Eigen::MatrixXd s = points_from(scan, "scan_sensor");
            const Eigen::Isometry3d p = pose_from(initial, "initial");
            py::gil_scoped_release release;
            return c.match(s, p, window, min_score);
          },
          py::arg("scan_sensor"), py::arg("initial"), py::arg("window") = SearchWindow3D{}, py::arg("min_score") = 0.0)
      .def(
          "match_exhaustive",
          [](const CorrelativeScanMatcher3D& c, const ArrayLike& scan, const ArrayLike& initial,
             const SearchWindow3D& window, double min_score) {
            const Eigen::MatrixXd s = points_from(scan, "scan_sensor");
            const Eigen::Isometry3d p = pose_from(initial, "initial");
            py::gil_scoped_release release;
            return c.match_exhaustive(s, p, window, min_score);
          },
          py::arg("scan_sensor"), py::arg("initial"), py::arg("window") = SearchWindow3D{}, py::arg("min_score") = 0.0);

  namespace r = iwlomap::registration;
  const r::IcpOptions icp;
  py::class_<r::IcpOptions>(m, "IcpOptions", "Point-to-plane ICP settings (metres, radians).")
      .def(py::init<>())
      .def_readwrite("max_iterations", &r::IcpOptions::max_iterations)
      .def_readwrite("max_correspondence_distance", &r::IcpOptions::max_correspondence_distance)
      .def_readwrite("huber_delta", &r::IcpOptions::huber_delta)
      .def_readwrite("translation_tolerance", &r::IcpOptions::translation_tolerance)
      .def_readwrite("rotation_tolerance", &r::IcpOptions::rotation_tolerance)
      .def_readwrite("min_inlier_fraction", &r::IcpOptions::min_inlier_fraction)
      .def_readwrite("degeneracy_ratio", &r::IcpOptions::degeneracy_ratio)
      .def_readwrite("planar", &r::IcpOptions::planar, "x, y and yaw only; z, roll, pitch held at the initial pose")
      .def_readwrite("inlier_distance", &r::IcpOptions::inlier_distance,
                     "metres: a paired point this close to its map point's tangent plane is an inlier")
      .def_readwrite("overlap_distance", &r::IcpOptions::overlap_distance,
                     "metres: a point with a map point this close is in the overlap")
      .def("validate", &r::IcpOptions::validate);
  py::class_<r::MatchQualityOptions>(m, "MatchQualityOptions",
                                     "When a registration counts as converged (the match-quality model).")
      .def(py::init<>())
      .def_readwrite("min_inlier_fraction", &r::MatchQualityOptions::min_inlier_fraction)
      .def_readwrite("min_axis_support", &r::MatchQualityOptions::min_axis_support)
      .def_readwrite("max_free_conflict", &r::MatchQualityOptions::max_free_conflict)
      .def_readwrite("max_coarse_disagreement", &r::MatchQualityOptions::max_coarse_disagreement,
                     "voxels (and coarse yaw steps) ICP may move the coarse pose")
      .def_readwrite("edge_margin", &r::MatchQualityOptions::edge_margin,
                     "voxels (yaw: steps) from the window's edge that trigger a second coarse search")
      .def_readwrite("hold_unconstrained", &r::MatchQualityOptions::hold_unconstrained,
                     "keep unconstrained directions at the initial pose (True) or refuse such scans")
      .def("validate", &r::MatchQualityOptions::validate);
  py::class_<r::ScanMatcherOptions>(m, "ScanMatcherOptions", "Both stages' settings.")
      .def(py::init<>())
      .def_readwrite("coarse", &r::ScanMatcherOptions::coarse)
      .def_readwrite("fine", &r::ScanMatcherOptions::fine)
      .def_readwrite("window", &r::ScanMatcherOptions::window)
      .def_readwrite("min_coarse_score", &r::ScanMatcherOptions::min_coarse_score)
      .def_readwrite("coarse_points", &r::ScanMatcherOptions::coarse_points)
      .def_readwrite("coarse_max_range", &r::ScanMatcherOptions::coarse_max_range)
      .def_readwrite("coarse_levels", &r::ScanMatcherOptions::coarse_levels)
      .def_readwrite("max_range", &r::ScanMatcherOptions::max_range)
      .def_readwrite("scan_voxel", &r::ScanMatcherOptions::scan_voxel)
      .def_readwrite("mean_hit_positions", &r::ScanMatcherOptions::mean_hit_positions)
      .def_readwrite("min_probability", &r::ScanMatcherOptions::min_probability)
      .def_readwrite("icp", &r::ScanMatcherOptions::icp)
      .def_readwrite("quality", &r::ScanMatcherOptions::quality)
      .def("validate", &r::ScanMatcherOptions::validate);
  py::class_<r::ScanMatchResult>(m, "ScanMatchResult")
      .def_property_readonly("pose", [](const r::ScanMatchResult& x) { return pose_to_numpy(x.pose); },
                             "(4, 4) sensor to map; the initial pose when not converged")
      .def_readonly("score", &r::ScanMatchResult::score)
      .def_readonly("fitness_rmse", &r::ScanMatchResult::fitness_rmse)
      .def_readonly("iterations", &r::ScanMatchResult::iterations)
      .def_readonly("converged", &r::ScanMatchResult::converged)
      .def_readonly("reason", &r::ScanMatchResult::reason)
      .def_readonly("coarse_score", &r::ScanMatchResult::coarse_score)
      .def_readonly("scan_points", &r::ScanMatchResult::scan_points)
      .def_readonly("pairs", &r::ScanMatchResult::pairs)
      .def_property_readonly("covariance", [](const r::ScanMatchResult& x) { return to_numpy(Eigen::MatrixXd(x.covariance)); },
                             "(6, 6): tx, ty, tz (m), rotations about the map's axes through the scan's centroid (rad)")
      .def_readonly("inlier_fraction", &r::ScanMatchResult::inlier_fraction)
      .def_readonly("overlap_fraction", &r::ScanMatchResult::overlap_fraction)
      .def_property_readonly("axis_support", [](const r::ScanMatchResult& x) { return to_numpy(Eigen::VectorXd(x.axis_support)); },
                             "(3,): per map axis, the share of the overlap facing it that fits")
      .def_readonly("free_conflict", &r::ScanMatchResult::free_conflict)
      .def_readonly("icp_shift", &r::ScanMatchResult::icp_shift)
      .def_readonly("icp_turn", &r::ScanMatchResult::icp_turn)
      .def_readonly("held_directions", &r::ScanMatchResult::held_directions)
      .def_property_readonly("unobservable", [](const r::ScanMatchResult& x) { return to_numpy(Eigen::MatrixXd(x.unobservable)); },
                             "(6, K): directions the scene does not constrain");
  // The matcher keeps a reference to the map: the Python object keeps the map alive.
  py::class_<r::ScanMatcher>(m, "ScanMatcher", "Registers scans against one state of a map (coarse, then ICP).")
      .def(py::init([](IMapperBackend& map, const r::ScanMatcherOptions& o) {
             return unlocked(map, [&] { return std::make_unique<r::ScanMatcher>(map, o); });
           }),
           py::arg("map"), py::arg("options") = r::ScanMatcherOptions{}, py::keep_alive<1, 2>())
      .def(
          "match",
          [](const r::ScanMatcher& s, const ArrayLike& scan, const ArrayLike& initial) {
            const Eigen::MatrixXd p = points_from(scan, "scan_sensor");
            const Eigen::Isometry3d t = pose_from(initial, "initial");
            py::gil_scoped_release release;
            return s.match(p, t);
          },
          py::arg("scan_sensor"), py::arg("initial"),
          "Registers scan_sensor (N, 3), metres, sensor frame, near initial (4, 4), sensor to map.");
  py::class_<r::RegisteredScan>(m, "RegisteredScan")
      .def_property_readonly("given_pose", [](const r::RegisteredScan& x) { return pose_to_numpy(x.given_pose); })
      .def_property_readonly("initial_guess", [](const r::RegisteredScan& x) { return pose_to_numpy(x.initial_guess); })
      .def_property_readonly("integrated_pose", [](const r::RegisteredScan& x) { return pose_to_numpy(x.integrated_pose); })
      .def_readonly("registered", &r::RegisteredScan::registered)
      .def_readonly("match", &r::RegisteredScan::match);
  py::class_<r::RegisteredMapper>(m, "RegisteredMapper",
                                  "Mapping with registration: each scan registered against the map so far.")
      .def(py::init([](std::shared_ptr<IMapperBackend> map, ExecutionMode mode, const r::ScanMatcherOptions& o,
                       double max_range, std::size_t capacity) {
             r::RegisteredMapperOptions ro;
             ro.matcher = o;
             ro.max_range = max_range;
             return std::make_unique<r::RegisteredMapper>(std::move(map), mode, ro, capacity);
           }),
           py::arg("map"), py::arg("mode") = ExecutionMode::kSequential, py::arg("options") = r::ScanMatcherOptions{},
           py::arg("max_range") = -1.0, py::arg("queue_capacity") = 4)
      .def(
          "integrate",
          [](r::RegisteredMapper& rm, const ArrayLike& pose, const ArrayLike& points, const ArrayLike& intensities) {
            const Eigen::Isometry3d t = pose_from(pose, "pose");
            Eigen::MatrixXd p = points_from(points, "points_sensor");
            if (intensities.is_none()) {
              py::gil_scoped_release release;
              rm.integrate(t, std::move(p));
              return;
            }
            Eigen::VectorXd i = values_from(intensities, "intensities", p.rows());
            py::gil_scoped_release release;
            rm.integrate(t, std::move(p), std::move(i));
          },
          py::arg("pose"), py::arg("points_sensor"), py::arg("intensities") = py::none(),
          "Queues a scan (points (N, 3) in the sensor frame; intensities (N,) or None: every point a return at the "
          "map's intensity_max).")
      .def("sync", &r::RegisteredMapper::sync, py::call_guard<py::gil_scoped_release>())
      .def("correction", [](r::RegisteredMapper& rm) {
        Eigen::Isometry3d c;
        {
          py::gil_scoped_release release;
          c = rm.correction();
        }
        return pose_to_numpy(c);
      });
  py::class_<r::RegisteredSonarMapperOptions>(m, "RegisteredSonarMapperOptions",
                                              "Sonar registration by submaps (see RegisteredSonarMapper).")
      .def(py::init<>())
      .def_readwrite("matcher", &r::RegisteredSonarMapperOptions::matcher,
                     "ScanMatcherOptions; by default no coarse stage and planar ICP")
      .def_readwrite("pings_per_submap", &r::RegisteredSonarMapperOptions::pings_per_submap)
      .def_readwrite("min_submap_voxels", &r::RegisteredSonarMapperOptions::min_submap_voxels)
      .def_readwrite("max_fitness_rmse", &r::RegisteredSonarMapperOptions::max_fitness_rmse,
                     "metres; negative: 1.2 voxels; 0: no limit");
  py::class_<r::RegisteredSubmap>(m, "RegisteredSubmap")
      .def_readonly("first_ping", &r::RegisteredSubmap::first_ping)
      .def_readonly("pings", &r::RegisteredSubmap::pings)
      .def_readonly("occupied_voxels", &r::RegisteredSubmap::occupied_voxels)
      .def_property_readonly("given_pose", [](const r::RegisteredSubmap& x) { return pose_to_numpy(x.given_pose); })
      .def_property_readonly("initial_guess", [](const r::RegisteredSubmap& x) { return pose_to_numpy(x.initial_guess); })
      .def_property_readonly("correction", [](const r::RegisteredSubmap& x) { return pose_to_numpy(x.correction); })
      .def_readonly("registered", &r::RegisteredSubmap::registered)
      .def_readonly("match", &r::RegisteredSubmap::match)
      .def_readonly("observations", &r::RegisteredSubmap::observations)
      .def_readonly("beams_with_return", &r::RegisteredSubmap::beams_with_return)
      .def_readonly("beams_without_return", &r::RegisteredSubmap::beams_without_return)
      .def_property_readonly(
          "integrated_poses",
          [](const r::RegisteredSubmap& x) {
            py::list out;
            for (const Eigen::Isometry3d& p : x.integrated_poses) out.append(pose_to_numpy(p));
            return out;
          },
          "per ping, (4, 4) sonar to map: where it went into the map");
  py::class_<r::RegisteredSonarMapper>(
      m, "RegisteredSonarMapper",
      "Sonar mapping with registration: pings gathered into submaps, each registered against the map.")
      .def(py::init([](std::shared_ptr<IMapperBackend> map, const SonarImageProjector& projector, ExecutionMode mode,
                       const r::RegisteredSonarMapperOptions& o, std::size_t capacity) {
             return std::make_unique<r::RegisteredSonarMapper>(std::move(map), projector, mode, o, capacity);
           }),
           py::arg("map"), py::arg("projector"), py::arg("mode") = ExecutionMode::kSequential,
           py::arg("options") = r::RegisteredSonarMapperOptions{}, py::arg("queue_capacity") = 2)
      .def(
          "integrate",
          [](r::RegisteredSonarMapper& rm, const ArrayLike& nav_pose, const ArrayLike& image,
             const SonarGeometry& geometry) {
            const Eigen::Isometry3d t = pose_from(nav_pose, "nav_pose");
            const py::array a = as_array(image, "image");
            const SonarImageView view = image_view_of(a);
            py::gil_scoped_release release;
            rm.integrate(t, view, geometry);  // copies the image
          },
          py::arg("nav_pose"), py::arg("image"), py::arg("geometry"),
          "Adds a ping: image (range_bins, beams) taken at nav_pose (4, 4), sonar to map frame.")
      .def("sync", &r::RegisteredSonarMapper::sync, py::call_guard<py::gil_scoped_release>())
      .def("correction", [](r::RegisteredSonarMapper& rm) {
        Eigen::Isometry3d c;
        {
          py::gil_scoped_release release;
          c = rm.correction();
        }
        return pose_to_numpy(c);
      });
  m.attr("HAS_REGISTRATION") = true;
#else
  m.attr("HAS_REGISTRATION") = false;
#endif
}

}  // namespace iwlomap::python
