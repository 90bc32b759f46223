// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/synthetic_world.h"

#include "model/checks.h"
#include "sim/portable_random.h"
#include "sim/ray_box.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kCornerRadius = 6.0;  // of the trajectory's turns
constexpr double kPavement = 3.0;      // kerb to building front
// A ray's cost grows with the cells it crosses and the boxes each cell lists: 4 m cells keep both
// small for street-sized boxes; the cell count is capped whatever the world's extent.
constexpr double kMinCellSize = 4.0;
constexpr double kMaxCells = 1 << 22;

[[noreturn]] void reject(const std::string& what) { throw std::invalid_argument("iwlomap: " + what); }

void validate_street_loop(const StreetLoopOptions& o) {
  if (!(std::isfinite(o.street_width) && o.street_width >= 11.0))
    reject("StreetLoopOptions: street_width must be >= 11 m (a 6 m lane and a row of parked cars on each side), got " +
           detail::describe("street_width", o.street_width));
  const double min_block = o.street_width + 20.0;
  if (!(std::isfinite(o.block_x) && o.block_x >= min_block))
    reject("StreetLoopOptions: block_x must be >= street_width + 20 m, got " + detail::describe("block_x", o.block_x));
  if (!(std::isfinite(o.block_y) && o.block_y >= min_block))
    reject("StreetLoopOptions: block_y must be >= street_width + 20 m, got " + detail::describe("block_y", o.block_y));
}

// One side of the loop as a street frame: s along the street from its start corner, l to the
// left of the direction of travel (positive: inside the block).
struct Street {
  Eigen::Vector2d start, along, left;
  double length, across;  // across: the block's other side, which bounds what fits inside it

  // The world box of the street-frame rectangle [s0, s1] x [l0, l1] x [z0, z1].
  WorldBox box(double s0, double s1, double l0, double l1, double z0, double z1, double reflectivity) const {
    const Eigen::Vector2d a = start + s0 * along + l0 * left, b = start + s1 * along + l1 * left;
    WorldBox w;
    w.lo = Eigen::Vector3d(std::min(a.x(), b.x()), std::min(a.y(), b.y()), z0);
    w.hi = Eigen::Vector3d(std::max(a.x(), b.x()), std::max(a.y(), b.y()), z1);
    w.reflectivity = reflectivity;
    return w;
  }
};

std::vector<Street> streets_of(const StreetLoopOptions& o) {
  const double bx = o.block_x, by = o.block_y;
  return {{{0.0, 0.0}, {1.0, 0.0}, {0.0, 1.0}, bx, by},
          {{bx, 0.0}, {0.0, 1.0}, {-1.0, 0.0}, by, bx},
          {{bx, by}, {-1.0, 0.0}, {0.0, -1.0}, bx, by},
          {{0.0, by}, {0.0, -1.0}, {1.0, 0.0}, by, bx}};
}

