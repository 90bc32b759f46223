// SPDX-License-Identifier: BSD-3-Clause
// The Amanatides-Woo traversal against a brute-force oracle: for every voxel of the key bounding
// box of a segment, the length of the segment inside the voxel by slab clipping. The fast model's
// line (cast_line()) against the definition of a digital line between the two end voxels.

#include "iwlomap/ray_caster.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace iwlomap {
namespace {

std::int64_t coord(const VoxelKey& k, int axis) { return axis == 0 ? k.x : (axis == 1 ? k.y : k.z); }

std::int64_t l1(const VoxelKey& a, const VoxelKey& b) {
  return std::llabs(coord(a, 0) - coord(b, 0)) + std::llabs(coord(a, 1) - coord(b, 1)) +
         std::llabs(coord(a, 2) - coord(b, 2));
}

std::string str(const VoxelKey& k) {
  std::ostringstream s;
  s << "(" << k.x << ", " << k.y << ", " << k.z << ")";
  return s.str();
}

// Parameter interval [t0, t1] (within [0, 1]) of the segment o + t (e - o) inside the box of voxel
// k grown by `grow` metres on every side. Empty when t1 < t0.
//
// Along an axis where the segment does not move, `half_open_flat` decides membership the way keys
// do (the voxel is [k r, (k + 1) r), so floor(coordinate / r) == k); otherwise the closed, grown
// box is used. Along a moving axis the two only differ on a set of measure zero.
struct Interval {
  double t0;
  double t1;
  [[nodiscard]] bool empty() const { return t1 < t0; }
};

Interval clip(const Eigen::Vector3d& o, const Eigen::Vector3d& e, const VoxelKey& k, double r, double grow,
              bool half_open_flat) {
  double t0 = 0.0;
  double t1 = 1.0;
  for (int i = 0; i < 3; ++i) {
    const double lo = static_cast<double>(coord(k, i)) * r - grow;
    const double hi = static_cast<double>(coord(k, i) + 1) * r + grow;
    const double d = e[i] - o[i];
    if (d == 0.0) {
      const bool inside = half_open_flat ? static_cast<std::int64_t>(std::floor(o[i] / r)) == coord(k, i)
                                         : (o[i] >= lo && o[i] <= hi);
      if (!inside) return {1.0, 0.0};
      continue;
    }
    double ta = (lo - o[i]) / d;
    double tb = (hi - o[i]) / d;
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  return {t0, t1};
}

// Length in metres of the segment inside voxel k (half-open along non-moving axes, see clip()).
double length_in_voxel(const Eigen::Vector3d& o, const Eigen::Vector3d& e, const VoxelKey& k, double r) {
  const Interval iv = clip(o, e, k, r, 0.0, true);
  return iv.empty() ? 0.0 : (iv.t1 - iv.t0) * (e - o).norm();
}

// True when the closed box of voxel k, grown by tol, touches the segment.
bool touches(const Eigen::Vector3d& o, const Eigen::Vector3d& e, const VoxelKey& k, double r, double tol) {
  return !clip(o, e, k, r, tol, false).empty();
}

struct RayCheckOptions {
  bool generic = false;  // also require visited == {voxels with positive length} \ {endpoint voxel}
  double tol_factor = 1e-9;  // tolerances are tol_factor * resolution
};

// Checks every requirement on one ray; returns a failure describing the first violation.
::testing::AssertionResult check_ray(const Eigen::Vector3d& o, const Eigen::Vector3d& e, double r,
                                     const RayCheckOptions& opt = {}) {
  std::ostringstream where;
  where.precision(17);
  where << "ray (" << o.transpose() << ") -> (" << e.transpose() << ") at r = " << r << ": ";

  std::vector<VoxelKey> visited;
  cast_ray(o, e, r, [&visited](const VoxelKey& k) { visited.push_back(k); });
  const std::vector<VoxelKey> computed = compute_ray_keys(o, e, r);
  if (computed != visited) return ::testing::AssertionFailure() << where.str() << "compute_ray_keys differs from cast_ray";

  const VoxelKey ko = world_to_key(o, r);
  const VoxelKey ke = world_to_key(e, r);
  if (ko == ke) {
    if (!visited.empty()) return ::testing::AssertionFailure() << where.str() << "same-voxel ray visited " << visited.size();
    return ::testing::AssertionSuccess();
  }
  if (visited.empty()) return ::testing::AssertionFailure() << where.str() << "nothing visited";
  if (visited.front() != ko)
    return ::testing::AssertionFailure() << where.str() << "starts at " << str(visited.front()) << ", not " << str(ko);
  for (std::size_t i = 1; i < visited.size(); ++i)
    if (l1(visited[i - 1], visited[i]) != 1)
      return ::testing::AssertionFailure() << where.str() << "not 6-connected between " << str(visited[i - 1])
                                           << " and " << str(visited[i]);
  if (l1(visited.back(), ke) != 1)
    return ::testing::AssertionFailure() << where.str() << "last key " << str(visited.back())
                                         << " is not one step from the endpoint key " << str(ke);
  if (static_cast<std::int64_t>(visited.size()) != l1(ko, ke))
    return ::testing::AssertionFailure() << where.str() << "visited " << visited.size() << " keys, expected "
                                         << l1(ko, ke);
  const std::set<VoxelKey> unique(visited.begin(), visited.end());
  if (unique.size() != visited.size()) return ::testing::AssertionFailure() << where.str() << "a key repeats";
  if (unique.count(ke) != 0) return ::testing::AssertionFailure() << where.str() << "the endpoint voxel was visited";

  const double tol = opt.tol_factor * r;
  for (const VoxelKey& k : visited)
    if (!touches(o, e, k, r, tol))
      return ::testing::AssertionFailure() << where.str() << "visited " << str(k) << " does not touch the segment";

  // Brute force over the key bounding box.
  const VoxelKey lo{std::min(ko.x, ke.x), std::min(ko.y, ke.y), std::min(ko.z, ke.z)};
  const VoxelKey hi{std::max(ko.x, ke.x), std::max(ko.y, ke.y), std::max(ko.z, ke.z)};
  std::set<VoxelKey> positive;
  for (std::int32_t x = lo.x; x <= hi.x; ++x) {
    for (std::int32_t y = lo.y; y <= hi.y; ++y) {
      for (std::int32_t z = lo.z; z <= hi.z; ++z) {
        const VoxelKey k{x, y, z};
        if (k == ke) continue;
        const double len = length_in_voxel(o, e, k, r);
        if (len > tol && unique.count(k) == 0)
          return ::testing::AssertionFailure() << where.str() << "voxel " << str(k) << " holds " << len
                                               << " m of the segment but was not visited";
        if (len > 0.0) positive.insert(k);
      }
    }
  }
  if (opt.generic && positive != unique)
    return ::testing::AssertionFailure() << where.str() << "visited " << unique.size() << " voxels, the oracle has "
                                         << positive.size() << " with positive length";
  return ::testing::AssertionSuccess();
}

constexpr std::array<double, 5> kResolutions = {0.05, 0.1, 0.25, 0.3, 1.0};

// ---- hand-checked cases ----------------------------------------------------------------------

TEST(CastRay, VisitsNothingWhenZeroLengthOrSameVoxel) {
  const Eigen::Vector3d o(0.01, -0.02, 0.03);
  EXPECT_TRUE(compute_ray_keys(o, o, 0.05).empty());
  EXPECT_TRUE(compute_ray_keys(o, Eigen::Vector3d(0.049, -0.001, 0.001), 0.05).empty());
  EXPECT_TRUE(check_ray(o, o, 0.05));
}

TEST(CastRay, VisitsOnlyOriginVoxelWhenEndInNeighbour) {
  const auto keys = compute_ray_keys(Eigen::Vector3d(0.04, 0.01, 0.01), Eigen::Vector3d(0.06, 0.01, 0.01), 0.05);
  ASSERT_EQ(keys.size(), 1u);
  EXPECT_EQ(keys[0], (VoxelKey{0, 0, 0}));
}

TEST(CastRay, VisitsRowWhenRayAlongPositiveX) {
  // 0.025 -> 0.525 at 0.05: keys 0..9 visited, endpoint key 10 not.
  const auto keys = compute_ray_keys(Eigen::Vector3d(0.025, 0.025, 0.025), Eigen::Vector3d(0.525, 0.025, 0.025), 0.05);
  ASSERT_EQ(keys.size(), 10u);
  for (int i = 0; i < 10; ++i) EXPECT_EQ(keys[static_cast<std::size_t>(i)], (VoxelKey{i, 0, 0}));
}

TEST(CastRay, VisitsRowWhenRayAlongNegativeAxesAcrossZero) {
  // y from 0.025 down to -0.475 at 0.05: keys 0, -1, ..., -9 visited, endpoint key -10 not.
  const auto ky = compute_ray_keys(Eigen::Vector3d(0.025, 0.025, 0.025), Eigen::Vector3d(0.025, -0.475, 0.025), 0.05);
  ASSERT_EQ(ky.size(), 10u);
  for (int i = 0; i < 10; ++i) EXPECT_EQ(ky[static_cast<std::size_t>(i)], (VoxelKey{0, -i, 0}));
  // z from -0.1 (on the lower face of voxel -1: -0.1 / 0.1 = -1 exactly) down to -0.35 (key -4):
  // keys -1, -2, -3 visited, endpoint key -4 not.
  const auto kz = compute_ray_keys(Eigen::Vector3d(0.05, 0.05, -0.1), Eigen::Vector3d(0.05, 0.05, -0.35), 0.1);
  ASSERT_EQ(kz.size(), 3u);
  EXPECT_EQ(kz[0], (VoxelKey{0, 0, -1}));
  EXPECT_EQ(kz[1], (VoxelKey{0, 0, -2}));
  EXPECT_EQ(kz[2], (VoxelKey{0, 0, -3}));
}

TEST(CastRay, StepsXBeforeYWhenPassingThroughVoxelEdges) {
  // (0.5, 0.5) -> (2.5, 2.5) at 1 m crosses the edges at (1, 1) and (2, 2); at each tie the walk
  // steps x first: (0,0) (1,0) (1,1) (2,1), endpoint (2,2).
  const auto keys = compute_ray_keys(Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::Vector3d(2.5, 2.5, 0.5), 1.0);
  const std::vector<VoxelKey> expected = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {2, 1, 0}};
  EXPECT_EQ(keys, expected);
}

TEST(CastRay, StepsXThenYThenZWhenPassingThroughVoxelCorner) {
  // (0.5, 0.5, 0.5) -> (1.5, 1.5, 1.5) crosses the corner (1, 1, 1): (0,0,0) (1,0,0) (1,1,0), endpoint (1,1,1).
  const auto keys = compute_ray_keys(Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::Vector3d(1.5, 1.5, 1.5), 1.0);
  const std::vector<VoxelKey> expected = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}};
  EXPECT_EQ(keys, expected);
  // Going down through the corner (0, 0, 0): (0,0,0) (-1,0,0) (-1,-1,0), endpoint (-1,-1,-1).
  const auto down = compute_ray_keys(Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::Vector3d(-0.5, -0.5, -0.5), 1.0);
  const std::vector<VoxelKey> expected_down = {{0, 0, 0}, {-1, 0, 0}, {-1, -1, 0}};
  EXPECT_EQ(down, expected_down);
}

