// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/sonar_image_projector.h"

#include "model/checks.h"
#include "storage/flat_key_map.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <stdexcept>
#include <string>

namespace iwlomap {

namespace {

constexpr double kPi = 3.14159265358979323846;

[[noreturn]] void fail(const std::string& what, const char* name, double value, const char* rule) {
  throw std::invalid_argument("iwlomap: invalid " + what + " " + detail::describe(name, value) + " (" + rule + ")");
}

// Per-voxel tally of one ping's samples.
struct Tally {
  std::uint32_t free_count = 0;
  std::uint32_t occupied_count = 0;
  double free_intensity = 0.0;      // largest intensity among the free samples
  double occupied_intensity = 0.0;  // peak intensity of the echo(es) that claimed the voxel
  double snr_weight = 0.0;          // largest SNR weight of those echoes (1 when it is off)
};

// Evenly spaced elevations across the aperture for an arc of the given length: the arc gets
// ceil(arc / spacing) + 1 samples, so the actual spacing never exceeds the requested one and both
// edges of the aperture are sampled; a zero-length arc (zero aperture or range) gets one sample
// on the axis.
void elevations(double range, double aperture, double spacing, std::vector<Eigen::Vector2d>& out) {
  out.clear();
  const double arc = range * aperture;
  if (!(arc > 0.0)) {
    out.emplace_back(1.0, 0.0);
    return;
  }
  const auto n = static_cast<std::size_t>(std::ceil(arc / spacing)) + 1;
  out.reserve(n);
  for (std::size_t j = 0; j < n; ++j) {
    const double e = -0.5 * aperture + aperture * static_cast<double>(j) / static_cast<double>(n - 1);
    out.emplace_back(std::cos(e), std::sin(e));  // (cos e, sin e)
  }
}

}  // namespace

void SonarGeometry::validate(int beams) const {
  const std::string what = "sonar geometry";
  if (beams < 1) fail(what, "beams", beams, "the image needs at least one beam");
  if (bearings.size() != static_cast<std::size_t>(beams))
    fail(what, "bearings.size()", static_cast<double>(bearings.size()),
         ("must equal the image's beam count " + std::to_string(beams)).c_str());
  for (std::size_t i = 0; i < bearings.size(); ++i)
    if (!(std::isfinite(bearings[i]) && std::abs(bearings[i]) < kPi))
      fail(what, ("bearings[" + std::to_string(i) + "]").c_str(), bearings[i], "must be finite radians in (-pi, pi)");
  if (!(std::isfinite(range_resolution) && range_resolution >= kMinSonarRangeResolution &&
        range_resolution <= kMaxSonarRangeResolution))
    fail(what, "range_resolution", range_resolution,
         "must be in [0.0001, 1] metres (kMinSonarRangeResolution, kMaxSonarRangeResolution)");
  if (!(std::isfinite(min_range) && min_range >= 0.0)) fail(what, "min_range", min_range, "must be finite and >= 0");
  if (!(std::isfinite(max_range) && max_range > min_range && max_range <= kMaxSonarRange))
    fail(what, "max_range", max_range,
         ("must be > min_range = " + std::to_string(min_range) + " and <= 1000 metres (kMaxSonarRange)").c_str());
  if (!(std::isfinite(vertical_aperture) && vertical_aperture >= 0.0 && vertical_aperture < kPi))
    fail(what, "vertical_aperture", vertical_aperture, "must be radians in [0, pi)");
}

void SonarSnrWeight::validate() const {
  const std::string what = "sonar SNR weight parameter";
  if (!std::isfinite(centre_db)) fail(what, "centre_db", centre_db, "must be finite");
  if (!(std::isfinite(width_db) && width_db > 0.0)) fail(what, "width_db", width_db, "must be finite and > 0 dB");
}

double sonar_snr_weight(double excess_db, const SonarSnrWeight& weight) {
  if (std::isnan(excess_db)) return 0.5;
  return 1.0 / (1.0 + std::exp(-(excess_db - weight.centre_db) / weight.width_db));
}

void SonarProjectorParams::validate() const {
  const std::string what = "sonar projector parameter";
  if (!std::isfinite(intensity_threshold)) fail(what, "intensity_threshold", intensity_threshold, "must be finite");
  if (!(std::isfinite(free_sample_stride) && free_sample_stride > 0.0))
    fail(what, "free_sample_stride", free_sample_stride, "must be finite and > 0 voxels");
  if (!(std::isfinite(elevation_sample_spacing) && elevation_sample_spacing > 0.0))
    fail(what, "elevation_sample_spacing", elevation_sample_spacing, "must be finite and > 0 voxels");
  if (!(std::isfinite(occupied_band) && occupied_band >= 0.0))
    fail(what, "occupied_band", occupied_band, "must be finite and >= 0 metres");
  if (no_return != SonarNoReturn::kNothing && no_return != SonarNoReturn::kFreeToMaxRange)
    fail(what, "no_return", static_cast<double>(no_return), "must be kNothing or kFreeToMaxRange");
  if (detector != SonarDetector::kThreshold && detector != SonarDetector::kCellAveragingCfar &&
      detector != SonarDetector::kOrderedStatisticCfar)
    fail(what, "detector", static_cast<double>(detector), "must be a SonarDetector");
  if (detector != SonarDetector::kThreshold) cfar.validate();
  if (snr_weight.enabled) {
    snr_weight.validate();
    if (detector == SonarDetector::kThreshold)
      throw std::invalid_argument(
          "iwlomap: invalid sonar projector parameter snr_weight.enabled = true (the SNR weight measures an echo "
          "against the CFAR threshold: it needs detector kCellAveragingCfar or kOrderedStatisticCfar)");
  }
}

SonarImageCopy::SonarImageCopy(const SonarImageView& image)
    : type_(image.type), range_bins_(image.range_bins), beams_(image.beams) {
  if (image.data == nullptr || image.range_bins < 1 || image.beams < 1)
    throw std::invalid_argument("iwlomap: SonarImageCopy: the sonar image is empty");
  std::size_t size = 1;
  switch (image.type) {
    case SonarPixelType::kUint8: size = 1; break;
    case SonarPixelType::kUint16: size = 2; break;
    case SonarPixelType::kFloat32: size = 4; break;
    case SonarPixelType::kFloat64: size = 8; break;
  }
  bytes_.resize(static_cast<std::size_t>(range_bins_) * static_cast<std::size_t>(beams_) * size);
  const auto* src = static_cast<const std::uint8_t*>(image.data);
  std::uint8_t* dst = bytes_.data();
  for (int bin = 0; bin < range_bins_; ++bin)
    for (int beam = 0; beam < beams_; ++beam, dst += size) {
      const std::ptrdiff_t i = static_cast<std::ptrdiff_t>(bin) * image.bin_stride +
                               static_cast<std::ptrdiff_t>(beam) * image.beam_stride;
      std::memcpy(dst, src + i * static_cast<std::ptrdiff_t>(size), size);
    }
}

SonarImageProjector::SonarImageProjector(double resolution, const SonarProjectorParams& params)
    : resolution_(resolution), params_(params) {
  detail::check_resolution(resolution);
  params_.validate();
  if (params_.detector != SonarDetector::kThreshold) cfar_ = std::make_shared<const SonarCfar>(params_.detector, params_.cfar);
}

SonarObservations SonarImageProjector::project(const SonarImageView& image, const SonarGeometry& geometry,
                                               const Eigen::Isometry3d& sonar_pose) const {
  if (image.range_bins < 1) fail("sonar image", "range_bins", image.range_bins, "must be >= 1");
  if (image.beams < 1) fail("sonar image", "beams", image.beams, "must be >= 1");
  if (image.data == nullptr) throw std::invalid_argument("iwlomap: invalid sonar image: data is null");
  geometry.validate(image.beams);
  if (!sonar_pose.matrix().allFinite())
    throw std::invalid_argument("iwlomap: invalid sonar pose: not finite");
  if (image.type == SonarPixelType::kFloat32 || image.type == SonarPixelType::kFloat64) {
    for (int bin = 0; bin < image.range_bins; ++bin)
      for (int beam = 0; beam < image.beams; ++beam)
        if (!std::isfinite(image.at(bin, beam)))
          fail("sonar image", ("pixel (bin " + std::to_string(bin) + ", beam " + std::to_string(beam) + ")").c_str(),
               image.at(bin, beam), "must be finite");
  }
  // Every sample lies within max_range of the sonar: checking that box once keeps the per-sample
  // key computation unchecked.
  const Eigen::Vector3d origin = sonar_pose.translation();
  const Eigen::Vector3d reach = Eigen::Vector3d::Constant(geometry.max_range);
  if (!is_representable(origin - reach, resolution_) || !is_representable(origin + reach, resolution_))
    throw std::out_of_range("iwlomap: sonar pose at (" + std::to_string(origin.x()) + ", " + std::to_string(origin.y()) +
                            ", " + std::to_string(origin.z()) + ") with max_range " +
                            std::to_string(geometry.max_range) + " leaves the map's key range");

  const SonarProjectorParams& p = params_;
  const double rr = geometry.range_resolution;
  const double step = p.free_sample_stride * resolution_;
  const double spacing = p.elevation_sample_spacing * resolution_;
  const double aperture = geometry.vertical_aperture;
  // The image says nothing beyond its last bin, whatever the range setting claims.
  const double max_range = std::min(geometry.max_range, image.range_bins * rr);
  // Bins whose centres lie in [min_range, max_range] are the only ones that count.
  const int first_bin = std::max(0, static_cast<int>(std::ceil(geometry.min_range / rr - 0.5)));
  const int last_bin = std::min(image.range_bins - 1, static_cast<int>(std::floor(max_range / rr - 0.5)));
  const bool any_bin = first_bin <= last_bin;
  // Intensity at a free sample's range; a range outside the counted bins takes the nearest one.
  const auto intensity_at = [&](double r, int beam) {
    if (!any_bin) return 0.0;
    return image.at(std::clamp(static_cast<int>(std::floor(r / rr)), first_bin, last_bin), beam);
  };

  // Free samples of every beam lie on one range grid: min_range + k * step. Their elevations
  // depend on the range only, so they are computed once per ping.
  std::vector<double> grid_range;
  std::vector<std::size_t> grid_offset{0};
  std::vector<Eigen::Vector2d> grid_elev, scratch;
  for (std::size_t k = 0;; ++k) {
    const double r = geometry.min_range + static_cast<double>(k) * step;
    if (r > max_range) break;
    grid_range.push_back(r);
    elevations(r, aperture, spacing, scratch);
    grid_elev.insert(grid_elev.end(), scratch.begin(), scratch.end());
    grid_offset.push_back(grid_elev.size());
  }
  // Range rows of the occupied band: m * step for m = 0.. up to the band length.
  const auto band_rows = static_cast<std::size_t>(std::floor(p.occupied_band / step + 1e-9)) + 1;

  // Expected samples of a voxel the fan crosses through its centre (see the class comment); the
  // band is at most band_rows rows long, so its voxels can get no more rows than that.
  const double rows_per_voxel = 1.0 / p.free_sample_stride;
  const double expected_free = rows_per_voxel / p.elevation_sample_spacing;
  const double expected_occupied =
      std::min(static_cast<double>(band_rows), rows_per_voxel) / p.elevation_sample_spacing;

  detail::FlatKeyMap index;
  std::vector<Tally> tallies;
  std::vector<VoxelKey> keys;
  const auto tally_at = [&](const Eigen::Vector3d& point) -> Tally& {
    const VoxelKey key = world_to_key(point, resolution_);
    const auto slot = static_cast<std::uint32_t>(tallies.size());
    const std::uint32_t i = index.insert(key, slot);
    if (i == slot) {
      tallies.emplace_back();
      keys.push_back(key);
    }
    return tallies[i];
  };

  SonarObservations out;
  const Eigen::Matrix3d rot = sonar_pose.linear();
  const Eigen::Vector3d down = rot.col(2);  // the sonar's +Z in the map frame
  for (int beam = 0; beam < image.beams; ++beam) {
    const double b = geometry.bearings[static_cast<std::size_t>(beam)];
    const Eigen::Vector3d ahead = rot * Eigen::Vector3d(std::cos(b), std::sin(b), 0.0);
    int hit = -1;
    double threshold_power = 0.0;  // the CFAR threshold at the detected bin
    if (cfar_) {
      hit = cfar_->first_detection(image.range_bins, first_bin, last_bin, [&](int i) { return image.at(i, beam); },
                                   p.intensity_threshold, &threshold_power);
    } else {
      for (int bin = first_bin; bin <= last_bin; ++bin)
        if (image.at(bin, beam) > p.intensity_threshold) {
          hit = bin;
          break;
        }
    }
    double free_end = 0.0;  // free samples at grid ranges r < free_end (or <= when no return)
    bool free_inclusive = false;
    if (hit >= 0) {
      ++out.beams_with_return;
      free_end = (hit + 0.5) * rr;
    } else {
      ++out.beams_without_return;
      if (p.no_return == SonarNoReturn::kFreeToMaxRange) {
        free_end = max_range;
        free_inclusive = true;
      }
    }
    for (std::size_t k = 0; k < grid_range.size(); ++k) {
      const double r = grid_range[k];
      if (free_inclusive ? r > free_end : r >= free_end) break;
      const double intensity = intensity_at(r, beam);
      for (std::size_t j = grid_offset[k]; j < grid_offset[k + 1]; ++j) {
        const Eigen::Vector2d& ce = grid_elev[j];
        Tally& t = tally_at(origin + r * (ce[0] * ahead + ce[1] * down));
        ++t.free_count;
        t.free_intensity = std::max(t.free_intensity, intensity);
        ++out.free_samples;
      }
    }
    if (hit < 0) continue;
    const double r_hit = (hit + 0.5) * rr;
    double peak = 0.0;
    const int band_last = std::clamp(static_cast<int>(std::floor((r_hit + p.occupied_band) / rr)), hit, last_bin);
    for (int bin = hit; bin <= band_last; ++bin) peak = std::max(peak, image.at(bin, beam));
    // A detection has peak^2 > threshold_power >= 0: the excess is > 0 dB (+inf, weight 1, for a zero threshold).
    const double snr_weight =
        p.snr_weight.enabled ? sonar_snr_weight(10.0 * std::log10(peak * peak / threshold_power), p.snr_weight) : 1.0;
    for (std::size_t m = 0; m < band_rows; ++m) {
      const double r = r_hit + static_cast<double>(m) * step;
      if (m > 0 && r > max_range) break;
      elevations(r, aperture, spacing, scratch);
      for (const Eigen::Vector2d& ce : scratch) {
        Tally& t = tally_at(origin + r * (ce[0] * ahead + ce[1] * down));
        ++t.occupied_count;
        t.occupied_intensity = std::max(t.occupied_intensity, peak);
        t.snr_weight = std::max(t.snr_weight, snr_weight);
        ++out.occupied_samples;
      }
    }
  }

  std::vector<std::uint32_t> order(tallies.size());
  std::iota(order.begin(), order.end(), 0u);
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) { return keys[a] < keys[b]; });
  const auto n = static_cast<Eigen::Index>(order.size());
  out.points.resize(n, 3);
  out.intensities.resize(n);
  out.weights.resize(n);
  out.is_occupied.resize(order.size());
  for (Eigen::Index row = 0; row < n; ++row) {
    const std::uint32_t i = order[static_cast<std::size_t>(row)];
    const Tally& t = tallies[i];
    const bool occupied = t.occupied_count > 0;  // occupied wins
    out.points.row(row) = key_to_center(keys[i], resolution_).transpose();
    out.is_occupied[static_cast<std::size_t>(row)] = occupied;
    out.intensities[row] = occupied ? t.occupied_intensity : t.free_intensity;
    out.weights[row] = occupied ? std::min(1.0, t.occupied_count / expected_occupied) * t.snr_weight
                                : std::min(1.0, t.free_count / expected_free);
  }
  return out;
}

SonarObservations SonarImageProjector::integrate(IMapperBackend& map, const SonarImageView& image,
                                                 const SonarGeometry& geometry,
                                                 const Eigen::Isometry3d& sonar_pose) const {
  const double map_resolution = map.get_resolution();
  if (std::abs(map_resolution - resolution_) > 1e-12 * resolution_)
    throw std::invalid_argument("iwlomap: the map's resolution " + detail::describe("resolution", map_resolution) +
                                " differs from the sonar projector's " + std::to_string(resolution_));
  SonarObservations obs = project(image, geometry, sonar_pose);
  map.batch_update_iwlo(obs.points, obs.intensities, obs.is_occupied, obs.weights);
  return obs;
}

}  // namespace iwlomap
