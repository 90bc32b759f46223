// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/registration/scan_matcher.h"

#include <Eigen/Eigenvalues>
#include <flann/flann.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <vector>

namespace iwlomap::registration {

namespace {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

constexpr int kNormalNeighbours = 8;
constexpr double kDegree = 3.14159265358979323846 / 180.0;
// The variance given to a direction the scene does not constrain (m^2 or rad^2): large enough that
// a caller weighing the result ignores it there, finite so the matrix stays usable.
constexpr double kUnobservableVariance = 1e6;

std::string num(double v) { return std::to_string(v); }

void check_pose(const Eigen::Isometry3d& pose) {
  if (!pose.matrix().allFinite()) throw std::invalid_argument("iwlomap: registration: the initial pose is not finite");
  const Eigen::Matrix3d r = pose.linear();
  if (!(r.transpose() * r).isApprox(Eigen::Matrix3d::Identity(), 1e-6) || r.determinant() < 0.0)
    throw std::invalid_argument("iwlomap: registration: the initial pose's rotation is not a rotation");
}

// Row-major copy of the finite rows of an N x 3 matrix.
std::vector<double> finite_rows(const Eigen::MatrixXd& m) {
  std::vector<double> out;
  out.reserve(static_cast<std::size_t>(m.rows()) * 3);
  for (Eigen::Index i = 0; i < m.rows(); ++i)
    if (m.row(i).allFinite())
      for (int c = 0; c < 3; ++c) out.push_back(m(i, c));
  return out;
}

// \p pose moved by \p step: a translation (first three) and a rotation vector (last three) about
// \p pivot, both in the map frame.
Eigen::Isometry3d apply_step(const Vector6d& step, const Eigen::Isometry3d& pose, const Eigen::Vector3d& pivot) {
  const Eigen::Vector3d w = step.tail<3>();
  const double angle = w.norm();
  Eigen::Isometry3d delta = Eigen::Isometry3d::Identity();
  if (angle > 0.0) delta.linear() = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
  delta.translation() = step.head<3>() + pivot - delta.linear() * pivot;
  Eigen::Isometry3d out = delta * pose;
  out.linear() = Eigen::Quaterniond(out.linear()).normalized().toRotationMatrix();
  return out;
}

}  // namespace

void IcpOptions::validate() const {
  const auto positive = [](const char* name, double v) {
    if (!(std::isfinite(v) && v > 0.0))
      throw std::invalid_argument(std::string("iwlomap: IcpOptions: ") + name + " = " + num(v) + " must be finite and > 0");
  };
  if (max_iterations < 1) throw std::invalid_argument("iwlomap: IcpOptions: max_iterations must be >= 1");
  positive("max_correspondence_distance", max_correspondence_distance);
  positive("huber_delta", huber_delta);
  positive("translation_tolerance", translation_tolerance);
  positive("rotation_tolerance", rotation_tolerance);
  positive("degeneracy_ratio", degeneracy_ratio);
  positive("inlier_distance", inlier_distance);
  if (!(overlap_distance >= inlier_distance) || !std::isfinite(overlap_distance))
    throw std::invalid_argument("iwlomap: IcpOptions: overlap_distance = " + num(overlap_distance) +
                                " must be finite and >= inlier_distance = " + num(inlier_distance));
  if (!(min_inlier_fraction >= 0.0 && min_inlier_fraction <= 1.0))
    throw std::invalid_argument("iwlomap: IcpOptions: min_inlier_fraction = " + num(min_inlier_fraction) +
                                " must be in [0, 1]");
}

void MatchQualityOptions::validate() const {
  const auto fraction = [](const char* name, double v) {
    if (!(v >= 0.0 && v <= 1.0))
      throw std::invalid_argument(std::string("iwlomap: MatchQualityOptions: ") + name + " = " + num(v) +
                                  " must be in [0, 1]");
  };
  fraction("min_inlier_fraction", min_inlier_fraction);
  fraction("min_axis_support", min_axis_support);
  fraction("max_free_conflict", max_free_conflict);
  if (!(max_coarse_disagreement > 0.0) || !std::isfinite(max_coarse_disagreement))
    throw std::invalid_argument("iwlomap: MatchQualityOptions: max_coarse_disagreement = " +
                                num(max_coarse_disagreement) + " must be finite and > 0");
  if (!(edge_margin >= 0.0) || !std::isfinite(edge_margin))
    throw std::invalid_argument("iwlomap: MatchQualityOptions: edge_margin = " + num(edge_margin) +
                                " must be finite and >= 0");
}

void ScanMatcherOptions::validate() const {
  if (!coarse && !fine) throw std::invalid_argument("iwlomap: ScanMatcherOptions: both stages are off");
  window.validate();
  if (!(min_coarse_score >= 0.0 && min_coarse_score <= 1.0))
    throw std::invalid_argument("iwlomap: ScanMatcherOptions: min_coarse_score = " + num(min_coarse_score) +
                                " must be in [0, 1]");
  if (coarse_points < 1) throw std::invalid_argument("iwlomap: ScanMatcherOptions: coarse_points must be >= 1");
  if (coarse_levels < 0 || coarse_levels > PrecomputationStack3D::kMaxLevels)
    throw std::invalid_argument("iwlomap: ScanMatcherOptions: coarse_levels = " + std::to_string(coarse_levels) +
                                " must be in [0, 16] (0: as the window needs)");
  if (std::isnan(max_range) || std::isnan(scan_voxel) || std::isnan(min_probability) || std::isnan(coarse_max_range))
    throw std::invalid_argument("iwlomap: ScanMatcherOptions: max_range, scan_voxel and min_probability must not be NaN");
  icp.validate();
  quality.validate();
}

Eigen::MatrixXd reduce_scan(const Eigen::MatrixXd& scan_sensor, double voxel, double max_range) {
  if (scan_sensor.cols() != 3 && scan_sensor.rows() > 0)
    throw std::invalid_argument("iwlomap: registration: the scan has " + std::to_string(scan_sensor.cols()) +
                                " columns, expected 3");
  struct Sum {
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    int n = 0;
  };
  std::unordered_map<std::uint64_t, std::size_t> slot;
  std::vector<Sum> sums;
  for (Eigen::Index i = 0; i < scan_sensor.rows(); ++i) {
    const Eigen::Vector3d p = scan_sensor.row(i).transpose();
    if (!p.allFinite() || (max_range > 0.0 && p.norm() > max_range)) continue;
    std::uint64_t key = static_cast<std::uint64_t>(i);
    if (voxel > 0.0) {
      const Eigen::Vector3d k = (p / voxel).array().floor();
      if ((k.array().abs() > 1e6).any()) continue;  // beyond any sensible range at this voxel
      key = (static_cast<std::uint64_t>(static_cast<std::int64_t>(k.x()) + (1 << 20)) << 42) |
            (static_cast<std::uint64_t>(static_cast<std::int64_t>(k.y()) + (1 << 20)) << 21) |
            static_cast<std::uint64_t>(static_cast<std::int64_t>(k.z()) + (1 << 20));
    }
    const auto [it, fresh] = slot.emplace(key, sums.size());
    if (fresh) sums.emplace_back();
    sums[it->second].p += p;
    ++sums[it->second].n;
  }
  Eigen::MatrixXd out(static_cast<Eigen::Index>(sums.size()), 3);
  for (std::size_t i = 0; i < sums.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = sums[i].p.transpose() / sums[i].n;
  return out;
}

// ---- MapSurface -------------------------------------------------------------------------------

struct MapSurface::Impl {
  std::vector<double> data;  // row-major points, owned: the index points into it
  Eigen::MatrixXd points;
  Eigen::MatrixXd normals;
  std::unique_ptr<flann::Index<flann::L2_Simple<double>>> index;

  // Nearest map point of each row of \p query (row-major, n x 3): index and squared distance.
  void nearest(std::vector<double>& query, std::size_t n, std::vector<int>& idx, std::vector<double>& dist2,
               int k = 1) const {
    idx.assign(n * static_cast<std::size_t>(k), -1);
    dist2.assign(n * static_cast<std::size_t>(k), std::numeric_limits<double>::infinity());
    if (n == 0) return;
    flann::Matrix<double> q(query.data(), n, 3);
    flann::Matrix<int> i(idx.data(), n, static_cast<std::size_t>(k));
    flann::Matrix<double> d(dist2.data(), n, static_cast<std::size_t>(k));
    flann::SearchParams params;
    params.cores = 1;
    index->knnSearch(q, i, d, static_cast<std::size_t>(k), params);
  }
};

MapSurface::MapSurface(const Eigen::MatrixXd& points) : impl_(std::make_unique<Impl>()) {
  if (points.cols() != 3 && points.rows() > 0)
    throw std::invalid_argument("iwlomap: MapSurface: the points have " + std::to_string(points.cols()) + " columns");
  Impl& s = *impl_;
  s.data = finite_rows(points);
  const std::size_t n = s.data.size() / 3;
  if (n < static_cast<std::size_t>(kNormalNeighbours))
    throw std::invalid_argument("iwlomap: MapSurface: " + std::to_string(n) + " finite points, at least " +
                                std::to_string(kNormalNeighbours) + " needed for normals");
  s.points = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>>(s.data.data(),
                                                                                        static_cast<Eigen::Index>(n), 3);
  s.index = std::make_unique<flann::Index<flann::L2_Simple<double>>>(flann::Matrix<double>(s.data.data(), n, 3),
                                                                     flann::KDTreeSingleIndexParams(10));
  s.index->buildIndex();
  // Normals: the direction of least spread of each point's neighbourhood.
  std::vector<double> query = s.data;
  std::vector<int> idx;
  std::vector<double> dist2;
  s.nearest(query, n, idx, dist2, kNormalNeighbours);
  s.normals.resize(static_cast<Eigen::Index>(n), 3);
  for (std::size_t i = 0; i < n; ++i) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (int k = 0; k < kNormalNeighbours; ++k) mean += s.points.row(idx[i * kNormalNeighbours + static_cast<std::size_t>(k)]).transpose();
    mean /= kNormalNeighbours;
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (int k = 0; k < kNormalNeighbours; ++k) {
      const Eigen::Vector3d d = s.points.row(idx[i * kNormalNeighbours + static_cast<std::size_t>(k)]).transpose() - mean;
      cov += d * d.transpose();
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
    s.normals.row(static_cast<Eigen::Index>(i)) = eig.eigenvectors().col(0).transpose();
  }
}

namespace {

// The occupied voxels of \p map as N x 3 points: probability above \p min_probability (< 0: the
// map's threshold), at their mean hit positions when asked and the map accumulates hits.
Eigen::MatrixXd surface_points(IMapperBackend& map, double min_probability, bool mean_hit_positions) {
  const double threshold = min_probability < 0.0 ? map.get_params().occupied_threshold : min_probability;
  const Eigen::MatrixXd v = mean_hit_positions && map.get_hit_accumulation() ? map.get_occupied_mean_positions(threshold)
                                                                             : map.get_occupied_voxels(threshold);
  return v.leftCols<3>();
}

}  // namespace

MapSurface MapSurface::from_map(IMapperBackend& map, double min_probability, bool mean_hit_positions) {
  return MapSurface(surface_points(map, min_probability, mean_hit_positions));
}

MapSurface::~MapSurface() = default;
MapSurface::MapSurface(MapSurface&&) noexcept = default;
MapSurface& MapSurface::operator=(MapSurface&&) noexcept = default;

std::size_t MapSurface::size() const noexcept { return static_cast<std::size_t>(impl_->points.rows()); }
const Eigen::MatrixXd& MapSurface::points() const noexcept { return impl_->points; }
const Eigen::MatrixXd& MapSurface::normals() const noexcept { return impl_->normals; }

ScanMatchResult MapSurface::align(const Eigen::MatrixXd& scan_sensor, const Eigen::Isometry3d& initial,
                                  const IcpOptions& options, const std::optional<Eigen::Isometry3d>& prior) const {
  options.validate();
  check_pose(initial);
  const std::vector<double> scan = finite_rows(scan_sensor);
  const std::size_t n = scan.size() / 3;
  if (n == 0) throw std::invalid_argument("iwlomap: registration: the scan has no finite point");
  const Impl& s = *impl_;
  const double max_d2 = options.max_correspondence_distance * options.max_correspondence_distance;

  std::vector<double> query(scan.size());
  std::vector<int> idx;
  std::vector<double> dist2;
  // One linearisation at \p pose: the Gauss-Newton system (Huber-weighted, and plain for the
  // covariance), the pair count and the squared residual sum.
  struct System {
    Matrix6d h = Matrix6d::Zero(), h_plain = Matrix6d::Zero();
    Vector6d g = Vector6d::Zero();
    std::size_t pairs = 0;
    double r2 = 0.0;
  };
  // Rotations are taken about the scan's centroid (the pivot), not the map's origin: a scan far
  // from the origin (a submap's frame lies at its first scan) would otherwise couple rotation and
  // translation so strongly that the system looks degenerate.
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) centre += Eigen::Vector3d(scan[3 * i], scan[3 * i + 1], scan[3 * i + 2]);
  centre /= static_cast<double>(n);
  const auto linearise = [&](const Eigen::Isometry3d& pose) {
    const Eigen::Vector3d pivot = pose * centre;
    for (std::size_t i = 0; i < n; ++i) {
      const Eigen::Vector3d q = pose * Eigen::Vector3d(scan[3 * i], scan[3 * i + 1], scan[3 * i + 2]);
      for (int c = 0; c < 3; ++c) query[3 * i + static_cast<std::size_t>(c)] = q[c];
    }
    s.nearest(query, n, idx, dist2);
    System sys;
    for (std::size_t i = 0; i < n; ++i) {
      if (idx[i] < 0 || !(dist2[i] <= max_d2)) continue;
      const Eigen::Vector3d q(query[3 * i], query[3 * i + 1], query[3 * i + 2]);
      const Eigen::Vector3d normal = s.normals.row(idx[i]).transpose();
      const double r = normal.dot(q - s.points.row(idx[i]).transpose());
      Vector6d j;
      j << normal, (q - pivot).cross(normal);
      const double w = std::abs(r) <= options.huber_delta ? 1.0 : options.huber_delta / std::abs(r);
      sys.h += w * j * j.transpose();
      sys.h_plain += j * j.transpose();
      sys.g += w * j * r;
      sys.r2 += r * r;
      ++sys.pairs;
    }
    return sys;
  };
  // Rotations are scaled by the scan's size so that the eigenvalues of translations and rotations
  // compare (a rotation of 1 / L radians moves the scan about as far as 1 m).
  double spread = 0.0;
  for (std::size_t i = 0; i < n; ++i)
    spread += (Eigen::Vector3d(scan[3 * i], scan[3 * i + 1], scan[3 * i + 2]) - centre).squaredNorm();
  const double length = std::max(std::sqrt(spread / static_cast<double>(n)), 1e-3);
  Vector6d scale;
  scale << 1.0, 1.0, 1.0, 1.0 / length, 1.0 / length, 1.0 / length;
  // Planar: z, roll and pitch (indices 2, 3, 4) are held. Their rows and columns of the scaled
  // system are cleared and their diagonal set to the largest free one, so each is an eigenvector
  // of its own that is neither weak nor moved (its gradient entry is cleared too).
  const std::array<int, 3> held = {2, 3, 4};
  const auto eigen_of = [&](const Matrix6d& h) {
    Matrix6d hs = scale.asDiagonal() * h * scale.asDiagonal();
    if (options.planar) {
      const double top_free = std::max({hs(0, 0), hs(1, 1), hs(5, 5), 1e-12});
      for (const int k : held) {
        hs.row(k).setZero();
        hs.col(k).setZero();
        hs(k, k) = top_free;
      }
    }
    return Eigen::SelfAdjointEigenSolver<Matrix6d>(hs);
  };

  ScanMatchResult result;
  result.pose = initial;
  result.scan_points = n;
  Eigen::Isometry3d pose = initial;
  bool settled = false;
  int it = 0;
  // Against a lattice of voxel centres the pairs can alternate between neighbouring centres, so
  // the steps never shrink below the tolerance although the fit no longer improves: three steps
  // in a row that lower the mean squared residual by less than 1e-4 of it also end the search.
  double last_mse = std::numeric_limits<double>::infinity();
  int stalled = 0;
  for (; it < options.max_iterations; ++it) {
    const System sys = linearise(pose);
    if (sys.pairs < 6) break;
    const double mse = sys.r2 / static_cast<double>(sys.pairs);
    stalled = mse > last_mse * (1.0 - 1e-4) ? stalled + 1 : 0;
    last_mse = std::min(last_mse, mse);
    if (stalled >= 3) {
      settled = true;
      break;
    }
    // Solve in the scaled coordinates, only along the directions the pairs constrain.
    const auto eig = eigen_of(sys.h);
    const double top = eig.eigenvalues().maxCoeff();
    Vector6d gs = scale.asDiagonal() * sys.g;
    if (options.planar)
      for (const int k : held) gs[k] = 0.0;
    Vector6d step_scaled = Vector6d::Zero();
    for (int k = 0; k < 6; ++k)
      if (eig.eigenvalues()[k] > options.degeneracy_ratio * top)
        step_scaled -= eig.eigenvectors().col(k) * (eig.eigenvectors().col(k).dot(gs) / eig.eigenvalues()[k]);
    const Vector6d step = scale.asDiagonal() * step_scaled;
    pose = apply_step(step, pose, pose * centre);
    if (step.head<3>().norm() < options.translation_tolerance && step.tail<3>().norm() < options.rotation_tolerance) {
      settled = true;
      ++it;
      break;
    }
  }
  result.iterations = it;
  {
    const Eigen::Isometry3d moved = pose * initial.inverse();
    result.icp_shift = (pose.translation() - initial.translation()).norm();
    result.icp_turn = Eigen::AngleAxisd(moved.linear()).angle();
  }
  System last = linearise(pose);
  // Covariance and unobservable directions from the plain Hessian at the final pose.
  auto eig = eigen_of(last.h_plain);
  const auto weak_of = [&](const Eigen::SelfAdjointEigenSolver<Matrix6d>& e) {
    std::vector<int> w;
    const double top = e.eigenvalues().maxCoeff();
    for (int k = 0; k < 6; ++k)
      if (!(top > 0.0 && e.eigenvalues()[k] > options.degeneracy_ratio * top)) w.push_back(k);
    return w;
  };
  std::vector<int> weak = weak_of(eig);
  // Held directions: the correction from the prior, in the scaled coordinates of the steps, loses
  // its components along the unconstrained eigenvectors (orthonormal there), so the pose keeps the
  // prior's values along them; the constrained components are ICP's, which the flat directions do
  // not change to first order.
  if (prior && !weak.empty() && last.pairs >= 6) {
    const Eigen::Isometry3d correction = pose * prior->inverse();
    const Eigen::AngleAxisd turn(correction.linear());
    const Eigen::Vector3d pivot = *prior * centre;
    Vector6d xi;  // the correction as a step about the pivot
    xi << correction.translation() - pivot + correction.linear() * pivot, turn.axis() * turn.angle();
    Vector6d xi_scaled = xi.cwiseQuotient(scale);
    for (const int k : weak) xi_scaled -= eig.eigenvectors().col(k) * eig.eigenvectors().col(k).dot(xi_scaled);
    pose = apply_step(scale.asDiagonal() * xi_scaled, *prior, pivot);
    last = linearise(pose);
    eig = eigen_of(last.h_plain);
    result.held_directions = static_cast<int>(weak.size());
  }
  result.pairs = last.pairs;
  result.score = static_cast<double>(last.pairs) / static_cast<double>(n);
  result.fitness_rmse = last.pairs > 0 ? std::sqrt(last.r2 / static_cast<double>(last.pairs)) : 0.0;
  // Quality at the final pose: a point is in the overlap when a map point lies within
  // overlap_distance, and an inlier when it also lies within inlier_distance of that point's
  // tangent plane (the plane, not the point: a sparse scan's rings fall between the map's). Per
  // axis, the overlap's points weighted by how much their plane faces the axis (query, idx and
  // dist2 hold the last pass).
  {
    const double near2 = options.overlap_distance * options.overlap_distance;
    std::size_t inliers = 0, near = 0;
    Eigen::Vector3d facing = Eigen::Vector3d::Zero(), facing_in = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < n; ++i) {
      if (idx[i] < 0 || !(dist2[i] <= near2)) continue;
      ++near;
      const Eigen::Vector3d normal = s.normals.row(idx[i]).transpose();
      const Eigen::Vector3d q(query[3 * i], query[3 * i + 1], query[3 * i + 2]);
      const bool in = std::abs(normal.dot(q - s.points.row(idx[i]).transpose())) <= options.inlier_distance;
      inliers += in ? 1 : 0;
      facing += normal.cwiseAbs();
      if (in) facing_in += normal.cwiseAbs();
    }
    result.inlier_fraction = static_cast<double>(inliers) / static_cast<double>(n);
    result.overlap_fraction = static_cast<double>(near) / static_cast<double>(n);
    for (int a = 0; a < 3; ++a) result.axis_support[a] = facing[a] > 0.0 ? facing_in[a] / facing[a] : 1.0;
  }
  const double top = eig.eigenvalues().maxCoeff();
  const double sigma2 = last.pairs > 6 ? last.r2 / static_cast<double>(last.pairs - 6) : 0.0;
  Matrix6d cov_scaled = Matrix6d::Zero();
  weak = weak_of(eig);
  for (int k = 0; k < 6; ++k) {
    const Vector6d v = eig.eigenvectors().col(k);
    if (top > 0.0 && eig.eigenvalues()[k] > options.degeneracy_ratio * top) cov_scaled += v * v.transpose() * (sigma2 / eig.eigenvalues()[k]);
  }
  // Back to metres and radians: cov = S cov_scaled S; unobservable directions in the same units.
  result.covariance = scale.asDiagonal() * cov_scaled * scale.asDiagonal();
  if (options.planar)
    for (const int k : held) {
      result.covariance.row(k).setZero();
      result.covariance.col(k).setZero();
    }
  result.unobservable.resize(6, static_cast<Eigen::Index>(weak.size()));
  for (std::size_t c = 0; c < weak.size(); ++c) {
    const Vector6d v = (scale.asDiagonal() * eig.eigenvectors().col(weak[c])).normalized();
    result.unobservable.col(static_cast<Eigen::Index>(c)) = v;
    result.covariance += v * v.transpose() * kUnobservableVariance;
  }

