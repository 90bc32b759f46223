// SPDX-License-Identifier: BSD-3-Clause
// The snapshot colour maps, without VTK and without a display: this suite compiles color_map.cpp
// on its own and links neither VTK nor X11. Expected colours are the stops of the ramps and
// linear interpolations between them worked out by hand.

#include "iwlomap/viewer/color_map.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace iwlomap::viewer {
namespace {

constexpr double kTol = 1e-12;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

void expect_rgb(const Rgb& got, double r, double g, double b) {
  EXPECT_NEAR(got.r, r, kTol);
  EXPECT_NEAR(got.g, g, kTol);
  EXPECT_NEAR(got.b, b, kTol);
}

ColorMap black_to_white() { return ColorMap({{0.0, {0.0, 0.0, 0.0}}, {1.0, {1.0, 1.0, 1.0}}}); }

template <typename F>
std::string invalid_argument_message(F&& f) {
  try {
    f();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "(no std::invalid_argument thrown)";
}

TEST(ColorMap, AtReturnsStopColoursAtStops) {
  const ColorMap m({{0.0, {0.1, 0.2, 0.3}}, {0.25, {0.4, 0.5, 0.6}}, {1.0, {0.9, 0.8, 0.7}}});
  expect_rgb(m.at(0.0), 0.1, 0.2, 0.3);
  expect_rgb(m.at(0.25), 0.4, 0.5, 0.6);
  expect_rgb(m.at(1.0), 0.9, 0.8, 0.7);
}

TEST(ColorMap, AtInterpolatesLinearlyBetweenNeighbouringStops) {
  const ColorMap m({{0.0, {0.0, 0.0, 0.0}}, {0.5, {1.0, 0.0, 0.5}}, {1.0, {1.0, 1.0, 1.0}}});
  // t = 0.25 is halfway between the stops at 0 and 0.5: (0.5, 0, 0.25).
  expect_rgb(m.at(0.25), 0.5, 0.0, 0.25);
  // t = 0.875 is 3/4 of the way from the stop at 0.5 to the one at 1: (1, 0.75, 0.875).
  expect_rgb(m.at(0.875), 1.0, 0.75, 0.875);
}

TEST(ColorMap, AtClampsOutsideTheUnitInterval) {
  const ColorMap m = black_to_white();
  expect_rgb(m.at(-3.0), 0.0, 0.0, 0.0);
  expect_rgb(m.at(7.0), 1.0, 1.0, 1.0);
  expect_rgb(m.at(-kInf), 0.0, 0.0, 0.0);
  expect_rgb(m.at(kInf), 1.0, 1.0, 1.0);
}

TEST(ColorMap, AtThrowsForNaN) { EXPECT_THROW((void)black_to_white().at(kNaN), std::invalid_argument); }

TEST(ColorMap, MapSpreadsTheRangeOverTheRamp) {
  const ColorMap m = black_to_white();
  expect_rgb(m.map(2.0, 2.0, 6.0), 0.0, 0.0, 0.0);
  expect_rgb(m.map(3.0, 2.0, 6.0), 0.25, 0.25, 0.25);
  expect_rgb(m.map(6.0, 2.0, 6.0), 1.0, 1.0, 1.0);
  expect_rgb(m.map(9.0, 2.0, 6.0), 1.0, 1.0, 1.0);  // clamped
  expect_rgb(m.map(-1.0, 2.0, 6.0), 0.0, 0.0, 0.0);
}

TEST(ColorMap, MapGivesTheMiddleColourForAnEmptyRange) {
  expect_rgb(black_to_white().map(4.0, 4.0, 4.0), 0.5, 0.5, 0.5);
  expect_rgb(black_to_white().map(-10.0, 4.0, 4.0), 0.5, 0.5, 0.5);
}

TEST(ColorMap, MapThrowsForNaNValueOrBadRange) {
  const ColorMap m = black_to_white();
  EXPECT_THROW((void)m.map(kNaN, 0.0, 1.0), std::invalid_argument);
  EXPECT_THROW((void)m.map(0.5, kNaN, 1.0), std::invalid_argument);
  EXPECT_THROW((void)m.map(0.5, 0.0, kInf), std::invalid_argument);
  const std::string msg = invalid_argument_message([&] { (void)m.map(0.5, 3.0, 1.0); });
  EXPECT_NE(msg.find("[3, 1]"), std::string::npos) << msg;
}

TEST(ColorMap, ConstructorRejectsBadStopsNamingTheValue) {
  const Rgb c{0.5, 0.5, 0.5};
  std::string msg = invalid_argument_message([&] { ColorMap m({{0.0, c}}); });
  EXPECT_NE(msg.find("got 1"), std::string::npos) << msg;
  msg = invalid_argument_message([&] { ColorMap m({{0.1, c}, {1.0, c}}); });
  EXPECT_NE(msg.find("0.1"), std::string::npos) << msg;
  msg = invalid_argument_message([&] { ColorMap m({{0.0, c}, {0.9, c}}); });
  EXPECT_NE(msg.find("0.9"), std::string::npos) << msg;
  msg = invalid_argument_message([&] { ColorMap m({{0.0, c}, {0.5, c}, {0.5, c}, {1.0, c}}); });
  EXPECT_NE(msg.find("stop 2 at 0.5"), std::string::npos) << msg;
  msg = invalid_argument_message([&] { ColorMap m({{0.0, c}, {1.0, {0.0, 1.5, 0.0}}}); });
  EXPECT_NE(msg.find("1.5"), std::string::npos) << msg;
  EXPECT_THROW(ColorMap({{0.0, c}, {1.0, {kNaN, 0.0, 0.0}}}), std::invalid_argument);
}

TEST(ColorMap, SampleSpansTheRampEvenly) {
  const auto s = black_to_white().sample(5);
  ASSERT_EQ(s.size(), 5u);
  for (std::size_t i = 0; i < s.size(); ++i) expect_rgb(s[i], 0.25 * i, 0.25 * i, 0.25 * i);
  EXPECT_THROW((void)black_to_white().sample(1), std::invalid_argument);
}

TEST(ColorMap, HeightRampRunsFromBlueToRed) {
  const ColorMap m = ColorMap::height();
  ASSERT_EQ(m.stops().size(), 5u);
  const Rgb low = m.at(0.0), mid = m.at(0.5), high = m.at(1.0);
  EXPECT_GT(low.b, low.r + 0.3);    // blue at the bottom
  EXPECT_GT(mid.g, mid.r);          // green in the middle
  EXPECT_GT(mid.g, mid.b);
  EXPECT_GT(high.r, high.b + 0.5);  // red at the top
}

TEST(ColorMap, ProbabilityRampRunsFromBlueThroughYellowToRed) {
  const ColorMap m = ColorMap::probability();
  ASSERT_EQ(m.stops().size(), 3u);
  expect_rgb(m.at(0.0), 0.23, 0.35, 0.78);
  expect_rgb(m.at(0.5), 0.96, 0.84, 0.30);
  expect_rgb(m.at(1.0), 0.80, 0.09, 0.09);
  // Halfway between the yellow and the red stop.
  expect_rgb(m.at(0.75), (0.96 + 0.80) / 2, (0.84 + 0.09) / 2, (0.30 + 0.09) / 2);
}

TEST(ToRgb8, RoundsAndClamps) {
  EXPECT_EQ(to_rgb8({0.0, 1.0, 0.5}), (std::array<std::uint8_t, 3>{0, 255, 128}));  // 127.5 rounds up
  EXPECT_EQ(to_rgb8({-0.2, 1.7, 0.1}), (std::array<std::uint8_t, 3>{0, 255, 26}));  // 25.5 rounds up
  EXPECT_EQ(to_rgb8({0.498, 0.502, 0.2}), (std::array<std::uint8_t, 3>{127, 128, 51}));
}

}  // namespace
}  // namespace iwlomap::viewer

