// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/oculus_reader.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <sstream>

namespace iwlomap {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr std::uint16_t kMagic = 0x4f53;
constexpr std::uint16_t kSimplePingResult = 0x23;
constexpr std::size_t kHeaderSize = 16;
constexpr std::size_t kBearingsOffset = 122;  // end of the fixed part of a v1 ping result
constexpr std::uint8_t kFlagRowGains = 0x04;

// Little-endian field access, independent of the host's byte order and alignment.
class Reader {
 public:
  Reader(const std::uint8_t* data, std::size_t size, const std::string& source)
      : data_(data), size_(size), source_(source) {}

  [[nodiscard]] std::uint8_t u8(std::size_t at) const { return data_[at]; }
  [[nodiscard]] std::uint16_t u16(std::size_t at) const {
    return static_cast<std::uint16_t>(data_[at] | (data_[at + 1] << 8));
  }
  [[nodiscard]] std::uint32_t u32(std::size_t at) const {
    return static_cast<std::uint32_t>(u16(at)) | (static_cast<std::uint32_t>(u16(at + 2)) << 16);
  }
  [[nodiscard]] double f64(std::size_t at) const {
    const std::uint64_t bits = static_cast<std::uint64_t>(u32(at)) | (static_cast<std::uint64_t>(u32(at + 4)) << 32);
    double d;
    std::memcpy(&d, &bits, sizeof d);
    return d;
  }
  [[noreturn]] void fail(std::size_t offset, const std::string& problem) const {
    throw OculusFormatError(source_, offset, problem);
  }
  [[nodiscard]] std::size_t size() const noexcept { return size_; }
  [[nodiscard]] const std::uint8_t* data() const noexcept { return data_; }

 private:
  const std::uint8_t* data_;
  std::size_t size_;
  const std::string& source_;
};

std::string hex(unsigned value) {
  std::ostringstream s;
  s << "0x" << std::hex << value;
  return s.str();
}

std::string number(double value) {
  std::ostringstream s;
  s.precision(17);
  s << value;
  return s.str();
}

// Parses the ping result at \p at (its header already checked), whose message spans \p length bytes.
OculusPing parse_ping(const Reader& in, std::size_t at, std::size_t length) {
  if (length < kBearingsOffset)
    in.fail(at, "a SimplePingResult needs at least " + std::to_string(kBearingsOffset) + " bytes, this message has " +
                    std::to_string(length));
  OculusPing ping;
  ping.file_offset = at;
  ping.master_mode = in.u8(at + 16);
  ping.flags = in.u8(at + 20);
  ping.range = in.f64(at + 21);
  ping.gain_percent = in.f64(at + 29);
  ping.ping_id = in.u32(at + 53);
  ping.frequency = in.f64(at + 61);
  ping.speed_of_sound = in.f64(at + 85);
  const std::uint8_t data_size = in.u8(at + 97);
  ping.range_resolution = in.f64(at + 98);
  ping.range_bins = in.u16(at + 106);
  ping.beams = in.u16(at + 108);
  const std::uint32_t image_offset = in.u32(at + 110);
  const std::uint32_t image_size = in.u32(at + 114);
  const std::uint32_t message_size = in.u32(at + 118);

  if (data_size != 0)
    in.fail(at + 97, "data size " + std::to_string(data_size) + " (only 8-bit images, data size 0, are read)");
  if (!(std::isfinite(ping.range_resolution) && ping.range_resolution >= kMinSonarRangeResolution &&
        ping.range_resolution <= kMaxSonarRangeResolution))
    in.fail(at + 98, "range resolution " + number(ping.range_resolution) + " m is not in [0.0001, 1] m");
  if (ping.range_bins == 0) in.fail(at + 106, "range bin count is 0");
  if (!(std::isfinite(ping.range) && ping.range > 0.0 && ping.range <= kMaxSonarRange))
    in.fail(at + 21, "range " + number(ping.range) + " m is not in (0, 1000] m");
  if (ping.range_bins * ping.range_resolution > kMaxSonarRange)
    in.fail(at + 106, std::to_string(ping.range_bins) + " range bins of " + number(ping.range_resolution) +
                          " m reach beyond 1000 m");
  if (ping.beams == 0) in.fail(at + 108, "beam count is 0");
  if (message_size != length)
    in.fail(at + 118, "message size " + std::to_string(message_size) + " differs from the header's 16 + payload = " +
                          std::to_string(length));
  const std::size_t bearings_end = kBearingsOffset + 2 * static_cast<std::size_t>(ping.beams);
  if (bearings_end > length)
    in.fail(at + kBearingsOffset, "the bearing table of " + std::to_string(ping.beams) + " beams needs " +
                                      std::to_string(bearings_end) + " bytes, the message has " + std::to_string(length));
  const bool row_gains = (ping.flags & kFlagRowGains) != 0;
  const std::size_t row_bytes = static_cast<std::size_t>(ping.beams) + (row_gains ? 4 : 0);
  const std::size_t expected_image = row_bytes * static_cast<std::size_t>(ping.range_bins);
  if (image_size != expected_image)
    in.fail(at + 114, "image size " + std::to_string(image_size) + " differs from " +
                          std::to_string(ping.range_bins) + " range bins x " + std::to_string(row_bytes) +
                          " bytes per row = " + std::to_string(expected_image) +
                          (row_gains ? " (rows carry a 4-byte gain, flag 0x04)" : ""));
  if (image_offset < bearings_end || static_cast<std::size_t>(image_offset) + image_size > length)
    in.fail(at + 110, "image offset " + std::to_string(image_offset) + " with image size " +
                          std::to_string(image_size) + " does not lie within the message after the bearing table (" +
                          std::to_string(bearings_end) + ".." + std::to_string(length) + ")");

  ping.bearing_table.resize(static_cast<std::size_t>(ping.beams));
  ping.bearings.resize(static_cast<std::size_t>(ping.beams));
  for (std::size_t i = 0; i < ping.bearing_table.size(); ++i) {
    ping.bearing_table[i] = static_cast<std::int16_t>(in.u16(at + kBearingsOffset + 2 * i));
    ping.bearings[i] = ping.bearing_table[i] / 100.0 * kPi / 180.0;
  }
  ping.image.resize(static_cast<std::size_t>(ping.beams) * static_cast<std::size_t>(ping.range_bins));
  const std::uint8_t* image = in.data() + at + image_offset;
  if (row_gains) ping.row_gains.resize(static_cast<std::size_t>(ping.range_bins));
  for (std::size_t row = 0; row < static_cast<std::size_t>(ping.range_bins); ++row) {
    const std::uint8_t* src = image + row * row_bytes;
    if (row_gains) {
      ping.row_gains[row] = in.u32(static_cast<std::size_t>(src - in.data()));
      src += 4;
    }
    std::memcpy(ping.image.data() + row * static_cast<std::size_t>(ping.beams), src, static_cast<std::size_t>(ping.beams));
  }
  return ping;
}

}  // namespace

