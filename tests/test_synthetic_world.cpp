// SPDX-License-Identifier: BSD-3-Clause
// The synthetic lidar world: ray casting against a brute-force oracle, scans that are seeded and
// lie on the surfaces, and the street loop's geometry and trajectory.

#include "iwlomap/synthetic_world.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;

WorldBox make_box(Eigen::Vector3d lo, Eigen::Vector3d hi, double reflectivity = 0.5) {
  WorldBox b;
  b.lo = lo;
  b.hi = hi;
  b.reflectivity = reflectivity;
  return b;
}

bool inside(const WorldBox& b, const Eigen::Vector3d& p, double tolerance = 0.0) {
  return (p.array() >= b.lo.array() - tolerance).all() && (p.array() <= b.hi.array() + tolerance).all();
}

// Face by face, independent of the slab test: the nearest point where the ray crosses a face
// plane inside the face's rectangle; boxes that contain the origin are skipped, as cast() does.
double brute_force_cast(const SyntheticWorld& world, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double max_range) {
  double best = kInf;
  if (d.z() != 0.0) {
    const double t = (world.ground_z() - o.z()) / d.z();
    if (t > 0.0) best = t;
  }
  for (const WorldBox& b : world.boxes()) {
    if (inside(b, o)) continue;
    for (int axis = 0; axis < 3; ++axis) {
      if (d[axis] == 0.0) continue;
      for (double plane : {b.lo[axis], b.hi[axis]}) {
        const double t = (plane - o[axis]) / d[axis];
        if (!(t > 0.0 && t < best)) continue;
        Eigen::Vector3d p = o + t * d;
        p[axis] = plane;
        if (inside(b, p, 1e-12)) best = t;
      }
    }
  }
  return best <= max_range ? best : kInf;
}

Eigen::Vector3d random_direction(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::Vector3d d;
  do d = Eigen::Vector3d(n(rng), n(rng), n(rng));
  while (d.norm() < 1e-3);
  return d.normalized();
}

// Whether a world-frame point lies on the ground or on a face of some box.
bool on_surface(const SyntheticWorld& world, const Eigen::Vector3d& p, double tolerance) {
  if (std::abs(p.z() - world.ground_z()) <= tolerance) return true;
  for (const WorldBox& b : world.boxes()) {
    if (!inside(b, p, tolerance)) continue;
    for (int axis = 0; axis < 3; ++axis)
      if (std::abs(p[axis] - b.lo[axis]) <= tolerance || std::abs(p[axis] - b.hi[axis]) <= tolerance) return true;
  }
  return false;
}

LidarOptions noise_free(LidarOptions lidar = {}) {
  lidar.range_noise = 0.0;
  lidar.intensity_noise = 0.0;
  return lidar;
}

TEST(SyntheticWorld, CastMatchesBruteForceWhenManyRandomBoxes) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> xy(0.0, 60.0), size(0.2, 12.0), height(0.5, 15.0), z0(0.0, 3.0);
  std::vector<WorldBox> boxes;
  for (int i = 0; i < 150; ++i) {
    const Eigen::Vector3d lo(xy(rng), xy(rng), i % 4 == 0 ? z0(rng) : 0.0);  // some boxes float
    boxes.push_back(make_box(lo, lo + Eigen::Vector3d(size(rng), size(rng), height(rng))));
  }
  const SyntheticWorld world(boxes, -0.5);
  std::uniform_real_distribution<double> ox(-15.0, 75.0), oz(0.0, 12.0);  // some origins off the grid
  int box_hits = 0, misses = 0, checked = 0;
  for (int i = 0; i < 4000; ++i) {
    const Eigen::Vector3d o(ox(rng), ox(rng), oz(rng));
    bool in_box = false;
    for (const WorldBox& b : boxes) in_box = in_box || inside(b, o);
    if (in_box) continue;
    const Eigen::Vector3d d = random_direction(rng);
    const double max_range = i % 2 == 0 ? 30.0 : 200.0;
    const double expected = brute_force_cast(world, o, d, max_range);
    const double got = world.cast(o, d, max_range);
    ++checked;
    if (expected == kInf) {
      ++misses;
      EXPECT_EQ(got, kInf) << "ray " << i;
    } else {
      box_hits += d.z() >= 0.0 || expected < (world.ground_z() - o.z()) / d.z();
      EXPECT_NEAR(got, expected, 1e-9) << "ray " << i;
    }
  }
  // Every case is well represented: box hits, ground hits and misses.
  EXPECT_GT(checked, 2500);
  EXPECT_GT(box_hits, checked / 5);
  EXPECT_GT(misses, checked / 10);
  EXPECT_LT(box_hits + misses, checked - checked / 10);
}

