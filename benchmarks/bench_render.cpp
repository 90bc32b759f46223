// SPDX-License-Identifier: BSD-3-Clause
//
// bench_render: wall time of SnapshotRenderer for maps of 100k and 1M voxels at 1280 x 960, the
// way a pipeline without a screen runs it (under Xvfb, Mesa's software rasteriser).
//
// The map is a synthetic terrain: a square grid of 0.1 m voxels whose heights follow smooth hills
// (one voxel per column, plus a second one below it on steep slopes so the surface has no holes),
// probabilities varying over (0.5, 1]. Each figure is the median of --reps timed calls after one
// untimed warm-up call; a call is everything SnapshotRenderer::render() does: open the display,
// build the scene, render off screen and read the pixels back. write_png() is timed separately.
//
// Usage: xvfb-run -a -s "-screen 0 1280x1024x24 -noreset" bench_render [--reps N] [--quick] [--png DIR]

#include "iwlomap/viewer/snapshot_renderer.h"

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <string>
#include <vector>

namespace {

using iwlomap::viewer::RgbImage;
using iwlomap::viewer::SnapshotOptions;
using iwlomap::viewer::SnapshotRenderer;

constexpr double kResolution = 0.1;
constexpr double kTargetSeconds = 5.0;  // issue 5: 1M voxels in under 5 s on the 2-core machine

/// About \p target voxels of hilly terrain (x, y, z, p), deterministic.
Eigen::MatrixXd make_terrain(std::size_t target) {
  // Enough columns for the target; the last row stays partly empty.
  const auto side = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(target))));
  const auto height = [](double x, double y) {
    return 2.0 * std::sin(x * 0.11) * std::cos(y * 0.07) + 0.8 * std::sin(x * 0.031 + y * 0.047);
  };
  std::vector<double> v;
  v.reserve(target * 4 + 1024);
  for (int i = 0; i < side && v.size() / 4 < target; ++i)
    for (int j = 0; j < side && v.size() / 4 < target; ++j) {
      const double x = (i + 0.5) * kResolution, y = (j + 0.5) * kResolution;
      const double z = std::floor(height(x, y) / kResolution) * kResolution + kResolution / 2;
      const double p = 0.5 + 0.5 * (0.5 + 0.5 * std::sin(x * 0.5 + y * 0.3));
      v.insert(v.end(), {x, y, z, std::max(p, 0.501)});
      // Steep slope: fill the step to the neighbour below so the surface stays closed.
      const double below = std::floor(height(x + kResolution, y) / kResolution) * kResolution + kResolution / 2;
      if (z - below > 1.5 * kResolution && v.size() / 4 < target) v.insert(v.end(), {x, y, z - kResolution, p});
    }
  Eigen::MatrixXd m(static_cast<Eigen::Index>(v.size() / 4), 4);
  for (Eigen::Index r = 0; r < m.rows(); ++r)
    for (int c = 0; c < 4; ++c) m(r, c) = v[static_cast<std::size_t>(r) * 4 + static_cast<std::size_t>(c)];
  return m;
}

double median_seconds(int reps, const std::function<void()>& f) {
  f();  // warm-up: first-call costs (shader compilation, font cache) are not what we measure
  std::vector<double> t;
  for (int r = 0; r < reps; ++r) {
    const auto start = std::chrono::steady_clock::now();
    f();
    t.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  int reps = 3;
  std::string png_dir;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--reps") == 0 && i + 1 < argc) {
      reps = std::max(1, std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--quick") == 0) {
      reps = 1;
    } else if (std::strcmp(argv[i], "--png") == 0 && i + 1 < argc) {
      png_dir = argv[++i];
    } else {
      std::printf("usage: %s [--reps N] [--quick] [--png DIR]\n"
                  "  --reps N   timed repetitions per figure (default 3; the median is reported)\n"
                  "  --quick    1 repetition\n"
                  "  --png DIR  also write the rendered images to DIR (to look at them)\n"
                  "Run under xvfb-run -a -s \"-screen 0 1280x1024x24 -noreset\" on a machine without a screen.\n",
                  argv[0]);
      return std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0 ? 0 : 2;
    }
  }
  try {
    SnapshotRenderer::check_display();
  } catch (const iwlomap::viewer::DisplayError& e) {
    std::fprintf(stderr, "bench_render: %s\n", e.what());
    return 1;
  }

  std::printf("bench_render: SnapshotRenderer::render at 1280 x 960, iso camera, height colours, lighting on,\n"
              "colour bar and title; median of %d after a warm-up\n\n",
              reps);
  std::printf("| voxels | cubes (s) | points (s) | write_png (s) | 1M target |\n");
  std::printf("|---:|---:|---:|---:|---|\n");
  bool met = true;
  for (const std::size_t n : {std::size_t{100000}, std::size_t{1000000}}) {
    const Eigen::MatrixXd voxels = make_terrain(n);
    SnapshotOptions o;
    o.width = 1280;
    o.height = 960;
    o.title = "bench_render: " + std::to_string(voxels.rows()) + " voxels";
    RgbImage image;
    const double cubes = median_seconds(reps, [&] { image = SnapshotRenderer::render(voxels, kResolution, o); });
    const std::string stem = png_dir.empty() ? std::string() : png_dir + "/bench_render_" + std::to_string(n);
    const std::string png = png_dir.empty() ? std::string("/tmp/bench_render_scratch.png") : stem + "_cubes.png";
    const double write = median_seconds(reps, [&] { iwlomap::viewer::write_png(image, png); });
    if (png_dir.empty()) std::remove(png.c_str());
    o.shape = iwlomap::viewer::VoxelShape::kPoints;
    o.point_size = 2.0;
    const double points = median_seconds(reps, [&] { image = SnapshotRenderer::render(voxels, kResolution, o); });
    if (!png_dir.empty()) iwlomap::viewer::write_png(image, stem + "_points.png");
    const bool is_1m = n == 1000000;
    if (is_1m) met = cubes < kTargetSeconds;
    std::printf("| %ld | %.2f | %.2f | %.2f | %s |\n", static_cast<long>(voxels.rows()), cubes, points, write,
                is_1m ? (cubes < kTargetSeconds ? "met (< 5 s)" : "MISSED (>= 5 s)") : "");
  }
  std::printf("\n1M voxels as cubes in under %.0f s: %s\n", kTargetSeconds, met ? "yes" : "no");
  return 0;
}
