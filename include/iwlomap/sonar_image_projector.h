// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// SonarImageProjector: one imaging-sonar ping (a polar image of echo intensities) turned into
/// IWLO observations, one per voxel, ready for IMapperBackend::batch_update_iwlo().
///
/// Sonar frame (right-handed): +X forward along the beam of bearing 0, +Y to the right, +Z down.
/// A beam of bearing b (radians, positive toward +Y) is a vertical fan: the direction at
/// elevation e (radians, positive toward +Z, i.e. downward) is
///   (cos e cos b, cos e sin b, sin e),
/// and the sample at range r lies at r times that direction. The image gives the intensity per
/// range and bearing only: the elevation of an echo inside the vertical aperture is unknown, which
/// is why one echo becomes an arc of occupied samples and only many pings from different poses
/// settle where the surface is.
///
/// Range bin i covers [i, i + 1) * range_resolution and stands for its centre,
/// r_i = (i + 0.5) * range_resolution (the convention of the Oculus fan clouds in ../shared/data).
///
/// The model, per beam:
/// - the first return is the first range bin with intensity > intensity_threshold whose centre
///   lies in [min_range, max_range] (with a CFAR detector: the first such bin that is also a CFAR
///   detection; the CFAR windows may reach bins outside that range);
/// - free samples cover ranges [min_range, r_return) (the sonar hears nothing there, so that
///   water is empty), spread over the vertical aperture;
/// - occupied samples cover [r_return, r_return + occupied_band], spread over the aperture arc,
///   all carrying the peak intensity of the echo in that band (the band is one echo, and its
///   strength is the evidence; a weak bin inside it is not free space);
/// - everything beyond the band is acoustic shadow: no evidence;
/// - a beam with no return gives nothing, or free samples over [min_range, max_range]
///   (SonarNoReturn).
/// The near field inside min_range gives no evidence at all: the transducer ringing hides it.

#include "iwlomap/mapper_backend.h"
#include "iwlomap/sonar_cfar.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <type_traits>
#include <vector>

namespace iwlomap {

/// Element type of a sonar image.
enum class SonarPixelType { kUint8, kUint16, kFloat32, kFloat64 };

/// A non-owning view of a polar sonar image of `range_bins` x `beams` intensities. Element
/// (bin, beam) is at `data + bin * bin_stride + beam * beam_stride` (strides in elements, not
/// bytes), so row-major buffers (Oculus: bin_stride = beams, beam_stride = 1) and column-major
/// Eigen matrices (bin_stride = 1, beam_stride = outer stride) are both views without a copy.
/// Intensities are raw units (the same units as the projector's and the map's thresholds).
struct SonarImageView {
  const void* data = nullptr;
  SonarPixelType type = SonarPixelType::kUint8;
  int range_bins = 0;
  int beams = 0;
  std::ptrdiff_t bin_stride = 0;   ///< elements from (bin, beam) to (bin + 1, beam)
  std::ptrdiff_t beam_stride = 0;  ///< elements from (bin, beam) to (bin, beam + 1)

