// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Cooperative cancellation: a long computation reads a StopToken and, once it is set, throws
/// StopRequested (or returns) before it changes anything its caller keeps.

#include <atomic>
#include <stdexcept>

namespace iwlomap {

/// Read by a long computation to learn that it should stop. A default token never stops.
class StopToken {
 public:
  explicit StopToken(const std::atomic<bool>* flag = nullptr) noexcept : flag_(flag) {}
  [[nodiscard]] bool stop_requested() const noexcept { return flag_ && flag_->load(std::memory_order_relaxed); }
  /// Throws StopRequested when a stop was requested.
  void throw_if_stopped() const;

 private:
  const std::atomic<bool>* flag_;
};

/// Thrown by a computation that saw its stop token; Optimizer and BackgroundJob discard the job.
struct StopRequested : std::runtime_error {
  StopRequested() : std::runtime_error("iwlomap: stopped on request") {}
};

inline void StopToken::throw_if_stopped() const {
  if (stop_requested()) throw StopRequested();
}

}  // namespace iwlomap