TEST(SyntheticWorld, CastMatchesBruteForceInTheStreetLoop) {
  const SyntheticWorld world = SyntheticWorld::street_loop();
  const std::vector<Eigen::Isometry3d> poses = SyntheticWorld::street_loop_trajectory({}, 1.0);
  std::mt19937 rng(11);
  int box_hits = 0;
  for (std::size_t i = 0; i < poses.size(); i += 23) {
    const Eigen::Vector3d o = poses[i].translation();
    for (int k = 0; k < 100; ++k) {
      const Eigen::Vector3d d = random_direction(rng);
      const double expected = brute_force_cast(world, o, d, 60.0);
      box_hits += expected < kInf && (d.z() >= 0.0 || expected < -o.z() / d.z() - 1e-9);
      if (expected == kInf)
        EXPECT_EQ(world.cast(o, d, 60.0), kInf) << "pose " << i << " ray " << k;
      else
        EXPECT_NEAR(world.cast(o, d, 60.0), expected, 1e-9) << "pose " << i << " ray " << k;
    }
  }
  EXPECT_GT(box_hits, 600);
}

TEST(SyntheticWorld, CastHitsNearestFaceWhenTwoBoxesInLine) {
  const SyntheticWorld world({make_box({5, 0, 0}, {6, 1, 1}), make_box({10, -1, 0}, {12, 2, 3})});
  EXPECT_DOUBLE_EQ(world.cast({0, 0.5, 0.5}, Eigen::Vector3d::UnitX(), 100.0), 5.0);
  EXPECT_DOUBLE_EQ(world.cast({20, 0.5, 0.5}, -Eigen::Vector3d::UnitX(), 100.0), 8.0);
  EXPECT_DOUBLE_EQ(world.cast({8, 0.5, 0.5}, Eigen::Vector3d::UnitX(), 100.0), 2.0);
  EXPECT_DOUBLE_EQ(world.cast({11, 0.5, 10}, -Eigen::Vector3d::UnitZ(), 100.0), 7.0);  // top face
}

TEST(SyntheticWorld, CastReturnsInfinityWhenRayMissesOrHitIsBeyondMaxRange) {
  const SyntheticWorld world({make_box({5, 0, 0}, {6, 1, 1})});
  EXPECT_EQ(world.cast({0, 0.5, 0.5}, -Eigen::Vector3d::UnitX(), 100.0), kInf);
  EXPECT_EQ(world.cast({0, 0.5, 0.5}, Eigen::Vector3d::UnitZ(), 100.0), kInf);
  EXPECT_EQ(world.cast({0, 0.5, 0.5}, Eigen::Vector3d::UnitX(), 4.9), kInf);
  EXPECT_DOUBLE_EQ(world.cast({0, 0.5, 0.5}, Eigen::Vector3d::UnitX(), 5.0), 5.0);
  EXPECT_EQ(world.cast({0, 3.0, 0.5}, Eigen::Vector3d::UnitX(), 100.0), kInf);  // passes beside it
}

TEST(SyntheticWorld, CastHitsGroundWhenNoBoxInTheWay) {
  const SyntheticWorld empty({}, -1.0);
  const Eigen::Vector3d down = Eigen::Vector3d(1, 0, -1).normalized();
  EXPECT_NEAR(empty.cast({0, 0, 2}, down, 100.0), 3.0 * std::sqrt(2.0), 1e-12);
  EXPECT_EQ(empty.cast({0, 0, 2}, down, 4.0), kInf);
  const SyntheticWorld world({make_box({50, 50, 0}, {51, 51, 1})});
  EXPECT_NEAR(world.cast({0, 0, 2}, down, 100.0), 2.0 * std::sqrt(2.0), 1e-12);
}