  /// Intensity of one pixel as a double (unchecked indices).
  [[nodiscard]] double at(int bin, int beam) const noexcept {
    const std::ptrdiff_t i = static_cast<std::ptrdiff_t>(bin) * bin_stride + static_cast<std::ptrdiff_t>(beam) * beam_stride;
    switch (type) {
      case SonarPixelType::kUint8: return static_cast<const std::uint8_t*>(data)[i];
      case SonarPixelType::kUint16: return static_cast<const std::uint16_t*>(data)[i];
      case SonarPixelType::kFloat32: return static_cast<double>(static_cast<const float*>(data)[i]);
      case SonarPixelType::kFloat64: return static_cast<const double*>(data)[i];
    }
    return 0.0;
  }
};

namespace detail {
template <typename T>
constexpr SonarPixelType sonar_pixel_type() {
  static_assert(std::is_same_v<T, std::uint8_t> || std::is_same_v<T, std::uint16_t> || std::is_same_v<T, float> ||
                    std::is_same_v<T, double>,
                "sonar images are uint8, uint16, float or double");
  if constexpr (std::is_same_v<T, std::uint8_t>) return SonarPixelType::kUint8;
  else if constexpr (std::is_same_v<T, std::uint16_t>) return SonarPixelType::kUint16;
  else if constexpr (std::is_same_v<T, float>) return SonarPixelType::kFloat32;
  else return SonarPixelType::kFloat64;
}
}  // namespace detail

/// A view of a row-major buffer of `range_bins` rows of `beams` values (the Oculus layout).
template <typename T>
[[nodiscard]] SonarImageView make_sonar_image_view(const T* data, int range_bins, int beams) {
  return {data, detail::sonar_pixel_type<T>(), range_bins, beams, static_cast<std::ptrdiff_t>(beams), 1};
}

/// A view of an Eigen matrix (or a Map or block of one: any expression with direct access) with one
/// row per range bin and one column per beam. The matrix must outlive the view.
template <typename Derived>
[[nodiscard]] SonarImageView make_sonar_image_view(const Eigen::MatrixBase<Derived>& image) {
  using T = typename Derived::Scalar;
  return {image.derived().data(), detail::sonar_pixel_type<T>(), static_cast<int>(image.rows()),
          static_cast<int>(image.cols()),
          static_cast<std::ptrdiff_t>(image.rowStride()), static_cast<std::ptrdiff_t>(image.colStride())};
}

/// An owned copy of a sonar image, row-major (bin_stride = beams): what a mapper keeps of a ping
/// it integrates later (submaps, re-integration at corrected poses).
class SonarImageCopy {
 public:
  SonarImageCopy() = default;
  /// Copies \p image through its strides. Throws std::invalid_argument for an empty view.
  explicit SonarImageCopy(const SonarImageView& image);
  /// A view of the copy, valid while the copy lives and is not moved.
  [[nodiscard]] SonarImageView view() const noexcept {
    return {bytes_.data(), type_, range_bins_, beams_, static_cast<std::ptrdiff_t>(beams_), 1};
  }
  /// Bytes held.
  [[nodiscard]] std::size_t size_bytes() const noexcept { return bytes_.size(); }

 private:
  SonarPixelType type_ = SonarPixelType::kUint8;
  int range_bins_ = 0, beams_ = 0;
  std::vector<std::uint8_t> bytes_;
};

/// Sonar images as Eigen matrices: rows = range bins, columns = beams.
using SonarImage8 = Eigen::Matrix<std::uint8_t, Eigen::Dynamic, Eigen::Dynamic>;
using SonarImage16 = Eigen::Matrix<std::uint16_t, Eigen::Dynamic, Eigen::Dynamic>;
using SonarImageF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic>;

/// The acquisition geometry of one ping.
/// Bounds of what an imaging sonar can measure, checked by SonarGeometry::validate() and by
/// read_oculus_pings(): beyond them a ping is a corrupt or crafted file, and projecting it would
/// take memory without bound (free space sampled at the map's resolution out to its range).
/// Imaging sonars range to about 300 m at their lowest frequencies, with bins of a few
/// centimetres.
constexpr double kMaxSonarRange = 1000.0;           ///< metres
constexpr double kMaxSonarRangeResolution = 1.0;    ///< metres per range bin
constexpr double kMinSonarRangeResolution = 1e-4;   ///< metres per range bin (0.1 mm)

struct SonarGeometry {
  std::vector<double> bearings;   ///< radians, one per beam (column), positive toward +Y
  double range_resolution = 0.0;  ///< metres per range bin, in [kMinSonarRangeResolution,
                                  ///< kMaxSonarRangeResolution]
  double min_range = 0.0;         ///< metres, >= 0: no evidence closer than this
  double max_range = 0.0;         ///< metres, in (min_range, kMaxSonarRange]: no evidence beyond
                                  ///< this (nor beyond the image's last bin, range_bins *
                                  ///< range_resolution)
  double vertical_aperture = 0.0; ///< full vertical opening of every beam, radians, in [0, pi)

