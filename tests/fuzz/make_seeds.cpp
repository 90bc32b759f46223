// SPDX-License-Identifier: BSD-3-Clause
// Writes a small seed corpus for each fuzz target into DIR/<target>/: valid files the fuzzer
// mutates from (a random start rarely gets past a format's first checks).
// usage: make_seeds DIR

#include "backends/disk/map_manifest.h"
#include "backends/disk/tile_file.h"
#include "integrate/hit_accumulator.h"
#include "storage/block_grid.h"

#include <Eigen/Core>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

namespace d = iwlomap::detail;
namespace fs = std::filesystem;

namespace {

void write(const fs::path& file, const std::vector<std::uint8_t>& bytes) {
  std::ofstream out(file, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error("cannot write " + file.string());
}

std::vector<std::uint8_t> text(char first, const std::string& body) {
  std::vector<std::uint8_t> v{static_cast<std::uint8_t>(first)};
  v.insert(v.end(), body.begin(), body.end());
  return v;
}

// fuzz_cloud: the first byte picks the extension (even: .pcd, odd: .ply).
void cloud_seeds(const fs::path& dir) {
  const std::string header = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\n"
                             "COUNT 1 1 1 1\nWIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 1.5 1 0 0 0\nPOINTS 3\n";
  write(dir / "ascii.pcd", text(0, header + "DATA ascii\n1 2 3 40\n-1.5 0.25 2 200\n3 3 0 0\n"));
  std::string binary = header + "DATA binary\n";
  const float values[12] = {1, 2, 3, 40, -1.5f, 0.25f, 2, 200, 3, 3, 0, 0};
  binary.append(reinterpret_cast<const char*>(values), sizeof values);
  write(dir / "binary.pcd", text(0, binary));
  write(dir / "doubles.pcd", text(0, "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 8 8 8 2\nTYPE F F F U\n"
                                     "COUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n"
                                     "1.5 -2.25 3.125 300\n2.5 -1.25 4.125 700\n"));
  write(dir / "ascii.ply", text(1, "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                                   "property float z\nproperty float intensity\nend_header\n1 2 3 4\n5 6 7 8\n"));
  std::string ply_bin = "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                        "property float z\nend_header\n";
  const float xyz[6] = {1, 2, 3, 4, 5, 6};
  ply_bin.append(reinterpret_cast<const char*>(xyz), sizeof xyz);
  write(dir / "binary.ply", text(1, ply_bin));
}

// fuzz_tile: a tile of a few blocks (format 3), without hit statistics, with them, and in the
// voxel layout of 12-bit counts.
void tile_seeds(const fs::path& dir) {
  const iwlomap::iwlo::VoxelFormat format;
  iwlomap::IwloParams slow;
  slow.decay_rate = 0.001;
  const iwlomap::iwlo::VoxelFormat wide = iwlomap::iwlo::voxel_format(slow);
  const double resolution = 0.1;
  const std::uint32_t tile_voxels = 32;
  d::BlockGrid grid;
  d::HitAccumulator hits(resolution);
  for (int i = 0; i < 40; ++i) {
    const iwlomap::VoxelKey key{i % 17, (i * 7) % 23, (i * 3) % 5};
    d::VoxelBlock* block = nullptr;
    d::BlockAccessor acc(grid);
    d::Voxel& v = acc.voxel(key, block);
    v.word = format.encode(0.5 * (i % 9) - 2.0, 1 + static_cast<std::uint32_t>(i % 4));
    ++block->known;
    hits.add_hit(key, Eigen::Vector3d(key.x + 0.5, key.y + 0.25, key.z + 0.75) * resolution);
  }
  std::vector<std::uint8_t> bytes;
  d::encode_tile(grid, format, nullptr, 0, resolution, tile_voxels, iwlomap::VoxelKey{0, 0, 0}, bytes);
  write(dir / "plain.tile", bytes);
  d::encode_tile(grid, format, &hits, 3, resolution, tile_voxels, iwlomap::VoxelKey{0, 0, 0}, bytes);
  write(dir / "hits.tile", bytes);
  for (d::VoxelBlock* b : grid.blocks())
    b->for_each_slot([&](int i, const d::Voxel& v) {
      if (v.known()) b->existing(i).word = wide.convert(v.word, format);
    });
  d::encode_tile(grid, wide, nullptr, 0, resolution, tile_voxels, iwlomap::VoxelKey{0, 0, 0}, bytes);
  write(dir / "wide.tile", bytes);
}

void put_u16(std::vector<std::uint8_t>& b, std::size_t at, std::uint16_t v) { std::memcpy(&b[at], &v, 2); }
void put_u32(std::vector<std::uint8_t>& b, std::size_t at, std::uint32_t v) { std::memcpy(&b[at], &v, 4); }
void put_f64(std::vector<std::uint8_t>& b, std::size_t at, double v) { std::memcpy(&b[at], &v, 8); }

// fuzz_manifest: an empty map's, and one of three tiles with a retired file and statistics on.
void manifest_seeds(const fs::path& dir) {
  d::MapManifest m;
  write(dir / "empty.manifest", d::encode_manifest(m));
  m.commit = 7;
  m.state.hit_statistics = true;
  m.state.hit_epoch = 2;
  m.state.params.occupied_threshold = 0.6;
  m.tiles = {{{-1, 0, 2}, 3, 400, 12, 0x1234abcdu}, {{0, 0, 0}, 7, 980, 51, 0x0badf00du}, {{5, -2, 1}, 0, 81, 1, 7u}};
  m.retired = {{{0, 0, 0}, 4}};
  std::vector<std::uint8_t> tiles = d::encode_manifest(m);
  write(dir / "tiles.manifest", tiles);
  // A fuzzing find: adaptive_enabled as -0.0 (equal to 0.0, but not its bytes) must be refused.
  put_f64(tiles, 32 + 8 * 9, -0.0);
  write(dir / "negative_zero_flag.manifest", tiles);
}

// fuzz_oculus: one SimplePingResult v1 message of 16 beams x 40 range bins, with and without
// per-row gains.
std::vector<std::uint8_t> oculus_ping(bool row_gains) {
  constexpr std::size_t kBearings = 122;
  const std::uint16_t beams = 16, bins = 40;
  const std::size_t row = beams + (row_gains ? 4 : 0);
  const std::size_t image_offset = kBearings + 2 * beams;
  const std::size_t length = image_offset + row * bins;
  std::vector<std::uint8_t> b(length, 0);
  put_u16(b, 0, 0x4f53);
  put_u16(b, 6, 0x23);
  put_u16(b, 8, 1);
  put_u32(b, 10, static_cast<std::uint32_t>(length - 16));
  b[16] = 1;
  b[20] = row_gains ? 0x04 : 0x00;
  put_f64(b, 21, 4.0);     // range, m
  put_f64(b, 29, 50.0);    // gain, %
  put_u32(b, 53, 7);       // ping id
  put_f64(b, 61, 1.2e6);   // Hz
  put_f64(b, 85, 1500.0);  // m/s
  b[97] = 0;               // 8-bit image
  put_f64(b, 98, 0.1);     // m per bin
  put_u16(b, 106, bins);
  put_u16(b, 108, beams);
  put_u32(b, 110, static_cast<std::uint32_t>(image_offset));
  put_u32(b, 114, static_cast<std::uint32_t>(row * bins));
  put_u32(b, 118, static_cast<std::uint32_t>(length));
  for (std::uint16_t i = 0; i < beams; ++i)
    put_u16(b, kBearings + 2 * i, static_cast<std::uint16_t>(static_cast<std::int16_t>(-6500 + 866 * i)));
  for (std::size_t r = 0; r < bins; ++r) {
    std::uint8_t* p = &b[image_offset + r * row];
    if (row_gains) {
      put_u32(b, image_offset + r * row, 1);
      p += 4;
    }
    for (std::size_t k = 0; k < beams; ++k) p[k] = static_cast<std::uint8_t>(r == 20 + k % 5 ? 200 : (r * 7 + k) % 30);
  }
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: make_seeds DIR\n";
    return 2;
  }
  try {
    const fs::path root(argv[1]);
    for (const char* t : {"fuzz_cloud", "fuzz_tile", "fuzz_manifest", "fuzz_oculus"}) fs::create_directories(root / t);
    cloud_seeds(root / "fuzz_cloud");
    tile_seeds(root / "fuzz_tile");
    manifest_seeds(root / "fuzz_manifest");
    write(root / "fuzz_oculus" / "ping.raw", oculus_ping(false));
    write(root / "fuzz_oculus" / "ping_gains.raw", oculus_ping(true));
    std::vector<std::uint8_t> two = oculus_ping(false);
    const std::vector<std::uint8_t> second = oculus_ping(true);
    two.insert(two.end(), second.begin(), second.end());
    write(root / "fuzz_oculus" / "two_pings.raw", two);
  } catch (const std::exception& e) {
    std::cerr << "make_seeds: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
