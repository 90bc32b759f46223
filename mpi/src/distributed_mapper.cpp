// SPDX-License-Identifier: BSD-3-Clause
// DistributedMapper: rays cast where the scan is, observations applied where the voxel lives.

#include "iwlomap/mpi/distributed_mapper.h"

#include "backends/backend_access.h"
#include "backends/disk/map_directory.h"
#include "backends/disk/tile_file.h"
#include "integrate/batch_input.h"
#include "integrate/scan_scratch.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "manifest.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <climits>
#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>

namespace iwlomap::mpi {

namespace fs = std::filesystem;

DistributedError::DistributedError(int rank, const std::string& message)
    : std::runtime_error("rank " + std::to_string(rank) + ": " + message), rank_(rank) {}

namespace {

// After a step that may have failed on some ranks (an empty \p error: this rank's step went well),
// every rank learns whether any failed; if so all throw DistributedError with the lowest failed
// rank's message. One MPI_Allreduce when nothing failed.
void agree(MPI_Comm comm, int rank, const std::string& error) {
  const int mine = error.empty() ? INT_MAX : rank;
  int first = INT_MAX;
  MPI_Allreduce(&mine, &first, 1, MPI_INT, MPI_MIN, comm);
  if (first == INT_MAX) return;
  int length = rank == first ? static_cast<int>(error.size()) : 0;
  MPI_Bcast(&length, 1, MPI_INT, first, comm);
  std::string message = rank == first ? error : std::string(static_cast<std::size_t>(length), '\0');
  MPI_Bcast(message.data(), length, MPI_CHAR, first, comm);
  throw DistributedError(first, message);
}

// Runs \p step, turning an exception into its message (empty: no error).
template <class Step>
std::string attempt(Step&& step) {
  try {
    step();
    return {};
  } catch (const std::exception& e) {
    return e.what()[0] != '\0' ? e.what() : "unnamed error";
  } catch (...) {
    return "unknown exception";
  }
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::string rank_directory(const std::string& directory, int rank) {
  return (fs::path(directory) / ("rank-" + std::to_string(rank))).string();
}

// Counts (bytes) and displacements of one MPI_Alltoallv / MPI_Gatherv, checked against int.
std::vector<int> to_int_counts(const std::vector<std::uint64_t>& bytes, const char* what) {
  std::vector<int> out(bytes.size());
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    if (bytes[i] > static_cast<std::uint64_t>(INT_MAX))
      throw std::length_error(std::string("iwlomap::mpi: ") + what + " of " + std::to_string(bytes[i]) +
                              " bytes to or from one rank exceeds MPI's 2 GiB count limit; use smaller scans");
    out[i] = static_cast<int>(bytes[i]);
  }
  return out;
}

std::vector<int> displacements(const std::vector<int>& counts) {
  std::vector<int> d(counts.size(), 0);
  std::uint64_t total = 0;
  for (std::size_t i = 0; i < counts.size(); ++i) {
    if (total > static_cast<std::uint64_t>(INT_MAX))
      throw std::length_error("iwlomap::mpi: more than 2 GiB in one exchange; use smaller scans");
    d[i] = static_cast<int>(total);
    total += static_cast<std::uint64_t>(counts[i]);
  }
  if (total > static_cast<std::uint64_t>(INT_MAX))
    throw std::length_error("iwlomap::mpi: more than 2 GiB in one exchange; use smaller scans");
  return d;
}

// Gathers each rank's bytes on root (concatenated in rank order); \p sizes (when given) receives
// each rank's byte count on root.
std::vector<char> gather_bytes(MPI_Comm comm, int root, int rank, int size, const std::vector<char>& mine,
                               std::vector<std::uint64_t>* sizes_out = nullptr) {
  const std::uint64_t n = mine.size();
  std::vector<std::uint64_t> sizes(static_cast<std::size_t>(size));
  MPI_Gather(&n, 1, MPI_UINT64_T, sizes.data(), 1, MPI_UINT64_T, root, comm);
  std::vector<int> counts, displs;
  std::vector<char> all;
  std::string error;
  if (rank == root) error = attempt([&] {
      counts = to_int_counts(sizes, "gathering");
      displs = displacements(counts);
      all.resize(static_cast<std::size_t>(displs.back()) + static_cast<std::size_t>(counts.back()));
    });
  agree(comm, rank, rank == root ? error : std::string());
  // (n <= INT_MAX here: root checked every rank's size above.)
  MPI_Gatherv(mine.data(), static_cast<int>(n), MPI_BYTE, all.data(), counts.data(), displs.data(), MPI_BYTE, root,
              comm);
  if (sizes_out != nullptr) *sizes_out = std::move(sizes);
  return all;
}

}  // namespace

VoxelKey tile_of_voxel(const VoxelKey& voxel, std::uint32_t tile_voxels) noexcept {
  const auto e = static_cast<std::int32_t>(tile_voxels);
  return {detail::floor_div(voxel.x, e), detail::floor_div(voxel.y, e), detail::floor_div(voxel.z, e)};
}

int owner_of_tile(const VoxelKey& tile, int ranks) noexcept {
  if (ranks <= 1) return 0;
  // splitmix64 finaliser over the packed coordinates: neighbouring tiles land on unrelated ranks,
  // so each scan's tiles spread evenly over the ranks.
  std::uint64_t h = (static_cast<std::uint64_t>(static_cast<std::uint32_t>(tile.x)) * 0x9E3779B97F4A7C15ULL) ^
                    (static_cast<std::uint64_t>(static_cast<std::uint32_t>(tile.y)) * 0xC2B2AE3D27D4EB4FULL) ^
                    (static_cast<std::uint64_t>(static_cast<std::uint32_t>(tile.z)) * 0x165667B19E3779F9ULL);
  h ^= h >> 30;
  h *= 0xBF58476D1CE4E5B9ULL;
  h ^= h >> 27;
  h *= 0x94D049BB133111EBULL;
  h ^= h >> 31;
  return static_cast<int>(h % static_cast<std::uint64_t>(ranks));
}

// On the wire, per destination: three counts (free blocks, hits, ordered records), the kind of the
// sender's part of the round and a scan part's origin and max_range, then the three sections. A
// scan's free voxels travel as 8^3 blocks with a 512-bit mask (80 bytes for up to 512 voxels; a
// ray-cast block holds tens of free voxels, so this is several times smaller than a record per
// voxel); its hits and a batch's observations as records, a batch's in call order.
struct DistributedMapper::Record {
  std::int32_t x, y, z;
  std::int32_t occupied;
  double intensity;
};
struct DistributedMapper::FreeBlock {
  std::int32_t x, y, z;  // block key (voxel key >> 3)
  std::int32_t unused;
  std::uint64_t cells[8];  // bit i: voxel_of(block, i) is free
};
// What a rank contributes to a round; every owner gets the kind, also with nothing else.
enum class DistributedMapper::Kind : std::uint64_t { kScan = 0, kBatch = 1, kPass = 2, kScanPart = 3 };
struct DistributedMapper::Outgoing {
  Kind kind = Kind::kPass;
  double origin[3] = {0.0, 0.0, 0.0};  // a scan part's origin and max_range, which all parts share
  double max_range = 0.0;
  std::vector<FreeBlock> blocks;
  std::vector<Record> hits;
  std::vector<Record> records;
  [[nodiscard]] std::uint64_t bytes() const noexcept {
    return 4 * sizeof(std::uint64_t) + 4 * sizeof(double) + blocks.size() * sizeof(FreeBlock) +
           (hits.size() + records.size()) * sizeof(Record);
  }
};

DistributedMapper::DistributedMapper(MPI_Comm comm, double resolution, const IwloParams& params,
                                     DistributedOptions options)
    : comm_(comm), resolution_(resolution), options_(std::move(options)),
      scratch_(std::make_unique<detail::ScanScratch>()) {
  static_assert(sizeof(Record) == 24 && sizeof(FreeBlock) == 80, "sent as bytes");
  MPI_Comm_rank(comm_, &rank_);
  MPI_Comm_size(comm_, &size_);
  const std::string backend = lower(options_.backend);
  std::string error = attempt([&] {
    if (!(std::isfinite(resolution) && resolution > 0.0))
      throw std::invalid_argument("iwlomap::mpi: resolution must be finite and > 0, got " + std::to_string(resolution));
    params.validate();
    if (options_.threads < 1)
      throw std::invalid_argument("iwlomap::mpi: threads must be >= 1, got " + std::to_string(options_.threads));
    if (options_.cache_tiles < 1) throw std::invalid_argument("iwlomap::mpi: cache_tiles must be >= 1");
    if (options_.tile_size < 0.0 || !std::isfinite(options_.tile_size))
      throw std::invalid_argument("iwlomap::mpi: tile_size must be >= 0 (0: the default), got " +
                                  std::to_string(options_.tile_size));
    if (options_.tile_size > 0.0)
      tile_voxels_ = detail::tile_voxels_for(resolution, options_.tile_size);
    else
      tile_voxels_ = backend == "disk" ? detail::tile_voxels_for(resolution, kDiskShardSize) : 8;
    if (backend == "ram") {
      local_ = make_backend("RAM", resolution);
    } else if (backend == "disk") {
      if (options_.directory.empty()) throw std::invalid_argument("iwlomap::mpi: the Disk backend needs a directory");
      const fs::path manifest = fs::path(options_.directory) / kManifestName;
      std::error_code ec;
      if (fs::exists(manifest, ec)) {
        const DistributedManifest m = read_manifest(options_.directory);
        if (m.ranks != size_)
          throw std::invalid_argument("iwlomap::mpi: " + manifest.string() + " holds a map of " +
                                      std::to_string(m.ranks) + " ranks; this job has " + std::to_string(size_) +
                                      " (merge_distributed_map() and split_map() change the number)");
      }
      const double tile = static_cast<double>(tile_voxels_) * resolution;
      local_ = std::make_unique<OutofcoreTileMapper>(rank_directory(options_.directory, rank_), resolution, tile,
                                                    options_.cache_tiles);
    } else {
      throw std::invalid_argument("iwlomap::mpi: backend must be RAM or Disk, got '" + options_.backend + "'");
    }
    local_->set_params(params);
    local_->set_num_threads(options_.threads);
  });
  agree(comm_, rank_, error);
  // A map reopened from disk keeps what it holds: the manifest of this set of shards is written
  // by the first flush().
}

DistributedMapper::~DistributedMapper() = default;

int DistributedMapper::owner_of_voxel(const VoxelKey& key) const noexcept {
  return owner_of_tile(tile_of_voxel(key, tile_voxels_), size_);
}

namespace {
double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}
}  // namespace