TEST(ColorMap, LabelDecimalsKeepEvenlySpacedLabelsDistinct) {
  EXPECT_EQ(iwlomap::viewer::label_decimals(0.5, 1.0, 5), 2);      // 0.50 0.62 0.75 0.88 1.00
  EXPECT_EQ(iwlomap::viewer::label_decimals(0.0, 100.0, 5), 0);    // 0 25 50 75 100
  EXPECT_EQ(iwlomap::viewer::label_decimals(0.0, 8.0, 5), 1);      // 0.0 2.0 4.0 6.0 8.0
  EXPECT_EQ(iwlomap::viewer::label_decimals(100.0, 100.04, 5), 3); // 100.000 100.010 ...
  EXPECT_EQ(iwlomap::viewer::label_decimals(1.0, 1.0, 5), 2);      // an empty range
  EXPECT_EQ(iwlomap::viewer::label_decimals(0.0, 1e-20, 5), 10);   // capped
  // Whatever the range, the printed labels differ.
  for (const auto& [lo, hi] : {std::pair{0.5, 0.51}, std::pair{-3.2, 1000.0}, std::pair{1e6, 1e6 + 0.3}, std::pair{0.0, 0.007}}) {
    const int d = iwlomap::viewer::label_decimals(lo, hi, 5);
    std::string previous;
    for (int i = 0; i < 5; ++i) {
      char buf[64];
      std::snprintf(buf, sizeof buf, "%.*f", d, lo + (hi - lo) * i / 4.0);
      EXPECT_NE(previous, buf) << lo << " .. " << hi;
      previous = buf;
    }
  }
}
