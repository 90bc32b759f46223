// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// BackgroundJob: runs work either in the caller's thread (sequential) or on one worker thread
/// (parallel), with the same results and the same error behaviour in both modes.

#include <iwlomap/stop_token.h>

#include <pthread.h>
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace iwlomap {

enum class ExecutionMode {
  kSequential,  ///< submit() runs the job in the caller's thread before it returns
  kParallel,    ///< submit() queues the job for the worker thread and returns
};

/// What submit() does when the queue of a parallel job is full.
enum class QueueFullPolicy {
  kBlock,       ///< wait until the worker takes a job from the queue
  kDropOldest,  ///< discard the oldest queued (not yet started) job; dropped() counts them
};

/// Runs `Output work(Input&&, Context&)` on each submitted input, in submission order. The context
/// lives as long as the job object and is passed to every run, so state survives between jobs.
///
/// Results: wait() blocks until every submitted job has finished and returns their outputs in
/// submission order (dropped jobs have none); write_map() does the same and hands each output to
/// an apply function. An exception thrown by the work is caught, the remaining jobs still run, and
/// the first exception is rethrown by the next wait() / write_map() — in both modes, so that
/// switching modes never changes what a caller sees.
///
/// Threads: submit(), wait(), write_map(), terminate(), is_running() and dropped() may be called
/// from any thread; the context must only be touched through with_context(), which waits first.
/// The destructor terminates the job (see terminate()) and joins the worker.
///
/// Stopping: a work function that takes a StopToken as third argument is asked to stop by
/// terminate(); it should throw StopRequested (or return) promptly, before it changes the
/// context, and its job then leaves no output and no error: the context is as before that job. The worker
/// thread blocks SIGINT and SIGTERM, so an interrupt is delivered to the program's own threads,
/// never to it. A job must not wait for its own BackgroundJob: wait(), write_map() and
/// with_context() called from inside a job throw std::logic_error instead of deadlocking.
template <class Input, class Context, class Output>
class BackgroundJob {
 public:
  using Work = std::function<Output(Input&&, Context&)>;
  using StoppableWork = std::function<Output(Input&&, Context&, const StopToken&)>;

  /// \param mode run each job in submit() (kSequential) or on a worker thread (kParallel)
  /// \param work the job: turns one input into one output, with the context at hand (not empty)
  /// \param context the state the jobs share (e.g. the map they write into)
  /// \param capacity queued (not yet started) jobs a parallel job holds, >= 1.
  /// \param policy what submit() does when the queue is full
  BackgroundJob(ExecutionMode mode, Work work, Context context = Context{}, std::size_t capacity = 4,
                QueueFullPolicy policy = QueueFullPolicy::kBlock)
      : BackgroundJob(mode, stoppable(std::move(work)), std::move(context), capacity, policy) {}

  /// As above, with a work function that reads the StopToken terminate() sets.
  BackgroundJob(ExecutionMode mode, StoppableWork work, Context context = Context{}, std::size_t capacity = 4,
                QueueFullPolicy policy = QueueFullPolicy::kBlock)
      : mode_(mode), work_(std::move(work)), context_(std::move(context)), capacity_(capacity), policy_(policy) {
    if (!work_) throw std::invalid_argument("BackgroundJob: the work function is empty");
    if (capacity_ == 0) throw std::invalid_argument("BackgroundJob: capacity must be >= 1, got 0");
    if (mode_ == ExecutionMode::kParallel) start_worker();
  }

  ~BackgroundJob() { terminate(); }

  BackgroundJob(const BackgroundJob&) = delete;
  BackgroundJob& operator=(const BackgroundJob&) = delete;
  BackgroundJob(BackgroundJob&&) = delete;
  BackgroundJob& operator=(BackgroundJob&&) = delete;

  [[nodiscard]] ExecutionMode mode() const noexcept { return mode_; }

  /// Queues \p input (parallel) or runs it now (sequential). Throws std::logic_error after
  /// terminate() in parallel mode.
  void submit(Input input) {
    std::unique_lock<std::mutex> lock(mutex_);
    if (terminated_) throw std::logic_error("BackgroundJob: submit() after terminate()");
    const std::size_t ticket = next_ticket_++;
    if (mode_ == ExecutionMode::kSequential) {
      ++in_flight_;
      lock.unlock();
      // Callers on several threads take turns, as they would behind the one worker.
      std::lock_guard<std::mutex> turn(sequential_turn_);
      execute(ticket, std::move(input));
      return;
    }
    if (queue_.size() >= capacity_) {
      if (policy_ == QueueFullPolicy::kDropOldest) {
        queue_.pop_front();
        ++dropped_;
      } else {
        space_.wait(lock, [this] { return queue_.size() < capacity_ || terminated_; });
        if (terminated_) throw std::logic_error("BackgroundJob: terminated while submit() waited");
      }
    }
    queue_.emplace_back(ticket, std::move(input));
    max_queued_ = std::max(max_queued_, queue_.size());
    work_ready_.notify_one();
  }

  /// Blocks until every submitted job has finished; returns their outputs in submission order and
  /// rethrows the first exception a job threw since the last wait().
  std::vector<Output> wait() {
    refuse_inside_job("wait()");
    std::unique_lock<std::mutex> lock(mutex_);
    idle_.wait(lock, [this] { return queue_.empty() && in_flight_ == 0; });
    return take_results();
  }

  /// wait(), then apply(map, output) for each output in order.
  template <class Map, class Apply>
  void write_map(Map& map, Apply&& apply) {
    refuse_inside_job("write_map()");
    for (Output& o : wait()) apply(map, o);
  }

  /// Calls fn(context) once no job runs (waits for queued jobs first); returns what fn returns.
  template <class Fn>
  decltype(auto) with_context(Fn&& fn) {
    refuse_inside_job("with_context()");
    std::unique_lock<std::mutex> lock(mutex_);
    idle_.wait(lock, [this] { return queue_.empty() && in_flight_ == 0; });
    return fn(context_);
  }

  /// Discards queued jobs and refuses new ones without waiting: a running job goes on to its end.
  /// For a sensor loop that must not block; terminate() also waits. Idempotent. In sequential
  /// mode there is no queue and no worker: a no-op, and later submit() calls still run.
  void cancel() {
    if (mode_ == ExecutionMode::kSequential) return;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      terminated_ = true;
      queue_.clear();
    }
    work_ready_.notify_all();
    space_.notify_all();
    idle_.notify_all();
  }

  /// cancel(), asks a running job to stop through its StopToken (a stoppable work function; any
  /// other runs to its end), and joins the worker. Finished outputs (and a pending exception) stay
  /// available to wait(). Idempotent; a no-op in sequential mode.
  void terminate() {
    if (mode_ == ExecutionMode::kParallel) stop_.store(true);
    cancel();
    if (worker_.joinable()) worker_.join();
  }

  /// True while a job is queued or running.
  [[nodiscard]] bool is_running() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return !queue_.empty() || in_flight_ > 0;
  }
  /// Jobs waiting in the queue (not yet started).
  [[nodiscard]] std::size_t queued() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return queue_.size();
  }
  /// Jobs discarded by QueueFullPolicy::kDropOldest so far.
  [[nodiscard]] std::size_t dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }
  /// The most jobs that were ever queued at once (never more than the capacity).
  [[nodiscard]] std::size_t max_queued() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return max_queued_;
  }

 private:
  // The worker is created with SIGINT and SIGTERM blocked (a new thread inherits the creating
  // thread's mask), so that the process's handlers run on the threads that expect them.
  void start_worker() {
    sigset_t block, previous;
    sigemptyset(&block);
    sigaddset(&block, SIGINT);
    sigaddset(&block, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &block, &previous);
    try {
      worker_ = std::thread([this] { run_worker(); });
    } catch (...) {
      pthread_sigmask(SIG_SETMASK, &previous, nullptr);
      throw;
    }
    pthread_sigmask(SIG_SETMASK, &previous, nullptr);
  }

  void refuse_inside_job(const char* what) const {
    std::lock_guard<std::mutex> lock(mutex_);
    if (running_on_ == std::this_thread::get_id())
      throw std::logic_error(std::string("BackgroundJob: ") + what +
                             " called from inside a job of the same BackgroundJob, which would wait for itself");
  }

  void run_worker() {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      work_ready_.wait(lock, [this] { return !queue_.empty() || terminated_; });
      if (queue_.empty()) return;  // terminated and nothing left
      auto [ticket, input] = std::move(queue_.front());
      queue_.pop_front();
      ++in_flight_;
      space_.notify_one();
      lock.unlock();
      execute(ticket, std::move(input));
      lock.lock();
    }
  }

  // Runs one job outside the lock and records its output or exception.
  void execute(std::size_t ticket, Input&& input) {
    std::exception_ptr error;
    std::vector<Output> out;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      running_on_ = std::this_thread::get_id();
    }
    try {
      out.push_back(work_(std::move(input), context_, StopToken(&stop_)));
    } catch (const StopRequested&) {
      // Stopped by terminate(): no output, no error.
    } catch (...) {
      error = std::current_exception();
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      running_on_ = std::thread::id();
      if (error && !error_) error_ = error;
      if (!out.empty()) results_.emplace_back(ticket, std::move(out.front()));
      --in_flight_;
    }
    idle_.notify_all();
  }

  std::vector<Output> take_results() {
    std::vector<std::pair<std::size_t, Output>> done;
    done.swap(results_);
    std::exception_ptr error = std::exchange(error_, nullptr);
    if (error) std::rethrow_exception(error);
    std::stable_sort(done.begin(), done.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<Output> outputs;
    outputs.reserve(done.size());
    for (auto& d : done) outputs.push_back(std::move(d.second));
    return outputs;
  }

  static StoppableWork stoppable(Work work) {
    if (!work) return {};
    return [w = std::move(work)](Input&& input, Context& context, const StopToken&) { return w(std::move(input), context); };
  }

  const ExecutionMode mode_;
  StoppableWork work_;
  std::atomic<bool> stop_{false};
  Context context_;
  const std::size_t capacity_;
  const QueueFullPolicy policy_;

  mutable std::mutex mutex_;
  std::mutex sequential_turn_;
  std::condition_variable work_ready_;  // queue gained a job, or terminate
  std::condition_variable space_;       // queue lost a job, or terminate
  std::condition_variable idle_;        // a job finished
  std::deque<std::pair<std::size_t, Input>> queue_;
  std::vector<std::pair<std::size_t, Output>> results_;
  std::exception_ptr error_;
  std::size_t next_ticket_ = 0;
  std::size_t in_flight_ = 0;
  std::size_t dropped_ = 0;
  std::size_t max_queued_ = 0;
  bool terminated_ = false;
  std::thread::id running_on_;  // the thread running a job, if one runs
  std::thread worker_;
};

}  // namespace iwlomap
