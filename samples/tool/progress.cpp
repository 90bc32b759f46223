// SPDX-License-Identifier: BSD-3-Clause
#include "progress.h"

#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <string>

namespace iwlomap::tool {

Progress::Progress(std::string label, std::size_t total, bool enabled)
    : label_(std::move(label)), total_(total), active_(enabled && isatty(STDERR_FILENO) != 0) {}

Progress::~Progress() { finish(); }

namespace {
// The terminal's width in columns (80 when it does not say).
int terminal_columns() {
  winsize ws{};
  if (ioctl(STDERR_FILENO, TIOCGWINSZ, &ws) == 0 && ws.ws_col > 0) return ws.ws_col;
  return 80;
}
}  // namespace

void Progress::update(std::size_t done, const std::string& note) { update(static_cast<double>(done), note); }

void Progress::update(double done, const std::string& note) {
  if (!active_ || total_ == 0) return;
  const double f = std::clamp(done / static_cast<double>(total_), 0.0, 1.0);
  const std::string counts = " " + std::to_string(static_cast<int>(f * 100.0)) + "% " +
                             std::to_string(static_cast<std::size_t>(std::max(done, 0.0))) + "/" + std::to_string(total_);
  // The line never reaches the last column: a terminal wraps there and the next \r would redraw
  // one line below. The bar shrinks first (to 10 cells), then the note is cut, then the label.
  const int columns = terminal_columns() - 1;
  const int fixed = static_cast<int>(label_.size() + counts.size()) + 3;  // " [" and "]"
  const int bar = std::clamp(columns - fixed - 1, 10, 30);
  std::string line = label_ + " [" + std::string(static_cast<std::size_t>(f * bar), '#') +
                     std::string(static_cast<std::size_t>(bar - static_cast<int>(f * bar)), ' ') + "]" + counts;
  if (!note.empty()) line += " " + note;
  if (static_cast<int>(line.size()) > columns) line.resize(static_cast<std::size_t>(std::max(columns, 0)));
  if (line == last_line_) return;
  last_line_ = line;
  std::fprintf(stderr, "\r%s\x1b[K", line.c_str());
  std::fflush(stderr);
}

ProgressCallback progress_within(Progress& bar, std::size_t item, const std::string& name) {
  return [&bar, item, name](const ProgressReport& r) {
    const double part = r.total == 0 ? 1.0 : static_cast<double>(r.done) / static_cast<double>(r.total);
    const double within = r.stage == ProgressStage::kCastingRays      ? 0.5 * part
                          : r.stage == ProgressStage::kUpdatingVoxels ? 0.5 + 0.5 * part
                                                                      : part;
    bar.update(static_cast<double>(item) + std::min(within, 1.0), name + ": " + progress_stage_name(r.stage));
  };
}

void show_status(bool enabled, const std::string& text) {
  if (!enabled || isatty(STDERR_FILENO) == 0) return;
  std::string line = text;
  const int columns = terminal_columns() - 1;
  if (static_cast<int>(line.size()) > columns) line.resize(static_cast<std::size_t>(std::max(columns, 0)));
  std::fprintf(stderr, "\r%s\x1b[K", line.c_str());
  std::fflush(stderr);
}

void Progress::finish() {
  if (!active_) return;
  std::fprintf(stderr, "\n");
  active_ = false;
}

}  // namespace iwlomap::tool