void DistributedMapper::insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                    const Eigen::VectorXd& intensities, double max_range) {
  cast_and_apply(origin, points, intensities, max_range, Kind::kScan);
}

void DistributedMapper::insert_scan_part(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                         const Eigen::VectorXd& intensities, double max_range) {
  cast_and_apply(origin, points, intensities, max_range, Kind::kScanPart);
}

void DistributedMapper::cast_and_apply(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                       const Eigen::VectorXd& intensities, double max_range, Kind kind) {
  const auto started = std::chrono::steady_clock::now();
  std::vector<Outgoing> outgoing(static_cast<std::size_t>(size_));
  for (Outgoing& o : outgoing) {
    o.kind = kind;
    o.origin[0] = origin.x();
    o.origin[1] = origin.y();
    o.origin[2] = origin.z();
    o.max_range = max_range;
  }
  std::size_t skipped = 0;
  const std::string error = attempt([&] {
    detail::check_scan_input(origin, points, intensities, max_range, resolution_);
    detail::ScanScratch& scratch = *scratch_;
    skipped = scratch.collect(origin, points, intensities, max_range, resolution_, options_.rays, options_.threads);
    // for_each_free() calls each block's voxels one after another.
    FreeBlock current{};
    bool open = false;
    const auto close = [&] {
      if (!open) return;
      const VoxelKey first_voxel = detail::voxel_of({current.x, current.y, current.z}, 0);
      outgoing[static_cast<std::size_t>(owner_of_voxel(first_voxel))].blocks.push_back(current);
    };
    scratch.for_each_free(0, scratch.num_chunks(), [&](const VoxelKey& block_key, int index) {
      if (!open || block_key.x != current.x || block_key.y != current.y || block_key.z != current.z) {
        close();
        current = FreeBlock{block_key.x, block_key.y, block_key.z, 0, {}};
        open = true;
      }
      current.cells[index >> 6] |= std::uint64_t{1} << (index & 63);
    });
    close();
    scratch.for_each_hit([&](const VoxelKey& key, double intensity) {
      outgoing[static_cast<std::size_t>(owner_of_voxel(key))].hits.push_back({key.x, key.y, key.z, 1, intensity});
    });
  });
  stats_.cast_seconds += seconds_since(started);
  agree(comm_, rank_, error);
  skipped_ += skipped;
  exchange_and_apply(outgoing);
}

void DistributedMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                          const std::vector<bool>& is_occupied) {
  std::vector<Outgoing> outgoing(static_cast<std::size_t>(size_));
  for (Outgoing& o : outgoing) o.kind = Kind::kBatch;
  std::size_t skipped = 0;
  const std::string error = attempt([&] {
    skipped = detail::validate_batch(points, intensities, is_occupied, nullptr, resolution_);
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
      const Eigen::Vector3d p = points.row(i).transpose();
      if (!p.allFinite() || !std::isfinite(intensities[i])) continue;
      const VoxelKey k = world_to_key(p, resolution_);
      outgoing[static_cast<std::size_t>(owner_of_voxel(k))].records.push_back(
          {k.x, k.y, k.z, is_occupied[static_cast<std::size_t>(i)] ? 1 : 0, intensities[i]});
    }
  });
  agree(comm_, rank_, error);
  skipped_ += skipped;
  exchange_and_apply(outgoing);
}

void DistributedMapper::pass() {
  agree(comm_, rank_, {});
  std::vector<Outgoing> outgoing(static_cast<std::size_t>(size_));
  exchange_and_apply(outgoing);
}

namespace {

template <class T>
void put(std::vector<char>& out, std::size_t& at, const std::vector<T>& items) {
  if (!items.empty()) std::memcpy(out.data() + at, items.data(), items.size() * sizeof(T));
  at += items.size() * sizeof(T);
}

}  // namespace

