// SPDX-License-Identifier: BSD-3-Clause
// The OctoMap backend and OctoMap file interop. This is the only file of iwlomap that includes
// OctoMap headers.
#include "iwlomap/octree_mapper.h"

#include "integrate/absolute_log_odds.h"
#include "integrate/batch_input.h"
#include "integrate/voxel_update.h"
#include "storage/block_grid.h"
#include "storage/free_memory.h"
#include "storage/grid_reads.h"
#include "integrate/scan_scratch.h"

#include <octomap/AbstractOcTree.h>
#include <octomap/OcTree.h>
#include <octomap/OcTreeKey.h>

#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <system_error>
#include <fstream>
#include <iostream>
#include <limits>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap {

namespace {

// ---- keys ----------------------------------------------------------------------------------

// OctoMap's 16-level tree: key = floor(coordinate / resolution) + 32768, in 0..65535.
constexpr std::int32_t kKeyOffset = 32768;
constexpr std::int32_t kMinKey = -kKeyOffset;
constexpr std::int32_t kMaxKey = kKeyOffset - 1;
constexpr unsigned kTreeDepth = 16;
// Range of block keys (8^3 voxels) whose voxels all lie inside the key range; the range is
// block-aligned, so a block is either wholly inside or wholly outside.
constexpr std::int32_t kMinBlock = kMinKey >> detail::kBlockShift;
constexpr std::int32_t kMaxBlock = kMaxKey >> detail::kBlockShift;

bool in_octomap_range(const VoxelKey& k) noexcept {
  return k.x >= kMinKey && k.x <= kMaxKey && k.y >= kMinKey && k.y <= kMaxKey && k.z >= kMinKey && k.z <= kMaxKey;
}
bool block_in_octomap_range(const VoxelKey& b) noexcept {
  return b.x >= kMinBlock && b.x <= kMaxBlock && b.y >= kMinBlock && b.y <= kMaxBlock && b.z >= kMinBlock &&
         b.z <= kMaxBlock;
}
octomap::OcTreeKey to_octomap(const VoxelKey& k) noexcept {
  return octomap::OcTreeKey(static_cast<octomap::key_type>(k.x + kKeyOffset),
                            static_cast<octomap::key_type>(k.y + kKeyOffset),
                            static_cast<octomap::key_type>(k.z + kKeyOffset));
}
VoxelKey from_octomap(const octomap::OcTreeKey& k) noexcept {
  return {static_cast<std::int32_t>(k[0]) - kKeyOffset, static_cast<std::int32_t>(k[1]) - kKeyOffset,
          static_cast<std::int32_t>(k[2]) - kKeyOffset};
}

std::string describe_key(const VoxelKey& k) {
  return "(" + std::to_string(k.x) + ", " + std::to_string(k.y) + ", " + std::to_string(k.z) + ")";
}
std::string describe_point(const Eigen::Vector3d& p) {
  std::ostringstream s;
  s.precision(17);
  s << "(" << p.x() << ", " << p.y() << ", " << p.z() << ")";
  return s.str();
}

// \p what names the offending input, e.g. "point 3 (x, y, z)".
[[noreturn]] void throw_outside_octomap(const std::string& what, const VoxelKey& key, double resolution) {
  std::ostringstream s;
  s << "iwlomap: OctoMap backend: " << what << " falls in voxel " << describe_key(key)
    << ", outside OctoMap's key range [" << kMinKey << ", " << kMaxKey << "] per axis (+-"
    << static_cast<double>(kKeyOffset) * resolution << " m at resolution " << resolution
    << " m); nothing was changed";
  throw std::out_of_range(s.str());
}

// The first row of \p points that falls in \p key, described for an error message (the error
// path only: a batch keeps no row numbers).
std::string describe_row_in(const Eigen::MatrixXd& points, const VoxelKey& key, double resolution) {
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    if (is_representable(p, resolution) && world_to_key(p, resolution) == key)
      return "point " + std::to_string(i) + " " + describe_point(p);
  }
  return "a point";
}

// Writes \p value into the leaf of \p key, creating the path to it. setNodeValue() clamps to the
// tree's clamping thresholds, which belong to OctoMap's own model; the mirror must hold the IWLO
// value itself, so the leaf is set again unclamped. lazy_eval: inner nodes are refreshed once
// before the tree is read (updateInnerOccupancy()), not on every write.
void set_leaf(octomap::OcTree& tree, const VoxelKey& key, float value) {
  octomap::OcTreeNode* leaf = tree.setNodeValue(to_octomap(key), value, /*lazy_eval=*/true);
  leaf->setLogOdds(value);
}

// ---- console -------------------------------------------------------------------------------

