// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap pyramid`: the multi-resolution max grids of a map (Cartographer's precomputation
// grids) as one PNG and one text dump per level.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "map_open.h"
#include "map_options.h"
#include "output_files.h"

#include <iwlomap/precomputation_stack.h>
#include <iwlomap/probability_updater.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap::tool {

namespace {

const char* kHelp = R"(usage: iwlomap pyramid INPUT -o DIR [options]

Builds the stack of max-pooled grids of a map, as Cartographer's branch-and-bound scan matcher
uses them: level K holds, in each cell, the largest 8-bit occupancy value of a 2^K x 2^K window
(value = round((p - 0.1) / 0.8 * 255), p clamped to [0.1, 0.9]; unknown = 0), and grows by
2^K - 1 cells per axis. For each level K it writes into DIR:
  level_K.png   grey = 255 - value (occupied dark, free and unknown white), +y up, +x right
  level_K.txt   Cartographer's debug dump: a line "num_y_cells num_x_cells", then one row of
                cell values per line, each right-aligned in a field of width 4, rows in the
                PNG's order (largest y first)

INPUT is a map:
  .pcd / .ply   a voxel cloud as 'iwlomap map' writes it: one point per voxel at its centre,
                intensity = occupancy probability (a raw scan is refused: map it first). Only
                the voxels in the file are known, so write it with a low --threshold (e.g.
                0.001) to keep free voxels, or with the default to keep the occupied ones only
                (free and unknown cells both have value 0). Needs --resolution.
  .bt / .ot     an OctoMap file (needs the OctoMap layer); its resolution is used.
  TILE_DIR      a disk-backend map directory; its resolution is used, tiles are read in turn.

options:
  -o, --output DIR    output directory (created when missing)
  --levels N          number of levels, widths 1, 2, ..., 2^(N-1) (default 7, at most 16)
  --resolution M      voxel edge of a .pcd/.ply voxel cloud in metres
  --slice Z           the horizontal slice of voxels at height Z metres
  --column            the maximum of every vertical column of the map (the default)
  --z-min Z, --z-max Z  limit the columns to this height range (metres)
  -q, --quiet         no summary
)";

// ---- a minimal PNG writer: 8-bit grey, deflate with the fixed Huffman code and run-length
// matches (distance 1) only. Grid images are long runs of one grey, which this alone shrinks
// 10-50x; it needs no image or compression library, so the command works in every build.

std::uint32_t crc32(const std::string& bytes, std::size_t begin) {
  static const std::array<std::uint32_t, 256> table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t n = 0; n < 256; ++n) {
      std::uint32_t c = n;
      for (int k = 0; k < 8; ++k) c = (c & 1U) != 0 ? 0xEDB88320U ^ (c >> 1) : c >> 1;
      t[n] = c;
    }
    return t;
  }();
  std::uint32_t c = 0xFFFFFFFFU;
  for (std::size_t i = begin; i < bytes.size(); ++i)
    c = table[(c ^ static_cast<unsigned char>(bytes[i])) & 0xFFU] ^ (c >> 8);
  return c ^ 0xFFFFFFFFU;
}

void put_be32(std::string& out, std::uint32_t v) {
  for (int s = 24; s >= 0; s -= 8) out.push_back(static_cast<char>((v >> s) & 0xFFU));
}

void put_chunk(std::string& png, const char* type, const std::string& data) {
  put_be32(png, static_cast<std::uint32_t>(data.size()));
  const std::size_t start = png.size();
  png.append(type, 4);
  png += data;
  put_be32(png, crc32(png, start));  // over type and data
}

// Deflate's bit order: values LSB first, Huffman codes MSB first (RFC 1951, 3.1.1).
class BitWriter {
 public:
  explicit BitWriter(std::string& out) : out_(out) {}
  void bits(std::uint32_t value, int count) {
    for (int i = 0; i < count; ++i) bit((value >> i) & 1U);
  }
  void code(std::uint32_t code, int length) {
    for (int i = length - 1; i >= 0; --i) bit((code >> i) & 1U);
  }
  void flush() {
    if (used_ > 0) out_.push_back(static_cast<char>(byte_));
    byte_ = 0;
    used_ = 0;
  }

