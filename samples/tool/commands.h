// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The tool's subcommands. Each returns the process exit code, throws UsageError for bad usage and
// std::exception for failures.

#include <string>
#include <vector>

namespace iwlomap::tool {

int run_map(const std::vector<std::string>& args);
int run_info(const std::vector<std::string>& args);
int run_export(const std::vector<std::string>& args);
int run_generate(const std::vector<std::string>& args);
int run_render(const std::vector<std::string>& args);
int run_sonar(const std::vector<std::string>& args);
int run_pyramid(const std::vector<std::string>& args);
int run_register(const std::vector<std::string>& args);
int run_repair(const std::vector<std::string>& args);

}  // namespace iwlomap::tool
