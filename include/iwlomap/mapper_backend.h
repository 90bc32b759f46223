// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// IMapperBackend: the one interface of every map backend (RAM, Disk, OctoMap).
///
/// Frames and units: points are in metres in the map frame; intensities are in the sensor's raw
/// units; log-odds are natural logarithms. The IWLO update every backend applies is documented in
/// iwlo.h. Each call handles a whole batch: there is one virtual call per batch, never per voxel.
///
/// Threads: a backend object is not a shared container. Every backend allows any number of
/// threads to call its const methods at once while no thread changes the map; a call that changes
/// it (updates, scans, parameters, clear, flush, set_log_odds) needs the map to itself, as a
/// std::vector does. The Disk backend goes further: it takes a lock inside every method, so any
/// calls from any threads are safe (they run one at a time). Inside one call the RAM and OctoMap
/// backends may use several threads of their own (set_num_threads()); the results do not depend
/// on how many. To share a map between a writer and readers, use AsyncMapper (async_mapper.h),
/// which orders them, or a lock of your own.
///
/// Errors: size mismatches and invalid parameters throw std::invalid_argument naming the value;
/// a call that throws for its input changes nothing. When memory runs out (std::bad_alloc) the map
/// stays consistent, but a batch may be partly applied (the RAM and Disk backends apply batches in
/// groups of 8,192 rows; the RAM backend applies a large batch of scattered points block by
/// block). Non-finite points are skipped and counted (get_num_skipped_points()). An empty batch
/// is a no-op.