TEST(CastRay, StaysInOriginColumnWhenRayLiesInVoxelFace) {
  // y = 0 is the face between y-keys -1 and 0; keys floor, so the ray stays in y = 0.
  const auto keys = compute_ray_keys(Eigen::Vector3d(0.25, 0.0, 0.25), Eigen::Vector3d(1.25, 0.0, 0.25), 0.5);
  const std::vector<VoxelKey> expected = {{0, 0, 0}, {1, 0, 0}};
  EXPECT_EQ(keys, expected);
  EXPECT_TRUE(check_ray(Eigen::Vector3d(0.25, 0.0, 0.25), Eigen::Vector3d(1.25, 0.0, 0.25), 0.5));
}

TEST(CastRay, ArrivesAtEndpointKeyWhenHundredKilometresAway) {
  // Far from the origin the coordinates carry ~1.5e-11 m of rounding; the touch tolerance is
  // widened to 1e-6 * r accordingly.
  RayCheckOptions opt;
  opt.tol_factor = 1e-6;
  opt.generic = true;
  EXPECT_TRUE(check_ray(Eigen::Vector3d(100000.0123, -100000.0271, 50.013),
                        Eigen::Vector3d(100000.8377, -99999.5219, 49.1031), 0.05, opt));
  EXPECT_TRUE(check_ray(Eigen::Vector3d(-100000.0123, 100000.0271, -50.013),
                        Eigen::Vector3d(-100001.8377, 99999.5219, -49.1031), 0.05, opt));
}

