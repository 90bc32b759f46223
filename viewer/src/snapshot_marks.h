// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The marks that make a snapshot readable beside the voxels: an axes triad turned as the view is,
// a scale bar, and the sensor's positions with its trajectory.

#include "iwlomap/viewer/color_map.h"

#include <Eigen/Core>

class vtkCamera;
class vtkRenderWindow;
class vtkRenderer;

namespace iwlomap::viewer::detail {

/// Adds a renderer of its own (layer 2, on top of the map) in the lower-left corner of the window,
/// \p size_px square, drawing x, y and z axes (red, green, blue) seen from the direction of
/// \p map_camera, labelled in \p ink.
void add_axes_triad(vtkRenderWindow* window, vtkCamera* map_camera, int size_px, int width, int height,
                    const Rgb& ink, int label_px);

/// Draws into \p front (a full-window renderer on top) a bar of a round length (1, 2 or 5 times a
/// power of ten metres) near a fifth of \p map_width_px, its left end at pixel (\p x_px, \p y_px)
/// from the lower left, labelled with its length; \p metres_per_pixel is the map's scale.
void add_scale_bar(vtkRenderer* front, double metres_per_pixel, int map_width_px, int x_px, int y_px, const Rgb& ink,
                   int label_px);

/// Adds to \p renderer markers at \p positions (N x 3, map frame) relative to \p centre (the
/// rendering origin), the last one larger, joined in order by a line when N >= 2.
void add_sensor_track(vtkRenderer* renderer, const Eigen::MatrixXd& positions, const Eigen::Vector3d& centre,
                      double marker_radius);

/// The round length the scale bar shows for a target of \p metres: the largest of 1, 2 or 5
/// times a power of ten not above it.
[[nodiscard]] double round_scale_length(double metres);

}  // namespace iwlomap::viewer::detail