 private:
  void bit(std::uint32_t b) {
    byte_ |= b << used_;
    if (++used_ == 8) flush();
  }
  std::string& out_;
  std::uint32_t byte_ = 0;
  int used_ = 0;
};

// A literal/length symbol in the fixed Huffman code (RFC 1951, 3.2.6).
void fixed_symbol(BitWriter& w, int symbol) {
  if (symbol < 144)
    w.code(static_cast<std::uint32_t>(0x30 + symbol), 8);
  else if (symbol < 256)
    w.code(static_cast<std::uint32_t>(0x190 + symbol - 144), 9);
  else if (symbol < 280)
    w.code(static_cast<std::uint32_t>(symbol - 256), 7);
  else
    w.code(static_cast<std::uint32_t>(0xC0 + symbol - 280), 8);
}

// A match of `length` (3..258) bytes at distance 1: repeat the previous byte.
void run_match(BitWriter& w, int length) {
  static constexpr int kBase[29] = {3,  4,  5,  6,  7,  8,  9,  10, 11,  13,  15,  17,  19,  23, 27,
                                    31, 35, 43, 51, 59, 67, 83, 99, 115, 131, 163, 195, 227, 258};
  static constexpr int kExtra[29] = {0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0};
  int i = 28;
  while (kBase[i] > length) --i;
  fixed_symbol(w, 257 + i);
  w.bits(static_cast<std::uint32_t>(length - kBase[i]), kExtra[i]);
  w.code(0, 5);  // distance code 0: distance 1
}

std::string deflate_runs(const std::string& raw) {
  std::string out;
  BitWriter w(out);
  w.bits(1, 1);  // BFINAL: one block
  w.bits(1, 2);  // BTYPE = 01: fixed Huffman codes
  for (std::size_t i = 0; i < raw.size();) {
    const auto b = static_cast<unsigned char>(raw[i]);
    fixed_symbol(w, b);
    std::size_t run = 0;
    while (i + 1 + run < raw.size() && static_cast<unsigned char>(raw[i + 1 + run]) == b) ++run;
    i += 1 + run;
    while (run >= 3) {
      // Never leave a tail of 1 or 2 that a match cannot take when the run could be split better.
      const int n = static_cast<int>(std::min<std::size_t>(run, 258));
      const int take = (run - static_cast<std::size_t>(n) > 0 && run - static_cast<std::size_t>(n) < 3) ? n - 3 : n;
      run_match(w, take);
      run -= static_cast<std::size_t>(take);
    }
    for (; run > 0; --run) fixed_symbol(w, b);
  }
  fixed_symbol(w, 256);  // end of block
  w.flush();
  return out;
}

// Rows top first, each width bytes.
std::string encode_grey_png(int width, int height, const std::vector<std::uint8_t>& pixels) {
  std::string raw;
  raw.reserve(static_cast<std::size_t>(height) * (static_cast<std::size_t>(width) + 1));
  for (int r = 0; r < height; ++r) {
    raw.push_back('\0');  // filter type 0 (none)
    raw.append(reinterpret_cast<const char*>(pixels.data()) + static_cast<std::size_t>(r) * static_cast<std::size_t>(width),
               static_cast<std::size_t>(width));
  }
  std::string z = {'\x78', '\x01'};  // zlib header: deflate, 32 KiB window, no dictionary
  z += deflate_runs(raw);
  std::uint32_t a = 1, b = 0;  // Adler-32 of the uncompressed data
  for (const char ch : raw) {
    a = (a + static_cast<unsigned char>(ch)) % 65521U;
    b = (b + a) % 65521U;
  }
  put_be32(z, (b << 16) | a);

  std::string png = "\x89PNG\r\n\x1a\n";
  std::string ihdr;
  put_be32(ihdr, static_cast<std::uint32_t>(width));
  put_be32(ihdr, static_cast<std::uint32_t>(height));
  ihdr += std::string{'\x08', '\x00', '\x00', '\x00', '\x00'};  // 8 bits, grey, deflate, no filter set, no interlace
  put_chunk(png, "IHDR", ihdr);
  put_chunk(png, "IDAT", z);
  put_chunk(png, "IEND", std::string());
  return png;
}

// Writes \p bytes to \p file (an OutputFiles temporary).
void write_bytes(const std::string& file, const std::string& bytes) {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) throw std::runtime_error("cannot write '" + file + "': " + std::strerror(errno));
}