TEST(SyntheticWorld, CastIgnoresBoxContainingOrigin) {
  const SyntheticWorld world({make_box({-1, -1, 0}, {1, 1, 3}), make_box({4, -1, 0}, {5, 1, 3})});
  EXPECT_DOUBLE_EQ(world.cast({0, 0, 1}, Eigen::Vector3d::UnitX(), 100.0), 4.0);
  EXPECT_DOUBLE_EQ(world.cast({0, 0, 1}, -Eigen::Vector3d::UnitZ(), 100.0), 1.0);  // the ground
  EXPECT_EQ(world.cast({0, 0, 1}, Eigen::Vector3d::UnitY(), 100.0), kInf);
}

TEST(SyntheticWorld, ScanIsDeterministicForASeedAndDiffersWithAnother) {
  const SyntheticWorld world = SyntheticWorld::street_loop();
  const Eigen::Isometry3d pose = SyntheticWorld::street_loop_trajectory({}, 2.0).at(20);
  LidarOptions lidar;
  lidar.columns = 512;
  const LidarFrame a = world.scan(pose, lidar, 3), b = world.scan(pose, lidar, 3), c = world.scan(pose, lidar, 4);
  ASSERT_GT(a.points.rows(), 0);
  EXPECT_EQ(a.points, b.points);
  EXPECT_EQ(a.intensities, b.intensities);
  ASSERT_EQ(a.points.rows(), c.points.rows());  // noise moves points, it does not drop beams
  EXPECT_NE(a.points, c.points);
  EXPECT_NE(a.intensities, c.intensities);
  EXPECT_GE(a.intensities.minCoeff(), 0.0);
  EXPECT_LE(a.intensities.maxCoeff(), 255.0);
}

TEST(SyntheticWorld, NoiseFreeScanPointsLieOnSurfacesWithinMaxRange) {
  const SyntheticWorld world = SyntheticWorld::street_loop();
  LidarOptions lidar = noise_free();
  lidar.rings = 16;
  lidar.columns = 256;
  lidar.max_range = 30.0;
  Eigen::Isometry3d tilted = SyntheticWorld::street_loop_trajectory({}, 2.0).at(40);
  const Eigen::Isometry3d level = tilted;
  tilted.rotate(Eigen::AngleAxisd(0.15, Eigen::Vector3d(1, 2, 0).normalized()));  // sensor-frame output must hold
  for (const Eigen::Isometry3d& pose : {level, tilted}) {
    const LidarFrame f = world.scan(pose, lidar, 1);
    ASSERT_GT(f.points.rows(), lidar.rings * lidar.columns / 2);
    ASSERT_EQ(f.intensities.size(), f.points.rows());
    for (Eigen::Index i = 0; i < f.points.rows(); ++i) {
      const Eigen::Vector3d p_sensor = f.points.row(i).transpose();
      EXPECT_LE(p_sensor.norm(), lidar.max_range + 1e-9);
      const Eigen::Vector3d p = pose * p_sensor;
      EXPECT_TRUE(on_surface(world, p, 1e-6)) << "point " << i << " at " << p.transpose();
      // The noise-free intensity is reflectivity * 255 * cos(incidence): 0 < I <= 255.
      EXPECT_GT(f.intensities[i], 0.0);
      EXPECT_LE(f.intensities[i], 255.0);
    }
  }
}

TEST(SyntheticWorld, ScanGivesNoPointForBeamsThatHitNothing) {
  const SyntheticWorld world({make_box({5, -1, 0}, {6, 1, 2}, 1.0)});
  LidarOptions lidar = noise_free();
  lidar.rings = 1;
  lidar.min_elevation = lidar.max_elevation = 0.0;
  lidar.columns = 360;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.translation() = Eigen::Vector3d(0, 0, 1);
  const LidarFrame f = world.scan(pose, lidar, 1);
  // The box's front face spans atan(1/5) either side of +x: columns -11..11.
  ASSERT_EQ(f.points.rows(), 23);
  EXPECT_DOUBLE_EQ(f.points(0, 0), 5.0);  // first beam, straight ahead
  EXPECT_DOUBLE_EQ(f.intensities[0], 255.0);
}

