// SPDX-License-Identifier: BSD-3-Clause
// A distributed mapping job in which one rank dies (SIGKILL) in its second round, while the others
// wait for its observations: run by Mpi.DeadRankEndsTheJob, which checks that mpirun ends the
// job (no hang) and names the rank.
//
// usage: mpirun -np N mpi_fault_probe DYING_RANK

#include <iwlomap/mpi/distributed_mapper.h>
#include <iwlomap/synthetic_scan.h>

#include <csignal>
#include <cstdio>
#include <cstdlib>

int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  const int dying = argc > 1 ? std::atoi(argv[1]) : 1;
  iwlomap::IwloParams p;
  p.intensity_threshold = 5.0;
  iwlomap::mpi::DistributedMapper map(MPI_COMM_WORLD, 0.2, p);
  iwlomap::SyntheticScanOptions o;
  o.rings = 16;
  o.columns = 256;
  const iwlomap::SyntheticScan scan = iwlomap::make_synthetic_scan(o);
  for (int round = 0; round < 4; ++round) {
    if (round == 1 && map.rank() == dying) std::raise(SIGKILL);
    map.insert_scan(scan.origin, scan.points, scan.intensities);
  }
  std::printf("rank %d: all rounds done, %zu voxels\n", map.rank(), map.num_nodes());
  MPI_Finalize();
  return 0;
}
