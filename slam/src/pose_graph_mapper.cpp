// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/slam/pose_graph_mapper.h"

#include <algorithm>
#include <cstddef>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace iwlomap::slam {

namespace detail {

// A scan as kept for the map: sensor frame, finite rows only.
struct SlamScan {
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
};

// A snapshot for one optimization: the graph over scans (nodes 0 .. scans - 1) and submaps (nodes
// scans ..), and the scans for the map rebuild.
struct SlamGraphData {
  PoseGraph graph;
  std::size_t scans = 0;
  std::vector<std::shared_ptr<const SlamScan>> scan_refs;
  std::vector<bool> integrated;
  std::vector<std::size_t> closure_constraint;
  bool rebuild = false;
};

struct SlamOutput {
  PoseGraphSolution solution;
  std::size_t scans = 0;
  std::vector<bool> closure_rejected;
  std::shared_ptr<IMapperBackend> map;  // null when not rebuilt
};

}  // namespace detail

struct PoseGraphMapper::Submap {
  std::unique_ptr<IMapperBackend> map;  // in the submap's frame
  Eigen::Isometry3d origin = Eigen::Isometry3d::Identity();  // local frame
  std::size_t first_scan = 0;
  std::size_t last_scan = 0;
  std::size_t inserted = 0;
  std::vector<Eigen::Vector3d> positions;  // its scans' local positions
  bool finished = false;
  // Built when it finishes, for loop-closure matching (surface and k-d tree once, not per scan).
  std::shared_ptr<const registration::MapSurface> surface;
  // Distance from \p p to the nearest of its scans' positions (local frame).
  [[nodiscard]] double distance_to(const Eigen::Vector3d& p) const {
    double d = std::numeric_limits<double>::infinity();
    for (const Eigen::Vector3d& q : positions) d = std::min(d, (q - p).norm());
    return d;
  }
};

namespace {

double translation_of(const Eigen::Isometry3d& p) { return p.translation().norm(); }

// The ICP surface of \p map as \p o would build it (occupied voxels, at their mean hit positions
// when asked and kept); null when the map has fewer than the 8 points a surface needs.
std::shared_ptr<const registration::MapSurface> surface_of(IMapperBackend& map, const registration::ScanMatcherOptions& o) {
  const double threshold = o.min_probability < 0.0 ? map.get_params().occupied_threshold : o.min_probability;
  const Eigen::MatrixXd v = o.mean_hit_positions && map.get_hit_accumulation()
                                ? map.get_occupied_mean_positions(threshold)
                                : map.get_occupied_voxels(threshold);
  if (v.rows() < 8) return nullptr;
  return std::make_shared<const registration::MapSurface>(Eigen::MatrixXd(v.leftCols<3>()));
}

Eigen::Isometry3d tidy(const Eigen::Isometry3d& p) {
  Eigen::Isometry3d out = p;
  out.linear() = Eigen::Quaterniond(p.linear()).normalized().toRotationMatrix();
  return out;
}

}  // namespace

registration::ScanMatcherOptions PoseGraphMapperOptions::default_closure_matcher() {
  registration::ScanMatcherOptions o;
  o.window.linear_xy = 5.0;
  o.window.linear_z = 1.0;
  o.window.angular_yaw = 15.0 * 3.14159265358979323846 / 180.0;
  o.min_coarse_score = 0.55;
  o.quality.min_inlier_fraction = 0.4;
  o.quality.min_axis_support = 0.6;
  o.quality.hold_unconstrained = false;  // a closure must constrain every direction
  return o;
}

