// SPDX-License-Identifier: BSD-3-Clause
//
// bench_sonar_accuracy: how well different update rules recover a known scene from the same
// simulated sonar pings (sonar_sim.h), at two noise levels.
//
// Every ping goes once through SonarImageProjector; the same observations (points, intensities,
// flags, weights) then update each map:
//   IWLO (defaults)    ProbabilityUpdater with the default IwloParams (sharpness 0.1, decay 0.1,
//                      adaptive on, L_occ 3.5, L_free -3), the projector's weights; occupied:
//                      p > 0.7 (its default occupied_threshold).
//   IWLO, sharpness 8  the same with an intensity sigmoid that discriminates (a barely-above-
//                      threshold echo weighs ~0.05, a saturated one ~0.98; at the default 0.1
//                      every echo weighs 0.49-0.51).
//   log-odds           plain fixed-increment log-odds as OctoMap does it: +ln(0.7/0.3) per
//                      occupied, ln(0.4/0.6) per free observation, clamped to
//                      [ln(0.12/0.88), ln(0.97/0.03)], one update per voxel per ping whatever the
//                      weight; occupied: p > 0.5 (OctoMap's). Run through ProbabilityUpdater with
//                      sharpness 0 (w = 0.5, so L_occ is doubled), decay 0 (alpha = 1), adaptive
//                      off and unit weights.
//   IWLO (defaults), OS-CFAR detection
//                      IWLO (defaults), the first return found by an ordered-statistic CFAR
//                      detector (near-side window, P_fa 1e-3, sonar_cfar.h) that must also
//                      exceed the threshold of 35, instead of the threshold alone.
//   IWLO (sonar preset) sonar_preset() (sonar_preset.h): OS-CFAR detection, the SNR weight, plain
//                      log-odds-like evidence (+1.5 per full-weight echo, -0.8 per free
//                      observation, clamped to [-2, 3.5], no learning-rate decay) with adaptive
//                      scaling; occupied: p > 0.8 (its occupied_threshold).
//   intensity average  a running weighted average of intensity per voxel, sum(W I) / sum(W) over
//                      all observations (free ones carry the dark pixels before the echo);
//                      occupied: the average exceeds the echo threshold (35).
//
// Scores against the simulator's first-return footprint truth (see sonar_sim.h):
//   P, R, F1   with a tolerance of one voxel: a map voxel is a true positive when a truth voxel
//              lies in its 3x3x3 neighbourhood, a truth voxel is recalled when a map voxel lies
//              in its neighbourhood (the elevation of an echo is uncertain by construction);
//   F1 exact   the same with no tolerance;
//   Chamfer    the mean of the two directed mean nearest-neighbour distances between voxel
//              centres, each distance truncated at 1 m;
//   best F1    the tolerant F1 at the best output threshold of a sweep (probability 0.50..0.95
//              in steps of 0.05; average intensity 35..120 in steps of 5), with that threshold:
//              it compares the update rules without the choice of threshold.
// Two tables: over everything, and inside the survey corridor only (x between the ends of the
// legs, |y| <= 4 m: the lanes the footprint rings of both legs swept). Outside it lie the edges of
// the swath and the ends of the legs, where the elevation arcs of a few pings are never seen
// again and no update rule can remove them.
//
// --ablation: heavy noise only: IWLO with one ingredient removed at a time, and plain log-odds
//             with other increments or threshold, to show where the differences come from; the
//             sonar preset with one ingredient removed at a time (the CFAR detector, the SNR
//             weight, its evidence).
// --scene pilings: the second scene (sonar_sim.h: a sloping floor, pier pilings, a quay wall).
// --gain-errors: what moves the noise floor: a time-varied-gain error of 0.5 dB per metre about
//             mid-range, the second leg 6 dB brighter, and mud (reflectivity 0.2) from x = 14 m.
// --dump PREFIX: writes the truth sets and every method's occupied voxels as x y z text files.
// --drift F:  instead of the tables above, the survey with navigation drift (F of the distance
//             travelled, see sonar_sim.h) mapped by IWLO (defaults): at the true poses,
//             at the drifted navigation poses, and at the navigation poses corrected by
//             registration (RegisteredSonarMapper, submaps of --submap-pings pings, default 80)
//             against the map it builds; and, as a repeat survey, registered against the map of an
//             earlier survey of the site (seed + 1000, true poses) and mapped alone at the poses
//             found; and the ceiling of registration against its own map (the return leg given,
//             where its footprint crosses the first leg's, that leg's navigation error: what an
//             exact registration against the map drawn at the first leg's poses would give). With
//             the pose errors before and after registration. Needs the registration layer.
//             Variants of the registration: --coarse (branch and bound before ICP), --six-dof
//             (ICP in 6 DoF instead of x, y, yaw), --no-rmse-limit (accept any converged fit);
//             --submaps prints each submap's registration to standard error.
// --loop-closure (with --drift F): the survey revisits its first line: --legs N legs (default 3:
//             out, back, and out again on the first leg's line and heading), mapped at the true
//             poses, at the drifted navigation poses, and by SonarPoseGraphMapper (submaps of
//             --submap-pings pings matched against older submaps of the same place and heading,
//             a pose graph over the submaps), with no prior map. Needs the SLAM layer.
//
// Usage: bench_sonar_accuracy [--resolution R] [--ping-spacing S] [--band M] [--seed N] [--quick]
//                             [--scene objects|pilings] [--gain-errors] [--ablation] [--dump PREFIX]
//                             [--drift F [--submap-pings K] [--coarse] [--six-dof] [--no-rmse-limit] [--submaps]
//                              [--loop-closure [--legs N]]]

#include "sonar_sim.h"

#include <iwlomap/probability_updater.h>
#include <iwlomap/sonar_image_projector.h>
#include <iwlomap/sonar_preset.h>
#ifdef IWLOMAP_BENCH_REGISTRATION
#include <iwlomap/registration/registered_sonar_mapper.h>
#endif
#ifdef IWLOMAP_BENCH_SLAM
#include <iwlomap/slam/sonar_pose_graph_mapper.h>
#endif

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <unordered_map>
#include <utility>
#include <vector>

