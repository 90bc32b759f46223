// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// OctreeMapper: the OctoMap backend, and export/import of any backend in OctoMap's .bt and .ot
/// files (library iwlomap::octomap). No OctoMap header is included here: the octree lives behind
/// a pointer to an implementation, so users of this header need OctoMap only to link.
///
/// Linking iwlomap::octomap makes make_backend("OctoMap") work; no header needs to be included.

#include "iwlomap/mapper_backend.h"
#include "iwlomap/probability_updater.h"

#include <memory>
#include <string>

namespace iwlomap {

/// An IWLO map kept as an OctoMap octree (octomap::OcTree), for users of RViz, octovis and MoveIt,
/// and as the reference that speed claims are measured against.
///
/// Two models share one map:
/// - IMapperBackend (batch_update_iwlo(), insert_scan(), ...) applies IWLO exactly as the RAM
///   backend (ProbabilityUpdater) does: the same input gives the same per-voxel log-odds and
///   observation counts, bit for bit. The exact state (float log-odds + uint16 count per voxel) is
///   kept beside the octree, because OcTree nodes hold no count and OctoMap clamps and prunes
///   values; every change is mirrored into the octree's leaves, so the tree is at all times an
///   OctoMap of the map (leaf log-odds = the map's log-odds, unknown voxels absent).
/// - OctoMap's own model (update_point(), batch_update(), insert_ray()) updates the octree as
///   OctoMap does, with prob_hit / prob_miss and OctoMap's clamping thresholds; the resulting leaf
///   log-odds is copied into the exact state and the voxel's count is incremented.
///
/// Keys: iwlomap's floor keys k map to OctoMap keys k + 32768. OctoMap's 16-bit keys limit the map
/// to voxels -32768 <= k <= 32767 per axis (+-1638 m at 0.05 m); an update touching a voxel
/// outside throws std::out_of_range and changes nothing (keys are never wrapped).
///
/// set_num_threads() lets insert_scan() cast rays on several threads; the octree and the exact
/// state are updated on the calling thread.
///
/// Not thread-safe: one thread at a time may call a mutating method; const methods may run
/// concurrently with each other (the octree's derived data they refresh is guarded).
/// Non-copyable, movable; a moved-from object throws std::logic_error from every method that reads
/// or changes the map (get_backend_type() and the thread count still answer).
class OctreeMapper final : public BackendBase {
 public:
  /// \param resolution     voxel edge in metres (> 0, finite)
  /// \param prob_hit       OctoMap model: probability of a hit, in (0.5, 1)
  /// \param prob_miss      OctoMap model: probability of a miss, in (0, 0.5)
  /// \param prob_thres_min OctoMap model: lower clamping threshold, a probability in (0, 1)
  /// \param prob_thres_max OctoMap model: upper clamping threshold, in (prob_thres_min, 1)
  /// Throws std::invalid_argument naming the first invalid value.
  explicit OctreeMapper(double resolution = 0.05, double prob_hit = 0.7, double prob_miss = 0.3,
                        double prob_thres_min = 0.12, double prob_thres_max = 0.97);
  ~OctreeMapper() override;
  OctreeMapper(const OctreeMapper&) = delete;
  OctreeMapper& operator=(const OctreeMapper&) = delete;
  OctreeMapper(OctreeMapper&&) noexcept;
  OctreeMapper& operator=(OctreeMapper&&) noexcept;

  // ---- OctoMap's own model ----