// OctoMap reports progress and errors on stdout/stderr (Debian's build prints its debug lines
// too), from the shared library where no macro can reach them. While OctoMap reads or writes a
// file, both descriptors point to a temporary file; what OctoMap said is then available for an
// exception message. One capture at a time in the process (the descriptors are global).
class ConsoleCapture {
 public:
  ConsoleCapture() : lock_(mutex()) {
    flush_all();
    sink_ = std::tmpfile();
    if (sink_ == nullptr) return;  // nowhere to capture: OctoMap's messages stay visible
    saved_out_ = ::dup(STDOUT_FILENO);
    saved_err_ = ::dup(STDERR_FILENO);
    ::dup2(::fileno(sink_), STDOUT_FILENO);
    ::dup2(::fileno(sink_), STDERR_FILENO);
    redirected_ = true;
  }
  ~ConsoleCapture() {
    restore();
    if (sink_ != nullptr) std::fclose(sink_);
  }
  ConsoleCapture(const ConsoleCapture&) = delete;
  ConsoleCapture& operator=(const ConsoleCapture&) = delete;

  /// Restores the console and returns what was printed meanwhile, as one line (may be empty).
  std::string finish() {
    restore();
    if (sink_ == nullptr) return {};
    std::string text(2048, '\0');
    std::rewind(sink_);
    text.resize(std::fread(text.data(), 1, text.size(), sink_));
    for (char& c : text)
      if (c == '\n' || c == '\r') c = ' ';
    const auto first = text.find_first_not_of(' ');
    if (first == std::string::npos) return {};
    const auto last = text.find_last_not_of(' ');
    return text.substr(first, last - first + 1);
  }

 private:
  static std::mutex& mutex() {
    static std::mutex m;
    return m;
  }
  static void flush_all() {
    std::cout.flush();
    std::cerr.flush();
    std::clog.flush();
    std::fflush(stdout);
    std::fflush(stderr);
  }
  static void put_back(int saved, int fd) {
    if (saved >= 0) {
      ::dup2(saved, fd);
      ::close(saved);
    } else {
      ::close(fd);  // the descriptor was closed before the capture: close it again
    }
  }
  void restore() {
    if (!redirected_) return;
    flush_all();
    put_back(saved_out_, STDOUT_FILENO);
    put_back(saved_err_, STDERR_FILENO);
    redirected_ = false;
  }

  std::lock_guard<std::mutex> lock_;
  std::FILE* sink_ = nullptr;
  int saved_out_ = -1;
  int saved_err_ = -1;
  bool redirected_ = false;
};

std::string octomap_said(const std::string& text) { return text.empty() ? std::string() : " (OctoMap: " + text + ")"; }

// ---- files ---------------------------------------------------------------------------------

enum class FileFormat { kBinary, kFull };  // .bt, .ot

const char* const kFullHeader = "# Octomap OcTree file";
const char* const kBinaryHeader = "# Octomap OcTree binary file";

FileFormat format_of(const std::string& path, const char* caller) {
  const std::string ext = std::filesystem::path(path).extension().string();
  std::string lower = ext;
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (lower == ".bt") return FileFormat::kBinary;
  if (lower == ".ot") return FileFormat::kFull;
  throw std::invalid_argument(std::string("iwlomap: ") + caller + ": '" + path + "' has extension '" + ext +
                              "'; OctoMap files end in .bt (binary occupancy) or .ot (full log-odds)");
}

struct FileHeader {
  std::string id;
  std::uint64_t size = 0;  // octree nodes
  double resolution = 0.0;
};

[[noreturn]] void throw_bad_file(const std::string& path, FileFormat f, const std::string& why) {
  throw std::runtime_error("iwlomap: '" + path + "' is not a valid OctoMap " +
                           (f == FileFormat::kBinary ? ".bt" : ".ot") + " file: " + why);
}

void skip_line(std::istream& s) {
  s.ignore(std::numeric_limits<std::streamsize>::max(), '\n');
}

// The header as OctoMap's readers accept it: a first line that names the format, then keyword
// lines (id, size, res; '#' comments and unknown keywords skipped) up to the line "data".
FileHeader read_header(std::istream& s, FileFormat f, const std::string& path) {
  const std::string expected = f == FileFormat::kBinary ? kBinaryHeader : kFullHeader;
  std::string line;
  std::getline(s, line);
  if (line.compare(0, expected.size(), expected) != 0) {
    // Neither header is a prefix of the other, so this tells a swapped extension apart.
    const std::string other = f == FileFormat::kBinary ? kFullHeader : kBinaryHeader;
    const bool swapped = line.compare(0, other.size(), other) == 0;
    throw_bad_file(path, f,
                   swapped ? "its header says it is the other OctoMap format (check the extension)"
                           : "its first line does not start with \"" + expected + "\"");
  }
  FileHeader h;
  bool have_res = false, have_size = false;
  std::string token;
  while (s >> token) {
    if (token == "data") {
      skip_line(s);
      if (h.id.empty()) throw_bad_file(path, f, "the header has no 'id'");
      if (!have_size) throw_bad_file(path, f, "the header has no 'size'");
      if (!have_res || !std::isfinite(h.resolution) || h.resolution <= 0.0)
        throw_bad_file(path, f, "the header has no valid 'res' (resolution > 0)");
      return h;
    }
    if (token[0] == '#') {
      skip_line(s);
    } else if (token == "id") {
      s >> h.id;
    } else if (token == "size") {
      have_size = static_cast<bool>(s >> h.size);
    } else if (token == "res") {
      have_res = static_cast<bool>(s >> h.resolution);
    } else {
      skip_line(s);  // OctoMap skips unknown keywords too
    }
    if (!s) break;
  }
  throw_bad_file(path, f, "the header is incomplete (no 'data' line)");
}