namespace {

using iwlomap::VoxelKey;
using KeySet = std::unordered_set<VoxelKey, iwlomap::VoxelKeyHash>;
/// A map's verdict per known voxel: probability, or average intensity.
using ScoredVoxels = std::unordered_map<VoxelKey, double, iwlomap::VoxelKeyHash>;

constexpr double kEchoThreshold = 35.0;
constexpr double kCorridorHalfWidth = 4.0;

double logit(double p) { return std::log(p / (1.0 - p)); }

// The running weighted average of intensity, per voxel.
class IntensityAverageMap {
 public:
  void update(const iwlomap::SonarObservations& obs, double resolution) {
    for (std::size_t i = 0; i < obs.size(); ++i) {
      const auto row = static_cast<Eigen::Index>(i);
      Sum& s = voxels_[iwlomap::world_to_key(obs.points.row(row).transpose(), resolution)];
      s.weighted += obs.weights[row] * obs.intensities[row];
      s.weight += obs.weights[row];
    }
  }
  [[nodiscard]] ScoredVoxels averages() const {
    ScoredVoxels out;
    for (const auto& [key, s] : voxels_)
      if (s.weight > 0.0) out.emplace(key, s.weighted / s.weight);
    return out;
  }

 private:
  struct Sum {
    double weighted = 0.0, weight = 0.0;
  };
  std::unordered_map<VoxelKey, Sum, iwlomap::VoxelKeyHash> voxels_;
};

ScoredVoxels probabilities(const iwlomap::IMapperBackend& map) {
  ScoredVoxels out;
  map.for_each_voxel([&](const VoxelKey& k, const iwlomap::VoxelState& s) { out.emplace(k, s.probability); });
  return out;
}

// The voxels of a set (or the entries of a map) whose key satisfies \p inside.
template <typename Set, typename Inside>
Set restrict_to(const Set& set, Inside&& inside) {
  Set out;
  for (const auto& item : set) {
    if constexpr (std::is_same_v<Set, KeySet>) {
      if (inside(item)) out.insert(item);
    } else {
      if (inside(item.first)) out.insert(item);
    }
  }
  return out;
}

KeySet above(const ScoredVoxels& voxels, double threshold) {
  KeySet out;
  for (const auto& [key, value] : voxels)
    if (value > threshold) out.insert(key);
  return out;
}

template <typename Visit>
void for_neighbourhood(const VoxelKey& k, Visit&& visit) {
  for (int dx = -1; dx <= 1; ++dx)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dz = -1; dz <= 1; ++dz) visit(VoxelKey{k.x + dx, k.y + dy, k.z + dz});
}

bool near_any(const VoxelKey& k, const KeySet& set) {
  bool found = false;
  for_neighbourhood(k, [&](const VoxelKey& q) { found = found || set.count(q) > 0; });
  return found;
}

// Nearest-neighbour distances to a voxel set, truncated at `cap` metres. The set's voxels are
// bucketed in cubic cells at least `cap` wide, so every voxel within cap of a query lies in the
// 27 cells around the query's cell.
class NearestVoxel {
 public:
  NearestVoxel(const KeySet& set, double resolution, double cap)
      : resolution_(resolution), cap_(cap), cell_(std::max(1, static_cast<int>(std::ceil(cap / resolution)))) {
    for (const VoxelKey& k : set) cells_[cell_of(k)].push_back(k);
  }
  [[nodiscard]] double distance(const VoxelKey& k) const {
    std::int64_t best = std::numeric_limits<std::int64_t>::max();
    for_neighbourhood(cell_of(k), [&](const VoxelKey& c) {
      const auto it = cells_.find(c);
      if (it == cells_.end()) return;
      for (const VoxelKey& q : it->second) {
        const std::int64_t ex = q.x - k.x, ey = q.y - k.y, ez = q.z - k.z;
        best = std::min(best, ex * ex + ey * ey + ez * ez);
      }
    });
    if (best == std::numeric_limits<std::int64_t>::max()) return cap_;
    return std::min(cap_, resolution_ * std::sqrt(static_cast<double>(best)));
  }

 private:
  [[nodiscard]] VoxelKey cell_of(const VoxelKey& k) const {
    const auto f = [&](std::int32_t v) { return static_cast<std::int32_t>(std::floor(static_cast<double>(v) / cell_)); };
    return {f(k.x), f(k.y), f(k.z)};
  }
  double resolution_, cap_;
  int cell_;
  std::unordered_map<VoxelKey, std::vector<VoxelKey>, iwlomap::VoxelKeyHash> cells_;
};

double f1(double precision, double recall) {
  return precision + recall > 0.0 ? 2.0 * precision * recall / (precision + recall) : 0.0;
}

struct Score {
  std::size_t occupied = 0;
  double precision = 0.0, recall = 0.0, f1 = 0.0, f1_exact = 0.0, chamfer = 0.0;
  double best_f1 = 0.0, best_threshold = 0.0;
  double visible_recall = 0.0;
};

// Scores the voxels above `threshold`, and the tolerant F1 over the threshold sweep.
Score score(const ScoredVoxels& voxels, double threshold, const std::vector<double>& sweep, const KeySet& truth,
            const KeySet& visible, double resolution) {
  Score s;
  const KeySet map = above(voxels, threshold);
  s.occupied = map.size();
  std::size_t tp = 0, tp_exact = 0, found = 0, found_exact = 0, seen = 0;
  double to_truth = 0.0, to_map = 0.0;
  const NearestVoxel nearest_truth(truth, resolution, 1.0), nearest_map(map, resolution, 1.0);
  for (const VoxelKey& k : map) {
    tp += near_any(k, truth) ? 1 : 0;
    tp_exact += truth.count(k);
    to_truth += nearest_truth.distance(k);
  }
  for (const VoxelKey& k : truth) {
    found += near_any(k, map) ? 1 : 0;
    found_exact += map.count(k);
    to_map += nearest_map.distance(k);
  }
  for (const VoxelKey& k : visible) seen += near_any(k, map) ? 1 : 0;
  const auto ratio = [](std::size_t a, std::size_t b) { return b == 0 ? 0.0 : static_cast<double>(a) / b; };
  s.precision = ratio(tp, map.size());
  s.recall = ratio(found, truth.size());
  s.f1 = f1(s.precision, s.recall);
  s.f1_exact = f1(ratio(tp_exact, map.size()), ratio(found_exact, truth.size()));
  s.chamfer = 0.5 * ((map.empty() ? 1.0 : to_truth / map.size()) + (truth.empty() ? 1.0 : to_map / truth.size()));
  s.visible_recall = ratio(seen, visible.size());

  // The sweep needs, per known voxel, whether it is near the truth, and per truth voxel, the
  // highest value in its neighbourhood: then every threshold is one pass over two arrays.
  std::vector<std::pair<double, bool>> known;  // value, near truth
  known.reserve(voxels.size());
  for (const auto& [key, value] : voxels) known.emplace_back(value, near_any(key, truth));
  std::vector<double> truth_best;
  truth_best.reserve(truth.size());
  for (const VoxelKey& k : truth) {
    double best = -std::numeric_limits<double>::infinity();
    for_neighbourhood(k, [&](const VoxelKey& q) {
      const auto it = voxels.find(q);
      if (it != voxels.end()) best = std::max(best, it->second);
    });
    truth_best.push_back(best);
  }
  for (const double t : sweep) {
    std::size_t n = 0, hits = 0, recalled = 0;
    for (const auto& [value, near] : known)
      if (value > t) {
        ++n;
        hits += near ? 1 : 0;
      }
    for (const double b : truth_best) recalled += b > t ? 1 : 0;
    const double f = f1(ratio(hits, n), ratio(recalled, truth_best.size()));
    if (f > s.best_f1) {
      s.best_f1 = f;
      s.best_threshold = t;
    }
  }
  return s;
}

