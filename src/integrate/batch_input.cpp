// SPDX-License-Identifier: BSD-3-Clause
#include "integrate/batch_input.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace iwlomap::detail {

namespace {

// The key of \p p, range-checked (is_representable() + world_to_key() in one pass).
bool checked_key(const Eigen::Vector3d& p, const FloorDivider& divide, VoxelKey& key) {
  constexpr double lo = static_cast<double>(std::numeric_limits<std::int32_t>::min());
  constexpr double hi = static_cast<double>(std::numeric_limits<std::int32_t>::max());
  const double kx = divide(p.x()), ky = divide(p.y()), kz = divide(p.z());
  if (!(kx >= lo && kx <= hi && ky >= lo && ky <= hi && kz >= lo && kz <= hi)) return false;
  key = {static_cast<std::int32_t>(kx), static_cast<std::int32_t>(ky), static_cast<std::int32_t>(kz)};
  return true;
}

std::int64_t bits_of(double d) {
  std::int64_t b;
  std::memcpy(&b, &d, sizeof b);
  return b;
}

// True when every row is finite, inside +-safe on every axis and has a finite weight >= 0: the
// common case, which then needs no per-row checks. Branch-free so that it vectorises: x - x is
// +0 (all bits clear) for a finite x and NaN otherwise; |x| - safe is negative (sign bit set)
// inside the range; a weight w is fine when w - w is +0 and the sign bit of w is clear (-0 is
// fine too, but goes the slow way).
IWLOMAP_CPU_CLONES
bool all_rows_plain(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities, const Eigen::VectorXd* weights,
                    double safe) noexcept {
  const Eigen::Index n = points.rows();
  if (n == 0) return true;
  const double* x = points.col(0).data();
  const double* y = points.col(1).data();
  const double* z = points.col(2).data();
  const double* in = intensities.data();
  std::int64_t not_finite = 0;
  std::int64_t inside = -1;
  for (Eigen::Index i = 0; i < n; ++i) {
    not_finite |= bits_of(x[i] - x[i]) | bits_of(y[i] - y[i]) | bits_of(z[i] - z[i]) | bits_of(in[i] - in[i]);
    inside &= bits_of(std::abs(x[i]) - safe) & bits_of(std::abs(y[i]) - safe) & bits_of(std::abs(z[i]) - safe);
  }
  if (weights != nullptr) {
    const double* w = weights->data();
    std::int64_t bad_weight = 0;
    for (Eigen::Index i = 0; i < n; ++i) bad_weight |= bits_of(w[i] - w[i]) | (bits_of(w[i]) & std::numeric_limits<std::int64_t>::min());
    not_finite |= bad_weight;
  }
  return not_finite == 0 && inside < 0;
}

}  // namespace

IWLOMAP_CPU_CLONES
void ChunkKeys::compute(const Eigen::MatrixXd& points, Eigen::Index begin, std::size_t rows,
                        const FloorDivider& divide) noexcept {
  for (std::size_t c = 0; c < 3; ++c)
    divide.floor_many(points.col(static_cast<Eigen::Index>(c)).data() + begin, rows, axis_[c].data(), flags_.data());
}

std::size_t validate_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                           const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights, double resolution) {
  check_points_shape(points, intensities.size(), "intensities");
  const Eigen::Index n = points.rows();
  if (static_cast<Eigen::Index>(is_occupied.size()) != n)
    throw std::invalid_argument("iwlomap: is_occupied has " + std::to_string(is_occupied.size()) +
                                " entries but points has " + std::to_string(n) + " rows");
  if (weights != nullptr && weights->size() != n)
    throw std::invalid_argument("iwlomap: weights has " + std::to_string(weights->size()) +
                                " entries but points has " + std::to_string(n) + " rows");
  if (static_cast<std::uint64_t>(n) > std::numeric_limits<std::uint32_t>::max())
    throw std::invalid_argument("iwlomap: a batch holds at most 4294967295 points, got " + std::to_string(n) +
                                " (split it)");
  // Coordinates below this magnitude have keys well inside int32 (the quotient stays below
  // 0.999 * 2^31, far more than any rounding away from the limit); the others are checked exactly.
  const double safe = 0.999 * 2147483648.0 * resolution;
  if (all_rows_plain(points, intensities, weights, safe)) return 0;
  const FloorDivider divide(resolution);
  std::size_t skipped = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const double w = weights != nullptr ? (*weights)[i] : 1.0;
    if (!(std::isfinite(w) && w >= 0.0))
      throw std::invalid_argument("iwlomap: weights must be finite and >= 0, got " +
                                  describe(("weights[" + std::to_string(i) + "]").c_str(), w));
    if (!row_is_finite(points, intensities, i)) {
      ++skipped;
      continue;
    }
    const double x = points(i, 0), y = points(i, 1), z = points(i, 2);
    if (std::abs(x) < safe && std::abs(y) < safe && std::abs(z) < safe) continue;
    const Eigen::Vector3d p(x, y, z);
    VoxelKey key;
    if (!checked_key(p, divide, key)) throw_out_of_range(i, p, resolution);
  }
  return skipped;
}

std::size_t prepare_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                          const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights,
                          double resolution, std::vector<Observation>& out) {
  out.clear();
  const std::size_t skipped = validate_batch(points, intensities, is_occupied, weights, resolution);
  const Eigen::Index n = points.rows();
  // Sized up front and written field by field: building an Observation on the stack and copying
  // it made every point wait for a store-forwarding stall (three narrow stores, one wide load).
  out.resize(static_cast<std::size_t>(n) - skipped);
  std::size_t kept = 0;
  for_each_finite_key(points, intensities, static_cast<std::size_t>(n), skipped != 0, FloorDivider(resolution),
                      [&](std::size_t row, const VoxelKey& key) {
                        Observation& o = out[kept++];
                        o.key = key;
                        o.row = static_cast<std::uint32_t>(row);
                      });
  return skipped;
}

void check_scan_input(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                      const Eigen::VectorXd& intensities, double max_range, double resolution) {
  check_points_shape(points, intensities.size(), "intensities");
  if (!origin.allFinite())
    throw std::invalid_argument("iwlomap: the scan origin must be finite, got (" + std::to_string(origin.x()) +
                                ", " + std::to_string(origin.y()) + ", " + std::to_string(origin.z()) + ")");
  if (!is_representable(origin, resolution)) throw_out_of_range(-1, origin, resolution);
  if (std::isnan(max_range))
    throw std::invalid_argument("iwlomap: max_range must not be NaN (use a value <= 0 for no limit)");
}

}  // namespace iwlomap::detail
