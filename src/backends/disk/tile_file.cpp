// SPDX-License-Identifier: BSD-3-Clause
#include "backends/disk/tile_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace iwlomap::detail {

namespace {

constexpr char kMagic[8] = {'I', 'W', 'L', 'O', 'T', 'I', 'L', 'E'};
constexpr std::uint32_t kByteOrderMark = 0x01020304u;

// Slicing-by-8 tables: eight bytes per step instead of one, so that checksums run at several GB/s
// and never dominate a flush.
using CrcTables = std::array<std::array<std::uint32_t, 256>, 8>;
constexpr CrcTables make_crc_tables() {
  CrcTables t{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
    t[0][i] = c;
  }
  for (std::size_t s = 1; s < 8; ++s)
    for (std::size_t i = 0; i < 256; ++i) t[s][i] = (t[s - 1][i] >> 8) ^ t[0][t[s - 1][i] & 0xFFu];
  return t;
}
constexpr CrcTables kCrc = make_crc_tables();

std::string error_text(int err) { return std::strerror(err); }

[[noreturn]] void throw_io(const std::string& path, const std::string& what, int err) {
  throw StorageError(StorageError::Kind::kIo, path, "iwlomap: " + what + " " + path + ": " + error_text(err));
}

class Fd {
 public:
  explicit Fd(int fd) : fd_(fd) {}
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  [[nodiscard]] int get() const noexcept { return fd_; }
  // close() reports errors a delayed write may only reveal here (e.g. on network file systems).
  int close() {
    const int r = ::close(fd_);
    fd_ = -1;
    return r;
  }

 private:
  int fd_;
};

int open_retry(const char* path, int flags, mode_t mode = 0) {
  int fd;
  do fd = ::open(path, flags | O_CLOEXEC, mode);
  while (fd < 0 && errno == EINTR);
  return fd;
}

}  // namespace

std::uint32_t crc32(const std::uint8_t* data, std::size_t size, std::uint32_t crc) noexcept {
  std::uint32_t c = ~crc;
  while (size >= 8) {
    const std::uint32_t lo = load_u32(data) ^ c;
    const std::uint32_t hi = load_u32(data + 4);
    c = kCrc[7][lo & 0xFFu] ^ kCrc[6][(lo >> 8) & 0xFFu] ^ kCrc[5][(lo >> 16) & 0xFFu] ^ kCrc[4][lo >> 24] ^
        kCrc[3][hi & 0xFFu] ^ kCrc[2][(hi >> 8) & 0xFFu] ^ kCrc[1][(hi >> 16) & 0xFFu] ^ kCrc[0][hi >> 24];
    data += 8;
    size -= 8;
  }
  while (size-- > 0) c = kCrc[0][(c ^ *data++) & 0xFFu] ^ (c >> 8);
  return ~c;
}

std::string hex32(std::uint32_t v) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%08x", v);
  return buf;
}

void throw_corrupt(const std::string& path, const std::string& what) {
  throw StorageError(StorageError::Kind::kCorrupt, path,
                     "iwlomap: tile file " + path + " is corrupt: " + what +
                         " (the file is left as it is; move it away to use the rest of the map)");
}

