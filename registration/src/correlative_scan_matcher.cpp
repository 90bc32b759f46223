// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/registration/correlative_scan_matcher.h"


#include <iwlomap/precomputation_grid.h>
#include <iwlomap/voxel_key.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

namespace iwlomap::registration {

namespace {

// "name = value" for an error message (the value as the stream prints a double).
std::string describe(const char* name, double value) {
  std::ostringstream out;
  out << name << " = " << value;
  return out.str();
}

using Index = Eigen::Vector3i;

constexpr double kPi = 3.14159265358979323846;

void check_pose(const Eigen::Isometry3d& pose) {
  if (!pose.matrix().allFinite()) throw std::invalid_argument("iwlomap: scan matching: the initial pose is not finite");
  const Eigen::Matrix3d r = pose.linear();
  if (!(r.transpose() * r).isApprox(Eigen::Matrix3d::Identity(), 1e-6) || r.determinant() < 0.0)
    throw std::invalid_argument("iwlomap: scan matching: the initial pose's rotation is not a rotation");
}

// The finite rows of a scan (sensor frame); std::invalid_argument when there is none.
std::vector<Eigen::Vector3d> finite_points(const Eigen::MatrixXd& scan) {
  if (scan.cols() != 3 && scan.rows() > 0)
    throw std::invalid_argument("iwlomap: scan matching: the scan has " + std::to_string(scan.cols()) +
                                " columns, expected 3 (x, y, z in metres)");
  std::vector<Eigen::Vector3d> out;
  out.reserve(static_cast<std::size_t>(scan.rows()));
  for (Eigen::Index i = 0; i < scan.rows(); ++i)
    if (scan.row(i).allFinite()) out.emplace_back(scan.row(i).transpose());
  if (out.empty()) throw std::invalid_argument("iwlomap: scan matching: the scan has no finite point");
  return out;
}

// Yaw candidates: steps such that the farthest point moves at most one voxel (Cartographer's
// rule), spread evenly over [-window, window]; returns the number of steps each way.
int yaw_steps(const std::vector<Eigen::Vector3d>& points, double resolution, double window, double& step) {
  double r = resolution;
  for (const auto& p : points) r = std::max(r, p.head<2>().norm());
  const double ratio = std::clamp(1.0 - resolution * resolution / (2.0 * r * r), -1.0, 1.0);
  const double natural = std::acos(ratio);
  const int n = std::max(1, static_cast<int>(std::ceil(window / natural)));
  step = window / n;
  return n;
}

Eigen::Matrix3d yawed(double yaw, const Eigen::Matrix3d& r0) {
  return Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() * r0;
}

int voxels_of(double metres, double resolution) {
  const double v = std::floor(metres / resolution + 1e-9);
  if (!(v < 1e6)) throw std::invalid_argument("iwlomap: scan matching: the window spans more than 10^6 voxels");
  return static_cast<int>(v);
}

}  // namespace

void SearchWindow3D::validate() const {
  const auto check = [](const char* name, double v) {
    if (!(std::isfinite(v) && v > 0.0)) throw std::invalid_argument(std::string("iwlomap: SearchWindow3D: ") + describe(name, v) + " must be finite and > 0");
  };
  check("linear_xy", linear_xy);
  check("linear_z", linear_z);
  check("angular_yaw", angular_yaw);
  if (angular_yaw > kPi) throw std::invalid_argument("iwlomap: SearchWindow3D: " + describe("angular_yaw", angular_yaw) + " exceeds pi");
}

/// A scan prepared for one window: per yaw candidate, the base-grid cell of every point at the
/// initial translation; candidate (j, x, y, z) adds (x, y, z) to every cell.
struct CorrelativeScanMatcher3D::Problem {
  std::vector<std::vector<Index>> cells;  // [yaw index][point]
  std::vector<double> yaws;               // radians, ascending
  Eigen::Matrix3d r0;
  Eigen::Vector3d t0;
  Index window;                           // offsets -window .. window per axis, voxels
  std::int64_t threshold = 0;             // a candidate must reach this sum
  std::size_t points = 0;
  double step = 0.0;
  int steps = 0;
};

CorrelativeScanMatcher3D::CorrelativeScanMatcher3D(const IMapperBackend& map, const VoxelBox& region, int num_levels,
                                                   int dilation)
    : region_(region), resolution_(map.get_resolution()) {
  region.validate();
  if (dilation < 0 || dilation > 16)
    throw std::invalid_argument("iwlomap: CorrelativeScanMatcher3D: dilation = " + std::to_string(dilation) +
                                " must be in [0, 16]");
  DiscreteGrid3D base = discretize_volume(map, region);
  if (dilation > 0) {
    // Cell c takes the maximum over c - dilation .. c + dilation: a window of 2 dilation + 1
    // starting at c - dilation.
    const PrecomputationGrid3D wide(base, 2 * dilation + 1);
    const Index size = base.size();
    std::vector<std::uint8_t>& v = base.values();
    std::size_t o = 0;
    for (int z = 0; z < size.z(); ++z)
      for (int y = 0; y < size.y(); ++y)
        for (int x = 0; x < size.x(); ++x) v[o++] = wide.window_max(Index(x, y, z) - Index::Constant(dilation));
  }
  stack_ = std::make_shared<const PrecomputationStack3D>(base, num_levels);
}

CorrelativeScanMatcher3D CorrelativeScanMatcher3D::for_scan(const IMapperBackend& map, const Eigen::MatrixXd& scan_sensor,
                                                            const Eigen::Isometry3d& initial, const SearchWindow3D& window,
                                                            int num_levels, int dilation) {
  window.validate();
  check_pose(initial);
  const std::vector<Eigen::Vector3d> points = finite_points(scan_sensor);
  const double res = map.get_resolution();
  double step = 0.0;
  const int n = yaw_steps(points, res, window.angular_yaw, step);
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  const Eigen::Matrix3d r0 = initial.linear();
  for (int j = -n; j <= n; ++j) {
    const Eigen::Matrix3d r = yawed(j * step, r0);
    for (const auto& p : points) {
      const Eigen::Vector3d q = r * p + initial.translation();
      lo = lo.cwiseMin(q);
      hi = hi.cwiseMax(q);
    }
  }
  const Eigen::Vector3d grow(window.linear_xy + 2 * res, window.linear_xy + 2 * res, window.linear_z + 2 * res);
  return CorrelativeScanMatcher3D(map, VoxelBox::from_world(lo - grow, hi + grow, res), num_levels, dilation);
}

CorrelativeScanMatcher3D::Problem CorrelativeScanMatcher3D::prepare(const Eigen::MatrixXd& scan_sensor,
                                                                    const Eigen::Isometry3d& initial,
                                                                    const SearchWindow3D& window,
                                                                    double min_score) const {
  window.validate();
  check_pose(initial);
  if (!(min_score >= 0.0 && min_score <= 1.0))
    throw std::invalid_argument("iwlomap: scan matching: " + describe("min_score", min_score) + " must be in [0, 1]");
  const std::vector<Eigen::Vector3d> points = finite_points(scan_sensor);
  Problem p;
  p.points = points.size();
  p.steps = yaw_steps(points, resolution_, window.angular_yaw, p.step);
  p.r0 = initial.linear();
  p.t0 = initial.translation();
  p.window = Index(voxels_of(window.linear_xy, resolution_), voxels_of(window.linear_xy, resolution_),
                   voxels_of(window.linear_z, resolution_));
  const Index origin(region_.min.x, region_.min.y, region_.min.z);
  for (int j = -p.steps; j <= p.steps; ++j) {
    const double yaw = j * p.step;
    p.yaws.push_back(yaw);
    const Eigen::Matrix3d r = yawed(yaw, p.r0);
    std::vector<Index> cells;
    cells.reserve(points.size());
    for (const auto& q : points) {
      const Eigen::Vector3d w = r * q + p.t0;
      const VoxelKey k = world_to_key_checked(w, resolution_);  // std::out_of_range beyond the key range
      cells.emplace_back(Index(k.x, k.y, k.z) - origin);
    }
    p.cells.push_back(std::move(cells));
  }
  p.threshold = static_cast<std::int64_t>(std::ceil(min_score * 255.0 * static_cast<double>(p.points) - 1e-9));
  return p;
}

namespace {

// The candidate order: yaw index, then x, y, z, each ascending.
using Order = std::tuple<int, int, int, int>;

struct Best {
  std::int64_t score;
  Order index{std::numeric_limits<int>::max(), 0, 0, 0};
  bool have = false;
  // A candidate (score, index) replaces the best: higher score, or equal and earlier.
  [[nodiscard]] bool beaten_by(std::int64_t s, const Order& i) const {
    return s > score || (have && s == score && i < index);
  }
  // No candidate of a node whose sums are at most \p bound and whose earliest index is \p first
  // can replace the best.
  [[nodiscard]] bool prunes(std::int64_t bound, const Order& first) const {
    return bound < score || (bound == score && (!have || !(first < index)));
  }
};

std::int64_t bound_of(const PrecomputationGrid3D& level, const std::vector<Index>& cells, const Index& offset) {
  std::int64_t sum = 0;
  for (const Index& c : cells) sum += level.window_max(c + offset);
  return sum;
}

CoarseMatch result_of(const Best& best, const std::vector<double>& yaws, int steps, double step,
                      const Eigen::Matrix3d& r0, const Eigen::Vector3d& t0, double resolution, std::size_t points,
                      std::uint64_t candidates, std::uint64_t visited, const Eigen::Isometry3d& initial) {
  CoarseMatch m;
  m.yaw_steps = steps;
  m.yaw_step = step;
  m.candidates = candidates;
  m.nodes_visited = visited;
  m.pose = initial;
  if (!best.have) {
    m.reason = "no pose in the window reaches min_score";
    return m;
  }
  const auto [j, x, y, z] = best.index;
  m.found = true;
  m.score_sum = static_cast<std::uint64_t>(best.score);
  m.score = static_cast<double>(best.score) / (255.0 * static_cast<double>(points));
  m.pose.linear() = yawed(yaws[static_cast<std::size_t>(j)], r0);
  m.pose.translation() = t0 + resolution * Eigen::Vector3d(x, y, z);
  return m;
}

}  // namespace

CoarseMatch CorrelativeScanMatcher3D::match(const Eigen::MatrixXd& scan_sensor, const Eigen::Isometry3d& initial,
                                            const SearchWindow3D& window, double min_score) const {
  const Problem p = prepare(scan_sensor, initial, window, min_score);
  const int top = stack_->num_levels() - 1;
  Best best{p.threshold - 1};
  std::uint64_t visited = 0;
  struct Node {
    std::int64_t bound;
    int yaw;
    Index offset;  // the node's lowest translation, voxels
  };
  const auto order_of = [](const Node& n) { return Order{n.yaw, n.offset.x(), n.offset.y(), n.offset.z()}; };
  const auto by_bound = [&](const Node& a, const Node& b) {
    return a.bound != b.bound ? a.bound > b.bound : order_of(a) < order_of(b);
  };
  // Children of a node at level k: its 2^(k-1)-wide octants that start inside the window.
  const auto search = [&](const auto& self, const Node& node, int k) -> void {
    if (k == 0) {
      if (best.beaten_by(node.bound, order_of(node))) {
        best.score = node.bound;
        best.index = order_of(node);
        best.have = true;
      }
      return;
    }
    const int half = 1 << (k - 1);
    const PrecomputationGrid3D& level = stack_->level(k - 1);
    std::vector<Node> children;
    children.reserve(8);
    for (int dx = 0; dx < 2; ++dx)
      for (int dy = 0; dy < 2; ++dy)
        for (int dz = 0; dz < 2; ++dz) {
          const Index o = node.offset + half * Index(dx, dy, dz);
          if ((o.array() > p.window.array()).any()) continue;
          ++visited;
          children.push_back({bound_of(level, p.cells[static_cast<std::size_t>(node.yaw)], o), node.yaw, o});
        }
    std::sort(children.begin(), children.end(), by_bound);
    for (const Node& c : children) {
      if (c.bound < best.score) break;  // sorted: no later child can do better
      if (!best.prunes(c.bound, order_of(c))) self(self, c, k - 1);
    }
  };
  std::vector<Node> roots;
  const int width = 1 << top;
  const PrecomputationGrid3D& coarsest = stack_->level(top);
  for (int j = 0; j < static_cast<int>(p.yaws.size()); ++j)
    for (int x = -p.window.x(); x <= p.window.x(); x += width)
      for (int y = -p.window.y(); y <= p.window.y(); y += width)
        for (int z = -p.window.z(); z <= p.window.z(); z += width) {
          ++visited;
          roots.push_back({bound_of(coarsest, p.cells[static_cast<std::size_t>(j)], Index(x, y, z)), j, Index(x, y, z)});
        }
  std::sort(roots.begin(), roots.end(), by_bound);
  for (const Node& r : roots) {
    if (r.bound < best.score) break;
    if (!best.prunes(r.bound, order_of(r))) search(search, r, top);
  }
  const std::uint64_t candidates = static_cast<std::uint64_t>(p.yaws.size()) * (2 * p.window.x() + 1) *
                                   (2 * p.window.y() + 1) * (2 * p.window.z() + 1);
  return result_of(best, p.yaws, p.steps, p.step, p.r0, p.t0, resolution_, p.points, candidates, visited, initial);
}

CoarseMatch CorrelativeScanMatcher3D::match_exhaustive(const Eigen::MatrixXd& scan_sensor,
                                                       const Eigen::Isometry3d& initial, const SearchWindow3D& window,
                                                       double min_score) const {
  const Problem p = prepare(scan_sensor, initial, window, min_score);
  const PrecomputationGrid3D& base = stack_->level(0);
  Best best{p.threshold - 1};
  std::uint64_t visited = 0;
  for (int j = 0; j < static_cast<int>(p.yaws.size()); ++j)
    for (int x = -p.window.x(); x <= p.window.x(); ++x)
      for (int y = -p.window.y(); y <= p.window.y(); ++y)
        for (int z = -p.window.z(); z <= p.window.z(); ++z) {
          ++visited;
          const std::int64_t s = bound_of(base, p.cells[static_cast<std::size_t>(j)], Index(x, y, z));
          if (best.beaten_by(s, Order{j, x, y, z})) {
            best.score = s;
            best.index = Order{j, x, y, z};
            best.have = true;
          }
        }
  return result_of(best, p.yaws, p.steps, p.step, p.r0, p.t0, resolution_, p.points, visited, visited, initial);
}

}  // namespace iwlomap::registration
