// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// A progress bar on stderr, drawn only when stderr is a terminal (logs and pipes stay clean).

#include <cstddef>
#include <string>

namespace iwlomap::tool {

class Progress {
 public:
  Progress(std::string label, std::size_t total, bool enabled = true);
  ~Progress();
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;
  /// Sets the number of finished items and redraws.
  void update(std::size_t done, const std::string& note = {});
  void finish();

 private:
  std::string label_;
  std::size_t total_;
  bool active_;
};

/// Shows \p text (cut to the terminal's width) in place on stderr when \p enabled and stderr is a
/// terminal, e.g. "writing map.ot" during a long export after the bar reached 100 %; an empty
/// text clears the line.
void show_status(bool enabled, const std::string& text);

}  // namespace iwlomap::tool
