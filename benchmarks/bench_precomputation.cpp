// SPDX-License-Identifier: BSD-3-Clause
//
// bench_precomputation: building Cartographer-style precomputation grids (iwlomap::
// PrecomputationGrid2D/3D, a separable sliding-window maximum) against the brute-force
// construction (every cell of the grown grid takes the maximum of its whole w^d window), for
// levels 0..6 (widths 1..64) of a 2000 x 2000 grid and of a 256^3 grid.
//
// The separable build is timed in full (median of --reps runs). Brute force at the wide levels
// would take hours in 3D (256^3 grid, w = 64: 3.3e7 cells x 2.6e5 window cells), so it is timed
// on a lattice of cells (every s-th index along each axis, s halved from a coarse start until the
// sample takes --budget seconds or covers every cell) and extrapolated by cell count; the table
// says which. Every brute-force cell is also compared with the separable grid, so the program
// checks what it times. Two base contents (fixed seeds): uniform random bytes, the worst case for
// the deque (its pops are unpredictable branches), and a map-like grid, 5% of the cells occupied
// (255) and the rest free or unknown (0). Times are thread CPU time (the machine is shared: wall
// time there measures the neighbours), medians of --reps runs; wall time is printed beside.
//
// Usage: bench_precomputation [--reps N] [--budget SECONDS] [--quick]

#include "iwlomap/precomputation_grid.h"
#include "iwlomap/precomputation_stack.h"

#include "bench_util.h"

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <random>
#include <string>
#include <vector>

namespace {

using iwlomap::bench::median;

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

double thread_cpu_seconds() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_nsec) * 1e-9;
}

enum class Content { kRandom, kMapLike };

template <int D>
iwlomap::DiscreteGrid<D> make_grid(const Eigen::Matrix<int, D, 1>& size, Content content, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> byte(0, 255), percent(0, 99);
  std::vector<std::uint8_t> v(static_cast<std::size_t>(size.prod()));
  for (auto& x : v)
    x = static_cast<std::uint8_t>(content == Content::kRandom ? byte(rng) : (percent(rng) < 5 ? 255 : 0));
  return iwlomap::DiscreteGrid<D>(size, std::move(v));
}

// Brute force for one cell s of the grown grid: max over base cells s - w + 1 .. s per axis.
template <int D>
std::uint8_t brute_cell(const iwlomap::DiscreteGrid<D>& g, int w, const Eigen::Matrix<int, D, 1>& s) {
  Eigen::Matrix<int, D, 1> lo, hi;
  for (int a = 0; a < D; ++a) {
    lo[a] = std::max(0, s[a] - w + 1);
    hi[a] = std::min(g.size()[a] - 1, s[a]);
  }
  const std::uint8_t* v = g.values().data();
  const auto nx = static_cast<std::size_t>(g.size().x());
  std::uint8_t m = 0;
  const int z_lo = D == 3 ? lo[D - 1] : 0, z_hi = D == 3 ? hi[D - 1] : 0;
  const auto ny = static_cast<std::size_t>(g.size().y());
  for (int k = z_lo; k <= z_hi; ++k)
    for (int j = lo.y(); j <= hi.y(); ++j) {
      const std::uint8_t* row = v + nx * (static_cast<std::size_t>(j) + ny * static_cast<std::size_t>(k));
      for (int i = lo.x(); i <= hi.x(); ++i) m = std::max(m, row[i]);
    }
  return m;
}

struct BruteTiming {
  double seconds = 0.0;  // extrapolated to the whole grid when sampled
  double fraction = 1.0;  // share of the cells actually computed
  long mismatches = 0;
};

// Brute force over the lattice of cells whose indices are multiples of `stride`.
template <int D>
BruteTiming brute_force(const iwlomap::DiscreteGrid<D>& base, const iwlomap::PrecomputationGrid<D>& fast,
                        double budget) {
  const Eigen::Matrix<int, D, 1> n = fast.size();
  const double total_cells = n.template cast<double>().prod();
  int stride = 1;
  while (stride < n.maxCoeff()) stride *= 2;
  for (;; stride /= 2) {
    long mismatches = 0, cells = 0;
    const double t = thread_cpu_seconds();
    Eigen::Matrix<int, D, 1> s;
    if constexpr (D == 2) {
      for (s.y() = 0; s.y() < n.y(); s.y() += stride)
        for (s.x() = 0; s.x() < n.x(); s.x() += stride, ++cells) mismatches += brute_cell<D>(base, fast.width(), s) != fast.value(s);
    } else {
      for (s.z() = 0; s.z() < n.z(); s.z() += stride)
        for (s.y() = 0; s.y() < n.y(); s.y() += stride)
          for (s.x() = 0; s.x() < n.x(); s.x() += stride, ++cells)
            mismatches += brute_cell<D>(base, fast.width(), s) != fast.value(s);
    }
    const double elapsed = thread_cpu_seconds() - t;
    if (elapsed >= budget || stride == 1) {
      BruteTiming r;
      r.fraction = static_cast<double>(cells) / total_cells;
      r.seconds = elapsed / r.fraction;
      r.mismatches = mismatches;
      return r;
    }
  }
}

