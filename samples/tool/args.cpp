// SPDX-License-Identifier: BSD-3-Clause
#include "args.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

namespace iwlomap::tool {

Args::Args(const std::vector<std::string>& argv, const std::set<std::string>& value_options,
           const std::set<std::string>& flags) {
  for (std::size_t i = 0; i < argv.size(); ++i) {
    const std::string& a = argv[i];
    if (a.size() < 2 || a[0] != '-' || a == "--" || (a[1] != '-' && (std::isdigit(static_cast<unsigned char>(a[1])) || a[1] == '.'))) {
      positional_.push_back(a == "--" ? std::string() : a);
      if (a == "--") {  // everything after -- is positional
        positional_.pop_back();
        positional_.insert(positional_.end(), argv.begin() + static_cast<std::ptrdiff_t>(i) + 1, argv.end());
        break;
      }
      continue;
    }
    std::string name = a, value;
    bool inline_value = false;
    if (const auto eq = a.find('='); eq != std::string::npos) {
      name = a.substr(0, eq);
      value = a.substr(eq + 1);
      inline_value = true;
    }
    if (flags.count(name) > 0) {
      if (inline_value) throw UsageError("option " + name + " takes no value");
      flags_.insert(name);
    } else if (value_options.count(name) > 0) {
      if (!inline_value) {
        if (i + 1 >= argv.size()) throw UsageError("option " + name + " needs a value");
        value = argv[++i];
      }
      values_[name] = value;
    } else {
      throw UsageError("unknown option " + name);
    }
  }
}

std::optional<std::string> Args::value(const std::string& name) const {
  const auto it = values_.find(name);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

std::optional<double> Args::number(const std::string& name) const {
  const auto v = value(name);
  if (!v) return std::nullopt;
  char* end = nullptr;
  const double d = std::strtod(v->c_str(), &end);
  if (v->empty() || end != v->c_str() + v->size() || !std::isfinite(d))
    throw UsageError("option " + name + " needs a finite number, got '" + *v + "'");
  return d;
}

double Args::number(const std::string& name, double fallback) const { return number(name).value_or(fallback); }

std::optional<double> Args::positive_or_none(const std::string& name) const {
  if (value(name) == "none") return std::nullopt;
  const std::optional<double> d = number(name);
  if (d && !(*d > 0.0)) throw UsageError(name + " must be > 0 metres or 'none', got " + shortest(*d));
  return d;
}

std::optional<double> Args::resolution() const {
  const std::optional<double> r = number("--resolution");
  if (r && !(*r > 0.0 && *r <= kMaxResolution))
    throw UsageError("--resolution must be > 0 and at most " + shortest(kMaxResolution) + " metres, got " + shortest(*r));
  return r;
}

long Args::integer(const std::string& name, long fallback, long min, long max) const {
  const auto v = value(name);
  if (!v) return fallback;
  long n = 0;
  // from_chars: no leading space or '+', no trailing characters, and overflow is reported.
  const auto [end, ec] = std::from_chars(v->data(), v->data() + v->size(), n);
  if (v->empty() || ec == std::errc::invalid_argument || end != v->data() + v->size())
    throw UsageError("option " + name + " needs an integer, got '" + *v + "'");
  if (ec == std::errc::result_out_of_range || n < min || n > max)
    throw UsageError("option " + name + " must be in [" + std::to_string(min) + ", " + std::to_string(max) + "], got '" +
                     *v + "'");
  return n;
}

std::string extension(const std::string& path) {
  const auto slash = path.find_last_of('/');
  const auto dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string e = path.substr(dot);
  std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return e;
}

std::string shortest(double value) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, value);
  return std::string(buf, r.ptr);
}

namespace {

double parse_number(const std::string& option, const std::string& text) {
  char* end = nullptr;
  const double d = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(d))
    throw UsageError(option + " needs finite numbers, got '" + text + "'");
  return d;
}

}  // namespace

std::vector<double> parse_list(const std::string& option, const std::string& text, std::size_t count) {
  std::vector<double> out;
  std::stringstream ss(text);
  for (std::string item; std::getline(ss, item, ',');) out.push_back(parse_number(option, item));
  if (out.size() != count || (!text.empty() && text.back() == ','))
    throw UsageError(option + " needs " + std::to_string(count) + " comma-separated numbers, got '" + text + "'");
  return out;
}

}  // namespace iwlomap::tool
