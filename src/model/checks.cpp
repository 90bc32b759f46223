// SPDX-License-Identifier: BSD-3-Clause
#include "model/checks.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>

namespace iwlomap::detail {

std::string shortest(double value) {
  char buf[40];
  for (int precision = 1; precision <= 17; ++precision) {
    std::snprintf(buf, sizeof buf, "%.*g", precision, value);
    if (std::strtod(buf, nullptr) == value || std::isnan(value)) break;
  }
  return buf;
}

std::string describe(const char* name, double value) { return std::string(name) + " = " + shortest(value); }

void check_resolution(double resolution) {
  if (!(std::isfinite(resolution) && resolution > 0.0))
    throw std::invalid_argument("iwlomap: resolution must be finite and > 0, got " +
                                describe("resolution", resolution));
}

void check_points_shape(const Eigen::MatrixXd& points, Eigen::Index n_values, const char* values_name) {
  if (points.rows() > 0 && points.cols() != 3)
    throw std::invalid_argument("iwlomap: points must be N x 3, got " + std::to_string(points.rows()) + " x " +
                                std::to_string(points.cols()));
  if (n_values != points.rows())
    throw std::invalid_argument("iwlomap: " + std::string(values_name) + " has " + std::to_string(n_values) +
                                " entries but points has " + std::to_string(points.rows()) + " rows");
}

void throw_out_of_range(Eigen::Index i, const Eigen::Vector3d& p, double resolution) {
  throw std::out_of_range(
      "iwlomap: " +
      (i == -1 ? std::string("the scan origin") : i < 0 ? std::string("the point") : "point " + std::to_string(i)) +
      " (" + shortest(p.x()) + ", " + shortest(p.y()) + ", " + shortest(p.z()) +
      ") lies outside the int32 key range at resolution " + shortest(resolution));
}

double resolve_min_probability(double min_probability) {
  if (std::isnan(min_probability) || min_probability > 1.0)
    throw std::invalid_argument("iwlomap: min_probability must be <= 1 (negative means 0.5), got " +
                                describe("min_probability", min_probability));
  return min_probability < 0.0 ? 0.5 : min_probability;
}

}  // namespace iwlomap::detail
