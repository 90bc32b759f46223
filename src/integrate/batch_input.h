// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Input checking shared by every backend, so that all of them reject the same inputs with the
// same messages and skip the same points.

#include "integrate/cpu_clones.h"
#include "model/checks.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

namespace iwlomap::detail {

/// One observation of a batch, ready to apply: its voxel and its row in the input, where the
/// intensity, flag and weight stay (16 bytes: a batch's observations are written once and read
/// once, so their size is memory traffic).
struct Observation {
  VoxelKey key;
  std::uint32_t row;
};

/// The per-row inputs of a batch.
struct BatchValues {
  const Eigen::VectorXd& intensities;
  const std::vector<bool>& is_occupied;
  const Eigen::VectorXd* weights;  // null: every weight is 1

  [[nodiscard]] double intensity(std::uint32_t row) const { return intensities[row]; }
  [[nodiscard]] bool occupied_flag(std::uint32_t row) const { return is_occupied[row]; }
  [[nodiscard]] double weight(std::uint32_t row) const { return weights != nullptr ? (*weights)[row] : 1.0; }
};

/// floor(x / r) without a division per coordinate (a division costs about as much as the rest of
/// a point's key). x * (1 / r) differs from the correctly rounded x / r by at most a few units in the
/// last place, so their floors differ only when the quotient lies within that distance of an
/// integer; there, and whenever 1 / r is not an ordinary number or the quotient is beyond the
/// int32 range, the division is done. The results are exactly coordinate_to_key()'s.
class FloorDivider {
 public:
  explicit FloorDivider(double resolution)
      : resolution_(resolution), inverse_(1.0 / resolution), fast_(std::isnormal(inverse_)) {}

  [[nodiscard]] double operator()(double x) const {
    if (fast_) {
      const double q = x * inverse_;
      // floor(q) through a conversion toward zero (std::floor is a dozen instructions on x86-64
      // without SSE4.1). Below 2^31 in magnitude the rounding difference is below 2^31 * 2^-50,
      // so a fractional part within (2^-17, 1 - 2^-17) decides; q - k is exact.
      if (std::abs(q) < 0x1p31) {  // false for inf and NaN
        const double t = static_cast<double>(static_cast<std::int64_t>(q));
        const double k = q < t ? t - 1.0 : t;
        if (std::abs((q - k) - 0.5) < 0.5 - 0x1p-17) return k;
      }
    }
    return std::floor(x / resolution_);
  }

  /// floor_many()'s computation for one value \p x: the key in the low 32 bits of the result,
  /// exact unless \p flag gets its sign bit set (then operator() must decide) or fast() is false.
  [[nodiscard]] std::int64_t fast_floor(double x, std::int64_t& flag) const noexcept {
    constexpr double kMagic = 0x1.8p52;
    const double q = x * inverse_;
    const double s = (q - 0.5) + kMagic;
    const double f = q - (s - kMagic);  // q - floor(q), exact when |q| < 2^31
    std::int64_t magic_key;
    std::memcpy(&magic_key, &s, sizeof s);
    // Negative when clear of an integer by 2^-17 (>> the rounding difference below 2^31) and
    // when inside the int32 range; sign bits rather than comparisons keep the loops branch-free.
    const double clear = std::abs(f - 0.5) - (0.5 - 0x1p-17);
    const double inside = std::abs(q) - 0x1p31;
    std::int64_t c, r;
    std::memcpy(&c, &clear, sizeof c);
    std::memcpy(&r, &inside, sizeof r);
    const double a = std::abs(q);
    const std::int64_t small = -static_cast<std::int64_t>((a < 0.5) & (a >= 0x1p-1000));  // all bits or none
    const std::int64_t sign_key = -static_cast<std::int64_t>(q < 0.0);                     // -1 or 0
    const std::int64_t nonzero = -static_cast<std::int64_t>(x != 0.0);
    flag = ~(c & r) & ~small & nonzero;  // sign bit set: needs operator()
    return (magic_key & ~small) | (sign_key & small);
  }
  [[nodiscard]] bool fast() const noexcept { return fast_; }

