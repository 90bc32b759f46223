// SPDX-License-Identifier: BSD-3-Clause
// OctoMap files: maps exported by export() and save_to_file() open in OctoMap's readers and in
// Debian's octomap-tools (convert_octree, compare_octrees), imports restore log-odds exactly, and
// bad files fail with clear messages.

#include "backend_test_support.h"
#include "iwlomap/octomap/octree_mapper.h"
#include "iwlomap/probability_updater.h"
#include "octomap_test_support.h"

#include <octomap/AbstractOcTree.h>
#include <octomap/OcTree.h>

#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#ifndef IWLOMAP_CONVERT_OCTREE
#define IWLOMAP_CONVERT_OCTREE ""
#endif
#ifndef IWLOMAP_COMPARE_OCTREES
#define IWLOMAP_COMPARE_OCTREES ""
#endif

namespace iwlomap {
namespace {

using octomap_test::fill_with_scans;
using octomap_test::message_of;
using octomap_test::read_ot;
using octomap_test::tree_voxels;
using test_support::Snapshot;
using test_support::TempDir;
using test_support::snapshot;

namespace fs = std::filesystem;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---- files -----------------------------------------------------------------------------------

TEST(OctoMapFiles, RestoresEveryLogOddsWhenRamMapExportedToOtAndImported) {
  TempDir dir;
  const double r = 0.15;
  ProbabilityUpdater ram(r);
  fill_with_scans(ram);
  std::mt19937 rng(6u);
  std::uniform_real_distribution<double> c(-2.0, 2.0);
  Eigen::MatrixXd pts(5000, 3);
  for (Eigen::Index i = 0; i < pts.rows(); ++i) pts.row(i) << c(rng), c(rng), c(rng);
  ram.batch_update_iwlo(pts, Eigen::VectorXd::LinSpaced(5000, 0.0, 255.0), std::vector<bool>(5000, true),
                        Eigen::VectorXd::LinSpaced(5000, 0.0, 1.5));
  const std::string path = dir.sub("map.ot");
  export_octomap(ram, path);
  ProbabilityUpdater copy(r);
  import_octomap(path, copy);
  const Snapshot want = snapshot(ram), got = snapshot(copy);
  ASSERT_EQ(got.size(), want.size());
  for (const auto& [k, v] : want) {
    const auto it = got.find(k);
    ASSERT_NE(it, got.end());
    EXPECT_EQ(it->second.first, v.first);  // float in, float out: exact
    EXPECT_EQ(it->second.second, 1u);      // .ot holds no counts: imported voxels are known once
  }
  // The OctoMap backend imports the same file to the same values.
  OctreeMapper octree(r);
  import_octomap(path, octree);
  for (const auto& [k, v] : snapshot(octree)) EXPECT_EQ(v.first, want.at(k).first);
  EXPECT_EQ(octree.get_num_known_voxels(), want.size());
}

TEST(OctoMapFiles, ExpandsPrunedNodesWhenImported) {
  TempDir dir;
  const double r = 0.1;
  ProbabilityUpdater ram(r);
  Eigen::MatrixXd cube(512, 3);  // 8^3 aligned voxels at one value: the export prunes them to one node
  for (int i = 0; i < 512; ++i)
    cube.row(i) = key_to_center(VoxelKey{-8 + i % 8, (i / 8) % 8, -8 + i / 64}, r).transpose();
  ram.set_log_odds(cube, Eigen::VectorXd::Constant(512, -3.25));
  export_octomap(ram, dir.sub("cube.ot"));
  const auto tree = read_ot(dir.sub("cube.ot"));
  ASSERT_NE(tree, nullptr);
  EXPECT_EQ(tree->getNumLeafNodes(), 1u);
  ProbabilityUpdater copy(r);
  import_octomap(dir.sub("cube.ot"), copy);
  EXPECT_EQ(snapshot(copy).size(), 512u);
  for (const auto& [k, v] : snapshot(ram)) EXPECT_EQ(copy.query(key_to_center(k, r))->log_odds, -3.25);
}

TEST(OctoMapFiles, ReadsSameOccupiedSetWhenBtReadBinary) {
  TempDir dir;
  const double r = 0.2;
  ProbabilityUpdater ram(r);
  fill_with_scans(ram);
  ram.set_occupied_threshold(0.8);
  const std::string path = dir.sub("map.bt");
  export_octomap(ram, path);

  octomap::OcTree tree(0.1);
  ASSERT_TRUE(tree.readBinary(path));
  EXPECT_EQ(tree.getResolution(), r);
  std::set<VoxelKey> occupied, free;
  for (const auto& [k, v] : tree_voxels(tree, r)) (v >= tree.getOccupancyThresLog() ? occupied : free).insert(k);
  std::set<VoxelKey> want_occupied;
  const Eigen::MatrixXd occ = ram.get_occupied_voxels(0.8);
  for (Eigen::Index i = 0; i < occ.rows(); ++i)
    want_occupied.insert(world_to_key(occ.row(i).head<3>().transpose(), r));
  EXPECT_GT(want_occupied.size(), 100u);
  EXPECT_EQ(occupied, want_occupied);
  EXPECT_EQ(occupied.size() + free.size(), ram.get_num_known_voxels());

  // Imported, .bt gives OctoMap's clamping log-odds of a fresh tree (to the nearest step of the
  // map's voxel format).
  ProbabilityUpdater copy(r);
  import_octomap(path, copy);
  const octomap::OcTree fresh(r);
  const iwlo::VoxelFormat format = iwlo::voxel_format(copy.get_params());
  for (const auto& [k, v] : snapshot(copy)) {
    const bool occ_voxel = want_occupied.count(k) > 0;
    EXPECT_EQ(v.first, static_cast<double>(format.quantize(occ_voxel ? fresh.getClampingThresMaxLog()
                                                                     : fresh.getClampingThresMinLog())));
  }
  EXPECT_EQ(copy.get_num_known_voxels(), ram.get_num_known_voxels());
  // OctreeMapper::load_from_file uses its own clamping thresholds instead.
  OctreeMapper octree(0.5, 0.7, 0.3, 0.2, 0.9);
  octree.load_from_file(path);
  EXPECT_EQ(octree.get_resolution(), r);
  EXPECT_EQ(octree.get_num_known_voxels(), ram.get_num_known_voxels());
  EXPECT_EQ(octree.get_occupied_voxels(0.5).rows(), static_cast<Eigen::Index>(want_occupied.size()));
  const VoxelKey some = *want_occupied.begin();
  EXPECT_NEAR(octree.query(key_to_center(some, r))->probability, 0.9, 1e-6);
}

TEST(OctoMapFiles, RoundTripsWhenOctreeMapperSavesAndLoads) {
  TempDir dir;
  OctreeMapper map(0.25);
  fill_with_scans(map, 2);
  map.save_to_file(dir.sub("a.ot"));
  map.save_to_file(dir.sub("a.bt"));
  OctreeMapper loaded(1.0);
  loaded.load_from_file(dir.sub("a.ot"));
  EXPECT_EQ(loaded.get_resolution(), 0.25);
  const Snapshot want = snapshot(map), got = snapshot(loaded);
  ASSERT_EQ(got.size(), want.size());
  for (const auto& [k, v] : want) EXPECT_EQ(got.at(k).first, v.first);
  // The .bt and the .ot of one map hold the same voxels.
  OctreeMapper binary(1.0);
  binary.load_from_file(dir.sub("a.bt"));
  EXPECT_EQ(binary.get_num_known_voxels(), map.get_num_known_voxels());
  // An empty map is a valid (empty) file in both formats.
  OctreeMapper empty(0.25);
  empty.save_to_file(dir.sub("empty.ot"));
  empty.save_to_file(dir.sub("empty.bt"));
  loaded.load_from_file(dir.sub("empty.ot"));
  EXPECT_EQ(loaded.get_num_known_voxels(), 0u);
  loaded.load_from_file(dir.sub("empty.bt"));
  EXPECT_EQ(loaded.get_num_known_voxels(), 0u);
  EXPECT_FALSE(fs::exists(dir.sub("a.ot.part")));
}

TEST(OctoMapFiles, PrintsNothingWhenWritingAndReading) {
  TempDir dir;
  OctreeMapper map(0.25);
  fill_with_scans(map, 1);
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  map.save_to_file(dir.sub("q.ot"));
  map.save_to_file(dir.sub("q.bt"));
  export_octomap(map, dir.sub("e.bt"));
  OctreeMapper other(0.25);
  other.load_from_file(dir.sub("q.ot"));
  other.load_from_file(dir.sub("q.bt"));
  ProbabilityUpdater ram(0.25);
  import_octomap(dir.sub("e.bt"), ram);
  (void)message_of([&] { import_octomap(dir.sub("missing.ot"), ram); });
  const std::string out = testing::internal::GetCapturedStdout();
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_EQ(out, "");
  EXPECT_EQ(err, "");
  EXPECT_GT(ram.get_num_known_voxels(), 0u);
}

// Bad files: each gives the stated exception, names the path, and leaves the map untouched.
TEST(OctoMapFiles, ThrowsNamingPathAndKeepsMapWhenFileBad) {
  TempDir dir;
  const double r = 0.25;
  OctreeMapper good(r);
  fill_with_scans(good, 1);
  good.save_to_file(dir.sub("good.ot"));
  good.save_to_file(dir.sub("good.bt"));
  const auto bytes = [](const std::string& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  const auto write = [](const std::string& p, const std::string& content) {
    std::ofstream(p, std::ios::binary) << content;
  };
  const std::string ot = bytes(dir.sub("good.ot")), bt = bytes(dir.sub("good.bt"));
  std::mt19937 rng(1u);
  std::string garbage(4096, '\0');
  for (char& ch : garbage) ch = static_cast<char>(rng() & 0xFF);
  write(dir.sub("garbage.bt"), garbage);
  write(dir.sub("garbage.ot"), garbage);
  write(dir.sub("empty.bt"), "");
  write(dir.sub("truncated.ot"), ot.substr(0, ot.size() * 2 / 3));
  write(dir.sub("truncated.bt"), bt.substr(0, bt.size() / 2));
  write(dir.sub("swapped.bt"), ot);
  write(dir.sub("swapped.ot"), bt);
  write(dir.sub("no_data.ot"), "# Octomap OcTree file\nid OcTree\nsize 3\nres 0.25\n");
  write(dir.sub("bad_res.bt"), "# Octomap OcTree binary file\nid OcTree\nsize 1\nres -1\ndata\n\x01\x00");
  write(dir.sub("color.ot"), "# Octomap OcTree file\nid ColorOcTree\nsize 1\nres 0.25\ndata\n");
  // A valid header over data that claims more levels than an octree has.
  std::string deep = "# Octomap OcTree binary file\nid OcTree\nsize 18\nres 0.25\ndata\n";
  for (int i = 0; i < 17; ++i) deep += std::string("\x03\x00", 2);
  write(dir.sub("deep.bt"), deep);
  // The announced node count disagrees with the data.
  std::string miscount = bt;
  const std::size_t size_at = miscount.find("size ") + 5, size_end = miscount.find('\n', size_at);
  miscount.replace(size_at, size_end - size_at, std::to_string(std::stoull(miscount.substr(size_at)) + 1));
  write(dir.sub("miscount.bt"), miscount);
  // A NaN log-odds in an .ot node.
  std::string nan_ot = "# Octomap OcTree file\nid OcTree\nsize 1\nres 0.25\ndata\n";
  const float nan_value = std::numeric_limits<float>::quiet_NaN();
  nan_ot.append(reinterpret_cast<const char*>(&nan_value), sizeof(float));
  nan_ot.push_back('\0');
  write(dir.sub("nan.ot"), nan_ot);
  fs::create_directories(dir.sub("folder.ot"));

  struct Case {
    std::string file;
    std::string what;  // expected in the message
    bool invalid_argument;
  };
  const std::vector<Case> cases = {
      {dir.sub("missing.bt"), "does not exist", false},
      {dir.sub("missing.ot"), "does not exist", false},
      {dir.sub("good.txt"), "extension '.txt'", true},
      {dir.sub("noextension"), "extension ''", true},
      {dir.sub("folder.ot"), "is a directory", false},
      {dir.sub("garbage.bt"), "first line", false},
      {dir.sub("garbage.ot"), "first line", false},
      {dir.sub("empty.bt"), "first line", false},
      {dir.sub("truncated.ot"), "ends early", false},
      {dir.sub("truncated.bt"), "ends early", false},
      {dir.sub("swapped.bt"), "other OctoMap format", false},
      {dir.sub("swapped.ot"), "other OctoMap format", false},
      {dir.sub("no_data.ot"), "no 'data' line", false},
      {dir.sub("bad_res.bt"), "'res'", false},
      {dir.sub("color.ot"), "'ColorOcTree'", false},
      {dir.sub("deep.bt"), "deepest level", false},
      {dir.sub("miscount.bt"), "nodes", false},
      {dir.sub("nan.ot"), "non-finite", false},
  };
  fs::copy_file(dir.sub("good.ot"), dir.sub("good.txt"));
  write(dir.sub("noextension"), ot);

  ProbabilityUpdater ram(r);
  ram.set_log_odds((Eigen::MatrixXd(1, 3) << 0.1, 0.1, 0.1).finished(), Eigen::VectorXd::Constant(1, 1.5));
  OctreeMapper octree(r);
  octree.set_log_odds((Eigen::MatrixXd(1, 3) << 0.1, 0.1, 0.1).finished(), Eigen::VectorXd::Constant(1, 1.5));
  const Snapshot ram_before = snapshot(ram), octree_before = snapshot(octree);
  for (const Case& c : cases) {
    SCOPED_TRACE(c.file);
    for (int target = 0; target < 2; ++target) {
      const auto call = [&] {
        if (target == 0)
          import_octomap(c.file, ram);
        else
          octree.load_from_file(c.file);
      };
      const std::string msg = message_of(call);
      EXPECT_NE(msg.find("'" + c.file + "'"), std::string::npos) << msg;
      EXPECT_NE(msg.find(c.what), std::string::npos) << msg;
      if (c.invalid_argument)
        EXPECT_THROW(call(), std::invalid_argument);
      else
        EXPECT_THROW(call(), std::runtime_error);
    }
  }
  EXPECT_EQ(snapshot(ram), ram_before);
  EXPECT_EQ(snapshot(octree), octree_before);
  EXPECT_EQ(octree.get_resolution(), r);

  // A resolution mismatch on import is an invalid argument naming both values.
  ProbabilityUpdater coarse(0.5);
  const std::string msg = message_of([&] { import_octomap(dir.sub("good.ot"), coarse); });
  EXPECT_NE(msg.find("0.25"), std::string::npos) << msg;
  EXPECT_NE(msg.find("0.5"), std::string::npos) << msg;
  EXPECT_THROW(import_octomap(dir.sub("good.ot"), coarse), std::invalid_argument);
  EXPECT_EQ(coarse.get_num_known_voxels(), 0u);
  // Writing: a bad extension, and a directory that does not exist.
  EXPECT_THROW(export_octomap(ram, dir.sub("map.ply")), std::invalid_argument);
  EXPECT_THROW(octree.save_to_file(dir.sub("map.BTX")), std::invalid_argument);
  const std::string nowhere = dir.sub("no/such/dir/map.bt");
  const std::string wmsg = message_of([&] { export_octomap(ram, nowhere); });
  EXPECT_NE(wmsg.find("'" + nowhere + "'"), std::string::npos) << wmsg;
  EXPECT_THROW(export_octomap(ram, nowhere), std::runtime_error);
}

TEST(OctoMapFiles, ThrowsLogicErrorWhenImportTargetCannotSetLogOdds) {
  // A backend that does not override set_log_odds() keeps the interface's default.
  class NoSet final : public IMapperBackend {
   public:
    void batch_update_iwlo(const Eigen::MatrixXd&, const Eigen::VectorXd&, const std::vector<bool>&) override {}
    void set_iwlo_params(double, double, double, double, double) override {}
    void set_log_odds_params(double, double) override {}
    void set_intensity_params(double, double) override {}
    void set_adaptive_params(bool, double, double) override {}
    void set_occupied_threshold(double) override {}
    Eigen::MatrixXd get_occupied_voxels(double) const override { return Eigen::MatrixXd(0, 4); }
    MemoryStats get_memory_usage() const override { return {}; }
    double get_resolution() const override { return 0.25; }
    size_t get_num_nodes() const override { return 0; }
    void clear() override {}
    std::string get_backend_type() const override { return "Test"; }
    void batch_update_iwlo(const Eigen::MatrixXd&, const Eigen::VectorXd&, const std::vector<bool>&,
                           const Eigen::VectorXd&) override {}
    void insert_scan(const Eigen::Vector3d&, const Eigen::MatrixXd&, const Eigen::VectorXd&, double) override {}
    std::optional<VoxelState> query(const Eigen::Vector3d&) const override { return std::nullopt; }
    void for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>&) const override {}
    size_t get_num_skipped_points() const override { return 0; }
    void set_params(const IwloParams&) override {}
    IwloParams get_params() const override { return {}; }
  };
  TempDir dir;
  OctreeMapper map(0.25);
  map.update_point(Eigen::Vector3d(0.1, 0.1, 0.1), true);
  map.save_to_file(dir.sub("one.ot"));
  NoSet target;
  const std::string msg = message_of([&] { import_octomap(dir.sub("one.ot"), target); });
  EXPECT_NE(msg.find("Test backend does not implement set_log_odds"), std::string::npos) << msg;
  EXPECT_THROW(import_octomap(dir.sub("one.ot"), target), std::logic_error);
}

// ---- Debian's octomap-tools --------------------------------------------------------------------

struct ToolRun {
  int exit_code;
  std::string output;  // stdout and stderr
};

ToolRun run_tool(const std::string& command) {
  ToolRun r{-1, {}};
  FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return r;
  std::array<char, 4096> buf{};
  std::size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), pipe)) > 0) r.output.append(buf.data(), n);
  const int status = ::pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