// Lines one side (+1: inside the block, -1: outside) of one street. Everything keeps off the
// lane: cars end 0.2 m inside the kerb, at least 3 m from the centreline for street_width >= 11.
void line_street(const Street& st, int side, double width, detail::PortableRandom& rng, std::vector<WorldBox>& out) {
  const double kerb = width / 2.0;
  // Inside the block, stop where the cross street's pavement begins; outside, run on to the cross
  // street's building line, so the outer corners are built up and the inner ones stay open.
  const double end_gap = kerb + kPavement;
  const double b_begin = side > 0 ? end_gap : -end_gap;
  const double b_end = side > 0 ? st.length - end_gap : st.length + end_gap;
  for (double s = b_begin + rng.uniform(0.0, 6.0);;) {
    const double len = rng.uniform(8.0, 30.0);
    const double s1 = std::min(s + len, b_end);
    if (s1 - s < 6.0) break;
    const double front = end_gap + rng.uniform(0.0, 1.5);
    double depth = rng.uniform(8.0, 20.0);
    if (side > 0) depth = std::min(depth, st.across - 2.0 * front);  // never into the opposite street
    const double height = rng.uniform(6.0, 25.0);
    const double refl = rng.uniform(0.3, 0.7);
    out.push_back(st.box(s, s1, side * front, side * (front + depth), 0.0, height, refl));
    s = s1 + rng.uniform(3.0, 12.0);
  }

  // Street furniture and parked cars keep clear of the corners, where the trajectory turns.
  const double f_begin = end_gap, f_end = st.length - end_gap;
  const double pole_l = side * (kerb + 0.6);
  for (double s = f_begin + rng.uniform(0.0, 10.0); s < f_end; s += rng.uniform(15.0, 25.0)) {
    if (rng.uniform(0.0, 1.0) < 0.4) {  // tree: trunk and crown; the crown overhangs the kerb
      const double trunk_top = 2.8;
      out.push_back(st.box(s - 0.2, s + 0.2, pole_l - 0.2, pole_l + 0.2, 0.0, trunk_top, 0.3));
      out.push_back(st.box(s - 1.5, s + 1.5, pole_l - 1.5, pole_l + 1.5, trunk_top, trunk_top + rng.uniform(2.5, 4.0), 0.25));
    } else {
      out.push_back(st.box(s - 0.125, s + 0.125, pole_l - 0.125, pole_l + 0.125, 0.0, rng.uniform(5.0, 8.0), 0.6));
    }
  }
  for (double s = f_begin + rng.uniform(0.0, 5.0); s < f_end;) {
    if (rng.uniform(0.0, 1.0) < 0.55) {
      const double len = rng.uniform(4.2, 4.8), car_width = rng.uniform(1.7, 1.9);
      const double height = rng.uniform(1.4, 1.6), refl = rng.uniform(0.2, 0.9);
      if (s + len > f_end) break;
      const double outer = kerb - 0.2;
      out.push_back(st.box(s, s + len, side * (outer - car_width), side * outer, 0.0, height, refl));
      s += len + rng.uniform(1.0, 3.0);
    } else {
      s += rng.uniform(5.0, 15.0);
    }
  }
}

}  // namespace

void LidarOptions::validate() const {
  if (rings < 1) reject("LidarOptions: rings must be >= 1, got rings = " + std::to_string(rings));
  if (columns < 1) reject("LidarOptions: columns must be >= 1, got columns = " + std::to_string(columns));
  if (!(min_elevation >= -kPi / 2 && min_elevation <= kPi / 2))
    reject("LidarOptions: min_elevation must be in [-pi/2, pi/2] radians, got " + detail::describe("min_elevation", min_elevation));
  if (!(max_elevation >= min_elevation && max_elevation <= kPi / 2))
    reject("LidarOptions: max_elevation must be in [min_elevation, pi/2] radians, got " +
           detail::describe("max_elevation", max_elevation));
  if (!(std::isfinite(max_range) && max_range > 0.0))
    reject("LidarOptions: max_range must be finite and > 0, got " + detail::describe("max_range", max_range));
  if (!(std::isfinite(range_noise) && range_noise >= 0.0))
    reject("LidarOptions: range_noise must be finite and >= 0, got " + detail::describe("range_noise", range_noise));
  if (!(std::isfinite(intensity_noise) && intensity_noise >= 0.0))
    reject("LidarOptions: intensity_noise must be finite and >= 0, got " +
           detail::describe("intensity_noise", intensity_noise));
}

