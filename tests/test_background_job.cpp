// SPDX-License-Identifier: BSD-3-Clause
// BackgroundJob and AsyncMapper: identical results in both modes, ordering, the bounded queue,
// errors, terminate and destruction. Jobs are held with promises, never with sleeps.

#include "iwlomap/async_mapper.h"
#include "iwlomap/background_job.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include <gtest/gtest.h>

#include <pthread.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <future>
#include <memory>
#include <stdexcept>
#include <thread>
#include <vector>

namespace {

using iwlomap::BackgroundJob;
using iwlomap::ExecutionMode;
using iwlomap::QueueFullPolicy;

// Context of the gated jobs: job `gated` announces that it started and then waits for the gate.
struct Gate {
  int gated = 0;
  std::shared_ptr<std::promise<void>> started = std::make_shared<std::promise<void>>();
  std::shared_ptr<std::promise<void>> open = std::make_shared<std::promise<void>>();
  std::shared_future<void> open_future = open->get_future().share();
  std::vector<int> ran;  // the order the worker ran jobs in (touched by the worker only)
};

using GatedJob = BackgroundJob<int, Gate, int>;

GatedJob::Work gated_work() {
  return [](int&& x, Gate& g) {
    if (x == g.gated) {
      g.started->set_value();
      g.open_future.wait();
    }
    g.ran.push_back(x);
    return x * 10;
  };
}

TEST(BackgroundJob, BothModesGiveTheSameOutputsInSubmissionOrder) {
  for (auto mode : {ExecutionMode::kSequential, ExecutionMode::kParallel}) {
    BackgroundJob<int, int, int> job(mode, [](int&& x, int& sum) { return sum += x; });
    for (int i = 1; i <= 100; ++i) job.submit(i);
    const std::vector<int> out = job.wait();
    ASSERT_EQ(out.size(), 100u);
    for (int i = 1; i <= 100; ++i) EXPECT_EQ(out[static_cast<std::size_t>(i - 1)], i * (i + 1) / 2);
    EXPECT_TRUE(job.wait().empty());  // outputs are handed out once
    EXPECT_FALSE(job.is_running());
    EXPECT_EQ(job.with_context([](int& sum) { return sum; }), 5050);  // the context survives between jobs
  }
}

TEST(BackgroundJob, ParallelSubmitReturnsWhileAJobRuns) {
  Gate gate;
  auto started = gate.started->get_future();
  GatedJob job(ExecutionMode::kParallel, gated_work(), gate, 8);
  job.submit(0);  // held at the gate
  started.wait();
  job.submit(1);
  job.submit(2);
  EXPECT_TRUE(job.is_running());
  gate.open->set_value();
  EXPECT_EQ(job.wait(), (std::vector<int>{0, 10, 20}));
  EXPECT_FALSE(job.is_running());
}

TEST(BackgroundJob, BlockPolicyNeverQueuesMoreThanTheCapacity) {
  Gate gate;
  auto started = gate.started->get_future();
  GatedJob job(ExecutionMode::kParallel, gated_work(), gate, 2, QueueFullPolicy::kBlock);
  job.submit(0);
  started.wait();
  job.submit(1);
  job.submit(2);  // queue now full
  std::thread producer([&] {
    for (int i = 3; i < 10; ++i) job.submit(i);  // blocks until the worker makes room
  });
  gate.open->set_value();
  producer.join();
  const std::vector<int> out = job.wait();
  ASSERT_EQ(out.size(), 10u);
  for (int i = 0; i < 10; ++i) EXPECT_EQ(out[static_cast<std::size_t>(i)], i * 10);
  EXPECT_EQ(job.max_queued(), 2u);
  EXPECT_EQ(job.dropped(), 0u);
}

TEST(BackgroundJob, DropOldestPolicyKeepsTheNewestJobs) {
  Gate gate;
  auto started = gate.started->get_future();
  GatedJob job(ExecutionMode::kParallel, gated_work(), gate, 2, QueueFullPolicy::kDropOldest);
  job.submit(0);
  started.wait();
  for (int i = 1; i <= 5; ++i) job.submit(i);  // never blocks: 1, 2, 3 are dropped
  EXPECT_EQ(job.dropped(), 3u);
  gate.open->set_value();
  EXPECT_EQ(job.wait(), (std::vector<int>{0, 40, 50}));
  EXPECT_EQ(job.with_context([](Gate& g) { return g.ran; }), (std::vector<int>{0, 4, 5}));
}

TEST(BackgroundJob, WorkerExceptionIsRethrownAtTheNextWaitInBothModes) {
  for (auto mode : {ExecutionMode::kSequential, ExecutionMode::kParallel}) {
    BackgroundJob<int, int, int> job(mode, [](int&& x, int&) {
      if (x == 2) throw std::runtime_error("bad job 2");
      return x;
    });
    job.submit(1);
    EXPECT_NO_THROW(job.submit(2));  // the error surfaces at wait(), never at submit()
    job.submit(3);
    try {
      (void)job.wait();
      FAIL() << "wait() did not rethrow";
    } catch (const std::runtime_error& e) {
      EXPECT_STREQ(e.what(), "bad job 2");
    }
    EXPECT_TRUE(job.wait().empty());  // the error was reported once; later jobs still ran
    job.submit(4);
    EXPECT_EQ(job.wait(), std::vector<int>{4});
  }
}

TEST(BackgroundJob, TerminateWhileAJobRunsFinishesItAndDiscardsTheQueue) {
  Gate gate;
  auto started = gate.started->get_future();
  GatedJob job(ExecutionMode::kParallel, gated_work(), gate, 8);
  job.submit(0);
  started.wait();
  job.submit(1);
  job.submit(2);
  job.cancel();  // discards 1 and 2 at once, does not wait
  EXPECT_TRUE(job.is_running());
  EXPECT_THROW(job.submit(3), std::logic_error);
  std::thread stopper([&] { job.terminate(); });  // waits for job 0
  gate.open->set_value();
  stopper.join();
  EXPECT_FALSE(job.is_running());
  EXPECT_EQ(job.wait(), std::vector<int>{0});
  EXPECT_THROW(job.submit(3), std::logic_error);
  job.terminate();  // idempotent
}

// A stoppable job that runs until it is stopped: terminate() stops it within 100 ms, it leaves no
// output and no error, and the context holds what the jobs before it left there.
TEST(BackgroundJob, TerminateStopsAStoppableJobQuicklyLeavingTheContextAsBefore) {
  std::atomic<bool> started{false};
  BackgroundJob<int, std::vector<int>, int> job(
      ExecutionMode::kParallel,
      [&](int&& x, std::vector<int>& seen, const iwlomap::StopToken& stop) {
        if (x == 1) {  // the long one
          started = true;
          for (;;) {
            stop.throw_if_stopped();
            std::this_thread::yield();
          }
        }
        seen.push_back(x);
        return x;
      },
      std::vector<int>{}, 4);
  job.submit(0);
  EXPECT_EQ(job.wait(), std::vector<int>{0});
  job.submit(1);
  while (!started.load()) std::this_thread::yield();
  const auto t0 = std::chrono::steady_clock::now();
  job.terminate();
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  std::printf("terminate() returned after %.3f ms\n", ms);
  EXPECT_LE(ms, 100.0);
  EXPECT_TRUE(job.wait().empty());  // the stopped job has no output and no error
  EXPECT_EQ(job.with_context([](std::vector<int>& seen) { return seen; }), std::vector<int>{0});
}

TEST(BackgroundJob, DestructionWithQueuedJobsJoinsWithoutRunningThem) {
  auto counter = std::make_shared<std::atomic<int>>(0);
  std::thread opener;
  Gate gate;
  auto started = gate.started->get_future();
  {
    BackgroundJob<int, Gate, int> job(
        ExecutionMode::kParallel,
        [counter](int&& x, Gate& g) {
          if (x == 0) {
            g.started->set_value();
            g.open_future.wait();
          }
          return ++*counter;
        },
        gate, 16);
    job.submit(0);
    started.wait();
    for (int i = 1; i < 10; ++i) job.submit(i);
    EXPECT_EQ(job.queued(), 9u);
    // Opens the gate once the destructor has discarded the queue (job 0 holds the worker, so
    // nothing else can empty it).
    opener = std::thread([&job, &gate] {
      while (job.queued() != 0) std::this_thread::yield();
      gate.open->set_value();
    });
  }  // destructor: discards 1..9, lets job 0 finish, joins
  opener.join();
  EXPECT_EQ(counter->load(), 1);
}

// Sequential mode has no queue and no worker: terminate() and cancel() change nothing, and later
// jobs still run.
TEST(BackgroundJob, TerminateIsANoOpWhenSequential) {
  BackgroundJob<int, int, int> job(ExecutionMode::kSequential, [](int&& x, int&) { return x + 1; });
  job.submit(1);
  job.terminate();
  job.cancel();
  job.submit(2);
  EXPECT_EQ(job.wait(), (std::vector<int>{2, 3}));
}

// The worker blocks SIGINT and SIGTERM, so an interrupt goes to the program's own threads.
TEST(BackgroundJob, WorkerBlocksInterruptAndTerminateSignals) {
  BackgroundJob<int, int, bool> job(ExecutionMode::kParallel, [](int&&, int&) {
    sigset_t mask;
    pthread_sigmask(SIG_BLOCK, nullptr, &mask);
    return sigismember(&mask, SIGINT) == 1 && sigismember(&mask, SIGTERM) == 1;
  });
  job.submit(0);
  EXPECT_EQ(job.wait(), (std::vector<bool>{true}));
  sigset_t mine;
  pthread_sigmask(SIG_BLOCK, nullptr, &mine);
  EXPECT_EQ(sigismember(&mine, SIGINT), 0) << "the creating thread's mask must be left as it was";
}

// A job that waits for its own BackgroundJob would wait for itself: wait(), write_map() and
// with_context() throw std::logic_error instead, in both modes. Checked in a child process with an
// alarm, so that a deadlock fails the test instead of hanging the suite.
TEST(BackgroundJob, ThrowsInsteadOfDeadlockWhenAJobWaitsForItsOwnJob) {
  for (const ExecutionMode mode : {ExecutionMode::kSequential, ExecutionMode::kParallel}) {
    const pid_t child = ::fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      ::alarm(10);
      using Job = BackgroundJob<int, int, int>;
      Job* self = nullptr;
      int refused = 0;
      Job job(mode, [&](int&& which, int&) {
        try {
          if (which == 0) (void)self->wait();
          if (which == 1) self->write_map(which, [](int&, int) {});
          if (which == 2) self->with_context([](int&) { return 0; });
        } catch (const std::logic_error&) {
          ++refused;
        }
        return which;
      });
      self = &job;
      for (int which = 0; which < 3; ++which) job.submit(which);
      const std::vector<int> outputs = job.wait();
      ::_exit(refused == 3 && outputs == std::vector<int>{0, 1, 2} ? 0 : 1);
    }
    int status = 0;
    ASSERT_EQ(::waitpid(child, &status, 0), child);
    EXPECT_TRUE(WIFEXITED(status)) << (mode == ExecutionMode::kSequential ? "sequential" : "parallel")
                                   << ": the job deadlocked (killed by the alarm)";
    EXPECT_EQ(WEXITSTATUS(status), 0) << (mode == ExecutionMode::kSequential ? "sequential" : "parallel");
  }
}