#include "iwlomap/hit_statistics.h"
#include "iwlomap/iwlo.h"
#include "iwlomap/progress.h"
#include "iwlomap/ray_caster.h"
#include "iwlomap/scan_phases.h"
#include "iwlomap/voxel_key.h"
#include "iwlomap/voxel_state.h"

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap {

/// Memory held by a backend.
struct MemoryStats {
  size_t num_nodes;          ///< known voxels (OctoMap backend: octree nodes)
  size_t num_leaf_nodes;     ///< known voxels (OctoMap backend: octree leaves)
  double memory_mb;          ///< bytes held in RAM / 2^20 (MiB)
  double memory_efficiency;  ///< known voxels / allocated voxel slots, in [0, 1]
};

/// What a backend may implement beyond the reference API's required methods (see
/// IMapperBackend::supports()).
enum class BackendFeature {
  kWeights,        ///< batch_update_iwlo() with weights other than 1
  kScan,           ///< its own insert_scan() (the default casts rays and calls the batch)
  kQuery,          ///< query() and for_each_voxel()
  kParams,         ///< get_params() reports parameters however they were set
  kSetLogOdds,     ///< set_log_odds(), so the backend can receive an import
  kHitStatistics,  ///< set_hit_accumulation(true) and the hit statistics
  kClone,          ///< clone()
};

class IMapperBackend {
 public:
  virtual ~IMapperBackend() = default;

  // ---- required (reference API) ----

  /// Applies one IWLO observation per point, in order (duplicates are separate observations).
  /// \param points      N x 3, metres, map frame
  /// \param intensities N raw intensities
  /// \param is_occupied N flags; a point is an occupied observation iff its flag is set and its
  ///                    intensity exceeds the intensity threshold, else a free one
  virtual void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                 const std::vector<bool>& is_occupied) = 0;
  /// Learning-rate and clamp parameters (see IwloParams). Validated; throws without changing anything.
  virtual void set_iwlo_params(double sharpness, double decay_rate, double min_alpha, double L_min,
                               double L_max) = 0;
  /// Log-odds increments of an occupied and of a free observation.
  virtual void set_log_odds_params(double log_odds_occupied, double log_odds_free) = 0;
  /// Intensity threshold (at or below: free evidence) and the intensity of full weight.
  virtual void set_intensity_params(double intensity_threshold, double intensity_max) = 0;
  /// Adaptive scale: on/off, P_th in (0, 1), r_max in [0, 1].
  virtual void set_adaptive_params(bool enabled, double threshold, double max_ratio) = 0;
  /// Probability above which a voxel counts as occupied for is_occupied() users (in (0, 1)).
  virtual void set_occupied_threshold(double threshold) = 0;
  /// Occupied voxels: every known voxel with probability > \p min_probability (strict), as an
  /// N x 4 matrix of rows (x, y, z, p) with the voxel centre in metres, map frame. A negative
  /// \p min_probability means 0.5; a value above 1 or NaN throws std::invalid_argument.
  [[nodiscard]] virtual Eigen::MatrixXd get_occupied_voxels(double min_probability = 0.5) const = 0;
  [[nodiscard]] virtual MemoryStats get_memory_usage() const = 0;
  /// Voxel edge length in metres.
  [[nodiscard]] virtual double get_resolution() const = 0;
  /// Number of nodes of the backend's storage, as the reference API counts them: for the voxel
  /// grids (RAM, Disk) the known voxels; for the OctoMap backend the octree's nodes (inner nodes
  /// and leaves, OcTree::size()). For the known voxels of any backend, get_num_known_voxels().
  [[nodiscard]] virtual size_t get_num_nodes() const = 0;
  /// Number of known voxels (observed or set at least once). The default returns get_num_nodes(),
  /// which is that count for a voxel grid; a backend whose nodes are not voxels overrides it.
  [[nodiscard]] virtual size_t get_num_known_voxels() const { return get_num_nodes(); }
  /// Forgets every voxel (parameters are kept).
  virtual void clear() = 0;
  /// "RAM", "Disk" or "OctoMap".
  [[nodiscard]] virtual std::string get_backend_type() const = 0;

  // ---- optional (these defaults are part of the contract) ----

  /// Writes pending state to persistent storage.
  virtual void flush() {}
  /// Loads the storage covering the box [min_bound, max_bound] (metres, map frame).
  virtual void preload_region(const Eigen::Vector3d& min_bound, const Eigen::Vector3d& max_bound) {
    (void)min_bound;
    (void)max_bound;
  }
  /// Bytes on disk.
  [[nodiscard]] virtual size_t get_disk_usage() const { return 0; }
  /// Frees storage that holds no information; returns the number of voxels removed.
  virtual size_t prune() { return 0; }
  [[nodiscard]] virtual bool supports_persistence() const { return false; }

  // ---- additions every backend of the library carries ----
  //
  // A backend written against the reference API alone (only the required methods above) gets a
  // default for each of these, built on the required methods or, where none can be, an explicit
  // "not supported" (std::logic_error naming the backend) that supports() reports beforehand.

  /// Whether this backend implements \p feature itself (false: the default of IMapperBackend
  /// applies, see BackendFeature). The library's backends support every feature but kClone on
  /// the Disk backend.
  [[nodiscard]] virtual bool supports(BackendFeature feature) const;

  /// As batch_update_iwlo() above, with a per-point weight W >= 0 multiplying each increment.
  /// Throws std::invalid_argument for a negative or non-finite weight (nothing is applied).
  /// Default: a batch whose weights are all 1 goes to the unweighted batch; any other weight
  /// throws std::logic_error (BackendFeature::kWeights).
  virtual void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                 const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights);

  /// Integrates one scan taken from \p origin (metres, map frame): every ray from the origin marks
  /// the voxels it crosses as free, up to but excluding the endpoint voxel, and the endpoint voxel
  /// receives an occupied observation with the point's intensity (a hit at or below the intensity
  /// threshold is free evidence). One scan updates each voxel at most once: occupied wins over
  /// free, and several hits in one voxel count once with the largest intensity. With
  /// \p max_range > 0, a point farther than max_range gives a free ray clipped at max_range and no
  /// hit. Non-finite points are skipped and counted, and so is a point whose ray (clipped at
  /// max_range) is longer than kMaxRayVoxels voxel edges: a stray return kilometres away would
  /// otherwise cross millions of voxels. A non-finite origin throws. With a memory limit
  /// (set_map_memory_limit()), a scan that would pass it throws MemoryLimitError.
  /// Default: the rays are cast by the library's ray caster and every voxel's one observation goes
  /// to the unweighted batch_update_iwlo() at the voxel centre (free voxels with intensity 0 and no
  /// occupied flag), which gives the same per-voxel result.
  virtual void insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                           const Eigen::VectorXd& intensities, double max_range = -1.0);

  /// The state of the voxel containing \p point, or std::nullopt when it is unknown (never
  /// observed). Throws std::invalid_argument for a non-finite point.
  /// Default: std::logic_error (BackendFeature::kQuery): the reference API has no per-voxel read.
  [[nodiscard]] virtual std::optional<VoxelState> query(const Eigen::Vector3d& point) const;

  /// Calls \p visit once for every known voxel, in an unspecified but deterministic order.
  /// Default: std::logic_error (BackendFeature::kQuery).
  virtual void for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const;

  /// Points skipped so far because a coordinate or intensity was not finite, or because their ray
  /// was longer than kMaxRayVoxels voxel edges (insert_scan()); reset by clear().
  /// Default: the points the default insert_scan() skipped.
  [[nodiscard]] virtual size_t get_num_skipped_points() const;

  /// All IWLO parameters at once (validated; throws std::invalid_argument without changing anything).
  /// Default: validates, then calls the five grouped setters of the reference API.
  virtual void set_params(const IwloParams& params);
  /// Default: the parameters last given to set_params() (the reference defaults before): a backend
  /// that does not override it cannot report values set through its grouped setters
  /// (BackendFeature::kParams).
  [[nodiscard]] virtual IwloParams get_params() const;

  /// Sets absolute log-odds, which is not an observation: importing a map from a file
  /// (import_octomap() of the OctoMap layer) must restore log-odds exactly, and no sequence of IWLO
  /// updates can do that. The voxel containing points.row(i) gets log_odds[i] clamped to
  /// [L_min, L_max] (stored as float, like every update), and its observation count becomes
  /// max(count, 1), so the voxel is known afterwards. Rows are applied in order (the last of
  /// several rows in one voxel wins). A row whose point or value is not finite is skipped and
  /// counted (get_num_skipped_points()).
  /// Throws, before changing anything: std::invalid_argument when points is not N x 3 or log_odds
  /// does not have N entries; std::out_of_range when a point lies outside the backend's key range.
  /// The default throws std::logic_error naming the backend: a backend without it cannot be the
  /// target of an import.
  virtual void set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds);

  /// Turns per-voxel hit statistics on or off (off by default; see hit_statistics.h for what
  /// counts as a hit and a visit). Turning it on when it is off starts from empty statistics (on
  /// again keeps them); turning it off frees them. clear() empties them and keeps the setting.
  /// The default throws std::logic_error naming the backend when asked to turn it on (turning it
  /// off is a no-op): a backend without it cannot give mean hit positions.
  virtual void set_hit_accumulation(bool enabled);
  [[nodiscard]] virtual bool get_hit_accumulation() const { return false; }
  /// Statistics of the voxel containing \p point, or std::nullopt when accumulation has never
  /// seen it visited. Throws std::logic_error when accumulation is off (the default: naming the
  /// backend), std::invalid_argument for a non-finite point.
  [[nodiscard]] virtual std::optional<HitStatistics> hit_statistics(const Eigen::Vector3d& point) const;
  /// get_occupied_voxels() with each voxel's mean hit position instead of its centre (the centre
  /// where the voxel has no accumulated hit): rows (x, y, z, p) in the same order. Throws
  /// std::logic_error when accumulation is off (the default: naming the backend).
  [[nodiscard]] virtual Eigen::MatrixXd get_occupied_mean_positions(double min_probability = 0.5);

  /// An independent copy of the map: its voxels, parameters, hit statistics and thread count;
  /// later changes to either do not show in the other (one map per particle of a particle filter,
  /// or a "what if" integration). Default: std::logic_error (BackendFeature::kClone). The Disk
  /// backend's map lives in its directory: OutofcoreTileMapper::copy_to() copies it there.
  [[nodiscard]] virtual std::unique_ptr<IMapperBackend> clone() const;

  /// Threads that insert_scan() may use to cast rays and apply them: 1 (the default, so that
  /// single-thread figures stay comparable), N, or 0 for every hardware thread. The map is
  /// bit-identical whatever the count. Backends that cannot use threads accept the setting and
  /// work on one. Throws std::invalid_argument for a negative count.
  void set_num_threads(int threads);
  /// The thread count in effect (0 resolved to the hardware's count, at least 1).
  [[nodiscard]] int get_num_threads() const noexcept { return num_threads_; }

  /// Which voxels insert_scan() marks free along each ray (ray_caster.h): RayModel::kExact, the
  /// default, every voxel the segment crosses; RayModel::kFast, a 26-connected line between voxel
  /// centres, up to three times fewer steps per ray and fewer free observations (RayModel says
  /// what it misses). Hits do not depend on it. The library's backends give the same map for the
  /// same model and any thread count. A setting of this object, like the thread count: not stored
  /// with the map; clone() copies it. A backend whose insert_scan() casts its own rays may ignore it.
  void set_ray_model(RayModel model) noexcept { ray_model_ = model; }
  [[nodiscard]] RayModel get_ray_model() const noexcept { return ray_model_; }

  /// Reports the progress of this map's long calls to \p callback (iwlomap/progress.h):
  /// insert_scan() (ProgressStage::kCastingRays, then kUpdatingVoxels) and, for the Disk backend,
  /// flush() (kWritingTiles). An empty callback (the default) turns the reports off. A backend of
  /// your own reports what it chooses; the default insert_scan() reports kCastingRays.
  void set_progress_callback(ProgressCallback callback) { progress_ = std::move(callback); }
  /// The callback set by set_progress_callback() (empty: none).
  [[nodiscard]] const ProgressCallback& get_progress_callback() const noexcept { return progress_; }

  /// Where the last insert_scan() of this map spent its time (scan_phases.h): the phases on up to
  /// get_num_threads() threads and those on the calling thread only, in seconds. All zero before
  /// the first scan; a scan that throws leaves what it measured. The library's backends and the
  /// default insert_scan() fill it; a backend of your own whose insert_scan() does not leaves it
  /// zero. Not covered by the Disk backend's locking: read it on the thread that inserted.
  [[nodiscard]] const ScanPhaseTimes& get_last_scan_phases() const noexcept { return scan_phases_; }

 protected:
  /// The record get_last_scan_phases() returns, for a backend's insert_scan() to fill.
  ScanPhaseTimes& last_scan_phases() noexcept { return scan_phases_; }

 private:
  int num_threads_ = 1;
  RayModel ray_model_ = RayModel::kExact;
  ScanPhaseTimes scan_phases_;
  ProgressCallback progress_;
  IwloParams default_params_;          // the default get_params()
  std::size_t default_skipped_ = 0;    // the default get_num_skipped_points()
};

