// SPDX-License-Identifier: BSD-3-Clause
// SLAM over a street loop: a synthetic city block larger than the lidar's range (SyntheticWorld,
// default 200 x 150 m, lidar 32 x 1024 beams to 40 m, a scan every 3 m around the loop), the
// navigation drifting 1 % of the distance and 0.5 degrees of heading per 10 m. Side by side in one
// run: navigation only, registration only (PoseGraphMapper without loop closure), registration
// with loop closure, the same with injected false closures, and frame-to-frame odometry by PCL's
// GICP when PCL is built in. Per row: absolute trajectory error (ATE: RMS of the position error,
// no alignment: every run starts at the true first pose), relative pose error between consecutive
// scans (RPE, translation and rotation, RMS), the map's F1 against the truth map, and the time
// per scan. The truth map: voxels holding a noise-free return at the true poses; a map voxel is
// right when a truth voxel lies within one voxel of it (and the other way round for recall).
//
// usage: bench_slam [--block X Y] [--step M] [--rings N] [--columns N] [--range M]
//                   [--scans-per-submap N] [--false-closures F] [--no-gicp] [--dump] [--quick]

#include <iwlomap/mapper_backend.h>
#include <iwlomap/sensor_preset.h>
#include <iwlomap/slam/pose_graph_mapper.h>
#include <iwlomap/synthetic_world.h>
#include <iwlomap/voxel_key.h>

#ifdef IWLOMAP_BENCH_WITH_PCL
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#endif

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <unordered_set>
#include <vector>

namespace {

using namespace iwlomap;
constexpr double kDeg = 3.14159265358979323846 / 180.0;

struct Setup {
  StreetLoopOptions street;
  LidarOptions lidar;
  double step = 3.0;
  int scans_per_submap = 20;
  double false_fraction = 0.1;
  bool gicp = true;
  bool dump = false;
  double resolution = 0.2;
};

struct Row {
  std::string name;
  std::vector<Eigen::Isometry3d> poses;
  double seconds = 0.0;
  double f1 = std::nan("");
  std::string note;
};

double ate(const std::vector<Eigen::Isometry3d>& p, const std::vector<Eigen::Isometry3d>& truth) {
  double s = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) s += (p[i].translation() - truth[i].translation()).squaredNorm();
  return std::sqrt(s / static_cast<double>(p.size()));
}

// RMS over consecutive pairs of the error of the relative motion: metres and degrees.
std::pair<double, double> rpe(const std::vector<Eigen::Isometry3d>& p, const std::vector<Eigen::Isometry3d>& truth) {
  double st = 0.0, sr = 0.0;
  for (std::size_t i = 1; i < p.size(); ++i) {
    const Eigen::Isometry3d e = (truth[i - 1].inverse() * truth[i]).inverse() * (p[i - 1].inverse() * p[i]);
    st += e.translation().squaredNorm();
    const double a = Eigen::AngleAxisd(e.linear()).angle() / kDeg;
    sr += a * a;
  }
  const double n = static_cast<double>(p.size() - 1);
  return {std::sqrt(st / n), std::sqrt(sr / n)};
}

using KeySet = std::unordered_set<VoxelKey>;  // std::hash<VoxelKey> from voxel_key.h

KeySet keys_of(const Eigen::MatrixXd& pts, double res) {
  KeySet s;
  for (Eigen::Index i = 0; i < pts.rows(); ++i) s.insert(world_to_key(pts.row(i).transpose(), res));
  return s;
}

bool near_any(const KeySet& s, const VoxelKey& k) {
  for (int dx = -1; dx <= 1; ++dx)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dz = -1; dz <= 1; ++dz)
        if (s.count(VoxelKey{k.x + dx, k.y + dy, k.z + dz})) return true;
  return false;
}

double f1_of(const KeySet& map, const KeySet& truth) {
  if (map.empty() || truth.empty()) return 0.0;
  std::size_t tp_map = 0, tp_truth = 0;
  for (const VoxelKey& k : map) tp_map += near_any(truth, k) ? 1 : 0;
  for (const VoxelKey& k : truth) tp_truth += near_any(map, k) ? 1 : 0;
  const double precision = static_cast<double>(tp_map) / static_cast<double>(map.size());
  const double recall = static_cast<double>(tp_truth) / static_cast<double>(truth.size());
  return precision + recall > 0.0 ? 2.0 * precision * recall / (precision + recall) : 0.0;
}

