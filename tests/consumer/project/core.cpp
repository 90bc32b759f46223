// SPDX-License-Identifier: BSD-3-Clause
// The README's library example: a map from points, the occupied voxels back as a matrix the
// program owns (built with -march=native too: the matrix crosses the library boundary).
#include <iwlomap/probability_updater.h>
#include <iwlomap/version.h>

#include <iostream>
#include <string>

int main() {
  if (std::string(iwlomap::version()) != IWLOMAP_VERSION_STRING) return 1;
  iwlomap::ProbabilityUpdater map(0.05);
  Eigen::MatrixXd points(3, 3);
  points << 1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 1.5;
  const Eigen::VectorXd intensities = Eigen::VectorXd::Constant(3, 200.0);
  map.insert_scan(Eigen::Vector3d::Zero(), points, intensities, 30.0);
  map.batch_update_iwlo(points, intensities, std::vector<bool>(3, true));
  for (int i = 0; i < 3; ++i) {
    const Eigen::MatrixXd occupied = map.get_occupied_voxels(0.7);  // freed here, allocated there
    if (occupied.rows() != 3) return 1;
  }
  const std::optional<iwlomap::VoxelState> v = map.query({1.0, 0.0, 0.0});
  std::cout << "consumer: " << map.get_num_nodes() << " known voxels, p = " << (v ? v->probability : 0.0) << "\n";
  return v && v->probability > 0.7 ? 0 : 1;
}
