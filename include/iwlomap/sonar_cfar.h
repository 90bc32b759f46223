// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Constant-false-alarm-rate (CFAR) detection along one sonar beam: a range bin is an echo when
/// its power exceeds the local noise level, estimated from the bins around it, by a factor chosen
/// so that a bin of noise alone is detected with a fixed probability whatever the noise level.
/// Gain, range and seabed type move the noise floor of a sonar image; a fixed intensity threshold
/// then detects noise where the floor is high and misses echoes where it is low, a CFAR detector
/// does neither.
///
/// The test works on power, the square of the image's intensity (a square-law detector): the
/// amplitude of sonar noise is Rayleigh distributed, its power exponential, and for exponential
/// noise the factors below give exactly the requested false-alarm rate.
///
/// Window, per side of the cell under test (bin i; both sides or only the nearer one, see
/// SonarCfarWindow): the `guard_cells` nearest bins are left out (an echo spreads over a few bins
/// and must not raise its own noise estimate), the next `training_cells - guard_cells` bins are
/// the training cells. Near the ends of the beam the
/// window is cut off and only the bins that exist are used, with the factor for their number.
/// - Cell averaging (CA): noise = mean of the training powers; factor
///   alpha = N (P_fa^(-1/N) - 1) for N training cells. Best in uniform noise.
/// - Ordered statistic (OS): noise = the k-th smallest training power, k = ceil(os_rank N); alpha
///   solves P_fa = prod_{i=0}^{k-1} (N - i) / (N - i + alpha). Robust to a second target or a
///   clutter patch among the training cells, which would raise a mean.

#include <Eigen/Core>

#include <cstddef>
#include <vector>

namespace iwlomap {

/// How SonarImageProjector finds a beam's first return.
enum class SonarDetector {
  kThreshold,             ///< the first bin whose intensity exceeds intensity_threshold (default)
  kCellAveragingCfar,     ///< the first CA-CFAR detection (see sonar_cfar.h)
  kOrderedStatisticCfar,  ///< the first OS-CFAR detection
};

/// Which training cells estimate the noise level.
enum class SonarCfarWindow {
  /// Both sides of the cell under test: the classic window, for point-like echoes in noise.
  kBothSides,
  /// Only the nearer bins (the water the pulse crossed before it): for the first return of an
  /// extended echo. A seabed or a wall keeps echoing for many bins beyond its leading edge, and a
  /// window on the far side would count that echo as noise and miss the edge.
  kNearSide,
};

struct SonarCfarParams {
  /// Bins each side of the cell under test that the noise estimate leaves out (>= 0).
  int guard_cells = 2;
  /// Bins each side of the cell under test that the window spans, guard cells included
  /// (> guard_cells, <= 4096): training_cells - guard_cells per side are averaged or ranked.
  int training_cells = 18;
  /// Which side(s) of the cell under test the training cells lie on.
  SonarCfarWindow window = SonarCfarWindow::kNearSide;
  /// Probability that a bin of noise alone is detected, in (0, 1).
  double false_alarm_rate = 1e-3;
  /// OS-CFAR: the noise level is this quantile of the training powers, in (0, 1].
  double os_rank = 0.75;
  /// The noise level is at least this intensity (raw units, >= 0): in an integer image a quiet
  /// stretch is all zeros, and a zero noise level would make any non-zero bin a detection. 1 is
  /// the quantisation step of 8- and 16-bit images.
  double min_noise_intensity = 1.0;

  /// Throws std::invalid_argument naming the first invalid value.
  void validate() const;
};

/// CFAR detection along beams, with the scaling factors for every training-cell count
/// precomputed. Immutable after construction; detect() may run concurrently.
class SonarCfar {
 public:
  /// Throws std::invalid_argument for invalid \p params or a \p detector that is not a CFAR one.
  SonarCfar(SonarDetector detector, const SonarCfarParams& params);

  /// Whether bin i of \p intensities (one beam, nearest bin first; raw units, >= 0) is a
  /// detection, for every bin.
  [[nodiscard]] std::vector<bool> detect(const Eigen::VectorXd& intensities) const;

  /// The first bin in [first, last] of a beam whose intensity at bin i is \p intensity(i) (valid
  /// for i in [0, bins)) that is a detection and whose intensity exceeds \p min_intensity; -1
  /// when there is none. The windows reach outside [first, last] to any bin in [0, bins). When
  /// \p threshold_power is not null and a bin is found, it receives that bin's detection
  /// threshold on power (see threshold()).
  template <typename Intensity>
  [[nodiscard]] int first_detection(int bins, int first, int last, Intensity&& intensity,
                                    double min_intensity = -1.0, double* threshold_power = nullptr) const {
    std::vector<double> power(static_cast<std::size_t>(bins > 0 ? bins : 0));
    for (int i = 0; i < bins; ++i) {
      const double v = intensity(i);
      power[static_cast<std::size_t>(i)] = v * v;
    }
    std::vector<double> scratch;
    for (int i = first > 0 ? first : 0; i <= last && i < bins; ++i) {
      if (!(intensity(i) > min_intensity)) continue;
      const double t = threshold(power, i, scratch);
      if (power[static_cast<std::size_t>(i)] > t) {
        if (threshold_power != nullptr) *threshold_power = t;
        return i;
      }
    }
    return -1;
  }

  /// The detection threshold on power of bin \p i of \p power (squared intensities): the factor
  /// times the noise estimate; +infinity when the window holds no training cell.
  [[nodiscard]] double threshold(const std::vector<double>& power, int i, std::vector<double>& scratch) const;

  /// The factor alpha for \p n training cells (1 <= n <= 2 * (training_cells - guard_cells)).
  [[nodiscard]] double factor(int n) const { return factors_.at(static_cast<std::size_t>(n)); }

  [[nodiscard]] SonarDetector detector() const noexcept { return detector_; }
  [[nodiscard]] const SonarCfarParams& params() const noexcept { return params_; }

 private:
  [[nodiscard]] bool is_detection(const std::vector<double>& power, int i, std::vector<double>& scratch) const {
    return power[static_cast<std::size_t>(i)] > threshold(power, i, scratch);
  }
  SonarDetector detector_;
  SonarCfarParams params_;
  std::vector<double> factors_;  // index: training-cell count
};

}  // namespace iwlomap