OculusFormatError::OculusFormatError(const std::string& source, std::size_t offset, const std::string& problem)
    : std::runtime_error("iwlomap: " + source + ": not a valid Oculus SimplePingResult file at byte offset " +
                         std::to_string(offset) + ": " + problem),
      source_(source),
      offset_(offset) {}

std::uint8_t OculusPing::intensity(int bin, int beam) const {
  if (bin < 0 || bin >= range_bins || beam < 0 || beam >= beams)
    throw std::out_of_range("iwlomap: Oculus pixel (bin " + std::to_string(bin) + ", beam " + std::to_string(beam) +
                            ") outside the " + std::to_string(range_bins) + " x " + std::to_string(beams) + " image");
  return image[static_cast<std::size_t>(bin) * static_cast<std::size_t>(beams) + static_cast<std::size_t>(beam)];
}

SonarImageView OculusPing::image_view() const { return make_sonar_image_view(image.data(), range_bins, beams); }

SonarGeometry OculusPing::geometry(double vertical_aperture, double min_range) const {
  SonarGeometry g;
  g.bearings = bearings;
  g.range_resolution = range_resolution;
  g.min_range = min_range;
  g.max_range = range;
  g.vertical_aperture = vertical_aperture;
  return g;
}

std::vector<OculusPing> parse_oculus_pings(const std::uint8_t* data, std::size_t size, const std::string& source) {
  const Reader in(data, size, source);
  std::vector<OculusPing> pings;
  std::size_t at = 0;
  while (at < size) {
    if (size - at < kHeaderSize)
      in.fail(at, "truncated message header: " + std::to_string(size - at) + " bytes left, 16 needed");
    const std::uint16_t magic = in.u16(at);
    if (magic != kMagic) in.fail(at, "message magic " + hex(magic) + " is not 0x4f53 (\"SO\")");
    const std::uint16_t id = in.u16(at + 6);
    const std::uint16_t version = in.u16(at + 8);
    const std::size_t length = kHeaderSize + in.u32(at + 10);
    if (length > size - at)
      in.fail(at, "truncated message: the header announces " + std::to_string(length) + " bytes, " +
                      std::to_string(size - at) + " are left");
    if (id == kSimplePingResult) {
      if (version >= 2)
        in.fail(at + 8, "message version " + std::to_string(version) +
                            " (SimplePingResult2); only version 0/1 messages are read");
      pings.push_back(parse_ping(in, at, length));
    }
    at += length;
  }
  if (pings.empty()) in.fail(0, "no SimplePingResult message (id 0x23) in " + std::to_string(size) + " bytes");
  return pings;
}

std::vector<OculusPing> read_oculus_pings(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  if (!file) throw std::runtime_error("iwlomap: cannot open Oculus file " + path);
  const std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  if (file.bad()) throw std::runtime_error("iwlomap: error while reading Oculus file " + path);
  return parse_oculus_pings(bytes.data(), bytes.size(), path);
}

}  // namespace iwlomap