void PoseGraphMapperOptions::validate() const {
  const auto positive = [](const char* name, double v) {
    if (!(v > 0.0) || !std::isfinite(v))
      throw std::invalid_argument(std::string("iwlomap: PoseGraphMapperOptions: ") + name + " = " +
                                  std::to_string(v) + " must be finite and > 0");
  };
  positive("resolution", resolution);
  if (scans_per_submap < 2)
    throw std::invalid_argument("iwlomap: PoseGraphMapperOptions: scans_per_submap must be >= 2, got " +
                                std::to_string(scans_per_submap));
  if (closure_stride < 1) throw std::invalid_argument("iwlomap: PoseGraphMapperOptions: closure_stride must be >= 1");
  positive("closure_max_distance", closure_max_distance);
  positive("submap_translation_sigma", submap_translation_sigma);
  positive("submap_rotation_sigma", submap_rotation_sigma);
  positive("closure_translation_sigma", closure_translation_sigma);
  positive("closure_rotation_sigma", closure_rotation_sigma);
  positive("odometry_translation_sigma_per_metre", odometry_translation_sigma_per_metre);
  positive("odometry_rotation_sigma_per_metre", odometry_rotation_sigma_per_metre);
  positive("odometry_translation_sigma_floor", odometry_translation_sigma_floor);
  positive("odometry_rotation_sigma_floor", odometry_rotation_sigma_floor);
  positive("unconstrained_sigma", unconstrained_sigma);
  if (std::isnan(max_range)) throw std::invalid_argument("iwlomap: PoseGraphMapperOptions: max_range is NaN");
  params.validate();
  matcher.validate();
  closure_matcher.validate();
  solver.validate();
}

PoseGraphMapper::PoseGraphMapper(ExecutionMode mode, PoseGraphMapperOptions options)
    : Optimizer(mode), options_(std::move(options)) {
  options_.validate();
  map_ = new_map();
}

PoseGraphMapper::~PoseGraphMapper() { terminate(); }

std::unique_ptr<IMapperBackend> PoseGraphMapper::new_map() const {
  std::unique_ptr<IMapperBackend> m =
      options_.make_map ? options_.make_map(options_.resolution) : make_backend("RAM", options_.resolution);
  if (!m) throw std::invalid_argument("iwlomap: PoseGraphMapper: make_map returned no map");
  m->set_params(options_.params);
  m->set_ray_model(options_.rays);
  if (m->supports(BackendFeature::kHitStatistics)) m->set_hit_accumulation(true);
  return m;
}

void PoseGraphMapper::insert(IMapperBackend& map, const Scan& scan, const Eigen::Isometry3d& pose) const {
  const Eigen::MatrixXd world = (scan.points * pose.linear().transpose()).rowwise() + pose.translation().transpose();
  map.insert_scan(pose.translation(), world, scan.intensities, options_.max_range);
}

Eigen::Isometry3d PoseGraphMapper::correction() const {
  if (applied_scans_ == 0) return Eigen::Isometry3d::Identity();
  return tidy(optimized_[applied_scans_ - 1] * local_[applied_scans_ - 1].inverse());
}

