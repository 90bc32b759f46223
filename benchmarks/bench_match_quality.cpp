// SPDX-License-Identifier: BSD-3-Clause
// Registration that never lies: ScanMatcher from seeded initial errors up to twice its search
// window (and from the identity pose) on the synthetic courtyard, the pillar scene and the
// recorded Ouster frames. Each trial is run with the match-quality model (the defaults) and
// without it (every quality test off, unconstrained directions refused as before), and counted as
// right (converged within 10 cm and 1 degree of the truth), wrong (converged farther off: a lie)
// or refused. --dump prints every trial's quality statistics (for calibrating the thresholds).
//
// usage: bench_match_quality [--trials N] [--seed S] [--data DIR] [--dump]

#include "bench_pcd.h"

#include <iwlomap/probability_updater.h>
#include <iwlomap/registration/scan_matcher.h>
#include <iwlomap/sensor_preset.h>
#include <iwlomap/synthetic_scan.h>
#include <iwlomap/synthetic_world.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>

namespace {

using namespace iwlomap;
constexpr double kDeg = 3.14159265358979323846 / 180.0;

struct Scene {
  std::string name;
  std::shared_ptr<ProbabilityUpdater> map;
  std::vector<Eigen::MatrixXd> scans;  // sensor frame
  std::vector<Eigen::Isometry3d> truths;
};

std::shared_ptr<ProbabilityUpdater> map_of(const Eigen::Vector3d& origin, const Eigen::MatrixXd& world,
                                           const Eigen::VectorXd& intensity) {
  auto m = std::make_shared<ProbabilityUpdater>(0.2);
  m->set_params(sensor_preset_params(SensorPreset::kLidar));
  m->set_hit_accumulation(true);
  m->insert_scan(origin, world, intensity, 60.0);
  return m;
}

Eigen::MatrixXd to_sensor(const Eigen::MatrixXd& world, const Eigen::Isometry3d& pose) {
  return (world.rowwise() - pose.translation().transpose()) * pose.linear();
}

struct Tally {
  int right = 0, wrong = 0, refused = 0;
  double worst_wrong_m = 0.0, worst_wrong_deg = 0.0;
};

}  // namespace

