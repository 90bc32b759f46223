// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// A synthetic forward-looking imaging sonar with known ground truth, shared by the sonar accuracy
// benchmark (bench_sonar_accuracy) and the sonar tests (the iwlomap_sonar_sim library of
// tests/support). Eigen and the standard library only.
//
// Scene kObjects (map frame, metres, +z up): a flat seafloor at z = -0.37 (off the voxel layer
// planes) and five objects standing on it or partly buried: a container-sized box (2 x 1 x 1 m), a low box,
// a boulder (sphere), a pipeline (horizontal cylinder across the survey) and a pile (vertical
// cylinder, 2 m high). The sea surface is `surface_height` above the floor. Scene kPilings: see
// SonarScene.
//
// Sensor: `beams` beams over `horizontal_fov_deg`, each a vertical fan of `vertical_aperture_deg`
// rendered with `elevation_rays` rays; `range_bins` bins of `range_resolution`. The sonar flies a
// two-leg lawnmower survey at `altitude`, pitched down by `pitch_deg`, pinging every
// `ping_spacing` metres. A pixel's clean intensity is the strongest echo in its bin,
// 255 * reflectivity * cos(incidence angle) (Lambertian-like), which is what a TVG-compensated
// 8-bit image shows.
//
// Noise and artefacts, all seeded:
// - speckle: the clean intensity times a Gamma(L, 1/L) variate (mean 1; L = 1 is fully developed
//   speckle, an exponential: the heaviest);
// - noise floor: Rayleigh-distributed amplitude of scale `noise_floor` added to every pixel;
// - multipath: each echo reappears with `multipath_gain` at the range of the path bounced off
//   the sea surface ((direct + mirrored) / 2), in the same beam;
// - sidelobes: each beam leaks `sidelobe_gain` of its two neighbours' echoes on each side (a
//   bright target smears across bearing);
// - clutter: `clutter_per_ping` transient targets in the water column per ping on average (fish,
//   bubbles): blobs of 1-4 beams x 2-8 bins of intensity 40-160 at random ranges.
//
// Ground truth: every ray's noise-free hit is a surface point the sonar ensonified ("visible").
// The first-return model of SonarImageProjector can only ever claim, per beam and ping, the
// surface at the beam's nearest hit range (plus its occupied band); those hits, within
// `truth_band` of the nearest one, form the "footprint" truth the benchmark scores against. Both
// sets are voxel keys at the benchmark's resolution.

#include <iwlomap/sonar_image_projector.h>
#include <iwlomap/voxel_key.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <string>
#include <unordered_set>
#include <vector>

namespace iwlomap::bench {

struct SonarNoise {
  std::string name = "none";
  int speckle_looks = 0;         ///< 0: no speckle; else L of the Gamma(L, 1/L) multiplier
  double noise_floor = 0.0;      ///< Rayleigh scale of the additive noise (raw units)
  double multipath_gain = 0.0;   ///< amplitude of the sea-surface ghost relative to the echo
  double sidelobe_gain = 0.0;    ///< leakage of the neighbouring beams' echoes
  double clutter_per_ping = 0.0; ///< mean number of water-column clutter blobs per ping
};

/// Light noise: some speckle averaging (4 looks), a low noise floor, rare clutter.
[[nodiscard]] SonarNoise light_noise();
/// Heavy noise: fully developed speckle (1 look), a noise floor that crosses the threshold,
/// strong multipath and sidelobes, frequent clutter.
[[nodiscard]] SonarNoise heavy_noise();

/// The scene surveyed.
enum class SonarScene {
  kObjects,  ///< flat floor, two boxes, a boulder, a pipeline, a pile (the header comment)
  kPilings,  ///< a floor sloping up 5 % along +x, two rows of pier pilings at y = +-3.5 m
             ///< (every 4 m, radius 0.25 m, 4 m tall) and a quay wall across x = 31 m
};

struct SonarSimOptions {
  SonarScene scene = SonarScene::kObjects;
  int beams = 128;
  double horizontal_fov_deg = 90.0;
  double vertical_aperture_deg = 20.0;
  int elevation_rays = 256;
  int range_bins = 500;
  double range_resolution = 0.025;  ///< 12.5 m of range
  double altitude = 3.0;            ///< sonar height above the seafloor, metres
  double pitch_deg = 25.0;          ///< the fan's centre line points this far below horizontal
  double surface_height = 12.0;     ///< sea surface above the seafloor, metres (multipath)
  double ping_spacing = 0.1;        ///< metres between pings along a leg
  double leg_start_x = -4.0, leg_end_x = 28.0;
  double leg_y[2] = {1.5, -1.5};    ///< the two legs: +x at leg_y[0], back along -x at leg_y[1]
  /// Legs run in all (>= 1): leg k runs as leg k % 2, so 3 repeats the first leg with its heading
  /// after the return leg (a survey that revisits its own lines, as loop closure needs).
  int legs = 2;
  double resolution = 0.1;          ///< voxel edge of the truth sets
  double truth_band = 0.1;          ///< footprint: hits within this of the beam's nearest hit
  double echo_threshold = 35.0;     ///< for the early/late return statistics only
  /// Navigation drift of the dead reckoning that gives SimulatedPing::nav_pose, as a fraction of
  /// the distance travelled (0: nav_pose = pose). The velocity error (metres of position error per
  /// metre travelled) starts at this magnitude in a random direction and random-walks by
  /// drift / sqrt(50 m) per axis; the heading error random-walks by 5 degrees x drift per
  /// sqrt(metre). Depth, roll and pitch stay true (a pressure sensor and the gravity vector
  /// observe them). With 0.01 over the 64 m survey the position error ends near 0.6 m.
  double drift = 0.0;
  /// What moves the noise floor in real surveys (all off by default). Range-dependent gain error:
  /// the image (echoes and noise alike) is off by this many dB per metre from mid-range, brighter
  /// far away for a positive value (a time-varied gain that over-compensates).
  double tvg_error_db_per_m = 0.0;
  /// A gain change mid-survey: the return legs' images (odd k) are this many dB brighter.
  double gain_change_db = 0.0;
  /// A second seabed type from x = 14 m on, of this reflectivity (sand is 0.45; mud 0.2, say);
  /// negative: the same sand everywhere.
  double second_floor_reflectivity = -1.0;
  std::uint32_t seed = 1;
  SonarNoise noise;
};

struct SimulatedPing {
  Eigen::Isometry3d pose;      ///< true sonar pose: sonar frame (+X fwd, +Y right, +Z down) to map frame (+z up)
  Eigen::Isometry3d nav_pose;  ///< the pose the navigation reports (= pose without drift)
  SonarImage8 image;       ///< range_bins x beams
};

struct SonarSimulation {
  SonarGeometry geometry;  ///< bearings, range resolution, max range, aperture (min range 0)
  std::vector<SimulatedPing> pings;
  std::unordered_set<VoxelKey, VoxelKeyHash> visible_truth;    ///< every ensonified surface voxel
  std::unordered_set<VoxelKey, VoxelKeyHash> footprint_truth;  ///< the first-return footprint
  std::size_t beams = 0;          ///< beams over all pings
  /// Beams whose first pixel above echo_threshold lies more than 2 bins before the true nearest
  /// surface (a false echo from noise or clutter), or more than 2 bins after it (a missed echo).
  std::size_t early_returns = 0;
  std::size_t late_returns = 0;
};

/// Renders the survey. Throws std::invalid_argument for non-positive sizes.
[[nodiscard]] SonarSimulation simulate_sonar_survey(const SonarSimOptions& options);

}  // namespace iwlomap::bench
