// SPDX-License-Identifier: BSD-3-Clause
#include "progress.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace iwlomap::tool {

Progress::Progress(std::string label, std::size_t total, bool enabled)
    : label_(std::move(label)), total_(total), active_(enabled && isatty(STDERR_FILENO) != 0) {}

Progress::~Progress() { finish(); }

void Progress::update(std::size_t done, const std::string& note) {
  if (!active_ || total_ == 0) return;
  constexpr int kWidth = 30;
  const double f = std::min(1.0, static_cast<double>(done) / static_cast<double>(total_));
  const int filled = static_cast<int>(f * kWidth);
  std::fprintf(stderr, "\r%s [%.*s%*s] %3d%% %zu/%zu %s\x1b[K", label_.c_str(), filled,
               "##############################", kWidth - filled, "", static_cast<int>(f * 100.0), done, total_,
               note.c_str());
  std::fflush(stderr);
}

void Progress::finish() {
  if (!active_) return;
  std::fprintf(stderr, "\n");
  active_ = false;
}

}  // namespace iwlomap::tool