int main(int argc, char** argv) {
  int trials = 20;
  unsigned seed = 7;
  bool dump = false;
  std::string data = IWLOMAP_BENCH_DATA_DIR;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--trials") && i + 1 < argc) trials = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--seed") && i + 1 < argc) seed = static_cast<unsigned>(std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--data") && i + 1 < argc) data = argv[++i];
    else if (!std::strcmp(argv[i], "--dump")) dump = true;
    else {
      std::printf("usage: bench_match_quality [--trials N] [--seed S] [--data DIR] [--dump]\n");
      return std::strcmp(argv[i], "--help") ? 2 : 0;
    }
  }
  std::vector<Scene> scenes;
  {
    const SyntheticScan a = make_synthetic_scan();
    SyntheticScanOptions o;
    o.seed = 2;
    const SyntheticScan b = make_synthetic_scan(o);
    Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
    truth.translation() = b.origin;
    scenes.push_back({"courtyard", map_of(a.origin, a.points, a.intensities), {to_sensor(b.points, truth)}, {truth}});
  }
  {
    const Eigen::Vector3d origin(0.3, -0.2, 1.2);
    const Eigen::MatrixXd a = make_pillar_scene(1, 0.005), b = make_pillar_scene(2, 0.01);
    Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
    truth.translation() = origin;
    scenes.push_back({"pillars", map_of(origin, a, Eigen::VectorXd::Constant(a.rows(), 100.0)),
                      {to_sensor(b, truth)}, {truth}});
  }
  const std::filesystem::path dir = std::filesystem::path(data) / "ouster_os1_128_3frames";
  if (std::filesystem::exists(dir / "frame_000_world.pcd")) {
    const auto pose_of = [](const bench::PcdCloud& c) {
      Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
      p.linear() = c.orientation.toRotationMatrix();
      p.translation() = c.origin;
      return p;
    };
    const bench::PcdCloud f0 = bench::read_pcd((dir / "frame_000_world.pcd").string());
    Scene s{"Ouster", map_of(f0.origin, f0.points, f0.intensities), {}, {}};
    for (const char* name : {"frame_001_world.pcd", "frame_002_world.pcd"}) {
      const bench::PcdCloud f = bench::read_pcd((dir / name).string());
      s.scans.push_back(to_sensor(f.points, pose_of(f)));
      s.truths.push_back(pose_of(f));
    }
    scenes.push_back(std::move(s));
  } else {
    std::printf("(no Ouster frames in %s: synthetic scenes only)\n", dir.string().c_str());
  }

  registration::ScanMatcherOptions with_model;
  with_model.max_range = 60.0;
  registration::ScanMatcherOptions without = with_model;
  without.quality.min_inlier_fraction = 0.0;
  without.quality.min_axis_support = 0.0;
  without.quality.max_free_conflict = 1.0;
  without.quality.max_coarse_disagreement = 1e9;
  without.quality.edge_margin = 0.0;
  without.quality.hold_unconstrained = false;
  const SearchWindow3D& w = with_model.window;
  std::printf("window +-%.2f m (x, y), +-%.2f m (z), +-%.1f deg; errors up to twice that, and the identity pose\n",
              w.linear_xy, w.linear_z, w.angular_yaw / kDeg);
  std::printf("%-10s %-10s %-14s %7s %7s %7s   %7s %7s %7s  %s\n", "scene", "stages", "errors", "right", "wrong",
              "refused", "right", "wrong", "refused", "worst wrong (model)");
  std::printf("%-36s %-23s   %-23s\n", "", "---- quality model ----", "---- without ----");

  int lies = 0;
  for (const Scene& s : scenes) {
    for (const bool coarse : {true, false}) {
      registration::ScanMatcherOptions a = with_model, b = without;
      a.coarse = b.coarse = coarse;
      const registration::ScanMatcher ma(*s.map, a), mb(*s.map, b);
      // Coarse+ICP: errors up to twice the window; ICP alone: up to 1 m / 10 degrees.
      const double scale = coarse ? 2.0 : 1.0;
      for (int band = 0; band < 3; ++band) {  // 0: within the window (or 1 m / 10 deg), 1: beyond it, 2: identity
        if (!coarse && band == 1) continue;
        Tally ta, tb;
        std::mt19937 rng(seed + 1000u * static_cast<unsigned>(band) + (coarse ? 0u : 500u));
        std::uniform_real_distribution<double> u(0.0, 1.0);
        const int n = band == 2 ? 1 : trials;
        for (std::size_t k = 0; k < s.scans.size(); ++k) {
          for (int t = 0; t < n; ++t) {
            const Eigen::Isometry3d& truth = s.truths[k];
            Eigen::Isometry3d initial = Eigen::Isometry3d::Identity();
            if (band < 2) {
              const double lo = band == 0 ? 0.0 : 1.0, hi = band == 0 ? 1.0 : scale;
              const double f = lo + (hi - lo) * u(rng);
              const double dir = 2.0 * 3.14159265358979323846 * u(rng);
              const double lin = coarse ? w.linear_xy : 1.0, ang = coarse ? w.angular_yaw : 10.0 * kDeg;
              const double yaw = (u(rng) < 0.5 ? -1.0 : 1.0) * (lo + (hi - lo) * u(rng)) * ang;
              initial = truth;
              initial.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() * truth.linear();
              initial.translation() += Eigen::Vector3d(f * lin * std::cos(dir), f * lin * std::sin(dir),
                                                       (2.0 * u(rng) - 1.0) * 0.5 * w.linear_z);
            }
            for (int which = 0; which < 2; ++which) {
              const registration::ScanMatchResult r = (which == 0 ? ma : mb).match(s.scans[k], initial);
              Tally& tally = which == 0 ? ta : tb;
              const double et = (r.pose.translation() - truth.translation()).norm();
              const double er = Eigen::AngleAxisd(r.pose.linear().transpose() * truth.linear()).angle() / kDeg;
              if (!r.converged) ++tally.refused;
              else if (et <= 0.1 && er <= 1.0) ++tally.right;
              else {
                ++tally.wrong;
                tally.worst_wrong_m = std::max(tally.worst_wrong_m, et);
                tally.worst_wrong_deg = std::max(tally.worst_wrong_deg, er);
              }
              if (dump)
                std::printf("  %s %s band %d model %d: conv %d err %.3f m %.2f deg | inl %.3f ovl %.3f ax %.2f %.2f %.2f "
                            "free %.3f icp %.3f m %.2f deg coarse %.3f held %d | %s\n",
                            s.name.c_str(), coarse ? "coarse+ICP" : "ICP", band, which == 0, r.converged, et, er,
                            r.inlier_fraction, r.overlap_fraction, r.axis_support.x(), r.axis_support.y(),
                            r.axis_support.z(), r.free_conflict, r.icp_shift, r.icp_turn / kDeg, r.coarse_score,
                            r.held_directions, r.reason.c_str());
            }
          }
        }
        lies += ta.wrong;
        const char* band_name = band == 0 ? (coarse ? "in window" : "<= 1 m/10 deg") : band == 1 ? "1-2x window" : "identity";
        char worst[64] = "-";
        if (ta.wrong > 0) std::snprintf(worst, sizeof worst, "%.2f m / %.1f deg", ta.worst_wrong_m, ta.worst_wrong_deg);
        std::printf("%-10s %-10s %-14s %7d %7d %7d   %7d %7d %7d  %s\n", s.name.c_str(), coarse ? "coarse+ICP" : "ICP",
                    band_name, ta.right, ta.wrong, ta.refused, tb.right, tb.wrong, tb.refused, worst);
      }
    }
  }
  std::printf("wrong poses reported as converged with the quality model: %d\n", lies);
  return 0;
}