SyntheticWorld::SyntheticWorld(std::vector<WorldBox> boxes, double ground_z, double ground_reflectivity)
    : boxes_(std::move(boxes)), ground_z_(ground_z), ground_reflectivity_(ground_reflectivity) {
  if (!std::isfinite(ground_z_)) reject("SyntheticWorld: ground_z must be finite, got " + detail::describe("ground_z", ground_z_));
  if (!(ground_reflectivity_ >= 0.0 && ground_reflectivity_ <= 1.0))
    reject("SyntheticWorld: ground_reflectivity must be in [0, 1], got " +
           detail::describe("ground_reflectivity", ground_reflectivity_));
  if (boxes_.size() >= std::numeric_limits<std::uint32_t>::max())
    reject("SyntheticWorld: too many boxes, got " + std::to_string(boxes_.size()));
  for (std::size_t i = 0; i < boxes_.size(); ++i) {
    const WorldBox& b = boxes_[i];
    if (!(b.lo.allFinite() && b.hi.allFinite() && (b.lo.array() <= b.hi.array()).all()))
      reject("SyntheticWorld: box " + std::to_string(i) + " needs finite corners with lo <= hi on every axis");
    if (!(b.reflectivity >= 0.0 && b.reflectivity <= 1.0))
      reject("SyntheticWorld: box " + std::to_string(i) + " reflectivity must be in [0, 1], got " +
             detail::describe("reflectivity", b.reflectivity));
  }
  if (boxes_.empty()) return;

  Eigen::Vector2d lo = boxes_[0].lo.head<2>(), hi = boxes_[0].hi.head<2>();
  for (const WorldBox& b : boxes_) {
    lo = lo.cwiseMin(b.lo.head<2>());
    hi = hi.cwiseMax(b.hi.head<2>());
  }
  const Eigen::Vector2d extent = hi - lo;
  cell_size_ = std::max({kMinCellSize, std::sqrt(extent.x() * extent.y() / kMaxCells), extent.maxCoeff() / 4096.0});
  grid_origin_ = lo;
  nx_ = std::max(1, static_cast<int>(std::ceil(extent.x() / cell_size_)));
  ny_ = std::max(1, static_cast<int>(std::ceil(extent.y() / cell_size_)));
  const auto cell_range = [&](const WorldBox& b, int axis, int n) {
    const double o = grid_origin_[axis];
    const int c0 = static_cast<int>(std::floor((b.lo[axis] - o) / cell_size_));
    const int c1 = static_cast<int>(std::floor((b.hi[axis] - o) / cell_size_));
    return std::make_pair(std::clamp(c0, 0, n - 1), std::clamp(c1, 0, n - 1));
  };
  // Two passes (count, then fill) give one flat array instead of a vector per cell.
  cell_begin_.assign(static_cast<std::size_t>(nx_) * ny_ + 1, 0);
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<std::uint32_t> fill;
    if (pass == 1) {
      for (std::size_t c = 1; c < cell_begin_.size(); ++c) cell_begin_[c] += cell_begin_[c - 1];
      cell_boxes_.resize(cell_begin_.back());
      fill.assign(cell_begin_.begin(), cell_begin_.end() - 1);
    }
    for (std::size_t i = 0; i < boxes_.size(); ++i) {
      const auto [x0, x1] = cell_range(boxes_[i], 0, nx_);
      const auto [y0, y1] = cell_range(boxes_[i], 1, ny_);
      for (int iy = y0; iy <= y1; ++iy)
        for (int ix = x0; ix <= x1; ++ix) {
          const std::size_t c = static_cast<std::size_t>(iy) * nx_ + ix;
          if (pass == 0)
            ++cell_begin_[c + 1];
          else
            cell_boxes_[fill[c]++] = static_cast<std::uint32_t>(i);
        }
    }
  }
}

double SyntheticWorld::trace(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double max_range, int& box,
                             int& axis) const {
  double best = kInf;
  box = -1;
  axis = 2;
  if (d.z() != 0.0) {
    const double t = (ground_z_ - o.z()) / d.z();
    if (t > 0.0 && t <= max_range) best = t;
  }
  if (nx_ == 0) return best;

  // The part of the ray over the grid, then a 2-D DDA through its cells (Amanatides and Woo):
  // each cell's boxes are tested until a hit lies before the cell's exit.
  double t_in = 0.0, t_out = std::min(best, max_range);
  const Eigen::Vector2d grid_hi = grid_origin_ + cell_size_ * Eigen::Vector2d(nx_, ny_);
  for (int i = 0; i < 2; ++i) {
    if (d[i] == 0.0) {
      if (o[i] < grid_origin_[i] || o[i] > grid_hi[i]) return best;
      continue;
    }
    double a = (grid_origin_[i] - o[i]) / d[i], c = (grid_hi[i] - o[i]) / d[i];
    if (a > c) std::swap(a, c);
    t_in = std::max(t_in, a);
    t_out = std::min(t_out, c);
  }
  if (t_in > t_out) return best;

  int cell[2], step[2];
  double t_next[2], t_delta[2];
  for (int i = 0; i < 2; ++i) {
    const int n = i == 0 ? nx_ : ny_;
    cell[i] = std::clamp(static_cast<int>(std::floor((o[i] + t_in * d[i] - grid_origin_[i]) / cell_size_)), 0, n - 1);
    if (d[i] > 0.0) {
      step[i] = 1;
      t_next[i] = (grid_origin_[i] + (cell[i] + 1) * cell_size_ - o[i]) / d[i];
      t_delta[i] = cell_size_ / d[i];
    } else if (d[i] < 0.0) {
      step[i] = -1;
      t_next[i] = (grid_origin_[i] + cell[i] * cell_size_ - o[i]) / d[i];
      t_delta[i] = -cell_size_ / d[i];
    } else {
      step[i] = 0;
      t_next[i] = kInf;
      t_delta[i] = kInf;
    }
  }
  for (;;) {
    const std::size_t c = static_cast<std::size_t>(cell[1]) * nx_ + cell[0];
    for (std::uint32_t k = cell_begin_[c]; k < cell_begin_[c + 1]; ++k) {
      const WorldBox& b = boxes_[cell_boxes_[k]];
      double t;
      int a;
      if (detail::ray_box_entry(o, d, b.lo, b.hi, t, a) && t < best && t <= max_range) {
        best = t;
        box = static_cast<int>(cell_boxes_[k]);
        axis = a;
      }
    }
    const int i = t_next[0] < t_next[1] ? 0 : 1;
    const double t_exit = t_next[i];
    if (best <= t_exit || t_exit > t_out) break;
    cell[i] += step[i];
    if (cell[i] < 0 || cell[i] >= (i == 0 ? nx_ : ny_)) break;
    t_next[i] += t_delta[i];
  }
  return best;
}

