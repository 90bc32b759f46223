// SPDX-License-Identifier: BSD-3-Clause
// The OctoMap backend: the exact IWLO state in a block grid, as in the RAM backend, mirrored into
// an octomap::OcTree; OctoMap's own model on the same tree.
#include "iwlomap/octomap/octree_mapper.h"

#include "octomap_files.h"
#include "octomap_keys.h"

#include "backends/pimpl.h"
#include "integrate/absolute_log_odds.h"
#include "integrate/batch_input.h"
#include "integrate/hit_accumulator.h"
#include "integrate/phase_clock.h"
#include "integrate/progress_report.h"
#include "integrate/scan_apply.h"
#include "integrate/scan_scratch.h"
#include "integrate/updater.h"
#include "integrate/voxel_update.h"
#include "model/checks.h"
#include "storage/block_grid.h"
#include "storage/free_memory.h"
#include "storage/grid_reads.h"

#include <octomap/OcTree.h>

#include <cmath>
#include <cstdint>
#include <exception>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap {

using detail::describe_point;
using detail::from_octomap;
using detail::in_octomap_range;
using detail::kKeyOffset;
using detail::set_leaf;
using detail::throw_outside_octomap;
using detail::to_octomap;

namespace {

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
    const iwlo::VoxelFormat& f = updater.format();
    const float before = f.log_odds(v.word);
    const bool was_unknown = detail::observe_voxel(b, v, intensity, occupied_flag, weight, updater);
    if (was_unknown) ++known;
    const float after = f.log_odds(v.word);
    if (was_unknown || after != before) set_leaf(tree, key, after);
  }

  // One observation of OctoMap's own model: the octree computes it, the exact state copies it,
  // rounded to its voxel format (the octree keeps OctoMap's own float).
  void observe_octomap(detail::BlockAccessor& acc, const VoxelKey& key, bool occupied) {
    const octomap::OcTreeNode* node = tree.updateNode(to_octomap(key), occupied, /*lazy_eval=*/true);
    detail::VoxelBlock* b = nullptr;
    detail::Voxel& v = acc.voxel(key, b);
    const iwlo::VoxelFormat& f = updater.format();
    if (!v.known()) {
      ++b->known;
      ++known;
    }
    v.word = f.encode(node->getLogOdds(), f.next_count(f.count(v.word)));
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
  detail::HitStatisticsOf hits{resolution};
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

IWLOMAP_DEFINE_PIMPL_MEMBERS(OctreeMapper)

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
  IwloParams p = m.updater.params();
  p.occupied_threshold = prob_thres_max;
  detail::Updater next(p);
  m.set_model(m.prob_hit, m.prob_miss, prob_thres_min, prob_thres_max);
  m.updater = std::move(next);
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

bool OctreeMapper::save_to_file(const std::string& path) const {
  const Impl& m = impl();
  if (detail::format_of(path, "save_to_file") == detail::FileFormat::kBinary) {
    export_octomap(*this, path);
    return true;
  }
  // .ot: the octree itself, whose leaves are the exact log-odds.
  std::lock_guard<std::mutex> lock(m.tree_mutex);
  m.refresh_inner_locked();
  detail::write_tree(m.tree, detail::FileFormat::kFull, path, "save_to_file");
  return true;
}

bool OctreeMapper::load_from_file(const std::string& path) {
  Impl& m = impl();
  const std::pair<double, double> clamping(m.prob_thres_min, m.prob_thres_max);
  const detail::LoadedTree loaded = detail::read_octomap_file(path, "load_from_file", &clamping);
  clear();
  m.resolution = loaded.resolution;
  m.tree.setResolution(loaded.resolution);
  m.hits.reset(loaded.resolution);
  detail::set_tree_voxels(*loaded.tree, *this);
  return true;
}

// ---- IMapperBackend ----

void OctreeMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                     const std::vector<bool>& is_occupied) {
  Impl& m = impl();
  m.apply_batch(points, intensities, is_occupied, nullptr);
  m.hits.add_batch(points, intensities, is_occupied, m.updater.params().intensity_threshold);
}

void OctreeMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                     const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) {
  Impl& m = impl();
  m.apply_batch(points, intensities, is_occupied, &weights);
  m.hits.add_batch(points, intensities, is_occupied, m.updater.params().intensity_threshold);
}

void OctreeMapper::insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                               const Eigen::VectorXd& intensities, double max_range) {
  Impl& m = impl();
  ScanPhaseTimes& phases = last_scan_phases();
  detail::PhaseClock total = detail::start_scan_phases(phases, get_num_threads());
  detail::check_scan_input(origin, points, intensities, max_range, m.resolution);
  // Rays may be cast on several threads (bit-identical); the octree is then updated on this one.
  const detail::RayStatistics ray_stats{m.updater.params().intensity_threshold};
  const detail::RayStatistics* stats = m.hits.enabled() ? &ray_stats : nullptr;
  const std::size_t skip = m.scratch.collect(origin, points, intensities, max_range, m.resolution, get_ray_model(),
                                             get_num_threads(), &get_progress_callback(), stats, &phases);
  // Every voxel the scan would update must have an OctoMap key; checked before anything changes.
  m.scratch.for_each_observation(
      [&](const VoxelKey& block_key, int index) {
        if (!detail::block_in_octomap_range(block_key))
          throw_outside_octomap("a ray of the scan from " + describe_point(origin), detail::voxel_of(block_key, index),
                                m.resolution);
      },
      [&](const VoxelKey& key, double) {
        if (!in_octomap_range(key)) throw_outside_octomap("a point of the scan", key, m.resolution);
      });
  // The exact state as the RAM backend lays it out (the same iteration order), mirrored.
  detail::OneGrid locate(m.grid);
  detail::allocate_scan(m.scratch, m.grid, locate, get_num_threads(), &phases);
  // The octree update is on this thread (an exception of the progress callback is rethrown once
  // the scan is applied in full).
  std::exception_ptr deferred;
  detail::StageProgress report(&get_progress_callback(), ProgressStage::kUpdatingVoxels, m.scratch.num_chunks() + 1,
                               &deferred);
  (void)detail::apply_scan(
      m.scratch, {}, 1, locate,
      [&m](detail::VoxelBlock& b, int index, const VoxelKey& key, double intensity, bool occupied) {
        m.observe(b, index, key, intensity, occupied, 1.0);
        return false;  // m.observe() counts the map's known voxels itself
      },
      report, 0, &phases.updating);
  m.skipped += skip;
  m.tree_changed();
  m.hits.add_scan(m.scratch.statistics());
  total.stop();
  if (deferred) std::rethrow_exception(deferred);
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
    if (detail::set_voxel_log_odds(*b, v, a.log_odds, m.updater.format())) ++m.known;
    set_leaf(m.tree, a.key, a.log_odds);
  }
  m.skipped += skip;
  if (!values.empty()) m.tree_changed();
}

