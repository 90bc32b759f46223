// SPDX-License-Identifier: BSD-3-Clause
// The viewer layer: off-screen snapshots as numpy images or PNG files.

#include "bindings.h"
#include "numpy_io.h"

#include <iwlomap/viewer/snapshot_renderer.h>

#include <pybind11/stl.h>

#include <cstring>

namespace iwlomap::python {

namespace {

viewer::Rgb rgb_from(const py::handle& obj, const char* name) {
  const Eigen::VectorXd v = values_from(obj, name, 3);
  return {v[0], v[1], v[2]};
}

}  // namespace

void bind_viewer(py::module_& m) {
  py::module_ v = m.def_submodule("viewer", "Off-screen snapshots of voxel maps (through $DISPLAY, or a private Xvfb started when there is none).");
  readable_enum_name(py::enum_<viewer::CameraPreset>(v, "CameraPreset")
      .value("kIso", viewer::CameraPreset::kIso)
      .value("kTop", viewer::CameraPreset::kTop)
      .value("kFront", viewer::CameraPreset::kFront)
      .value("kSide", viewer::CameraPreset::kSide));
  readable_enum_name(py::enum_<viewer::ColorBy>(v, "ColorBy")
      .value("kProbability", viewer::ColorBy::kProbability)
      .value("kHeight", viewer::ColorBy::kHeight)
      .value("kFixed", viewer::ColorBy::kFixed)
      .value("kRgb", viewer::ColorBy::kRgb));
  readable_enum_name(py::enum_<viewer::VoxelShape>(v, "VoxelShape")
      .value("kCubes", viewer::VoxelShape::kCubes)
      .value("kPoints", viewer::VoxelShape::kPoints));
  py::register_exception<viewer::DisplayError>(v, "DisplayError", PyExc_RuntimeError);

  py::class_<viewer::SnapshotOptions>(v, "SnapshotOptions", "How a snapshot is drawn (see the C++ SnapshotOptions).")
      .def(py::init<>())
      .def_readwrite("width", &viewer::SnapshotOptions::width, "pixels, in [16, 8192]")
      .def_readwrite("height", &viewer::SnapshotOptions::height, "pixels, in [16, 8192]")
      .def_readwrite("camera", &viewer::SnapshotOptions::camera)
      .def_readwrite("perspective", &viewer::SnapshotOptions::perspective)
      .def_readwrite("color_by", &viewer::SnapshotOptions::color_by)
      .def_property(
          "fixed_color", [](const viewer::SnapshotOptions& o) { return py::make_tuple(o.fixed_color.r, o.fixed_color.g, o.fixed_color.b); },
          [](viewer::SnapshotOptions& o, const ArrayLike& c) { o.fixed_color = rgb_from(c, "fixed_color"); },
          "(r, g, b) in [0, 1]")
      .def_readwrite("color_min", &viewer::SnapshotOptions::color_min)
      .def_readwrite("color_max", &viewer::SnapshotOptions::color_max)
      .def_property(
          "voxel_rgb", [](const viewer::SnapshotOptions& o) { return to_numpy(o.voxel_rgb); },
          [](viewer::SnapshotOptions& o, const ArrayLike& c) { o.voxel_rgb = colors_from(c, "voxel_rgb"); },
          "ColorBy.kRgb: (N, 3) uint8, one row per voxel row")
      .def_readwrite("color_bar", &viewer::SnapshotOptions::color_bar)
      .def_readwrite("shape", &viewer::SnapshotOptions::shape)
      .def_readwrite("point_size", &viewer::SnapshotOptions::point_size)
      .def_property(
          "background", [](const viewer::SnapshotOptions& o) { return py::make_tuple(o.background.r, o.background.g, o.background.b); },
          [](viewer::SnapshotOptions& o, const ArrayLike& c) { o.background = rgb_from(c, "background"); },
          "(r, g, b) in [0, 1]")
      .def_readwrite("lighting", &viewer::SnapshotOptions::lighting)
      .def_readwrite("title", &viewer::SnapshotOptions::title)
      .def_readwrite("color_bar_title", &viewer::SnapshotOptions::color_bar_title,
                     "empty: 'probability', 'height (m)' or with z_down 'depth (m)'")
      .def_readwrite("z_down", &viewer::SnapshotOptions::z_down,
                     "the map's +z points down (sonar, NED): presets turned so the surface is on top; depth colours")
      .def_readwrite("axes", &viewer::SnapshotOptions::axes, "an axes triad in the lower-left corner")
      .def_readwrite("scale_bar", &viewer::SnapshotOptions::scale_bar, "a scale bar beside it (parallel views)")
      .def_property(
          "sensor_positions", [](const viewer::SnapshotOptions& o) { return to_numpy(o.sensor_positions); },
          [](viewer::SnapshotOptions& o, const ArrayLike& p) { o.sensor_positions = points_from(p, "sensor_positions"); },
          "(N, 3) metres, map frame: the sensor's track (a line; markers when N <= 20; the last one larger)")
      .def("validate", &viewer::SnapshotOptions::validate);

  const auto to_image = [](const viewer::RgbImage& img) {
    py::array_t<std::uint8_t> out({static_cast<py::ssize_t>(img.height), static_cast<py::ssize_t>(img.width), py::ssize_t{3}});
    std::memcpy(out.mutable_data(), img.rgb.data(), img.rgb.size());
    return out;
  };
  v.def(
      "render",
      [to_image](const ArrayLike& voxels, double resolution, const viewer::SnapshotOptions& options) {
        const Eigen::MatrixXd rows = rows_from(voxels, "voxels", 4, 4);
        viewer::RgbImage img;
        {
          py::gil_scoped_release release;
          img = viewer::SnapshotRenderer::render(rows, resolution, options);
        }
        return to_image(img);
      },
      py::arg("voxels"), py::arg("resolution"), py::arg("options") = viewer::SnapshotOptions{},
      "Draws voxels (N, 4) rows (x, y, z, p) as cubes of edge resolution metres; an (H, W, 3) uint8 image.");
  v.def(
      "render_map",
      [to_image](IMapperBackend& map, const viewer::SnapshotOptions& options, double min_probability) {
        const viewer::RgbImage img =
            unlocked(map, [&] { return viewer::SnapshotRenderer::render(map, options, min_probability); });
        return to_image(img);
      },
      py::arg("map"), py::arg("options") = viewer::SnapshotOptions{}, py::arg("min_probability") = -1.0,
      "Draws the occupied voxels of map (p > min_probability; negative: the map's threshold).");
  v.def(
      "write_png",
      [](const ArrayLike& image, const PathLike& path) {
        const py::array a = as_array(image, "image");
        if (a.ndim() != 3 || a.shape(2) != 3 || a.dtype().kind() != 'u' || a.itemsize() != 1)
          throw py::value_error("image: expected an (H, W, 3) uint8 array, got " + shape_text(a));
        const auto c = py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast>::ensure(a);
        viewer::RgbImage img;
        img.height = static_cast<int>(a.shape(0));
        img.width = static_cast<int>(a.shape(1));
        img.rgb.assign(c.data(), c.data() + c.size());
        const std::string file = path_from(path);
        with_file_errors(file, [&] { viewer::write_png(img, file); });
      },
      py::arg("image"), py::arg("path"), "Writes an (H, W, 3) uint8 image as PNG.");
  v.def("check_display", &viewer::SnapshotRenderer::check_display,
        "Raises DisplayError when neither $DISPLAY nor a private Xvfb can be used.");
}

}  // namespace iwlomap::python