TEST(BackgroundJob, RejectsBadConstructionArguments) {
  using Job = BackgroundJob<int, int, int>;
  EXPECT_THROW((Job(ExecutionMode::kParallel, Job::Work{})), std::invalid_argument);
  EXPECT_THROW((Job(ExecutionMode::kParallel, Job::StoppableWork{})), std::invalid_argument);
  EXPECT_THROW((BackgroundJob<int, int, int>(ExecutionMode::kParallel, [](int&& x, int&) { return x; }, 0, 0)),
               std::invalid_argument);
}

// ---- AsyncMapper ----

std::vector<iwlomap::SyntheticScan> three_scans() {
  std::vector<iwlomap::SyntheticScan> scans;
  for (int k = 0; k < 3; ++k) {
    iwlomap::SyntheticScanOptions o;
    o.rings = 16;
    o.columns = 256;
    o.sensor_xy = Eigen::Vector2d(2.0 * k, -1.0 * k);
    o.seed = static_cast<std::uint32_t>(k + 1);
    scans.push_back(iwlomap::make_synthetic_scan(o));
  }
  return scans;
}

TEST(AsyncMapper, BothModesBuildTheIdenticalMap) {
  const auto scans = three_scans();
  auto seq = std::make_shared<iwlomap::ProbabilityUpdater>(0.2);
  auto par = std::make_shared<iwlomap::ProbabilityUpdater>(0.2);
  iwlomap::AsyncMapper a(seq, ExecutionMode::kSequential);
  iwlomap::AsyncMapper b(par, ExecutionMode::kParallel, 2);
  for (const auto& s : scans) {
    a.integrate(s.origin, s.points, s.intensities, 20.0);
    b.integrate(s.origin, s.points, s.intensities, 20.0);
  }
  ASSERT_EQ(a.get_num_known_voxels(), b.get_num_known_voxels());
  ASSERT_GT(a.get_num_known_voxels(), 1000u);
  std::size_t compared = 0;
  a.map().for_each_voxel([&](const iwlomap::VoxelKey& k, const iwlomap::VoxelState& s) {
    const auto other = b.query(iwlomap::key_to_center(k, 0.2));
    ASSERT_TRUE(other.has_value());
    ASSERT_EQ(other->log_odds, s.log_odds);
    ASSERT_EQ(other->count, s.count);
    ++compared;
  });
  EXPECT_EQ(compared, a.get_num_known_voxels());
}