void DistributedMapper::exchange_and_apply(std::vector<Outgoing>& outgoing) {
  const auto started = std::chrono::steady_clock::now();
  ++stats_.rounds;
  const std::size_t n = static_cast<std::size_t>(size_);
  std::vector<std::uint64_t> send_bytes(n), recv_bytes(n);
  for (std::size_t r = 0; r < n; ++r) send_bytes[r] = outgoing[r].bytes();
  MPI_Alltoall(send_bytes.data(), 1, MPI_UINT64_T, recv_bytes.data(), 1, MPI_UINT64_T, comm_);
  std::vector<int> sc, sd, rc, rd;
  std::vector<char> send, recv;
  agree(comm_, rank_, attempt([&] {
          sc = to_int_counts(send_bytes, "a round's observations");
          rc = to_int_counts(recv_bytes, "a round's observations");
          sd = displacements(sc);
          rd = displacements(rc);
          send.resize(static_cast<std::size_t>(sd.back()) + static_cast<std::size_t>(sc.back()));
          recv.resize(static_cast<std::size_t>(rd.back()) + static_cast<std::size_t>(rc.back()));
        }));
  for (std::size_t r = 0; r < n; ++r) {
    Outgoing& o = outgoing[r];
    std::size_t at = static_cast<std::size_t>(sd[r]);
    const std::uint64_t counts[4] = {o.blocks.size(), o.hits.size(), o.records.size(), static_cast<std::uint64_t>(o.kind)};
    std::memcpy(send.data() + at, counts, sizeof counts);
    at += sizeof counts;
    const double where[4] = {o.origin[0], o.origin[1], o.origin[2], o.max_range};
    std::memcpy(send.data() + at, where, sizeof where);
    at += sizeof where;
    put(send, at, o.blocks);
    put(send, at, o.hits);
    put(send, at, o.records);
    if (static_cast<int>(r) != rank_) stats_.bytes_sent += send_bytes[r];
    o = Outgoing{};
  }
  MPI_Alltoallv(send.data(), sc.data(), sd.data(), MPI_BYTE, recv.data(), rc.data(), rd.data(), MPI_BYTE, comm_);
  std::vector<char>().swap(send);
  const auto received = std::chrono::steady_clock::now();
  stats_.exchange_seconds += std::chrono::duration<double>(received - started).count();

  // The sources in rank order (= scan order). A scan is rebuilt into a scan scratch (its free
  // blocks, its hits) and applied; a round of scan parts merges every source into one scratch
  // first (OR of the free bits, the largest intensity per hit voxel, occupied over free: the
  // per-scan rule across the parts), then applies it once; a batch's records go in order.
  agree(comm_, rank_, attempt([&] {
          struct Source {
            const char* blocks;
            const char* hits;
            const char* records;
            std::uint64_t n_blocks, n_hits, n_records;
            Kind kind;
            double where[4];  // a scan part's origin and max_range
          };
          std::vector<Source> sources(n);
          bool parts = false, wholes = false;
          for (std::size_t r = 0; r < n; ++r) {
            const char* at = recv.data() + rd[r];
            std::uint64_t counts[4];
            std::memcpy(counts, at, sizeof counts);
            at += sizeof counts;
            Source& src = sources[r];
            std::memcpy(src.where, at, sizeof src.where);
            at += sizeof src.where;
            src.blocks = at;
            src.hits = at + counts[0] * sizeof(FreeBlock);
            src.records = src.hits + counts[1] * sizeof(Record);
            src.n_blocks = counts[0];
            src.n_hits = counts[1];
            src.n_records = counts[2];
            src.kind = static_cast<Kind>(counts[3]);
            parts = parts || src.kind == Kind::kScanPart;
            wholes = wholes || src.kind == Kind::kScan || src.kind == Kind::kBatch;
          }
          if (parts && wholes)
            throw std::logic_error("iwlomap::mpi: in one round some ranks called insert_scan_part() and others "
                                   "insert_scan() or batch_update_iwlo(); a round holds one kind (pass() goes with any)");
          // Every owner sees every part's origin: all reach the same verdict.
          const Source* first = nullptr;
          for (const Source& src : sources) {
            if (src.kind != Kind::kScanPart) continue;
            if (first == nullptr) first = &src;
            for (int i = 0; i < 4; ++i)
              if (!(src.where[i] == first->where[i]))
                throw std::invalid_argument(std::string("iwlomap::mpi: insert_scan_part(): the ranks passed different ") +
                                            (i < 3 ? "origins" : "max_range values") +
                                            "; one scan's parts share its origin and max_range");
          }

          const auto add_to_scratch = [&](const Source& src) {
            for (std::uint64_t i = 0; i < src.n_blocks; ++i) {
              FreeBlock b;
              std::memcpy(&b, src.blocks + i * sizeof(FreeBlock), sizeof b);
              scratch_->add_free_cells({b.x, b.y, b.z}, b.cells);
            }
            for (std::uint64_t i = 0; i < src.n_hits; ++i) {
              Record rec;
              std::memcpy(&rec, src.hits + i * sizeof(Record), sizeof rec);
              scratch_->add_hit({rec.x, rec.y, rec.z}, rec.intensity);
            }
          };
          // The backend applies a rebuilt scratch as its own insert_scan() would (a RAM shard
          // through its scan path, about 3x faster than a batch row per voxel).
          if (parts) {
            scratch_->reset();
            for (const Source& src : sources) add_to_scratch(src);
            detail::BackendAccess::apply_collected_scan(*local_, *scratch_);
            return;
          }
          for (const Source& src : sources) {
            if (src.kind == Kind::kScan && src.n_blocks + src.n_hits > 0) {
              scratch_->reset();
              add_to_scratch(src);
              detail::BackendAccess::apply_collected_scan(*local_, *scratch_);
            } else if (src.kind == Kind::kBatch && src.n_records > 0) {
              // A batch in its call order, one backend call (the sender held it whole too).
              const auto rows = static_cast<Eigen::Index>(src.n_records);
              Eigen::MatrixXd centres(rows, 3);
              Eigen::VectorXd values(rows);
              std::vector<bool> flags(static_cast<std::size_t>(rows));
              for (Eigen::Index i = 0; i < rows; ++i) {
                Record rec;
                std::memcpy(&rec, src.records + static_cast<std::size_t>(i) * sizeof(Record), sizeof rec);
                centres.row(i) = key_to_center({rec.x, rec.y, rec.z}, resolution_).transpose();
                values[i] = rec.intensity;
                flags[static_cast<std::size_t>(i)] = rec.occupied != 0;
              }
              local_->batch_update_iwlo(centres, values, flags);
            }
          }
        }));
  stats_.apply_seconds += seconds_since(received);
}

