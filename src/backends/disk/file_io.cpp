// SPDX-License-Identifier: BSD-3-Clause
#include "backends/disk/file_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>

namespace iwlomap::detail {

namespace {

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

void throw_corrupt(const std::string& path, const std::string& what) {
  const std::string dir = std::filesystem::path(path).parent_path().string();
  throw StorageError(StorageError::Kind::kCorrupt, path,
                     "iwlomap: tile file " + path + " is corrupt: " + what + kCorruptAdvice +
                         (dir.empty() ? std::string() : "; 'iwlomap repair " + dir + "' sets damaged tiles aside") + ")");
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
