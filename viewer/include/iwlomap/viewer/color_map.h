// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Colour maps of the snapshot renderer: piecewise-linear ramps over [0, 1]. Pure C++ (no VTK), so
/// the colours a snapshot uses can be computed and checked without a display.

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace iwlomap::viewer {

/// A colour with components in [0, 1].
struct Rgb {
  double r = 0.0;
  double g = 0.0;
  double b = 0.0;
};

/// 8-bit form of \p c (each component clamped to [0, 1] and rounded), as PNG files store it.
[[nodiscard]] std::array<std::uint8_t, 3> to_rgb8(const Rgb& c);

/// The number of decimals (0 to 10) with which \p labels evenly spaced values over [\p lo, \p hi]
/// print as distinct numbers: one more than the leading digit of the step between them needs, so
/// [0.5, 1] gives 2 ("0.50 0.62 0.75 0.88 1.00") and a height range [100.00, 100.04] gives 3. An
/// empty or invalid range gives 2.
[[nodiscard]] int label_decimals(double lo, double hi, int labels);

/// A colour ramp: colours at increasing positions in [0, 1], interpolated linearly between them
/// (in RGB). The first stop is at 0 and the last at 1.
class ColorMap {
 public:
  struct Stop {
    double position;  ///< in [0, 1]
    Rgb color;
  };

  /// Throws std::invalid_argument (naming the stop and value) unless there are at least two stops,
  /// the first at 0 and the last at 1, positions strictly increasing, components in [0, 1].
  explicit ColorMap(std::vector<Stop> stops);

  /// Height ramp, low to high: deep blue, cyan-blue, green, yellow, red. Hue changes
  /// monotonically, so terrain reads as contour bands.
  [[nodiscard]] static ColorMap height();
  /// Occupancy-probability ramp, uncertain to certain: blue, yellow, red. The warm end marks the
  /// confident voxels, which is what a reviewer looks for first.
  [[nodiscard]] static ColorMap probability();

  /// Colour at \p t; t is clamped to [0, 1]. Throws std::invalid_argument for NaN.
  [[nodiscard]] Rgb at(double t) const;
  /// Colour of \p value on the range [lo, hi] (lo maps to 0, hi to 1, clamped). lo == hi maps
  /// everything to the middle of the ramp. Throws std::invalid_argument for a NaN value or a
  /// non-finite or reversed range.
  [[nodiscard]] Rgb map(double value, double lo, double hi) const;
  /// \p n colours evenly spaced over [0, 1] (n >= 2), e.g. for a lookup table or a colour bar.
  [[nodiscard]] std::vector<Rgb> sample(std::size_t n) const;

  [[nodiscard]] const std::vector<Stop>& stops() const { return stops_; }

 private:
  std::vector<Stop> stops_;
};

}  // namespace iwlomap::viewer