std::uint64_t encode_tile(const BlockGrid& grid, double resolution, std::uint32_t tile_voxels, const VoxelKey& tile,
                          std::vector<std::uint8_t>& out) {
  std::vector<const VoxelBlock*> blocks;
  blocks.reserve(grid.num_blocks());
  std::size_t payload = 0;
  for (const auto& b : grid.blocks()) {
    if (b->known == 0) continue;
    blocks.push_back(b);
    payload += kRecordFixedBytes + kVoxelBytes * b->known;
  }
  std::sort(blocks.begin(), blocks.end(), [](const VoxelBlock* a, const VoxelBlock* b) { return a->key < b->key; });

  out.assign(kTileHeaderBytes + payload, 0);
  std::uint8_t* p = out.data() + kTileHeaderBytes;
  std::uint64_t known = 0;
  DenseBlock dense;  // one block with every voxel in place, read in file order
  for (const VoxelBlock* b : blocks) {
    dense.voxels.fill(Voxel{});
    b->for_each_slot([&](int i, const Voxel& v) { dense.voxels[static_cast<std::size_t>(i)] = v; });
    store_u32(p, static_cast<std::uint32_t>(b->key.x));
    store_u32(p + 4, static_cast<std::uint32_t>(b->key.y));
    store_u32(p + 8, static_cast<std::uint32_t>(b->key.z));
    std::uint8_t* const mask = p + 16;
    std::uint8_t* v = p + kRecordFixedBytes;
    std::uint32_t n = 0;
    for (int w = 0; w < kBlockVoxels / 64; ++w) {
      std::uint64_t bits = 0;
      for (int i = 0; i < 64; ++i) {
        const Voxel& voxel = dense.voxels[file_to_block_index(w * 64 + i)];
        if (voxel.count == 0) continue;
        bits |= std::uint64_t{1} << i;
        std::uint32_t raw;
        std::memcpy(&raw, &voxel.log_odds, sizeof raw);
        store_u32(v, raw);
        store_u16(v + 4, voxel.count);
        v += kVoxelBytes;
        ++n;
      }
      store_u64(mask + 8 * w, bits);
    }
    // b->known is maintained by every update; a mismatch would be a bug that must not reach disk.
    if (n != b->known) throw std::logic_error("iwlomap: block voxel count out of sync while writing a tile");
    store_u32(p + 12, n);
    known += n;
    p = v;
  }

  std::uint8_t* h = out.data();
  std::memcpy(h, kMagic, sizeof kMagic);
  store_u32(h + 8, kTileFormatVersion);
  store_u32(h + 12, kByteOrderMark);
  store_u32(h + 16, static_cast<std::uint32_t>(kTileHeaderBytes));
  store_u32(h + 20, tile_voxels);
  std::uint64_t res_bits;
  std::memcpy(&res_bits, &resolution, sizeof res_bits);
  store_u64(h + 24, res_bits);
  store_u32(h + 32, static_cast<std::uint32_t>(tile.x));
  store_u32(h + 36, static_cast<std::uint32_t>(tile.y));
  store_u32(h + 40, static_cast<std::uint32_t>(tile.z));
  store_u32(h + 44, static_cast<std::uint32_t>(blocks.size()));
  store_u64(h + 48, known);
  store_u64(h + 56, payload);
  store_u32(h + 64, crc32(out.data() + kTileHeaderBytes, payload));
  store_u32(h + 76, crc32(h, kTileHeaderBytes - 4));
  return known;
}