  /// One hit (\p occupied) or miss in the voxel containing \p point (metres, map frame), as
  /// OcTree::updateNode() applies it. A non-finite point is skipped and counted.
  void update_point(const Eigen::Vector3d& point, bool occupied);
  /// update_point() for every row of \p points (N x 3), in order; non-finite rows are skipped and
  /// counted. Throws std::invalid_argument for mismatched sizes and std::out_of_range for a
  /// point outside OctoMap's key range, before changing anything.
  void batch_update(const Eigen::MatrixXd& points, const std::vector<bool>& occupied_flags);
  /// Absolute log-odds, clamped to [L_min, L_max], kept exactly (same as set_log_odds()).
  void batch_update_with_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds);
  /// One ray as OcTree::insertRay() integrates it: OctoMap's own ray traversal (in float, as
  /// OctoMap computes it) gives misses up to the endpoint's voxel and a hit there. With
  /// \p max_range > 0 a longer ray is cut at max_range and gives no hit. Throws
  /// std::invalid_argument for a non-finite origin or endpoint and std::out_of_range when the ray
  /// leaves OctoMap's key range, before changing anything.
  void insert_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& endpoint, double max_range = -1.0);
  /// OctoMap model: probabilities of a hit, in (0.5, 1), and of a miss, in (0, 0.5).
  void set_probability_params(double prob_hit, double prob_miss);
  /// The reference API's thresholds, probabilities with 0 < min < max < 1: OctoMap's clamping
  /// thresholds, and \p prob_thres_max is also the occupancy threshold, the map's
  /// IwloParams::occupied_threshold, above which a voxel is written occupied to a .bt file
  /// (export_octomap(), save_to_file()).
  void set_occupancy_thresholds(double prob_thres_min, double prob_thres_max);
  [[nodiscard]] double get_prob_hit() const;
  [[nodiscard]] double get_prob_miss() const;
  [[nodiscard]] double get_prob_thres_min() const;
  [[nodiscard]] double get_prob_thres_max() const;
  /// OcTree::prune(): merges every 8 sibling leaves that hold the same log-odds into their parent.
  /// Lossless; the exact state is untouched. Returns the number of octree nodes freed.
  size_t prune_tree();

  /// Writes the map to \p path: ".ot" is the octree itself with full log-odds; ".bt" is
  /// OctoMap's maximum-likelihood binary format, as export_octomap() writes it. The file is
  /// written to a temporary name and renamed, so a failure never leaves a partial file.
  /// OctoMap's console messages while it writes ".ot" are captured, never printed: the process's
  /// standard output and error are redirected meanwhile, so other threads' output is lost then.
  /// Returns true, as the reference API's `bool ok = save_to_file(path)` expects; a failure is
  /// never reported by false but thrown: std::invalid_argument for another extension,
  /// std::runtime_error naming the path when writing fails.
  bool save_to_file(const std::string& path) const;
  /// Replaces the map by the contents of \p path (".bt" or ".ot", see import_octomap()) and takes
  /// the file's resolution; IWLO parameters and the OctoMap model are kept. Every voxel of the
  /// file becomes known with count 1. Returns true (the reference API's bool); throws like
  /// import_octomap() instead of returning false, and on error the map is unchanged.
  bool load_from_file(const std::string& path);

  // ---- IMapperBackend ----

  void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                         const std::vector<bool>& is_occupied) override;
  void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                         const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) override;
  void insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                   const Eigen::VectorXd& intensities, double max_range = -1.0) override;
  void set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) override;

  void set_params(const IwloParams& params) override;
  [[nodiscard]] IwloParams get_params() const override;

  /// Occupied voxels from the exact log-odds; a negative \p min_probability means 0.5, as in
  /// IMapperBackend. Rows come in the same order as the RAM backend's for the same input.
  [[nodiscard]] Eigen::MatrixXd get_occupied_voxels(double min_probability = -1.0) const override;
  /// A voxel outside OctoMap's key range is never known: std::nullopt.
  [[nodiscard]] std::optional<VoxelState> query(const Eigen::Vector3d& point) const override;
  void for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const override;

  /// Hit statistics of the IWLO model, kept as the RAM backend keeps them and equal to its
  /// (hit_statistics.h); OctoMap's own model (update_point(), batch_update(), insert_ray()) adds
  /// nothing to them.
  void set_hit_accumulation(bool enabled) override;
  [[nodiscard]] bool get_hit_accumulation() const override;
  [[nodiscard]] std::optional<HitStatistics> hit_statistics(const Eigen::Vector3d& point) const override;
  [[nodiscard]] Eigen::MatrixXd get_occupied_mean_positions(double min_probability = 0.5) override;

  /// A deep copy (a new OctreeMapper): the octree, the exact state, both models' parameters, hit
  /// statistics and thread count.
  [[nodiscard]] std::unique_ptr<IMapperBackend> clone() const override;

  /// num_nodes and num_leaf_nodes are the octree's (OcTree::size(), getNumLeafNodes());
  /// memory_mb counts the octree (OcTree::memoryUsage()) plus the exact state and scratch
  /// buffers; memory_efficiency is known voxels / allocated voxel slots of the exact state. The
  /// octree figures walk the whole tree, so they are cached until the next update.
  [[nodiscard]] MemoryStats get_memory_usage() const override;
  [[nodiscard]] double get_resolution() const override;
  /// The octree's nodes, inner nodes and leaves (OcTree::size(), as OctoMap counts them).
  [[nodiscard]] size_t get_num_nodes() const override;
  /// Known voxels (as every backend).
  [[nodiscard]] size_t get_num_known_voxels() const override;
  [[nodiscard]] size_t get_num_skipped_points() const override;
  void clear() override;
  [[nodiscard]] std::string get_backend_type() const override { return "OctoMap"; }
  /// prune_tree(), and returns the exact state's scratch buffers; returns the octree nodes freed.
  size_t prune() override;

 private:
  struct Impl;
  Impl& impl();
  const Impl& impl() const;
  std::unique_ptr<Impl> impl_;
};