  if (last.pairs < 6 || result.score < options.min_inlier_fraction) {
    result.reason = "too few correspondences: " + std::to_string(last.pairs) + " of " + std::to_string(n) +
                    " scan points within " + num(options.max_correspondence_distance) +
                    " m of the map (does the scan overlap the map near the initial pose?)";
  } else if (!weak.empty() && !prior) {
    result.reason = "degenerate scene: " + std::to_string(weak.size()) +
                    " direction(s) of the pose are not constrained (see unobservable)";
  } else if (!settled) {
    result.reason = "no convergence within " + std::to_string(options.max_iterations) + " iterations";
  } else {
    result.converged = true;
    result.pose = pose;
  }
  return result;
}

Eigen::VectorXd MapSurface::distances(const Eigen::MatrixXd& points, double reach) const {
  if (points.cols() != 3 && points.rows() > 0)
    throw std::invalid_argument("iwlomap: MapSurface: the points have " + std::to_string(points.cols()) + " columns");
  std::vector<double> query(static_cast<std::size_t>(points.rows()) * 3);
  for (Eigen::Index i = 0; i < points.rows(); ++i)
    for (int c = 0; c < 3; ++c)
      query[3 * static_cast<std::size_t>(i) + static_cast<std::size_t>(c)] = std::isfinite(points(i, c)) ? points(i, c) : 0.0;
  std::vector<int> idx;
  std::vector<double> dist2;
  impl_->nearest(query, static_cast<std::size_t>(points.rows()), idx, dist2);
  Eigen::VectorXd out(points.rows());
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    if (!points.row(i).allFinite() || idx[k] < 0) {
      out[i] = std::numeric_limits<double>::infinity();
    } else if (dist2[k] <= reach * reach) {
      out[i] = std::abs(impl_->normals.row(idx[k]).dot(points.row(i) - impl_->points.row(idx[k])));
    } else {
      out[i] = std::sqrt(dist2[k]);
    }
  }
  return out;
}