// ---- randomised against the oracle -----------------------------------------------------------

TEST(CastRay, MatchesOracleWhenGenericRandomRays) {
  std::mt19937 rng(20240611u);
  std::uniform_real_distribution<double> pos(-3.0, 3.0);
  std::uniform_real_distribution<double> offset(-12.0, 12.0);  // in voxels
  std::uniform_int_distribution<std::size_t> pick_res(0, kResolutions.size() - 1);
  RayCheckOptions opt;
  opt.generic = true;
  int failures = 0;
  for (int i = 0; i < 6000 && failures < 5; ++i) {
    const double r = kResolutions[pick_res(rng)];
    const Eigen::Vector3d o(pos(rng), pos(rng), pos(rng));
    const Eigen::Vector3d e = o + r * Eigen::Vector3d(offset(rng), offset(rng), offset(rng));
    const auto res = check_ray(o, e, r, opt);
    if (!res) ++failures;
    EXPECT_TRUE(res);
  }
}

TEST(CastRay, MatchesOracleWhenRaysRunAlongAxes) {
  std::mt19937 rng(77u);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> cell(-8, 7);
  std::uniform_int_distribution<int> steps(-15, 15);
  std::uniform_int_distribution<int> axis_dist(0, 2);
  std::uniform_int_distribution<std::size_t> pick_res(0, kResolutions.size() - 1);
  int failures = 0;
  for (int i = 0; i < 2400 && failures < 5; ++i) {
    const double r = kResolutions[pick_res(rng)];
    const int axis = axis_dist(rng);
    // Each coordinate either strictly inside a voxel or exactly on a voxel boundary, so some rays
    // lie in voxel faces or run along voxel edges.
    Eigen::Vector3d o;
    for (int a = 0; a < 3; ++a) o[a] = (cell(rng) + (unit(rng) < 0.5 ? 0.0 : unit(rng))) * r;
    Eigen::Vector3d e = o;
    // End either on a boundary or inside a voxel, up to 15 voxels away, in either direction.
    e[axis] = o[axis] + (steps(rng) + (unit(rng) < 0.5 ? 0.0 : unit(rng) - 0.5)) * r;
    const auto res = check_ray(o, e, r);
    if (!res) ++failures;
    EXPECT_TRUE(res);
  }
}

