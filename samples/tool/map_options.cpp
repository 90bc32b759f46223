// SPDX-License-Identifier: BSD-3-Clause
#include "map_options.h"

#include "progress.h"

#include <iwlomap/map_memory.h>
#include <iwlomap/outofcore_tile_mapper.h>

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <iostream>
#include <filesystem>
#include <cctype>
#include <iomanip>
#include <sstream>
#include <charconv>
#include <cstdio>
#include <limits>
#include <optional>

namespace iwlomap::tool {

std::set<std::string> map_value_options() {
  return {"--resolution", "--backend", "--tiles", "--max-range", "--sensor", "--threshold",
          "--sharpness", "--decay-rate", "--min-alpha", "--l-min", "--l-max", "--l-occ", "--l-free",
          "--intensity-threshold", "--intensity-max", "--adaptive-threshold", "--adaptive-max-ratio",
          "--threads", "--tile-size", "--cache-tiles", "--max-memory", "--rays"};
}

std::set<std::string> map_flag_options() { return {"--no-rays", "--no-adaptive"}; }

std::string map_options_help(bool rays, SensorPreset default_sensor) {
  const IwloParams d;
  const auto num = [](double v) { return shortest(v); };
  const std::string ray_options = rays ? R"(  --max-range M             clip rays longer than M metres (> 0); those points give no hit
                            (default and 'none': no limit)
  --no-rays                 no ray casting: every point is one observation, occupied iff its
                            intensity exceeds the threshold (sonar pipelines)
  --rays exact|fast         the voxels a ray marks free: exact (default), every voxel the ray
                            crosses; fast, a 26-connected line between voxel centres, up to 3x
                            fewer steps per ray but fewer free voxels (a voxel the ray only
                            clips at an edge or corner stays as it was); hits are the same
)" : "";
  return std::string(R"(
map:
  --resolution M            voxel edge in metres (default 0.05)
  --backend ram|disk|octomap  map storage (default ram)
  --tiles DIR               map directory of the disk backend; an existing map there is continued
                            (with its stored resolution and tile size unless given); the run's
                            changes are committed at its end, all at once: a run that fails
                            leaves the map as it was ('iwlomap repair DIR' for a damaged tile)
  --tile-size M             disk backend: tile edge in metres, rounded to whole blocks of 8 voxels
                            (default 10; 'iwlomap info DIR' prints the size in use)
  --cache-tiles N           disk backend: tiles kept in RAM (default 16)
)") + ray_options + R"(  --sensor sonar|lidar|depth  preset (default )" + sensor_preset_name(default_sensor) + R"(); lidar: every return is a hit
                            weighted by its intensity, however dark, and moved obstacles clear
                            after 7 free observations as in OctoMap; depth: as lidar with every
                            return full weight; sonar: the reference defaults, an echo at or below
                            the intensity threshold is free space. The options below override the
                            preset; the defaults given with them are the reference's (sonar).
                            A run warns when its preset makes most returns free space.
  --threshold P             output voxels with occupancy probability > P (default )" + num(d.occupied_threshold) + R"()
  --threads N               threads for ray casting (default 1; 0 = all cores); same map for any N
  --max-memory SIZE         memory the map may hold, in bytes or with a suffix K, M, G, T (powers
                            of 1024), or 'none'; past it the run stops with an error before the
                            scan that would pass it changes the map (default: 3/4 of the physical
                            memory, or half of the address space left under 'ulimit -v' if less)

IWLO parameters (defaults in brackets):
  --sharpness S [)" + num(d.sharpness) + R"(]   --decay-rate D [)" + num(d.decay_rate) + R"(]   --min-alpha A [)" + num(d.min_alpha) + R"(]
  --l-min L [)" + num(d.L_min) + R"(]   --l-max L [)" + num(d.L_max) + R"(]   --l-occ L [)" + num(d.log_odds_occupied) + R"(]   --l-free L [)" + num(d.log_odds_free) + R"(]
  --intensity-threshold I [)" + num(d.intensity_threshold) + R"(]   --intensity-max I [)" + num(d.intensity_max) + R"(]
  --no-adaptive   --adaptive-threshold P [)" + num(d.adaptive_threshold) + R"(]   --adaptive-max-ratio R [)" + num(d.adaptive_max_ratio) + R"(]
)";
}

