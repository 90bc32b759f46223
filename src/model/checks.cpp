// SPDX-License-Identifier: BSD-3-Clause
#include "model/checks.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace iwlomap::detail {

std::string describe(const char* name, double value) {
  std::ostringstream s;
  s.precision(17);
  s << name << " = " << value;
  return s.str();
}

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
  std::ostringstream s;
  s.precision(17);
  s << "iwlomap: "
    << (i == -1 ? std::string("the scan origin") : i < 0 ? std::string("the point") : "point " + std::to_string(i))
    << " (" << p.x() << ", " << p.y() << ", " << p.z() << ") lies outside the int32 key range at resolution "
    << resolution;
  throw std::out_of_range(s.str());
}

double resolve_min_probability(double min_probability) {
  if (std::isnan(min_probability) || min_probability > 1.0)
    throw std::invalid_argument("iwlomap: min_probability must be <= 1 (negative means 0.5), got " +
                                describe("min_probability", min_probability));
  return min_probability < 0.0 ? 0.5 : min_probability;
}

}  // namespace iwlomap::detail