SlamScanReport PoseGraphMapper::add_scan(const Eigen::Isometry3d& navigation_pose, Eigen::MatrixXd points_sensor,
                                         Eigen::VectorXd intensities) {
  if (!navigation_pose.matrix().allFinite())
    throw std::invalid_argument("iwlomap: PoseGraphMapper: the navigation pose is not finite");
  if (points_sensor.cols() != 3 && points_sensor.rows() > 0)
    throw std::invalid_argument("iwlomap: PoseGraphMapper: the scan has " + std::to_string(points_sensor.cols()) +
                                " columns, expected 3");
  if (intensities.size() != points_sensor.rows())
    throw std::invalid_argument("iwlomap: PoseGraphMapper: " + std::to_string(intensities.size()) +
                                " intensities for " + std::to_string(points_sensor.rows()) + " points");
  auto scan = std::make_shared<detail::SlamScan>();
  {
    Eigen::Index n = 0;
    for (Eigen::Index i = 0; i < points_sensor.rows(); ++i) n += points_sensor.row(i).allFinite() ? 1 : 0;
    scan->points.resize(n, 3);
    scan->intensities.resize(n);
    n = 0;
    for (Eigen::Index i = 0; i < points_sensor.rows(); ++i)
      if (points_sensor.row(i).allFinite()) {
        scan->points.row(n) = points_sensor.row(i);
        scan->intensities[n++] = intensities[i];
      }
  }
  if (scan->points.rows() == 0) throw std::invalid_argument("iwlomap: PoseGraphMapper: the scan has no finite point");

  const std::size_t index = scans_.size();
  SlamScanReport report;
  report.index = index;
  // The prior: the last local pose moved as the navigation moved.
  const Eigen::Isometry3d prior =
      index == 0 ? tidy(navigation_pose) : tidy(local_.back() * navigation_.back().inverse() * navigation_pose);
  Eigen::Isometry3d local = prior;
  registration::ScanMatchResult match;
  bool matched = false;
  // The front end: against the oldest active submap (the one holding the most scans).
  std::size_t target = submaps_.size();
  for (std::size_t j = 0; j < submaps_.size(); ++j)
    if (!submaps_[j]->finished) {
      target = j;
      break;
    }
  if (target < submaps_.size() && submaps_[target]->map->get_num_known_voxels() > 0) {
    Submap& s = *submaps_[target];
    // ICP from the prior first (the navigation's step error is small); the branch and bound only
    // when that is refused. The map's surface is built once for both.
    const Eigen::Isometry3d guess = s.origin.inverse() * prior;
    if (const auto surface = surface_of(*s.map, options_.matcher)) {
      if (options_.matcher.fine) {
        registration::ScanMatcherOptions icp_only = options_.matcher;
        icp_only.coarse = false;
        match = registration::ScanMatcher(*s.map, surface, icp_only).match(scan->points, guess);
      }
      if (!match.converged && options_.matcher.coarse)
        match = registration::ScanMatcher(*s.map, surface, options_.matcher).match(scan->points, guess);
    } else {
      match.reason = "the submap has fewer than 8 occupied voxels";
    }
    matched = true;
    report.submap = target;
    if (match.converged) {
      local = tidy(s.origin * match.pose);
      report.registered = true;
      report.held_directions = match.held_directions;
    } else {
      report.reason = match.reason;
    }
  } else {
    report.reason = index == 0 ? "" : "no submap to register against";
  }
  report.integrated = report.registered || index == 0 || options_.refused == RefusedScanPolicy::kIntegrateAtPrior;
  report.local_pose = local;

  // A new submap every half of scans_per_submap scans (the first with the first scan).
  const std::size_t half = static_cast<std::size_t>(std::max(1, options_.scans_per_submap / 2));
  if (submaps_.empty() || ((report.registered || index == 0) && submaps_.back()->inserted >= half)) {
    auto s = std::make_unique<Submap>();
    s->map = new_map();
    s->origin = local;
    s->first_scan = index;
    submaps_.push_back(std::move(s));
  }

  scans_.push_back(scan);
  navigation_.push_back(tidy(navigation_pose));
  local_.push_back(local);
  integrated_.push_back(report.integrated);
  ++summary_.scans;
  if (report.registered) ++summary_.registered;
  if (matched && !report.registered) ++summary_.refused;
  if (!report.integrated) ++summary_.held_back;

  // Odometry from the previous scan (the navigation's motion, its uncertainty growing with the
  // distance travelled) where registration does not tie the two scans together: either was not
  // registered, or left directions unconstrained. Between registered scans the submaps relate
  // them far more closely, and a navigation that drifts would only bias them.
  const bool tied = index > 0 && report.registered && report.held_directions == 0 && registered_.back();
  registered_.push_back(report.registered && report.held_directions == 0);
  if (index > 0 && !tied) {
    PoseConstraint c;
    c.from = index - 1;
    c.to = index;
    c.kind = ConstraintKind::kOdometry;
    c.measurement = tidy(navigation_[index - 1].inverse() * navigation_[index]);
    const double d = translation_of(c.measurement);
    c.information = information_from_sigmas(
        std::max(options_.odometry_translation_sigma_floor, options_.odometry_translation_sigma_per_metre * d),
        std::max(options_.odometry_rotation_sigma_floor, options_.odometry_rotation_sigma_per_metre * d));
    constraints_.push_back(c);
  }

  // Only registered scans (and the first) go into the submaps: a scan at a doubtful pose would
  // pull the next scans' registrations after it.
  if (report.registered || index == 0) {
    // Into every active submap, and a constraint for each; directions the registration could not
    // constrain get a loose sigma so that the graph, not the prior, decides them.
    Matrix6d info = information_from_sigmas(options_.submap_translation_sigma, options_.submap_rotation_sigma);
    if (report.registered && match.held_directions > 0) {
      Matrix6d cov = info.inverse();
      for (Eigen::Index k = 0; k < match.unobservable.cols(); ++k) {
        const Vector6d u = match.unobservable.col(k);
        cov += u * u.transpose() * (options_.unconstrained_sigma * options_.unconstrained_sigma);
      }
      info = cov.inverse();
      info = 0.5 * (info + info.transpose()).eval();
    }
    for (std::size_t j = 0; j < submaps_.size(); ++j) {
      Submap& s = *submaps_[j];
      if (s.finished) continue;
      const Eigen::Isometry3d in_submap = tidy(s.origin.inverse() * local);
      insert(*s.map, *scan, in_submap);
      ++s.inserted;
      s.positions.push_back(local.translation());
      s.last_scan = index;
      PoseConstraint c;
      c.from = j;
      c.to = index;
      c.kind = ConstraintKind::kSubmap;
      c.measurement = in_submap;
      c.information = info;
      constraints_.push_back(c);
      if (s.inserted >= static_cast<std::size_t>(options_.scans_per_submap)) {
        s.finished = true;
        if (options_.loop_closure) s.surface = surface_of(*s.map, options_.closure_matcher);
      }
    }
  }
  if (report.integrated) insert(*map_, *scan, correction() * local);

  if (options_.loop_closure && index % static_cast<std::size_t>(options_.closure_stride) == 0)
    search_closure(index, report);
  if (!report.closures.empty()) optimize();
  return report;
}