double SyntheticWorld::cast(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double max_range) const {
  if (!(max_range >= 0.0)) reject("SyntheticWorld::cast: max_range must be >= 0, got " + detail::describe("max_range", max_range));
  int box, axis;
  return trace(origin, dir, max_range, box, axis);
}

LidarFrame SyntheticWorld::scan(const Eigen::Isometry3d& sensor_pose, const LidarOptions& lidar, std::uint32_t seed) const {
  lidar.validate();
  std::vector<double> cos_el(lidar.rings), sin_el(lidar.rings), cos_az(lidar.columns), sin_az(lidar.columns);
  for (int r = 0; r < lidar.rings; ++r) {
    const double el = lidar.rings == 1 ? 0.5 * (lidar.min_elevation + lidar.max_elevation)
                                       : lidar.min_elevation + (lidar.max_elevation - lidar.min_elevation) * r / (lidar.rings - 1);
    cos_el[r] = std::cos(el);
    sin_el[r] = std::sin(el);
  }
  for (int c = 0; c < lidar.columns; ++c) {
    const double az = 2.0 * kPi * c / lidar.columns;
    cos_az[c] = std::cos(az);
    sin_az[c] = std::sin(az);
  }

  const Eigen::Matrix3d rotation = sensor_pose.linear();
  const Eigen::Vector3d origin = sensor_pose.translation();
  const Eigen::Index beams = static_cast<Eigen::Index>(lidar.rings) * lidar.columns;
  LidarFrame frame;
  frame.points.resize(beams, 3);
  frame.intensities.resize(beams);
  detail::PortableRandom noise(seed);
  Eigen::Index n = 0;
  for (int r = 0; r < lidar.rings; ++r) {
    for (int c = 0; c < lidar.columns; ++c) {
      const Eigen::Vector3d beam(cos_el[r] * cos_az[c], cos_el[r] * sin_az[c], sin_el[r]);
      const Eigen::Vector3d d = rotation * beam;
      int box, axis;
      const double t = trace(origin, d, lidar.max_range, box, axis);
      if (t == kInf) continue;
      // Both deviates are drawn even when a noise is 0, so that one noise level does not shift
      // the other's sequence.
      const double range_dev = noise.gaussian(), intensity_dev = noise.gaussian();
      const double range = std::clamp(t + lidar.range_noise * range_dev, 0.0, lidar.max_range);
      frame.points.row(n) = (beam * range).transpose();
      const double reflectivity = box < 0 ? ground_reflectivity_ : boxes_[box].reflectivity;
      const double cos_incidence = std::abs(d[axis]);  // every surface normal is a unit axis
      frame.intensities[n] =
          std::clamp(reflectivity * 255.0 * cos_incidence + lidar.intensity_noise * intensity_dev, 0.0, 255.0);
      ++n;
    }
  }
  frame.points.conservativeResize(n, 3);
  frame.intensities.conservativeResize(n);
  return frame;
}

