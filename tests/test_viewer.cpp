// SPDX-License-Identifier: BSD-3-Clause
// SnapshotRenderer on known scenes, checked pixel by pixel. Needs an X display: the suite runs
// under xvfb-run -a -s "-screen 0 1280x1024x24 -noreset" (scripts/test.sh); the no-display tests
// remove DISPLAY in a child process, where the renderer starts its own Xvfb.
//
// Where pixels are predicted, the scene is seen from the top with a parallel projection, no
// colour bar, no title and no lighting, so (as SnapshotOptions documents) the bounding box of the
// cubes fills 90% of the limiting image dimension and every top face shows exactly its colour-map
// colour. Pixels are compared a few pixels away from cube edges, where edge smoothing can blend.

#include "iwlomap/probability_updater.h"
#include "iwlomap/viewer/color_map.h"
#include "iwlomap/viewer/snapshot_renderer.h"
#ifdef IWLOMAP_TEST_PCL_ADAPTER
#include "iwlomap/viewer/pcl_adapter.h"
#endif

#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <limits>
#include <stdexcept>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

namespace iwlomap::viewer {
namespace {

using Pixel = std::array<std::uint8_t, 3>;

constexpr double kFill = 0.9;  // documented framing of parallel views
constexpr int kColorTol = 3;   // 8-bit rounding of the rasteriser

/// Options for predictable pixels: flat colours, no overlays, black background, top view.
SnapshotOptions flat_top_view(int width, int height) {
  SnapshotOptions o;
  o.width = width;
  o.height = height;
  o.camera = CameraPreset::kTop;
  o.color_bar = false;
  o.lighting = false;
  o.background = {0.0, 0.0, 0.0};
  o.axes = false;
  o.scale_bar = false;
  return o;
}

Eigen::MatrixXd rows(const std::vector<std::array<double, 4>>& v) {
  Eigen::MatrixXd m(static_cast<Eigen::Index>(v.size()), 4);
  for (std::size_t i = 0; i < v.size(); ++i)
    for (int c = 0; c < 4; ++c) m(static_cast<Eigen::Index>(i), c) = v[i][static_cast<std::size_t>(c)];
  return m;
}

/// Maps map-frame (x, y) to image pixels for a top view framing the box [lo, hi] (x, y).
struct TopViewFrame {
  double cx, cy, pixels_per_metre;
  int width, height;
  TopViewFrame(double lo_x, double hi_x, double lo_y, double hi_y, int w, int h) : width(w), height(h) {
    cx = (lo_x + hi_x) / 2;
    cy = (lo_y + hi_y) / 2;
    const double aspect = static_cast<double>(w) / h;
    const double scale = std::max((hi_y - lo_y) / 2, (hi_x - lo_x) / 2 / aspect) / kFill;  // half height, metres
    pixels_per_metre = h / (2 * scale);
  }
  [[nodiscard]] double px(double x) const { return width / 2.0 + (x - cx) * pixels_per_metre; }
  [[nodiscard]] double py(double y) const { return height / 2.0 - (y - cy) * pixels_per_metre; }
  [[nodiscard]] Pixel at(const RgbImage& img, double x, double y) const {
    return img.pixel(static_cast<int>(std::floor(px(x))), static_cast<int>(std::floor(py(y))));
  }
};

::testing::AssertionResult near(const Pixel& got, const Pixel& want, int tol = kColorTol) {
  for (int c = 0; c < 3; ++c)
    if (std::abs(int(got[static_cast<std::size_t>(c)]) - int(want[static_cast<std::size_t>(c)])) > tol)
      return ::testing::AssertionFailure() << "pixel (" << int(got[0]) << ", " << int(got[1]) << ", " << int(got[2])
                                           << "), expected (" << int(want[0]) << ", " << int(want[1]) << ", "
                                           << int(want[2]) << ") +- " << tol;
  return ::testing::AssertionSuccess();
}

constexpr Pixel kBlack{0, 0, 0};

TEST(SnapshotRenderer, TopViewDrawsCentreBlockOverTheExpectedRegion) {
  // A 4 x 4 block of 1 m voxels around the origin, plus one voxel in each corner of a 20 m square
  // so the framing is known: cubes span [-10, 10] in x and y.
  std::vector<std::array<double, 4>> v;
  for (double x : {-1.5, -0.5, 0.5, 1.5})
    for (double y : {-1.5, -0.5, 0.5, 1.5}) v.push_back({x, y, 0.0, 1.0});
  for (double x : {-9.5, 9.5})
    for (double y : {-9.5, 9.5}) v.push_back({x, y, 0.0, 1.0});
  SnapshotOptions o = flat_top_view(240, 200);
  o.color_by = ColorBy::kFixed;
  o.fixed_color = {1.0, 0.0, 0.0};
  const RgbImage img = SnapshotRenderer::render(rows(v), 1.0, o);
  ASSERT_EQ(img.width, 240);
  ASSERT_EQ(img.height, 200);
  ASSERT_EQ(img.rgb.size(), 240u * 200u * 3u);

  const TopViewFrame f(-10, 10, -10, 10, 240, 200);  // 9 pixels per metre, block = 36 x 36 pixels
  ASSERT_NEAR(f.pixels_per_metre, 9.0, 1e-9);
  const Pixel red{255, 0, 0};
  const int x0 = static_cast<int>(f.px(-2)), x1 = static_cast<int>(f.px(2));
  const int y0 = static_cast<int>(f.py(2)), y1 = static_cast<int>(f.py(-2));
  int inside = 0, stray = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const Pixel p = img.pixel(x, y);
      const bool in_block = x >= x0 + 2 && x < x1 - 2 && y >= y0 + 2 && y < y1 - 2;
      const bool near_block = x >= x0 - 2 && x < x1 + 2 && y >= y0 - 2 && y < y1 + 2;
      if (in_block) inside += near(p, red) ? 1 : 0;
      // Away from the block, only the four corner voxels may be drawn.
      const bool near_corner = std::abs(std::abs(x - img.width / 2.0) - 9.5 * 9) < 7 &&
                               std::abs(std::abs(y - img.height / 2.0) - 9.5 * 9) < 7;
      if (!near_block && !near_corner && !near(p, kBlack)) ++stray;
    }
  EXPECT_EQ(inside, (x1 - x0 - 4) * (y1 - y0 - 4)) << "block interior [" << x0 << ", " << x1 << ") x [" << y0 << ", "
                                                   << y1 << ")";
  EXPECT_EQ(stray, 0);
  // The block's edges sit where the framing puts them: background just outside, red just inside.
  EXPECT_TRUE(near(img.pixel(x0 - 3, 100), kBlack));
  EXPECT_TRUE(near(img.pixel(x0 + 3, 100), red));
  EXPECT_TRUE(near(img.pixel(x1 + 3, 100), kBlack));
  EXPECT_TRUE(near(img.pixel(120, y0 - 3), kBlack));
  EXPECT_TRUE(near(img.pixel(120, y1 + 3), kBlack));
  // The corner voxels.
  for (double x : {-9.5, 9.5})
    for (double y : {-9.5, 9.5}) EXPECT_TRUE(near(f.at(img, x, y), red)) << "corner voxel " << x << ", " << y;
}

TEST(SnapshotRenderer, TopViewPutsPlusXRightAndPlusYUp) {
  // Corners fix the frame; a red voxel at +x and a green one at +y.
  SnapshotOptions o = flat_top_view(200, 200);
  o.color_by = ColorBy::kProbability;
  o.color_min = 0.0;
  o.color_max = 1.0;
  const Pixel lo = to_rgb8(ColorMap::probability().at(0.0)), hi = to_rgb8(ColorMap::probability().at(1.0));
  const RgbImage img = SnapshotRenderer::render(
      rows({{-9.5, -9.5, 0, 0.0}, {9.5, 9.5, 0, 0.0}, {5.5, 0.5, 0, 1.0}, {0.5, 5.5, 0, 0.0}}), 1.0, o);
  const TopViewFrame f(-10, 10, -10, 10, 200, 200);
  EXPECT_TRUE(near(f.at(img, 5.5, 0.5), hi));
  EXPECT_TRUE(near(f.at(img, 0.5, 5.5), lo));
  EXPECT_TRUE(near(f.at(img, -5.5, 0.5), kBlack));
  EXPECT_TRUE(near(f.at(img, 0.5, -5.5), kBlack));
}

TEST(SnapshotRenderer, HeightColouredGroundPlaneShowsTheColourMapGradient) {
  // A 40 m x 10 m ground of 1 m voxels rising in steps of 0.1 m along x (z = 0 ... 3.9), coloured
  // by height over [0, 3.9]: each column's top face must show the height ramp at its z.
  std::vector<std::array<double, 4>> v;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 10; ++j) v.push_back({-19.5 + i, -4.5 + j, 0.1 * i, 1.0});
  SnapshotOptions o = flat_top_view(400, 200);
  o.color_by = ColorBy::kHeight;
  const RgbImage img = SnapshotRenderer::render(rows(v), 1.0, o);
  const TopViewFrame f(-20, 20, -5, 5, 400, 200);
  const ColorMap ramp = ColorMap::height();
  Pixel previous{};
  int changes = 0;
  for (int i = 0; i < 40; ++i) {
    const double z = 0.1 * i;
    const Pixel want = to_rgb8(ramp.map(z, 0.0, 3.9));
    const Pixel got = f.at(img, -19.5 + i, 0.5);
    EXPECT_TRUE(near(got, want)) << "column " << i << " (z = " << z << ")";
    if (i > 0 && got != previous) ++changes;
    previous = got;
  }
  EXPECT_GE(changes, 35);  // a gradient, not a few flat bands
  // The ends of the ramp: blue at the low end, red at the high end.
  const Pixel low = f.at(img, -19.5, 0.5), high = f.at(img, 19.5, 0.5);
  EXPECT_GT(low[2], low[0] + 60);
  EXPECT_GT(high[0], high[2] + 120);
}

