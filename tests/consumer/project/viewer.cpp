// SPDX-License-Identifier: BSD-3-Clause
// The snapshot renderer from a C++-only project. Without a display it throws DisplayError before
// VTK touches X; with one (Xvfb) it renders.
#include <iwlomap/viewer/snapshot_renderer.h>

#include <iostream>

int main() {
  Eigen::MatrixXd voxels(2, 4);
  voxels << 0.05, 0.05, 0.05, 0.9, 0.15, 0.05, 0.05, 0.8;
  try {
    const iwlomap::viewer::RgbImage image =
        iwlomap::viewer::SnapshotRenderer::render(voxels, 0.1, iwlomap::viewer::SnapshotOptions{});
    std::cout << "consumer: rendered " << image.width << " x " << image.height << "\n";
    return image.width > 0 ? 0 : 1;
  } catch (const iwlomap::viewer::DisplayError& e) {
    std::cout << "consumer: no display (" << e.what() << ")\n";
    return 0;
  }
}