// ---- ScanMatcher ------------------------------------------------------------------------------

ScanMatcher::ScanMatcher(IMapperBackend& map, ScanMatcherOptions options) : map_(map), options_(std::move(options)) {
  options_.validate();
  if (options_.fine) {
    const Eigen::MatrixXd v = surface_points(map, options_.min_probability, options_.mean_hit_positions);
    if (v.rows() >= kNormalNeighbours) surface_ = std::make_shared<const MapSurface>(v);
  }
}

ScanMatcher::ScanMatcher(IMapperBackend& map, const Eigen::MatrixXd& surface_points, ScanMatcherOptions options)
    : map_(map), options_(std::move(options)) {
  options_.validate();
  if (options_.fine) surface_ = std::make_shared<const MapSurface>(surface_points);
}

ScanMatcher::ScanMatcher(IMapperBackend& map, std::shared_ptr<const MapSurface> surface, ScanMatcherOptions options)
    : map_(map), options_(std::move(options)), surface_(std::move(surface)) {
  options_.validate();
  if (options_.fine && !surface_) throw std::invalid_argument("iwlomap: ScanMatcher: the surface is null");
}

ScanMatchResult ScanMatcher::match(const Eigen::MatrixXd& scan_sensor, const Eigen::Isometry3d& initial) const {
  check_pose(initial);
  const double voxel = options_.scan_voxel > 0.0 ? options_.scan_voxel : map_.get_resolution();
  const Eigen::MatrixXd scan = reduce_scan(scan_sensor, voxel, options_.max_range);
  if (scan.rows() == 0)
    throw std::invalid_argument("iwlomap: registration: the scan has no finite point within max_range = " +
                                num(options_.max_range) + " m");
  ScanMatchResult result;
  result.pose = initial;
  result.scan_points = static_cast<std::size_t>(scan.rows());
  Eigen::Isometry3d start = initial;
  double coarse_yaw_step = 0.0;
  if (options_.coarse) {
    if (map_.get_num_known_voxels() == 0) {
      result.reason = "the map is empty";
      return result;
    }
    int levels = options_.coarse_levels;
    if (levels == 0) {  // the widest window (2^(levels-1)) spans the search's x extent
      const double cells = 2.0 * std::floor(options_.window.linear_xy / map_.get_resolution() + 1e-9) + 1.0;
      levels = std::min(PrecomputationStack3D::kMaxLevels, 1 + static_cast<int>(std::ceil(std::log2(cells))));
    }
    // The points within coarse_max_range, every k-th of them, k chosen to keep at most
    // coarse_points; all points when none is that close.
    std::vector<Eigen::Index> near;
    for (Eigen::Index i = 0; i < scan.rows(); ++i)
      if (options_.coarse_max_range <= 0.0 || scan.row(i).norm() <= options_.coarse_max_range) near.push_back(i);
    if (near.empty())
      for (Eigen::Index i = 0; i < scan.rows(); ++i) near.push_back(i);
    const std::size_t stride = (near.size() + static_cast<std::size_t>(options_.coarse_points) - 1) /
                               static_cast<std::size_t>(options_.coarse_points);
    Eigen::MatrixXd sample(static_cast<Eigen::Index>((near.size() + stride - 1) / stride), 3);
    for (Eigen::Index i = 0; i < sample.rows(); ++i) sample.row(i) = scan.row(near[static_cast<std::size_t>(i) * stride]);
    const auto search = [&](const Eigen::Isometry3d& centre) {
      const auto coarse = CorrelativeScanMatcher3D::for_scan(map_, sample, centre, options_.window, levels);
      return coarse.match(sample, centre, options_.window, options_.min_coarse_score);
    };
    CoarseMatch m = search(initial);
    // An optimum on the window's outermost cells or yaw steps may be the best the window holds of
    // a pose beyond it: search once more around it, and refuse if that optimum lies on the edge
    // again (edge_margin = 0 turns this off).
    if (m.found && options_.quality.edge_margin > 0.0 &&
        at_edge(m.pose, initial, m.yaw_step)) {
      const CoarseMatch again = search(m.pose);
      if (again.found && at_edge(again.pose, m.pose, again.yaw_step)) {
        result.coarse_score = again.score;
        result.reason = "match quality: the coarse optimum lies at the edge of the search window twice in a row; "
                        "the pose lies beyond it (widen the window)";
        return result;
      }
      if (again.found) m = again;
    }
    result.coarse_score = m.score;
    if (!m.found) {
      result.reason = "coarse stage: " + m.reason + " (" + num(options_.min_coarse_score) +
                      "); the scan does not overlap the map within the search window";
      return result;
    }
    start = m.pose;
    coarse_yaw_step = m.yaw_step;
    if (!options_.fine) {
      result.pose = m.pose;
      result.score = m.score;
      result.converged = true;
      return result;
    }
  }
  if (!surface_) {
    result.reason = "the map has fewer than 8 occupied voxels to align to";
    return result;
  }
  IcpOptions icp = options_.icp;
  icp.inlier_distance = std::max(icp.inlier_distance, map_.get_resolution());
  icp.overlap_distance = std::max(icp.overlap_distance, 2.0 * icp.inlier_distance);
  const std::optional<Eigen::Isometry3d> prior =
      options_.quality.hold_unconstrained ? std::optional<Eigen::Isometry3d>(initial) : std::nullopt;
  ScanMatchResult fine = surface_->align(scan, start, icp, prior);
  fine.coarse_score = result.coarse_score;
  if (fine.converged) {
    fine.free_conflict = free_conflict(scan, fine.pose, icp);
    fine.reason = quality_refusal(fine, icp, coarse_yaw_step);
  }
  if (!fine.reason.empty()) {
    fine.converged = false;
    fine.pose = initial;
  }
  return fine;
}

