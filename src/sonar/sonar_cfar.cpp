// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/sonar_cfar.h"

#include "model/checks.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace iwlomap {

namespace {

[[noreturn]] void fail(const char* name, double value, const char* rule) {
  throw std::invalid_argument(std::string("iwlomap: invalid CFAR parameter ") + detail::describe(name, value) + " (" +
                              rule + ")");
}

// The OS-CFAR false-alarm rate of factor alpha for n cells and rank k: prod (n - i) / (n - i + alpha).
double os_false_alarm(int n, int k, double alpha) {
  double p = 1.0;
  for (int i = 0; i < k; ++i) p *= static_cast<double>(n - i) / (static_cast<double>(n - i) + alpha);
  return p;
}

}  // namespace

void SonarCfarParams::validate() const {
  if (guard_cells < 0) fail("guard_cells", guard_cells, "must be >= 0");
  if (training_cells <= guard_cells)
    fail("training_cells", training_cells,
         ("must be > guard_cells = " + std::to_string(guard_cells) + ": the window would hold no training cell").c_str());
  if (training_cells > 4096) fail("training_cells", training_cells, "must be <= 4096");
  if (window != SonarCfarWindow::kBothSides && window != SonarCfarWindow::kNearSide)
    fail("window", static_cast<double>(window), "must be a SonarCfarWindow");
  if (!(false_alarm_rate > 0.0 && false_alarm_rate < 1.0))
    fail("false_alarm_rate", false_alarm_rate, "must be in (0, 1)");
  if (!(os_rank > 0.0 && os_rank <= 1.0)) fail("os_rank", os_rank, "must be in (0, 1]");
  if (!(std::isfinite(min_noise_intensity) && min_noise_intensity >= 0.0))
    fail("min_noise_intensity", min_noise_intensity, "must be finite and >= 0");
}

SonarCfar::SonarCfar(SonarDetector detector, const SonarCfarParams& params) : detector_(detector), params_(params) {
  if (detector != SonarDetector::kCellAveragingCfar && detector != SonarDetector::kOrderedStatisticCfar)
    throw std::invalid_argument("iwlomap: SonarCfar needs kCellAveragingCfar or kOrderedStatisticCfar, got detector " +
                                std::to_string(static_cast<int>(detector)));
  params_.validate();
  const int most = 2 * (params_.training_cells - params_.guard_cells);
  const double pfa = params_.false_alarm_rate;
  factors_.assign(static_cast<std::size_t>(most) + 1, std::numeric_limits<double>::infinity());
  for (int n = 1; n <= most; ++n) {
    double alpha = 0.0;
    if (detector == SonarDetector::kCellAveragingCfar) {
      alpha = n * (std::pow(pfa, -1.0 / n) - 1.0);
    } else {
      // The false-alarm rate falls as alpha grows: bisection on [0, hi] with hi doubled until
      // it is below the target.
      const int k = std::clamp(static_cast<int>(std::ceil(params_.os_rank * n)), 1, n);
      double lo = 0.0, hi = 1.0;
      while (os_false_alarm(n, k, hi) > pfa) hi *= 2.0;
      for (int it = 0; it < 200 && hi - lo > 1e-12 * hi; ++it) {
        const double mid = 0.5 * (lo + hi);
        (os_false_alarm(n, k, mid) > pfa ? lo : hi) = mid;
      }
      alpha = hi;
    }
    factors_[static_cast<std::size_t>(n)] = alpha;
  }
}

double SonarCfar::threshold(const std::vector<double>& power, int i, std::vector<double>& scratch) const {
  const int bins = static_cast<int>(power.size());
  const int g = params_.guard_cells, t = params_.training_cells;
  scratch.clear();
  double sum = 0.0;
  const auto take = [&](int lo, int hi) {  // bins [lo, hi], clipped to the beam
    for (int j = std::max(lo, 0); j <= std::min(hi, bins - 1); ++j) {
      const double v = power[static_cast<std::size_t>(j)];
      sum += v;
      scratch.push_back(v);
    }
  };
  take(i - t, i - g - 1);
  if (params_.window == SonarCfarWindow::kBothSides) take(i + g + 1, i + t);
  const int n = static_cast<int>(scratch.size());
  if (n == 0) return std::numeric_limits<double>::infinity();
  double noise = 0.0;
  if (detector_ == SonarDetector::kCellAveragingCfar) {
    noise = sum / n;
  } else {
    const int k = std::clamp(static_cast<int>(std::ceil(params_.os_rank * n)), 1, n);
    std::nth_element(scratch.begin(), scratch.begin() + (k - 1), scratch.end());
    noise = scratch[static_cast<std::size_t>(k - 1)];
  }
  const double floor = params_.min_noise_intensity * params_.min_noise_intensity;
  return factors_[static_cast<std::size_t>(n)] * std::max(noise, floor);
}

std::vector<bool> SonarCfar::detect(const Eigen::VectorXd& intensities) const {
  const auto bins = static_cast<int>(intensities.size());
  std::vector<double> power(static_cast<std::size_t>(bins));
  for (int i = 0; i < bins; ++i) {
    const double v = intensities[i];
    if (!(std::isfinite(v) && v >= 0.0))
      throw std::invalid_argument("iwlomap: CFAR: intensity " + std::to_string(v) + " at bin " + std::to_string(i) +
                                  " is not finite and >= 0");
    power[static_cast<std::size_t>(i)] = v * v;
  }
  std::vector<bool> out(static_cast<std::size_t>(bins));
  std::vector<double> scratch;
  for (int i = 0; i < bins; ++i) out[static_cast<std::size_t>(i)] = is_detection(power, i, scratch);
  return out;
}

}  // namespace iwlomap
