// SPDX-License-Identifier: BSD-3-Clause
// The Disk backend's public methods: each takes the lock once and calls into its Impl
// (disk_map_impl.h).
#include "backends/backend_access.h"
#include "backends/disk/disk_map_impl.h"

#include "backends/pimpl.h"

#include <memory>

namespace iwlomap {

StorageError::StorageError(Kind kind, std::string path, const std::string& message)
    : std::runtime_error(message), kind_(kind), path_(std::move(path)) {}

// ---- public methods: each takes the lock once ----

OutofcoreTileMapper::OutofcoreTileMapper(const std::string& directory, double resolution, double tile_size,
                                         size_t cache_tiles) {
  if (directory.empty()) throw std::invalid_argument("iwlomap: OutofcoreTileMapper needs a map directory, got an empty path");
  // kStored: the stored value of a map that exists, the default of a new one.
  if (resolution == kStored || tile_size == kStored) {
    const bool exists = detail::holds_map(directory);
    const DiskMapInfo info = exists ? read_map_info(directory) : DiskMapInfo{};
    if (resolution == kStored) resolution = exists ? info.resolution : kDefaultResolution;
    if (tile_size == kStored) tile_size = exists ? info.tile_size : kDefaultTileSize;
  }
  detail::check_resolution(resolution);
  if (cache_tiles < 1) throw std::invalid_argument("iwlomap: cache_tiles must be >= 1, got cache_tiles = 0");
  impl_ = std::make_unique<Impl>(directory, resolution, tile_size, cache_tiles);
}

OutofcoreTileMapper::OutofcoreTileMapper(std::unique_ptr<Impl> impl) { impl_ = std::move(impl); }

OutofcoreTileMapper OutofcoreTileMapper::open_read_only(const std::string& directory, size_t cache_tiles) {
  if (cache_tiles < 1) throw std::invalid_argument("iwlomap: cache_tiles must be >= 1, got cache_tiles = 0");
  const DiskMapInfo info = read_map_info(directory);
  return OutofcoreTileMapper(std::make_unique<Impl>(directory, info.resolution, info.tile_size, cache_tiles, true));
}

bool OutofcoreTileMapper::is_read_only() const { return impl().dir.read_only(); }

IWLOMAP_DEFINE_PIMPL_MEMBERS(OutofcoreTileMapper)

void OutofcoreTileMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                            const std::vector<bool>& is_occupied) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("batch_update_iwlo()");
  m.apply_batch(points, intensities, is_occupied, nullptr);
}

void OutofcoreTileMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                            const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("batch_update_iwlo()");
  m.apply_batch(points, intensities, is_occupied, &weights);
}

void OutofcoreTileMapper::insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                      const Eigen::VectorXd& intensities, double max_range) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("insert_scan()");
  m.insert_scan(origin, points, intensities, max_range, get_ray_model(), get_num_threads(), &get_progress_callback(),
                last_scan_phases());
}

void OutofcoreTileMapper::set_params(const IwloParams& params) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("set_params()");
  m.set_params(params);
}
void OutofcoreTileMapper::modify_params(const std::function<void(IwloParams&)>& change) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("modify_params()");
  IwloParams p = m.updater.params();
  change(p);
  m.set_params(p);
}

void OutofcoreTileMapper::set_hit_accumulation(bool enabled) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("set_hit_accumulation()");
  m.set_hit_accumulation(enabled);
}

bool OutofcoreTileMapper::get_hit_accumulation() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.hit_settings.enabled;
}

std::optional<HitStatistics> OutofcoreTileMapper::hit_statistics(const Eigen::Vector3d& point) const {
  (void)impl();
  Impl& m = *impl_;  // may load a tile, as query() does
  const VoxelKey key = world_to_key_checked(point, m.resolution);
  std::lock_guard<std::mutex> lock(m.mutex);
  if (!m.hit_settings.enabled)
    throw std::logic_error("iwlomap: hit_statistics() needs hit accumulation, which is off (set_hit_accumulation(true))");
  const detail::Tile* tile = m.resident_tile(m.routing.tile_of_voxel(key));
  return tile != nullptr ? tile->hits->statistics(key) : std::nullopt;
}

