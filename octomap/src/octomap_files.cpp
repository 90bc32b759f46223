// SPDX-License-Identifier: BSD-3-Clause
#include "octomap_files.h"

#include "octree_writer.h"

#include "console_capture.h"
#include "iwlomap/octomap/octree_mapper.h"
#include "model/checks.h"

#include <octomap/AbstractOcTree.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <istream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <system_error>
#include <vector>

namespace iwlomap {

namespace detail {

namespace {

const char* const kFullHeader = "# Octomap OcTree file";
const char* const kBinaryHeader = "# Octomap OcTree binary file";

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


}  // namespace

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

void write_file(const std::string& path, const char* caller, const std::function<bool(std::ostream&)>& write,
                const std::string* octomap_output) {
  const std::string tmp = path + ".part";
  std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
  if (!out)
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": cannot write OctoMap file '" + path +
                             "': cannot create '" + tmp + "': " + std::strerror(errno));
  bool ok = false;
  try {
    ok = write(out);
    out.flush();
    out.close();
  } catch (...) {
    out.close();
    std::remove(tmp.c_str());
    throw;
  }
  if (!ok || !out) {
    const int err = errno;
    std::remove(tmp.c_str());
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": writing OctoMap file '" + path + "' failed: " +
                             std::strerror(err) + (octomap_output ? octomap_said(*octomap_output) : std::string()));
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int err = errno;
    std::remove(tmp.c_str());
    throw std::runtime_error(std::string("iwlomap: ") + caller + ": cannot move '" + tmp + "' to '" + path +
                             "': " + std::strerror(err));
  }
}

void write_tree(const octomap::OcTree& tree, FileFormat f, const std::string& path, const char* caller) {
  std::string said;
  write_file(
      path, caller,
      [&](std::ostream& out) {
        ConsoleCapture capture;
        const bool ok = f == FileFormat::kBinary ? tree.writeBinaryConst(out) : tree.write(out);
        out.flush();
        said = capture.finish();
        return ok;
      },
      &said);
}

}  // namespace detail

void export_octomap(const IMapperBackend& map, const std::string& path) {
  export_octomap(map, path, map.get_params().occupied_threshold);
}

void export_octomap(const IMapperBackend& map, const std::string& path, double occupied_threshold,
                    const ProgressCallback& progress) {
  const detail::FileFormat f = detail::format_of(path, "export_octomap");
  if (!(occupied_threshold > 0.0 && occupied_threshold < 1.0))
    throw std::invalid_argument("iwlomap: export_octomap: " + detail::describe("occupied_threshold", occupied_threshold) +
                                " is not in (0, 1)");
  detail::OctreeStream stream(map, f, occupied_threshold, path);
  detail::write_file(path, "export_octomap",
                     [&](std::ostream& out) { return stream.write(out, map.get_resolution(), &progress); });
}

std::unique_ptr<ProbabilityUpdater> import_octomap(const std::string& path) {
  const detail::LoadedTree loaded = detail::read_octomap_file(path, "import_octomap", nullptr);
  auto map = std::make_unique<ProbabilityUpdater>(loaded.resolution);
  detail::set_tree_voxels(*loaded.tree, *map);
  return map;
}

void import_octomap(const std::string& path, IMapperBackend& map) {
  const detail::LoadedTree loaded = detail::read_octomap_file(path, "import_octomap", nullptr);
  const double r = map.get_resolution();
  if (!(std::abs(loaded.resolution - r) <= 1e-5 * r)) {
    std::ostringstream s;
    s.precision(17);
    s << "iwlomap: import_octomap('" << path << "'): the file's resolution " << loaded.resolution
      << " m differs from the map's " << r << " m";
    throw std::invalid_argument(s.str());
  }
  detail::set_tree_voxels(*loaded.tree, map);
}

}  // namespace iwlomap