template <int D>
bool run(const char* name, const Eigen::Matrix<int, D, 1>& size, Content content, int reps, double budget) {
  const iwlomap::DiscreteGrid<D> base = make_grid<D>(size, content, 2024);
  std::printf("\n%s base grid, %s\n\n", name,
              content == Content::kRandom ? "uniform random bytes" : "map-like: 5% occupied (255), the rest 0");
  std::printf("| level | width | cells (grown) | separable CPU (ms) | ns / cell | wall (ms) | brute force CPU (ms) | "
              "brute / separable | brute force measured on |\n");
  std::printf("|---:|---:|---:|---:|---:|---:|---:|---:|---|\n");
  bool ok = true;
  double stack_total = 0.0;
  for (int k = 0; k <= 6; ++k) {
    const int w = 1 << k;
    std::vector<double> cpu, wall;
    for (int r = 0; r < reps; ++r) {
      const auto start = Clock::now();
      const double c0 = thread_cpu_seconds();
      const iwlomap::PrecomputationGrid<D> grid(base, w);
      cpu.push_back(thread_cpu_seconds() - c0);
      wall.push_back(seconds_since(start));
      if (grid.values().empty()) std::abort();  // keeps the build from being optimised away
    }
    const double fast = median(cpu);
    stack_total += fast;
    const iwlomap::PrecomputationGrid<D> grid(base, w);
    const BruteTiming brute = brute_force<D>(base, grid, budget);
    ok = ok && brute.mismatches == 0;
    const double cells = grid.size().template cast<double>().prod();
    char where[64];
    if (brute.fraction >= 1.0)
      std::snprintf(where, sizeof where, "all cells");
    else
      std::snprintf(where, sizeof where, "%.2g%% of cells, extrapolated", brute.fraction * 100.0);
    std::printf("| %d | %d | %.3g | %.1f | %.2f | %.1f | %.4g | %.3gx | %s%s |\n", k, w, cells, fast * 1e3,
                fast * 1e9 / cells, median(wall) * 1e3, brute.seconds * 1e3, brute.seconds / fast, where,
                brute.mismatches == 0 ? "" : " (MISMATCH)");
    std::fflush(stdout);
  }
  std::vector<double> cpu;
  for (int r = 0; r < reps; ++r) {
    const double c0 = thread_cpu_seconds();
    const iwlomap::PrecomputationStack<D> stack(base, 7);
    cpu.push_back(thread_cpu_seconds() - c0);
    if (stack.num_levels() != 7) std::abort();
  }
  std::printf("\nPrecomputationStack, levels 0..6 in one call: %.1f ms CPU (sum of the levels above: %.1f ms)\n",
              median(cpu) * 1e3, stack_total * 1e3);
  return ok;
}

}  // namespace

int main(int argc, char** argv) {
  int reps = 3;
  double budget = 0.5;
  bool quick = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--reps" && i + 1 < argc) {
      reps = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--budget" && i + 1 < argc) {
      budget = std::atof(argv[++i]);
    } else if (a == "--quick") {
      quick = true;
    } else {
      std::fprintf(stderr, "usage: bench_precomputation [--reps N] [--budget SECONDS] [--quick]\n");
      return 2;
    }
  }
  std::printf("bench_precomputation: separable sliding-window maximum vs brute force; median of %d runs; "
              "brute-force budget %.2f s per level\n",
              reps, budget);
  const Eigen::Vector2i size2 = quick ? Eigen::Vector2i(500, 500) : Eigen::Vector2i(2000, 2000);
  const Eigen::Vector3i size3 = quick ? Eigen::Vector3i(64, 64, 64) : Eigen::Vector3i(256, 256, 256);
  const char* name2 = quick ? "500 x 500" : "2000 x 2000";
  const char* name3 = quick ? "64^3" : "256^3";
  bool ok2 = true, ok3 = true;
  for (const Content c : {Content::kRandom, Content::kMapLike}) ok2 = run<2>(name2, size2, c, reps, budget) && ok2;
  for (const Content c : {Content::kRandom, Content::kMapLike}) ok3 = run<3>(name3, size3, c, reps, budget) && ok3;
  if (!ok2 || !ok3) {
    std::fprintf(stderr, "bench_precomputation: brute force and separable grids differ\n");
    return 1;
  }
  return 0;
}