inline void IMapperBackend::set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) {
  (void)points;
  (void)log_odds;
  throw std::logic_error("iwlomap: the " + get_backend_type() + " backend does not implement set_log_odds()");
}

inline void IMapperBackend::set_hit_accumulation(bool enabled) {
  if (enabled)
    throw std::logic_error("iwlomap: the " + get_backend_type() + " backend does not implement hit accumulation");
}

inline std::optional<HitStatistics> IMapperBackend::hit_statistics(const Eigen::Vector3d& point) const {
  (void)point;
  throw std::logic_error("iwlomap: the " + get_backend_type() + " backend does not implement hit_statistics()");
}

inline Eigen::MatrixXd IMapperBackend::get_occupied_mean_positions(double min_probability) {
  (void)min_probability;
  throw std::logic_error("iwlomap: the " + get_backend_type() +
                         " backend does not implement get_occupied_mean_positions()");
}

/// The common base of the library's backends (RAM, Disk, OctoMap): the reference API's grouped
/// parameter setters implemented once, each as set_params() of a validated copy of get_params()
/// with the named fields changed, so a rejected value changes nothing. A backend of your own may
/// derive from it to get them, or implement IMapperBackend directly.
class BackendBase : public IMapperBackend {
 public:
  void set_iwlo_params(double sharpness, double decay_rate, double min_alpha, double L_min, double L_max) final;
  void set_log_odds_params(double log_odds_occupied, double log_odds_free) final;
  void set_intensity_params(double intensity_threshold, double intensity_max) final;
  void set_adaptive_params(bool enabled, double threshold, double max_ratio) final;
  void set_occupied_threshold(double threshold) final;
  /// The library's backends implement every feature (the Disk backend overrides this for kClone).
  [[nodiscard]] bool supports(BackendFeature feature) const override;