TEST(SnapshotRenderer, ProbabilityColoursSitWhereTheColourMapPutsThem) {
  // Eleven 2 m voxels in a row with p = 0.5, 0.55, ..., 1.0 over the default range [0.5, 1], and
  // one with p = 0.3 below the range (clamped to the low end).
  std::vector<std::array<double, 4>> v;
  for (int i = 0; i <= 10; ++i) v.push_back({-11.0 + 2.0 * i, 0.0, 0.0, 0.5 + 0.05 * i});
  v.push_back({-11.0, -2.0, 0.0, 0.3});
  SnapshotOptions o = flat_top_view(440, 200);
  o.color_by = ColorBy::kProbability;
  const RgbImage img = SnapshotRenderer::render(rows(v), 2.0, o);
  const TopViewFrame f(-12, 10, -3, 1, 440, 200);
  const ColorMap ramp = ColorMap::probability();
  for (int i = 0; i <= 10; ++i) {
    const double p = 0.5 + 0.05 * i;
    EXPECT_TRUE(near(f.at(img, -11.0 + 2.0 * i, 0.0), to_rgb8(ramp.at((p - 0.5) / 0.5)))) << "p = " << p;
  }
  EXPECT_TRUE(near(f.at(img, -11.0, -2.0), to_rgb8(ramp.at(0.0))));
  EXPECT_TRUE(near(f.at(img, -9.0, -2.0), kBlack));
}

