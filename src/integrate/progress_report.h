// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Reporting one stage of a long call to a ProgressCallback (iwlomap/progress.h): done = 0 at the
// start, done = total at finish(), and the calls in between only when done advanced.

#include "iwlomap/progress.h"

#include <exception>

namespace iwlomap::detail {

class StageProgress {
 public:
  /// Reports nothing when \p callback is null or empty. With \p deferred, an exception of the
  /// callback is kept there (the first one) and stops the reports, so the work can go on to its
  /// end; without, it propagates from the report.
  StageProgress(const ProgressCallback* callback, ProgressStage stage, std::size_t total,
                std::exception_ptr* deferred = nullptr)
      : callback_(callback != nullptr && *callback ? callback : nullptr), stage_(stage), total_(total),
        deferred_(deferred) {
    report(0);
  }

  [[nodiscard]] bool active() const noexcept { return callback_ != nullptr; }

  void report(std::size_t done) {
    if (callback_ == nullptr || (done <= last_ && last_ != kNone)) return;
    last_ = done > total_ ? total_ : done;
    if (deferred_ == nullptr) {
      (*callback_)(ProgressReport{stage_, last_, total_});
      return;
    }
    try {
      (*callback_)(ProgressReport{stage_, last_, total_});
    } catch (...) {
      if (!*deferred_) *deferred_ = std::current_exception();
      callback_ = nullptr;
    }
  }

  void finish() { report(total_); }

 private:
  static constexpr std::size_t kNone = ~std::size_t{0};
  const ProgressCallback* callback_;
  ProgressStage stage_;
  std::size_t total_;
  std::exception_ptr* deferred_;
  std::size_t last_ = kNone;
};

}  // namespace iwlomap::detail
