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

void Progress::update(std::size_t done, const std::string& note) {
  if (!active_ || total_ == 0) return;
  const double f = std::min(1.0, static_cast<double>(done) / static_cast<double>(total_));
  const std::string counts = " " + std::to_string(static_cast<int>(f * 100.0)) + "% " + std::to_string(done) + "/" +
                             std::to_string(total_);
  // The line never reaches the last column: a terminal wraps there and the next \r would redraw
  // one line below. The bar shrinks first (to 10 cells), then the note is cut, then the label.
  const int columns = terminal_columns() - 1;
  const int fixed = static_cast<int>(label_.size() + counts.size()) + 3;  // " [" and "]"
  const int bar = std::clamp(columns - fixed - 1, 10, 30);
  std::string line = label_ + " [" + std::string(static_cast<std::size_t>(f * bar), '#') +
                     std::string(static_cast<std::size_t>(bar - static_cast<int>(f * bar)), ' ') + "]" + counts;
  if (!note.empty()) line += " " + note;
  if (static_cast<int>(line.size()) > columns) line.resize(static_cast<std::size_t>(std::max(columns, 0)));
  std::fprintf(stderr, "\r%s\x1b[K", line.c_str());
  std::fflush(stderr);
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
