// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// `--config FILE.yaml` and `--print-config` for `iwlomap map`: a flat YAML mapping whose keys are
// the command's options without their dashes (`resolution: 0.1`, `sensor: lidar`,
// `intensity-threshold: 35`, `no-adaptive: true`). Options on the command line win over the file.

#include "args.h"
#include "map_options.h"

#include <set>
#include <string>
#include <vector>

namespace iwlomap::tool {

/// Parses \p argv; when it has --config FILE, parses it again with the file's options added (those
/// not given on the command line). Only \p allowed options (without --config, --print-config and
/// the outputs) may appear in the file. Throws UsageError naming the file and line for a key
/// that is not such an option, a value that is not a scalar, a flag that is not true or false,
/// or a file YAML cannot read; std::runtime_error when the file cannot be opened.
[[nodiscard]] Args args_with_config(const std::vector<std::string>& argv, std::set<std::string> value_options,
                                    const std::set<std::string>& flags, const std::set<std::string>& allowed);

/// The effective configuration of \p setup as the YAML --config reads: the preset, then every
/// IWLO parameter, resolution, max-range, backend and threads.
[[nodiscard]] std::string config_yaml(const MapSetup& setup, const std::string& command);

}  // namespace iwlomap::tool