void dump(const std::string& path, const KeySet& keys, double resolution) {
  std::ofstream out(path);
  for (const VoxelKey& k : keys) {
    const Eigen::Vector3d c = iwlomap::key_to_center(k, resolution);
    out << c.x() << ' ' << c.y() << ' ' << c.z() << '\n';
  }
  if (!out) throw std::runtime_error("cannot write " + path);
}

struct Options {
  double resolution = 0.1;
  double ping_spacing = 0.1;
  double band = 0.0;
  std::uint32_t seed = 1;
  bool ablation = false;
  double drift = -1.0;    // < 0: no drift comparison
  int submap_pings = 80;
  bool coarse = false, six_dof = false, no_rmse_limit = false, submaps = false;  // --drift variants
  bool loop_closure = false;
  int legs = 3;  // with --loop-closure
  iwlomap::bench::SonarScene scene = iwlomap::bench::SonarScene::kObjects;
  bool gain_errors = false;
  std::string dump;  // prefix of x y z text files of the truth and of every method's voxels
};

[[noreturn]] void usage(const std::string& problem) {
  std::fprintf(stderr,
               "bench_sonar_accuracy: %s\nusage: bench_sonar_accuracy [--resolution R] [--ping-spacing S] "
               "[--band M] [--seed N] [--quick]\n    [--scene objects|pilings] [--gain-errors] [--ablation] "
               "[--dump PREFIX] [--drift F [--submap-pings K] [--coarse] [--six-dof] [--no-rmse-limit] "
               "[--submaps] [--loop-closure [--legs N]]]\n",
               problem.c_str());
  std::exit(2);
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto value = [&]() -> double {
      if (i + 1 >= argc) usage(a + " needs a value");
      char* end = nullptr;
      const double v = std::strtod(argv[++i], &end);
      if (*end != '\0' || !std::isfinite(v)) usage(a + " needs a number, got '" + argv[i] + "'");
      return v;
    };
    if (a == "--resolution") o.resolution = value();
    else if (a == "--ping-spacing") o.ping_spacing = value();
    else if (a == "--band") o.band = value();
    else if (a == "--seed") o.seed = static_cast<std::uint32_t>(value());
    else if (a == "--quick") o.ping_spacing = 0.4;
    else if (a == "--ablation") o.ablation = true;
    else if (a == "--drift") o.drift = value();
    else if (a == "--submap-pings") o.submap_pings = static_cast<int>(value());
    else if (a == "--coarse") o.coarse = true;
    else if (a == "--six-dof") o.six_dof = true;
    else if (a == "--no-rmse-limit") o.no_rmse_limit = true;
    else if (a == "--submaps") o.submaps = true;
    else if (a == "--loop-closure") o.loop_closure = true;
    else if (a == "--legs") o.legs = static_cast<int>(value());
    else if (a == "--gain-errors") o.gain_errors = true;
    else if (a == "--scene") {
      if (i + 1 >= argc) usage("--scene needs objects or pilings");
      const std::string scene = argv[++i];
      if (scene == "objects") o.scene = iwlomap::bench::SonarScene::kObjects;
      else if (scene == "pilings") o.scene = iwlomap::bench::SonarScene::kPilings;
      else usage("--scene must be objects or pilings, got '" + scene + "'");
    }
    else if (a == "--dump") {
      if (i + 1 >= argc) usage("--dump needs a prefix");
      o.dump = argv[++i];
    } else usage("unknown option " + a);
  }
  if (!(o.resolution > 0.0) || !(o.ping_spacing > 0.0) || !(o.band >= 0.0) || o.submap_pings < 1)
    usage("values must be > 0 (band >= 0)");
  if (o.drift >= 0.0 && o.ablation) usage("--drift and --ablation are separate runs");
  if (o.loop_closure && o.drift < 0.0) usage("--loop-closure needs --drift");
  if (o.legs < 1) usage("--legs must be >= 1");
  return o;
}

// One map under test: an IWLO parameter set (plain log-odds is one of them) and whether it takes
// the projector's weights or a unit weight per observation.
struct Method {
  std::string name;
  iwlomap::IwloParams params;
  bool unit_weights = false;
  int projector = 0;  // index into projectors(): the fixed-threshold projector, the CFAR one, ...
};

// The projections the methods draw on, in the order Method::projector counts them.
enum Projection { kThresholdProjection, kCfarProjection, kPresetProjection, kPresetWithoutSnrProjection };

std::vector<iwlomap::SonarProjectorParams> projections(const Options& opt) {
  using namespace iwlomap;
  SonarProjectorParams pp;
  pp.intensity_threshold = kEchoThreshold;
  pp.occupied_band = opt.band;
  pp.no_return = SonarNoReturn::kFreeToMaxRange;
  SonarProjectorParams cp = pp;  // OS-CFAR, near-side window, P_fa 1e-3; echoes must also exceed 35
  cp.detector = SonarDetector::kOrderedStatisticCfar;
  SonarProjectorParams preset = sonar_preset(kEchoThreshold).projector;
  preset.occupied_band = opt.band;
  SonarProjectorParams without_snr = preset;
  without_snr.snr_weight.enabled = false;
  return {pp, cp, preset, without_snr};
}