  /// The key floor(x[i] / r) of each of x[0 .. n) in the low 32 bits of out[i] (read it as
  /// static_cast<std::int32_t>(out[i])), exactly as operator(), for every finite x[i] whose key fits
  /// in int32 (others get unspecified values). \p flags (n entries) is scratch. Branch-free so that
  /// it vectorises: floor(q) is in the low bits of (q - 0.5) + 1.5 * 2^52, which rounds q - 0.5 to
  /// the nearest integer, and that is floor(q) whenever q is not within the rounding difference of
  /// an integer. Two cases near the integer 0 are exact here too: x = +-0 (a ground plane at
  /// z = 0), whose tie rounds to the even 0, and 2^-1000 <= |q| < 0.5 (the coordinate 1e-16 of a
  /// beam at an azimuth of 90 degrees), where x / r has q's sign and floor(x / r) is 0 or -1.
  /// The other values near a voxel face, and every value when 1 / r is not ordinary, go through
  /// operator() afterwards, one by one.
  void floor_many(const double* x, std::size_t n, std::int64_t* out, std::int64_t* flags) const {
    std::int64_t any = 0;
    for (std::size_t i = 0; i < n; ++i) {
      out[i] = fast_floor(x[i], flags[i]);
      any |= flags[i];
    }
    if (fast_ && any >= 0) return;
    for (std::size_t i = 0; i < n; ++i) {
      if (fast_ && flags[i] >= 0) continue;
      const double k = (*this)(x[i]);  // NaN for a non-finite x
      out[i] = k >= -0x1p31 && k < 0x1p31 ? static_cast<std::int64_t>(k) : 0;
    }
  }

 private:
  double resolution_;
  double inverse_;
  bool fast_;
};

/// True when row \p i of a batch is applied: its point and intensity are finite.
[[nodiscard]] inline bool row_is_finite(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                        Eigen::Index i) {
  return std::isfinite(points(i, 0)) && std::isfinite(points(i, 1)) && std::isfinite(points(i, 2)) &&
         std::isfinite(intensities[i]);
}

/// The keys of a chunk of up to kRows consecutive rows of a batch that validate_batch() accepted,
/// computed with FloorDivider::floor_many() axis by axis: the one way every backend turns batch
/// points into keys.
class ChunkKeys {
 public:
  static constexpr std::size_t kRows = 512;

  /// Keys of rows [begin, begin + rows), rows <= kRows.
  void compute(const Eigen::MatrixXd& points, Eigen::Index begin, std::size_t rows, const FloorDivider& divide) noexcept;
  /// After compute(): the key of row begin + r (meaningful for finite rows only).
  [[nodiscard]] VoxelKey operator[](std::size_t r) const {
    return {static_cast<std::int32_t>(axis_[0][r]), static_cast<std::int32_t>(axis_[1][r]),
            static_cast<std::int32_t>(axis_[2][r])};
  }

 private:
  std::array<std::array<std::int64_t, kRows>, 3> axis_;  // keys in the low 32 bits
  std::array<std::int64_t, kRows> flags_;                // scratch of floor_many()
};

/// Validates a batch: sizes (also more than 2^32 - 1 rows), weights (finite, >= 0) and keys that
/// fit int32, row by row, throwing for the first bad row: std::invalid_argument for sizes and
/// weights, std::out_of_range for a point whose key does not fit in int32. Returns how many rows
/// are skipped (a non-finite point or intensity); the others are to be applied.
std::size_t validate_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                           const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights, double resolution);

/// Calls fn(row, key) for every finite row among the first \p rows rows of a batch that
/// validate_batch() accepted, in order, with keys from ChunkKeys::compute(), a chunk at a time.
/// \p any_skipped: validate_batch() counted non-finite rows (otherwise no row is checked).
template <class Fn>
void for_each_finite_key(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities, std::size_t rows,
                         bool any_skipped, const FloorDivider& divide, Fn&& fn) {
  // Default-initialised (not make_unique's zeroing of 26 KiB): compute() writes what is read.
  const std::unique_ptr<ChunkKeys> keys(new ChunkKeys);
  for (std::size_t begin = 0; begin < rows; begin += ChunkKeys::kRows) {
    const std::size_t count = std::min(rows - begin, ChunkKeys::kRows);
    keys->compute(points, static_cast<Eigen::Index>(begin), count, divide);
    for (std::size_t r = 0; r < count; ++r) {
      const std::size_t row = begin + r;
      if (any_skipped && !row_is_finite(points, intensities, static_cast<Eigen::Index>(row))) continue;
      fn(row, (*keys)[r]);
    }
  }
}

/// Validates a batch (validate_batch()) and converts it to observations in
/// \p out (cleared first). Non-finite points or intensities are skipped; returns how many.
/// Throws before producing anything when the batch is invalid: std::invalid_argument for sizes
/// (also more than 2^32 - 1 rows) and weights, std::out_of_range for a point whose key does not
/// fit in int32.
std::size_t prepare_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                          const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights,
                          double resolution, std::vector<Observation>& out);

/// Throws std::invalid_argument unless points is N x 3 and intensities has N entries.
void check_scan_input(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                      const Eigen::VectorXd& intensities, double max_range, double resolution);

}  // namespace iwlomap::detail