/// Writes any backend's map to an OctoMap file, chosen by extension:
/// - ".ot": every known voxel with its log-odds (OctoMap's full format; OcTree::read() and
///   octovis open it). Observation counts are not part of the format.
/// - ".bt": maximum likelihood, OctoMap's compact binary format: a known voxel is occupied when
///   its probability exceeds the map's occupied_threshold (IwloParams, default 0.7), else free.
/// The tree is pruned (lossless: only 8 equal siblings merge). The file holds the bytes OctoMap's
/// OcTree writes for these voxels, written straight from the map's blocks in the octree's order,
/// without building an OcTree: time about 15 ns a voxel for ".bt" (under half the time of mapping
/// the scan that made the map), extra memory under the map's own (docs/benchmarks.md, "Outputs").
/// The Disk backend is read tile by tile. The file is written to a temporary name and renamed.
/// Throws std::invalid_argument for another extension, std::out_of_range naming the voxel when a
/// known voxel lies outside OctoMap's key range (-32768..32767 per axis), std::runtime_error
/// naming the path when the file cannot be written.
void export_octomap(const IMapperBackend& map, const std::string& path);
/// As above, with \p occupied_threshold, a probability in (0, 1), instead of the map's own for
/// ".bt" (ignored for ".ot"): for maps whose parameters cannot change (read-only disk maps).
/// \p progress, when set, hears ProgressStage::kWritingFile (the map's 8^3 blocks written, from
/// the calling thread; iwlomap/progress.h); an exception it throws cancels the export and leaves
/// no file.
void export_octomap(const IMapperBackend& map, const std::string& path, double occupied_threshold,
                    const ProgressCallback& progress = {});

/// Reads an OctoMap file (".bt" or ".ot" by extension) into \p map, whose resolution must match
/// the file's (to the 6 significant digits OctoMap writes). Every voxel of the file is set with
/// IMapperBackend::set_log_odds(): ".ot" gives its log-odds exactly (within float precision, the
/// precision of the file); ".bt" gives OctoMap's clamping log-odds of a freshly made OcTree
/// (about 3.51 occupied, -2.0 free). Voxels of pruned nodes are expanded. Voxels of \p map that
/// the file does not hold are kept (clear() the map first for a copy).
/// The file is checked completely before OctoMap reads it, so a corrupt or truncated file is an
/// exception, never a crash or a partial map; a file whose leaves expand to more than 2^30 voxels
/// is refused. Throws std::invalid_argument for another
/// extension or a resolution mismatch, std::runtime_error naming the path when the file is
/// missing, unreadable, not an OctoMap file or corrupt; the map is unchanged then.
void import_octomap(const std::string& path, IMapperBackend& map);

/// Reads an OctoMap file into a new RAM map (ProbabilityUpdater) at the file's resolution (as
/// OctoMap wrote it, 6 significant digits), with the reference's default parameters; otherwise as
/// import_octomap(path, map).
[[nodiscard]] std::unique_ptr<ProbabilityUpdater> import_octomap(const std::string& path);

}  // namespace iwlomap
