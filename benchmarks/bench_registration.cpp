// SPDX-License-Identifier: BSD-3-Clause
// Scan-to-map registration side by side in one run: iwlomap's ScanMatcher (both stages, coarse
// only, fine only) against PCL's IterativeClosestPoint, GeneralizedIterativeClosestPoint and
// NormalDistributionsTransform (and small_gicp's GICP and VGICP when its source folder is given
// to CMake as IWLOMAP_SMALL_GICP_DIR), from the same initial guesses, on the recorded Ouster frames
// (frames 1 and 2 against the map of frame 0; truth = the recorded SLAM poses) and on the
// synthetic courtyard (truth known). Per method and initial-error level: success rate (within
// 5 cm and 0.5 degrees of the truth), median time and median error of the successes. Error levels
// from 0.2 m / 2 deg to 2 m / 20 deg; iwlomap searches its default window (+-1 m, +-10 deg),
// widened to 1.25 times the level's error beyond 1 m / 10 deg.
//
// usage: bench_registration [--trials N] [--data DIR] [--only TEXT[,TEXT...]]   (methods whose name has one)

#include <iwlomap/probability_updater.h>
#include <iwlomap/registration/scan_matcher.h>
#include <iwlomap/sensor_preset.h>
#include <iwlomap/synthetic_scan.h>

#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#include <pcl/registration/icp.h>
#include <pcl/registration/ndt.h>

#ifdef IWLOMAP_BENCH_WITH_SMALL_GICP
#include <small_gicp/registration/registration_helper.hpp>
#endif

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <random>
#include <string>
#include <vector>

