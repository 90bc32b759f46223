// SPDX-License-Identifier: BSD-3-Clause
#include "output_files.h"

#include "args.h"

#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <memory>
#include <mutex>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>

namespace iwlomap::tool {

namespace fs = std::filesystem;

namespace {

// True when \p a and \p b name the same file: the same inode when both exist (links included),
// else the same normalised absolute path.
bool same_file(const fs::path& a, const fs::path& b) {
  std::error_code ec;
  if (fs::exists(a, ec) && fs::exists(b, ec)) {
    const bool same = fs::equivalent(a, b, ec);
    if (!ec) return same;
  }
  const fs::path ca = fs::weakly_canonical(a, ec);
  if (ec) return false;
  const fs::path cb = fs::weakly_canonical(b, ec);
  return !ec && ca == cb;
}

// The temporaries of uncommitted runs, for the signal handler: SIGINT, SIGTERM or SIGHUP removes
// them before the process ends as the signal says, so that an interrupted run leaves no output.
// Slots are taken with a compare-and-swap and the paths are kept to the end (a handler may be
// reading one), so the handler touches nothing but atomics, unlink() and rmdir(), which are
// async-signal-safe.
std::array<std::atomic<const char*>, 512> g_temporaries{};
std::array<std::atomic<const char*>, 8> g_folders{};  // made by a run, removed after (if empty)

extern "C" void remove_temporaries_and_end(int sig) {
  for (auto& slot : g_temporaries)
    if (const char* path = slot.load()) ::unlink(path);
  for (auto& slot : g_folders)
    if (const char* path = slot.load()) ::rmdir(path);
  ::signal(sig, SIG_DFL);
  ::raise(sig);
}

void watch_signals() {
  static const bool installed = [] {
    struct sigaction action {};
    action.sa_handler = remove_temporaries_and_end;
    sigemptyset(&action.sa_mask);
    for (const int sig : {SIGINT, SIGTERM, SIGHUP}) ::sigaction(sig, &action, nullptr);
    return true;
  }();
  (void)installed;
}

// Registers \p path in a free slot (a run with more outputs than slots keeps the rest to its
// destructor); returns the slot or -1.
template <std::size_t N>
int register_path(std::array<std::atomic<const char*>, N>& slots, const std::string& path) {
  // Every copy stays reachable from here for the process's life (a handler may be reading one).
  static std::mutex kept_lock;
  static std::vector<std::unique_ptr<char[]>> kept;
  auto owned = std::make_unique<char[]>(path.size() + 1);
  std::memcpy(owned.get(), path.c_str(), path.size() + 1);
  const char* copy = owned.get();
  {
    const std::lock_guard<std::mutex> lock(kept_lock);
    kept.push_back(std::move(owned));
  }
  for (std::size_t i = 0; i < slots.size(); ++i) {
    const char* expected = nullptr;
    if (slots[i].compare_exchange_strong(expected, copy)) return static_cast<int>(i);
  }
  return -1;
}

int register_temporary(const std::string& path) { return register_path(g_temporaries, path); }

void release_temporary(int slot) {
  if (slot >= 0) g_temporaries[static_cast<std::size_t>(slot)].store(nullptr);
}

}  // namespace

OutputFiles::OutputFiles(const Args& args) {
  watch_signals();
  for (const std::string& p : args.positional()) inputs_.emplace_back("the input", p);
  for (const auto& [option, value] : args.values()) inputs_.emplace_back(option, value);
}

OutputFiles::~OutputFiles() {
  for (const int slot : slots_) release_temporary(slot);
  if (folder_slot_ >= 0) g_folders[static_cast<std::size_t>(folder_slot_)].store(nullptr);
  if (committed_) return;
  for (const std::string& t : temporaries_) std::remove(t.c_str());
  std::error_code ec;
  if (!made_folder_.empty()) fs::remove(made_folder_, ec);  // only when empty
}

void OutputFiles::make_folder(const std::string& folder) {
  std::error_code ec;
  if (fs::is_directory(folder, ec)) return;
  if (!fs::create_directories(folder, ec))
    throw std::runtime_error("cannot create the output folder '" + folder + "': " + ec.message());
  made_folder_ = folder;
  folder_slot_ = register_path(g_folders, folder);
}

void OutputFiles::add(const std::string& option, const std::string& path, std::initializer_list<const char*> extensions) {
  const std::string ext = extension(path);
  if (std::none_of(extensions.begin(), extensions.end(), [&](const char* e) { return ext == e; })) {
    std::string known;
    for (const char* e : extensions) known += (known.empty() ? "" : ", ") + std::string(e);
    throw UsageError(option + " must end in " + known + ", got '" + path + "'");
  }
  const fs::path target(path);
  const fs::path folder = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(folder, ec))
    throw std::runtime_error("cannot write '" + path + "': the folder '" + folder.string() + "' does not exist");
  if (::access(folder.c_str(), W_OK | X_OK) != 0)
    throw std::runtime_error("cannot write '" + path + "': the folder '" + folder.string() + "' is not writable (" +
                             std::strerror(errno) + ")");
  if (fs::is_directory(target, ec)) throw std::runtime_error("cannot write '" + path + "': it is a folder");
  if (fs::exists(target, ec) && ::access(path.c_str(), W_OK) != 0)
    throw std::runtime_error("cannot write '" + path + "': " + std::strerror(errno));
  for (const std::string& other : targets_)
    if (fs::weakly_canonical(other, ec) == fs::weakly_canonical(target, ec))
      throw UsageError("'" + path + "' is given as two outputs");
  // An output never replaces an input: refused before any work, whatever the spelling or link.
  for (const auto& [given_by, input] : inputs_) {
    if (given_by == option) continue;  // the option's own value is this output
    if (same_file(target, fs::path(input)))
      throw UsageError(option + " '" + path + "' is the same file as " + given_by + " '" + input +
                       "': an output may not replace an input");
  }
  targets_.push_back(path);
  // Hidden, in the target's folder (so the rename stays on one file system), unique per process.
  const std::string name = "." + target.stem().string() + ".iwlomap-" + std::to_string(::getpid()) + "-" +
                           std::to_string(targets_.size()) + ext;
  temporaries_.push_back((folder / name).string());
  slots_.push_back(register_temporary(temporaries_.back()));
}

