// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// A progress bar on stderr, drawn only when stderr is a terminal (logs and pipes stay clean).

#include <iwlomap/progress.h>

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
  /// The same with a part of an item done (2.5: two items and half of the third); the count shown
  /// is the whole items.
  void update(double done, const std::string& note = {});
  void finish();

 private:
  std::string label_;
  std::size_t total_;
  bool active_;
  std::string last_line_;  // not drawn again when unchanged
};

/// A progress callback (IMapperBackend::set_progress_callback(), export_octomap()) that moves
/// \p bar within item \p item (the items before it done): a scan's rays are the first half of the
/// item and its voxel updates the second; any other stage is the whole item. The note names the
/// stage after \p name.
[[nodiscard]] ProgressCallback progress_within(Progress& bar, std::size_t item, const std::string& name);

/// Shows \p text (cut to the terminal's width) in place on stderr when \p enabled and stderr is a
/// terminal, e.g. "writing map.ot" during a long export after the bar reached 100 %; an empty
/// text clears the line.
void show_status(bool enabled, const std::string& text);

}  // namespace iwlomap::tool