std::vector<Method> methods(bool ablation) {
  using iwlomap::IwloParams;
  IwloParams iwlo;  // the defaults
  iwlo.intensity_threshold = kEchoThreshold;
  IwloParams log_odds;
  log_odds.sharpness = 0.0;                       // w = 0.5 for every echo above the threshold
  log_odds.log_odds_occupied = 2.0 * logit(0.7);  // so w * L_occ = ln(0.7 / 0.3)
  log_odds.log_odds_free = logit(0.4);
  log_odds.decay_rate = 0.0;                      // alpha = 1
  log_odds.min_alpha = 1.0;
  log_odds.adaptive_enabled = false;
  log_odds.L_min = logit(0.12);
  log_odds.L_max = logit(0.97);
  log_odds.intensity_threshold = kEchoThreshold;
  log_odds.occupied_threshold = 0.5;

  std::vector<Method> out;
  out.push_back({"IWLO (defaults)", iwlo, false});
  IwloParams sharp = iwlo;
  sharp.sharpness = 8.0;
  out.push_back({"IWLO, sharpness 8", sharp, false});
  out.push_back({"log-odds (OctoMap increments)", log_odds, true});
  // The detector alone: the same map, the first return found by OS-CFAR against the beam's own
  // water column instead of the fixed threshold.
  out.push_back({"IWLO (defaults), OS-CFAR detection", iwlo, false, kCfarProjection});
  const iwlomap::SonarPreset preset = iwlomap::sonar_preset(kEchoThreshold);
  out.push_back({"IWLO (sonar preset)", preset.map, false, kPresetProjection});
  if (ablation) {
    // Which ingredient of IWLO makes the difference: take them away one at a time, and give plain
    // log-odds IWLO's increments or threshold.
    IwloParams p = iwlo;
    p.adaptive_enabled = false;
    out.push_back({"IWLO without adaptive scale", p, false});
    p = iwlo;
    p.decay_rate = 0.0;
    out.push_back({"IWLO without learning-rate decay", p, false});
    out.push_back({"IWLO with unit weights", iwlo, true});
    p = sharp;
    p.adaptive_enabled = false;
    out.push_back({"IWLO, sharpness 8, without adaptive scale", p, false});
    p = iwlo;
    p.adaptive_enabled = false;
    p.decay_rate = 0.0;
    p.sharpness = 0.0;
    out.push_back({"fixed increments +1.75/-3.0, p > 0.7", p, true});
    p = log_odds;
    p.occupied_threshold = 0.7;
    out.push_back({"log-odds (OctoMap increments), p > 0.7", p, true});
    p = log_odds;
    p.log_odds_free = -2.0 * logit(0.7);  // as strong as a hit
    out.push_back({"log-odds +0.85/-0.85", p, true});
    // The sonar preset with one ingredient taken away at a time. Without the CFAR detector there
    // is no SNR weight either (it measures echoes against the CFAR threshold).
    out.push_back({"sonar preset, fixed-threshold detection (so no SNR weight)", preset.map, false,
                   kThresholdProjection});
    out.push_back({"sonar preset without SNR weight", preset.map, false, kPresetWithoutSnrProjection});
    p = iwlo;  // the reference evidence: increments, learning rate, clamps; sharpness 0 and p > 0.8 kept
    p.sharpness = preset.map.sharpness;
    p.occupied_threshold = preset.map.occupied_threshold;
    out.push_back({"sonar preset with the reference evidence", p, false, kPresetProjection});
    p = preset.map;
    p.adaptive_enabled = false;
    out.push_back({"sonar preset without adaptive scale", p, false, kPresetProjection});
    p = preset.map;
    p.occupied_threshold = iwlo.occupied_threshold;
    out.push_back({"sonar preset, p > 0.7", p, false, kPresetProjection});
  }
  return out;
}

// The survey the options ask for, at one noise level.
iwlomap::bench::SonarSimOptions sim_options(const Options& opt, const iwlomap::bench::SonarNoise& noise) {
  iwlomap::bench::SonarSimOptions so;
  so.noise = noise;
  so.resolution = opt.resolution;
  so.ping_spacing = opt.ping_spacing;
  so.truth_band = std::max(opt.band, 0.5 * opt.resolution);
  so.echo_threshold = kEchoThreshold;
  so.seed = opt.seed;
  so.scene = opt.scene;
  if (opt.gain_errors) {
    so.tvg_error_db_per_m = 0.5;
    so.gain_change_db = 6.0;
    so.second_floor_reflectivity = 0.2;
  }
  return so;
}

// Whether a voxel's centre lies in the survey corridor of \p so (see the file comment).
bool in_corridor(const VoxelKey& k, const iwlomap::bench::SonarSimOptions& so, double resolution) {
  const Eigen::Vector3d c = iwlomap::key_to_center(k, resolution);
  return c.x() >= so.leg_start_x && c.x() <= so.leg_end_x && std::abs(c.y()) <= kCorridorHalfWidth;
}

// One table row: noise level, what was scored, and its scores.
std::string score_row(const std::string& noise, const std::string& name, const Score& s) {
  char row[512];
  std::snprintf(row, sizeof row, "| %s | %s | %zu | %.3f | %.3f | **%.3f** | %.3f | %.3f | %.3f (%g) |", noise.c_str(),
                name.c_str(), s.occupied, s.precision, s.recall, s.f1, s.f1_exact, s.chamfer, s.best_f1,
                s.best_threshold);
  return row;
}

