// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/registration/registered_sonar_mapper.h"

#include <iwlomap/probability_updater.h>

#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

namespace iwlomap::registration {

namespace {

std::shared_ptr<IMapperBackend> checked(std::shared_ptr<IMapperBackend> map, const SonarImageProjector& projector,
                                        const RegisteredSonarMapperOptions& o) {
  if (!map) throw std::invalid_argument("iwlomap: RegisteredSonarMapper: the map is null");
  if (map->get_resolution() != projector.resolution())
    throw std::invalid_argument("iwlomap: RegisteredSonarMapper: the projector's resolution " +
                                std::to_string(projector.resolution()) + " differs from the map's " +
                                std::to_string(map->get_resolution()));
  o.matcher.validate();
  if (o.pings_per_submap < 1)
    throw std::invalid_argument("iwlomap: RegisteredSonarMapper: pings_per_submap must be >= 1, got " +
                                std::to_string(o.pings_per_submap));
  if (std::isnan(o.max_fitness_rmse))
    throw std::invalid_argument("iwlomap: RegisteredSonarMapper: max_fitness_rmse is NaN");
  if (o.min_submap_voxels < 8)
    throw std::invalid_argument("iwlomap: RegisteredSonarMapper: min_submap_voxels must be >= 8, got " +
                                std::to_string(o.min_submap_voxels));
  return map;
}

}  // namespace

RegisteredSonarMapperOptions::RegisteredSonarMapperOptions() {
  matcher.coarse = false;
  matcher.icp.planar = true;
  // The match-quality model's thresholds were set on lidar scenes; sonar submaps keep its own
  // residual test (max_fitness_rmse) until the model is calibrated on sonar surveys.
  matcher.quality.min_inlier_fraction = 0.0;
  matcher.quality.min_axis_support = 0.0;
  matcher.quality.max_free_conflict = 1.0;
  matcher.quality.hold_unconstrained = false;
}

RegisteredSonarMapper::RegisteredSonarMapper(std::shared_ptr<IMapperBackend> map, SonarImageProjector projector,
                                             ExecutionMode mode, RegisteredSonarMapperOptions options,
                                             std::size_t queue_capacity)
    : pings_per_submap_(options.pings_per_submap),
      job_(mode, &RegisteredSonarMapper::process,
           State{checked(std::move(map), projector, options), std::move(projector), options}, queue_capacity) {}

void RegisteredSonarMapper::integrate(const Eigen::Isometry3d& nav_pose, const SonarImageView& image,
                                      const SonarGeometry& geometry) {
  if (!nav_pose.matrix().allFinite())
    throw std::invalid_argument("iwlomap: RegisteredSonarMapper: the navigation pose is not finite");
  if (image.data == nullptr || image.range_bins < 1 || image.beams < 1)
    throw std::invalid_argument("iwlomap: RegisteredSonarMapper: the sonar image is empty");
  geometry.validate(image.beams);
  Ping ping{nav_pose, geometry, SonarImageCopy(image)};
  if (pending_.pings.empty()) pending_.first_ping = pings_seen_;
  pending_.pings.push_back(std::move(ping));
  ++pings_seen_;
  if (static_cast<int>(pending_.pings.size()) >= pings_per_submap_) submit_pending();
}

void RegisteredSonarMapper::submit_pending() {
  if (pending_.pings.empty()) return;
  Submap submap = std::move(pending_);
  pending_ = Submap{};
  job_.submit(std::move(submap));
}

std::vector<RegisteredSubmap> RegisteredSonarMapper::sync() {
  submit_pending();
  return job_.wait();
}

Eigen::Isometry3d RegisteredSonarMapper::correction() {
  return job_.with_context([](State& s) { return s.correction; });
}

IMapperBackend& RegisteredSonarMapper::map() {
  return *job_.with_context([](State& s) { return s.map; });
}

RegisteredSubmap RegisteredSonarMapper::process(Submap&& submap, State& state) {
  RegisteredSubmap out;
  out.first_ping = submap.first_ping;
  out.pings = submap.pings.size();
  const Eigen::Isometry3d anchor = submap.pings.front().nav_pose;
  out.given_pose = anchor;
  out.initial_guess = state.correction * anchor;
  out.correction = state.correction;

  if (state.map->get_num_known_voxels() > 0) {
    // The submap in the frame of its first ping, with the map's update rule.
    ProbabilityUpdater local(state.map->get_resolution());
    const IwloParams params = state.map->get_params();
    local.set_params(params);
    const Eigen::Isometry3d to_anchor = anchor.inverse();
    for (const Ping& ping : submap.pings) {
      const SonarObservations obs = state.projector.project(ping.image.view(), ping.geometry, to_anchor * ping.nav_pose);
      local.batch_update_iwlo(obs.points, obs.intensities, obs.is_occupied, obs.weights);
    }
    const Eigen::MatrixXd points = local.get_occupied_voxels(params.occupied_threshold).leftCols(3);
    out.occupied_voxels = static_cast<std::size_t>(points.rows());
    if (points.rows() >= state.options.min_submap_voxels) {
      out.match = ScanMatcher(*state.map, state.options.matcher).match(points, out.initial_guess);
      const double limit = state.options.max_fitness_rmse < 0.0 ? 1.2 * state.map->get_resolution()
                                                                 : state.options.max_fitness_rmse;
      if (out.match.converged && limit > 0.0 && out.match.fitness_rmse > limit) {
        out.match.converged = false;
        out.match.pose = out.initial_guess;
        out.match.reason = "the residual " + std::to_string(out.match.fitness_rmse) + " m exceeds max_fitness_rmse " +
                           std::to_string(limit) + " m";
      }
      if (out.match.converged) {
        out.registered = true;
        state.correction = out.match.pose * anchor.inverse();
        out.correction = state.correction;
      }
    }
  }
  for (const Ping& ping : submap.pings) {
    const Eigen::Isometry3d pose = out.correction * ping.nav_pose;
    const SonarObservations obs = state.projector.integrate(*state.map, ping.image.view(), ping.geometry, pose);
    out.observations += obs.size();
    out.beams_with_return += obs.beams_with_return;
    out.beams_without_return += obs.beams_without_return;
    out.integrated_poses.push_back(pose);
  }
  return out;
}

}  // namespace iwlomap::registration