TEST(SnapshotRenderer, LightingShadesTheVisibleFacesOfACubeDifferently) {
  SnapshotOptions o;
  o.width = 200;
  o.height = 200;
  o.camera = CameraPreset::kIso;
  o.color_bar = false;
  o.color_by = ColorBy::kFixed;
  o.fixed_color = {0.8, 0.8, 0.8};
  o.background = {0.0, 0.0, 0.0};
  const RgbImage img = SnapshotRenderer::render(rows({{0, 0, 0, 1}}), 1.0, o);
  // Brightness histogram of the cube's pixels: three faces, three clearly different grey levels.
  std::vector<int> count(256, 0);
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const Pixel p = img.pixel(x, y);
      if (p != kBlack) ++count[p[1]];
    }
  int levels = 0;
  for (int g = 0; g < 256; ++g) levels += count[static_cast<std::size_t>(g)] > 300 ? 1 : 0;
  EXPECT_GE(levels, 3);
}

TEST(SnapshotRenderer, FrontAndSideViewsPutHighVoxelsAtTheTop) {
  const Eigen::MatrixXd v = rows({{0, 0, 0, 1}, {0, 0, 8, 1}, {4, 0, 0, 1}, {0, 4, 0, 1}});
  for (CameraPreset preset : {CameraPreset::kFront, CameraPreset::kSide}) {
    SnapshotOptions o = flat_top_view(200, 200);
    o.camera = preset;
    o.color_by = ColorBy::kFixed;
    o.fixed_color = {1.0, 1.0, 1.0};
    const RgbImage img = SnapshotRenderer::render(v, 1.0, o);
    // Topmost and bottommost rows holding a drawn pixel: the z = 8 voxel must be the topmost.
    int top = -1, bottom = -1;
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x)
        if (img.pixel(x, y) != kBlack) {
          if (top < 0) top = y;
          bottom = y;
        }
    ASSERT_GE(top, 0);
    // The z range [-0.5, 8.5] is the limiting extent: 9 m over 90% of 200 pixels.
    EXPECT_NEAR(top, 10, 2) << "preset " << static_cast<int>(preset);
    EXPECT_NEAR(bottom, 189, 2) << "preset " << static_cast<int>(preset);
  }
}