 protected:
  /// Sets the parameters to \p change applied to a copy of get_params(), once the copy is
  /// validated (std::invalid_argument otherwise, nothing changed). The default reads with
  /// get_params() and writes with set_params(); a backend whose calls may run concurrently
  /// overrides it to do both under one lock.
  virtual void modify_params(const std::function<void(IwloParams&)>& change);
};

/// Options of make_backend() that only some backends use.
struct BackendOptions {
  std::string directory;      ///< Disk: map directory
  double tile_size = 10.0;    ///< Disk: tile edge in metres
  size_t cache_tiles = 16;    ///< Disk: resident tiles
  double prob_hit = 0.7;      ///< OctoMap: probability of a hit in OctoMap's own model
  double prob_miss = 0.3;     ///< OctoMap: probability of a miss in OctoMap's own model
};

/// Creates a backend by name: "RAM" (case-insensitive; also "ram"), "Disk", "OctoMap". A backend
/// whose layer is not part of this build, or an unknown name, throws std::invalid_argument that
/// lists the available names.
[[nodiscard]] std::unique_ptr<IMapperBackend> make_backend(const std::string& type, double resolution = 0.05,
                                                           const BackendOptions& options = {});

/// Factory signature for backends provided by an optional layer.
using BackendFactory = std::function<std::unique_ptr<IMapperBackend>(double resolution, const BackendOptions&)>;

/// Makes a backend of an optional layer available to make_backend() under \p type
/// (case-insensitive). Layers call this; users rarely need to.
void register_backend(const std::string& type, BackendFactory factory);

/// Names make_backend() accepts in this process, in registration order.
[[nodiscard]] std::vector<std::string> available_backends();

}  // namespace iwlomap