TEST(StreetLoop, TrajectoryIsClosedAndTurnsSmoothly) {
  const StreetLoopOptions options;
  const double step = 1.0;
  const std::vector<Eigen::Isometry3d> poses = SyntheticWorld::street_loop_trajectory(options, step);
  const double r = 6.0;
  const double perimeter = 2.0 * (options.block_x + options.block_y) - 8.0 * r + 2.0 * kPi * r;
  ASSERT_EQ(static_cast<double>(poses.size()), std::round(perimeter / step));
  EXPECT_TRUE(poses.front().translation().isApprox(Eigen::Vector3d(r, 0, 1.8), 1e-12));
  EXPECT_TRUE(poses.front().linear().isApprox(Eigen::Matrix3d::Identity(), 1e-12));

  const double spacing = perimeter / static_cast<double>(poses.size());
  EXPECT_NEAR(spacing, step, 0.5 * step / static_cast<double>(poses.size()) + 1e-12);
  // The last pose plus one step along its heading is the first pose, up to the sagitta of the
  // last corner's arc.
  const Eigen::Vector3d next = poses.back() * Eigen::Vector3d(spacing, 0, 0);
  EXPECT_LT((next - poses.front().translation()).norm(), spacing * spacing / r);
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const Eigen::Isometry3d& a = poses[i];
    const Eigen::Isometry3d& b = poses[(i + 1) % poses.size()];
    const double chord = (b.translation() - a.translation()).norm();
    EXPECT_NEAR(chord, spacing, 2e-3) << "pose " << i;  // an arc of radius 6 shortens a 1 m chord by 1.2 mm
    const double turn = Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
    EXPECT_LE(turn, spacing / r + 1e-9) << "pose " << i;
    EXPECT_NEAR(a.translation().z(), 1.8, 1e-12);
    EXPECT_NEAR((a.linear() * Eigen::Vector3d::UnitZ()).z(), 1.0, 1e-12);  // z stays up
  }
}

TEST(StreetLoop, LaneIsFreeAndNoPoseIsInsideABox) {
  const StreetLoopOptions options;
  const SyntheticWorld world = SyntheticWorld::street_loop(options);
  const auto free_point = [&](const Eigen::Vector3d& p) {
    for (const WorldBox& b : world.boxes())
      if (inside(b, p)) return false;
    return true;
  };
  for (const Eigen::Isometry3d& pose : SyntheticWorld::street_loop_trajectory(options, 1.0)) {
    EXPECT_TRUE(free_point(pose.translation())) << pose.translation().transpose();
    for (double lateral = -3.0; lateral <= 3.0; lateral += 0.5)
      for (double z : {0.05, 1.0, 2.5, 4.0}) {
        Eigen::Vector3d p = pose * Eigen::Vector3d(0, lateral, 0);
        p.z() = z;
        EXPECT_TRUE(free_point(p)) << p.transpose();
      }
  }
  // The rectangle's centreline too, corners included.
  const double bx = options.block_x, by = options.block_y;
  for (double s = 0.0; s <= 2.0 * (bx + by); s += 1.0) {
    Eigen::Vector2d c = s < bx ? Eigen::Vector2d(s, 0) : s < bx + by ? Eigen::Vector2d(bx, s - bx)
                      : s < 2 * bx + by ? Eigen::Vector2d(bx - (s - bx - by), by) : Eigen::Vector2d(0, by - (s - 2 * bx - by));
    for (double dx = -3.0; dx <= 3.0; dx += 1.0)
      for (double dy = -3.0; dy <= 3.0; dy += 1.0) EXPECT_TRUE(free_point({c.x() + dx, c.y() + dy, 1.0}));
  }
}

TEST(StreetLoop, ScanSeesBuildingsOnBothSidesOfTheStreet) {
  const SyntheticWorld world = SyntheticWorld::street_loop();
  const std::vector<Eigen::Isometry3d> poses = SyntheticWorld::street_loop_trajectory({}, 1.0);
  for (std::size_t i : {std::size_t{0}, poses.size() / 3}) {
    const LidarFrame f = world.scan(poses[i], LidarOptions{}, 5);
    int left = 0, right = 0;
    for (Eigen::Index k = 0; k < f.points.rows(); ++k) {
      if (f.points(k, 2) < 0.5) continue;  // above the parked cars: walls, poles, trees
      if (f.points(k, 1) > 5.0) ++left;
      if (f.points(k, 1) < -5.0) ++right;
    }
    EXPECT_GT(left, 500) << "pose " << i;
    EXPECT_GT(right, 500) << "pose " << i;
  }
}

