// SPDX-License-Identifier: BSD-3-Clause
// Fuzz target: the Oculus sonar reader, and every ping it accepts projected into a map at 1 m
// (a ping the reader lets through must be safe to project; a coarse map keeps the projection of a
// 1,000 m ping fast enough to fuzz). Input: the bytes of a file.

#include <iwlomap/oculus_reader.h>
#include <iwlomap/probability_updater.h>
#include <iwlomap/sonar_image_projector.h>

#include <Eigen/Geometry>

#include <cstddef>
#include <cstdint>
#include <stdexcept>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::vector<iwlomap::OculusPing> pings;
  try {
    pings = iwlomap::parse_oculus_pings(data, size, "fuzz input");
  } catch (const std::runtime_error&) {
    return 0;  // OculusFormatError (and its base): the expected answer to a bad file
  }
  iwlomap::ProbabilityUpdater map(1.0);
  const iwlomap::SonarImageProjector projector(1.0);
  for (const iwlomap::OculusPing& ping : pings) {
    try {
      (void)projector.integrate(map, ping.image_view(), ping.geometry(0.35, 0.5), Eigen::Isometry3d::Identity());
    } catch (const std::invalid_argument&) {
      // A geometry the projector refuses, with the value named: also an expected answer.
    }
  }
  return 0;
}