Eigen::MatrixXd OutofcoreTileMapper::get_occupied_mean_positions(double min_probability) {
  const double threshold = detail::resolve_min_probability(min_probability);
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  if (!m.hit_settings.enabled)
    throw std::logic_error(
        "iwlomap: get_occupied_mean_positions() needs hit accumulation, which is off (set_hit_accumulation(true))");
  // get_occupied_voxels()'s walk (tiles in key order), each tile with its statistics.
  std::vector<double> rows;
  for (const VoxelKey& k : m.all_tiles()) {
    const detail::Tile* t = m.cache.find(k);
    std::unique_ptr<detail::Tile> loaded;
    if (t == nullptr) {
      loaded = m.cache.load(k);
      t = loaded.get();
    }
    const std::vector<double> tile_rows = detail::occupied_rows(
        [t](auto&& fn) { detail::for_each_known(t->grid, fn); }, m.updater.format(), threshold,
        [t](const VoxelKey& key) { return t->hits->mean_position(key); });
    rows.insert(rows.end(), tile_rows.begin(), tile_rows.end());
  }
  return detail::rows_to_matrix(rows);
}

std::unique_ptr<IMapperBackend> OutofcoreTileMapper::clone() const {
  throw std::logic_error("iwlomap: the Disk backend's map lives in its directory and is not copied in RAM; "
                         "OutofcoreTileMapper::copy_to() copies it to another directory");
}

bool OutofcoreTileMapper::supports(BackendFeature feature) const { return feature != BackendFeature::kClone; }

IwloParams OutofcoreTileMapper::get_params() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.updater.params();
}

void OutofcoreTileMapper::set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("set_log_odds()");
  m.set_log_odds(points, log_odds);
}

Eigen::MatrixXd OutofcoreTileMapper::get_occupied_voxels(double min_probability) const {
  const double threshold = detail::resolve_min_probability(min_probability);
  // Reads tiles that are not resident through the cache's buffers (not observable state), as
  // query() does.
  (void)impl();
  Impl& m = *impl_;
  std::lock_guard<std::mutex> lock(m.mutex);
  return detail::rows_to_matrix(
      detail::occupied_rows([&m](auto&& fn) { m.for_each_known(fn); }, m.updater.format(), threshold,
                            [&m](const VoxelKey& k) { return key_to_center(k, m.resolution); }));
}

std::optional<VoxelState> OutofcoreTileMapper::query(const Eigen::Vector3d& point) const {
  // The cache is not part of the observable state: a query may load a tile into it, so it works
  // on the non-const Impl (impl() only checks for a moved-from object).
  (void)impl();
  Impl& m = *impl_;
  const VoxelKey key = world_to_key_checked(point, m.resolution);
  std::lock_guard<std::mutex> lock(m.mutex);
  const detail::Tile* tile = m.resident_tile(m.routing.tile_of_voxel(key));
  if (tile == nullptr) return std::nullopt;
  return detail::query_voxel(tile->grid, m.updater.format(), key);
}

void OutofcoreTileMapper::for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const {
  (void)impl();
  Impl& m = *impl_;
  std::lock_guard<std::mutex> lock(m.mutex);
  const iwlo::VoxelFormat& f = m.updater.format();
  m.for_each_known([&](const VoxelKey& key, const detail::Voxel& v) { visit(key, detail::state_of(v, f)); });
}

void detail::BackendAccess::apply_to_disk(OutofcoreTileMapper& map, const ScanScratch& scratch) {
  OutofcoreTileMapper::Impl& m = map.impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("insert_scan()");
  std::exception_ptr deferred;
  m.apply_collected(scratch, map.get_num_threads(), &map.get_progress_callback(), deferred);
  if (deferred) std::rethrow_exception(deferred);
}