std::size_t default_memory_limit() {
  const long pages = sysconf(_SC_PHYS_PAGES);
  const long page = sysconf(_SC_PAGESIZE);
  std::size_t limit = pages > 0 && page > 0 ? static_cast<std::size_t>(pages) / 4 * 3 * static_cast<std::size_t>(page)
                                            : std::size_t{0};
  rlimit as{};
  if (getrlimit(RLIMIT_AS, &as) == 0 && as.rlim_cur != RLIM_INFINITY) {
    // The address space already taken (libraries, the input reader) is not available to the map;
    // half of what is left leaves room for the scan's input and the outputs.
    std::size_t used = 0;
    if (std::FILE* f = std::fopen("/proc/self/statm", "r")) {
      unsigned long size_pages = 0;
      if (std::fscanf(f, "%lu", &size_pages) == 1 && page > 0) used = size_pages * static_cast<std::size_t>(page);
      std::fclose(f);
    }
    const auto cap = static_cast<std::size_t>(as.rlim_cur);
    const std::size_t left = cap > used ? (cap - used) / 2 : std::size_t{1};
    limit = limit == 0 ? left : std::min(limit, left);
  }
  return limit;
}

std::string beyond_memory_budget(double bytes) {
  const double budget = static_cast<double>(default_memory_limit());
  if (bytes <= budget) return {};
  std::ostringstream m;
  m << std::setprecision(3) << "about " << bytes / 1e9 << " GB, more than the memory budget of " << budget / 1e9
    << " GB (3/4 of the memory, or of what ulimit -v leaves)";
  return m.str();
}

std::size_t parse_memory_size(const std::string& text) {
  if (text == "none") return 0;
  unsigned long long value = 0;
  const char* const end = text.data() + text.size();
  const auto [at, ec] = std::from_chars(text.data(), end, value);
  const auto bad = [&] {
    return UsageError("--max-memory must be a byte count with an optional K, M, G or T suffix, or 'none', got '" +
                      text + "'");
  };
  if (ec != std::errc() || at == text.data()) throw bad();
  int shift = 0;
  if (at != end) {
    if (at + 1 != end) throw bad();
    switch (*at) {
      case 'K': case 'k': shift = 10; break;
      case 'M': case 'm': shift = 20; break;
      case 'G': case 'g': shift = 30; break;
      case 'T': case 't': shift = 40; break;
      default: throw bad();
    }
  }
  if (value == 0) throw UsageError("--max-memory must be > 0 (or 'none' for no limit)");
  if (value > (std::numeric_limits<std::size_t>::max() >> shift)) throw bad();
  return static_cast<std::size_t>(value) << shift;
}

