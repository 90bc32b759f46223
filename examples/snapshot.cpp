// SPDX-License-Identifier: BSD-3-Clause
// An off-screen PNG of a map: no window opens, and no screen is needed (without $DISPLAY the
// renderer starts its own virtual X server, Xvfb).
//
//   snapshot OUT.png
#include <iwlomap/probability_updater.h>
#include <iwlomap/sensor_preset.h>
#include <iwlomap/synthetic_scan.h>
#include <iwlomap/viewer/snapshot_renderer.h>

#include <iostream>

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: " << argv[0] << " OUT.png\n";
    return 2;
  }
  iwlomap::ProbabilityUpdater map(0.1);
  map.set_params(iwlomap::sensor_preset_params(iwlomap::SensorPreset::kLidar));  // every return is a hit
  const iwlomap::SyntheticScan scan = iwlomap::make_synthetic_scan();
  map.insert_scan(scan.origin, scan.points, scan.intensities, 30.0);

  iwlomap::viewer::SnapshotOptions options;  // 1280 x 960, coloured by height, with a colour bar
  options.title = "synthetic courtyard, 0.1 m";
  // Throws iwlomap::viewer::DisplayError (a std::runtime_error) saying what to install when
  // neither $DISPLAY nor Xvfb can be used.
  iwlomap::viewer::SnapshotRenderer::render_png(map, options, argv[1]);
  std::cout << "wrote " << argv[1] << "\n";
  return 0;
}
