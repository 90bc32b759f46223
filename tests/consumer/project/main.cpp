// SPDX-License-Identifier: BSD-3-Clause
// Maps one small scan through the public API and checks a result, so that a broken package
// (missing header, missing library, wrong include path) fails to build or to run.
#include <iwlomap/mapper_backend.h>
#include <iwlomap/probability_updater.h>

#include <iostream>

int main() {
  auto map = iwlomap::make_backend("RAM", 0.1);
  Eigen::MatrixXd points(2, 3);
  points << 1.0, 0.0, 0.0, 0.0, 2.0, 0.0;
  Eigen::VectorXd intensities(2);
  intensities << 200.0, 200.0;
  map->insert_scan(Eigen::Vector3d::Zero(), points, intensities);
  const Eigen::MatrixXd occupied = map->get_occupied_voxels(0.5);
  std::cout << "consumer: " << map->get_num_nodes() << " known voxels, " << occupied.rows() << " occupied\n";
  return occupied.rows() == 2 ? 0 : 1;
}