namespace {

using namespace iwlomap;
using registration::SearchWindow3D;
using Cloud = pcl::PointCloud<pcl::PointXYZ>;
constexpr double kDeg = 3.14159265358979323846 / 180.0;

struct Case {
  std::string scene;
  Eigen::MatrixXd scan_sensor;  // reduced to one point per 0.2 m voxel
  Eigen::Isometry3d truth;
};

struct Target {
  std::shared_ptr<ProbabilityUpdater> map;
  Cloud::Ptr cloud;  // the map's occupied voxels at their mean hit positions, for PCL
};

Target make_target(const Eigen::Vector3d& origin, const Eigen::MatrixXd& world, const Eigen::VectorXd& intensity) {
  Target t;
  t.map = std::make_shared<ProbabilityUpdater>(0.2);
  t.map->set_params(sensor_preset_params(SensorPreset::kLidar));
  t.map->set_hit_accumulation(true);
  t.map->insert_scan(origin, world, intensity, 60.0);
  const Eigen::MatrixXd v = t.map->get_occupied_mean_positions(0.7);
  t.cloud.reset(new Cloud);
  for (Eigen::Index i = 0; i < v.rows(); ++i)
    t.cloud->push_back(pcl::PointXYZ(static_cast<float>(v(i, 0)), static_cast<float>(v(i, 1)), static_cast<float>(v(i, 2))));
  return t;
}

Cloud::Ptr to_cloud(const Eigen::MatrixXd& m) {
  Cloud::Ptr c(new Cloud);
  for (Eigen::Index i = 0; i < m.rows(); ++i)
    c->push_back(pcl::PointXYZ(static_cast<float>(m(i, 0)), static_cast<float>(m(i, 1)), static_cast<float>(m(i, 2))));
  return c;
}

struct Outcome {
  bool converged = false;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
};

// A method runs one case from an initial pose; the window is iwlomap's coarse search window.
using Method = std::function<Outcome(const Target&, const Case&, const Eigen::Isometry3d&, const SearchWindow3D&)>;

// iwlomap's search window for an initial error of \p metres and \p degrees: the default (+-1 m,
// +-10 deg), widened to 1.25 times the error where that is larger, as a user who expects such
// errors would set it.
SearchWindow3D window_for(double metres, double degrees) {
  SearchWindow3D w;
  w.linear_xy = std::max(w.linear_xy, 1.25 * metres);
  w.angular_yaw = std::max(w.angular_yaw, 1.25 * degrees * kDeg);
  return w;
}

Outcome run_iwlomap(const Target& t, const Case& c, const Eigen::Isometry3d& initial, const SearchWindow3D& window,
                    bool coarse, bool fine) {
  registration::ScanMatcherOptions o;
  o.coarse = coarse;
  o.fine = fine;
  o.max_range = 60.0;
  o.window = window;
  const auto r = registration::ScanMatcher(*t.map, o).match(c.scan_sensor, initial);
  return {r.converged, r.pose};
}

template <class Reg>
Outcome run_pcl(Reg& reg, const Target& t, const Case& c, const Eigen::Isometry3d& initial) {
  reg.setInputTarget(t.cloud);
  reg.setInputSource(to_cloud(c.scan_sensor));
  Cloud aligned;
  reg.align(aligned, initial.matrix().cast<float>());
  Outcome o;
  o.converged = reg.hasConverged();
  o.pose.matrix() = reg.getFinalTransformation().template cast<double>();
  return o;
}

#ifdef IWLOMAP_BENCH_WITH_SMALL_GICP
// small_gicp's GICP or VGICP (one thread, as iwlomap's registration runs) against the map's
// occupied voxels at their mean hit positions, the scan as given (already one point per 0.2 m
// voxel); each call preprocesses both clouds (covariances, k-d tree), as a user's one-off
// registration does.
Outcome run_small_gicp(const Target& t, const Case& c, const Eigen::Isometry3d& initial, bool voxelized) {
  std::vector<Eigen::Vector3d> target, source;
  for (const auto& p : *t.cloud) target.emplace_back(p.x, p.y, p.z);
  for (Eigen::Index i = 0; i < c.scan_sensor.rows(); ++i) source.emplace_back(c.scan_sensor.row(i).transpose());
  small_gicp::RegistrationSetting setting;
  setting.type = voxelized ? small_gicp::RegistrationSetting::VGICP : small_gicp::RegistrationSetting::GICP;
  setting.num_threads = 1;
  setting.downsampling_resolution = 0.2;
  setting.voxel_resolution = 1.0;
  setting.max_correspondence_distance = 1.0;
  setting.max_iterations = 50;
  const small_gicp::RegistrationResult r = small_gicp::align(target, source, initial, setting);
  return {r.converged, r.T_target_source};
}
#endif

double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  int trials = 6;
  std::string data = IWLOMAP_BENCH_DATA_DIR;
  std::string only;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--trials") && i + 1 < argc) trials = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--data") && i + 1 < argc) data = argv[++i];
    else if (!std::strcmp(argv[i], "--only") && i + 1 < argc) only = argv[++i];
    else {
      std::printf("usage: bench_registration [--trials N] [--data DIR] [--only TEXT[,TEXT...]]\n");
      return std::strcmp(argv[i], "--help") ? 2 : 0;
    }
  }
  // Scenes: (target, cases).
  std::vector<std::pair<Target, std::vector<Case>>> scenes;
  {
    const SyntheticScan a = make_synthetic_scan();
    SyntheticScanOptions o;
    o.seed = 2;
    const SyntheticScan b = make_synthetic_scan(o);
    Case c{"courtyard", registration::reduce_scan(b.points.rowwise() - b.origin.transpose(), 0.2, 60.0),
           Eigen::Isometry3d::Identity()};
    c.truth.translation() = b.origin;
    scenes.push_back({make_target(a.origin, a.points, a.intensities), {c}});
  }
  const std::filesystem::path dir = std::filesystem::path(data) / "ouster_os1_128_3frames";
  if (std::filesystem::exists(dir / "frame_000_world.pcd")) {
    const auto load = [&](int k, Eigen::MatrixXd& world, Eigen::VectorXd& intensity, Eigen::Isometry3d& pose) {
      pcl::PointCloud<pcl::PointXYZI> c;
      char name[64];
      std::snprintf(name, sizeof name, "frame_%03d_world.pcd", k);
      if (pcl::io::loadPCDFile((dir / name).string(), c) < 0) throw std::runtime_error("cannot read a frame");
      world.resize(static_cast<Eigen::Index>(c.size()), 3);
      intensity.resize(static_cast<Eigen::Index>(c.size()));
      for (std::size_t i = 0; i < c.size(); ++i) {
        world.row(static_cast<Eigen::Index>(i)) << c[i].x, c[i].y, c[i].z;
        intensity[static_cast<Eigen::Index>(i)] = c[i].intensity;
      }
      pose = Eigen::Isometry3d::Identity();
      pose.linear() = c.sensor_orientation_.cast<double>().normalized().toRotationMatrix();
      pose.translation() = c.sensor_origin_.head<3>().cast<double>();
    };
    Eigen::MatrixXd w0;
    Eigen::VectorXd i0;
    Eigen::Isometry3d p0;
    load(0, w0, i0, p0);
    std::vector<Case> cases;
    for (int k : {1, 2}) {
      Eigen::MatrixXd w;
      Eigen::VectorXd in;
      Eigen::Isometry3d p;
      load(k, w, in, p);
      const Eigen::MatrixXd sensor = (w.rowwise() - p.translation().transpose()) * p.linear();
      cases.push_back({"Ouster frame " + std::to_string(k), registration::reduce_scan(sensor, 0.2, 60.0), p});
    }
    scenes.push_back({make_target(p0.translation(), w0, i0), cases});
  } else {
    std::printf("(no Ouster frames in %s: synthetic scene only)\n", dir.string().c_str());
  }

  std::vector<std::pair<std::string, Method>> methods = {
      {"iwlomap coarse+ICP", [](const Target& t, const Case& c, const Eigen::Isometry3d& i, const SearchWindow3D& w) {
         return run_iwlomap(t, c, i, w, true, true);
       }},
      {"iwlomap coarse only", [](const Target& t, const Case& c, const Eigen::Isometry3d& i, const SearchWindow3D& w) {
         return run_iwlomap(t, c, i, w, true, false);
       }},
      {"iwlomap ICP only", [](const Target& t, const Case& c, const Eigen::Isometry3d& i, const SearchWindow3D& w) {
         return run_iwlomap(t, c, i, w, false, true);
       }},
      {"PCL ICP", [](const Target& t, const Case& c, const Eigen::Isometry3d& i, const SearchWindow3D&) {
         pcl::IterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> r;
         r.setMaxCorrespondenceDistance(0.5);
         r.setMaximumIterations(50);
         r.setTransformationEpsilon(1e-8);
         return run_pcl(r, t, c, i);
       }},
      {"PCL GICP", [](const Target& t, const Case& c, const Eigen::Isometry3d& i, const SearchWindow3D&) {
         pcl::GeneralizedIterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> r;
         r.setMaxCorrespondenceDistance(0.5);
         r.setMaximumIterations(50);
         return run_pcl(r, t, c, i);
       }},
      {"PCL NDT", [](const Target& t, const Case& c, const Eigen::Isometry3d& i, const SearchWindow3D&) {
         pcl::NormalDistributionsTransform<pcl::PointXYZ, pcl::PointXYZ> r;
         r.setResolution(1.0);
         r.setStepSize(0.1);
         r.setTransformationEpsilon(1e-6);
         r.setMaximumIterations(35);
         return run_pcl(r, t, c, i);
       }},
  };