  /// Throws std::invalid_argument naming the first invalid value; \p beams is the image's width.
  void validate(int beams) const;
};

/// What a beam without any return above the threshold means.
enum class SonarNoReturn {
  kNothing,        ///< no evidence (e.g. the gain was too low to trust silence)
  kFreeToMaxRange  ///< the water is empty up to max_range (sonar semantics: no echo, no object)
};

/// The spread of the power of Rayleigh-amplitude noise on a decibel scale: the standard deviation
/// of 10 log10(P) for exponentially distributed P, (pi / sqrt(6)) * 10 / ln(10) = 5.570 dB. It is
/// how far a bin of noise alone typically strays from its mean level, whatever that level.
constexpr double kRayleighPowerSpreadDb = 5.57004;

/// A weight for each occupied observation from the strength of its echo over the detector's
/// threshold (needs a CFAR detector). With the excess
///   x = 10 log10(P_peak / T)  dB,
/// P_peak the squared peak intensity of the echo band and T the CFAR threshold on power at the
/// detected bin (the noise estimate times the factor of the false-alarm rate), the weight is
///   w = 1 / (1 + exp(-(x - centre_db) / width_db)).
/// Both constants come from the detector's statistics: at the default centre 0 an echo just at the
/// threshold, which noise alone reaches with the false-alarm rate, weighs 0.5; the default width
/// is the spread of a noise bin's power (kRayleighPowerSpreadDb), so an echo one such spread above
/// the threshold weighs 0.73, two spreads 0.88, four 0.98. A weak echo in a bright stretch of the
/// image (a raised noise floor) thus counts less than an echo of the same intensity in quiet
/// water, which a fixed intensity scale cannot express.
struct SonarSnrWeight {
  bool enabled = false;     ///< off: occupied weights are the coverage weights alone
  double centre_db = 0.0;   ///< excess over the threshold (dB) that weighs 0.5, finite
  double width_db = kRayleighPowerSpreadDb;  ///< dB per e-fold of the odds, finite and > 0

  /// Throws std::invalid_argument naming the first invalid value.
  void validate() const;
};

/// The weight of SonarSnrWeight for an echo \p excess_db decibels above the detection threshold
/// (+infinity gives 1; NaN gives 0.5, no information either way).
[[nodiscard]] double sonar_snr_weight(double excess_db, const SonarSnrWeight& weight);

struct SonarProjectorParams {
  /// A bin is an echo when its intensity exceeds this (raw units). Use the map's
  /// intensity_threshold: the map counts an occupied observation at or below its own threshold as
  /// free, so a lower value here only adds free observations. With a CFAR detector, an echo must
  /// also exceed this (0: CFAR alone).
  double intensity_threshold = 35.0;
  /// How the first return is found: the fixed threshold above (default) or a CFAR detector
  /// against the beam's local noise level (sonar_cfar.h).
  SonarDetector detector = SonarDetector::kThreshold;
  SonarCfarParams cfar;  ///< the CFAR detector's window and false-alarm rate
  /// Weighs occupied observations by the echo's strength over the CFAR threshold (needs a CFAR
  /// detector; off by default).
  SonarSnrWeight snr_weight;
  /// Range step between samples along a beam, in voxels (> 0). 0.5 puts about two samples along
  /// every voxel a beam crosses, so no voxel is skipped.
  double free_sample_stride = 0.5;
  /// Arc length between samples across the vertical aperture, in voxels (> 0). At range r the
  /// aperture arc r * vertical_aperture gets ceil(arc / spacing) + 1 evenly spaced samples.
  double elevation_sample_spacing = 1.0;
  /// Length of the occupied band after the first return, metres (>= 0). 0: only the arc at the
  /// return's range.
  double occupied_band = 0.0;
  SonarNoReturn no_return = SonarNoReturn::kFreeToMaxRange;