TEST(SnapshotRenderer, PointsDrawAtTheVoxelCentres) {
  SnapshotOptions o = flat_top_view(200, 200);
  o.shape = VoxelShape::kPoints;
  o.point_size = 6.0;
  o.color_by = ColorBy::kFixed;
  o.fixed_color = {0.0, 1.0, 0.0};
  const RgbImage img = SnapshotRenderer::render(rows({{-9.5, -9.5, 0, 1}, {9.5, 9.5, 0, 1}, {3.0, 2.0, 0, 1}}), 1.0, o);
  const TopViewFrame f(-10, 10, -10, 10, 200, 200);
  EXPECT_TRUE(near(f.at(img, 3.0, 2.0), {0, 255, 0}));
  // A 6-pixel point is much smaller than the 9-pixel cube would be.
  EXPECT_TRUE(near(f.at(img, 3.0 + 0.7, 2.0), kBlack));
}

TEST(SnapshotRenderer, EmptyMapGivesTheBackgroundOnly) {
  SnapshotOptions o = flat_top_view(64, 48);
  o.background = {0.2, 0.4, 0.6};
  const RgbImage img = SnapshotRenderer::render(Eigen::MatrixXd(0, 4), 0.1, o);
  const Pixel bg = to_rgb8(o.background);
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) ASSERT_TRUE(near(img.pixel(x, y), bg)) << x << ", " << y;
}

TEST(SnapshotRenderer, SkipsRowsWithNonFiniteValues) {
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  SnapshotOptions o = flat_top_view(200, 200);
  o.color_by = ColorBy::kProbability;
  // The NaN rows would stretch or break the framing if they were used.
  const RgbImage img = SnapshotRenderer::render(
      rows({{-9.5, -9.5, 0, 1}, {9.5, 9.5, 0, 1}, {kNaN, 0, 0, 1}, {0, std::numeric_limits<double>::infinity(), 0, 1}, {0.5, 0.5, 0, kNaN}}),
      1.0, o);
  const TopViewFrame f(-10, 10, -10, 10, 200, 200);
  EXPECT_TRUE(near(f.at(img, 9.5, 9.5), to_rgb8(ColorMap::probability().at(1.0))));
  EXPECT_TRUE(near(f.at(img, 0.5, 0.5), kBlack));  // NaN probability: not drawn
}

TEST(SnapshotRenderer, ColourBarAndTitleGetTheirOwnBands) {
  // A map filling the view, coloured by height; with a bar and a title the map must stay clear of
  // the bar band on the right and the title band on top.
  std::vector<std::array<double, 4>> v;
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < 20; ++j) v.push_back({i + 0.5, j + 0.5, 0.2 * i, 1.0});
  SnapshotOptions o = flat_top_view(400, 300);
  o.color_bar = true;
  o.title = "Title";
  const RgbImage img = SnapshotRenderer::render(rows(v), 1.0, o);
  const Pixel top_colour = to_rgb8(ColorMap::height().at(1.0));
  const int band_x = 400 - static_cast<int>(std::lround(400 * 0.13));
  int bar_hits = 0, text = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = band_x; x < img.width; ++x) bar_hits += near(img.pixel(x, y), top_colour, 10) ? 1 : 0;
  for (int y = 0; y < 20; ++y)
    for (int x = 150; x < 250; ++x) text += img.pixel(x, y) != kBlack ? 1 : 0;
  EXPECT_GT(bar_hits, 20) << "no colour bar in the right band";
  EXPECT_GT(text, 20) << "no title in the top band";
  // The map is framed in the 348 x 277 pixels left of the bar and below the title: 20 m over 90%
  // of 277 pixels, centred at x = 174, so its right edge (the red end of the ramp) is at x = 299.
  int map_right = -1;
  for (int x = 0; x < band_x; ++x)
    if (near(img.pixel(x, 160), top_colour, 10)) map_right = x;
  EXPECT_NEAR(map_right, 298, 2);
}