// The two tables (all voxels, corridor) and the notes under them; \p column names the second column.
void print_tables(const std::vector<std::string> (&rows)[2], const std::vector<std::string>& notes, const char* column) {
  const iwlomap::bench::SonarSimOptions so;
  for (int region = 0; region < 2; ++region) {
    if (region == 0)
      std::printf("All voxels:\n\n");
    else
      std::printf("\nInside the survey corridor (x in [%g, %g] m, |y| <= %g m):\n\n", so.leg_start_x, so.leg_end_x,
                  kCorridorHalfWidth);
    std::printf("| noise | %s | occupied | precision | recall | F1 | F1 exact | Chamfer (m) | best F1 (at) |\n", column);
    std::printf("|---|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for (const std::string& row : rows[region]) std::printf("%s\n", row.c_str());
  }
  std::printf("\n");
  for (const std::string& n : notes) std::printf("- %s\n", n.c_str());
}

constexpr double kPi = 3.14159265358979323846;

// Position (m) and rotation (degrees) between two poses.
std::pair<double, double> pose_error(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  const Eigen::AngleAxisd turn(a.linear().transpose() * b.linear());
  return {(a.translation() - b.translation()).norm(), std::abs(turn.angle()) * 180.0 / kPi};
}

struct ErrorStats {
  double rms = 0.0, max = 0.0, rms_angle = 0.0, max_angle = 0.0;
  void add(const std::pair<double, double>& e) {
    rms += e.first * e.first;
    max = std::max(max, e.first);
    rms_angle += e.second * e.second;
    max_angle = std::max(max_angle, e.second);
    ++n;
  }
  [[nodiscard]] std::string text() const {
    char out[160];
    std::snprintf(out, sizeof out, "RMS %.3f m / %.2f deg, max %.3f m / %.2f deg", std::sqrt(rms / std::max<std::size_t>(1, n)),
                  std::sqrt(rms_angle / std::max<std::size_t>(1, n)), max, max_angle);
    return out;
  }
  std::size_t n = 0;
};

#ifdef IWLOMAP_BENCH_REGISTRATION
// The drifted survey mapped at the true poses, at the navigation poses, and at the navigation
// poses corrected by registration; IWLO defaults for all three.
int run_drift(const Options& opt, const iwlomap::SonarImageProjector& projector,
              const std::vector<double>& probability_sweep) {
  using namespace iwlomap;
  IwloParams iwlo;
  iwlo.intensity_threshold = kEchoThreshold;
  std::vector<std::string> rows[2], notes;
  for (const bench::SonarNoise& noise : {bench::light_noise(), bench::heavy_noise()}) {
    bench::SonarSimOptions so = sim_options(opt, noise);
    so.drift = opt.drift;
    const bench::SonarSimulation sim = bench::simulate_sonar_survey(so);

    ProbabilityUpdater truth_map(opt.resolution), drifted_map(opt.resolution);
    truth_map.set_params(iwlo);
    drifted_map.set_params(iwlo);
    auto registered_map = std::make_shared<ProbabilityUpdater>(opt.resolution);
    registered_map->set_params(iwlo);
    registration::RegisteredSonarMapperOptions ro;
    ro.pings_per_submap = opt.submap_pings;
    ro.matcher.coarse = ro.matcher.coarse || opt.coarse;
    ro.matcher.icp.planar = ro.matcher.icp.planar && !opt.six_dof;
    if (opt.no_rmse_limit) ro.max_fitness_rmse = 0.0;
    registration::RegisteredSonarMapper mapper(registered_map, projector, ExecutionMode::kSequential, ro);
    double register_seconds = 0.0;
    ErrorStats nav_error;
    for (const bench::SimulatedPing& ping : sim.pings) {
      const SonarImageView view = make_sonar_image_view(ping.image);
      static_cast<void>(projector.integrate(truth_map, view, sim.geometry, ping.pose));
      static_cast<void>(projector.integrate(drifted_map, view, sim.geometry, ping.nav_pose));
      const auto t0 = std::chrono::steady_clock::now();
      mapper.integrate(ping.nav_pose, view, sim.geometry);
      register_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      nav_error.add(pose_error(ping.pose, ping.nav_pose));
    }
    const auto t0 = std::chrono::steady_clock::now();
    const std::vector<registration::RegisteredSubmap> submaps = mapper.sync();
    register_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    // A repeat survey: the map of an earlier survey of the site (other noise draws, true poses) is
    // the chart; the drifted survey registers against it, and its own pings are mapped alone at
    // the poses found.
    bench::SonarSimOptions earlier_options = so;
    earlier_options.seed = so.seed + 1000;
    earlier_options.drift = 0.0;
    const bench::SonarSimulation earlier = bench::simulate_sonar_survey(earlier_options);
    auto chart = std::make_shared<ProbabilityUpdater>(opt.resolution);
    chart->set_params(iwlo);
    for (const bench::SimulatedPing& ping : earlier.pings)
      static_cast<void>(projector.integrate(*chart, make_sonar_image_view(ping.image), earlier.geometry, ping.pose));
    registration::RegisteredSonarMapper chart_mapper(chart, projector, ExecutionMode::kSequential, ro);
    for (const bench::SimulatedPing& ping : sim.pings)
      chart_mapper.integrate(ping.nav_pose, make_sonar_image_view(ping.image), sim.geometry);
    const std::vector<registration::RegisteredSubmap> chart_submaps = chart_mapper.sync();
    ProbabilityUpdater repeat_map(opt.resolution);
    repeat_map.set_params(iwlo);
    ErrorStats chart_error;
    std::size_t chart_registered = 0;
    {
      std::size_t ping = 0;
      for (const registration::RegisteredSubmap& submap : chart_submaps) {
        chart_registered += submap.registered ? 1 : 0;
        for (const Eigen::Isometry3d& pose : submap.integrated_poses) {
          const bench::SimulatedPing& p = sim.pings[ping++];
          chart_error.add(pose_error(p.pose, pose));
          static_cast<void>(projector.integrate(repeat_map, make_sonar_image_view(p.image), sim.geometry, pose));
        }
      }
    }

    ErrorStats corrected_error;
    std::size_t registered = 0, ping = 0;
    for (const registration::RegisteredSubmap& submap : submaps) {
      registered += submap.registered ? 1 : 0;
      if (opt.submaps) {
        const auto guess = pose_error(sim.pings[submap.first_ping].pose, submap.initial_guess);
        const auto found = pose_error(sim.pings[submap.first_ping].pose, submap.correction * submap.given_pose);
        std::fprintf(stderr,
                     "%s submap at ping %zu: %zu voxels, registered %d, score %.3f, rmse %.3f m, %d iterations; "
                     "guess off by %.3f m / %.2f deg, result %.3f m / %.2f deg%s%s\n",
                     noise.name.c_str(), submap.first_ping, submap.occupied_voxels, submap.registered ? 1 : 0,
                     submap.match.score, submap.match.fitness_rmse, submap.match.iterations, guess.first, guess.second,
                     found.first, found.second, submap.match.reason.empty() ? "" : "; ", submap.match.reason.c_str());
      }
      for (const Eigen::Isometry3d& pose : submap.integrated_poses)
        corrected_error.add(pose_error(sim.pings[ping++].pose, pose));
    }

    // The ceiling of registration against its own map: a ping whose seabed the survey saw before,
    // from the other heading, is given that earlier ping's navigation error (as a perfect
    // registration of it against the map drawn at the earlier navigation poses would), and a ping
    // after it keeps that correction; pings before the first such overlap keep their navigation
    // poses. The floor is claimed occupied where a ping's fan first reaches it: the near-edge ring,
    // altitude / tan(pitch + aperture / 2) ahead across the horizontal field of view; two pings
    // saw the same seabed where their rings cross (sampled at 33 bearings, within 0.15 m).
    ProbabilityUpdater ceiling_map(opt.resolution);
    ceiling_map.set_params(iwlo);
    ErrorStats ceiling_error;
    std::size_t ceiling_matched = 0;  // pings that crossed an earlier ring
    {
      // Each ping's heading (radians) and near-edge ring, at its true pose, computed once.
      const double ahead = so.altitude / std::tan((so.pitch_deg + so.vertical_aperture_deg / 2.0) * kPi / 180.0);
      constexpr int kRing = 33;
      std::vector<double> heading(sim.pings.size());
      std::vector<std::array<Eigen::Vector2d, kRing>> ring(sim.pings.size());
      for (std::size_t i = 0; i < sim.pings.size(); ++i) {
        const Eigen::Isometry3d& pose = sim.pings[i].pose;
        heading[i] = std::atan2(pose.linear()(1, 0), pose.linear()(0, 0));
        for (int b = 0; b < kRing; ++b) {
          const double a = heading[i] + (b / (kRing - 1.0) - 0.5) * so.horizontal_fov_deg * kPi / 180.0;
          ring[i][static_cast<std::size_t>(b)] =
              pose.translation().head<2>() + ahead * Eigen::Vector2d(std::cos(a), std::sin(a));
        }
      }
      Eigen::Isometry3d correction = Eigen::Isometry3d::Identity();  // map pose = correction * navigation pose
      for (std::size_t i = 0; i < sim.pings.size(); ++i) {
        const bench::SimulatedPing& p = sim.pings[i];
        std::size_t best = i;
        double best_d = 0.15;
        for (std::size_t j = 0; j < i; ++j) {
          if (std::cos(heading[j] - heading[i]) >= 0.0) continue;
          for (const Eigen::Vector2d& a : ring[i])
            for (const Eigen::Vector2d& b : ring[j])
              if ((a - b).norm() < best_d) {
                best_d = (a - b).norm();
                best = j;
              }
        }
        if (best != i) {
          ++ceiling_matched;
          const bench::SimulatedPing& q = sim.pings[best];
          correction = (q.nav_pose * q.pose.inverse()) * (p.pose * p.nav_pose.inverse());
        }
        const Eigen::Isometry3d pose = correction * p.nav_pose;
        ceiling_error.add(pose_error(p.pose, pose));
        static_cast<void>(projector.integrate(ceiling_map, make_sonar_image_view(p.image), sim.geometry, pose));
      }
    }

    const auto corridor = [&](const VoxelKey& k) { return in_corridor(k, so, opt.resolution); };
    const KeySet truth_inside = restrict_to(sim.footprint_truth, corridor);
    const KeySet visible_inside = restrict_to(sim.visible_truth, corridor);
    const std::pair<const char*, const IMapperBackend*> maps[] = {
        {"true poses", &truth_map},
        {"drifted navigation", &drifted_map},
        {"drifted, registered", registered_map.get()},
        {"drifted, registered against an earlier survey's map", &repeat_map},
        {"drifted, return leg aligned to the first exactly (own-map ceiling)", &ceiling_map}};
    double f1s[2][5] = {};
    for (int m = 0; m < 5; ++m) {
      const ScoredVoxels voxels = probabilities(*maps[m].second);
      if (!opt.dump.empty())
        dump(opt.dump + noise.name + "_drift" + std::to_string(m) + ".xyz", above(voxels, iwlo.occupied_threshold),
             opt.resolution);
      for (int region = 0; region < 2; ++region) {
        const Score s = region == 0 ? score(voxels, iwlo.occupied_threshold, probability_sweep, sim.footprint_truth,
                                            sim.visible_truth, opt.resolution)
                                    : score(restrict_to(voxels, corridor), iwlo.occupied_threshold, probability_sweep,
                                            truth_inside, visible_inside, opt.resolution);
        f1s[region][m] = s.f1;
        rows[region].push_back(score_row(noise.name, std::string("IWLO (defaults), ") + maps[m].first, s));
      }
    }
    const auto recovered = [&](int region, int m) {
      const double lost = f1s[region][0] - f1s[region][1];
      return lost > 0.0 ? 100.0 * (f1s[region][m] - f1s[region][1]) / lost : 0.0;
    };
    char line[1536];
    std::snprintf(line, sizeof line,
                  "%s noise: %zu pings; navigation error %s, final %.3f m. Registered against its own map: %zu of "
                  "%zu submaps, pose error %s, recovering %.0f %% (all voxels) and %.0f %% (corridor) of the F1 "
                  "lost to drift, %.1f s. Registered against the earlier survey's map: %zu of %zu submaps, pose "
                  "error %s, recovering %.0f %% and %.0f %%. Own-map ceiling (a ping given the navigation error of an "
                  "earlier ping of the other heading that saw the same seabed, %zu of %zu pings): pose error %s, "
                  "recovering %.0f %% and %.0f %%",
                  noise.name.c_str(), sim.pings.size(), nav_error.text().c_str(),
                  (sim.pings.back().pose.translation() - sim.pings.back().nav_pose.translation()).norm(), registered,
                  submaps.size(), corrected_error.text().c_str(), recovered(0, 2), recovered(1, 2), register_seconds,
                  chart_registered, chart_submaps.size(), chart_error.text().c_str(), recovered(0, 3), recovered(1, 3),
                  ceiling_matched, sim.pings.size(), ceiling_error.text().c_str(), recovered(0, 4), recovered(1, 4));
    notes.emplace_back(line);
  }
  print_tables(rows, notes, "map");
  return 0;
}
#endif

#ifdef IWLOMAP_BENCH_SLAM
// A survey that revisits its first line, with drift and no prior map: mapped at the true poses, at
// the navigation poses, and by SonarPoseGraphMapper; the share of the F1 lost to drift that the
// loop closures win back.
int run_loop_closure(const Options& opt, const iwlomap::SonarImageProjector& projector,
                     const std::vector<double>& probability_sweep) {
  using namespace iwlomap;
  IwloParams iwlo;
  iwlo.intensity_threshold = kEchoThreshold;
  std::vector<std::string> rows[2], notes;
  for (const bench::SonarNoise& noise : {bench::light_noise(), bench::heavy_noise()}) {
    bench::SonarSimOptions so = sim_options(opt, noise);
    so.drift = opt.drift;
    so.legs = opt.legs;
    const bench::SonarSimulation sim = bench::simulate_sonar_survey(so);
    ProbabilityUpdater truth_map(opt.resolution), drifted_map(opt.resolution);
    truth_map.set_params(iwlo);
    drifted_map.set_params(iwlo);
    auto closed_map = std::make_shared<ProbabilityUpdater>(opt.resolution);
    closed_map->set_params(iwlo);
    slam::SonarPoseGraphMapperOptions lo;
    lo.pings_per_submap = opt.submap_pings;
    if (opt.no_rmse_limit) lo.max_fitness_rmse = 0.0;
    slam::SonarPoseGraphMapper mapper(closed_map, projector, lo);
    ErrorStats nav_error, closed_error;
    double seconds = 0.0;
    for (const bench::SimulatedPing& ping : sim.pings) {
      const SonarImageView view = make_sonar_image_view(ping.image);
      static_cast<void>(projector.integrate(truth_map, view, sim.geometry, ping.pose));
      static_cast<void>(projector.integrate(drifted_map, view, sim.geometry, ping.nav_pose));
      const auto t0 = std::chrono::steady_clock::now();
      mapper.integrate(ping.nav_pose, view, sim.geometry);
      seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      nav_error.add(pose_error(ping.pose, ping.nav_pose));
    }
    const auto t0 = std::chrono::steady_clock::now();
    mapper.finish();
    seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const std::vector<Eigen::Isometry3d> poses = mapper.poses();
    for (std::size_t i = 0; i < poses.size(); ++i) closed_error.add(pose_error(sim.pings[i].pose, poses[i]));
    if (opt.submaps) {
      for (std::size_t k = 0; k < mapper.submaps().size(); ++k) {
        const slam::SonarSubmapReport& r = mapper.submaps()[k];
        const auto e = pose_error(sim.pings[r.first_ping].pose, poses[r.first_ping]);
        std::fprintf(stderr, "%s submap %zu at ping %zu (%zu pings, %zu voxels): %zu of %zu closures; now %.3f m / %.2f deg off\n",
                     noise.name.c_str(), k, r.first_ping, r.pings, r.occupied_voxels, r.closures, r.closure_attempts,
                     e.first, e.second);
        for (const std::string& why : r.refusals) std::fprintf(stderr, "    refused against %s\n", why.c_str());
      }
      for (const slam::SonarLoopClosure& c : mapper.loop_closures()) {
        // The closure's error: its relative pose against the true one. A submap's frame is its
        // first ping's navigation pose, gravity-aligned (position and heading); where that frame
        // truly lies: true pose * navigation pose^-1 * frame.
        const auto true_frame = [&](std::size_t submap) {
          const bench::SimulatedPing& p = sim.pings[mapper.submaps()[submap].first_ping];
          Eigen::Isometry3d frame = Eigen::Isometry3d::Identity();
          frame.translation() = p.nav_pose.translation();
          frame.linear() = Eigen::AngleAxisd(std::atan2(p.nav_pose.linear()(1, 0), p.nav_pose.linear()(0, 0)),
                                             Eigen::Vector3d::UnitZ()).toRotationMatrix();
          return p.pose * p.nav_pose.inverse() * frame;
        };
        const Eigen::Isometry3d truth = true_frame(c.target).inverse() * true_frame(c.submap);
        const auto e = pose_error(truth, c.relative);
        std::fprintf(stderr, "%s closure %zu -> %zu: rmse %.3f m, off by %.3f m / %.2f deg%s\n", noise.name.c_str(),
                     c.target, c.submap, c.fitness_rmse, e.first, e.second, c.rejected ? " (rejected)" : "");
      }
    }

    const auto corridor = [&](const VoxelKey& k) { return in_corridor(k, so, opt.resolution); };
    const KeySet truth_inside = restrict_to(sim.footprint_truth, corridor);
    const KeySet visible_inside = restrict_to(sim.visible_truth, corridor);
    const std::pair<const char*, const IMapperBackend*> maps[] = {
        {"true poses", &truth_map}, {"drifted navigation", &drifted_map}, {"drifted, loop closure", closed_map.get()}};
    double f1s[2][3] = {};
    for (int m = 0; m < 3; ++m) {
      const ScoredVoxels voxels = probabilities(*maps[m].second);
      for (int region = 0; region < 2; ++region) {
        const Score s = region == 0 ? score(voxels, iwlo.occupied_threshold, probability_sweep, sim.footprint_truth,
                                            sim.visible_truth, opt.resolution)
                                    : score(restrict_to(voxels, corridor), iwlo.occupied_threshold, probability_sweep,
                                            truth_inside, visible_inside, opt.resolution);
        f1s[region][m] = s.f1;
        rows[region].push_back(score_row(noise.name, std::string("IWLO (defaults), ") + maps[m].first, s));
      }
    }
    const auto recovered = [&](int region) {
      const double lost = f1s[region][0] - f1s[region][1];
      return lost > 0.0 ? 100.0 * (f1s[region][2] - f1s[region][1]) / lost : 0.0;
    };
    const slam::SonarSlamSummary sum = mapper.summary();
    char line[1024];
    std::snprintf(line, sizeof line,
                  "%s noise: %zu pings in %d legs; navigation error %s, final %.3f m. Loop closure: %zu submaps, %zu "
                  "of %zu closures accepted (%zu rejected by the optimizer), pose error %s, recovering %.0f %% (all "
                  "voxels) and %.0f %% (corridor) of the F1 lost to drift, %.1f s",
                  noise.name.c_str(), sim.pings.size(), so.legs, nav_error.text().c_str(),
                  (sim.pings.back().pose.translation() - sim.pings.back().nav_pose.translation()).norm(), sum.submaps,
                  sum.closures_found, sum.closure_attempts, sum.closures_rejected_by_optimizer,
                  closed_error.text().c_str(), recovered(0), recovered(1), seconds);
    notes.emplace_back(line);
  }
  print_tables(rows, notes, "map");
  return 0;
}
#endif

}  // namespace