void detail::BackendAccess::for_each_known_block_disk(const OutofcoreTileMapper& map, const KnownBlockVisit& visit) {
  (void)map.impl();
  OutofcoreTileMapper::Impl& m = *map.impl_;
  std::lock_guard<std::mutex> lock(m.mutex);
  auto group = std::make_unique<detail::KnownBlockGrouper>(visit);
  const iwlo::VoxelFormat& f = m.updater.format();
  m.for_each_known([&group, &f](const VoxelKey& key, const detail::Voxel& v) { group->add(key, f.log_odds(v.word)); });
  group->finish();
}

MemoryStats OutofcoreTileMapper::get_memory_usage() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  std::size_t bytes = sizeof(Impl) + m.scratch.bytes() + m.batch.capacity() * sizeof(detail::Observation) +
                      m.routing.bytes() + m.io_buffer.capacity() + m.cache.buffer_bytes() +
                      m.cache.resident().capacity() * sizeof(m.cache.resident()[0]);
  // The index: a node per tile (key, info, next pointer, cached hash) and the bucket array.
  bytes += m.store.images().size() * (sizeof(std::pair<const VoxelKey, detail::TileImage>) + 2 * sizeof(void*)) +
           m.store.images().bucket_count() * sizeof(void*);
  std::size_t slots = 0, resident_known = 0;
  for (const auto& t : m.cache.resident()) {
    bytes += sizeof(detail::Tile) + t->grid.bytes() + (t->hits ? t->hits->bytes() : 0);
    slots += t->grid.num_slots();
    resident_known += t->grid.known_voxels();
  }
  return MemoryStats{m.total_known, m.total_known, static_cast<double>(bytes) / (1024.0 * 1024.0),
                     slots == 0 ? 0.0 : static_cast<double>(resident_known) / static_cast<double>(slots)};
}

double OutofcoreTileMapper::get_resolution() const { return impl().resolution; }

size_t OutofcoreTileMapper::get_num_nodes() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.total_known;
}

size_t OutofcoreTileMapper::get_num_skipped_points() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.skipped;
}

void OutofcoreTileMapper::clear() {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.check_writable("clear()");
  m.clear();
}

void OutofcoreTileMapper::flush() {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.flush(&get_progress_callback());
}

void OutofcoreTileMapper::preload_region(const Eigen::Vector3d& min_bound, const Eigen::Vector3d& max_bound) {
  if (!min_bound.allFinite() || !max_bound.allFinite())
    throw std::invalid_argument("iwlomap: preload_region needs finite bounds, got min (" + std::to_string(min_bound.x()) +
                                ", " + std::to_string(min_bound.y()) + ", " + std::to_string(min_bound.z()) + ") max (" +
                                std::to_string(max_bound.x()) + ", " + std::to_string(max_bound.y()) + ", " +
                                std::to_string(max_bound.z()) + ")");
  for (int a = 0; a < 3; ++a)
    if (min_bound[a] > max_bound[a])
      throw std::invalid_argument("iwlomap: preload_region needs min <= max on every axis, got " +
                                  detail::describe("min", min_bound[a]) + " > " + detail::describe("max", max_bound[a]) +
                                  " on axis " + std::to_string(a));
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  // Tile range in doubles: floor(floor(x / r) / edge) is exact for any key, and never overflows.
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::floor(std::floor(min_bound[a] / m.resolution) / m.tile_voxels);
    hi[a] = std::floor(std::floor(max_bound[a] / m.resolution) / m.tile_voxels);
  }
  std::vector<VoxelKey> keys;
  for (const VoxelKey& k : m.all_tiles()) {
    const double t[3] = {static_cast<double>(k.x), static_cast<double>(k.y), static_cast<double>(k.z)};
    if (t[0] >= lo[0] && t[0] <= hi[0] && t[1] >= lo[1] && t[1] <= hi[1] && t[2] >= lo[2] && t[2] <= hi[2])
      keys.push_back(k);
  }
  std::sort(keys.begin(), keys.end());
  if (keys.size() > m.cache.capacity()) keys.resize(m.cache.capacity());
  std::vector<detail::Tile*> out;
  detail::TileCache::PinScope pins(m.cache);
  m.cache.make_resident(keys, out);
}