TileHeader parse_tile_header(const std::uint8_t* data, std::size_t available, std::uint64_t file_size,
                             double resolution, std::uint32_t tile_voxels, const VoxelKey& tile,
                             const std::string& path) {
  if (available >= sizeof kMagic && std::memcmp(data, kMagic, sizeof kMagic) != 0)
    throw_corrupt(path, "wrong magic (not an iwlomap tile)");
  if (available < 16)
    throw_corrupt(path, "truncated: " + std::to_string(file_size) + " bytes, shorter than a tile header");
  TileHeader h;
  h.version = load_u32(data + 8);
  if (h.version > kTileFormatVersion)
    throw StorageError(StorageError::Kind::kNewerVersion, path,
                       "iwlomap: tile file " + path + " has format version " + std::to_string(h.version) +
                           ", newer than the version " + std::to_string(kTileFormatVersion) +
                           " this build reads; open the map with a newer iwlomap");
  if (h.version == 0) throw_corrupt(path, "format version 0");
  if (load_u32(data + 12) != kByteOrderMark) throw_corrupt(path, "unknown byte-order mark " + hex32(load_u32(data + 12)));
  if (available < kTileHeaderBytes)
    throw_corrupt(path, "truncated: " + std::to_string(file_size) + " bytes, shorter than the " +
                            std::to_string(kTileHeaderBytes) + "-byte header");
  const std::uint32_t stored_crc = load_u32(data + 76);
  const std::uint32_t crc = crc32(data, kTileHeaderBytes - 4);
  if (stored_crc != crc)
    throw_corrupt(path, "header checksum mismatch (stored CRC-32 " + hex32(stored_crc) + ", computed " + hex32(crc) + ")");
  if (load_u32(data + 16) != kTileHeaderBytes)
    throw_corrupt(path, "header size " + std::to_string(load_u32(data + 16)) + ", expected " +
                            std::to_string(kTileHeaderBytes));
  h.tile_voxels = load_u32(data + 20);
  const std::uint64_t res_bits = load_u64(data + 24);
  std::memcpy(&h.resolution, &res_bits, sizeof h.resolution);
  h.tile = {static_cast<std::int32_t>(load_u32(data + 32)), static_cast<std::int32_t>(load_u32(data + 36)),
            static_cast<std::int32_t>(load_u32(data + 40))};
  h.record_count = load_u32(data + 44);
  h.known_voxels = load_u64(data + 48);
  h.payload_bytes = load_u64(data + 56);
  h.payload_crc = load_u32(data + 64);
  if (h.resolution != resolution || h.tile_voxels != tile_voxels)
    throw_corrupt(path, "written for resolution " + std::to_string(h.resolution) + " and " +
                            std::to_string(h.tile_voxels) + "-voxel tiles, the map has " + std::to_string(resolution) +
                            " and " + std::to_string(tile_voxels));
  if (h.tile != tile)
    throw_corrupt(path, "holds tile (" + std::to_string(h.tile.x) + ", " + std::to_string(h.tile.y) + ", " +
                            std::to_string(h.tile.z) + "), not the tile its name says");
  if (file_size < kTileHeaderBytes + h.payload_bytes)
    throw_corrupt(path, "truncated: " + std::to_string(file_size) + " bytes, the header announces " +
                            std::to_string(kTileHeaderBytes + h.payload_bytes));
  if (file_size > kTileHeaderBytes + h.payload_bytes)
    throw_corrupt(path, std::to_string(file_size) + " bytes, longer than the " +
                            std::to_string(kTileHeaderBytes + h.payload_bytes) + " its header announces");
  if (h.payload_bytes < static_cast<std::uint64_t>(h.record_count) * kRecordFixedBytes ||
      h.known_voxels > static_cast<std::uint64_t>(h.record_count) * kBlockVoxels)
    throw_corrupt(path, "inconsistent record count " + std::to_string(h.record_count));
  return h;
}

std::vector<std::uint8_t> read_file_prefix(const std::string& path, std::size_t max_bytes, std::uint64_t& file_size) {
  Fd fd(open_retry(path.c_str(), O_RDONLY));
  if (fd.get() < 0) throw_io(path, "cannot open", errno);
  struct stat st {};
  if (::fstat(fd.get(), &st) != 0) throw_io(path, "cannot stat", errno);
  file_size = static_cast<std::uint64_t>(st.st_size);
  std::vector<std::uint8_t> data(static_cast<std::size_t>(std::min<std::uint64_t>(file_size, max_bytes)));
  std::size_t done = 0;
  while (done < data.size()) {
    const ssize_t r = ::read(fd.get(), data.data() + done, data.size() - done);
    if (r < 0 && errno == EINTR) continue;
    if (r < 0) throw_io(path, "cannot read", errno);
    if (r == 0) break;  // shrank since fstat: the caller sees the short size
    done += static_cast<std::size_t>(r);
  }
  data.resize(done);
  return data;
}

std::vector<std::uint8_t> read_file(const std::string& path) {
  std::uint64_t size = 0;
  return read_file_prefix(path, static_cast<std::size_t>(-1), size);
}

