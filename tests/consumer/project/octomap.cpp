// SPDX-License-Identifier: BSD-3-Clause
// make_backend("OctoMap") with nothing of the OctoMap layer included: linking it registers it.
#include <iwlomap/mapper_backend.h>

#include <iostream>

int main() {
  const auto map = iwlomap::make_backend("OctoMap", 0.1);
  Eigen::MatrixXd points(1, 3);
  points << 1.0, 0.5, 0.25;
  map->insert_scan(Eigen::Vector3d::Zero(), points, Eigen::VectorXd::Constant(1, 200.0));
  std::cout << "consumer: " << map->get_backend_type() << ", " << map->get_num_nodes() << " known voxels\n";
  return map->get_backend_type() == "OctoMap" && map->get_num_nodes() > 5 ? 0 : 1;
}
