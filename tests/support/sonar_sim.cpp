// SPDX-License-Identifier: BSD-3-Clause
#include "sonar_sim.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

namespace iwlomap::bench {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kFloorReflectivity = 0.45;
// The seafloor's height in the map frame: off the planes between voxel layers (at 0.1, 0.05 or
// 0.2 m voxels), so the floor's truth voxels form one layer instead of two layers picked by
// rounding noise. Every height below is relative to it.
constexpr double kFloorZ = -0.37;

struct Hit {
  double t = std::numeric_limits<double>::infinity();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  double reflectivity = 0.0;
};

struct Box {
  Eigen::Vector3d lo, hi;
  double reflectivity;
};
struct Sphere {
  Eigen::Vector3d centre;
  double radius, reflectivity;
};
// Axis-aligned cylinders: a pipeline along y (lying) and a pile along z (standing on the floor).
struct LyingCylinder {
  double x, z, radius, y0, y1, reflectivity;
};
struct StandingCylinder {
  double x, y, radius, height, reflectivity;
};

// The scene is fixed: the benchmark's figures refer to exactly these objects.
const Box kBoxes[] = {{{8.0, 0.5, kFloorZ}, {10.0, 1.5, kFloorZ + 1.0}, 0.9},
                      {{17.0, -2.5, kFloorZ}, {18.0, -1.5, kFloorZ + 0.5}, 0.8}};
const Sphere kBoulder{{13.0, -0.5, kFloorZ + 0.2}, 0.6, 0.7};
const LyingCylinder kPipeline{22.0, kFloorZ + 0.15, 0.3, -5.0, 5.0, 0.85};
const StandingCylinder kPile{5.0, -2.0, 0.3, 2.0, 0.9};

void keep(Hit& best, double t, const Eigen::Vector3d& n, double reflectivity) {
  if (t > 1e-9 && t < best.t) {
    best.t = t;
    best.normal = n;
    best.reflectivity = reflectivity;
  }
}

void hit_box(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Box& b, Hit& best) {
  double t0 = 0.0, t1 = std::numeric_limits<double>::infinity();
  int axis = -1;
  for (int i = 0; i < 3; ++i) {
    if (std::abs(d[i]) < 1e-12) {
      if (o[i] < b.lo[i] || o[i] > b.hi[i]) return;
      continue;
    }
    double a = (b.lo[i] - o[i]) / d[i], c = (b.hi[i] - o[i]) / d[i];
    if (a > c) std::swap(a, c);
    if (a > t0) {
      t0 = a;
      axis = i;
    }
    t1 = std::min(t1, c);
    if (t0 > t1) return;
  }
  if (axis < 0) return;
  Eigen::Vector3d n = Eigen::Vector3d::Zero();
  n[axis] = d[axis] > 0 ? -1.0 : 1.0;
  keep(best, t0, n, b.reflectivity);
}

void hit_sphere(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Sphere& s, Hit& best) {
  const Eigen::Vector3d oc = o - s.centre;
  const double b = oc.dot(d), c = oc.squaredNorm() - s.radius * s.radius;
  const double disc = b * b - c;
  if (disc < 0.0) return;
  const double t = -b - std::sqrt(disc);
  keep(best, t, (o + t * d - s.centre) / s.radius, s.reflectivity);
}

// Nearest root of a 2D circle intersection (u, v) = (ou + t du, ov + t dv), |(u, v) - c| = r.
double circle_entry(double ou, double ov, double du, double dv, double cu, double cv, double r) {
  const double a = du * du + dv * dv;
  if (a < 1e-18) return -1.0;
  const double pu = ou - cu, pv = ov - cv;
  const double b = pu * du + pv * dv, c = pu * pu + pv * pv - r * r;
  const double disc = b * b - a * c;
  if (disc < 0.0) return -1.0;
  return (-b - std::sqrt(disc)) / a;
}

// A standing cylinder on a floor at height base (its top is a disc).
void hit_standing(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const StandingCylinder& c, double base,
                  Hit& best) {
  const double t = circle_entry(o.x(), o.y(), d.x(), d.y(), c.x, c.y, c.radius);
  const Eigen::Vector3d p = o + t * d;
  if (t > 0.0 && p.z() >= base && p.z() <= base + c.height)
    keep(best, t, Eigen::Vector3d(p.x() - c.x, p.y() - c.y, 0.0) / c.radius, c.reflectivity);
  if (d.z() < 0.0) {
    const double tc = (base + c.height - o.z()) / d.z();
    const Eigen::Vector3d q = o + tc * d;
    if (std::hypot(q.x() - c.x, q.y() - c.y) <= c.radius) keep(best, tc, Eigen::Vector3d::UnitZ(), c.reflectivity);
  }
}

// The seafloor's reflectivity at x: sand, and from x = 14 m on the second seabed type.
double floor_reflectivity(double x, const SonarSimOptions& o) {
  return x >= 14.0 && o.second_floor_reflectivity >= 0.0 ? o.second_floor_reflectivity : kFloorReflectivity;
}

// Scene kObjects: a flat floor and five objects.
void hit_objects(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const SonarSimOptions& options, Hit& best) {
  if (d.z() < 0.0) {
    const double t = (kFloorZ - o.z()) / d.z();
    keep(best, t, Eigen::Vector3d::UnitZ(), floor_reflectivity(o.x() + t * d.x(), options));
  }
  for (const Box& b : kBoxes) hit_box(o, d, b, best);
  hit_sphere(o, d, kBoulder, best);
  {
    const LyingCylinder& c = kPipeline;
    const double t = circle_entry(o.x(), o.z(), d.x(), d.z(), c.x, c.z, c.radius);
    const Eigen::Vector3d p = o + t * d;
    if (t > 0.0 && p.y() >= c.y0 && p.y() <= c.y1)
      keep(best, t, Eigen::Vector3d(p.x() - c.x, 0.0, p.z() - c.z) / c.radius, c.reflectivity);
  }
  hit_standing(o, d, kPile, kFloorZ, best);
}

// Scene kPilings: a floor sloping up along +x (kSlope, through kFloorZ at x = 12 m), two rows of
// pier pilings (radius 0.25 m, 4 m tall, every 4 m along x at y = +-3.5 m) and a quay wall across
// the end of the survey (x = 31 m).
constexpr double kSlope = 0.05;
double sloped_floor(double x) { return kFloorZ + kSlope * (x - 12.0); }

void hit_pilings(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const SonarSimOptions& options, Hit& best) {
  // The floor z = kFloorZ + kSlope (x - 12): along the ray, its height above the floor falls at
  // the rate d.z - kSlope d.x.
  const double rate = d.z() - kSlope * d.x();
  if (rate < 0.0) {
    const double t = (sloped_floor(o.x()) - o.z()) / rate;
    keep(best, t, Eigen::Vector3d(-kSlope, 0.0, 1.0).normalized(), floor_reflectivity(o.x() + t * d.x(), options));
  }
  for (int k = 0; k < 8; ++k)
    for (const double y : {-3.5, 3.5}) {
      const StandingCylinder c{-1.0 + 4.0 * k, y, 0.25, 4.0, 0.85};
      hit_standing(o, d, c, sloped_floor(c.x) - 0.5, best);
    }
  hit_box(o, d, Box{{31.0, -10.0, sloped_floor(31.0) - 1.0}, {32.0, 10.0, kFloorZ + 8.0}, 0.8}, best);
}

void hit_scene(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const SonarSimOptions& options, Hit& best) {
  if (options.scene == SonarScene::kPilings)
    hit_pilings(o, d, options, best);
  else
    hit_objects(o, d, options, best);
}

// Seeded noise from mt19937, whose output sequence the standard fixes (the standard's
// distributions are implementation-defined, so they are written out here).
class Rng {
 public:
  explicit Rng(std::uint32_t seed) : gen_(seed) {}
  double uniform() { return (static_cast<double>(gen_()) + 0.5) / 4294967296.0; }  // (0, 1)
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  double normal() { return std::sqrt(-2.0 * std::log(uniform())) * std::cos(2.0 * kPi * uniform()); }
  int integer(int lo, int hi) { return std::min(hi, lo + static_cast<int>(uniform() * (hi - lo + 1))); }
  double rayleigh(double scale) { return scale * std::sqrt(-2.0 * std::log(uniform())); }
  // Gamma(L, 1/L) for integer L: the mean of L unit exponentials.
  double speckle(int looks) {
    double s = 0.0;
    for (int i = 0; i < looks; ++i) s -= std::log(uniform());
    return s / looks;
  }
  int poisson(double mean) {
    const double limit = std::exp(-mean);
    int k = 0;
    for (double p = uniform(); p > limit; p *= uniform()) ++k;
    return k;
  }

