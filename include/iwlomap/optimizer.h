// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Optimizer: runs a long computation over a snapshot of some state (a pose graph, say) either in
/// the caller's thread or on a worker thread, and writes its result back only when the caller
/// asks, so the caller's state changes in the caller's thread alone.
///
/// A derived class supplies four steps:
/// - get_graph_data(): a snapshot of the input, taken in the caller's thread by optimize();
/// - init_context(context): once, before the first run; the context is kept between runs (for
///   structures worth reusing) and only the running job touches it;
/// - run(data, context, stop): the computation; it must return promptly (within 100 ms, the bound
///   the tests check) once stop.stop_requested() turns true, by throwing StopRequested or
///   returning anything: a stopped run's output is discarded;
/// - write_result(output): applies an output, in the caller's thread, from write_map().
///
/// Sequential mode runs the job inside optimize(). Parallel mode snapshots in optimize() and
/// returns at once: the job runs on the worker; an optimize() while a job runs queues one request
/// (a newer one replaces it), so the caller is never blocked by the optimizer. Given the same
/// sequence of calls, both modes apply the same outputs in the same order from write_map(), so
/// when run() depends only on its input the results are identical.
///
/// terminate() stops a running job through its stop token, discards its output, any queued
/// request and any output not yet applied, and returns once the worker has finished: what the
/// caller's state holds is what the last write_map() wrote. A derived class must call terminate() first in its destructor (the
/// worker calls its virtual functions). An exception thrown by run() is rethrown by write_map().

#include <iwlomap/background_job.h>
#include <iwlomap/stop_token.h>

#include <atomic>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <thread>
#include <utility>

namespace iwlomap {

template <class GraphData, class Context, class Output>
class Optimizer {
 public:
  /// \p mode: run jobs inside optimize() (kSequential) or on a worker thread (kParallel).
  explicit Optimizer(ExecutionMode mode) : parallel_(mode == ExecutionMode::kParallel) {}
  virtual ~Optimizer() { terminate(); }

  Optimizer(const Optimizer&) = delete;
  Optimizer& operator=(const Optimizer&) = delete;

  /// Snapshots the input (get_graph_data(), in this thread) and optimizes it: now (sequential), or
  /// on the worker (parallel; returns at once). Throws std::logic_error after terminate().
  void optimize() {
    GraphData data = get_graph_data();
    std::unique_lock<std::mutex> lock(mutex_);
    if (terminated_) throw std::logic_error("iwlomap: Optimizer: optimize() after terminate()");
    if (!parallel_) {
      lock.unlock();
      std::lock_guard<std::mutex> turn(sequential_turn_);
      execute(std::move(data));
      return;
    }
    request_ = std::move(data);
    if (!worker_.joinable()) worker_ = std::thread([this] { run_worker(); });
    wake_.notify_all();
  }

  /// Waits for a queued or running job, then applies the newest output not yet applied
  /// (write_result()) in this thread: each run works on a whole snapshot, so a newer output
  /// supersedes an older one. Returns true when an output was applied. Rethrows a job's exception.
  bool write_map() {
    std::unique_lock<std::mutex> lock(mutex_);
    if (std::this_thread::get_id() == worker_.get_id())
      throw std::logic_error("iwlomap: Optimizer: write_map() called from inside the optimization");
    idle_.wait(lock, [this] { return !request_ && !running_; });
    if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
    std::optional<Output> out = std::exchange(output_, std::nullopt);
    lock.unlock();
    if (!out) return false;
    write_result(*out);
    return true;
  }

  /// Stops a running job, drops a queued request and an output not yet applied, and joins the
  /// worker: the caller's state stays what the last write_map() made it. Idempotent; optimize()
  /// throws afterwards.
  void terminate() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      terminated_ = true;
      request_.reset();
      output_.reset();
      stop_.store(true);
    }
    wake_.notify_all();
    if (worker_.joinable() && std::this_thread::get_id() != worker_.get_id()) worker_.join();
    idle_.notify_all();
  }

  /// True while a job is queued or running.
  [[nodiscard]] bool is_running() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return request_.has_value() || running_;
  }

  [[nodiscard]] ExecutionMode mode() const noexcept {
    return parallel_ ? ExecutionMode::kParallel : ExecutionMode::kSequential;
  }

 protected:
  virtual GraphData get_graph_data() = 0;
  virtual void init_context(Context& context) = 0;
  virtual Output run(const GraphData& data, Context& context, const StopToken& stop) = 0;
  virtual void write_result(const Output& output) = 0;

 private:
  void run_worker() {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      wake_.wait(lock, [this] { return request_.has_value() || terminated_; });
      if (terminated_) return;
      GraphData data = std::move(*request_);
      request_.reset();
      running_ = true;
      lock.unlock();
      execute(std::move(data));
      lock.lock();
      running_ = false;
      idle_.notify_all();
    }
  }

  // Runs one job and keeps its output, unless it was stopped.
  void execute(GraphData data) {
    std::exception_ptr error;
    std::optional<Output> out;
    try {
      if (!context_ready_) {
        init_context(context_);
        context_ready_ = true;
      }
      out.emplace(run(data, context_, StopToken(&stop_)));
    } catch (const StopRequested&) {
    } catch (...) {
      error = std::current_exception();
    }
    std::lock_guard<std::mutex> lock(mutex_);
    if (stop_.load()) return;
    if (error && !error_) error_ = error;
    if (out) output_ = std::move(out);
  }

  const bool parallel_;
  Context context_{};
  bool context_ready_ = false;  // touched only by the thread running jobs
  std::atomic<bool> stop_{false};
  mutable std::mutex mutex_;
  std::mutex sequential_turn_;
  std::condition_variable wake_;  // a request arrived, or terminate
  std::condition_variable idle_;  // a job finished
  std::optional<GraphData> request_;
  std::optional<Output> output_;
  std::exception_ptr error_;
  bool running_ = false;
  bool terminated_ = false;
  std::thread worker_;
};

}  // namespace iwlomap