std::string quoted(const std::string& s) { return "'" + s + "'"; }

// The tools come from octomap-tools (scripts/setup.sh installs it); CMake passes their paths.
// Missing tools fail the test: a silent skip would let CI pass without the interop check.
std::string tool_path(const char* configured, const char* name) {
  const std::string p = configured;
  if (p.empty() || p.find("NOTFOUND") != std::string::npos || !fs::exists(p)) {
    ADD_FAILURE() << name << " was not found when CMake configured the tests (got '" << p
                  << "'): install Debian's octomap-tools (scripts/setup.sh) and reconfigure";
    return {};
  }
  return p;
}

// compare_octrees prints "KLD: <sum>" and exits 0 when the trees have the same leaves; it reports
// a missing voxel with "ERROR" and a size mismatch with a non-zero exit. No difference means: exit
// 0, no ERROR/WARNING, and a KLD of exactly 0.
struct Comparison {
  bool same;
  double kld;
  std::string output;
};
Comparison compare(const std::string& tool, const std::string& a, const std::string& b) {
  const ToolRun run = run_tool(quoted(tool) + " " + quoted(a) + " " + quoted(b));
  Comparison c{false, kNaN, run.output};
  const auto pos = run.output.find("KLD: ");
  if (pos != std::string::npos) c.kld = std::strtod(run.output.c_str() + pos + 5, nullptr);
  c.same = run.exit_code == 0 && pos != std::string::npos && c.kld == 0.0 &&
           run.output.find("ERROR") == std::string::npos && run.output.find("WARNING") == std::string::npos;
  return c;
}