 private:
  std::mt19937 gen_;
};

}  // namespace

SonarNoise light_noise() {
  SonarNoise n;
  n.name = "light";
  n.speckle_looks = 4;
  n.noise_floor = 6.0;
  n.multipath_gain = 0.2;
  n.sidelobe_gain = 0.03;
  n.clutter_per_ping = 2.0;
  return n;
}

SonarNoise heavy_noise() {
  SonarNoise n;
  n.name = "heavy";
  n.speckle_looks = 1;
  n.noise_floor = 9.0;
  n.multipath_gain = 0.5;
  n.sidelobe_gain = 0.15;
  n.clutter_per_ping = 15.0;
  return n;
}

SonarSimulation simulate_sonar_survey(const SonarSimOptions& o) {
  if (o.beams < 1 || o.legs < 1 || o.range_bins < 1 || o.elevation_rays < 1 || !(o.range_resolution > 0.0) ||
      !(o.ping_spacing > 0.0) || !(o.resolution > 0.0) || !(o.drift >= 0.0) || !std::isfinite(o.tvg_error_db_per_m) ||
      !std::isfinite(o.gain_change_db) || !(o.second_floor_reflectivity <= 1.0))
    throw std::invalid_argument("sonar simulation: beams, legs, range_bins, elevation_rays, range_resolution, "
                                "ping_spacing and resolution must be > 0, drift >= 0, gains finite, "
                                "second_floor_reflectivity <= 1");
  SonarSimulation sim;
  SonarGeometry& g = sim.geometry;
  const double fov = o.horizontal_fov_deg * kPi / 180.0;
  for (int b = 0; b < o.beams; ++b)
    g.bearings.push_back(o.beams == 1 ? 0.0 : -0.5 * fov + fov * b / (o.beams - 1));
  g.range_resolution = o.range_resolution;
  g.min_range = 0.0;
  g.max_range = o.range_bins * o.range_resolution;
  g.vertical_aperture = o.vertical_aperture_deg * kPi / 180.0;

  std::vector<Eigen::Vector2d> elevation;  // (cos e, sin e) of every rendered ray
  for (int j = 0; j < o.elevation_rays; ++j) {
    const double e = -0.5 * g.vertical_aperture + g.vertical_aperture * (j + 0.5) / o.elevation_rays;
    elevation.emplace_back(std::cos(e), std::sin(e));
  }
  // Map frame +z up; sonar frame +Z down: the level sonar heading +x has X = x, Y = -y, Z = -z.
  const Eigen::Matrix3d level = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();
  // Nose down is a negative rotation about the sonar's +Y (right) axis.
  const Eigen::Matrix3d pitch(Eigen::AngleAxisd(-o.pitch_deg * kPi / 180.0, Eigen::Vector3d::UnitY()));

  Rng rng(o.seed);
  // The drift has its own generator, so a survey with drift has the same images as without.
  Rng nav_rng(o.seed ^ 0x9e3779b9u);
  const double start_direction = nav_rng.uniform(0.0, 2.0 * kPi);
  Eigen::Vector2d velocity_error = o.drift * Eigen::Vector2d(std::cos(start_direction), std::sin(start_direction));
  Eigen::Vector2d position_error = Eigen::Vector2d::Zero();
  double heading_error = 0.0;
  Eigen::Vector3d last_position = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  const SonarNoise& noise = o.noise;
  const double max_range = g.max_range;
  Eigen::MatrixXf echo(o.range_bins, o.beams), ghost(o.range_bins, o.beams);
  for (int run = 0; run < o.legs; ++run) {
    const int leg = run % 2;
    const double heading = leg == 0 ? 0.0 : kPi;
    const Eigen::Matrix3d rot = Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ()).toRotationMatrix() * level * pitch;
    const double length = o.leg_end_x - o.leg_start_x;
    const int n_pings = static_cast<int>(std::floor(length / o.ping_spacing)) + 1;
    for (int k = 0; k < n_pings; ++k) {
      const double along = k * o.ping_spacing;
      const double x = leg == 0 ? o.leg_start_x + along : o.leg_end_x - along;
      SimulatedPing ping;
      ping.pose = Eigen::Isometry3d::Identity();
      ping.pose.linear() = rot;
      ping.pose.translation() =
          Eigen::Vector3d(x, o.leg_y[leg], (o.scene == SonarScene::kPilings ? sloped_floor(x) : kFloorZ) + o.altitude);
      const Eigen::Vector3d origin = ping.pose.translation();
      if (o.drift > 0.0 && last_position.allFinite()) {
        const double travelled = (origin - last_position).norm();
        const double root = std::sqrt(travelled);
        velocity_error += o.drift / std::sqrt(50.0) * root * Eigen::Vector2d(nav_rng.normal(), nav_rng.normal());
        position_error += travelled * velocity_error;
        heading_error += 5.0 * kPi / 180.0 * o.drift * root * nav_rng.normal();
      }
      last_position = origin;
      ping.nav_pose = ping.pose;
      ping.nav_pose.linear() = Eigen::AngleAxisd(heading_error, Eigen::Vector3d::UnitZ()).toRotationMatrix() * rot;
      ping.nav_pose.translation().head<2>() += position_error;

      echo.setZero();
      ghost.setZero();
      std::vector<int> clean_first(static_cast<std::size_t>(o.beams), -1);
      for (int b = 0; b < o.beams; ++b) {
        const double bearing = g.bearings[static_cast<std::size_t>(b)];
        const Eigen::Vector3d ahead = rot * Eigen::Vector3d(std::cos(bearing), std::sin(bearing), 0.0);
        const Eigen::Vector3d down = rot.col(2);
        std::vector<std::pair<double, Eigen::Vector3d>> hits;
        hits.reserve(elevation.size());
        double nearest = std::numeric_limits<double>::infinity();
        for (const Eigen::Vector2d& ce : elevation) {
          const Eigen::Vector3d d = ce[0] * ahead + ce[1] * down;
          Hit hit;
          hit_scene(origin, d, o, hit);
          if (!(hit.t < max_range)) continue;
          const Eigen::Vector3d p = origin + hit.t * d;
          const double amplitude = 255.0 * hit.reflectivity * std::abs(d.dot(hit.normal));
          const int bin = std::min(o.range_bins - 1, static_cast<int>(hit.t / o.range_resolution));
          echo(bin, b) = std::max(echo(bin, b), static_cast<float>(amplitude));
          // The sea-surface bounce: half the path to the mirrored point and back.
          const Eigen::Vector3d mirrored(p.x(), p.y(), 2.0 * (kFloorZ + o.surface_height) - p.z());
          const double ghost_range = 0.5 * (hit.t + (mirrored - origin).norm());
          const int ghost_bin = static_cast<int>(ghost_range / o.range_resolution);
          if (ghost_bin < o.range_bins)
            ghost(ghost_bin, b) = std::max(ghost(ghost_bin, b), static_cast<float>(noise.multipath_gain * amplitude));
          hits.emplace_back(hit.t, p);
          nearest = std::min(nearest, hit.t);
          sim.visible_truth.insert(world_to_key(p, o.resolution));
        }
        for (const auto& [t, p] : hits)
          if (t <= nearest + o.truth_band) sim.footprint_truth.insert(world_to_key(p, o.resolution));
        if (std::isfinite(nearest)) clean_first[static_cast<std::size_t>(b)] = static_cast<int>(nearest / o.range_resolution);
      }

      // Echoes, their ghosts and the sidelobe leakage of the neighbouring beams add up (incoherent
      // intensities); speckle multiplies the sum, the noise floor and the clutter add to it.
      Eigen::MatrixXf image = echo + ghost;
      if (noise.sidelobe_gain > 0.0) {
        for (int b = 0; b < o.beams; ++b)
          for (int nb = std::max(0, b - 2); nb <= std::min(o.beams - 1, b + 2); ++nb)
            if (nb != b) image.col(b) += static_cast<float>(noise.sidelobe_gain) * echo.col(nb);
      }
      for (int b = 0; b < o.beams; ++b)
        for (int r = 0; r < o.range_bins; ++r) {
          float& v = image(r, b);
          if (noise.speckle_looks > 0 && v > 0.0f) v *= static_cast<float>(rng.speckle(noise.speckle_looks));
          if (noise.noise_floor > 0.0) v += static_cast<float>(rng.rayleigh(noise.noise_floor));
        }
      const int blobs = noise.clutter_per_ping > 0.0 ? rng.poisson(noise.clutter_per_ping) : 0;
      for (int i = 0; i < blobs; ++i) {
        const int b0 = rng.integer(0, o.beams - 1), width = rng.integer(1, 4);
        const int r0 = static_cast<int>(rng.uniform(1.0, max_range) / o.range_resolution), len = rng.integer(2, 8);
        const double strength = rng.uniform(40.0, 160.0);
        for (int b = b0; b < std::min(o.beams, b0 + width); ++b)
          for (int r = r0; r < std::min(o.range_bins, r0 + len); ++r)
            image(r, b) += static_cast<float>(strength * (noise.speckle_looks > 0 ? rng.speckle(noise.speckle_looks) : 1.0));
      }
      // Receiver gain errors act on everything the receiver records: a time-varied-gain error
      // that grows with range (dB per metre about mid-range) and a gain change on the second leg.
      if (o.tvg_error_db_per_m != 0.0 || (leg == 1 && o.gain_change_db != 0.0)) {
        const double leg_db = leg == 1 ? o.gain_change_db : 0.0;
        for (int r = 0; r < o.range_bins; ++r) {
          const double range = (r + 0.5) * o.range_resolution;
          const double db = leg_db + o.tvg_error_db_per_m * (range - 0.5 * max_range);
          image.row(r) *= static_cast<float>(std::pow(10.0, db / 20.0));
        }
      }
      ping.image = image.array().round().min(255.0f).max(0.0f).cast<std::uint8_t>();

      for (int b = 0; b < o.beams; ++b) {
        const int truth = clean_first[static_cast<std::size_t>(b)];
        int seen = -1;
        for (int r = 0; r < o.range_bins; ++r)
          if (ping.image(r, b) > o.echo_threshold) {
            seen = r;
            break;
          }
        ++sim.beams;
        if (seen >= 0 && (truth < 0 || seen < truth - 2)) ++sim.early_returns;
        else if (truth >= 0 && (seen < 0 || seen > truth + 2)) ++sim.late_returns;
      }
      sim.pings.push_back(std::move(ping));
    }
  }
  return sim;
}

}  // namespace iwlomap::bench