// Walks the node data after the header without building anything, so that OctoMap's readers,
// which trust their input (a truncated or corrupt file makes them read uninitialised bytes and
// recurse without bound), only ever see a well-formed tree.
class DataChecker {
 public:
  DataChecker(std::istream& s, FileFormat f, const FileHeader& h, const std::string& path)
      : buf_(*s.rdbuf()), format_(f), header_(h), path_(path) {}

  /// Returns the number of voxels the tree's leaves cover (pruned leaves expanded).
  std::uint64_t run() {
    if (header_.size == 0) return 0;
    if (format_ == FileFormat::kFull)
      full_node(0);
    else
      binary_node(0);
    if (nodes_ != header_.size)
      fail("the header announces " + std::to_string(header_.size) + " nodes but the data holds " +
           std::to_string(nodes_));
    return voxels_;
  }

 private:
  [[noreturn]] void fail(const std::string& why) const { throw_bad_file(path_, format_, why); }

  unsigned char byte() {
    const auto c = buf_.sbumpc();
    if (c == std::char_traits<char>::eof())
      fail("the data ends early, inside node " + std::to_string(nodes_) + " of " + std::to_string(header_.size));
    return static_cast<unsigned char>(c);
  }

  void count_node() {
    if (++nodes_ > header_.size)
      fail("the data holds more nodes than the " + std::to_string(header_.size) + " its header announces");
  }

  void add_leaf(unsigned depth) {
    const unsigned level = kTreeDepth - depth;
    voxels_ += std::uint64_t{1} << (3 * level);
  }

  // .ot: per node a float log-odds and a byte with one bit per existing child, depth first.
  void full_node(unsigned depth) {
    count_node();
    float value;
    unsigned char raw[sizeof(float)];
    for (unsigned char& b : raw) b = byte();
    std::memcpy(&value, raw, sizeof(value));
    if (!std::isfinite(value)) fail("node " + std::to_string(nodes_ - 1) + " holds a non-finite log-odds");
    const unsigned char children = byte();
    if (children == 0) {
      add_leaf(depth);
      return;
    }
    if (depth == kTreeDepth) fail("a node at the deepest level (16) claims children");
    for (int i = 0; i < 8; ++i)
      if ((children >> i) & 1) full_node(depth + 1);
  }

  // .bt: per inner node two bytes with two bits per child (01 occupied leaf, 10 free leaf,
  // 11 inner node, 00 none), then the inner children depth first.
  void binary_node(unsigned depth) {
    if (depth == 0) count_node();  // the root; other nodes are counted by their parent
    const unsigned char bytes[2] = {byte(), byte()};
    bool inner[8] = {};
    bool any = false;
    for (int i = 0; i < 8; ++i) {
      const unsigned bits = (bytes[i / 4] >> (2 * (i % 4))) & 3u;
      if (bits == 0) continue;
      any = true;
      count_node();
      if (bits == 3) {
        if (depth + 1 >= kTreeDepth) fail("a node at the deepest level (16) claims children");
        inner[i] = true;
      } else {
        add_leaf(depth + 1);
      }
    }
    if (!any) {
      if (depth == 0) {  // a tree that is a single root leaf: OctoMap reads it as occupied
        add_leaf(0);
        return;
      }
      fail("an inner node has no children");
    }
    for (int i = 0; i < 8; ++i)
      if (inner[i]) binary_node(depth + 1);
  }

  std::streambuf& buf_;
  FileFormat format_;
  const FileHeader& header_;
  const std::string& path_;
  std::uint64_t nodes_ = 0;
  std::uint64_t voxels_ = 0;
};

// Imports expand pruned leaves voxel by voxel; a (corrupt or absurd) file whose leaves cover
// more voxels than this is refused rather than exhausting memory.
constexpr std::uint64_t kMaxImportVoxels = std::uint64_t{1} << 30;

struct LoadedTree {
  FileFormat format;
  double resolution;
  std::unique_ptr<octomap::OcTree> tree;
};

