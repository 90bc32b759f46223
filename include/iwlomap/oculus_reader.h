// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// A reader for files of Blueprint Subsea Oculus `SimplePingResult` (version 1) network messages,
/// such as ../shared/data/oculus_sonar_3pings/three_pings_8bit.raw.
///
/// The layout, little-endian and packed (offsets from the start of a message):
///   0   message header, 16 bytes: uint16 magic 0x4f53 ("SO"), uint16 source device,
///       uint16 destination device, uint16 message id (0x23 = simple ping result), uint16 message
///       version (0 or 1 here; 2 is the SimplePingResult2 layout, not read), uint32 payload size
///       (bytes after this header), uint16 spare
///   16  fire settings: uint8 master mode, uint8 ping rate, uint8 network speed, uint8 gamma,
///       uint8 flags; double range (m), double gain (%), double speed of sound (m/s, as set),
///       double salinity (ppt)
///   53  result: uint32 ping id, uint32 status, double frequency (Hz), double temperature,
///       double pressure, double speed of sound used (m/s), uint32 ping start time, uint8 data
///       size (0 = 8-bit), double range resolution (m), uint16 range bins, uint16 beams,
///       uint32 image offset, uint32 image size, uint32 message size (header included)
///   122 bearing table: int16 per beam, hundredths of a degree
///   image offset: the image, range bins x beams, row-major by range bin; with flag 0x04 every
///       row starts with a uint32 gain. Bytes between the bearing table and the image are padding.
/// Messages follow each other with no gap; the next starts 16 + payload size bytes later.
/// Messages with another id (status messages, ...) are skipped.
///
/// The image's pixel (bin, beam) lies at range (bin + 0.5) * range resolution and bearing
/// bearings[beam]; see SonarImageProjector for the frame.

#include "iwlomap/sonar_image_projector.h"

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {

/// One ping with its settings and its 8-bit image.
struct OculusPing {
  std::size_t file_offset = 0;         ///< byte offset of the message in the file
  std::uint32_t ping_id = 0;
  std::uint8_t master_mode = 0;        ///< 1: low frequency, wide aperture; 2: high frequency
  std::uint8_t flags = 0;              ///< the fire message's flags byte
  double range = 0.0;                  ///< range setting, metres
  double gain_percent = 0.0;
  double speed_of_sound = 0.0;         ///< speed of sound used, m/s
  double frequency = 0.0;              ///< Hz
  double range_resolution = 0.0;       ///< metres per range bin
  int range_bins = 0;
  int beams = 0;
  std::vector<std::int16_t> bearing_table;  ///< as stored: hundredths of a degree
  std::vector<double> bearings;             ///< radians, one per beam
  std::vector<std::uint32_t> row_gains;     ///< one per range bin when flag 0x04 is set, else empty
  std::vector<std::uint8_t> image;          ///< range_bins x beams, row-major by range bin

  /// Intensity of pixel (bin, beam); throws std::out_of_range naming the index.
  [[nodiscard]] std::uint8_t intensity(int bin, int beam) const;
  /// A view of the image for SonarImageProjector (valid while this ping lives).
  [[nodiscard]] SonarImageView image_view() const;
  /// The geometry for SonarImageProjector: bearings, range resolution, [min_range, range] and
  /// the given vertical aperture (radians; the message does not record it).
  [[nodiscard]] SonarGeometry geometry(double vertical_aperture, double min_range = 0.0) const;
};

/// A file that is not a sequence of valid Oculus messages. what() names the file and the byte
/// offset; both are also available.
class OculusFormatError : public std::runtime_error {
 public:
  OculusFormatError(const std::string& source, std::size_t offset, const std::string& problem);
  [[nodiscard]] const std::string& source() const noexcept { return source_; }
  [[nodiscard]] std::size_t offset() const noexcept { return offset_; }

 private:
  std::string source_;
  std::size_t offset_;
};

/// Reads every SimplePingResult v1 message of a file, in file order. Throws std::runtime_error
/// naming the file when it cannot be opened or read, and OculusFormatError for malformed or
/// truncated content (a file without any ping is malformed too).
[[nodiscard]] std::vector<OculusPing> read_oculus_pings(const std::string& path);

/// The same from memory; \p source names the data in error messages.
[[nodiscard]] std::vector<OculusPing> parse_oculus_pings(const std::uint8_t* data, std::size_t size,
                                                         const std::string& source);

}  // namespace iwlomap