int main(int argc, char** argv) {
  const Options opt = parse(argc, argv);
  using namespace iwlomap;

  std::vector<SonarImageProjector> projectors;
  for (const SonarProjectorParams& p : projections(opt)) projectors.emplace_back(opt.resolution, p);
  const SonarImageProjector& projector = projectors[kThresholdProjection];
  const std::vector<Method> tested = methods(opt.ablation);
  std::vector<double> probability_sweep, intensity_sweep;
  for (int i = 0; i <= 9; ++i) probability_sweep.push_back(0.5 + 0.05 * i);
  for (int i = 0; i <= 17; ++i) intensity_sweep.push_back(35.0 + 5.0 * i);

  std::printf("# bench_sonar_accuracy: resolution %.3f m, ping spacing %.3f m, occupied band %.3f m, seed %u%s%s%s\n\n",
              opt.resolution, opt.ping_spacing, opt.band, opt.seed, opt.ablation ? ", ablation" : "",
              opt.scene == bench::SonarScene::kPilings ? ", scene pilings" : "", opt.gain_errors ? ", gain errors" : "");
  if (opt.drift >= 0.0) {
#ifdef IWLOMAP_BENCH_REGISTRATION
    std::printf("Navigation drift %.3f of the distance travelled, registration with submaps of %d pings\n\n", opt.drift,
                opt.submap_pings);
    if (opt.loop_closure) {
#ifdef IWLOMAP_BENCH_SLAM
      return run_loop_closure(opt, projector, probability_sweep);
#else
      usage("--loop-closure needs the SLAM layer (IWLOMAP_WITH_SLAM)");
#endif
    }
    return run_drift(opt, projector, probability_sweep);
#else
    usage("--drift needs the registration layer (IWLOMAP_WITH_REGISTRATION)");
#endif
  }
  std::vector<std::string> notes, rows[2];
  std::vector<bench::SonarNoise> levels = {bench::light_noise(), bench::heavy_noise()};
  if (opt.ablation) levels.erase(levels.begin());
  for (const bench::SonarNoise& noise : levels) {
    const bench::SonarSimOptions so = sim_options(opt, noise);
    const auto t0 = std::chrono::steady_clock::now();
    const bench::SonarSimulation sim = bench::simulate_sonar_survey(so);
    const auto t1 = std::chrono::steady_clock::now();

    std::vector<std::unique_ptr<ProbabilityUpdater>> maps;
    for (const Method& m : tested) {
      maps.push_back(std::make_unique<ProbabilityUpdater>(opt.resolution));
      maps.back()->set_params(m.params);
    }
    IntensityAverageMap average;
    std::size_t observations = 0;
    // Each projection that some method uses (the fixed-threshold one always: it feeds the intensity
    // average and the counts), once per ping.
    std::vector<bool> used(projectors.size(), false);
    used[kThresholdProjection] = true;
    for (const Method& m : tested) used[static_cast<std::size_t>(m.projector)] = true;
    for (const bench::SimulatedPing& ping : sim.pings) {
      std::vector<SonarObservations> projected(projectors.size());
      for (std::size_t j = 0; j < projectors.size(); ++j)
        if (used[j]) projected[j] = projectors[j].project(make_sonar_image_view(ping.image), sim.geometry, ping.pose);
      const SonarObservations& obs = projected[kThresholdProjection];
      observations += obs.size();
      for (std::size_t i = 0; i < tested.size(); ++i) {
        const SonarObservations& o = projected[static_cast<std::size_t>(tested[i].projector)];
        const Eigen::VectorXd ones = Eigen::VectorXd::Ones(o.weights.size());
        maps[i]->batch_update_iwlo(o.points, o.intensities, o.is_occupied, tested[i].unit_weights ? ones : o.weights);
      }
      average.update(obs, opt.resolution);
    }
    const auto t2 = std::chrono::steady_clock::now();

    struct Result {
      std::string name;
      ScoredVoxels voxels;
      double threshold;
      const std::vector<double>* sweep;
    };
    std::vector<Result> results;
    for (std::size_t i = 0; i < tested.size(); ++i)
      results.push_back({tested[i].name, probabilities(*maps[i]), tested[i].params.occupied_threshold,
                         &probability_sweep});
    if (!opt.ablation) results.push_back({"intensity average", average.averages(), kEchoThreshold, &intensity_sweep});
    const auto corridor = [&](const VoxelKey& k) { return in_corridor(k, so, opt.resolution); };
    std::size_t known_inside = 0;
    maps.front()->for_each_voxel([&](const VoxelKey& k, const VoxelState&) { known_inside += corridor(k) ? 1 : 0; });
    const KeySet truth_inside = restrict_to(sim.footprint_truth, corridor);
    const KeySet visible_inside = restrict_to(sim.visible_truth, corridor);
    double visible_recall = 0.0;
    for (std::size_t i = 0; i < results.size(); ++i) {
      const Result& r = results[i];
      if (!opt.dump.empty())
        dump(opt.dump + noise.name + "_method" + std::to_string(i) + ".xyz", above(r.voxels, r.threshold),
             opt.resolution);
      for (int region = 0; region < 2; ++region) {
        const Score s = region == 0 ? score(r.voxels, r.threshold, *r.sweep, sim.footprint_truth, sim.visible_truth,
                                            opt.resolution)
                                    : score(restrict_to(r.voxels, corridor), r.threshold, *r.sweep, truth_inside,
                                            visible_inside, opt.resolution);
        if (i == 0 && region == 0) visible_recall = s.visible_recall;
        rows[region].push_back(score_row(noise.name, r.name, s));
      }
    }
    if (!opt.dump.empty()) {
      dump(opt.dump + noise.name + "_truth.xyz", sim.footprint_truth, opt.resolution);
      dump(opt.dump + noise.name + "_visible.xyz", sim.visible_truth, opt.resolution);
    }
    char line[640];
    std::snprintf(line, sizeof line,
                  "%s noise: %zu pings, %zu beams: %.1f %% with a false early echo (noise, clutter, sidelobes), "
                  "%.1f %% with a late or missed echo; truth: %zu footprint voxels, %zu visible surface voxels "
                  "(of which IWLO (defaults) recalls %.3f); %zu voxel observations, %zu known voxels, "
                  "%zu of them in the corridor, which holds %zu footprint voxels; simulation %.1f s, projection and mapping %.1f s",
                  noise.name.c_str(), sim.pings.size(), sim.beams, 100.0 * sim.early_returns / sim.beams,
                  100.0 * sim.late_returns / sim.beams, sim.footprint_truth.size(), sim.visible_truth.size(),
                  visible_recall, observations, maps.front()->get_num_known_voxels(), known_inside,
                  truth_inside.size(), std::chrono::duration<double>(t1 - t0).count(),
                  std::chrono::duration<double>(t2 - t1).count());
    notes.emplace_back(line);
  }
  print_tables(rows, notes, "method");
  return 0;
}