TEST(CastRay, MatchesOracleWhenRaysPassThroughVoxelCornersAndEdges) {
  std::mt19937 rng(4242u);
  std::uniform_int_distribution<int> cell(-6, 6);
  std::uniform_int_distribution<int> dir(-5, 5);
  std::uniform_int_distribution<int> scale_pick(0, 3);
  std::uniform_int_distribution<std::size_t> pick_res(0, kResolutions.size() - 1);
  const double scales[] = {0.5, 1.0, 1.5, 2.0};
  int failures = 0;
  int rays = 0;
  while (rays < 2400 && failures < 5) {
    const double r = kResolutions[pick_res(rng)];
    // Origin on a voxel corner; the direction is a grid vector, so the segment passes through
    // corners and edges (diagonals such as (n, n, n), (n, -n, 0), (2n, n, 0)).
    const Eigen::Vector3d o(cell(rng) * r, cell(rng) * r, cell(rng) * r);
    const Eigen::Vector3d d(dir(rng), dir(rng), dir(rng));
    if (d.isZero()) continue;
    const Eigen::Vector3d e = o + scales[scale_pick(rng)] * r * d;
    const auto res = check_ray(o, e, r);
    if (!res) ++failures;
    EXPECT_TRUE(res);
    ++rays;
  }
}

TEST(CastRay, VisitsNothingWhenRandomRaysEndInOriginVoxel) {
  std::mt19937 rng(9u);
  std::uniform_int_distribution<int> cell(-50, 50);
  std::uniform_real_distribution<double> inside(0.001, 0.999);
  std::uniform_int_distribution<std::size_t> pick_res(0, kResolutions.size() - 1);
  for (int i = 0; i < 500; ++i) {
    const double r = kResolutions[pick_res(rng)];
    const VoxelKey k{cell(rng), cell(rng), cell(rng)};
    const Eigen::Vector3d o((k.x + inside(rng)) * r, (k.y + inside(rng)) * r, (k.z + inside(rng)) * r);
    const Eigen::Vector3d e = i % 5 == 0 ? o : Eigen::Vector3d((k.x + inside(rng)) * r, (k.y + inside(rng)) * r,
                                                               (k.z + inside(rng)) * r);
    ASSERT_EQ(world_to_key(o, r), k);
    ASSERT_EQ(world_to_key(e, r), k);
    EXPECT_TRUE(compute_ray_keys(o, e, r).empty());
    EXPECT_TRUE(check_ray(o, e, r));
  }
}

