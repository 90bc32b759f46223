// SPDX-License-Identifier: BSD-3-Clause
#include "detail/batch_input.h"

#include <cmath>
#include <cstdint>
#include <limits>
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

namespace {

void check_points_shape(const Eigen::MatrixXd& points, Eigen::Index n_intensities) {
  if (points.rows() > 0 && points.cols() != 3)
    throw std::invalid_argument("iwlomap: points must be N x 3, got " + std::to_string(points.rows()) + " x " +
                                std::to_string(points.cols()));
  if (n_intensities != points.rows())
    throw std::invalid_argument("iwlomap: intensities has " + std::to_string(n_intensities) +
                                " entries but points has " + std::to_string(points.rows()) + " rows");
}

// floor(x / r) computed once, range-checked, then converted (is_representable() + world_to_key()
// in one pass).
bool checked_key(const Eigen::Vector3d& p, double resolution, VoxelKey& key) {
  constexpr double lo = static_cast<double>(std::numeric_limits<std::int32_t>::min());
  constexpr double hi = static_cast<double>(std::numeric_limits<std::int32_t>::max());
  const double kx = std::floor(p.x() / resolution), ky = std::floor(p.y() / resolution),
               kz = std::floor(p.z() / resolution);
  if (!(kx >= lo && kx <= hi && ky >= lo && ky <= hi && kz >= lo && kz <= hi)) return false;
  key = {static_cast<std::int32_t>(kx), static_cast<std::int32_t>(ky), static_cast<std::int32_t>(kz)};
  return true;
}

}  // namespace

void throw_out_of_range(Eigen::Index i, const Eigen::Vector3d& p, double resolution) {
  std::ostringstream s;
  s.precision(17);
  s << "iwlomap: " << (i == -1 ? std::string("the scan origin") : i < 0 ? std::string("the point") : "point " + std::to_string(i)) << " (" << p.x()
    << ", " << p.y() << ", " << p.z() << ") lies outside the int32 key range at resolution " << resolution;
  throw std::out_of_range(s.str());
}

std::size_t prepare_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                          const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights,
                          double resolution, std::vector<Observation>& out) {
  out.clear();
  check_points_shape(points, intensities.size());
  const Eigen::Index n = points.rows();
  if (static_cast<Eigen::Index>(is_occupied.size()) != n)
    throw std::invalid_argument("iwlomap: is_occupied has " + std::to_string(is_occupied.size()) +
                                " entries but points has " + std::to_string(n) + " rows");
  if (weights != nullptr && weights->size() != n)
    throw std::invalid_argument("iwlomap: weights has " + std::to_string(weights->size()) +
                                " entries but points has " + std::to_string(n) + " rows");
  out.reserve(static_cast<std::size_t>(n));
  std::size_t skipped = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const double w = weights != nullptr ? (*weights)[i] : 1.0;
    if (!(std::isfinite(w) && w >= 0.0))
      throw std::invalid_argument("iwlomap: weights must be finite and >= 0, got " +
                                  describe(("weights[" + std::to_string(i) + "]").c_str(), w));
    const Eigen::Vector3d p = points.row(i).transpose();
    const double intensity = intensities[i];
    if (!p.allFinite() || !std::isfinite(intensity)) {
      ++skipped;
      continue;
    }
    VoxelKey key;
    if (!checked_key(p, resolution, key)) {
      out.clear();
      throw_out_of_range(i, p, resolution);
    }
    out.push_back({key, intensity, w, static_cast<bool>(is_occupied[i])});
  }
  return skipped;
}

void check_scan_input(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                      const Eigen::VectorXd& intensities, double max_range, double resolution) {
  check_points_shape(points, intensities.size());
  if (!origin.allFinite())
    throw std::invalid_argument("iwlomap: the scan origin must be finite, got (" + std::to_string(origin.x()) +
                                ", " + std::to_string(origin.y()) + ", " + std::to_string(origin.z()) + ")");
  if (!is_representable(origin, resolution)) throw_out_of_range(-1, origin, resolution);
  if (std::isnan(max_range))
    throw std::invalid_argument("iwlomap: max_range must not be NaN (use a value <= 0 for no limit)");
}

double resolve_min_probability(double min_probability) {
  if (std::isnan(min_probability) || min_probability > 1.0)
    throw std::invalid_argument("iwlomap: min_probability must be <= 1 (negative means 0.5), got " +
                                describe("min_probability", min_probability));
  return min_probability < 0.0 ? 0.5 : min_probability;
}

Eigen::MatrixXd rows_to_matrix(const std::vector<double>& rows) {
  const Eigen::Index n = static_cast<Eigen::Index>(rows.size() / 4);
  Eigen::MatrixXd m(n, 4);
  for (Eigen::Index i = 0; i < n; ++i)
    for (Eigen::Index c = 0; c < 4; ++c) m(i, c) = rows[static_cast<std::size_t>(i * 4 + c)];
  return m;
}

}  // namespace iwlomap::detail