// The marks: a sensor position outside the voxels is framed and drawn dark; the axes triad
// draws its three colours in the lower-left corner; the scale bar is a round length drawn to the
// map's scale; z_down turns a top view so +y points down the image.
TEST(SnapshotRenderer, SensorPositionsAreFramedAndDrawn) {
  SnapshotOptions o = flat_top_view(200, 200);
  o.color_by = ColorBy::kFixed;
  o.fixed_color = {0.0, 1.0, 0.0};
  o.background = {1.0, 1.0, 1.0};
  // Voxels in [-10, 0] x [-10, 10]; the sensor at (9.5, 0): framing both gives the box [-10, 10]^2.
  o.sensor_positions = Eigen::MatrixXd(1, 3);
  o.sensor_positions << 9.5, 0.0, 0.0;
  const RgbImage img = SnapshotRenderer::render(rows({{-9.5, -9.5, 0, 1}, {-0.5, 9.5, 0, 1}}), 1.0, o);
  const TopViewFrame f(-10, 10, -10, 10, 200, 200);
  EXPECT_TRUE(near(f.at(img, -9.5, -9.5), {0, 255, 0})) << "the voxels keep their place in the larger frame";
  const Pixel sensor = f.at(img, 9.5, 0.0);
  EXPECT_LT(int(sensor[0]) + int(sensor[1]) + int(sensor[2]), 150) << "a dark marker at the sensor";
}

TEST(SnapshotRenderer, AxesTriadDrawsItsColoursInTheLowerLeftCorner) {
  SnapshotOptions o = flat_top_view(300, 300);
  o.camera = CameraPreset::kIso;
  o.axes = true;
  o.background = {1.0, 1.0, 1.0};
  const RgbImage img = SnapshotRenderer::render(rows({{0.5, 0.5, 0.5, 1}}), 1.0, o);
  int red = 0, green = 0, blue = 0;
  for (int y = 300 - 48; y < 300; ++y)
    for (int x = 0; x < 48; ++x) {
      const Pixel p = img.pixel(x, y);
      red += p[0] > 150 && p[1] < 100 && p[2] < 100;
      green += p[1] > 100 && p[0] < 100 && p[2] < 100;
      blue += p[2] > 150 && p[0] < 100 && p[1] < 150;
    }
  EXPECT_GT(red, 5);
  EXPECT_GT(green, 5);
  EXPECT_GT(blue, 5);
}

TEST(SnapshotRenderer, ScaleBarIsARoundLengthAtTheMapsScale) {
  // Top view of 20 m x 10 m in 400 x 300 pixels: 0.9 of the limiting width, so 20 m span
  // 0.9 * 400 = 360 px (18 px a metre); a fifth of the width is 4.4 m, rounded down to 2 m: 36 px.
  std::vector<std::array<double, 4>> v;
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < 10; ++j) v.push_back({i + 0.5, j + 0.5, 0.0, 1.0});
  SnapshotOptions o = flat_top_view(400, 300);
  o.scale_bar = true;
  o.color_by = ColorBy::kFixed;
  o.fixed_color = {0.0, 0.0, 1.0};
  const RgbImage img = SnapshotRenderer::render(rows(v), 1.0, o);
  // The longest run of light (ink on black) pixels in a row of the bottom band.
  int longest = 0;
  for (int y = 240; y < 300; ++y) {
    int run = 0;
    for (int x = 0; x < 400; ++x) {
      const Pixel p = img.pixel(x, y);
      run = p[0] > 150 && p[1] > 150 && p[2] > 150 ? run + 1 : 0;
      longest = std::max(longest, run);
    }
  }
  EXPECT_NEAR(longest, 36, 3);
}

TEST(SnapshotRenderer, ZDownTurnsTheTopViewSoPlusYPointsDown) {
  SnapshotOptions o = flat_top_view(200, 200);
  o.z_down = true;
  o.color_by = ColorBy::kFixed;
  o.fixed_color = {1.0, 0.0, 0.0};
  // One voxel at +y, one at +x; the frame is [-10, 10]^2.
  const RgbImage img =
      SnapshotRenderer::render(rows({{0.5, 9.5, 0, 1}, {9.5, 0.5, 0, 1}, {-9.5, -9.5, 0, 1}}), 1.0, o);
  const TopViewFrame f(-10, 10, -10, 10, 200, 200);
  // +x stays to the right; +y is mirrored to the bottom of the image.
  EXPECT_TRUE(near(f.at(img, 9.5, -0.5), {255, 0, 0})) << "+x to the right";
  EXPECT_TRUE(near(f.at(img, 0.5, -9.5), {255, 0, 0})) << "+y at the bottom";
  EXPECT_TRUE(near(f.at(img, 0.5, 9.5), kBlack));
}