TEST(StreetLoop, SameSeedGivesSameWorldAndAnotherSeedAnother) {
  StreetLoopOptions options;
  const SyntheticWorld a = SyntheticWorld::street_loop(options), b = SyntheticWorld::street_loop(options);
  options.seed = 2;
  const SyntheticWorld c = SyntheticWorld::street_loop(options);
  ASSERT_EQ(a.boxes().size(), b.boxes().size());
  for (std::size_t i = 0; i < a.boxes().size(); ++i) {
    EXPECT_EQ(a.boxes()[i].lo, b.boxes()[i].lo);
    EXPECT_EQ(a.boxes()[i].hi, b.boxes()[i].hi);
  }
  bool differ = a.boxes().size() != c.boxes().size();
  for (std::size_t i = 0; !differ && i < a.boxes().size(); ++i) differ = a.boxes()[i].hi != c.boxes()[i].hi;
  EXPECT_TRUE(differ);
  // Buildings 6-25 m high line the loop; nothing is taller.
  double tallest = 0.0;
  int buildings = 0;
  for (const WorldBox& box : a.boxes()) {
    tallest = std::max(tallest, box.hi.z());
    buildings += box.hi.z() >= 6.0 && (box.hi - box.lo).head<2>().minCoeff() >= 6.0;
  }
  EXPECT_LE(tallest, 25.0);
  EXPECT_GT(buildings, 30);
}

void expect_invalid(const std::function<void()>& f, const std::string& name) {
  try {
    f();
    ADD_FAILURE() << "no exception for " << name;
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
  }
}

TEST(SyntheticWorld, BadOptionsThrowInvalidArgumentNamingTheValue) {
  const auto lidar_with = [](auto change) {
    LidarOptions o;
    change(o);
    return [o] { o.validate(); };
  };
  expect_invalid(lidar_with([](LidarOptions& o) { o.rings = 0; }), "rings");
  expect_invalid(lidar_with([](LidarOptions& o) { o.columns = -1; }), "columns");
  expect_invalid(lidar_with([](LidarOptions& o) { o.min_elevation = -2.0; }), "min_elevation");
  expect_invalid(lidar_with([](LidarOptions& o) { o.max_elevation = -0.5; }), "max_elevation");
  expect_invalid(lidar_with([](LidarOptions& o) { o.max_elevation = kNaN; }), "max_elevation");
  expect_invalid(lidar_with([](LidarOptions& o) { o.max_range = 0.0; }), "max_range");
  expect_invalid(lidar_with([](LidarOptions& o) { o.max_range = kInf; }), "max_range");
  expect_invalid(lidar_with([](LidarOptions& o) { o.range_noise = -0.1; }), "range_noise");
  expect_invalid(lidar_with([](LidarOptions& o) { o.intensity_noise = kNaN; }), "intensity_noise");
  EXPECT_NO_THROW(LidarOptions{}.validate());

  const SyntheticWorld world({});
  LidarOptions bad;
  bad.rings = 0;
  expect_invalid([&] { (void)world.scan(Eigen::Isometry3d::Identity(), bad, 1); }, "rings");
  expect_invalid([&] { (void)world.cast(Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitX(), -1.0); }, "max_range");

  expect_invalid([] { SyntheticWorld({make_box({0, 0, 0}, {1, -1, 1})}); }, "box 0");
  expect_invalid([] { SyntheticWorld({make_box({0, 0, 0}, {1, 1, 1}, 1.5)}); }, "reflectivity");
  expect_invalid([] { SyntheticWorld({}, kNaN); }, "ground_z");
  expect_invalid([] { SyntheticWorld({}, 0.0, -0.1); }, "ground_reflectivity");

  StreetLoopOptions narrow;
  narrow.street_width = 8.0;
  expect_invalid([&] { (void)SyntheticWorld::street_loop(narrow); }, "street_width");
  StreetLoopOptions small;
  small.block_y = 20.0;
  expect_invalid([&] { (void)SyntheticWorld::street_loop(small); }, "block_y");
  expect_invalid([&] { (void)SyntheticWorld::street_loop_trajectory(small, 1.0); }, "block_y");
  expect_invalid([] { (void)SyntheticWorld::street_loop_trajectory({}, 0.0); }, "step");
  expect_invalid([] { (void)SyntheticWorld::street_loop_trajectory({}, -1.0); }, "step");
  expect_invalid([] { (void)SyntheticWorld::street_loop_trajectory({}, kNaN); }, "step");
  expect_invalid([] { (void)SyntheticWorld::street_loop_trajectory({}, 1.0, kInf); }, "sensor_height");
}

}  // namespace
}  // namespace iwlomap
