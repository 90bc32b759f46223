// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// numpy arrays in and out of the C++ API. Every input is checked here, under the GIL, before any
// C++ call: its shape, its dtype (the message names the argument, the shape or dtype it got and
// what it needs) and then copied into the Eigen type the C++ API takes, through numpy's strides,
// so a transposed, sliced or Fortran-order view reads correctly. NaN values pass through: the
// library skips and counts them as it does in C++.

#include <iwlomap/sonar_image_projector.h>
#include <iwlomap/voxel_colors.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <cstdint>
#include <string>
#include <vector>

namespace iwlomap::python {

namespace py = pybind11;

/// "(3, 4)" for a shape.
std::string shape_text(const py::array& a);

/// \p obj as a numpy array (lists and tuples are converted); ValueError naming \p name otherwise.
py::array as_array(const py::handle& obj, const char* name);

/// An (N, 3) array of real numbers (float64, float32 or integers) as an N x 3 matrix in metres.
Eigen::MatrixXd points_from(const py::handle& obj, const char* name = "points");
/// An (N, 3) or (N, 4) array (x, y, z[, p]) as a matrix with its own column count.
Eigen::MatrixXd rows_from(const py::handle& obj, const char* name, int min_cols, int max_cols);
/// A (3,) array as a vector.
Eigen::Vector3d vector3_from(const py::handle& obj, const char* name);
/// An (N,) array of real numbers; \p n >= 0 requires exactly n values.
Eigen::VectorXd values_from(const py::handle& obj, const char* name, Eigen::Index n = -1);
/// The intensities of \p n points: \p obj as values_from(), or, when it is None, \p missing for
/// every point (callers pass the map's intensity_max: every point a full return, as the tool
/// reads a cloud without intensities).
Eigen::VectorXd intensities_or(const py::handle& obj, Eigen::Index n, double missing);
/// An (N,) array of booleans (bool dtype, or integers 0/1); \p n >= 0 requires exactly n values.
std::vector<bool> flags_from(const py::handle& obj, const char* name, Eigen::Index n = -1);
/// An (N, 3) uint8 array of colours.
ColorMatrix colors_from(const py::handle& obj, const char* name, Eigen::Index n = -1);
/// A (4, 4) homogeneous transform (rotation + translation, metres) as an isometry; ValueError
/// when the last row is not (0, 0, 0, 1) or the rotation is not orthonormal (1e-6).
Eigen::Isometry3d pose_from(const py::handle& obj, const char* name);

/// A matrix as a C-order float64 numpy array of its shape.
/// A 2-D image array (range bins x beams; uint8, uint16, float32 or float64; any strides) as a
/// view of its own buffer: the array must outlive the view, so the caller keeps it.
SonarImageView image_view_of(const py::array& a);

py::array_t<double> to_numpy(const Eigen::MatrixXd& m);
/// A vector as a 1-D float64 numpy array.
py::array_t<double> to_numpy(const Eigen::VectorXd& v);
py::array_t<double> to_numpy(const Eigen::Vector3d& v);
/// Colours as an (N, 3) uint8 array.
py::array_t<std::uint8_t> to_numpy(const ColorMatrix& m);
/// A pose as a (4, 4) float64 array.
py::array_t<double> pose_to_numpy(const Eigen::Isometry3d& pose);
/// Flags as a 1-D bool array.
py::array_t<bool> to_numpy(const std::vector<bool>& flags);

}  // namespace iwlomap::python
