// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/viewer/color_map.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <utility>

namespace iwlomap::viewer {

namespace {

std::string num(double v) {
  // std::to_string prints 6 decimals, which hides the tiny violations these messages are about.
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

bool unit(double v) { return v >= 0.0 && v <= 1.0; }  // false for NaN too

std::uint8_t to_byte(double v) {
  const double c = std::clamp(v, 0.0, 1.0);
  return static_cast<std::uint8_t>(std::lround(c * 255.0));
}

}  // namespace

std::array<std::uint8_t, 3> to_rgb8(const Rgb& c) { return {to_byte(c.r), to_byte(c.g), to_byte(c.b)}; }

ColorMap::ColorMap(std::vector<Stop> stops) : stops_(std::move(stops)) {
  if (stops_.size() < 2)
    throw std::invalid_argument("ColorMap: needs at least 2 stops, got " + std::to_string(stops_.size()));
  if (stops_.front().position != 0.0)
    throw std::invalid_argument("ColorMap: the first stop must be at 0, got " + num(stops_.front().position));
  if (stops_.back().position != 1.0)
    throw std::invalid_argument("ColorMap: the last stop must be at 1, got " + num(stops_.back().position));
  for (std::size_t i = 0; i < stops_.size(); ++i) {
    const Stop& s = stops_[i];
    if (i > 0 && !(s.position > stops_[i - 1].position))
      throw std::invalid_argument("ColorMap: stop " + std::to_string(i) + " at " + num(s.position) +
                                  " is not after stop " + std::to_string(i - 1) + " at " +
                                  num(stops_[i - 1].position));
    if (!unit(s.color.r) || !unit(s.color.g) || !unit(s.color.b))
      throw std::invalid_argument("ColorMap: stop " + std::to_string(i) + " has colour (" + num(s.color.r) + ", " +
                                  num(s.color.g) + ", " + num(s.color.b) + ") outside [0, 1]");
  }
}

ColorMap ColorMap::height() {
  return ColorMap({{0.0, {0.16, 0.19, 0.58}},
                   {0.25, {0.13, 0.52, 0.84}},
                   {0.5, {0.25, 0.74, 0.42}},
                   {0.75, {0.96, 0.80, 0.22}},
                   {1.0, {0.84, 0.22, 0.15}}});
}

ColorMap ColorMap::probability() {
  return ColorMap({{0.0, {0.23, 0.35, 0.78}}, {0.5, {0.96, 0.84, 0.30}}, {1.0, {0.80, 0.09, 0.09}}});
}

Rgb ColorMap::at(double t) const {
  if (std::isnan(t)) throw std::invalid_argument("ColorMap::at: t is NaN");
  t = std::clamp(t, 0.0, 1.0);
  // First stop strictly after t; t == 1 falls on the last segment.
  auto hi = std::upper_bound(stops_.begin(), stops_.end(), t,
                             [](double v, const Stop& s) { return v < s.position; });
  if (hi == stops_.end()) return stops_.back().color;
  const Stop& b = *hi;
  const Stop& a = *(hi - 1);
  const double f = (t - a.position) / (b.position - a.position);
  return {a.color.r + f * (b.color.r - a.color.r), a.color.g + f * (b.color.g - a.color.g),
          a.color.b + f * (b.color.b - a.color.b)};
}

Rgb ColorMap::map(double value, double lo, double hi) const {
  if (std::isnan(value)) throw std::invalid_argument("ColorMap::map: value is NaN");
  if (!std::isfinite(lo) || !std::isfinite(hi) || lo > hi)
    throw std::invalid_argument("ColorMap::map: range [" + num(lo) + ", " + num(hi) + "] is not a finite, ordered range");
  if (hi == lo) return at(0.5);
  return at((value - lo) / (hi - lo));
}

std::vector<Rgb> ColorMap::sample(std::size_t n) const {
  if (n < 2) throw std::invalid_argument("ColorMap::sample: n must be >= 2, got " + std::to_string(n));
  std::vector<Rgb> out(n);
  for (std::size_t i = 0; i < n; ++i) out[i] = at(static_cast<double>(i) / static_cast<double>(n - 1));
  return out;
}

int label_decimals(double lo, double hi, int labels) {
  const double step = (hi - lo) / std::max(1, labels - 1);
  if (!std::isfinite(step) || !(step > 0.0)) return 2;
  return std::clamp(static_cast<int>(std::ceil(-std::log10(step))) + 1, 0, 10);
}

}  // namespace iwlomap::viewer
