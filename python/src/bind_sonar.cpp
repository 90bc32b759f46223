// SPDX-License-Identifier: BSD-3-Clause
// Sonar: Oculus recordings and the projection of sonar images into IWLO observations.

#include "bindings.h"
#include "numpy_io.h"

#include <iwlomap/oculus_reader.h>
#include <iwlomap/sonar_image_projector.h>
#include <iwlomap/sonar_preset.h>

#include <pybind11/stl.h>

#include <cstring>

namespace iwlomap::python {

namespace {

py::object observations_to_python(const SonarObservations& o) {
  py::dict d;
  d["points"] = to_numpy(o.points);
  d["intensities"] = to_numpy(o.intensities);
  d["is_occupied"] = to_numpy(o.is_occupied);
  d["weights"] = to_numpy(o.weights);
  d["beams_with_return"] = o.beams_with_return;
  d["beams_without_return"] = o.beams_without_return;
  d["free_samples"] = o.free_samples;
  d["occupied_samples"] = o.occupied_samples;
  return py::module_::import("types").attr("SimpleNamespace")(**d);
}

}  // namespace

void bind_sonar(py::module_& m) {
  py::class_<SonarGeometry>(m, "SonarGeometry", "Where a sonar image's pixels lie (radians, metres).")
      .def(py::init([](const ArrayLike& bearings, double range_resolution, double min_range, double max_range,
                       double vertical_aperture) {
             SonarGeometry g;
             const Eigen::VectorXd b = values_from(bearings, "bearings");
             g.bearings.assign(b.data(), b.data() + b.size());
             g.range_resolution = range_resolution;
             g.min_range = min_range;
             g.max_range = max_range;
             g.vertical_aperture = vertical_aperture;
             g.validate(static_cast<int>(g.bearings.size()));
             return g;
           }),
           py::kw_only(), py::arg("bearings"), py::arg("range_resolution"), py::arg("min_range") = 0.0,
           py::arg("max_range"), py::arg("vertical_aperture") = 0.0,
           "bearings (beams,) radians, positive toward +y; range_resolution metres per bin; [min_range, max_range] "
           "metres; vertical_aperture radians.")
      .def_property_readonly("bearings", [](const SonarGeometry& g) {
        return to_numpy(Eigen::VectorXd(Eigen::Map<const Eigen::VectorXd>(g.bearings.data(), static_cast<Eigen::Index>(g.bearings.size()))));
      })
      .def_readwrite("range_resolution", &SonarGeometry::range_resolution)
      .def_readwrite("min_range", &SonarGeometry::min_range)
      .def_readwrite("max_range", &SonarGeometry::max_range)
      .def_readwrite("vertical_aperture", &SonarGeometry::vertical_aperture);

  readable_enum_name(py::enum_<SonarNoReturn>(m, "SonarNoReturn")
      .value("kNothing", SonarNoReturn::kNothing)
      .value("kFreeToMaxRange", SonarNoReturn::kFreeToMaxRange));
  readable_enum_name(py::enum_<SonarDetector>(m, "SonarDetector")
      .value("kThreshold", SonarDetector::kThreshold)
      .value("kCellAveragingCfar", SonarDetector::kCellAveragingCfar)
      .value("kOrderedStatisticCfar", SonarDetector::kOrderedStatisticCfar));
  readable_enum_name(py::enum_<SonarCfarWindow>(m, "SonarCfarWindow")
      .value("kBothSides", SonarCfarWindow::kBothSides)
      .value("kNearSide", SonarCfarWindow::kNearSide));
  const SonarCfarParams c;
  py::class_<SonarCfarParams>(m, "SonarCfarParams", "CFAR window and false-alarm rate (bins, probability).")
      .def(py::init([](int guard_cells, int training_cells, SonarCfarWindow window, double false_alarm_rate,
                       double os_rank, double min_noise_intensity) {
             SonarCfarParams p{guard_cells, training_cells, window, false_alarm_rate, os_rank, min_noise_intensity};
             p.validate();
             return p;
           }),
           py::kw_only(), py::arg("guard_cells") = c.guard_cells, py::arg("training_cells") = c.training_cells,
           py::arg("window") = c.window, py::arg("false_alarm_rate") = c.false_alarm_rate,
           py::arg("os_rank") = c.os_rank, py::arg("min_noise_intensity") = c.min_noise_intensity)
      .def_readwrite("guard_cells", &SonarCfarParams::guard_cells)
      .def_readwrite("training_cells", &SonarCfarParams::training_cells)
      .def_readwrite("window", &SonarCfarParams::window)
      .def_readwrite("false_alarm_rate", &SonarCfarParams::false_alarm_rate)
      .def_readwrite("os_rank", &SonarCfarParams::os_rank)
      .def_readwrite("min_noise_intensity", &SonarCfarParams::min_noise_intensity)
      .def("validate", &SonarCfarParams::validate);
  py::class_<SonarCfar>(m, "SonarCfar", "CFAR detection along one beam.")
      .def(py::init<SonarDetector, const SonarCfarParams&>(), py::arg("detector"), py::arg("params") = SonarCfarParams{})
      .def(
          "detect",
          [](const SonarCfar& cfar, const ArrayLike& intensities) {
            const Eigen::VectorXd v = values_from(intensities, "intensities");
            const std::vector<bool> d = cfar.detect(v);
            return to_numpy(d);
          },
          py::arg("intensities"), "Per bin of one beam (nearest first): whether it is a detection.")
      .def("factor", &SonarCfar::factor, py::arg("n"));

  const SonarSnrWeight w;
  py::class_<SonarSnrWeight>(m, "SonarSnrWeight",
                             "Weight of an echo from its excess over the CFAR threshold (dB); needs a CFAR detector.")
      .def(py::init([](bool enabled, double centre_db, double width_db) {
             SonarSnrWeight s{enabled, centre_db, width_db};
             s.validate();
             return s;
           }),
           py::kw_only(), py::arg("enabled") = w.enabled, py::arg("centre_db") = w.centre_db,
           py::arg("width_db") = w.width_db)
      .def_readwrite("enabled", &SonarSnrWeight::enabled)
      .def_readwrite("centre_db", &SonarSnrWeight::centre_db)
      .def_readwrite("width_db", &SonarSnrWeight::width_db)
      .def("validate", &SonarSnrWeight::validate);
  m.attr("kRayleighPowerSpreadDb") = kRayleighPowerSpreadDb;
  m.def("sonar_snr_weight", &sonar_snr_weight, py::arg("excess_db"), py::arg("weight") = SonarSnrWeight{},
        "The weight of an echo excess_db decibels above the CFAR threshold.");

  const SonarProjectorParams d;
  py::class_<SonarProjectorParams>(m, "SonarProjectorParams")
      .def(py::init([](double intensity_threshold, double free_sample_stride, double elevation_sample_spacing,
                       double occupied_band, SonarNoReturn no_return, SonarDetector detector,
                       const SonarCfarParams& cfar, const SonarSnrWeight& snr_weight) {
             SonarProjectorParams p;
             p.intensity_threshold = intensity_threshold;
             p.free_sample_stride = free_sample_stride;
             p.elevation_sample_spacing = elevation_sample_spacing;
             p.occupied_band = occupied_band;
             p.no_return = no_return;
             p.detector = detector;
             p.cfar = cfar;
             p.snr_weight = snr_weight;
             p.validate();
             return p;
           }),
           py::kw_only(), py::arg("intensity_threshold") = d.intensity_threshold,
           py::arg("free_sample_stride") = d.free_sample_stride,
           py::arg("elevation_sample_spacing") = d.elevation_sample_spacing,
           py::arg("occupied_band") = d.occupied_band, py::arg("no_return") = d.no_return,
           py::arg("detector") = d.detector, py::arg("cfar") = d.cfar, py::arg("snr_weight") = d.snr_weight)
      .def_readwrite("intensity_threshold", &SonarProjectorParams::intensity_threshold)
      .def_readwrite("free_sample_stride", &SonarProjectorParams::free_sample_stride)
      .def_readwrite("elevation_sample_spacing", &SonarProjectorParams::elevation_sample_spacing)
      .def_readwrite("occupied_band", &SonarProjectorParams::occupied_band)
      .def_readwrite("no_return", &SonarProjectorParams::no_return)
      .def_readwrite("detector", &SonarProjectorParams::detector)
      .def_readwrite("cfar", &SonarProjectorParams::cfar)
      .def_readwrite("snr_weight", &SonarProjectorParams::snr_weight);

  py::class_<SonarPreset>(m, "SonarPreset", "Map and projector parameters chosen together for sonar surveys.")
      .def_readwrite("map", &SonarPreset::map)
      .def_readwrite("projector", &SonarPreset::projector);
  m.def("sonar_preset", &sonar_preset, py::arg("intensity_threshold") = 35.0,
        "The sonar preset: OS-CFAR detection, SNR weight, a weak echo seen once not occupied (sonar_preset.h).");

  py::class_<SonarImageProjector>(m, "SonarImageProjector",
                                  "Turns a sonar image (range bins x beams) at a pose into IWLO observations.")
      .def(py::init<double, const SonarProjectorParams&>(), py::arg("resolution"),
           py::arg("params") = SonarProjectorParams{})
      .def("resolution", &SonarImageProjector::resolution)
      .def("params", &SonarImageProjector::params)
      .def(
          "project",
          [](const SonarImageProjector& p, const ArrayLike& image, const SonarGeometry& geometry,
             const ArrayLike& pose) {
            const py::array a = as_array(image, "image");
            const SonarImageView view = image_view_of(a);
            const Eigen::Isometry3d T = pose_from(pose, "sonar_pose");
            SonarObservations o;
            {
              py::gil_scoped_release release;
              o = p.project(view, geometry, T);
            }
            return observations_to_python(o);
          },
          py::arg("image"), py::arg("geometry"), py::arg("sonar_pose"),
          "The observations of image (range_bins, beams) seen from sonar_pose (4, 4), sonar to map frame; a "
          "namespace with points (N, 3), intensities, is_occupied, weights and counts.")
      .def(
          "integrate",
          [](const SonarImageProjector& p, IMapperBackend& map, const ArrayLike& image, const SonarGeometry& geometry,
             const ArrayLike& pose) {
            const py::array a = as_array(image, "image");
            const SonarImageView view = image_view_of(a);
            const Eigen::Isometry3d T = pose_from(pose, "sonar_pose");
            const SonarObservations o = unlocked(map, [&] { return p.integrate(map, view, geometry, T); });
            return observations_to_python(o);
          },
          py::arg("map"), py::arg("image"), py::arg("geometry"), py::arg("sonar_pose"),
          "project() and then map.batch_update_iwlo() with the weights.");

  py::class_<OculusPing>(m, "OculusPing", "One Oculus SimplePingResult message.")
      .def_readonly("file_offset", &OculusPing::file_offset)
      .def_readonly("ping_id", &OculusPing::ping_id)
      .def_readonly("master_mode", &OculusPing::master_mode)
      .def_readonly("flags", &OculusPing::flags)
      .def_readonly("range", &OculusPing::range, "metres")
      .def_readonly("gain_percent", &OculusPing::gain_percent)
      .def_readonly("speed_of_sound", &OculusPing::speed_of_sound, "m/s")
      .def_readonly("frequency", &OculusPing::frequency, "Hz")
      .def_readonly("range_resolution", &OculusPing::range_resolution, "metres per range bin")
      .def_readonly("range_bins", &OculusPing::range_bins)
      .def_readonly("beams", &OculusPing::beams)
      .def_property_readonly("bearings",
                             [](const OculusPing& p) {
                               return to_numpy(Eigen::VectorXd(Eigen::Map<const Eigen::VectorXd>(
                                   p.bearings.data(), static_cast<Eigen::Index>(p.bearings.size()))));
                             },
                             "radians, one per beam")
      .def_property_readonly(
          "image",
          [](const OculusPing& p) {
            py::array_t<std::uint8_t> out({static_cast<py::ssize_t>(p.range_bins), static_cast<py::ssize_t>(p.beams)});
            if (!p.image.empty()) std::memcpy(out.mutable_data(), p.image.data(), p.image.size());
            return out;
          },
          "(range_bins, beams) uint8")
      .def("intensity", &OculusPing::intensity, py::arg("bin"), py::arg("beam"))
      .def("geometry", &OculusPing::geometry, py::arg("vertical_aperture"), py::arg("min_range") = 0.0);
  m.def(
      "read_oculus_pings",
      [](const PathLike& path) {
        const std::string file = path_from(path);
        py::gil_scoped_release release;
        return with_file_errors(file, [&] { return read_oculus_pings(file); });
      },
      py::arg("path"), "Every ping of an Oculus recording; OculusFormatError (an OSError) names the problem.");
}

}  // namespace iwlomap::python
