// SPDX-License-Identifier: BSD-3-Clause
// The core: IWLO parameters and formulas, sensor presets, keys, the backend interface, the RAM and
// Disk backends, make_backend, the memory limit, colours, entropy and the synthetic scan.

#include "bindings.h"
#include "numpy_io.h"

#include <iwlomap/hit_statistics.h>
#include <iwlomap/iwlo.h>
#include <iwlomap/map_entropy.h>
#include <iwlomap/map_memory.h>
#include <iwlomap/mapper_backend.h>
#include <iwlomap/outofcore_tile_mapper.h>
#include <iwlomap/probability_updater.h>
#include <iwlomap/ray_caster.h>
#include <iwlomap/scan_phases.h>
#include <iwlomap/sensor_preset.h>
#include <iwlomap/synthetic_scan.h>
#include <iwlomap/voxel_box.h>
#include <iwlomap/voxel_colors.h>
#include <iwlomap/voxel_key.h>

#include <pybind11/functional.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <string>
#include <charconv>
#include <cmath>
#include <limits>
#include <optional>
#include <sstream>
#include <unordered_map>
#include <vector>

namespace iwlomap::python {

namespace {

using Backend = IMapperBackend;
using BackendPtr = std::shared_ptr<IMapperBackend>;

// The shortest text that reads back as the same double, as Python's repr() of a float.
std::string num(double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  std::string s(buf, r.ptr);
  if (std::isfinite(v) && s.find_first_of(".e") == std::string::npos) s += ".0";  // 2 -> 2.0, as Python
  return s;
}

std::string repr_params(const IwloParams& p) {
  std::ostringstream o;
  o << "IwloParams(sharpness=" << num(p.sharpness) << ", decay_rate=" << num(p.decay_rate) << ", min_alpha=" << num(p.min_alpha)
    << ", L_min=" << num(p.L_min) << ", L_max=" << num(p.L_max) << ", log_odds_occupied=" << num(p.log_odds_occupied)
    << ", log_odds_free=" << num(p.log_odds_free) << ", intensity_threshold=" << num(p.intensity_threshold)
    << ", intensity_max=" << num(p.intensity_max) << ", adaptive_enabled=" << (p.adaptive_enabled ? "True" : "False")
    << ", adaptive_threshold=" << num(p.adaptive_threshold) << ", adaptive_max_ratio=" << num(p.adaptive_max_ratio)
    << ", occupied_threshold=" << num(p.occupied_threshold) << ")";
  return o.str();
}

void bind_params(py::module_& m) {
  const IwloParams d;
  py::class_<IwloParams>(m, "IwloParams",
                         "Every parameter of the IWLO update (log-odds units unless stated). Keyword arguments; "
                         "the defaults are the reference API's (sonar).")
      .def(py::init([](double sharpness, double decay_rate, double min_alpha, double L_min, double L_max,
                       double log_odds_occupied, double log_odds_free, double intensity_threshold,
                       double intensity_max, bool adaptive_enabled, double adaptive_threshold,
                       double adaptive_max_ratio, double occupied_threshold) {
             IwloParams p;
             p.sharpness = sharpness;
             p.decay_rate = decay_rate;
             p.min_alpha = min_alpha;
             p.L_min = L_min;
             p.L_max = L_max;
             p.log_odds_occupied = log_odds_occupied;
             p.log_odds_free = log_odds_free;
             p.intensity_threshold = intensity_threshold;
             p.intensity_max = intensity_max;
             p.adaptive_enabled = adaptive_enabled;
             p.adaptive_threshold = adaptive_threshold;
             p.adaptive_max_ratio = adaptive_max_ratio;
             p.occupied_threshold = occupied_threshold;
             return p;
           }),
           py::kw_only(), py::arg("sharpness") = d.sharpness, py::arg("decay_rate") = d.decay_rate,
           py::arg("min_alpha") = d.min_alpha, py::arg("L_min") = d.L_min, py::arg("L_max") = d.L_max,
           py::arg("log_odds_occupied") = d.log_odds_occupied, py::arg("log_odds_free") = d.log_odds_free,
           py::arg("intensity_threshold") = d.intensity_threshold, py::arg("intensity_max") = d.intensity_max,
           py::arg("adaptive_enabled") = d.adaptive_enabled, py::arg("adaptive_threshold") = d.adaptive_threshold,
           py::arg("adaptive_max_ratio") = d.adaptive_max_ratio, py::arg("occupied_threshold") = d.occupied_threshold)
      .def_readwrite("sharpness", &IwloParams::sharpness, "slope of the intensity sigmoid (unitless)")
      .def_readwrite("decay_rate", &IwloParams::decay_rate, "learning-rate decay per observation")
      .def_readwrite("min_alpha", &IwloParams::min_alpha, "floor of the learning rate, in (0, 1]")
      .def_readwrite("L_min", &IwloParams::L_min, "lower log-odds clamp")
      .def_readwrite("L_max", &IwloParams::L_max, "upper log-odds clamp")
      .def_readwrite("log_odds_occupied", &IwloParams::log_odds_occupied, "increment of a full-weight hit")
      .def_readwrite("log_odds_free", &IwloParams::log_odds_free, "increment of a free observation")
      .def_readwrite("intensity_threshold", &IwloParams::intensity_threshold,
                     "a return at or below this intensity is free-space evidence")
      .def_readwrite("intensity_max", &IwloParams::intensity_max, "intensity that maps to full weight")
      .def_readwrite("adaptive_enabled", &IwloParams::adaptive_enabled, "protect settled voxels")
      .def_readwrite("adaptive_threshold", &IwloParams::adaptive_threshold, "P_th of the adaptive scale, in (0, 1)")
      .def_readwrite("adaptive_max_ratio", &IwloParams::adaptive_max_ratio, "r_max of the adaptive scale, in [0, 1]")
      .def_readwrite("occupied_threshold", &IwloParams::occupied_threshold,
                     "probability above which a voxel is reported occupied, in (0, 1)")
      .def("validate", &IwloParams::validate, "Raises ValueError naming the first parameter out of its range.")
      .def("__repr__", &repr_params)
      .def("__eq__", [](const IwloParams& a, const IwloParams& b) { return repr_params(a) == repr_params(b); });

  py::module_ iwlo = m.def_submodule("iwlo", "The IWLO formulas for one voxel (log-odds units).");
  iwlo.attr("MAX_COUNT") = iwlo::kMaxCount;
  iwlo.def("probability", &iwlo::probability, py::arg("log_odds"), "1 / (1 + exp(-L))");
  iwlo.def(
      "log_odds",
      [](double p) {
        if (!(p > 0.0 && p < 1.0)) throw py::value_error("probability must be in (0, 1), got " + num(p));
        return iwlo::log_odds(p);
      },
      py::arg("probability"), "ln(p / (1 - p)); ValueError outside (0, 1)");
  iwlo.def("is_occupied_observation", &iwlo::is_occupied_observation, py::arg("occupied_flag"), py::arg("intensity"),
           py::arg("params"));
  iwlo.def("intensity_weight", &iwlo::intensity_weight, py::arg("intensity"), py::arg("params"));
  iwlo.def("learning_rate", &iwlo::learning_rate, py::arg("count"), py::arg("params"));
  iwlo.def("adaptive_scale", &iwlo::adaptive_scale, py::arg("probability"), py::arg("occupied"), py::arg("params"));
  iwlo.def("delta", &iwlo::delta, py::arg("log_odds"), py::arg("count"), py::arg("intensity"),
           py::arg("occupied_flag"), py::arg("weight"), py::arg("params"));
  iwlo.def("step", &iwlo::step, py::arg("log_odds"), py::arg("count"), py::arg("intensity"), py::arg("occupied_flag"),
           py::arg("weight"), py::arg("params"), "The voxel's next log-odds after one observation (count includes it).");
  py::class_<iwlo::VoxelFormat>(iwlo, "VoxelFormat",
                                "How a map's voxels store their state in 4 bytes: fixed-point log-odds above a "
                                "saturating count (see voxel_format()).")
      .def_property_readonly("count_bits", &iwlo::VoxelFormat::count_bits)
      .def_property_readonly("fraction_bits", &iwlo::VoxelFormat::fraction_bits)
      .def_property_readonly("step", &iwlo::VoxelFormat::step, "the log-odds step 2^-fraction_bits")
      .def_property_readonly("max_count", &iwlo::VoxelFormat::max_count, "counts saturate here")
      .def("quantize", &iwlo::VoxelFormat::quantize, py::arg("log_odds"),
           "The log-odds as an update stores it: to the nearest step, within [L_min, L_max].")
      .def("__repr__", [](const iwlo::VoxelFormat& f) {
        return "VoxelFormat(count_bits=" + std::to_string(f.count_bits()) +
               ", fraction_bits=" + std::to_string(f.fraction_bits()) + ")";
      });
  iwlo.def("voxel_format", &iwlo::voxel_format, py::arg("params"),
           "The voxel format of a map with these parameters; ValueError when they are invalid.");

  readable_enum_name(py::enum_<SensorPreset>(m, "SensorPreset", "IWLO parameters suited to a kind of sensor.")
      .value("kSonar", SensorPreset::kSonar)
      .value("kLidar", SensorPreset::kLidar)
      .value("kDepthCamera", SensorPreset::kDepthCamera));
  m.def("sensor_preset_params", &sensor_preset_params, py::arg("preset"));
  m.def("sensor_preset_name", &sensor_preset_name, py::arg("preset"));
  m.def("parse_sensor_preset", &parse_sensor_preset, py::arg("name"),
        "'sonar', 'lidar' or 'depth' -> SensorPreset; None for another name");
  py::class_<IntensityCheck>(m, "IntensityCheck")
      .def_readonly("points", &IntensityCheck::points)
      .def_readonly("at_or_below_threshold", &IntensityCheck::at_or_below_threshold)
      .def_readonly("all_equal", &IntensityCheck::all_equal)
      .def("thins_map", &IntensityCheck::thins_map)
      .def("advice", &IntensityCheck::advice);
  m.def(
      "check_intensities",
      [](const ArrayLike& intensities, const IwloParams& params) {
        return check_intensities(values_from(intensities, "intensities"), params);
      },
      py::arg("intensities"), py::arg("params"),
      "Whether a cloud's intensities suit the parameters (most at or below the threshold: free space).");
}

void bind_keys(py::module_& m) {
  py::class_<VoxelKey>(m, "VoxelKey", "Integer voxel coordinates: floor(coordinate / resolution).")
      .def(py::init([](std::int32_t x, std::int32_t y, std::int32_t z) { return VoxelKey{x, y, z}; }), py::arg("x"),
           py::arg("y"), py::arg("z"))
      .def_readwrite("x", &VoxelKey::x)
      .def_readwrite("y", &VoxelKey::y)
      .def_readwrite("z", &VoxelKey::z)
      .def("__eq__", [](const VoxelKey& a, const VoxelKey& b) { return a == b; })
      .def("__hash__", [](const VoxelKey& k) { return VoxelKeyHash{}(k); })
      .def("__repr__", [](const VoxelKey& k) {
        return "VoxelKey(" + std::to_string(k.x) + ", " + std::to_string(k.y) + ", " + std::to_string(k.z) + ")";
      });
  m.def(
      "world_to_key",
      [](const ArrayLike& point, double resolution) { return world_to_key_checked(vector3_from(point, "point"), resolution); },
      py::arg("point"), py::arg("resolution"), "The key of the voxel containing a point (metres, map frame).");
  m.def(
      "key_to_center", [](const VoxelKey& k, double resolution) { return to_numpy(key_to_center(k, resolution)); },
      py::arg("key"), py::arg("resolution"), "The centre of a voxel in metres, map frame.");
  py::class_<ScanPhaseTimes>(m, "ScanPhaseTimes",
                             "Where one insert_scan() spent its time, in wall-clock seconds (scan_phases.h).")
      .def_readonly("casting_rays", &ScanPhaseTimes::casting_rays, "parallel: the rays walked")
      .def_readonly("merging", &ScanPhaseTimes::merging, "serial: the threads' scratches merged")
      .def_readonly("allocating", &ScanPhaseTimes::allocating, "serial: the scan's new blocks created")
      .def_readonly("preparing", &ScanPhaseTimes::preparing, "parallel: the cells gathered and zero-filled")
      .def_readonly("updating", &ScanPhaseTimes::updating, "parallel: every observed voxel updated")
      .def_readonly("total", &ScanPhaseTimes::total, "the whole call")
      .def_readonly("threads", &ScanPhaseTimes::threads, "threads the call could use")
      .def("serial", &ScanPhaseTimes::serial, "total minus the parallel phases")
      .def("serial_share", &ScanPhaseTimes::serial_share, "serial() / total")
      .def("amdahl_speedup", &ScanPhaseTimes::amdahl_speedup, py::arg("threads"),
           "1 / (s + (1 - s) / threads) for the serial share s")
      .def("__repr__", [](const ScanPhaseTimes& p) {
        return "ScanPhaseTimes(total=" + std::to_string(p.total) + " s, serial share " +
               std::to_string(p.serial_share()) + ", threads=" + std::to_string(p.threads) + ")";
      });

  readable_enum_name(py::enum_<RayModel>(m, "RayModel", "The voxels a ray of insert_scan() marks free.")
      .value("kExact", RayModel::kExact, "every voxel the ray crosses (the default)")
      .value("kFast", RayModel::kFast, "a 26-connected line between voxel centres: fewer steps, fewer free voxels"));
  m.def(
      "cast_ray",
      [](const ArrayLike& origin, const ArrayLike& end, double resolution, RayModel model) {
        const Eigen::Vector3d o = vector3_from(origin, "origin"), e = vector3_from(end, "end");
        if (!(resolution > 0.0)) throw py::value_error("resolution must be > 0, got " + std::to_string(resolution));
        if (!is_representable(o, resolution) || !is_representable(e, resolution))
          throw py::value_error("origin and end must be finite points whose keys fit in int32");
        if ((e - o).norm() > kMaxRayVoxels * resolution)
          throw py::value_error("the ray is longer than MAX_RAY_VOXELS voxel edges");
        std::vector<VoxelKey> keys;
        cast_ray(o, e, resolution, model, [&](const VoxelKey& k) { keys.push_back(k); });
        py::array_t<std::int32_t> out({static_cast<py::ssize_t>(keys.size()), py::ssize_t{3}});
        auto w = out.mutable_unchecked<2>();
        for (std::size_t i = 0; i < keys.size(); ++i) {
          w(static_cast<py::ssize_t>(i), 0) = keys[i].x;
          w(static_cast<py::ssize_t>(i), 1) = keys[i].y;
          w(static_cast<py::ssize_t>(i), 2) = keys[i].z;
        }
        return out;
      },
      py::arg("origin"), py::arg("end"), py::arg("resolution"), py::arg("model") = RayModel::kExact,
      "The keys of the voxels a ray crosses from origin to end (metres), the end voxel excluded, as (K, 3) int32; "
      "with model=RayModel.kFast, the voxels of the line insert_scan() marks free under that model.");
  m.attr("MAX_RAY_VOXELS") = kMaxRayVoxels;

  py::class_<VoxelBox>(m, "VoxelBox", "An axis-aligned box of voxels, bounds included (keys).")
      .def(py::init([](const VoxelKey& lo, const VoxelKey& hi) {
             VoxelBox b{lo, hi};
             b.validate();
             return b;
           }),
           py::arg("min"), py::arg("max"))
      .def_static(
          "from_world",
          [](const ArrayLike& lo, const ArrayLike& hi, double resolution) {
            return VoxelBox::from_world(vector3_from(lo, "min_corner"), vector3_from(hi, "max_corner"), resolution);
          },
          py::arg("min_corner"), py::arg("max_corner"), py::arg("resolution"),
          "The voxels that contain the corners (metres) and every voxel between.")
      .def_readwrite("min", &VoxelBox::min)
      .def_readwrite("max", &VoxelBox::max)
      .def("contains", &VoxelBox::contains, py::arg("key"))
      .def("num_voxels", &VoxelBox::num_voxels)
      .def("validate", &VoxelBox::validate);
}

void bind_states(py::module_& m) {
  py::class_<VoxelState>(m, "VoxelState", "One voxel: log-odds, probability and observation count.")
      .def_readonly("log_odds", &VoxelState::log_odds)
      .def_readonly("probability", &VoxelState::probability)
      .def_readonly("count", &VoxelState::count)
      .def("__repr__", [](const VoxelState& s) {
        return "VoxelState(log_odds=" + std::to_string(s.log_odds) + ", probability=" + std::to_string(s.probability) +
               ", count=" + std::to_string(s.count) + ")";
      });
  py::class_<MemoryStats>(m, "MemoryStats")
      .def_readonly("num_nodes", &MemoryStats::num_nodes)
      .def_readonly("num_leaf_nodes", &MemoryStats::num_leaf_nodes)
      .def_readonly("memory_mb", &MemoryStats::memory_mb, "bytes held in RAM / 2^20")
      .def_readonly("memory_efficiency", &MemoryStats::memory_efficiency);
  py::class_<HitStatistics>(m, "HitStatistics", "GMapping-style statistics of one voxel.")
      .def_property_readonly("mean_hit_position", [](const HitStatistics& s) { return to_numpy(s.mean_hit_position); },
                             "metres, map frame; the voxel centre without hits")
      .def_readonly("hits", &HitStatistics::hits)
      .def_readonly("visits", &HitStatistics::visits)
      .def_readonly("entropy", &HitStatistics::entropy, "nats");
  m.def("cell_entropy", &cell_entropy, py::arg("hits"), py::arg("visits"), "GMapping's cell entropy in nats.");
  readable_enum_name(py::enum_<BackendFeature>(m, "BackendFeature")
      .value("kWeights", BackendFeature::kWeights)
      .value("kScan", BackendFeature::kScan)
      .value("kQuery", BackendFeature::kQuery)
      .value("kParams", BackendFeature::kParams)
      .value("kSetLogOdds", BackendFeature::kSetLogOdds)
      .value("kHitStatistics", BackendFeature::kHitStatistics)
      .value("kClone", BackendFeature::kClone));
}

void bind_backend(py::module_& m) {
  py::class_<Backend, BackendPtr>(m, "IMapperBackend",
                                  "The map interface every backend implements. Points are metres in the map frame; "
                                  "calls release the GIL while the library works, and one map takes one call at a time.")
      .def(
          "batch_update_iwlo",
          [](Backend& map, const ArrayLike& points, const ArrayLike& intensities, const ArrayLike& is_occupied,
             const py::object& weights) {
            const Eigen::MatrixXd p = points_from(points);
            const double missing = intensities.is_none() ? unlocked(map, [&] { return map.get_params().intensity_max; }) : 0.0;
            const Eigen::VectorXd i = intensities_or(intensities, p.rows(), missing);
            const std::vector<bool> f = flags_from(is_occupied, "is_occupied", p.rows());
            if (weights.is_none()) return unlocked(map, [&] { map.batch_update_iwlo(p, i, f); });
            const Eigen::VectorXd w = values_from(weights, "weights", p.rows());
            unlocked(map, [&] { map.batch_update_iwlo(p, i, f, w); });
          },
          py::arg("points"), py::arg("intensities"), py::arg("is_occupied"), py::arg("weights") = py::none(),
          "One IWLO observation per row: points (N, 3) metres, map frame; intensities (N,) or None (every point at "
          "the map's intensity_max); is_occupied (N,) bool; "
          "optional weights (N,) in [0, 1]. Rows of one voxel apply in call order; NaN rows are skipped and counted.")
      .def(
          "insert_scan",
          [](Backend& map, const ArrayLike& origin, const ArrayLike& points, const ArrayLike& intensities,
             double max_range) {
            const Eigen::Vector3d o = vector3_from(origin, "origin");
            const Eigen::MatrixXd p = points_from(points);
            const double missing = intensities.is_none() ? unlocked(map, [&] { return map.get_params().intensity_max; }) : 0.0;
            const Eigen::VectorXd i = intensities_or(intensities, p.rows(), missing);
            unlocked(map, [&] { map.insert_scan(o, p, i, max_range); });
          },
          py::arg("origin"), py::arg("points"), py::arg("intensities") = py::none(), py::arg("max_range") = -1.0,
          "One scan: rays from origin (3,) to every point (N, 3), metres, map frame; a point whose intensity "
          "exceeds the threshold is a hit; intensities None: every point a return at the map's intensity_max. Each "
          "voxel gets one observation per scan (occupied wins). Rays longer than max_range metres (> 0) are clipped "
          "and give no hit.")
      .def(
          "set_iwlo_params",
          [](Backend& map, double sharpness, double decay_rate, double min_alpha, double L_min, double L_max) {
            unlocked(map, [&] { map.set_iwlo_params(sharpness, decay_rate, min_alpha, L_min, L_max); });
          },
          py::arg("sharpness"), py::arg("decay_rate"), py::arg("min_alpha"), py::arg("L_min"), py::arg("L_max"))
      .def(
          "set_log_odds_params",
          [](Backend& map, double occ, double free) { unlocked(map, [&] { map.set_log_odds_params(occ, free); }); },
          py::arg("log_odds_occupied"), py::arg("log_odds_free"))
      .def(
          "set_intensity_params",
          [](Backend& map, double th, double mx) { unlocked(map, [&] { map.set_intensity_params(th, mx); }); },
          py::arg("intensity_threshold"), py::arg("intensity_max"))
      .def(
          "set_adaptive_params",
          [](Backend& map, bool on, double th, double ratio) {
            unlocked(map, [&] { map.set_adaptive_params(on, th, ratio); });
          },
          py::arg("enabled"), py::arg("threshold"), py::arg("max_ratio"))
      .def(
          "set_occupied_threshold",
          [](Backend& map, double t) { unlocked(map, [&] { map.set_occupied_threshold(t); }); }, py::arg("threshold"))
      .def(
          "get_occupied_voxels",
          [](Backend& map, double min_probability) {
            const Eigen::MatrixXd v = unlocked(map, [&] { return map.get_occupied_voxels(min_probability); });
            return to_numpy(v);
          },
          py::arg("min_probability") = 0.5,
          "Voxels with probability > min_probability as an (N, 4) float64 array: centre x, y, z (metres, map "
          "frame) and p. A negative value means 0.5.")
      .def("get_memory_usage", [](Backend& map) { return unlocked(map, [&] { return map.get_memory_usage(); }); })
      .def("get_resolution", [](Backend& map) { return unlocked(map, [&] { return map.get_resolution(); }); },
           "voxel edge in metres")
      .def("get_num_nodes", [](Backend& map) { return unlocked(map, [&] { return map.get_num_nodes(); }); },
           "nodes of the storage: known voxels (RAM, Disk), octree nodes (OctoMap)")
      .def("get_num_known_voxels",
           [](Backend& map) { return unlocked(map, [&] { return map.get_num_known_voxels(); }); }, "known voxels")
      .def("clear", [](Backend& map) { unlocked(map, [&] { map.clear(); }); })
      .def("get_backend_type", [](Backend& map) { return unlocked(map, [&] { return map.get_backend_type(); }); })
      .def("flush", [](Backend& map) { unlocked(map, [&] { map.flush(); }); },
           "Makes everything so far durable (Disk); a no-op for RAM maps.")
      .def(
          "preload_region",
          [](Backend& map, const ArrayLike& lo, const ArrayLike& hi) {
            const Eigen::Vector3d a = vector3_from(lo, "min_bound"), b = vector3_from(hi, "max_bound");
            unlocked(map, [&] { map.preload_region(a, b); });
          },
          py::arg("min_bound"), py::arg("max_bound"), "Loads the tiles of a box (metres) ahead of use (Disk).")
      .def("get_disk_usage", [](Backend& map) { return unlocked(map, [&] { return map.get_disk_usage(); }); },
           "bytes on disk")
      .def("prune", [](Backend& map) { return unlocked(map, [&] { return map.prune(); }); })
      .def("supports_persistence", [](Backend& map) { return unlocked(map, [&] { return map.supports_persistence(); }); })
      .def(
          "supports", [](Backend& map, BackendFeature f) { return unlocked(map, [&] { return map.supports(f); }); },
          py::arg("feature"))
      .def(
          "query",
          [](Backend& map, const ArrayLike& point) -> py::object {
            const py::array a = as_array(point, "point");
            if (a.ndim() != 2) {
              const Eigen::Vector3d p = vector3_from(point, "point");
              return py::cast(unlocked(map, [&] { return map.query(p); }));
            }
            // (N, 3): one call for all points, the states as arrays.
            const Eigen::MatrixXd p = points_from(point, "point");
            const Eigen::Index n = p.rows();
            Eigen::VectorXd log_odds(n), probability(n);
            std::vector<std::uint32_t> counts(static_cast<std::size_t>(n));
            std::vector<bool> known(static_cast<std::size_t>(n));
            unlocked(map, [&] {
              constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
              for (Eigen::Index r = 0; r < n; ++r) {
                const std::optional<VoxelState> s = map.query(p.row(r).transpose());
                const auto i = static_cast<std::size_t>(r);
                known[i] = s.has_value();
                log_odds[r] = s ? s->log_odds : kNaN;
                probability[r] = s ? s->probability : kNaN;
                counts[i] = s ? s->count : 0;
              }
            });
            py::array_t<bool> k(n);
            py::array_t<std::uint32_t> c(n);
            for (Eigen::Index r = 0; r < n; ++r) {
              k.mutable_at(r) = known[static_cast<std::size_t>(r)];
              c.mutable_at(r) = counts[static_cast<std::size_t>(r)];
            }
            py::dict out;
            out["known"] = k;
            out["log_odds"] = to_numpy(log_odds);
            out["probability"] = to_numpy(probability);
            out["count"] = c;
            return out;
          },
          py::arg("point"),
          "The voxel containing point (3,) (metres, map frame), or None when it is unknown. For points (N, 3): a "
          "dict of (N,) arrays 'known' (bool), 'log_odds' and 'probability' (NaN where unknown) and 'count' "
          "(0 where unknown), in one call.")
      .def(
          "for_each_voxel",
          [](Backend& map, const std::function<void(const VoxelKey&, const VoxelState&)>& visit) {
            // The callback runs Python: the GIL stays held, the map's lock is taken, and the
            // visitor's calls into this map are refused (they would wait on that lock).
            refuse_call_from_visitor(map);
            const std::lock_guard<std::mutex> lock(map_mutex(map));
            const VisitScope scope(map);
            map.for_each_voxel(visit);
          },
          py::arg("visit"),
          "Calls visit(key, state) for every known voxel. The visitor may not call into this map "
          "(RuntimeError); other maps are fine.")
      .def(
          "get_voxels",
          [](Backend& map) {
            std::vector<VoxelKey> keys;
            std::vector<VoxelState> states;
            unlocked(map, [&] {
              map.for_each_voxel([&](const VoxelKey& k, const VoxelState& s) {
                keys.push_back(k);
                states.push_back(s);
              });
            });
            const auto n = static_cast<py::ssize_t>(keys.size());
            py::array_t<std::int32_t> k({n, py::ssize_t{3}});
            py::array_t<double> lo(n);
            py::array_t<std::uint32_t> c(n);
            auto wk = k.mutable_unchecked<2>();
            auto wl = lo.mutable_unchecked<1>();
            auto wc = c.mutable_unchecked<1>();
            for (py::ssize_t i = 0; i < n; ++i) {
              const auto& key = keys[static_cast<std::size_t>(i)];
              wk(i, 0) = key.x;
              wk(i, 1) = key.y;
              wk(i, 2) = key.z;
              wl(i) = states[static_cast<std::size_t>(i)].log_odds;
              wc(i) = states[static_cast<std::size_t>(i)].count;
            }
            return py::make_tuple(k, lo, c);
          },
          "Every known voxel as (keys (N, 3) int32, log_odds (N,) float64, counts (N,) uint32), in the map's order.")
      .def("get_num_skipped_points",
           [](Backend& map) { return unlocked(map, [&] { return map.get_num_skipped_points(); }); })
      .def(
          "set_params", [](Backend& map, const IwloParams& p) { unlocked(map, [&] { map.set_params(p); }); },
          py::arg("params"))
      .def("get_params", [](Backend& map) { return unlocked(map, [&] { return map.get_params(); }); })
      .def(
          "set_log_odds",
          [](Backend& map, const ArrayLike& points, const ArrayLike& log_odds) {
            const Eigen::MatrixXd p = points_from(points);
            const Eigen::VectorXd l = values_from(log_odds, "log_odds", p.rows());
            unlocked(map, [&] { map.set_log_odds(p, l); });
          },
          py::arg("points"), py::arg("log_odds"), "Sets the voxels of points (N, 3) to log_odds (N,) (imports).")
      .def(
          "set_hit_accumulation", [](Backend& map, bool on) { unlocked(map, [&] { map.set_hit_accumulation(on); }); },
          py::arg("enabled"))
      .def("get_hit_accumulation", [](Backend& map) { return unlocked(map, [&] { return map.get_hit_accumulation(); }); })
      .def(
          "hit_statistics",
          [](Backend& map, const ArrayLike& point) {
            const Eigen::Vector3d p = vector3_from(point, "point");
            return unlocked(map, [&] { return map.hit_statistics(p); });
          },
          py::arg("point"))
      .def(
          "get_occupied_mean_positions",
          [](Backend& map, double min_probability) {
            return to_numpy(unlocked(map, [&] { return map.get_occupied_mean_positions(min_probability); }));
          },
          py::arg("min_probability") = 0.5, "As get_occupied_voxels(), at each voxel's mean hit position.")
      .def("clone",
           [](Backend& map) { return BackendPtr(unlocked(map, [&] { return map.clone(); })); })
      .def(
          "set_num_threads", [](Backend& map, int t) { unlocked(map, [&] { map.set_num_threads(t); }); },
          py::arg("threads"), "Threads for one call (0: all hardware threads); the map is identical for any count.")
      .def("get_num_threads", [](Backend& map) { return unlocked(map, [&] { return map.get_num_threads(); }); })
      .def(
          "set_ray_model", [](Backend& map, RayModel model) { unlocked(map, [&] { map.set_ray_model(model); }); },
          py::arg("model"),
          "The voxels insert_scan() marks free: RayModel.kExact (default), every voxel a ray crosses; "
          "RayModel.kFast, a 26-connected line, up to 3x fewer steps and fewer free voxels. Hits are the same.")
      .def("get_ray_model", [](Backend& map) { return unlocked(map, [&] { return map.get_ray_model(); }); })
      .def(
          "get_last_scan_phases",
          [](Backend& map) { return unlocked(map, [&] { return map.get_last_scan_phases(); }); },
          "Where the last insert_scan() spent its time, in seconds (ScanPhaseTimes): the phases on the threads "
          "and those on the calling thread, the serial share and Amdahl's projection.")
      .def(
          "set_progress_callback",
          [](Backend& map, const py::object& callback) {
            ProgressCallback cb = python_progress(callback, map);
            unlocked(map, [&] { map.set_progress_callback(std::move(cb)); });
          },
          py::arg("callback"),
          "callback(stage, done, total) hears the progress of insert_scan() (stage 'casting rays', then "
          "'updating voxels') and of a Disk map's flush() ('writing tiles'), on the calling thread; None turns it "
          "off. An exception it raises while rays are cast cancels the scan (map unchanged); later ones are raised "
          "once the call is done. Calling into the map from it raises RuntimeError.")
      .def("__repr__", [](Backend& map) {
        return "<iwlomap " + map.get_backend_type() + " map, " + std::to_string(map.get_num_known_voxels()) +
               " known voxels at " + std::to_string(map.get_resolution()) + " m>";
      });

  py::class_<ProbabilityUpdater, Backend, std::shared_ptr<ProbabilityUpdater>>(m, "ProbabilityUpdater",
                                                                               "The RAM backend (block grid).")
      .def(py::init<double>(), py::arg("resolution") = 0.05, "resolution: voxel edge in metres");

  py::class_<DiskMapInfo>(m, "DiskMapInfo")
      .def_readonly("resolution", &DiskMapInfo::resolution)
      .def_readonly("tile_size", &DiskMapInfo::tile_size)
      .def_readonly("tile_voxels", &DiskMapInfo::tile_voxels)
      .def_readonly("format_version", &DiskMapInfo::format_version);
  py::class_<DiskMapRepair>(m, "DiskMapRepair")
      .def_readonly("set_aside", &DiskMapRepair::set_aside)
      .def_readonly("tiles_kept", &DiskMapRepair::tiles_kept);
  py::class_<OutofcoreTileMapper, Backend, std::shared_ptr<OutofcoreTileMapper>>(
      m, "OutofcoreTileMapper", "The Disk backend: a map larger than RAM in crash-safe tiles of a directory.")
      .def(py::init([](const PathLike& directory, double resolution, double tile_size, size_t cache_tiles) {
             const std::string dir = path_from(directory);
             py::gil_scoped_release release;
             return std::make_shared<OutofcoreTileMapper>(dir, resolution, tile_size, cache_tiles);
           }),
           py::arg("directory"), py::arg("resolution") = OutofcoreTileMapper::kStored,
           py::arg("tile_size") = OutofcoreTileMapper::kStored, py::arg("cache_tiles") = 16,
           "Opens or creates the map in directory (resolution and tile_size in metres; cache_tiles resident tiles). "
           "resolution and tile_size 0 (the defaults): an existing map's stored values, or 0.05 m and 10 m for a new "
           "map.")
      .def_static(
          "open_read_only",
          [](const PathLike& directory, size_t cache_tiles) {
            const std::string dir = path_from(directory);
            py::gil_scoped_release release;
            return std::make_shared<OutofcoreTileMapper>(OutofcoreTileMapper::open_read_only(dir, cache_tiles));
          },
          py::arg("directory"), py::arg("cache_tiles") = 16,
          "Reads the map's last commit, writing nothing; a writer may go on committing beside it.")
      .def_static(
          "repair",
          [](const PathLike& directory) {
            const std::string dir = path_from(directory);
            py::gil_scoped_release release;
            return OutofcoreTileMapper::repair(dir);
          },
          py::arg("directory"), "Sets the damaged tiles of a map aside so that the rest can be used.")
      .def_static(
          "read_map_info", [](const PathLike& directory) { return OutofcoreTileMapper::read_map_info(path_from(directory)); },
          py::arg("directory"))
      .def("is_read_only", &OutofcoreTileMapper::is_read_only)
      .def("get_directory", &OutofcoreTileMapper::get_directory)
      .def("get_tile_size", &OutofcoreTileMapper::get_tile_size, "metres")
      .def("get_tile_voxels", &OutofcoreTileMapper::get_tile_voxels)
      .def("get_cache_tiles", &OutofcoreTileMapper::get_cache_tiles)
      .def("get_num_resident_tiles", [](OutofcoreTileMapper& map) { return unlocked(map, [&] { return map.get_num_resident_tiles(); }); })
      .def("get_num_tiles", [](OutofcoreTileMapper& map) { return unlocked(map, [&] { return map.get_num_tiles(); }); })
      .def("get_peak_resident_tiles", [](OutofcoreTileMapper& map) { return unlocked(map, [&] { return map.get_peak_resident_tiles(); }); })
      .def(
          "copy_to",
          [](OutofcoreTileMapper& map, const PathLike& directory) {
            const std::string dir = path_from(directory);
            unlocked(map, [&] { map.copy_to(dir); });
          },
          py::arg("directory"))
      .def(
          "rollback", [](OutofcoreTileMapper& map) { unlocked(map, [&] { map.rollback(); }); },
          "Gives up every change since the last flush(); nothing on disk changes.")
      .def("__enter__", [](const std::shared_ptr<OutofcoreTileMapper>& map) { return map; })
      // A block that ends normally commits; one that raises gives its changes up, so that a failed
      // run leaves the map on disk as it was.
      .def("__exit__", [](OutofcoreTileMapper& map, const py::object& type, const py::object&, const py::object&) {
        if (map.is_read_only()) return false;
        if (type.is_none())
          unlocked(map, [&] { map.flush(); });
        else
          unlocked(map, [&] { map.rollback(); });
        return false;
      });

  py::class_<BackendOptions>(m, "BackendOptions")
      .def(py::init([](const std::string& directory, double tile_size, size_t cache_tiles, double prob_hit,
                       double prob_miss) {
             return BackendOptions{directory, tile_size, cache_tiles, prob_hit, prob_miss};
           }),
           py::kw_only(), py::arg("directory") = "", py::arg("tile_size") = 10.0, py::arg("cache_tiles") = 16,
           py::arg("prob_hit") = 0.7, py::arg("prob_miss") = 0.3)
      .def_readwrite("directory", &BackendOptions::directory)
      .def_readwrite("tile_size", &BackendOptions::tile_size)
      .def_readwrite("cache_tiles", &BackendOptions::cache_tiles)
      .def_readwrite("prob_hit", &BackendOptions::prob_hit)
      .def_readwrite("prob_miss", &BackendOptions::prob_miss);
  m.def(
      "make_backend",
      [](const std::string& type, double resolution, const std::optional<BackendOptions>& options) {
        const BackendOptions o = options.value_or(BackendOptions{});
        py::gil_scoped_release release;
        return BackendPtr(make_backend(type, resolution, o));
      },
      py::arg("type"), py::arg("resolution") = 0.05, py::arg("options") = py::none(),
      "A backend by name ('RAM', 'Disk', 'OctoMap'; see available_backends()).");
  m.def("available_backends", &available_backends);
}

void bind_misc(py::module_& m) {
  m.def("set_map_memory_limit", &set_map_memory_limit, py::arg("bytes"),
        "Caps the bytes all maps of the process may hold (0: no limit); a call that would pass it raises "
        "MemoryLimitError before changing the map.");
  m.def("get_map_memory_limit", &get_map_memory_limit);
  m.def("get_map_memory_in_use", &get_map_memory_in_use);

  py::class_<VoxelColorMeans>(m, "VoxelColorMeans",
                              "The running mean 8-bit colour of the hits in each voxel, beside any map.")
      .def(py::init<double>(), py::arg("resolution"))
      .def("resolution", &VoxelColorMeans::resolution)
      .def(
          "add_scan",
          [](VoxelColorMeans& c, const ArrayLike& origin, const ArrayLike& points, const ArrayLike& intensities,
             const ArrayLike& colors, const IwloParams& params, double max_range) {
            const Eigen::Vector3d o = vector3_from(origin, "origin");
            const Eigen::MatrixXd p = points_from(points);
            const Eigen::VectorXd i = values_from(intensities, "intensities", p.rows());
            const ColorMatrix rgb = colors_from(colors, "colors", p.rows());
            py::gil_scoped_release release;
            c.add_scan(o, p, i, rgb, params, max_range);
          },
          py::arg("origin"), py::arg("points"), py::arg("intensities"), py::arg("colors"), py::arg("params"),
          py::arg("max_range") = -1.0, "The hits of one scan as insert_scan() counts them; colors (N, 3) uint8.")
      .def(
          "add_observations",
          [](VoxelColorMeans& c, const ArrayLike& points, const ArrayLike& intensities, const ArrayLike& flags,
             const ArrayLike& colors, const IwloParams& params) {
            const Eigen::MatrixXd p = points_from(points);
            c.add_observations(p, values_from(intensities, "intensities", p.rows()),
                               flags_from(flags, "is_occupied", p.rows()), colors_from(colors, "colors", p.rows()),
                               params);
          },
          py::arg("points"), py::arg("intensities"), py::arg("is_occupied"), py::arg("colors"), py::arg("params"))
      .def(
          "mean",
          [](const VoxelColorMeans& c, const ArrayLike& point) -> std::optional<py::tuple> {
            const auto m = c.mean(vector3_from(point, "point"));
            if (!m) return std::nullopt;
            return py::make_tuple(m->r, m->g, m->b);
          },
          py::arg("point"), "(r, g, b) of the voxel containing point, or None.")
      .def(
          "hits", [](const VoxelColorMeans& c, const ArrayLike& point) { return c.hits(vector3_from(point, "point")); },
          py::arg("point"))
      .def(
          "colors_at",
          [](const VoxelColorMeans& c, const ArrayLike& positions) {
            return to_numpy(c.colors_at(rows_from(positions, "positions", 3, 4)));
          },
          py::arg("positions"), "(N, 3) uint8 mean colours of the voxels of rows (x, y, z[, p]); 0 without hits.")
      .def("size", &VoxelColorMeans::size)
      .def("__len__", &VoxelColorMeans::size)
      .def("memory_bytes", &VoxelColorMeans::memory_bytes)
      .def("clear", &VoxelColorMeans::clear);

  m.def("occupancy_entropy_bits", &occupancy_entropy_bits, py::arg("probability"));
  m.def(
      "map_entropy_bits", [](Backend& map) { return unlocked(map, [&] { return map_entropy_bits(map); }); },
      py::arg("map"), "Sum of the binary entropies of the known voxels, bits.");
  py::class_<BoxEntropy>(m, "BoxEntropy")
      .def_readonly("known_bits", &BoxEntropy::known_bits)
      .def_readonly("known_voxels", &BoxEntropy::known_voxels)
      .def_readonly("unknown_voxels", &BoxEntropy::unknown_voxels)
      .def("total_bits", &BoxEntropy::total_bits);
  m.def(
      "box_entropy", [](Backend& map, const VoxelBox& box) { return unlocked(map, [&] { return box_entropy(map, box); }); },
      py::arg("map"), py::arg("box"));
  m.def(
      "count_unknown_voxels",
      [](Backend& map, const VoxelBox& box) { return unlocked(map, [&] { return count_unknown_voxels(map, box); }); },
      py::arg("map"), py::arg("box"));
  m.def(
      "known_voxel_box", [](Backend& map) { return unlocked(map, [&] { return known_voxel_box(map); }); },
      py::arg("map"), "The smallest box holding every known voxel, or None for an empty map.");

  const SyntheticScanOptions d;
  m.def(
      "make_synthetic_scan",
      [](int rings, int columns, double sensor_height, const ArrayLike& sensor_xy, double range_noise,
         double intensity_noise, std::uint32_t seed) {
        SyntheticScanOptions o;
        o.rings = rings;
        o.columns = columns;
        o.sensor_height = sensor_height;
        const py::array xy = as_array(sensor_xy, "sensor_xy");
        const Eigen::VectorXd v = values_from(xy, "sensor_xy", 2);
        o.sensor_xy = Eigen::Vector2d(v[0], v[1]);
        o.range_noise = range_noise;
        o.intensity_noise = intensity_noise;
        o.seed = seed;
        const SyntheticScan s = make_synthetic_scan(o);
        return py::make_tuple(to_numpy(s.origin), to_numpy(s.points), to_numpy(s.intensities));
      },
      py::kw_only(), py::arg("rings") = d.rings, py::arg("columns") = d.columns,
      py::arg("sensor_height") = d.sensor_height, py::arg("sensor_xy") = py::make_tuple(0.0, 0.0),
      py::arg("range_noise") = d.range_noise, py::arg("intensity_noise") = d.intensity_noise, py::arg("seed") = d.seed,
      "The synthetic courtyard scan of `iwlomap generate`: (origin (3,), points (N, 3), intensities (N,)), metres.");
}

}  // namespace

namespace {
thread_local std::vector<const IMapperBackend*> visiting;  // maps whose visitor this thread runs
}  // namespace

void refuse_call_from_visitor(const IMapperBackend& map) {
  if (std::find(visiting.begin(), visiting.end(), &map) != visiting.end())
    throw std::runtime_error(
        "iwlomap: a for_each_voxel() visitor may not call into the map it visits (the visit holds the map); "
        "collect what you need in the visitor and call after it, or use get_voxels()");
}

ProgressCallback python_progress(const py::object& fn, const IMapperBackend& map) {
  if (fn.is_none()) return {};
  if (!PyCallable_Check(fn.ptr())) throw py::type_error("progress: expected a callable(stage, done, total) or None");
  // The callback may be dropped where the GIL is not held (replaced inside a call): its Python
  // object is released under the GIL.
  const std::shared_ptr<py::object> held(new py::object(fn), [](py::object* o) {
    py::gil_scoped_acquire gil;
    delete o;
  });
  const IMapperBackend* target = &map;
  return [held, target](const ProgressReport& r) {
    py::gil_scoped_acquire gil;
    const VisitScope scope(*target);
    (*held)(progress_stage_name(r.stage), r.done, r.total);
  };
}

VisitScope::VisitScope(const IMapperBackend& map) { visiting.push_back(&map); }
VisitScope::~VisitScope() { visiting.pop_back(); }

std::mutex& map_mutex(const IMapperBackend& map) {
  static std::mutex table_lock;
  static std::unordered_map<const IMapperBackend*, std::unique_ptr<std::mutex>> table;
  const std::lock_guard<std::mutex> lock(table_lock);
  auto& slot = table[&map];
  if (!slot) slot = std::make_unique<std::mutex>();
  return *slot;
}

std::string path_from(const py::handle& obj) {
  const py::object fspath = py::module_::import("os").attr("fspath");
  const py::object p = fspath(obj);
  if (!py::isinstance<py::str>(p)) throw py::value_error("paths must be str or os.PathLike of str");
  return p.cast<std::string>();
}

void bind_core(py::module_& m) {
  bind_params(m);
  bind_keys(m);
  bind_states(m);
  bind_backend(m);
  bind_misc(m);
}

}  // namespace iwlomap::python