void PoseGraphMapper::search_closure(std::size_t scan_index, SlamScanReport& report) {
  // Candidates: finished submaps whose last scan lies at least a submap's worth of scans back (so
  // a closure is a return, not the front end's own overlap), within closure_max_distance of the
  // scan; the nearest is tried, one attempt per scan.
  const Eigen::Isometry3d& local = local_[scan_index];
  std::size_t best = submaps_.size();
  double best_d = options_.closure_max_distance;
  for (std::size_t j = 0; j < submaps_.size(); ++j) {
    const Submap& s = *submaps_[j];
    if (!s.finished || !s.surface ||
        scan_index < s.last_scan + static_cast<std::size_t>(options_.scans_per_submap))
      continue;
    const double d = s.distance_to(local.translation());
    if (d < best_d) {
      best_d = d;
      best = j;
    }
  }
  if (best == submaps_.size()) return;
  Submap& s = *submaps_[best];
  ++summary_.closure_attempts;
  const registration::ScanMatcher matcher(*s.map, s.surface, options_.closure_matcher);
  const registration::ScanMatchResult r = matcher.match(scans_[scan_index]->points, tidy(s.origin.inverse() * local));
  if (!r.converged) {
    ++summary_.closures_refused_by_matcher;
    return;
  }
  LoopClosure lc;
  lc.scan = scan_index;
  lc.submap = best;
  lc.relative = tidy(r.pose);
  lc.coarse_score = r.coarse_score;
  lc.inlier_fraction = r.inlier_fraction;
  PoseConstraint c;
  c.from = best;
  c.to = scan_index;
  c.kind = ConstraintKind::kLoopClosure;
  c.measurement = lc.relative;
  c.information = information_from_sigmas(options_.closure_translation_sigma, options_.closure_rotation_sigma);
  c.robust = true;
  closure_constraint_.push_back(constraints_.size());
  constraints_.push_back(c);
  report.closures.push_back(closures_.size());
  closures_.push_back(lc);
  ++summary_.closures_found;
}

std::size_t PoseGraphMapper::add_loop_closure(std::size_t scan, std::size_t submap, const Eigen::Isometry3d& relative,
                                              const Matrix6d& information) {
  if (scan >= scans_.size())
    throw std::out_of_range("iwlomap: PoseGraphMapper: scan " + std::to_string(scan) + " of " +
                            std::to_string(scans_.size()));
  if (submap >= submaps_.size())
    throw std::out_of_range("iwlomap: PoseGraphMapper: submap " + std::to_string(submap) + " of " +
                            std::to_string(submaps_.size()));
  if (!relative.matrix().allFinite()) throw std::invalid_argument("iwlomap: PoseGraphMapper: the closure is not finite");
  PoseConstraint c;
  c.from = submap;
  c.to = scan;
  c.kind = ConstraintKind::kExternal;
  c.measurement = tidy(relative);
  c.information = information;
  c.robust = true;
  LoopClosure lc;
  lc.scan = scan;
  lc.submap = submap;
  lc.relative = c.measurement;
  lc.external = true;
  closure_constraint_.push_back(constraints_.size());
  constraints_.push_back(c);
  closures_.push_back(lc);
  return closures_.size() - 1;
}