// Reads and fully checks an OctoMap file. \p clamping holds the clamping thresholds (min, max
// probability) of the reading tree, which are the log-odds of .bt leaves; nullptr keeps those of
// a fresh OcTree, as OctoMap's own tools read the file.
LoadedTree read_octomap_file(const std::string& path, const char* caller,
                             const std::pair<double, double>* clamping) {
  const FileFormat f = format_of(path, caller);
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (!std::filesystem::exists(status)) {
    if (ec && ec != std::errc::no_such_file_or_directory)
      throw std::runtime_error(std::string("iwlomap: ") + caller + ": cannot access OctoMap file '" + path +
                               "': " + ec.message());
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": OctoMap file '" + path + "' does not exist");
  }
  if (std::filesystem::is_directory(status))
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": '" + path + "' is a directory, not an OctoMap file");
  std::ifstream in(path, std::ios::binary);
  if (!in)
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": cannot open OctoMap file '" + path +
                             "': " + std::strerror(errno));

  const FileHeader h = read_header(in, f, path);
  if (f == FileFormat::kFull && h.id != "OcTree" && h.id != "1")  // "1" is OctoMap's legacy id of OcTree
    throw_bad_file(path, f, "it holds an octree of type '" + h.id + "'; only 'OcTree' files can be read");
  const std::uint64_t voxels = DataChecker(in, f, h, path).run();
  if (voxels > kMaxImportVoxels)
    throw std::runtime_error("iwlomap: " + std::string(caller) + ": '" + path + "' expands to " +
                             std::to_string(voxels) + " voxels, more than the import limit of " +
                             std::to_string(kMaxImportVoxels));

  LoadedTree loaded{f, h.resolution, std::make_unique<octomap::OcTree>(h.resolution)};
  if (clamping != nullptr) {
    loaded.tree->setClampingThresMin(clamping->first);
    loaded.tree->setClampingThresMax(clamping->second);
  }
  if (h.size == 0) return loaded;  // OctoMap's .ot reader would read past the end of an empty tree

  in.clear();
  in.seekg(0);
  bool ok = false;
  std::string said;
  {
    ConsoleCapture capture;
    if (f == FileFormat::kBinary) {
      ok = loaded.tree->readBinary(in);
    } else {
      std::unique_ptr<octomap::AbstractOcTree> any(octomap::AbstractOcTree::read(in));
      if (auto* t = dynamic_cast<octomap::OcTree*>(any.get())) {
        any.release();
        loaded.tree.reset(t);
        ok = true;
      }
    }
    said = capture.finish();
  }
  if (!ok || loaded.tree->size() != h.size)
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": OctoMap could not read '" + path + "'" +
                             octomap_said(said));
  return loaded;
}

// Calls visit(key, log_odds) for every voxel of \p tree, expanding pruned leaves.
template <class Visit>
void for_each_tree_voxel(const octomap::OcTree& tree, Visit&& visit) {
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const float value = it->getLogOdds();
    const VoxelKey lo = from_octomap(it.getIndexKey());
    const std::int32_t side = std::int32_t{1} << (kTreeDepth - it.getDepth());
    for (std::int32_t dz = 0; dz < side; ++dz)
      for (std::int32_t dy = 0; dy < side; ++dy)
        for (std::int32_t dx = 0; dx < side; ++dx) visit(VoxelKey{lo.x + dx, lo.y + dy, lo.z + dz}, value);
  }
}

// Feeds every voxel of \p tree to map.set_log_odds() in batches, at the voxel centres of the
// map's own resolution (the keys are what matter; the resolutions agree to OctoMap's precision).
void set_tree_voxels(const octomap::OcTree& tree, IMapperBackend& map) {
  constexpr Eigen::Index kBatch = 1 << 16;
  const double r = map.get_resolution();
  Eigen::MatrixXd points(kBatch, 3);
  Eigen::VectorXd values(kBatch);
  Eigen::Index n = 0;
  const auto flush = [&]() {
    if (n == 0) return;
    if (n == kBatch) {
      map.set_log_odds(points, values);
    } else {
      map.set_log_odds(points.topRows(n), values.head(n));
    }
    n = 0;
  };
  for_each_tree_voxel(tree, [&](const VoxelKey& k, float value) {
    points.row(n) = key_to_center(k, r).transpose();
    values[n] = static_cast<double>(value);
    if (++n == kBatch) flush();
  });
  flush();
}

// Writes \p tree to a temporary file next to \p path and renames it over \p path.
void write_tree(const octomap::OcTree& tree, FileFormat f, const std::string& path, const char* caller) {
  const std::string tmp = path + ".part";
  std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
  if (!out)
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": cannot write OctoMap file '" + path +
                             "': cannot create '" + tmp + "': " + std::strerror(errno));
  bool ok;
  std::string said;
  {
    ConsoleCapture capture;
    ok = f == FileFormat::kBinary ? tree.writeBinaryConst(out) : tree.write(out);
    out.flush();
    said = capture.finish();
  }
  out.close();
  if (!ok || !out) {
    const int err = errno;
    std::remove(tmp.c_str());
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": writing OctoMap file '" + path + "' failed: " +
                             std::strerror(err) + octomap_said(said));
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int err = errno;
    std::remove(tmp.c_str());
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": cannot move '" + tmp + "' to '" + path +
                             "': " + std::strerror(err));
  }
}