KeySet occupied_keys(IMapperBackend& map, double res) { return keys_of(map.get_occupied_voxels(0.7).leftCols<3>(), res); }

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  Setup s;
  s.lidar.max_range = 40.0;
  for (int i = 1; i < argc; ++i) {
    const auto next = [&] { return i + 1 < argc ? std::atof(argv[++i]) : 0.0; };
    if (!std::strcmp(argv[i], "--block")) {
      s.street.block_x = next();
      s.street.block_y = next();
    } else if (!std::strcmp(argv[i], "--step")) s.step = next();
    else if (!std::strcmp(argv[i], "--rings")) s.lidar.rings = static_cast<int>(next());
    else if (!std::strcmp(argv[i], "--columns")) s.lidar.columns = static_cast<int>(next());
    else if (!std::strcmp(argv[i], "--range")) s.lidar.max_range = next();
    else if (!std::strcmp(argv[i], "--scans-per-submap")) s.scans_per_submap = static_cast<int>(next());
    else if (!std::strcmp(argv[i], "--false-closures")) s.false_fraction = next();
    else if (!std::strcmp(argv[i], "--no-gicp")) s.gicp = false;
    else if (!std::strcmp(argv[i], "--dump")) s.dump = true;
    else if (!std::strcmp(argv[i], "--quick")) {  // the smoke run of the tests: a small block
      s.street.block_x = 70.0;
      s.street.block_y = 50.0;
      s.step = 5.0;
      s.lidar.rings = 16;
      s.lidar.columns = 360;
      s.lidar.max_range = 30.0;
      s.scans_per_submap = 8;
      s.gicp = false;
    } else {
      std::printf("usage: bench_slam [--block X Y] [--step M] [--rings N] [--columns N] [--range M]\n"
                  "                  [--scans-per-submap N] [--false-closures F] [--no-gicp] [--dump] [--quick]\n");
      return std::strcmp(argv[i], "--help") ? 2 : 0;
    }
  }
  const SyntheticWorld world = SyntheticWorld::street_loop(s.street);
  std::vector<Eigen::Isometry3d> truth = SyntheticWorld::street_loop_trajectory(s.street, s.step);
  // Around once and on to the second pose: the end of the loop overlaps its start.
  truth.push_back(truth[0]);
  truth.push_back(truth[1]);
  const std::size_t n = truth.size();

  // Navigation: each true step lengthened by 1 % and turned by 0.5 degrees per 10 m.
  std::vector<Eigen::Isometry3d> nav(n);
  nav[0] = truth[0];
  for (std::size_t i = 1; i < n; ++i) {
    Eigen::Isometry3d step = truth[i - 1].inverse() * truth[i];
    const double d = step.translation().norm();
    step.translation() *= 1.01;
    step.linear() = Eigen::AngleAxisd(0.05 * kDeg * d, Eigen::Vector3d::UnitZ()).toRotationMatrix() * step.linear();
    nav[i] = nav[i - 1] * step;
  }
  std::vector<LidarFrame> frames;
  frames.reserve(n);
  KeySet truth_keys;
  {
    LidarOptions exact = s.lidar;
    exact.range_noise = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      frames.push_back(world.scan(truth[i], s.lidar, static_cast<std::uint32_t>(i + 1)));
      const LidarFrame f = world.scan(truth[i], exact, static_cast<std::uint32_t>(i + 1));
      const Eigen::MatrixXd w = (f.points * truth[i].linear().transpose()).rowwise() + truth[i].translation().transpose();
      const KeySet k = keys_of(w, s.resolution);
      truth_keys.insert(k.begin(), k.end());
    }
  }
  std::printf("world: block %.0f x %.0f m, %zu boxes; %zu scans every %.1f m; lidar %d x %d to %.0f m; "
              "%zu truth voxels at %.2f m\n",
              s.street.block_x, s.street.block_y, world.boxes().size(), n, s.step, s.lidar.rings, s.lidar.columns,
              s.lidar.max_range, truth_keys.size(), s.resolution);

  slam::PoseGraphMapperOptions base;
  base.resolution = s.resolution;
  base.params = sensor_preset_params(SensorPreset::kLidar);
  base.max_range = s.lidar.max_range;
  base.scans_per_submap = s.scans_per_submap;
  base.matcher.max_range = s.lidar.max_range;
  base.closure_matcher.max_range = s.lidar.max_range;

  std::vector<Row> rows;
  // The map any pose list gives: the scans re-integrated at those poses.
  const auto map_f1 = [&](const std::vector<Eigen::Isometry3d>& poses) {
    std::unique_ptr<IMapperBackend> m = make_backend("RAM", s.resolution);
    m->set_params(base.params);
    for (std::size_t i = 0; i < n; ++i) {
      const Eigen::MatrixXd w =
          (frames[i].points * poses[i].linear().transpose()).rowwise() + poses[i].translation().transpose();
      m->insert_scan(poses[i].translation(), w, frames[i].intensities, s.lidar.max_range);
    }
    return f1_of(occupied_keys(*m, s.resolution), truth_keys);
  };
  rows.push_back({"true poses", truth, 0.0, map_f1(truth), "the ceiling"});
  rows.push_back({"navigation only", nav, 0.0, map_f1(nav), ""});

  const auto run = [&](const char* name, bool closures, double false_fraction) {
    slam::PoseGraphMapperOptions o = base;
    o.loop_closure = closures;
    slam::PoseGraphMapper mapper(ExecutionMode::kSequential, o);
    const auto t0 = std::chrono::steady_clock::now();
    std::size_t held = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const slam::SlamScanReport r = mapper.add_scan(nav[i], frames[i].points, frames[i].intensities);
      held += r.held_directions > 0 ? 1 : 0;
      if (s.dump) {
        const Eigen::Isometry3d e = truth[i].inverse() * r.local_pose;
        std::printf("  %s scan %zu: reg %d held %d submap %zu closures %zu local error %.3f m | %s\n", name, i,
                    r.registered, r.held_directions, r.submap, r.closures.size(), e.translation().norm(),
                    r.reason.c_str());
      }
    }
    // False closures: each joins a random scan to a random finished submap at a pose 2-10 m and
    // 5-30 degrees away from any true one, as many as make false_fraction of all closures.
    std::size_t injected = 0;
    if (false_fraction > 0.0) {
      const std::size_t found = mapper.loop_closures().size();
      injected = static_cast<std::size_t>(std::ceil(false_fraction * static_cast<double>(found) / (1.0 - false_fraction)));
      std::mt19937 rng(17);
      std::uniform_real_distribution<double> u(0.0, 1.0);
      for (std::size_t k = 0; k < injected; ++k) {
        const std::size_t scan = static_cast<std::size_t>(u(rng) * static_cast<double>(n - 1));
        const std::size_t submap = static_cast<std::size_t>(u(rng) * static_cast<double>(mapper.num_submaps() - 1));
        Eigen::Isometry3d rel = Eigen::Isometry3d::Identity();
        const double a = 2 * 3.14159265358979323846 * u(rng), d = 2.0 + 8.0 * u(rng);
        rel.translation() = Eigen::Vector3d(d * std::cos(a), d * std::sin(a), 0.0);
        rel.linear() = Eigen::AngleAxisd((5.0 + 25.0 * u(rng)) * kDeg, Eigen::Vector3d::UnitZ()).toRotationMatrix();
        (void)mapper.add_loop_closure(scan, submap, rel,
                                      slam::information_from_sigmas(o.closure_translation_sigma, o.closure_rotation_sigma));
      }
    }
    if (closures) mapper.finish();
    const double secs = seconds_since(t0);
    const slam::SlamSummary sum = mapper.summary();
    char note[256];
    std::snprintf(note, sizeof note,
                  "%zu/%zu registered (%zu with held directions), %zu submaps, closures %zu found in %zu tries%s",
                  sum.registered, sum.scans, held, sum.submaps, sum.closures_found, sum.closure_attempts,
                  injected ? (", " + std::to_string(injected) + " false injected, " +
                              std::to_string(sum.closures_rejected_by_optimizer) + " rejected")
                                 .c_str()
                           : "");
    const std::vector<Eigen::Isometry3d> poses = mapper.poses();
    rows.push_back({name, poses, secs, f1_of(occupied_keys(*mapper.map(), s.resolution), truth_keys), note});
  };
  run("registration only", false, 0.0);
  run("registration + loop closure", true, 0.0);
  if (s.false_fraction > 0.0) run("... with false closures", true, s.false_fraction);

