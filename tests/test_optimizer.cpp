// SPDX-License-Identifier: BSD-3-Clause
// Optimizer: a running job stopped within 100 ms with nothing applied, the caller never blocked in
// parallel mode, the same outputs applied in both modes, the context kept between runs.

#include "iwlomap/optimizer.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <stdexcept>
#include <thread>

namespace iwlomap {
namespace {

// A job that counts until it is told to stop or reaches its input's target.
struct CountingJob : Optimizer<long, long, long> {
  explicit CountingJob(ExecutionMode mode) : Optimizer(mode) {}
  ~CountingJob() override { terminate(); }
  long target = 1000;
  long applied = -1;
  std::atomic<bool> started{false};
  std::atomic<bool> release{false};  // run() waits for it (or for stop) before it finishes
  long get_graph_data() override { return target; }
  void init_context(long& runs) override { runs = 0; }
  long run(const long& data, long& runs, const StopToken& stop) override {
    ++runs;
    started = true;
    while (!release.load()) {
      if (stop.stop_requested()) throw StopRequested();
      std::this_thread::yield();
    }
    return data * 10 + runs;
  }
  void write_result(const long& out) override { applied = out; }
};

TEST(Optimizer, ParallelNeverBlocksTheCallerAndTerminateStopsARunningJobQuickly) {
  CountingJob job(ExecutionMode::kParallel);
  job.optimize();  // returns although run() cannot finish until released
  while (!job.started.load()) std::this_thread::yield();
  EXPECT_TRUE(job.is_running());
  const auto t0 = std::chrono::steady_clock::now();
  job.terminate();
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  std::printf("terminate() returned after %.3f ms\n", ms);
  EXPECT_LE(ms, 100.0);
  EXPECT_FALSE(job.is_running());
  EXPECT_FALSE(job.write_map());  // the stopped job's output is discarded: nothing changed
  EXPECT_EQ(job.applied, -1);
  EXPECT_THROW(job.optimize(), std::logic_error);
}

TEST(Optimizer, SequentialAndParallelApplyTheSameOutputs) {
  for (const ExecutionMode mode : {ExecutionMode::kSequential, ExecutionMode::kParallel}) {
    CountingJob job(mode);
    job.release = true;
    job.target = 7;
    job.optimize();
    EXPECT_TRUE(job.write_map());
    EXPECT_EQ(job.applied, 71);  // the context counts runs: kept between runs
    job.target = 8;
    job.optimize();
    EXPECT_TRUE(job.write_map());
    EXPECT_EQ(job.applied, 82);
    EXPECT_FALSE(job.write_map());
  }
}

}  // namespace
}  // namespace iwlomap