void check_probability(const char* name, double value, double lo, double hi) {
  if (!(value > lo && value < hi))
    throw std::invalid_argument("iwlomap: OctreeMapper: " + detail::describe(name, value) + " must be in (" +
                                std::to_string(lo) + ", " + std::to_string(hi) + ")");
}
void check_model(double prob_hit, double prob_miss, double thres_min, double thres_max) {
  check_probability("prob_hit", prob_hit, 0.5, 1.0);
  check_probability("prob_miss", prob_miss, 0.0, 0.5);
  check_probability("prob_thres_min", thres_min, 0.0, 1.0);
  check_probability("prob_thres_max", thres_max, thres_min, 1.0);
}

}  // namespace

// ---- OctreeMapper --------------------------------------------------------------------------

struct OctreeMapper::Impl {
  Impl(double res, double hit, double miss, double thres_min, double thres_max) : resolution(res), tree(res) {
    set_model(hit, miss, thres_min, thres_max);
  }

  void set_model(double hit, double miss, double thres_min, double thres_max) {
    tree.setProbHit(hit);
    tree.setProbMiss(miss);
    tree.setClampingThresMin(thres_min);
    tree.setClampingThresMax(thres_max);
    prob_hit = hit;
    prob_miss = miss;
    prob_thres_min = thres_min;
    prob_thres_max = thres_max;
  }

  // Every change of the octree goes through here or set_leaf(): the cached figures and the inner
  // nodes are stale afterwards.
  void tree_changed() {
    std::lock_guard<std::mutex> lock(tree_mutex);
    inner_stale = true;
    stats_valid = false;
  }

  // One IWLO observation of voxel \p index of block \p b (key \p key), mirrored into the octree
  // when the value changed or the voxel is new.
  void observe(detail::VoxelBlock& b, int index, const VoxelKey& key, double intensity, bool occupied_flag,
               double weight) {
    detail::Voxel& v = grid.voxel(b, index);
    const float before = v.log_odds;
    const bool was_unknown = detail::observe_voxel(b, v, intensity, occupied_flag, weight, updater);
    if (was_unknown) ++known;
    if (was_unknown || v.log_odds != before) set_leaf(tree, key, v.log_odds);
  }

  // One observation of OctoMap's own model: the octree computes it, the exact state copies it.
  void observe_octomap(detail::BlockAccessor& acc, const VoxelKey& key, bool occupied) {
    const octomap::OcTreeNode* node = tree.updateNode(to_octomap(key), occupied, /*lazy_eval=*/true);
    detail::VoxelBlock* b = nullptr;
    detail::Voxel& v = acc.voxel(key, b);
    if (v.count == 0) {
      ++b->known;
      ++known;
    }
    v.count = static_cast<std::uint16_t>(iwlo::increment_count(v.count));
    v.log_odds = node->getLogOdds();
  }

  void apply_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                   const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights) {
    const std::size_t skip = detail::prepare_batch(points, intensities, is_occupied, weights, resolution, batch);
    for (const detail::Observation& o : batch)
      if (!in_octomap_range(o.key)) throw_outside_octomap(describe_row_in(points, o.key, resolution), o.key, resolution);
    const detail::BatchValues in{intensities, is_occupied, weights};
    detail::BlockAccessor acc(grid);
    for (const detail::Observation& o : batch)
      observe(acc.block(detail::block_of(o.key)), detail::index_in_block(o.key), o.key, in.intensity(o.row),
              in.occupied_flag(o.row), in.weight(o.row));
    skipped += skip;
    if (!batch.empty()) tree_changed();
  }

  // Call with tree_mutex held. Inner nodes are derived from the leaves, so refreshing them is
  // allowed from const methods.
  void refresh_inner_locked() const {
    if (inner_stale) {
      const_cast<octomap::OcTree&>(tree).updateInnerOccupancy();
      inner_stale = false;
    }
  }

  double resolution;
  detail::Updater updater;
  detail::BlockGrid grid;  // the exact state, as in the RAM backend
  detail::ScanScratch scratch;
  std::vector<detail::Observation> batch;  // reused between batches
  octomap::OcTree tree;                    // leaves mirror the exact log-odds
  std::unique_ptr<octomap::KeyRay> ray;    // insert_ray()'s buffer (OctoMap preallocates 100,000 keys)
  double prob_hit = 0.7, prob_miss = 0.3, prob_thres_min = 0.12, prob_thres_max = 0.97;
  std::size_t known = 0;
  std::size_t skipped = 0;

  // The octree's inner nodes and figures are derived data, refreshed on demand by const methods;
  // the mutex keeps concurrent const calls safe.
  mutable std::mutex tree_mutex;
  mutable bool inner_stale = false;
  mutable bool stats_valid = false;
  mutable std::size_t stat_nodes = 0, stat_leaves = 0, stat_bytes = 0;
};

OctreeMapper::OctreeMapper(double resolution, double prob_hit, double prob_miss, double prob_thres_min,
                           double prob_thres_max) {
  detail::check_resolution(resolution);
  check_model(prob_hit, prob_miss, prob_thres_min, prob_thres_max);
  impl_ = std::make_unique<Impl>(resolution, prob_hit, prob_miss, prob_thres_min, prob_thres_max);
}
OctreeMapper::~OctreeMapper() = default;
OctreeMapper::OctreeMapper(OctreeMapper&&) noexcept = default;
OctreeMapper& OctreeMapper::operator=(OctreeMapper&&) noexcept = default;