// The oracle itself must be able to fail: a walk that skipped a voxel would be caught.
TEST(RayOracle, ReportsPositiveLengthWhenSegmentCrossesVoxel) {
  const Eigen::Vector3d o(0.5, 0.5, 0.5);
  const Eigen::Vector3d e(2.5, 0.75, 0.5);
  // The segment runs x 0.5 -> 2.5 at y in [0.5, 0.75]: voxel (1,0,0) holds x in [1, 2], length ~1.0008.
  EXPECT_NEAR(length_in_voxel(o, e, VoxelKey{1, 0, 0}, 1.0), std::sqrt(1.0 + 0.125 * 0.125), 1e-12);
  EXPECT_EQ(length_in_voxel(o, e, VoxelKey{1, 1, 0}, 1.0), 0.0);
  EXPECT_FALSE(touches(o, e, VoxelKey{0, 2, 0}, 1.0, 1e-9));
  EXPECT_FALSE(touches(o, e, VoxelKey{0, 0, 1}, 1.0, 1e-9));
  // Touching only at the corner (1, 1) of a diagonal counts as touching, with zero length.
  const Eigen::Vector3d d0(0.5, 0.5, 0.5);
  const Eigen::Vector3d d1(1.5, 1.5, 0.5);
  EXPECT_TRUE(touches(d0, d1, VoxelKey{1, 0, 0}, 1.0, 1e-9));
  EXPECT_EQ(length_in_voxel(d0, d1, VoxelKey{1, 0, 0}, 1.0), 0.0);
}

// ---- the fast ray model: cast_line() -----------------------------------------------------------

std::vector<VoxelKey> line_keys(const Eigen::Vector3d& o, const Eigen::Vector3d& e, double r) {
  std::vector<VoxelKey> keys;
  cast_line(o, e, r, [&keys](const VoxelKey& k) { keys.push_back(k); });
  return keys;
}

std::int64_t chebyshev(const VoxelKey& a, const VoxelKey& b) {
  std::int64_t d = 0;
  for (int axis = 0; axis < 3; ++axis) d = std::max<std::int64_t>(d, std::llabs(coord(a, axis) - coord(b, axis)));
  return d;
}

// The line from key a to key b, by definition: at step s of n = max |b - a| along the axes, each
// axis at a + (b - a) s / n rounded to the nearest key, a tie going towards a.
VoxelKey line_point(const VoxelKey& a, const VoxelKey& b, std::int64_t s, std::int64_t n) {
  std::int64_t c[3];
  for (int axis = 0; axis < 3; ++axis) {
    const std::int64_t from = coord(a, axis), d = coord(b, axis) - from;
    // from + round(d s / n), ties towards 0 (towards a): exact in integers.
    const std::int64_t num = 2 * std::llabs(d) * s, den = 2 * n;
    const std::int64_t q = num / den, rem = num - q * den;
    const std::int64_t rounded = q + (2 * rem > den ? 1 : 0);
    c[axis] = from + (d < 0 ? -rounded : rounded);
  }
  return VoxelKey{static_cast<std::int32_t>(c[0]), static_cast<std::int32_t>(c[1]), static_cast<std::int32_t>(c[2])};
}

TEST(CastLine, VisitsTheDigitalLineBetweenTheEndVoxelsWhenRaysAreRandom) {
  std::mt19937 rng(20261128u);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::uniform_int_distribution<std::size_t> pick_res(0, kResolutions.size() - 1);
  std::uniform_int_distribution<int> pick_kind(0, 3);
  std::size_t visited = 0;
  for (int i = 0; i < 4000; ++i) {
    const double r = kResolutions[pick_res(rng)];
    const Eigen::Vector3d o = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 40.0;
    Eigen::Vector3d d = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 10.0;
    const int kind = pick_kind(rng);
    if (kind == 1) d[i % 3] = 0.0;                // in a plane
    if (kind == 2) d = Eigen::Vector3d::Constant(d.x());  // a main diagonal
    const Eigen::Vector3d e = o + d;
    const VoxelKey a = world_to_key(o, r), b = world_to_key(e, r);
    const std::int64_t n = chebyshev(a, b);
    const std::vector<VoxelKey> keys = line_keys(o, e, r);
    ASSERT_EQ(static_cast<std::int64_t>(keys.size()), n) << "ray " << i;
    for (std::int64_t s = 0; s < n; ++s)
      ASSERT_EQ(keys[static_cast<std::size_t>(s)], line_point(a, b, s, n)) << "ray " << i << " step " << s;
    visited += keys.size();
  }
  EXPECT_GT(visited, 100000u);
}