#ifdef IWLOMAP_BENCH_WITH_PCL
  if (s.gicp) {
    using Cloud = pcl::PointCloud<pcl::PointXYZ>;
    const auto cloud_of = [&](const LidarFrame& f) {
      Cloud::Ptr c(new Cloud);
      for (Eigen::Index i = 0; i < f.points.rows(); ++i)
        c->push_back(pcl::PointXYZ(static_cast<float>(f.points(i, 0)), static_cast<float>(f.points(i, 1)),
                                   static_cast<float>(f.points(i, 2))));
      return c;
    };
    std::vector<Eigen::Isometry3d> poses(n);
    poses[0] = nav[0];
    const auto t0 = std::chrono::steady_clock::now();
    for (std::size_t i = 1; i < n; ++i) {
      pcl::GeneralizedIterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> gicp;
      gicp.setMaxCorrespondenceDistance(1.0);
      gicp.setMaximumIterations(50);
      gicp.setInputTarget(cloud_of(frames[i - 1]));
      gicp.setInputSource(cloud_of(frames[i]));
      const Eigen::Isometry3d guess = nav[i - 1].inverse() * nav[i];
      Cloud aligned;
      gicp.align(aligned, guess.matrix().cast<float>());
      Eigen::Isometry3d step = guess;
      if (gicp.hasConverged()) step.matrix() = gicp.getFinalTransformation().cast<double>();
      step.linear() = Eigen::Quaterniond(step.linear()).normalized().toRotationMatrix();
      poses[i] = poses[i - 1] * step;
    }
    rows.push_back({"PCL GICP frame to frame", poses, seconds_since(t0), map_f1(poses), "odometry, no map"});
  }
#endif

  const double f1_true = rows[0].f1;
  std::printf("\n%-30s %9s %10s %10s %7s %9s %11s  %s\n", "run", "ATE (m)", "RPE (m)", "RPE (deg)", "F1",
              "F1/true", "ms / scan", "notes");
  for (const Row& r : rows) {
    const auto [rt, rr] = rpe(r.poses, truth);
    std::printf("%-30s %9.3f %10.4f %10.4f %7.4f %9.4f %11.1f  %s\n", r.name.c_str(), ate(r.poses, truth), rt, rr,
                r.f1, r.f1 / f1_true, 1000.0 * r.seconds / static_cast<double>(n), r.note.c_str());
  }
  return 0;
}