OctreeMapper::Impl& OctreeMapper::impl() {
  if (!impl_) throw std::logic_error("iwlomap: OctreeMapper used after it was moved from");
  return *impl_;
}
const OctreeMapper::Impl& OctreeMapper::impl() const {
  if (!impl_) throw std::logic_error("iwlomap: OctreeMapper used after it was moved from");
  return *impl_;
}

// ---- OctoMap's own model ----

void OctreeMapper::update_point(const Eigen::Vector3d& point, bool occupied) {
  Impl& m = impl();
  if (!point.allFinite()) {
    ++m.skipped;
    return;
  }
  const VoxelKey key = world_to_key_checked(point, m.resolution);
  if (!in_octomap_range(key)) throw_outside_octomap("the point " + describe_point(point), key, m.resolution);
  detail::BlockAccessor acc(m.grid);
  m.observe_octomap(acc, key, occupied);
  m.tree_changed();
}

void OctreeMapper::batch_update(const Eigen::MatrixXd& points, const std::vector<bool>& occupied_flags) {
  Impl& m = impl();
  if (points.rows() > 0 && points.cols() != 3)
    throw std::invalid_argument("iwlomap: points must be N x 3, got " + std::to_string(points.rows()) + " x " +
                                std::to_string(points.cols()));
  if (static_cast<Eigen::Index>(occupied_flags.size()) != points.rows())
    throw std::invalid_argument("iwlomap: occupied_flags has " + std::to_string(occupied_flags.size()) +
                                " entries but points has " + std::to_string(points.rows()) + " rows");
  std::vector<std::pair<VoxelKey, bool>> updates;
  updates.reserve(static_cast<std::size_t>(points.rows()));
  std::size_t skip = 0;
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    if (!p.allFinite()) {
      ++skip;
      continue;
    }
    if (!is_representable(p, m.resolution)) detail::throw_out_of_range(i, p, m.resolution);
    const VoxelKey key = world_to_key(p, m.resolution);
    if (!in_octomap_range(key))
      throw_outside_octomap("point " + std::to_string(i) + " " + describe_point(p), key, m.resolution);
    updates.emplace_back(key, static_cast<bool>(occupied_flags[static_cast<std::size_t>(i)]));
  }
  detail::BlockAccessor acc(m.grid);
  for (const auto& [key, occupied] : updates) m.observe_octomap(acc, key, occupied);
  m.skipped += skip;
  if (!updates.empty()) m.tree_changed();
}

void OctreeMapper::batch_update_with_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) {
  set_log_odds(points, log_odds);
}

void OctreeMapper::insert_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& endpoint, double max_range) {
  Impl& m = impl();
  if (!origin.allFinite() || !endpoint.allFinite())
    throw std::invalid_argument("iwlomap: insert_ray needs a finite origin and endpoint, got " +
                                describe_point(origin) + " -> " + describe_point(endpoint));
  if (std::isnan(max_range))
    throw std::invalid_argument("iwlomap: max_range must not be NaN (use a value <= 0 for no limit)");
  // OctoMap's insertRay() in its own float arithmetic, so the voxels are exactly OctoMap's.
  const octomap::point3d o(static_cast<float>(origin.x()), static_cast<float>(origin.y()),
                           static_cast<float>(origin.z()));
  octomap::point3d e(static_cast<float>(endpoint.x()), static_cast<float>(endpoint.y()),
                     static_cast<float>(endpoint.z()));
  const bool clipped = max_range > 0.0 && (e - o).norm() > max_range;
  if (clipped) e = o + (e - o).normalized() * static_cast<float>(max_range);
  // OctoMap converts with an unchecked int cast first: keep coordinates far from overflow before
  // asking it whether they are inside its range.
  const auto inside = [&m](const octomap::point3d& p, octomap::OcTreeKey& k) {
    const double limit = 2.0 * kKeyOffset * m.resolution;
    for (unsigned i = 0; i < 3; ++i)
      if (!(std::abs(static_cast<double>(p(i))) < limit)) return false;
    return m.tree.coordToKeyChecked(p, k);
  };
  octomap::OcTreeKey ko, ke;
  const bool origin_inside = inside(o, ko);
  if (!origin_inside || !inside(e, ke)) {
    const Eigen::Vector3d bad = origin_inside ? Eigen::Vector3d(e.x(), e.y(), e.z()) : origin;
    throw_outside_octomap(std::string(origin_inside ? "the ray end " : "the ray origin ") + describe_point(bad),
                          world_to_key(bad, m.resolution), m.resolution);
  }
  if (!m.ray) m.ray = std::make_unique<octomap::KeyRay>();
  m.tree.computeRayKeys(o, e, *m.ray);  // both ends are inside, so it succeeds
  detail::BlockAccessor acc(m.grid);
  for (const octomap::OcTreeKey& k : *m.ray) m.observe_octomap(acc, from_octomap(k), false);
  if (!clipped) m.observe_octomap(acc, from_octomap(ke), true);
  m.tree_changed();
}