#ifdef IWLOMAP_BENCH_WITH_SMALL_GICP
  methods.push_back({"small_gicp GICP", [](const Target& t, const Case& c, const Eigen::Isometry3d& i,
                                           const SearchWindow3D&) { return run_small_gicp(t, c, i, false); }});
  methods.push_back({"small_gicp VGICP", [](const Target& t, const Case& c, const Eigen::Isometry3d& i,
                                            const SearchWindow3D&) { return run_small_gicp(t, c, i, true); }});
#else
  std::printf("(no small_gicp rows: configure with -DIWLOMAP_SMALL_GICP_DIR=DIR, small_gicp's source folder)\n");
#endif
  const std::vector<std::pair<double, double>> levels = {{0.2, 2.0}, {0.5, 5.0}, {0.8, 8.0}, {1.0, 10.0},
                                                                {1.5, 15.0}, {2.0, 20.0}};
  std::printf("scan-to-map registration, %d trial(s) per scene case and error level; success = within 5 cm "
              "and 0.5 deg of the truth\n", trials);
  std::printf("%-22s %-16s %10s %12s %14s %14s\n", "method", "initial error", "success", "median ms",
              "median cm", "median deg");
  for (const auto& [name, method] : methods) {
    // --only TEXT[,TEXT...]: methods whose name holds one of them.
    bool wanted = only.empty();
    for (std::size_t a = 0; !wanted && a <= only.size();) {
      const std::size_t b = std::min(only.find(',', a), only.size());
      wanted = name.find(only.substr(a, b - a)) != std::string::npos;
      a = b + 1;
    }
    if (!wanted) continue;
    for (const auto& [metres, degrees] : levels) {
      std::mt19937 rng(11);
      std::uniform_real_distribution<double> u(-1.0, 1.0);
      int ok = 0, runs = 0;
      std::vector<double> ms, cm, deg;
      for (const auto& [target, cases] : scenes)
        for (const Case& c : cases)
          for (int k = 0; k < trials; ++k) {
            // An error of exactly `metres` horizontally in a random direction and +-`degrees` of yaw.
            const double a = 3.14159265358979323846 * u(rng);
            Eigen::Isometry3d initial = c.truth;
            initial.translation() += metres * Eigen::Vector3d(std::cos(a), std::sin(a), 0.0);
            initial.linear() = Eigen::AngleAxisd((k % 2 ? 1 : -1) * degrees * kDeg, Eigen::Vector3d::UnitZ())
                                   .toRotationMatrix() * c.truth.linear();
            const auto t0 = std::chrono::steady_clock::now();
            const Outcome o = method(target, c, initial, window_for(metres, degrees));
            const double elapsed = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
            const double et = (o.pose.translation() - c.truth.translation()).norm();
            const double er = Eigen::AngleAxisd(o.pose.linear().transpose() * c.truth.linear()).angle();
            ++runs;
            ms.push_back(elapsed);
            if (o.converged && et <= 0.05 && er <= 0.5 * kDeg) {
              ++ok;
              cm.push_back(100.0 * et);
              deg.push_back(er / kDeg);
            }
          }
      char level[32];
      std::snprintf(level, sizeof level, "%.1f m / %.0f deg", metres, degrees);
      std::printf("%-22s %-16s %6d/%-3d %12.1f %14.2f %14.3f\n", name.c_str(), level, ok, runs, median(ms), median(cm),
                  median(deg));
      std::fflush(stdout);
    }
  }
  return 0;
}