TEST(SnapshotRenderer, RendersTheOccupiedVoxelsOfABackend) {
  ProbabilityUpdater map(1.0);
  // Occupied observations in two voxels: (0.5, 0.5, 0.5) and (5.5, 0.5, 0.5).
  Eigen::MatrixXd points(6, 3);
  points << 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 5.5, 0.5, 0.5, 5.5, 0.5, 0.5, 5.5, 0.5, 0.5;
  map.batch_update_iwlo(points, Eigen::VectorXd::Constant(6, 255.0), std::vector<bool>(6, true));
  ASSERT_EQ(map.get_occupied_voxels(map.get_params().occupied_threshold).rows(), 2);
  SnapshotOptions o = flat_top_view(240, 100);
  o.color_by = ColorBy::kFixed;
  o.fixed_color = {1.0, 1.0, 1.0};
  const RgbImage img = SnapshotRenderer::render(map, o);
  const TopViewFrame f(0, 6, 0, 1, 240, 100);
  EXPECT_TRUE(near(f.at(img, 0.5, 0.5), {255, 255, 255}));
  EXPECT_TRUE(near(f.at(img, 5.5, 0.5), {255, 255, 255}));
  EXPECT_TRUE(near(f.at(img, 3.0, 0.5), kBlack));
}

TEST(SnapshotRenderer, ExplicitPerspectivePoseLooksAtItsTarget) {
  SnapshotOptions o = flat_top_view(200, 200);
  o.camera_pose = CameraPose{{0.0, 0.0, 30.0}, {5.0, 0.0, 0.0}, {0.0, 1.0, 0.0}};
  o.perspective = true;
  o.color_by = ColorBy::kFixed;
  o.fixed_color = {1.0, 1.0, 1.0};
  // The voxel at the target must appear at the image centre.
  const RgbImage img = SnapshotRenderer::render(rows({{5.0, 0.0, 0.0, 1}, {-5.0, 0.0, 0.0, 1}}), 1.0, o);
  EXPECT_TRUE(near(img.pixel(100, 100), {255, 255, 255}));
}

TEST(SnapshotRenderer, RenderPngWritesAPngOfTheRequestedSize) {
  SnapshotOptions o;
  o.width = 321;
  o.height = 123;
  o.title = "png";
  const std::string path = ::testing::TempDir() + "iwlomap_snapshot_test.png";
  std::remove(path.c_str());
  SnapshotRenderer::render_png(rows({{0, 0, 0, 0.9}, {1, 0, 1, 0.8}}), 1.0, o, path);
  std::ifstream in(path, std::ios::binary);
  ASSERT_TRUE(in.good()) << path;
  const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 33u);
  const unsigned char signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  EXPECT_TRUE(std::equal(signature, signature + 8, bytes.begin()));
  // IHDR: width and height, big-endian, at bytes 16 and 20.
  const auto be32 = [&](std::size_t at) {
    return (bytes[at] << 24) | (bytes[at + 1] << 16) | (bytes[at + 2] << 8) | bytes[at + 3];
  };
  EXPECT_EQ(be32(16), 321);
  EXPECT_EQ(be32(20), 123);
  std::remove(path.c_str());
}

TEST(SnapshotRenderer, WritePngNamesAnUnwritablePath) {
  RgbImage img;
  img.width = 2;
  img.height = 2;
  img.rgb.assign(12, 0);
  try {
    write_png(img, "/nonexistent-dir/x.png");
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-dir/x.png"), std::string::npos) << e.what();
  }
  img.rgb.resize(5);
  EXPECT_THROW(write_png(img, ::testing::TempDir() + "never.png"), std::invalid_argument);
}

