// SPDX-License-Identifier: BSD-3-Clause
// The MPI layer from a downstream project, run as a one-rank job (no mpirun needed).
#include <iwlomap/mpi/distributed_mapper.h>

#include <iostream>

int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  int rc = 1;
  {
    iwlomap::mpi::DistributedMapper map(MPI_COMM_WORLD, 0.1);
    Eigen::MatrixXd points(2, 3);
    points << 1.0, 0.0, 0.0, 0.0, 2.0, 0.0;
    const Eigen::VectorXd intensities = Eigen::VectorXd::Constant(2, 200.0);
    map.insert_scan(Eigen::Vector3d::Zero(), points, intensities);
    auto one = iwlomap::make_backend("RAM", 0.1);
    one->insert_scan(Eigen::Vector3d::Zero(), points, intensities);
    const std::size_t known = map.num_nodes();
    std::cout << "consumer: " << map.ranks() << " rank(s), " << known << " known voxels (one process: "
              << one->get_num_nodes() << ")\n";
    rc = known > 0 && known == one->get_num_nodes() ? 0 : 1;
  }
  MPI_Finalize();
  return rc;
}
