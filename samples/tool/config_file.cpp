// SPDX-License-Identifier: BSD-3-Clause
#include "config_file.h"

#include <iwlomap/sensor_preset.h>

#include <yaml-cpp/yaml.h>

#include <fstream>
#include <sstream>
#include <stdexcept>

namespace iwlomap::tool {

Args args_with_config(const std::vector<std::string>& argv, std::set<std::string> value_options,
                      const std::set<std::string>& flags, const std::set<std::string>& allowed) {
  value_options.insert("--config");
  Args first(argv, value_options, flags);
  const auto path = first.value("--config");
  if (!path) return first;
  if (!std::ifstream(*path).good()) throw std::runtime_error("--config: cannot open '" + *path + "'");
  YAML::Node root;
  try {
    root = YAML::LoadFile(*path);
  } catch (const YAML::Exception& e) {
    throw UsageError("--config '" + *path + "' line " + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
  if (root.IsNull()) return first;  // an empty file
  if (!root.IsMap()) throw UsageError("--config '" + *path + "': expected 'option: value' lines (a YAML mapping)");
  std::vector<std::string> extended = argv;
  for (const auto& entry : root) {
    const auto where = "--config '" + *path + "' line " + std::to_string(entry.first.Mark().line + 1) + ": ";
    if (!entry.first.IsScalar()) throw UsageError(where + "a key must be an option name");
    const std::string key = entry.first.as<std::string>();
    const std::string option = "--" + key;
    if (allowed.count(option) == 0)
      throw UsageError(where + "'" + key + "' is not an option this file may set (the options of --help without their dashes)");
    if (!entry.second.IsScalar()) throw UsageError(where + "'" + key + "' needs one value");
    const std::string value = entry.second.as<std::string>();
    if (first.has(option)) continue;  // the command line wins
    if (flags.count(option) > 0) {
      if (value == "true") extended.push_back(option);
      else if (value != "false") throw UsageError(where + "'" + key + "' is true or false, got '" + value + "'");
      continue;
    }
    extended.push_back(option);
    extended.push_back(value);
  }
  return Args(extended, value_options, flags);
}

std::string config_yaml(const MapSetup& setup, const std::string& command) {
  const IwloParams& p = setup.params;
  std::ostringstream out;
  out << "# iwlomap " << command << ": the effective configuration (read it back with --config FILE;\n"
      << "# options on the command line win over the file)\n"
      << "sensor: " << sensor_preset_name(setup.sensor) << "\n"
      << "resolution: " << shortest(setup.resolution) << "\n"
      << "max-range: " << (setup.max_range > 0.0 ? shortest(setup.max_range) : std::string("none")) << "\n"
      << "threshold: " << shortest(p.occupied_threshold) << "\n"
      << "sharpness: " << shortest(p.sharpness) << "\n"
      << "decay-rate: " << shortest(p.decay_rate) << "\n"
      << "min-alpha: " << shortest(p.min_alpha) << "\n"
      << "l-min: " << shortest(p.L_min) << "\n"
      << "l-max: " << shortest(p.L_max) << "\n"
      << "l-occ: " << shortest(p.log_odds_occupied) << "\n"
      << "l-free: " << shortest(p.log_odds_free) << "\n"
      << "intensity-threshold: " << shortest(p.intensity_threshold) << "\n"
      << "intensity-max: " << shortest(p.intensity_max) << "\n"
      << "no-adaptive: " << (p.adaptive_enabled ? "false" : "true") << "\n"
      << "adaptive-threshold: " << shortest(p.adaptive_threshold) << "\n"
      << "adaptive-max-ratio: " << shortest(p.adaptive_max_ratio) << "\n"
      << "no-rays: " << (setup.ray_casting ? "false" : "true") << "\n"
      << "rays: " << ray_model_name(setup.rays) << "\n"
      << "backend: " << setup.backend << "\n"
      << "threads: " << setup.threads << "\n";
  return out.str();
}

}  // namespace iwlomap::tool