TEST(SnapshotRenderer, RejectsBadInputNamingTheValue) {
  const SnapshotOptions ok = flat_top_view(100, 100);
  const auto message = [](auto&& f) -> std::string {
    try {
      f();
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "(no std::invalid_argument)";
  };
  EXPECT_NE(message([&] { (void)SnapshotRenderer::render(Eigen::MatrixXd(3, 3), 1.0, ok); }).find("3 columns"),
            std::string::npos);
  EXPECT_NE(message([&] { (void)SnapshotRenderer::render(Eigen::MatrixXd(0, 4), -0.5, ok); }).find("-0.5"),
            std::string::npos);
  SnapshotOptions o = ok;
  o.width = 8;
  EXPECT_NE(message([&] { (void)SnapshotRenderer::render(Eigen::MatrixXd(0, 4), 1.0, o); }).find("width 8"),
            std::string::npos);
  o = ok;
  o.camera_pose = CameraPose{{0, 0, 5}, {0, 0, 0}, {0, 0, 2}};
  EXPECT_NE(message([&] { o.validate(); }).find("parallel"), std::string::npos);
  o = ok;
  o.color_min = 2.0;
  o.color_max = 1.0;
  EXPECT_NE(message([&] { o.validate(); }).find("color_min 2"), std::string::npos);
  o = ok;
  o.background = {0.0, 2.0, 0.0};
  EXPECT_NE(message([&] { o.validate(); }).find("background"), std::string::npos);
  o = ok;
  o.color_by = ColorBy::kHeight;
  o.color_min = 100.0;  // above every voxel: the range would be empty
  EXPECT_NE(message([&] { (void)SnapshotRenderer::render(Eigen::MatrixXd::Zero(1, 4), 1.0, o); }).find("[100, "),
            std::string::npos);
}

// Each voxel in its own colour: three voxels and the corners that fix the framing.
TEST(SnapshotRenderer, RgbColoursDrawEachVoxelInItsOwnColour) {
  SnapshotOptions o = flat_top_view(200, 200);
  o.color_by = ColorBy::kRgb;
  const Eigen::MatrixXd v = rows({{-9.5, -9.5, 0, 1}, {9.5, 9.5, 0, 1}, {5.5, 0.5, 0, 1}, {0.5, 5.5, 0, 1}, {-5.5, -5.5, 0, 1}});
  o.voxel_rgb.resize(5, 3);
  o.voxel_rgb << 255, 255, 255, 255, 255, 255, 200, 30, 10, 12, 180, 40, 90, 60, 250;
  const RgbImage img = SnapshotRenderer::render(v, 1.0, o);
  const TopViewFrame f(-10, 10, -10, 10, 200, 200);
  EXPECT_TRUE(near(f.at(img, 5.5, 0.5), {200, 30, 10}));
  EXPECT_TRUE(near(f.at(img, 0.5, 5.5), {12, 180, 40}));
  EXPECT_TRUE(near(f.at(img, -5.5, -5.5), {90, 60, 250}));
  EXPECT_TRUE(near(f.at(img, 0.5, -5.5), kBlack));
  o.voxel_rgb.resize(4, 3);
  EXPECT_THROW((void)SnapshotRenderer::render(v, 1.0, o), std::invalid_argument);
}

TEST(SnapshotRenderer, PixelOutsideTheImageThrowsNamingIt) {
  RgbImage img;
  img.width = 4;
  img.height = 3;
  img.rgb.assign(36, 7);
  EXPECT_EQ(img.pixel(3, 2), (Pixel{7, 7, 7}));
  try {
    (void)img.pixel(4, 0);
    FAIL() << "no exception";
  } catch (const std::out_of_range& e) {
    EXPECT_NE(std::string(e.what()).find("(4, 0)"), std::string::npos) << e.what();
  }
}

TEST(SnapshotRenderer, CallsFromSeveralThreadsAllSucceed) {
  // Renders are serialised inside; each thread must still get its own, correct image.
  std::vector<RgbImage> images(3);
  std::vector<std::thread> threads;
  for (std::size_t t = 0; t < images.size(); ++t)
    threads.emplace_back([&images, t] {
      SnapshotOptions o = flat_top_view(100, 100);
      o.color_by = ColorBy::kFixed;
      o.fixed_color = {t == 0 ? 1.0 : 0.0, t == 1 ? 1.0 : 0.0, t == 2 ? 1.0 : 0.0};
      images[t] = SnapshotRenderer::render(rows({{0, 0, 0, 1}}), 1.0, o);
    });
  for (auto& th : threads) th.join();
  EXPECT_TRUE(near(images[0].pixel(50, 50), {255, 0, 0}));
  EXPECT_TRUE(near(images[1].pixel(50, 50), {0, 255, 0}));
  EXPECT_TRUE(near(images[2].pixel(50, 50), {0, 0, 255}));
}

#ifdef IWLOMAP_TEST_PCL_ADAPTER
TEST(CloudToVoxels, RgbCloudsRenderInTheirOwnColours) {
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  for (const auto& [x, y, r, g, b] : std::vector<std::tuple<float, float, int, int, int>>{
           {-9.5f, -9.5f, 255, 255, 255}, {9.5f, 9.5f, 255, 255, 255}, {5.5f, 0.5f, 10, 220, 30}}) {
    pcl::PointXYZRGB p(static_cast<std::uint8_t>(r), static_cast<std::uint8_t>(g), static_cast<std::uint8_t>(b));
    p.x = x;
    p.y = y;
    p.z = 0.0f;
    cloud.push_back(p);
  }
  SnapshotOptions o = flat_top_view(200, 200);
  o.color_by = ColorBy::kRgb;
  const RgbImage img = render_cloud(cloud, 1.0, o);
  EXPECT_TRUE(near(TopViewFrame(-10, 10, -10, 10, 200, 200).at(img, 5.5, 0.5), {10, 220, 30}));
}

TEST(CloudToVoxels, TakesIntensityAsProbabilityOrTheDefault) {
  pcl::PointCloud<pcl::PointXYZI> with;
  with.push_back(pcl::PointXYZI(0.8f));
  with[0].x = 1.0f;
  with[0].y = 2.0f;
  with[0].z = 3.0f;
  const Eigen::MatrixXd a = cloud_to_voxels(with);
  ASSERT_EQ(a.rows(), 1);
  ASSERT_EQ(a.cols(), 4);
  EXPECT_DOUBLE_EQ(a(0, 0), 1.0);
  EXPECT_DOUBLE_EQ(a(0, 1), 2.0);
  EXPECT_DOUBLE_EQ(a(0, 2), 3.0);
  EXPECT_DOUBLE_EQ(a(0, 3), 0.8f);
  pcl::PointCloud<pcl::PointXYZ> without;
  without.push_back(pcl::PointXYZ(4.0f, 5.0f, 6.0f));
  EXPECT_DOUBLE_EQ(cloud_to_voxels(without)(0, 3), 1.0);
  EXPECT_DOUBLE_EQ(cloud_to_voxels(without, 0.75)(0, 3), 0.75);
  EXPECT_EQ(cloud_to_voxels(pcl::PointCloud<pcl::PointXYZ>()).rows(), 0);
}
#endif

/// Runs \p display_value (nullptr: unset) as DISPLAY and \p xvfb (nullptr: unset) as IWLOMAP_XVFB
/// in a child process, renders a few voxels there, and returns how the child ended: 0 an image
/// with the voxels drawn, 4 a blank image, 5 DisplayError naming xvfb-run and Xvfb's absence,
/// 1 another DisplayError message, 3 another exception; a signal (e.g. VTK's abort()) shows as
/// 128 + signal.
int render_in_child(const char* display_value, const char* xvfb) {
  std::fflush(nullptr);
  const pid_t pid = fork();
  if (pid == 0) {
    if (display_value == nullptr)
      unsetenv("DISPLAY");
    else
      setenv("DISPLAY", display_value, 1);
    if (xvfb == nullptr)
      unsetenv("IWLOMAP_XVFB");
    else
      setenv("IWLOMAP_XVFB", xvfb, 1);
    int code = 3;
    try {
      Eigen::MatrixXd voxels(2, 4);
      voxels << 0.0, 0.0, 0.0, 1.0, 4.0, 4.0, 0.0, 1.0;
      SnapshotOptions o;
      o.width = 160;
      o.height = 120;
      const RgbImage image = SnapshotRenderer::render(voxels, 1.0, o);
      const auto background = image.pixel(0, 0);
      code = 4;
      for (int y = 0; y < image.height && code == 4; ++y)
        for (int x = 0; x < image.width && code == 4; ++x)
          if (image.pixel(x, y) != background) code = 0;
    } catch (const DisplayError& e) {
      const std::string msg = e.what();
      code = msg.find("xvfb-run -a -s \"-screen 0 1280x1024x24 -noreset\"") != std::string::npos &&
                     msg.find("DISPLAY") != std::string::npos && msg.find("not found") != std::string::npos
                 ? 5
                 : 1;
      if (code != 5) std::fprintf(stderr, "unexpected message: %s\n", e.what());
    } catch (...) {
      code = 3;
    }
    std::fflush(nullptr);
    _exit(code);
  }
  int status = 0;
  if (pid < 0 || waitpid(pid, &status, 0) != pid) return -1;
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(SnapshotRenderer, WithoutADisplayRendersThroughAPrivateVirtualXServer) {
  EXPECT_EQ(render_in_child(nullptr, nullptr), 0) << "DISPLAY unset";
  EXPECT_EQ(render_in_child("", nullptr), 0) << "DISPLAY empty";
  EXPECT_EQ(render_in_child(":64999", nullptr), 0) << "DISPLAY of a server that does not exist";
}

TEST(SnapshotRenderer, WithoutADisplayOrXvfbThrowsDisplayErrorInsteadOfAborting) {
  EXPECT_EQ(render_in_child(nullptr, "/nonexistent/Xvfb"), 5);
  EXPECT_EQ(render_in_child(":64999", "/nonexistent/Xvfb"), 5);
}

TEST(SnapshotRenderer, CheckDisplaySucceedsWhenADisplayIsAvailable) {
  ASSERT_NE(std::getenv("DISPLAY"), nullptr) << "run the suite under xvfb-run (see the file comment)";
  EXPECT_NO_THROW(SnapshotRenderer::check_display());
}

}  // namespace
}  // namespace iwlomap::viewer