std::shared_ptr<const detail::SlamGraphData> PoseGraphMapper::get_graph_data() {
  auto data = std::make_shared<detail::SlamGraphData>();
  const std::size_t n = scans_.size();
  data->scans = n;
  data->graph.nodes = local_;
  for (const auto& s : submaps_) data->graph.nodes.push_back(s->origin);
  data->graph.constraints = constraints_;
  for (PoseConstraint& c : data->graph.constraints)
    if (c.kind != ConstraintKind::kOdometry) c.from += n;  // a submap's node follows the scans
  data->graph.validate();
  data->scan_refs.assign(scans_.begin(), scans_.end());
  data->integrated = integrated_;
  data->closure_constraint = closure_constraint_;
  data->rebuild = options_.rebuild_map_on_optimize || finishing_;
  return data;
}

std::shared_ptr<const detail::SlamOutput> PoseGraphMapper::run(const std::shared_ptr<const detail::SlamGraphData>& data,
                                                               detail::SlamContext&, const StopToken& stop) {
  auto out = std::make_shared<detail::SlamOutput>();
  out->solution = solve_pose_graph(data->graph, options_.solver, stop);
  out->scans = data->scans;
  for (const std::size_t k : data->closure_constraint) out->closure_rejected.push_back(out->solution.rejected[k]);
  if (data->rebuild) {
    std::shared_ptr<IMapperBackend> map = new_map();
    for (std::size_t i = 0; i < data->scans; ++i) {
      if (stop.stop_requested()) throw StopRequested();
      if (!data->integrated[i]) continue;
      insert(*map, *data->scan_refs[i], out->solution.nodes[i]);
    }
    out->map = std::move(map);
  }
  return out;
}

void PoseGraphMapper::write_result(const std::shared_ptr<const detail::SlamOutput>& out) {
  const std::size_t n = out->scans;
  optimized_.assign(out->solution.nodes.begin(), out->solution.nodes.begin() + static_cast<std::ptrdiff_t>(n));
  applied_scans_ = n;
  ++summary_.optimizations;
  summary_.closures_rejected_by_optimizer = 0;
  for (std::size_t k = 0; k < out->closure_rejected.size() && k < closures_.size(); ++k) {
    closures_[k].rejected = out->closure_rejected[k];
    if (closures_[k].rejected) ++summary_.closures_rejected_by_optimizer;
  }
  if (out->map) {
    // The rebuilt map holds the scans of the snapshot; the scans added since go in at their
    // poses under the new correction.
    map_ = out->map;
    const Eigen::Isometry3d c = correction();
    for (std::size_t i = n; i < scans_.size(); ++i)
      if (integrated_[i]) insert(*map_, *scans_[i], c * local_[i]);
  }
}

void PoseGraphMapper::finish() {
  finishing_ = true;  // this optimization rebuilds the map whatever rebuild_map_on_optimize says
  try {
    optimize();
  } catch (...) {
    finishing_ = false;
    throw;
  }
  finishing_ = false;
  write_map();
}

std::vector<Eigen::Isometry3d> PoseGraphMapper::poses() const {
  std::vector<Eigen::Isometry3d> out(scans_.size());
  const Eigen::Isometry3d c = correction();
  for (std::size_t i = 0; i < scans_.size(); ++i) out[i] = i < applied_scans_ ? optimized_[i] : tidy(c * local_[i]);
  return out;
}


std::unique_ptr<IMapperBackend> PoseGraphMapper::build_map(const StopToken& stop) const {
  std::unique_ptr<IMapperBackend> map = new_map();
  const std::vector<Eigen::Isometry3d> p = poses();
  for (std::size_t i = 0; i < scans_.size(); ++i) {
    if (stop.stop_requested()) throw StopRequested();
    if (integrated_[i]) insert(*map, *scans_[i], p[i]);
  }
  return map;
}

std::size_t PoseGraphMapper::submap_first_scan(std::size_t submap) const {
  if (submap >= submaps_.size())
    throw std::out_of_range("iwlomap: PoseGraphMapper: submap " + std::to_string(submap) + " of " +
                            std::to_string(submaps_.size()));
  return submaps_[submap]->first_scan;
}

SlamSummary PoseGraphMapper::summary() const {
  SlamSummary s = summary_;
  s.submaps = submaps_.size();
  return s;
}

}  // namespace iwlomap::slam