MapSetup map_setup_from(const Args& args, SensorPreset default_sensor, const std::optional<IwloParams>& base,
                        bool open_map) {
  MapSetup s;
  if (base) {
    s.params = *base;
  } else {
    const auto preset = args.has("--sensor") ? parse_sensor_preset(*args.value("--sensor")) : default_sensor;
    if (!preset) throw UsageError("--sensor must be sonar, lidar or depth, got '" + *args.value("--sensor") + "'");
    s.sensor = *preset;
    s.params = sensor_preset_params(*preset);
  }
  IwloParams& p = s.params;
  p.sharpness = args.number("--sharpness", p.sharpness);
  p.decay_rate = args.number("--decay-rate", p.decay_rate);
  p.min_alpha = args.number("--min-alpha", p.min_alpha);
  p.L_min = args.number("--l-min", p.L_min);
  p.L_max = args.number("--l-max", p.L_max);
  p.log_odds_occupied = args.number("--l-occ", p.log_odds_occupied);
  p.log_odds_free = args.number("--l-free", p.log_odds_free);
  p.intensity_threshold = args.number("--intensity-threshold", p.intensity_threshold);
  p.intensity_max = args.number("--intensity-max", p.intensity_max);
  if (args.flag("--no-adaptive")) p.adaptive_enabled = false;
  p.adaptive_threshold = args.number("--adaptive-threshold", p.adaptive_threshold);
  p.adaptive_max_ratio = args.number("--adaptive-max-ratio", p.adaptive_max_ratio);
  p.occupied_threshold = args.number("--threshold", p.occupied_threshold);
  try {
    p.validate();
  } catch (const std::invalid_argument& e) {
    throw UsageError(e.what());
  }

  double resolution = args.resolution().value_or(0.05);
  // "none" (or no option) is no limit, the library's negative range; 0 or a negative value on the
  // command line is a mistake, not a request for no limit.
  s.max_range = args.positive_or_none("--max-range").value_or(-1.0);
  s.ray_casting = !args.flag("--no-rays");
  if (const auto rays = args.value("--rays")) {
    const std::optional<RayModel> model = parse_ray_model(*rays);
    if (!model) throw UsageError("--rays must be exact or fast, got '" + *rays + "'");
    s.rays = *model;
    // (exact is the default, so --print-config writes it beside no-rays: true; fast asks for rays)
    if (s.rays == RayModel::kFast && !s.ray_casting)
      throw UsageError("--rays fast chooses how rays are cast: it cannot go with --no-rays");
  }

  std::string backend = args.value("--backend").value_or("ram");
  std::transform(backend.begin(), backend.end(), backend.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  BackendOptions options;
  if (backend == "disk") {
    const auto tiles = args.value("--tiles");
    if (!tiles) throw UsageError("--backend disk needs --tiles DIR");
    options.directory = *tiles;
    options.tile_size = args.number("--tile-size", options.tile_size);
    if (!(options.tile_size > 0.0)) throw UsageError("--tile-size must be > 0 metres");
    const long cache = args.integer("--cache-tiles", static_cast<long>(options.cache_tiles));
    if (cache < 1) throw UsageError("--cache-tiles must be >= 1");
    options.cache_tiles = static_cast<std::size_t>(cache);
    // An existing map continues with its stored geometry unless the options say otherwise
    // (and then the backend reports the mismatch).
    std::error_code ec;
    if (open_map && std::filesystem::exists(std::filesystem::path(*tiles) / "iwlomap_map.meta", ec)) {
      const DiskMapInfo info = OutofcoreTileMapper::read_map_info(*tiles);
      if (!args.has("--resolution")) resolution = info.resolution;
      if (!args.has("--tile-size")) options.tile_size = info.tile_size;
    }
  } else if (args.has("--tiles") || args.has("--tile-size") || args.has("--cache-tiles")) {
    throw UsageError("--tiles, --tile-size and --cache-tiles are only for --backend disk");
  } else if (backend != "ram" && backend != "octomap") {
    throw UsageError("--backend must be ram, disk or octomap, got '" + backend + "'");
  }
  const long threads = args.integer("--threads", 1);
  if (threads < 0) throw UsageError("--threads must be >= 0 (0 = all cores)");
  const auto max_memory = args.value("--max-memory");
  s.memory_limit = max_memory ? parse_memory_size(*max_memory) : default_memory_limit();
  set_map_memory_limit(s.memory_limit);
  s.backend = backend;
  s.backend_options = options;
  s.resolution = resolution;
  s.threads = static_cast<int>(threads);
  if (!open_map) return s;
  s.map = make_backend(backend, resolution, options);
  s.map->set_params(p);
  s.map->set_num_threads(static_cast<int>(threads));
  s.map->set_ray_model(s.rays);
  return s;
}

void warn_skipped_points(const char* command, std::size_t skipped, std::size_t points, double resolution,
                         bool ray_casting) {
  show_status(true, "");
  std::cerr << "iwlomap " << command << ": warning: " << skipped << " of " << points
            << " points skipped: a coordinate or intensity not finite";
  if (ray_casting)
    std::cerr << ", or farther than " << shortest(kMaxRayVoxels * resolution) << " m (" << shortest(kMaxRayVoxels)
              << " voxels) from the sensor origin (a stray return; --max-range clips such rays instead)";
  std::cerr << "\n";
}

void IntensityWarning::check(const std::string& file, const Eigen::VectorXd& intensities, const IwloParams& params) {
  if (warned_) return;
  const IntensityCheck c = check_intensities(intensities, params);
  if (!c.thins_map()) return;
  show_status(true, "");  // on a line of its own, not after a progress bar
  std::cerr << "iwlomap " << command_ << ": warning: " << file << ": " << c.advice() << " (--sensor lidar)\n";
  warned_ = true;
}

MapCommit::~MapCommit() {
  if (committed_) return;
  if (auto* disk = dynamic_cast<OutofcoreTileMapper*>(map_.get())) disk->rollback();
}

void MapCommit::commit() {
  map_->flush();
  committed_ = true;
}

}  // namespace iwlomap::tool