std::string OutputFiles::temporary(const std::string& path) const {
  const auto it = std::find(targets_.begin(), targets_.end(), path);
  if (it == targets_.end()) throw std::logic_error("OutputFiles: '" + path + "' was not added");
  return temporaries_[static_cast<std::size_t>(it - targets_.begin())];
}

void OutputFiles::write(const std::string& path, const std::function<void(const std::string& file)>& writer) const {
  const std::string file = temporary(path);
  try {
    writer(file);
  } catch (const std::exception& e) {
    std::string message = e.what();
    for (std::size_t at = message.find(file); at != std::string::npos; at = message.find(file, at + path.size()))
      message.replace(at, file.size(), path);
    // Some writers (PCL's) do not name the file; a full file system is said as such.
    if (message.find(path) == std::string::npos) message = "cannot write '" + path + "': " + message;
    const fs::path folder = fs::path(file).has_parent_path() ? fs::path(file).parent_path() : fs::path(".");
    std::error_code ec;
    const fs::space_info space = fs::space(folder, ec);
    if (!ec && space.available < (std::uintmax_t{1} << 20))
      message += " (the file system has " + std::to_string(space.available) + " bytes free)";
    std::remove(file.c_str());
    throw std::runtime_error(message);
  }
}

void OutputFiles::commit() {
  for (std::size_t i = 0; i < targets_.size(); ++i) {
    std::error_code ec;
    if (!fs::exists(temporaries_[i], ec)) throw std::runtime_error("'" + targets_[i] + "' was not written");
  }
  for (std::size_t i = 0; i < targets_.size(); ++i) {
    if (std::rename(temporaries_[i].c_str(), targets_[i].c_str()) != 0)
      throw std::runtime_error("cannot write '" + targets_[i] + "': " + std::strerror(errno));
    release_temporary(slots_[i]);
    slots_[i] = -1;
  }
  committed_ = true;
}

}  // namespace iwlomap::tool
