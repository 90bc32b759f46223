// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/async_mapper.h"

#include <stdexcept>
#include <utility>

namespace iwlomap {

namespace {
std::shared_ptr<IMapperBackend> require(std::shared_ptr<IMapperBackend> backend) {
  if (!backend) throw std::invalid_argument("AsyncMapper: the backend is null");
  return backend;
}
}  // namespace

AsyncMapper::AsyncMapper(std::shared_ptr<IMapperBackend> backend, ExecutionMode mode, std::size_t queue_capacity,
                         QueueFullPolicy policy)
    : backend_(require(std::move(backend))),
      job_(
          mode,
          [](Scan&& s, std::shared_ptr<IMapperBackend>& map, const StopToken& stop) {
            stop.throw_if_stopped();  // terminate(): a scan not yet begun stays out of the map
            if (s.all_returns) s.intensities = Eigen::VectorXd::Constant(s.points.rows(), map->get_params().intensity_max);
            map->insert_scan(s.origin, s.points, s.intensities, s.max_range);
            return Done{};
          },
          backend_, queue_capacity, policy) {}

void AsyncMapper::integrate(const Eigen::Vector3d& origin, Eigen::MatrixXd points, Eigen::VectorXd intensities,
                            double max_range) {
  job_.submit(Scan{origin, std::move(points), std::move(intensities), max_range});
}

void AsyncMapper::integrate(const Eigen::Vector3d& origin, Eigen::MatrixXd points, double max_range) {
  job_.submit(Scan{origin, std::move(points), Eigen::VectorXd(), max_range, true});
}

void AsyncMapper::sync() { (void)job_.wait(); }

IMapperBackend& AsyncMapper::map() {
  sync();
  return *backend_;
}

Eigen::MatrixXd AsyncMapper::get_occupied_voxels(double min_probability) {
  return map().get_occupied_voxels(min_probability);
}

std::optional<VoxelState> AsyncMapper::query(const Eigen::Vector3d& point) { return map().query(point); }

std::size_t AsyncMapper::get_num_nodes() { return map().get_num_nodes(); }
std::size_t AsyncMapper::get_num_known_voxels() { return map().get_num_known_voxels(); }

}  // namespace iwlomap
