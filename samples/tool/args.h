// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// A small command-line parser for the iwlomap tool: `--name value`, `--name=value`, flags and
// positional arguments. Bad usage raises UsageError, which the tool turns into exit code 2.

#include <cstddef>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap::tool {

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class Args {
 public:
  /// \param value_options options that take a value; \param flags options without one.
  Args(const std::vector<std::string>& argv, const std::set<std::string>& value_options,
       const std::set<std::string>& flags);

  [[nodiscard]] bool has(const std::string& name) const { return values_.count(name) > 0 || flags_.count(name) > 0; }
  [[nodiscard]] bool flag(const std::string& name) const { return flags_.count(name) > 0; }
  [[nodiscard]] std::optional<std::string> value(const std::string& name) const;
  /// The option's value as a finite number, or \p fallback when absent.
  [[nodiscard]] double number(const std::string& name, double fallback) const;
  [[nodiscard]] std::optional<double> number(const std::string& name) const;
  /// The option's value as a finite number > 0, or std::nullopt when absent or "none"; UsageError
  /// for 0, a negative value or anything else (e.g. --max-range: "none" is no limit).
  [[nodiscard]] std::optional<double> positive_or_none(const std::string& name) const;
  /// --resolution in metres, in (0, kMaxResolution], or std::nullopt when absent; UsageError
  /// otherwise. Voxel centres are written as 32-bit floats: an edge of 1e300 m would put them at
  /// infinity.
  [[nodiscard]] std::optional<double> resolution() const;
  static constexpr double kMaxResolution = 10000.0;
  /// The option's value as an integer in [\p min, \p max] (UsageError otherwise, also for a sign
  /// or space around it, or a value beyond the range of long), or \p fallback when absent.
  [[nodiscard]] long integer(const std::string& name, long fallback, long min = std::numeric_limits<int>::min(),
                             long max = std::numeric_limits<int>::max()) const;
  [[nodiscard]] const std::vector<std::string>& positional() const { return positional_; }
  /// Every option given with a value, by name.
  [[nodiscard]] const std::map<std::string, std::string>& values() const { return values_; }

 private:
  std::map<std::string, std::string> values_;
  std::set<std::string> flags_;
  std::vector<std::string> positional_;
};

/// The shortest decimal form of \p value that reads back as the same double ("0.2").
[[nodiscard]] std::string shortest(double value);

/// Lower-case file extension with the dot (".pcd"), or "" when there is none.
[[nodiscard]] std::string extension(const std::string& path);

/// \p count comma-separated finite numbers from \p text; UsageError naming \p option otherwise.
[[nodiscard]] std::vector<double> parse_list(const std::string& option, const std::string& text, std::size_t count);

}  // namespace iwlomap::tool