// The voxel cloud of `iwlomap map` as a map: each point's voxel gets the log-odds of its
// probability, so that every grid is built through the one IMapperBackend path.
std::unique_ptr<IMapperBackend> load_voxel_cloud(const std::string& path, double resolution) {
  const LoadedCloud in = load_cloud(path, 0.0f);
  if (!in.has_intensity)
    throw std::runtime_error("'" + path + "' has no intensity field: a voxel cloud carries each voxel's probability there");
  const auto& cloud = *in.cloud;
  Eigen::MatrixXd points(static_cast<Eigen::Index>(cloud.size()), 3);
  Eigen::VectorXd log_odds(static_cast<Eigen::Index>(cloud.size()));
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const auto& p = cloud[i];
    const auto row = static_cast<Eigen::Index>(i);
    if (std::isfinite(p.intensity) && (p.intensity < 0.0f || p.intensity > 1.0f))
      throw std::runtime_error("'" + path + "': intensity " + shortest(p.intensity) + " of point " +
                               std::to_string(i) +
                               " is not a probability; the input must be a voxel cloud as 'iwlomap map' writes it "
                               "(map a raw scan first)");
    points.row(row) << p.x, p.y, p.z;
    const double q = std::clamp(static_cast<double>(p.intensity), 1e-6, 1.0 - 1e-6);
    log_odds[row] = std::log(q / (1.0 - q));  // NaN stays NaN: set_log_odds() skips the row
  }
  auto map = std::make_unique<ProbabilityUpdater>(resolution);
  map->set_log_odds(points, log_odds);
  return map;
}

std::unique_ptr<IMapperBackend> load_map(const std::string& path, const Args& args) {
  const std::string ext = extension(path);
  if (is_map_path(path)) {  // a tile directory or an OctoMap file, at its own resolution
    if (args.has("--resolution")) throw UsageError("--resolution is for .pcd/.ply voxel clouds; a stored map has its own");
    return open_map(path);
  }
  if (ext != ".pcd" && ext != ".ply")
    throw UsageError("the input must be .pcd, .ply, .bt, .ot or a tile directory, got '" + path + "'");
  const auto resolution = args.resolution();
  if (!resolution) throw UsageError("a .pcd/.ply voxel cloud needs --resolution (the map's voxel edge)");
  return load_voxel_cloud(path, *resolution);
}

std::string text_dump(const PrecomputationGrid2D& grid) {
  std::ostringstream out;
  const int nx = grid.size().x(), ny = grid.size().y();
  out << ny << " " << nx << "\n";
  for (int j = ny - 1; j >= 0; --j) {
    for (int i = 0; i < nx; ++i) out << std::setw(4) << static_cast<int>(grid.values()[static_cast<std::size_t>(i) + static_cast<std::size_t>(nx) * static_cast<std::size_t>(j)]);
    out << "\n";
  }
  return out.str();
}

std::string png_of(const PrecomputationGrid2D& grid) {
  const int nx = grid.size().x(), ny = grid.size().y();
  std::vector<std::uint8_t> pixels(grid.values().size());
  for (int r = 0; r < ny; ++r) {
    const int j = ny - 1 - r;  // +y up
    for (int i = 0; i < nx; ++i)
      pixels[static_cast<std::size_t>(r) * static_cast<std::size_t>(nx) + static_cast<std::size_t>(i)] =
          static_cast<std::uint8_t>(255 - grid.values()[static_cast<std::size_t>(i) + static_cast<std::size_t>(nx) * static_cast<std::size_t>(j)]);
  }
  return encode_grey_png(nx, ny, pixels);
}

}  // namespace