TEST(CastLine, StepsAlongEveryAxisAtOnceWhenRayRunsAlongTheMainDiagonal) {
  // From voxel (0,0,0) to voxel (3,3,3) at 1 m: (0,0,0) (1,1,1) (2,2,2); the exact walk takes 9
  // voxels between the same ends.
  const Eigen::Vector3d o(0.5, 0.5, 0.5), e(3.5, 3.5, 3.5);
  const std::vector<VoxelKey> expected = {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}};
  EXPECT_EQ(line_keys(o, e, 1.0), expected);
  EXPECT_EQ(compute_ray_keys(o, e, 1.0).size(), 9u);
  // cast_ray() with a model calls the walk of that model.
  std::vector<VoxelKey> fast, exact;
  cast_ray(o, e, 1.0, RayModel::kFast, [&](const VoxelKey& k) { fast.push_back(k); });
  cast_ray(o, e, 1.0, RayModel::kExact, [&](const VoxelKey& k) { exact.push_back(k); });
  EXPECT_EQ(fast, expected);
  EXPECT_EQ(exact, compute_ray_keys(o, e, 1.0));
}

TEST(CastLine, EqualsTheExactWalkWhenRaysRunAlongAnAxis) {
  std::mt19937 rng(7u);
  std::uniform_real_distribution<double> u(-20.0, 20.0);
  for (int i = 0; i < 300; ++i) {
    const double r = kResolutions[static_cast<std::size_t>(i) % kResolutions.size()];
    const Eigen::Vector3d o(u(rng), u(rng), u(rng));
    Eigen::Vector3d e = o;
    e[i % 3] += u(rng);
    EXPECT_EQ(line_keys(o, e, r), compute_ray_keys(o, e, r)) << "ray " << i;
  }
}

TEST(CastLine, VisitsNothingWhenTheEndIsInTheOriginVoxel) {
  const Eigen::Vector3d o(0.01, -0.02, 0.03);
  EXPECT_TRUE(line_keys(o, o, 0.05).empty());
  EXPECT_TRUE(line_keys(o, Eigen::Vector3d(0.049, -0.001, 0.001), 0.05).empty());
  // The end in a corner neighbour: the origin's voxel only.
  const std::vector<VoxelKey> one = {{0, -1, 0}};
  EXPECT_EQ(line_keys(o, Eigen::Vector3d(0.06, -0.06, 0.06), 0.05), one);
}

TEST(CastLine, ArrivesNextToTheEndKeyWhenHundredKilometresAway) {
  const Eigen::Vector3d o(100000.0123, -100000.0271, 50.013), e(99990.8377, -99993.5219, 49.1031);
  const std::vector<VoxelKey> keys = line_keys(o, e, 0.05);
  const VoxelKey a = world_to_key(o, 0.05), b = world_to_key(e, 0.05);
  ASSERT_EQ(static_cast<std::int64_t>(keys.size()), chebyshev(a, b));
  EXPECT_EQ(keys.front(), a);
  EXPECT_EQ(chebyshev(keys.back(), b), 1);
  for (std::size_t i = 1; i < keys.size(); ++i) ASSERT_EQ(chebyshev(keys[i - 1], keys[i]), 1);
}

TEST(RayModelNames, ReadBackWhatTheyPrint) {
  for (const RayModel m : {RayModel::kExact, RayModel::kFast}) EXPECT_EQ(parse_ray_model(ray_model_name(m)), m);
  EXPECT_STREQ(ray_model_name(RayModel::kExact), "exact");
  EXPECT_STREQ(ray_model_name(RayModel::kFast), "fast");
  EXPECT_FALSE(parse_ray_model("Fast").has_value());
  EXPECT_FALSE(parse_ray_model("").has_value());
  EXPECT_FALSE(parse_ray_model("exact ").has_value());
}

}  // namespace
}  // namespace iwlomap