SyntheticWorld SyntheticWorld::street_loop(const StreetLoopOptions& options) {
  validate_street_loop(options);
  detail::PortableRandom rng(options.seed);
  std::vector<WorldBox> boxes;
  for (const Street& st : streets_of(options))
    for (int side : {1, -1}) line_street(st, side, options.street_width, rng, boxes);
  return SyntheticWorld(std::move(boxes), 0.0, 0.15);
}

std::vector<Eigen::Isometry3d> SyntheticWorld::street_loop_trajectory(const StreetLoopOptions& options, double step,
                                                                      double sensor_height) {
  validate_street_loop(options);
  if (!(std::isfinite(step) && step > 0.0))
    reject("SyntheticWorld::street_loop_trajectory: step must be finite and > 0, got " + detail::describe("step", step));
  if (!(std::isfinite(sensor_height) && sensor_height > 0.0))
    reject("SyntheticWorld::street_loop_trajectory: sensor_height must be finite and > 0, got " +
           detail::describe("sensor_height", sensor_height));

  const double r = kCornerRadius;
  const double quarter = 0.5 * kPi * r;
  const std::vector<Street> streets = streets_of(options);
  double perimeter = 0.0;
  for (const Street& st : streets) perimeter += st.length - 2.0 * r + quarter;
  const long count = std::max(1L, std::lround(perimeter / step));
  const double spacing = perimeter / static_cast<double>(count);

  std::vector<Eigen::Isometry3d> poses;
  poses.reserve(static_cast<std::size_t>(count));
  for (long i = 0; i < count; ++i) {
    // Each street: a straight from r after its start corner to r before its end corner, then a
    // quarter circle of radius r turning left into the next street.
    double s = spacing * static_cast<double>(i);
    Eigen::Vector2d xy;
    double heading = 0.0;
    for (std::size_t k = 0; k < streets.size(); ++k) {
      const Street& st = streets[k];
      const double straight = st.length - 2.0 * r;
      const double base_heading = 0.5 * kPi * static_cast<double>(k);
      if (s <= straight) {
        xy = st.start + (r + s) * st.along;
        heading = base_heading;
        break;
      }
      s -= straight;
      if (s <= quarter || k + 1 == streets.size()) {
        const Eigen::Vector2d centre = st.start + (st.length - r) * st.along + r * st.left;
        heading = base_heading + std::min(s, quarter) / r;
        xy = centre + r * Eigen::Vector2d(std::sin(heading), -std::cos(heading));
        break;
      }
      s -= quarter;
    }
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    pose.translation() = Eigen::Vector3d(xy.x(), xy.y(), sensor_height);
    poses.push_back(pose);
  }
  return poses;
}

Eigen::MatrixXd make_pillar_scene(std::uint32_t seed, double noise) {
  if (!(noise >= 0.0) || !std::isfinite(noise))
    throw std::invalid_argument("iwlomap: make_pillar_scene: noise = " + std::to_string(noise) + " must be finite and >= 0");
  constexpr double kTwoPi = 6.283185307179586;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> e(0.0, noise > 0.0 ? noise : 1.0);
  const auto err = [&] { return noise > 0.0 ? e(rng) : 0.0; };
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 20000; ++i) {
    const double x = 24 * u(rng) - 12, y = 24 * u(rng) - 12;
    pts.emplace_back(x, y, err());
  }
  std::mt19937 place(99);  // the same pillars for every seed
  for (int k = 0; k < 12; ++k) {
    const double a = kTwoPi * k / 12 + 0.3 * u(place);
    const double r = 4.0 + 6.0 * u(place);
    const Eigen::Vector2d c(r * std::cos(a), r * std::sin(a));
    for (int i = 0; i < 1500; ++i) {
      const double t = kTwoPi * u(rng);
      const double rr = 0.3 + err();
      const double z = 3.0 * u(rng);
      pts.emplace_back(c.x() + rr * std::cos(t), c.y() + rr * std::sin(t), z);
    }
  }
  Eigen::MatrixXd m(static_cast<Eigen::Index>(pts.size()), 3);
  for (std::size_t i = 0; i < pts.size(); ++i) m.row(static_cast<Eigen::Index>(i)) = pts[i].transpose();
  return m;
}

}  // namespace iwlomap