double ScanMatcher::free_conflict(const Eigen::MatrixXd& scan, const Eigen::Isometry3d& pose, const IcpOptions& icp) const {
  if (!map_.supports(BackendFeature::kQuery)) return 0.0;
  const Eigen::MatrixXd world = (scan * pose.linear().transpose()).rowwise() + pose.translation().transpose();
  const Eigen::VectorXd away = surface_->distances(world, icp.overlap_distance);
  const double inlier_distance = icp.inlier_distance;
  std::size_t known = 0, conflicts = 0;
  for (Eigen::Index i = 0; i < world.rows(); ++i) {
    const std::optional<VoxelState> v = map_.query(world.row(i).transpose());
    if (!v) continue;
    ++known;
    if (v->probability < 0.5 && away[i] > inlier_distance) ++conflicts;
  }
  return known > 0 ? static_cast<double>(conflicts) / static_cast<double>(known) : 0.0;
}

bool ScanMatcher::at_edge(const Eigen::Isometry3d& pose, const Eigen::Isometry3d& centre, double yaw_step) const {
  const double resolution = map_.get_resolution();
  const double margin = options_.quality.edge_margin;
  const Eigen::Vector3d dt = pose.translation() - centre.translation();
  const Eigen::Matrix3d turn = pose.linear() * centre.linear().transpose();
  const double dyaw = std::atan2(turn(1, 0), turn(0, 0));
  const double edge_xy = options_.window.linear_xy - margin * resolution;
  const double edge_yaw = options_.window.angular_yaw - margin * yaw_step;
  return std::abs(dt.x()) > edge_xy || std::abs(dt.y()) > edge_xy || std::abs(dyaw) > edge_yaw;
}

