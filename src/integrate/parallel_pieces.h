// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The threads of the scan kernels: work over [0, n) in pieces taken from a shared counter, on up
// to `threads` threads of which the calling thread is one.

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <exception>
#include <thread>
#include <vector>

namespace iwlomap::detail {

/// Calls work(k, begin, end) for pieces [begin, end) of at most \p grain items covering [0, n) once
/// each, on up to \p threads threads; k (0 .. threads - 1) names the thread, 0 being the calling
/// one. An exception of any call stops every thread from taking more pieces and is rethrown here
/// once all have joined (the first thread's, by k). Which thread takes which piece is not fixed:
/// work must give the same result in any assignment.
template <class Work>
void parallel_pieces(std::size_t n, std::size_t grain, std::size_t threads, Work&& work) {
  const std::size_t t = std::max<std::size_t>(threads, 1);
  if (t == 1) {
    for (std::size_t b = 0; b < n; b += grain) work(std::size_t{0}, b, std::min(b + grain, n));
    return;
  }
  std::atomic<std::size_t> next{0};
  std::vector<std::exception_ptr> failed(t);
  const auto run = [&](std::size_t k) {
    try {
      for (std::size_t b = next.fetch_add(grain); b < n; b = next.fetch_add(grain)) work(k, b, std::min(b + grain, n));
    } catch (...) {
      failed[k] = std::current_exception();
      next.store(n);
    }
  };
  std::vector<std::thread> workers;
  workers.reserve(t - 1);
  for (std::size_t k = 1; k < t; ++k) workers.emplace_back(run, k);
  run(0);
  for (auto& w : workers) w.join();
  for (const std::exception_ptr& e : failed)
    if (e) std::rethrow_exception(e);
}

}  // namespace iwlomap::detail