size_t OutofcoreTileMapper::get_disk_usage() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return static_cast<size_t>(m.store.committed_bytes() + m.store.staging_bytes() + m.store.manifest_bytes() +
                             m.dir.meta_bytes());
}

size_t OutofcoreTileMapper::prune() {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.release_buffers();
  return m.cache.prune();
}

std::string OutofcoreTileMapper::get_directory() const { return impl().dir.path(); }
double OutofcoreTileMapper::get_tile_size() const { return impl().tile_size; }
size_t OutofcoreTileMapper::get_tile_voxels() const { return impl().tile_voxels; }
size_t OutofcoreTileMapper::get_cache_tiles() const { return impl().cache.capacity(); }

size_t OutofcoreTileMapper::get_num_resident_tiles() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.cache.resident().size();
}
size_t OutofcoreTileMapper::get_num_tiles() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.all_tiles().size();
}
size_t OutofcoreTileMapper::get_peak_resident_tiles() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.cache.peak();
}

void OutofcoreTileMapper::copy_to(const std::string& directory) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.flush();
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(directory, ec);
  if (ec || !fs::is_directory(directory))
    throw StorageError(StorageError::Kind::kIo, directory,
                       "iwlomap: cannot copy the map to " + directory + ": " +
                           (ec ? ec.message() : std::string("it exists and is not a directory")));
  if (fs::exists(fs::path(directory) / "iwlomap_map.meta", ec))
    throw StorageError(StorageError::Kind::kIo, directory,
                       "iwlomap: cannot copy the map to " + directory + ": it already holds a map");
  // Tiles, then the manifest, the metadata last: until it is there, the copy is not a map.
  const detail::MapManifest manifest = m.store.committed_manifest();
  const auto copy = [&](const std::string& name, const std::vector<std::uint8_t>& bytes) {
    const std::string to = (fs::path(directory) / name).string();
    detail::write_file_durably(to + detail::kTempSuffix, to, bytes);
  };
  for (const detail::ManifestTile& t : manifest.tiles) {
    const std::string name = detail::tile_file_name(t.key, t.generation);
    copy(name, detail::read_file(m.dir.path_of(name)));
  }
  if (m.store.manifest_bytes() != 0) copy(detail::kManifestName, detail::encode_manifest(manifest));
  copy("iwlomap_map.meta", detail::read_file(m.dir.path_of("iwlomap_map.meta")));
  detail::sync_directory(directory);
}

void OutofcoreTileMapper::rollback() {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.rollback();
}

DiskMapRepair OutofcoreTileMapper::repair(const std::string& directory) {
  const DiskMapInfo info = read_map_info(directory);
  const std::uint32_t tile_voxels = static_cast<std::uint32_t>(info.tile_voxels);
  detail::MapDirectory dir(directory, info.resolution, info.tile_size, tile_voxels);
  detail::TileStore store(dir, info.resolution, tile_voxels, detail::state_of(dir.meta()), true);
  dir.remove_leftovers();
  DiskMapRepair result;
  result.set_aside = store.set_aside_damaged();
  result.tiles_kept = store.images().size();
  store.remove_retired();
  return result;
}

DiskMapInfo OutofcoreTileMapper::read_map_info(const std::string& directory) {
  const detail::MapMeta m = detail::MapDirectory::read_meta(directory);
  return DiskMapInfo{m.resolution, m.tile_size, m.tile_voxels, m.version};
}

}  // namespace iwlomap