TEST(AsyncMapper, QueriesSeeEveryScanIntegratedBeforeThem) {
  auto map = std::make_shared<iwlomap::ProbabilityUpdater>(0.2);
  iwlomap::AsyncMapper m(map, ExecutionMode::kParallel);
  const auto scans = three_scans();
  m.integrate(scans[0].origin, scans[0].points, scans[0].intensities);
  const std::size_t after_one = m.get_num_known_voxels();
  iwlomap::ProbabilityUpdater direct(0.2);
  direct.insert_scan(scans[0].origin, scans[0].points, scans[0].intensities);
  EXPECT_EQ(after_one, direct.get_num_known_voxels());
}

TEST(AsyncMapper, ScanErrorsSurfaceAtTheNextSync) {
  auto map = std::make_shared<iwlomap::ProbabilityUpdater>(0.2);
  iwlomap::AsyncMapper m(map, ExecutionMode::kParallel);
  m.integrate(Eigen::Vector3d::Zero(), Eigen::MatrixXd::Zero(3, 3), Eigen::VectorXd::Zero(2));  // size mismatch
  Eigen::MatrixXd one(1, 3);
  one << 1.0, 0.0, 0.0;
  m.integrate(Eigen::Vector3d::Zero(), one, Eigen::VectorXd::Constant(1, 200.0));
  EXPECT_THROW(m.sync(), std::invalid_argument);
  EXPECT_EQ(m.get_num_known_voxels(), 6u);  // the scan after the bad one was integrated: 5 free + 1 hit
  EXPECT_THROW(iwlomap::AsyncMapper(nullptr, ExecutionMode::kSequential), std::invalid_argument);
}

}  // namespace