TEST(OctoMapTools, ReportNoDifferenceWhenExportedBtConvertedAndComparedWithReference) {
  const std::string convert = tool_path(IWLOMAP_CONVERT_OCTREE, "convert_octree");
  const std::string compare_tool = tool_path(IWLOMAP_COMPARE_OCTREES, "compare_octrees");
  ASSERT_FALSE(convert.empty() || compare_tool.empty());
  TempDir dir;
  const double r = 0.2;
  ProbabilityUpdater ram(r);
  fill_with_scans(ram);
  const std::string exported = dir.sub("exported.bt");
  export_octomap(ram, exported);

  // convert_octree reads the .bt as OctoMap does and writes it as .ot.
  const std::string converted = dir.sub("converted.ot");
  const ToolRun conv = run_tool(quoted(convert) + " " + quoted(exported) + " " + quoted(converted));
  ASSERT_EQ(conv.exit_code, 0) << conv.output;
  ASSERT_TRUE(fs::exists(converted)) << conv.output;

  // The reference: a plain OcTree built from the same voxels with OctoMap's own coordinate
  // conversion, each voxel set to OctoMap's maximum-likelihood value of its occupancy.
  const double threshold = ram.get_params().occupied_threshold;
  octomap::OcTree reference(r);
  std::size_t occupied = 0;
  ram.for_each_voxel([&](const VoxelKey& k, const VoxelState& v) {
    const Eigen::Vector3d c = key_to_center(k, r);
    const bool occ = v.probability > threshold;
    occupied += occ ? 1 : 0;
    reference.setNodeValue(c.x(), c.y(), c.z(),
                           occ ? reference.getClampingThresMaxLog() : reference.getClampingThresMinLog());
  });
  reference.updateInnerOccupancy();
  const std::string reference_ot = dir.sub("reference.ot");  // compare_octrees needs .ot
  ASSERT_TRUE(reference.write(reference_ot));
  EXPECT_GT(occupied, 100u);

  for (const auto& [a, b] : {std::make_pair(converted, reference_ot), std::make_pair(reference_ot, converted)}) {
    const Comparison c = compare(compare_tool, a, b);
    EXPECT_TRUE(c.same) << c.output;
    EXPECT_NE(c.output.find("Expanded num. leafs: " + std::to_string(ram.get_num_known_voxels())), std::string::npos)
        << c.output;
  }

  // The check can fail: one voxel flipped in the reference gives a KLD above 0.
  const Eigen::Vector3d first = key_to_center(snapshot(ram).begin()->first, r);
  const octomap::OcTreeKey flip = reference.coordToKey(first.x(), first.y(), first.z());
  const octomap::OcTreeNode* n = reference.search(flip);
  ASSERT_NE(n, nullptr);
  reference.setNodeValue(flip, -n->getLogOdds());
  reference.updateInnerOccupancy();
  const std::string flipped = dir.sub("flipped.ot");
  ASSERT_TRUE(reference.write(flipped));
  const Comparison c = compare(compare_tool, converted, flipped);
  EXPECT_FALSE(c.same) << c.output;
  EXPECT_GT(c.kld, 0.0) << c.output;
}

}  // namespace
}  // namespace iwlomap
