// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/synthetic_scan.h"

#include "sim/portable_random.h"
#include "sim/ray_box.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace iwlomap {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kHalfX = 20.0;
constexpr double kHalfY = 15.0;
constexpr double kWallHeight = 10.0;

struct Box {
  Eigen::Vector3d lo, hi;
  double reflectivity;
};

// Ray-box slab test; returns the entry distance and the normal of the entered face.
bool hit_box(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Box& b, double& t, Eigen::Vector3d& n) {
  int axis;
  if (!detail::ray_box_entry(o, d, b.lo, b.hi, t, axis)) return false;
  n = Eigen::Vector3d::Zero();
  n[axis] = d[axis] > 0 ? -1.0 : 1.0;
  return true;
}

}  // namespace

SyntheticScan make_synthetic_scan(const SyntheticScanOptions& opt) {
  if (opt.rings < 1 || opt.columns < 1)
    throw std::invalid_argument("iwlomap: make_synthetic_scan needs rings >= 1 and columns >= 1, got rings = " +
                                std::to_string(opt.rings) + ", columns = " + std::to_string(opt.columns));
  if (!(std::abs(opt.sensor_xy.x()) < kHalfX - 1.0 && std::abs(opt.sensor_xy.y()) < kHalfY - 1.0 &&
        opt.sensor_height > 0.1 && opt.sensor_height < kWallHeight - 1.0))
    throw std::invalid_argument("iwlomap: make_synthetic_scan: the sensor must stand inside the courtyard");

  const Box boxes[] = {
      {{6.0, 3.0, 0.0}, {8.0, 5.0, 1.5}, 200.0},       // crate
      {{-9.0, -6.0, 0.0}, {-6.5, -2.0, 2.5}, 170.0},   // container
      {{3.0, -8.0, 0.0}, {4.0, -7.0, 0.8}, 230.0},     // small bright box
      {{-14.0, 6.0, 0.0}, {-2.0, 6.4, 1.2}, 120.0},    // low wall
  };
  const Eigen::Vector2d pole_xy(10.0, -4.0);
  const double pole_radius = 0.15, pole_height = 4.0;

  SyntheticScan scan;
  scan.origin = Eigen::Vector3d(opt.sensor_xy.x(), opt.sensor_xy.y(), opt.sensor_height);
  const Eigen::Index n = static_cast<Eigen::Index>(opt.rings) * opt.columns;
  scan.points.resize(n, 3);
  scan.intensities.resize(n);
  detail::PortableRandom noise(opt.seed);
  const Eigen::Vector3d& o = scan.origin;

  Eigen::Index row = 0;
  for (int r = 0; r < opt.rings; ++r) {
    const double elev = (opt.rings == 1 ? 0.0 : (-25.0 + 40.0 * r / (opt.rings - 1))) * kPi / 180.0;
    for (int c = 0; c < opt.columns; ++c) {
      const double az = 2.0 * kPi * c / opt.columns;
      const Eigen::Vector3d d(std::cos(elev) * std::cos(az), std::cos(elev) * std::sin(az), std::sin(elev));
      double best = std::numeric_limits<double>::infinity();
      Eigen::Vector3d normal(0, 0, 1);
      double refl = 0.0;
      const auto consider = [&](double t, const Eigen::Vector3d& nrm, double rf) {
        if (t > 1e-6 && t < best) {
          best = t;
          normal = nrm;
          refl = rf;
        }
      };
      if (d.z() < 0) consider(-o.z() / d.z(), {0, 0, 1}, 60.0);  // asphalt
      if (d.z() > 0) consider((kWallHeight - o.z()) / d.z(), {0, 0, -1}, 90.0);  // awning over the court
      for (int axis = 0; axis < 2; ++axis) {  // courtyard walls
        const double half = axis == 0 ? kHalfX : kHalfY;
        if (std::abs(d[axis]) > 1e-12) {
          const double wall = d[axis] > 0 ? half : -half;
          Eigen::Vector3d nrm = Eigen::Vector3d::Zero();
          nrm[axis] = d[axis] > 0 ? -1.0 : 1.0;
          consider((wall - o[axis]) / d[axis], nrm, 110.0);
        }
      }
      for (const Box& b : boxes) {
        double t;
        Eigen::Vector3d nrm;
        if (hit_box(o, d, b, t, nrm)) consider(t, nrm, b.reflectivity);
      }
      {  // vertical pole: solve |o_xy + t d_xy - c|^2 = r^2
        const Eigen::Vector2d oc = o.head<2>() - pole_xy, dxy = d.head<2>();
        const double a = dxy.squaredNorm(), b = 2.0 * oc.dot(dxy), cc = oc.squaredNorm() - pole_radius * pole_radius;
        const double disc = b * b - 4 * a * cc;
        if (a > 1e-12 && disc >= 0) {
          const double t = (-b - std::sqrt(disc)) / (2 * a);
          const double z = o.z() + t * d.z();
          if (z >= 0 && z <= pole_height) {
            Eigen::Vector3d nrm(oc.x() + t * dxy.x(), oc.y() + t * dxy.y(), 0.0);
            consider(t, nrm.normalized(), 180.0);
          }
        }
      }
      const double range = best + opt.range_noise * noise.gaussian();
      scan.points.row(row) = (o + d * range).transpose();
      const double cos_incidence = std::max(0.05, std::abs(d.dot(normal)));
      const double value = refl * (0.4 + 0.6 * cos_incidence) + opt.intensity_noise * noise.gaussian();
      scan.intensities[row] = std::clamp(std::round(value), 0.0, 255.0);
      ++row;
    }
  }
  return scan;
}

}  // namespace iwlomap
