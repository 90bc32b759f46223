// SPDX-License-Identifier: BSD-3-Clause
#pragma once

#include <cstdio>
#include <mutex>
#include <string>

namespace iwlomap::detail {

/// OctoMap reports progress and errors on stdout/stderr (Debian's build prints its debug lines
/// too), from the shared library where no macro can reach them. While a capture lives, both
/// descriptors point to a temporary file, so what OctoMap said can go into an exception message
/// instead of the console. One capture at a time in the process (the descriptors are global);
/// console output of other threads in that window is captured too.
class ConsoleCapture {
 public:
  ConsoleCapture();
  ~ConsoleCapture();
  ConsoleCapture(const ConsoleCapture&) = delete;
  ConsoleCapture& operator=(const ConsoleCapture&) = delete;

  /// Restores the console and returns what was printed meanwhile, as one line (may be empty).
  std::string finish();

 private:
  void restore();

  std::lock_guard<std::mutex> lock_;
  std::FILE* sink_ = nullptr;
  int saved_out_ = -1;
  int saved_err_ = -1;
  bool redirected_ = false;
};

/// " (OctoMap: <text>)", or nothing for an empty text.
[[nodiscard]] std::string octomap_said(const std::string& text);

}  // namespace iwlomap::detail