void OctreeMapper::set_probability_params(double prob_hit, double prob_miss) {
  Impl& m = impl();
  check_model(prob_hit, prob_miss, m.prob_thres_min, m.prob_thres_max);
  m.set_model(prob_hit, prob_miss, m.prob_thres_min, m.prob_thres_max);
}
void OctreeMapper::set_occupancy_thresholds(double prob_thres_min, double prob_thres_max) {
  Impl& m = impl();
  check_model(m.prob_hit, m.prob_miss, prob_thres_min, prob_thres_max);
  m.set_model(m.prob_hit, m.prob_miss, prob_thres_min, prob_thres_max);
}
double OctreeMapper::get_prob_hit() const { return impl().prob_hit; }
double OctreeMapper::get_prob_miss() const { return impl().prob_miss; }
double OctreeMapper::get_prob_thres_min() const { return impl().prob_thres_min; }
double OctreeMapper::get_prob_thres_max() const { return impl().prob_thres_max; }

size_t OctreeMapper::prune_tree() {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.tree_mutex);
  m.refresh_inner_locked();  // pruning compares children and sets the parent's value
  const std::size_t before = m.tree.size();
  m.tree.prune();
  m.stats_valid = false;
  return before - m.tree.size();
}

void OctreeMapper::save_to_file(const std::string& path) const {
  const Impl& m = impl();
  if (format_of(path, "save_to_file") == FileFormat::kBinary) {
    export_octomap(*this, path);
    return;
  }
  // .ot: the octree itself, whose leaves are the exact log-odds.
  std::lock_guard<std::mutex> lock(m.tree_mutex);
  m.refresh_inner_locked();
  write_tree(m.tree, FileFormat::kFull, path, "save_to_file");
}

void OctreeMapper::load_from_file(const std::string& path) {
  Impl& m = impl();
  const std::pair<double, double> clamping(m.prob_thres_min, m.prob_thres_max);
  const LoadedTree loaded = read_octomap_file(path, "load_from_file", &clamping);
  clear();
  m.resolution = loaded.resolution;
  m.tree.setResolution(loaded.resolution);
  set_tree_voxels(*loaded.tree, *this);
}

// ---- IMapperBackend ----

void OctreeMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                     const std::vector<bool>& is_occupied) {
  impl().apply_batch(points, intensities, is_occupied, nullptr);
}

void OctreeMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                     const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) {
  impl().apply_batch(points, intensities, is_occupied, &weights);
}

void OctreeMapper::insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                               const Eigen::VectorXd& intensities, double max_range) {
  Impl& m = impl();
  detail::check_scan_input(origin, points, intensities, max_range, m.resolution);
  // Rays may be cast on several threads (bit-identical); the octree is then updated on this one.
  const std::size_t skip =
      m.scratch.collect(origin, points, intensities, max_range, m.resolution, get_num_threads());
  // Every voxel the scan would update must have an OctoMap key; checked before anything changes.
  m.scratch.for_each_observation(
      [&](const VoxelKey& block_key, int index) {
        if (!block_in_octomap_range(block_key))
          throw_outside_octomap("a ray of the scan from " + describe_point(origin), detail::voxel_of(block_key, index),
                                m.resolution);
      },
      [&](const VoxelKey& key, double) {
        if (!in_octomap_range(key)) throw_outside_octomap("a point of the scan", key, m.resolution);
      });
  detail::BlockAccessor acc(m.grid);
  // Blocks and cells first, in the scratch's order, as the RAM backend does: the same layout, so
  // the two list voxels in the same order, and one allocation per block instead of one per cell.
  m.scratch.for_each_block(
      [&](const VoxelKey& block_key, const detail::CellMask& cells) { m.grid.ensure_cells(acc.block(block_key), cells); });
  m.scratch.for_each_observation(
      [&](const VoxelKey& block_key, int index) {
        m.observe(acc.block(block_key), index, detail::voxel_of(block_key, index), 0.0, false, 1.0);
      },
      [&](const VoxelKey& key, double intensity) {
        m.observe(acc.block(detail::block_of(key)), detail::index_in_block(key), key, intensity, true, 1.0);
      });
  m.skipped += skip;
  m.tree_changed();
}

void OctreeMapper::set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) {
  Impl& m = impl();
  std::vector<detail::AbsoluteLogOdds> values;
  const std::size_t skip = detail::prepare_log_odds(points, log_odds, m.updater.params(), m.resolution, values);
  for (const detail::AbsoluteLogOdds& a : values)
    if (!in_octomap_range(a.key)) throw_outside_octomap(describe_row_in(points, a.key, m.resolution), a.key, m.resolution);
  detail::BlockAccessor acc(m.grid);
  for (const detail::AbsoluteLogOdds& a : values) {
    detail::VoxelBlock* b = nullptr;
    detail::Voxel& v = acc.voxel(a.key, b);
    if (detail::set_voxel_log_odds(*b, v, a.log_odds)) ++m.known;
    set_leaf(m.tree, a.key, a.log_odds);
  }
  m.skipped += skip;
  if (!values.empty()) m.tree_changed();
}