void OctreeMapper::set_params(const IwloParams& params) {
  Impl& m = impl();
  detail::Updater next(params);
  if (!next.format().same_layout(m.updater.format())) {
    // The stored values are rounded to the new format; the octree's leaves follow them.
    detail::convert_voxels(m.grid, m.updater.format(), next.format());
    detail::for_each_known(m.grid, [&](const VoxelKey& key, const detail::Voxel& v) {
      set_leaf(m.tree, key, next.format().log_odds(v.word));
    });
    m.tree_changed();
  }
  m.updater = std::move(next);
}
IwloParams OctreeMapper::get_params() const { return impl().updater.params(); }

Eigen::MatrixXd OctreeMapper::get_occupied_voxels(double min_probability) const {
  return detail::occupied_matrix(impl().grid, impl().updater.format(), impl().resolution, min_probability);
}

std::optional<VoxelState> OctreeMapper::query(const Eigen::Vector3d& point) const {
  return detail::query_point(impl().grid, impl().updater.format(), impl().resolution, point);
}

void OctreeMapper::for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const {
  detail::for_each_state(impl().grid, impl().updater.format(), visit);
}

void OctreeMapper::set_hit_accumulation(bool enabled) { impl().hits.set_enabled(enabled); }

bool OctreeMapper::get_hit_accumulation() const { return impl().hits.enabled(); }

std::optional<HitStatistics> OctreeMapper::hit_statistics(const Eigen::Vector3d& point) const {
  const Impl& m = impl();
  return m.hits.get("hit_statistics()").statistics(world_to_key_checked(point, m.resolution));
}

Eigen::MatrixXd OctreeMapper::get_occupied_mean_positions(double min_probability) {
  const Impl& m = impl();
  return detail::occupied_mean_matrix(m.grid, m.updater.format(), m.hits.get("get_occupied_mean_positions()"), min_probability);
}

std::unique_ptr<IMapperBackend> OctreeMapper::clone() const {
  const Impl& m = impl();
  auto copy = std::make_unique<OctreeMapper>(m.resolution, m.prob_hit, m.prob_miss, m.prob_thres_min, m.prob_thres_max);
  Impl& c = *copy->impl_;
  c.updater = m.updater;
  c.grid = m.grid.clone();
  if (m.hits.enabled()) {
    c.hits.set_enabled(true);
    c.hits.get()->merge(m.hits.get("clone()"));
  }
  {
    std::lock_guard<std::mutex> lock(m.tree_mutex);  // const readers may refresh the tree meanwhile
    octomap::OcTree tree(m.tree);
    c.tree.swapContent(tree);
  }
  c.known = m.known;
  c.skipped = m.skipped;
  c.tree_changed();
  copy->set_num_threads(get_num_threads());
  copy->set_ray_model(get_ray_model());
  return copy;
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
                            m.batch.capacity() * sizeof(detail::Observation) + m.hits.bytes();
  const std::size_t slots = m.grid.num_slots();
  return MemoryStats{nodes, leaves, static_cast<double>(bytes) / (1024.0 * 1024.0),
                     slots == 0 ? 0.0 : static_cast<double>(m.known) / static_cast<double>(slots)};
}

double OctreeMapper::get_resolution() const { return impl().resolution; }
size_t OctreeMapper::get_num_nodes() const { return impl().tree.size(); }
size_t OctreeMapper::get_num_known_voxels() const { return impl().known; }
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
  m.hits.clear();
  m.tree_changed();
}

size_t OctreeMapper::prune() {
  Impl& m = impl();
  m.scratch.release();
  detail::free_memory(m.batch);
  m.ray.reset();
  return prune_tree();
}

// ---- registration --------------------------------------------------------------------------

namespace detail {
bool register_octomap_backend();
}  // namespace detail

// Linking iwlomap::octomap is enough for make_backend("OctoMap"): every program that links the
// layer compiles link_reference.cpp, which refers to this function, so the object that defines it
// (static build) or the library (shared build) is part of the program, and so is the initializer
// below.
extern "C" bool iwlomap_octomap_backend_registered() noexcept { return detail::register_octomap_backend(); }
namespace {
[[maybe_unused]] const bool kRegisteredAtStartup = detail::register_octomap_backend();
}  // namespace

// Registers "OctoMap" with make_backend() (idempotent; returns true).
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