void write_temp_file(const std::string& temp_path, const std::string& final_path, const std::vector<std::uint8_t>& data,
                     bool sync) {
  const auto fail = [&](const std::string& what, int err) {
    ::unlink(temp_path.c_str());
    throw StorageError(StorageError::Kind::kIo, final_path,
                       "iwlomap: cannot write " + final_path + " (" + what + " " + temp_path + ": " + error_text(err) +
                           "); the previous file is unchanged");
  };
  Fd fd(open_retry(temp_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644));
  if (fd.get() < 0) fail("creating", errno);
  std::size_t done = 0;
  while (done < data.size()) {
    const ssize_t w = ::write(fd.get(), data.data() + done, data.size() - done);
    if (w < 0 && errno == EINTR) continue;
    if (w < 0) fail("writing", errno);
    if (w == 0) fail("writing", EIO);
    done += static_cast<std::size_t>(w);
  }
  if (sync && ::fsync(fd.get()) != 0) fail("fsync of", errno);
  if (fd.close() != 0) fail("closing", errno);
}

void commit_temp_file(const std::string& temp_path, const std::string& final_path, bool already_synced) {
  const auto fail = [&](const std::string& what, const std::string& path, int err) {
    throw StorageError(StorageError::Kind::kIo, final_path,
                       "iwlomap: cannot write " + final_path + " (" + what + " " + path + ": " + error_text(err) +
                           "); the previous file is unchanged");
  };
  if (!already_synced) {
    // fsync through a read-only descriptor: Linux and the BSDs flush the file's data whatever the
    // descriptor's mode.
    Fd fd(open_retry(temp_path.c_str(), O_RDONLY));
    if (fd.get() < 0) fail("opening", temp_path, errno);
    if (::fsync(fd.get()) != 0) fail("fsync of", temp_path, errno);
  }
  if (::rename(temp_path.c_str(), final_path.c_str()) != 0) fail("renaming", temp_path, errno);
}

void write_file_durably(const std::string& temp_path, const std::string& final_path,
                        const std::vector<std::uint8_t>& data) {
  write_temp_file(temp_path, final_path, data, true);
  commit_temp_file(temp_path, final_path, true);
}

int create_scratch_file(const std::string& path) {
  const int fd = open_retry(path.c_str(), O_RDWR | O_CREAT | O_TRUNC, 0644);
  if (fd < 0) throw_io(path, "cannot create", errno);
  return fd;
}

void write_at(int fd, const std::vector<std::uint8_t>& data, std::uint64_t offset, const std::string& path) {
  std::size_t done = 0;
  while (done < data.size()) {
    const ssize_t w = ::pwrite(fd, data.data() + done, data.size() - done, static_cast<off_t>(offset + done));
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) throw_io(path, "cannot write", w < 0 ? errno : EIO);
    done += static_cast<std::size_t>(w);
  }
}

void read_at(int fd, std::uint64_t offset, std::size_t size, const std::string& path, std::vector<std::uint8_t>& out) {
  out.resize(size);
  std::size_t done = 0;
  while (done < size) {
    const ssize_t r = ::pread(fd, out.data() + done, size - done, static_cast<off_t>(offset + done));
    if (r < 0 && errno == EINTR) continue;
    if (r < 0) throw_io(path, "cannot read", errno);
    if (r == 0) throw_corrupt(path, "cut short: " + std::to_string(done) + " of " + std::to_string(size) + " bytes");
    done += static_cast<std::size_t>(r);
  }
}

void sync_directory(const std::string& directory) {
  Fd fd(open_retry(directory.c_str(), O_RDONLY | O_DIRECTORY));
  if (fd.get() < 0) throw_io(directory, "cannot open directory", errno);
  if (::fsync(fd.get()) != 0) throw_io(directory, "cannot fsync directory", errno);
}

void remove_file(const std::string& path) {
  if (::unlink(path.c_str()) != 0 && errno != ENOENT) throw_io(path, "cannot remove", errno);
}

}  // namespace iwlomap::detail