void OctreeMapper::set_params(const IwloParams& params) { impl().updater = detail::Updater(params); }
IwloParams OctreeMapper::get_params() const { return impl().updater.params(); }

Eigen::MatrixXd OctreeMapper::get_occupied_voxels(double min_probability) {
  const double threshold = detail::resolve_min_probability(min_probability);
  const Impl& m = impl();
  const std::vector<double> rows = detail::occupied_rows(m.grid, m.resolution, threshold);
  return detail::rows_to_matrix(rows);
}

std::optional<VoxelState> OctreeMapper::query(const Eigen::Vector3d& point) const {
  const Impl& m = impl();
  const VoxelKey key = world_to_key_checked(point, m.resolution);
  return detail::query_voxel(m.grid, key);
}

void OctreeMapper::for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const {
  detail::for_each_known(impl().grid, [&visit](const VoxelKey& k, const detail::Voxel& v) { visit(k, detail::state_of(v)); });
}

MemoryStats OctreeMapper::get_memory_usage() const {
  const Impl& m = impl();
  std::size_t nodes, leaves, tree_bytes;
  {
    std::lock_guard<std::mutex> lock(m.tree_mutex);
    if (!m.stats_valid) {
      m.stat_nodes = m.tree.size();
      m.stat_leaves = m.tree.getNumLeafNodes();
      m.stat_bytes = m.tree.memoryUsage();
      m.stats_valid = true;
    }
    nodes = m.stat_nodes;
    leaves = m.stat_leaves;
    tree_bytes = m.stat_bytes;
  }
  const std::size_t bytes = sizeof(Impl) + tree_bytes + m.grid.bytes() + m.scratch.bytes() +
                            m.batch.capacity() * sizeof(detail::Observation);
  const std::size_t slots = m.grid.num_slots();
  return MemoryStats{nodes, leaves, static_cast<double>(bytes) / (1024.0 * 1024.0),
                     slots == 0 ? 0.0 : static_cast<double>(m.known) / static_cast<double>(slots)};
}

double OctreeMapper::get_resolution() const { return impl().resolution; }
size_t OctreeMapper::get_num_nodes() const { return impl().known; }
size_t OctreeMapper::get_num_skipped_points() const { return impl().skipped; }

void OctreeMapper::clear() {
  Impl& m = impl();
  m.tree.clear();
  m.grid.clear();
  m.scratch.release();
  detail::free_memory(m.batch);
  m.ray.reset();
  m.known = 0;
  m.skipped = 0;
  m.tree_changed();
}

size_t OctreeMapper::prune() {
  Impl& m = impl();
  m.scratch.release();
  detail::free_memory(m.batch);
  m.ray.reset();
  return prune_tree();
}

// ---- export / import -----------------------------------------------------------------------

void export_octomap(const IMapperBackend& map, const std::string& path) {
  const FileFormat f = format_of(path, "export_octomap");
  const double threshold = map.get_params().occupied_threshold;
  octomap::OcTree tree(map.get_resolution());
  const float occupied = tree.getClampingThresMaxLog();
  const float free = tree.getClampingThresMinLog();
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState& v) {
    if (!in_octomap_range(k))
      throw std::out_of_range("iwlomap: export_octomap('" + path + "'): voxel " + describe_key(k) +
                              " lies outside OctoMap's key range [" + std::to_string(kMinKey) + ", " +
                              std::to_string(kMaxKey) + "] per axis; an OctoMap file cannot hold it");
    // .bt holds occupancy only: maximum likelihood, as OctoMap's own writeBinary() stores it.
    const float value =
        f == FileFormat::kFull ? static_cast<float>(v.log_odds) : (v.probability > threshold ? occupied : free);
    set_leaf(tree, k, value);
  });
  tree.updateInnerOccupancy();
  tree.prune();
  write_tree(tree, f, path, "export_octomap");
}

void import_octomap(const std::string& path, IMapperBackend& map) {
  const LoadedTree loaded = read_octomap_file(path, "import_octomap", nullptr);
  const double r = map.get_resolution();
  if (!(std::abs(loaded.resolution - r) <= 1e-5 * r)) {
    std::ostringstream s;
    s.precision(17);
    s << "iwlomap: import_octomap('" << path << "'): the file's resolution " << loaded.resolution
      << " m differs from the map's " << r << " m";
    throw std::invalid_argument(s.str());
  }
  set_tree_voxels(*loaded.tree, map);
}

// ---- registration --------------------------------------------------------------------------

bool detail::register_octomap_backend() {
  static const bool registered = [] {
    register_backend("OctoMap", [](double resolution, const BackendOptions& options) {
      return std::unique_ptr<IMapperBackend>(
          std::make_unique<OctreeMapper>(resolution, options.prob_hit, options.prob_miss));
    });
    return true;
  }();
  return registered;
}

}  // namespace iwlomap