int run_pyramid(const std::vector<std::string>& argv) {
  const Args args(argv, {"-o", "--output", "--levels", "--resolution", "--slice", "--z-min", "--z-max"},
                  {"-h", "--help", "--column", "-q", "--quiet"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
  if (args.positional().size() != 1) throw UsageError("give exactly one input map");
  const auto output = args.value("-o") ? args.value("-o") : args.value("--output");
  if (!output) throw UsageError("no output directory (-o DIR)");
  const long levels = args.integer("--levels", PrecomputationStack2D::kDefaultLevels);
  if (levels < 1 || levels > PrecomputationStack2D::kMaxLevels)
    throw UsageError("--levels must be in [1, " + std::to_string(PrecomputationStack2D::kMaxLevels) + "], got " +
                     std::to_string(levels));
  const auto slice = args.number("--slice");
  if (slice && args.flag("--column")) throw UsageError("--slice and --column exclude each other");
  if (slice && (args.has("--z-min") || args.has("--z-max"))) throw UsageError("--z-min/--z-max are for --column");
  const bool quiet = args.flag("-q") || args.flag("--quiet");

  const std::string& input = args.positional()[0];
  // The level files are checked before any work and appear together at the end (OutputFiles): a
  // run that fails or is interrupted leaves none of them, and removes the folder if it made it.
  namespace fs = std::filesystem;
  OutputFiles files(args);
  files.make_folder(*output);
  std::vector<std::string> level_files;
  for (long k = 0; k < levels; ++k)
    for (const char* ext : {".png", ".txt"}) {
      level_files.push_back((fs::path(*output) / ("level_" + std::to_string(k) + ext)).string());
      files.add("-o", level_files.back(), {".png", ".txt"});
    }
  const auto started = std::chrono::steady_clock::now();
  const std::unique_ptr<IMapperBackend> map = load_map(input, args);
  const double r = map->get_resolution();
  const auto known = known_voxel_box(*map);
  if (!known) throw std::runtime_error("'" + input + "' holds no voxel");
  VoxelBox box = *known;
  const auto z_key = [r](double z) { return world_to_key_checked(Eigen::Vector3d(0.0, 0.0, z), r).z; };
  if (const auto z = args.number("--z-min")) box.min.z = std::max(box.min.z, z_key(*z));
  if (const auto z = args.number("--z-max")) box.max.z = std::min(box.max.z, z_key(*z));
  if (box.min.z > box.max.z) throw UsageError("--z-min/--z-max leave no voxel of the map");
  const DiscreteGrid2D base = slice ? discretize_slice(*map, box, *slice) : discretize_column_max(*map, box);
  // Level k holds (X + 2^k - 1) x (Y + 2^k - 1) one-byte cells, and is written through a PNG and a
  // text dump of up to 5 bytes a cell: refused before building when that passes the memory budget.
  double stack_bytes = 0.0, level_bytes = 0.0;
  for (long k = 0; k < levels; ++k) {
    const double grow = std::ldexp(1.0, static_cast<int>(k)) - 1.0;
    const double cells = (base.size().x() + grow) * (base.size().y() + grow);
    stack_bytes += 2.0 * cells;  // the level and the buffer that builds it
    level_bytes = std::max(level_bytes, 6.0 * cells);
  }
  if (const std::string beyond = beyond_memory_budget(stack_bytes + level_bytes); !beyond.empty())
    throw std::runtime_error(std::to_string(levels) + " levels over a " + std::to_string(base.size().x()) + " x " +
                             std::to_string(base.size().y()) + " base grid need " + beyond + "; give fewer --levels");
  const PrecomputationStack2D stack(base, static_cast<int>(levels));

  for (int k = 0; k < stack.num_levels(); ++k) {
    const auto at = static_cast<std::size_t>(2 * k);
    files.write(level_files[at], [&](const std::string& file) { write_bytes(file, png_of(stack.level(k))); });
    files.write(level_files[at + 1], [&](const std::string& file) { write_bytes(file, text_dump(stack.level(k))); });
  }
  files.commit();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  if (!quiet) {
    const GridFrame& f = stack.frame();
    std::cout << input << ": " << map->get_num_known_voxels() << " known voxels at " << r << " m; "
              << (slice ? "slice at z = " + shortest(*slice) + " m" : std::string("column maximum"))
              << "; base grid " << base.size().x() << " x " << base.size().y() << " cells, cell (0, 0) = voxel ("
              << f.origin.x << ", " << f.origin.y << "), x from " << f.origin.x * r << " m, y from " << f.origin.y * r
              << " m\n";
    for (int k = 0; k < stack.num_levels(); ++k)
      std::cout << "  level " << k << ": width " << stack.width(k) << ", " << stack.level(k).size().x() << " x "
                << stack.level(k).size().y() << " cells\n";
    std::cout << "wrote " << stack.num_levels() << " levels to " << *output << " in " << seconds << " s\n";
  }
  return 0;
}

}  // namespace iwlomap::tool
