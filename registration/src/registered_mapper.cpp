// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/registration/registered_mapper.h"

#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

namespace iwlomap::registration {

namespace {

std::shared_ptr<IMapperBackend> checked(std::shared_ptr<IMapperBackend> map, const RegisteredMapperOptions& o) {
  if (!map) throw std::invalid_argument("iwlomap: RegisteredMapper: the map is null");
  o.matcher.validate();
  if (std::isnan(o.max_range)) throw std::invalid_argument("iwlomap: RegisteredMapper: max_range is NaN");
  return map;
}

}  // namespace

RegisteredMapper::RegisteredMapper(std::shared_ptr<IMapperBackend> map, ExecutionMode mode,
                                   RegisteredMapperOptions options, std::size_t queue_capacity)
    : job_(mode, &RegisteredMapper::process, State{checked(std::move(map), options), options}, queue_capacity) {}

RegisteredScan RegisteredMapper::process(Scan&& scan, State& state, const StopToken& stop) {
  RegisteredScan out;
  out.given_pose = scan.pose;
  out.initial_guess = state.correction * scan.pose;
  out.integrated_pose = out.initial_guess;
  Eigen::Isometry3d correction = state.correction;
  if (state.map->get_num_known_voxels() > 0) {
    stop.throw_if_stopped();
    out.match = ScanMatcher(*state.map, state.options.matcher).match(scan.points, out.initial_guess);
    if (out.match.converged) {
      out.registered = true;
      out.integrated_pose = out.match.pose;
      correction = out.match.pose * scan.pose.inverse();
    }
  }
  // terminate() during the registration: neither the map nor the correction changes.
  stop.throw_if_stopped();
  state.correction = correction;
  // The scan in the map frame, rays from the corrected sensor position.
  const Eigen::MatrixXd world = (scan.points * out.integrated_pose.linear().transpose()).rowwise() +
                                out.integrated_pose.translation().transpose();
  if (scan.all_returns)
    scan.intensities = Eigen::VectorXd::Constant(scan.points.rows(), state.map->get_params().intensity_max);
  state.map->insert_scan(out.integrated_pose.translation(), world, scan.intensities, state.options.max_range);
  return out;
}

void RegisteredMapper::integrate(const Eigen::Isometry3d& pose, Eigen::MatrixXd points_sensor) {
  submit(pose, std::move(points_sensor), Eigen::VectorXd(), true);
}

void RegisteredMapper::integrate(const Eigen::Isometry3d& pose, Eigen::MatrixXd points_sensor,
                                 Eigen::VectorXd intensities) {
  submit(pose, std::move(points_sensor), std::move(intensities), false);
}

void RegisteredMapper::submit(const Eigen::Isometry3d& pose, Eigen::MatrixXd points_sensor, Eigen::VectorXd intensities,
                              bool all_returns) {
  if (!pose.matrix().allFinite()) throw std::invalid_argument("iwlomap: RegisteredMapper: the pose is not finite");
  if (points_sensor.cols() != 3 && points_sensor.rows() > 0)
    throw std::invalid_argument("iwlomap: RegisteredMapper: the scan has " + std::to_string(points_sensor.cols()) +
                                " columns, expected 3");
  if (!all_returns && intensities.size() != points_sensor.rows())
    throw std::invalid_argument("iwlomap: RegisteredMapper: " + std::to_string(intensities.size()) +
                                " intensities for " + std::to_string(points_sensor.rows()) + " points");
  job_.submit(Scan{pose, std::move(points_sensor), std::move(intensities), all_returns});
}

std::vector<RegisteredScan> RegisteredMapper::sync() { return job_.wait(); }

Eigen::Isometry3d RegisteredMapper::correction() {
  return job_.with_context([](State& s) { return s.correction; });
}

IMapperBackend& RegisteredMapper::map() {
  return *job_.with_context([](State& s) { return s.map; });
}

}  // namespace iwlomap::registration
