// SPDX-License-Identifier: BSD-3-Clause
#include "numpy_io.h"

#include <Eigen/Geometry>

#include <cmath>
#include <cstring>
#include <stdexcept>

namespace iwlomap::python {

namespace {

// numpy dtype kinds: 'f' float, 'i' signed, 'u' unsigned, 'b' bool.
char kind(const py::array& a) { return a.dtype().kind(); }

std::string dtype_text(const py::array& a) { return py::str(a.dtype()).cast<std::string>(); }

[[noreturn]] void bad(const char* name, const std::string& problem) {
  throw py::value_error(std::string(name) + ": " + problem);
}

// The array as float64 (a copy converting integers and float32; float64 is taken as it is).
py::array_t<double> real_array(const py::array& a, const char* name) {
  const char k = kind(a);
  if (k != 'f' && k != 'i' && k != 'u')
    bad(name, "expected real numbers (float64, float32 or integers), got dtype " + dtype_text(a));
  if (k == 'f' && a.itemsize() > 8) bad(name, "expected float64 or float32, got dtype " + dtype_text(a));
  return py::array_t<double>::ensure(a);  // keeps float64 as is (any strides), converts the rest
}

// Copies a 2-D float64 array of \p cols columns (any strides) into a column-major matrix.
Eigen::MatrixXd copy_2d(const py::array_t<double>& a) {
  const auto r = a.unchecked<2>();
  Eigen::MatrixXd m(r.shape(0), r.shape(1));
  for (py::ssize_t j = 0; j < r.shape(1); ++j)
    for (py::ssize_t i = 0; i < r.shape(0); ++i) m(i, j) = r(i, j);
  return m;
}

}  // namespace

std::string shape_text(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

py::array as_array(const py::handle& obj, const char* name) {
  if (obj.is_none()) bad(name, "expected a numpy array, got None");
  py::array a = py::array::ensure(obj);
  // A scalar or a string becomes a 0-d array: not what any argument takes.
  if (!a || (a.ndim() == 0 && !py::isinstance<py::array>(obj)))
    bad(name, std::string("expected a numpy array, got ") + py::str(py::type::of(obj)).cast<std::string>());
  return a;
}

Eigen::MatrixXd rows_from(const py::handle& obj, const char* name, int min_cols, int max_cols) {
  const py::array a = as_array(obj, name);
  const std::string want = min_cols == max_cols ? "(N, " + std::to_string(min_cols) + ")"
                                                : "(N, " + std::to_string(min_cols) + ") or (N, " +
                                                      std::to_string(max_cols) + ")";
  // An empty input may come as shape (0,).
  if (a.ndim() == 1 && a.shape(0) == 0) return Eigen::MatrixXd(0, min_cols);
  if (a.ndim() != 2 || a.shape(1) < min_cols || a.shape(1) > max_cols)
    bad(name, "expected shape " + want + ", got " + shape_text(a));
  return copy_2d(real_array(a, name));
}

Eigen::MatrixXd points_from(const py::handle& obj, const char* name) { return rows_from(obj, name, 3, 3); }

Eigen::Vector3d vector3_from(const py::handle& obj, const char* name) {
  const py::array a = as_array(obj, name);
  if (a.ndim() != 1 || a.shape(0) != 3) bad(name, "expected shape (3,), got " + shape_text(a));
  const py::array_t<double> values = real_array(a, name);  // keeps a converted copy alive
  const auto r = values.unchecked<1>();
  return {r(0), r(1), r(2)};
}

Eigen::VectorXd values_from(const py::handle& obj, const char* name, Eigen::Index n) {
  const py::array a = as_array(obj, name);
  if (a.ndim() != 1) bad(name, "expected shape (N,), got " + shape_text(a));
  if (n >= 0 && a.shape(0) != n)
    bad(name, "expected " + std::to_string(n) + " values (one per point), got " + std::to_string(a.shape(0)));
  const py::array_t<double> values = real_array(a, name);  // keeps a converted copy alive
  const auto r = values.unchecked<1>();
  Eigen::VectorXd v(r.shape(0));
  for (py::ssize_t i = 0; i < r.shape(0); ++i) v[i] = r(i);
  return v;
}

Eigen::VectorXd intensities_or(const py::handle& obj, Eigen::Index n, double missing) {
  if (obj.is_none()) return Eigen::VectorXd::Constant(n, missing);
  return values_from(obj, "intensities", n);
}

std::vector<bool> flags_from(const py::handle& obj, const char* name, Eigen::Index n) {
  const py::array a = as_array(obj, name);
  if (a.ndim() != 1) bad(name, "expected shape (N,), got " + shape_text(a));
  if (n >= 0 && a.shape(0) != n)
    bad(name, "expected " + std::to_string(n) + " flags (one per point), got " + std::to_string(a.shape(0)));
  const char k = kind(a);
  if (k != 'b' && k != 'i' && k != 'u') bad(name, "expected bool flags, got dtype " + dtype_text(a));
  const py::array_t<std::int64_t> values = py::array_t<std::int64_t>::ensure(a);
  const auto r = values.unchecked<1>();
  std::vector<bool> flags(static_cast<std::size_t>(r.shape(0)));
  for (py::ssize_t i = 0; i < r.shape(0); ++i) {
    if (r(i) != 0 && r(i) != 1) bad(name, "flag " + std::to_string(i) + " is " + std::to_string(r(i)) + ", not 0 or 1");
    flags[static_cast<std::size_t>(i)] = r(i) != 0;
  }
  return flags;
}

ColorMatrix colors_from(const py::handle& obj, const char* name, Eigen::Index n) {
  const py::array a = as_array(obj, name);
  if (a.ndim() != 2 || a.shape(1) != 3) bad(name, "expected shape (N, 3), got " + shape_text(a));
  if (n >= 0 && a.shape(0) != n)
    bad(name, "expected " + std::to_string(n) + " colours (one per point), got " + std::to_string(a.shape(0)));
  if (!py::isinstance<py::array_t<std::uint8_t>>(a) || kind(a) != 'u' || a.itemsize() != 1)
    bad(name, "expected dtype uint8, got " + dtype_text(a));
  const py::array_t<std::uint8_t> values = py::array_t<std::uint8_t>::ensure(a);
  const auto r = values.unchecked<2>();
  ColorMatrix m(r.shape(0), 3);
  for (py::ssize_t i = 0; i < r.shape(0); ++i)
    for (py::ssize_t j = 0; j < 3; ++j) m(i, j) = r(i, j);
  return m;
}

Eigen::Isometry3d pose_from(const py::handle& obj, const char* name) {
  const py::array a = as_array(obj, name);
  if (a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4) bad(name, "expected a (4, 4) transform, got " + shape_text(a));
  const Eigen::MatrixXd m = copy_2d(real_array(a, name));
  if (!m.allFinite()) bad(name, "the transform is not finite");
  if (m(3, 0) != 0.0 || m(3, 1) != 0.0 || m(3, 2) != 0.0 || m(3, 3) != 1.0)
    bad(name, "the last row of the transform must be (0, 0, 0, 1)");
  const Eigen::Matrix3d rot = m.topLeftCorner<3, 3>();
  if (!(rot.transpose() * rot).isApprox(Eigen::Matrix3d::Identity(), 1e-6) || rot.determinant() < 0.0)
    bad(name, "the upper-left 3 x 3 block is not a rotation");
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = rot;
  pose.translation() = m.topRightCorner<3, 1>();
  return pose;
}

py::array_t<double> to_numpy(const Eigen::MatrixXd& m) {
  py::array_t<double> out({static_cast<py::ssize_t>(m.rows()), static_cast<py::ssize_t>(m.cols())});
  auto w = out.mutable_unchecked<2>();
  for (Eigen::Index i = 0; i < m.rows(); ++i)
    for (Eigen::Index j = 0; j < m.cols(); ++j) w(i, j) = m(i, j);
  return out;
}

py::array_t<double> to_numpy(const Eigen::VectorXd& v) {
  py::array_t<double> out(static_cast<py::ssize_t>(v.size()));
  if (v.size() > 0) std::memcpy(out.mutable_data(), v.data(), sizeof(double) * static_cast<std::size_t>(v.size()));
  return out;
}

py::array_t<double> to_numpy(const Eigen::Vector3d& v) {
  py::array_t<double> out(3);
  std::memcpy(out.mutable_data(), v.data(), 3 * sizeof(double));
  return out;
}

py::array_t<std::uint8_t> to_numpy(const ColorMatrix& m) {
  py::array_t<std::uint8_t> out({static_cast<py::ssize_t>(m.rows()), py::ssize_t{3}});
  if (m.rows() > 0) std::memcpy(out.mutable_data(), m.data(), static_cast<std::size_t>(m.size()));  // row-major
  return out;
}

py::array_t<bool> to_numpy(const std::vector<bool>& flags) {
  py::array_t<bool> out(static_cast<py::ssize_t>(flags.size()));
  auto w = out.mutable_unchecked<1>();
  for (std::size_t i = 0; i < flags.size(); ++i) w(static_cast<py::ssize_t>(i)) = flags[i];
  return out;
}

// A 2-D image array (range bins x beams; uint8, uint16, float32 or float64; any strides) as a view
// of its own buffer: the array must outlive the view, so the caller keeps it.
SonarImageView image_view_of(const py::array& a) {
  if (a.ndim() != 2) throw py::value_error("image: expected shape (range_bins, beams), got " + shape_text(a));
  SonarImageView v;
  const char k = a.dtype().kind();
  const auto size = a.itemsize();
  if (k == 'u' && size == 1)
    v.type = SonarPixelType::kUint8;
  else if (k == 'u' && size == 2)
    v.type = SonarPixelType::kUint16;
  else if (k == 'f' && size == 4)
    v.type = SonarPixelType::kFloat32;
  else if (k == 'f' && size == 8)
    v.type = SonarPixelType::kFloat64;
  else
    throw py::value_error("image: expected dtype uint8, uint16, float32 or float64, got " +
                          py::str(a.dtype()).cast<std::string>());
  if (a.strides(0) % size != 0 || a.strides(1) % size != 0)
    throw py::value_error("image: strides are not whole elements; pass a copy (numpy.ascontiguousarray)");
  v.data = a.data();
  v.range_bins = static_cast<int>(a.shape(0));
  v.beams = static_cast<int>(a.shape(1));
  v.bin_stride = a.strides(0) / size;
  v.beam_stride = a.strides(1) / size;
  return v;
}

py::array_t<double> pose_to_numpy(const Eigen::Isometry3d& pose) { return to_numpy(Eigen::MatrixXd(pose.matrix())); }

}  // namespace iwlomap::python
