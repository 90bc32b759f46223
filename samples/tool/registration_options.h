// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The registration options shared by `iwlomap register` and `iwlomap map --register`.

#include "args.h"

#include <iwlomap/registration/scan_matcher.h>

#include <Eigen/Geometry>

#include <set>
#include <string>

namespace iwlomap::tool {

[[nodiscard]] std::set<std::string> registration_value_options();
[[nodiscard]] std::set<std::string> registration_flag_options();
[[nodiscard]] const char* registration_options_help();

/// The options from --window, --min-score, --max-distance, --no-coarse, --no-fine; UsageError
/// naming a bad value.
[[nodiscard]] registration::ScanMatcherOptions registration_options_from(const Args& args);

/// "X Y Z ROLL PITCH YAW" (metres, degrees) as a pose; UsageError naming \p option otherwise.
[[nodiscard]] Eigen::Isometry3d pose_from_text(const std::string& option, const std::string& text);

}  // namespace iwlomap::tool
