// SPDX-License-Identifier: BSD-3-Clause
// make_sonar_survey DIR: writes two simulated sonar surveys of the same site (benchmarks/
// sonar_sim.h, a smaller sonar of 64 beams, a ping every 0.4 m, light noise) as Oculus
// SimplePingResult (v1) files with their poses, for the tool's registration test:
//   earlier.raw, earlier_truth.txt            a first survey and its true poses
//   survey.raw, survey_truth.txt, survey_nav.txt   a second survey (other noise), its true poses
//                                                  and its navigation's, drifting 1 % of the distance
//   loop.raw, loop_truth.txt, loop_nav.txt         a survey that runs its first line again after
//                                                  the return leg (three legs, a ping every 0.2 m),
//                                                  drifting 1 %: for --loop-closure
// Poses: one per line, x y z qw qx qy qz (sonar frame to map frame).

#include "sonar_sim.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using iwlomap::bench::SonarSimulation;

template <typename T>
void put(std::vector<std::uint8_t>& b, std::size_t at, T v) {
  std::memcpy(&b[at], &v, sizeof v);
}

// One 8-bit SimplePingResult v1 message without gain rows: the layout iwlomap's Oculus reader
// reads (src/sonar/oculus_reader.cpp).
std::vector<std::uint8_t> oculus_message(const SonarSimulation& sim, std::size_t index) {
  constexpr std::size_t kBearings = 122;
  const auto& image = sim.pings[index].image;
  const auto beams = static_cast<std::size_t>(image.cols()), bins = static_cast<std::size_t>(image.rows());
  const std::size_t image_offset = kBearings + 2 * beams;
  const std::size_t length = image_offset + beams * bins;
  std::vector<std::uint8_t> b(length, 0);
  put<std::uint16_t>(b, 0, 0x4f53);
  put<std::uint16_t>(b, 6, 0x23);
  put<std::uint16_t>(b, 8, 1);
  put<std::uint32_t>(b, 10, static_cast<std::uint32_t>(length - 16));
  b[16] = 1;
  put<double>(b, 21, sim.geometry.max_range);
  put<double>(b, 29, 50.0);
  put<std::uint32_t>(b, 53, static_cast<std::uint32_t>(index));
  put<double>(b, 61, 1.2e6);
  put<double>(b, 85, 1500.0);
  b[97] = 0;  // 8-bit samples
  put<double>(b, 98, sim.geometry.range_resolution);
  put<std::uint16_t>(b, 106, static_cast<std::uint16_t>(bins));
  put<std::uint16_t>(b, 108, static_cast<std::uint16_t>(beams));
  put<std::uint32_t>(b, 110, static_cast<std::uint32_t>(image_offset));
  put<std::uint32_t>(b, 114, static_cast<std::uint32_t>(beams * bins));
  put<std::uint32_t>(b, 118, static_cast<std::uint32_t>(length));
  for (std::size_t k = 0; k < beams; ++k) {  // hundredths of a degree
    const double centi = sim.geometry.bearings[k] * 18000.0 / 3.14159265358979323846;
    put<std::int16_t>(b, kBearings + 2 * k, static_cast<std::int16_t>(std::lround(centi)));
  }
  for (std::size_t r = 0; r < bins; ++r)
    for (std::size_t k = 0; k < beams; ++k)
      b[image_offset + r * beams + k] = image(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(k));
  return b;
}

void write_pings(const fs::path& path, const SonarSimulation& sim) {
  std::ofstream out(path, std::ios::binary);
  for (std::size_t i = 0; i < sim.pings.size(); ++i) {
    const std::vector<std::uint8_t> m = oculus_message(sim, i);
    out.write(reinterpret_cast<const char*>(m.data()), static_cast<std::streamsize>(m.size()));
  }
  if (!out) throw std::runtime_error("cannot write " + path.string());
}

void write_poses(const fs::path& path, const SonarSimulation& sim, bool nav) {
  std::ofstream out(path);
  out.precision(17);
  for (const auto& ping : sim.pings) {
    const Eigen::Isometry3d& pose = nav ? ping.nav_pose : ping.pose;
    const Eigen::Quaterniond q(pose.linear());
    out << pose.translation().x() << ' ' << pose.translation().y() << ' ' << pose.translation().z() << ' ' << q.w()
        << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << '\n';
  }
  if (!out) throw std::runtime_error("cannot write " + path.string());
}

SonarSimulation simulate(std::uint32_t seed, double drift, int legs = 2, double spacing = 0.4) {
  iwlomap::bench::SonarSimOptions o;
  o.beams = 64;
  o.elevation_rays = 96;
  o.ping_spacing = spacing;
  o.legs = legs;
  o.noise = iwlomap::bench::light_noise();
  o.drift = drift;
  o.seed = seed;
  return iwlomap::bench::simulate_sonar_survey(o);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: make_sonar_survey DIR\n";
    return 2;
  }
  try {
    const fs::path dir(argv[1]);
    fs::create_directories(dir);
    const SonarSimulation earlier = simulate(4, 0.0);
    write_pings(dir / "earlier.raw", earlier);
    write_poses(dir / "earlier_truth.txt", earlier, false);
    const SonarSimulation survey = simulate(3, 0.01);
    write_pings(dir / "survey.raw", survey);
    write_poses(dir / "survey_truth.txt", survey, false);
    write_poses(dir / "survey_nav.txt", survey, true);
    const SonarSimulation loop = simulate(1, 0.01, 3, 0.2);
    write_pings(dir / "loop.raw", loop);
    write_poses(dir / "loop_truth.txt", loop, false);
    write_poses(dir / "loop_nav.txt", loop, true);
  } catch (const std::exception& e) {
    std::cerr << "make_sonar_survey: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
