// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// AsyncMapper: integrates scans into any backend without stalling the sensor loop.

#include "iwlomap/background_job.h"
#include "iwlomap/mapper_backend.h"

#include <cstddef>
#include <memory>

namespace iwlomap {

/// Queues scans for a backend and integrates them in submission order, in the caller's thread
/// (ExecutionMode::kSequential) or on a worker thread (kParallel). The map after the same scans is
/// identical in both modes.
///
/// Consistency: every query here (map(), get_occupied_voxels(), query(), get_num_nodes()) first
/// waits for all queued scans, so it always sees every scan integrated before it was called. The
/// backend must not be used directly while scans are queued; map() is the safe way to reach it.
/// An exception from a scan (e.g. a size mismatch) is rethrown by the next sync() or query; the
/// scans queued after it are still integrated.
class AsyncMapper {
 public:
  /// \param backend the map (not null; throws std::invalid_argument)
  /// \param mode integrate in the caller's thread (kSequential) or on a worker thread (kParallel)
  /// \param queue_capacity scans that may wait in parallel mode (>= 1)
  /// \param policy what integrate() does when the queue is full
  AsyncMapper(std::shared_ptr<IMapperBackend> backend, ExecutionMode mode, std::size_t queue_capacity = 4,
              QueueFullPolicy policy = QueueFullPolicy::kBlock);

  /// Queues one scan (copied): rays from \p origin (metres, map frame) to each of the N x 3
  /// \p points, as IMapperBackend::insert_scan(). Returns at once in parallel mode unless the queue
  /// is full under QueueFullPolicy::kBlock.
  void integrate(const Eigen::Vector3d& origin, Eigen::MatrixXd points, Eigen::VectorXd intensities,
                 double max_range = -1.0);
  /// The same for a scan without intensities: every point is a return at the map's intensity_max
  /// as the scan is integrated (as a cloud without an intensity field maps in the tool).
  void integrate(const Eigen::Vector3d& origin, Eigen::MatrixXd points, double max_range = -1.0);

  /// Waits until every queued scan is integrated; rethrows the first error since the last sync().
  void sync();

  /// The backend, after sync().
  [[nodiscard]] IMapperBackend& map();
  [[nodiscard]] Eigen::MatrixXd get_occupied_voxels(double min_probability = 0.5);
  [[nodiscard]] std::optional<VoxelState> query(const Eigen::Vector3d& point);
  /// The map's get_num_nodes(), after the queue drains.
  [[nodiscard]] std::size_t get_num_nodes();
  /// The map's get_num_known_voxels(), after the queue drains.
  [[nodiscard]] std::size_t get_num_known_voxels();

  /// True while a scan is queued or being integrated.
  [[nodiscard]] bool is_running() const { return job_.is_running(); }
  /// Scans discarded by QueueFullPolicy::kDropOldest.
  [[nodiscard]] std::size_t dropped() const { return job_.dropped(); }
  /// Discards queued scans, finishes the running one and stops the worker; later integrate() throws.
  void terminate() { job_.terminate(); }

 private:
  struct Scan {
    Eigen::Vector3d origin;
    Eigen::MatrixXd points;
    Eigen::VectorXd intensities;
    double max_range;
    bool all_returns = false;  // no intensities: each point at the map's intensity_max
  };
  struct Done {};

  std::shared_ptr<IMapperBackend> backend_;
  BackgroundJob<Scan, std::shared_ptr<IMapperBackend>, Done> job_;
};

}  // namespace iwlomap