std::string ScanMatcher::quality_refusal(const ScanMatchResult& r, const IcpOptions& icp,
                                         double coarse_yaw_step) const {
  const MatchQualityOptions& q = options_.quality;
  const double res = map_.get_resolution();
  if (r.inlier_fraction < q.min_inlier_fraction)
    return "match quality: " + num(r.inlier_fraction) + " of the scan lies within " + num(icp.inlier_distance) +
           " m of the map, below min_inlier_fraction " + num(q.min_inlier_fraction);
  for (int a = 0; a < 3; ++a)
    if (r.axis_support[a] < q.min_axis_support)
      return std::string("match quality: the surfaces facing ") + "xyz"[a] + " fit at " +
             num(r.axis_support[a]) + ", below min_axis_support " + num(q.min_axis_support);
  if (r.free_conflict > q.max_free_conflict)
    return "match quality: " + num(r.free_conflict) + " of the scan lies in space the map holds free, above " +
           "max_free_conflict " + num(q.max_free_conflict);
  if (options_.coarse) {
    const double max_turn = std::max(q.max_coarse_disagreement * coarse_yaw_step, 1.0 * kDegree);
    if (r.icp_shift > q.max_coarse_disagreement * res || r.icp_turn > max_turn)
      return "match quality: ICP moved " + num(r.icp_shift) + " m and " + num(r.icp_turn / kDegree) +
             " degrees from the coarse pose; the two stages disagree";
  }
  return {};
}

}  // namespace iwlomap::registration