  /// Throws std::invalid_argument naming the first invalid parameter and its value.
  void validate() const;
};

/// The observations of one ping: one row per voxel, each at the voxel's centre (map frame), so
/// that a backend of the same resolution puts it in exactly that voxel.
struct SonarObservations {
  Eigen::MatrixXd points;          ///< N x 3 voxel centres, metres, map frame
  Eigen::VectorXd intensities;     ///< occupied: the echo's peak intensity; free: the largest
                                   ///< intensity of the free samples in the voxel (<= threshold)
  std::vector<bool> is_occupied;   ///< true: occupied observation; false: free observation
  Eigen::VectorXd weights;         ///< in (0, 1], see SonarImageProjector
  std::size_t beams_with_return = 0;
  std::size_t beams_without_return = 0;
  std::size_t free_samples = 0;      ///< samples before the returns (and of no-return beams)
  std::size_t occupied_samples = 0;  ///< samples in the occupied bands

  [[nodiscard]] std::size_t size() const noexcept { return is_occupied.size(); }
};

/// Projects sonar pings into voxel observations at a fixed map resolution.
///
/// One observation per voxel per ping: a voxel with any occupied sample is occupied (occupied
/// wins, as in OctoMap's scan insertion), else free. Its weight is
///   W = min(1, n / n_expected),  n_expected = 1 / (free_sample_stride * elevation_sample_spacing),
/// n being the samples of the winning kind that fell in the voxel. n_expected is the count of a
/// voxel whose centre one beam's fan (range x elevation sheet) crosses: the sheet meets it over
/// about one voxel face, sampled every stride voxels in range and every spacing voxels in
/// elevation. So a voxel only grazed by a fan's edge or corner gets a fraction of an observation
/// (the ping barely saw it), and one well covered gets a full one. The cap at 1 keeps one ping one
/// observation: near the sonar many beams cross the same voxel, but adjacent beams overlap and
/// are not independent measurements, and the IWLO learning rate assumes one update per ping.
/// With SonarProjectorParams::snr_weight enabled, an occupied voxel's weight is further multiplied
/// by the largest SNR weight (sonar_snr_weight()) of the echoes that claimed it.
///
/// Immutable after construction; project() may run concurrently on one projector.
class SonarImageProjector {
 public:
  /// \param resolution the map's voxel edge in metres (> 0, finite)
  /// \param params detection and sampling settings (see SonarProjectorParams)
  /// Throws std::invalid_argument naming the value for an invalid resolution or parameter.
  explicit SonarImageProjector(double resolution, const SonarProjectorParams& params = {});

  [[nodiscard]] double resolution() const noexcept { return resolution_; }
  [[nodiscard]] const SonarProjectorParams& params() const noexcept { return params_; }

  /// Projects one ping taken at \p sonar_pose (sonar frame to map frame). Observations are sorted
  /// by voxel key, so the output is deterministic. Throws std::invalid_argument, naming the value,
  /// for an empty or null image, a geometry that does not fit the image or is invalid, a
  /// non-finite pose, or a NaN or infinite pixel.
  [[nodiscard]] SonarObservations project(const SonarImageView& image, const SonarGeometry& geometry,
                                          const Eigen::Isometry3d& sonar_pose) const;

  /// project() followed by map.batch_update_iwlo(points, intensities, is_occupied, weights).
  /// Throws std::invalid_argument when the map's resolution differs from the projector's (the
  /// one-observation-per-voxel guarantee only holds at the same resolution). Returns the
  /// observations applied.
  SonarObservations integrate(IMapperBackend& map, const SonarImageView& image, const SonarGeometry& geometry,
                              const Eigen::Isometry3d& sonar_pose) const;

 private:
  double resolution_;
  SonarProjectorParams params_;
  std::shared_ptr<const SonarCfar> cfar_;  // null for SonarDetector::kThreshold
};

}  // namespace iwlomap