std::vector<std::pair<VoxelKey, VoxelState>> DistributedMapper::gather_voxels(int root) const {
  // A voxel travels as its key and its 4-byte word: every rank stores the same voxel format (the
  // same parameters), and the word holds the state exactly.
  struct Packed {
    std::int32_t x, y, z;
    std::uint32_t word;
  };
  static_assert(sizeof(Packed) == 16, "Packed is sent as bytes");
  const iwlo::VoxelFormat format = iwlo::voxel_format(local_->get_params());
  std::vector<char> mine;
  agree(comm_, rank_, attempt([&] {
          if (root < 0 || root >= size_) throw std::invalid_argument("iwlomap::mpi: root " + std::to_string(root) + " is not a rank");
          local_->for_each_voxel([&](const VoxelKey& k, const VoxelState& s) {
            const Packed p{k.x, k.y, k.z, format.encode_kept(s.log_odds, s.count)};
            const auto* b = reinterpret_cast<const char*>(&p);
            mine.insert(mine.end(), b, b + sizeof p);
          });
        }));
  const std::vector<char> all = gather_bytes(comm_, root, rank_, size_, mine);
  std::vector<std::pair<VoxelKey, VoxelState>> out;
  if (rank_ != root) return out;
  out.reserve(all.size() / sizeof(Packed));
  for (std::size_t off = 0; off + sizeof(Packed) <= all.size(); off += sizeof(Packed)) {
    Packed p;
    std::memcpy(&p, all.data() + off, sizeof p);
    VoxelState s;
    s.log_odds = format.log_odds(p.word);
    s.probability = iwlo::probability(s.log_odds);
    s.count = format.count(p.word);
    out.emplace_back(VoxelKey{p.x, p.y, p.z}, s);
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  return out;
}

Eigen::MatrixXd DistributedMapper::gather_occupied_voxels(double min_probability, int root) {
  Eigen::MatrixXd local;
  agree(comm_, rank_, attempt([&] {
          if (root < 0 || root >= size_) throw std::invalid_argument("iwlomap::mpi: root " + std::to_string(root) + " is not a rank");
          local = local_->get_occupied_voxels(min_probability);
        }));
  // Rows as (x, y, z, p) doubles, row-major on the wire.
  using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor>;
  const RowMajor rows_local = local;
  const auto* first = reinterpret_cast<const char*>(rows_local.data());
  const std::vector<char> mine(first, first + rows_local.size() * static_cast<Eigen::Index>(sizeof(double)));
  const std::vector<char> all = gather_bytes(comm_, root, rank_, size_, mine);
  if (rank_ != root) return Eigen::MatrixXd(0, 4);
  RowMajor v(static_cast<Eigen::Index>(all.size() / (4 * sizeof(double))), 4);
  if (!all.empty()) std::memcpy(v.data(), all.data(), all.size());
  std::vector<std::pair<VoxelKey, Eigen::Index>> order(static_cast<std::size_t>(v.rows()));
  for (Eigen::Index i = 0; i < v.rows(); ++i)
    order[static_cast<std::size_t>(i)] = {world_to_key(v.row(i).head<3>().transpose(), resolution_), i};
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  Eigen::MatrixXd out(v.rows(), 4);
  for (std::size_t i = 0; i < order.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = v.row(order[i].second);
  return out;
}

std::size_t DistributedMapper::num_nodes() const {
  const std::uint64_t mine = local_->get_num_known_voxels();
  std::uint64_t total = 0;
  MPI_Allreduce(&mine, &total, 1, MPI_UINT64_T, MPI_SUM, comm_);
  return static_cast<std::size_t>(total);
}

std::size_t DistributedMapper::num_skipped_points() const {
  const std::uint64_t mine = skipped_;
  std::uint64_t total = 0;
  MPI_Allreduce(&mine, &total, 1, MPI_UINT64_T, MPI_SUM, comm_);
  return static_cast<std::size_t>(total);
}

void DistributedMapper::flush() {
  if (lower(options_.backend) != "disk") {
    agree(comm_, rank_, {});
    return;
  }
  // Each rank's shard first (durable, as the Disk backend's flush()), then the manifest from the
  // tile lists: a manifest never names a tile that its shard has not written.
  std::string names;
  agree(comm_, rank_, attempt([&] {
          local_->flush();
          for (const std::string& t : committed_tile_files(rank_directory(options_.directory, rank_))) names += t + "\n";
        }));
  std::vector<std::uint64_t> lengths;  // where each rank's list ends
  const std::vector<char> all =
      gather_bytes(comm_, 0, rank_, size_, std::vector<char>(names.begin(), names.end()), &lengths);
  agree(comm_, rank_, attempt([&] {
          if (rank_ != 0) return;
          DistributedManifest m;
          m.ranks = size_;
          m.resolution = resolution_;
          m.tile_voxels = tile_voxels_;
          m.tile_size = static_cast<double>(tile_voxels_) * resolution_;
          std::size_t off = 0;
          for (int r = 0; r < size_; ++r) {
            const std::string list(all.data() + off, static_cast<std::size_t>(lengths[static_cast<std::size_t>(r)]));
            off += static_cast<std::size_t>(lengths[static_cast<std::size_t>(r)]);
            std::vector<std::string> tiles;
            std::size_t start = 0;
            for (std::size_t end; (end = list.find('\n', start)) != std::string::npos; start = end + 1)
              tiles.push_back(list.substr(start, end - start));
            m.tiles.push_back(std::move(tiles));
          }
          write_manifest(options_.directory, m);
        }));
}

}  // namespace iwlomap::mpi
