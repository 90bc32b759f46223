// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/mapper_backend.h"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <thread>

namespace iwlomap {

void IMapperBackend::set_num_threads(int threads) {
  if (threads < 0)
    throw std::invalid_argument("iwlomap: set_num_threads: threads must be >= 0 (0 = all hardware threads), got " +
                                std::to_string(threads));
  num_threads_ = threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

void BackendBase::modify_params(const std::function<void(IwloParams&)>& change) {
  IwloParams p = get_params();
  change(p);
  p.validate();
  set_params(p);
}

// Each setter changes its fields of a validated copy, so a rejected value leaves every parameter
// as it was.
void BackendBase::set_iwlo_params(double sharpness, double decay_rate, double min_alpha, double L_min, double L_max) {
  modify_params([&](IwloParams& p) {
    p.sharpness = sharpness;
    p.decay_rate = decay_rate;
    p.min_alpha = min_alpha;
    p.L_min = L_min;
    p.L_max = L_max;
  });
}

void BackendBase::set_log_odds_params(double log_odds_occupied, double log_odds_free) {
  modify_params([&](IwloParams& p) {
    p.log_odds_occupied = log_odds_occupied;
    p.log_odds_free = log_odds_free;
  });
}

void BackendBase::set_intensity_params(double intensity_threshold, double intensity_max) {
  modify_params([&](IwloParams& p) {
    p.intensity_threshold = intensity_threshold;
    p.intensity_max = intensity_max;
  });
}

void BackendBase::set_adaptive_params(bool enabled, double threshold, double max_ratio) {
  modify_params([&](IwloParams& p) {
    p.adaptive_enabled = enabled;
    p.adaptive_threshold = threshold;
    p.adaptive_max_ratio = max_ratio;
  });
}

void BackendBase::set_occupied_threshold(double threshold) {
  modify_params([&](IwloParams& p) { p.occupied_threshold = threshold; });
}

}  // namespace iwlomap
