// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The parts of the extension module, one function per group of the C++ API.

#include <pybind11/pybind11.h>

#include <iwlomap/mapper_backend.h>

#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <typeinfo>
#include <utility>

namespace iwlomap::python {

/// A file that could not be read or written: raised as OSError with the path as filename.
struct FileError : std::runtime_error {
  FileError(const std::string& message, std::string file) : std::runtime_error(message), path(std::move(file)) {}
  std::string path;
};

/// Runs \p f; a std::runtime_error it throws (the library's file errors name the path) becomes a
/// FileError for \p path. Other exceptions pass unchanged.
template <typename F>
auto with_file_errors(const std::string& path, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const FileError&) {
    throw;
  } catch (const std::runtime_error& e) {
    // Subclasses with their own Python class (StorageError, OculusFormatError, MemoryLimitError)
    // are rethrown as they are by the caller's translator; plain runtime errors name the file.
    if (typeid(e) != typeid(std::runtime_error)) throw;
    throw FileError(e.what(), path);
  }
}

/// The lock that serialises every call on \p map from Python: a call releases the GIL while the
/// library works, so two Python threads could otherwise enter one map at once (maps are not
/// thread-safe). One mutex per map object, kept for the process's life.
std::mutex& map_mutex(const IMapperBackend& map);

/// Throws std::runtime_error (Python's RuntimeError) when this thread is running a
/// for_each_voxel() visitor of \p map: the visit holds the map's lock, so a call into the map
/// from its visitor would wait for itself.
void refuse_call_from_visitor(const IMapperBackend& map);

/// Marks this thread as running a visitor of \p map while it lives (for_each_voxel()).
class VisitScope {
 public:
  explicit VisitScope(const IMapperBackend& map);
  ~VisitScope();
  VisitScope(const VisitScope&) = delete;
  VisitScope& operator=(const VisitScope&) = delete;
};

/// Runs \p f on \p map with the GIL released and the map's lock held (the GIL is given back
/// before the lock is taken and retaken after it is released, so no thread holds one while
/// waiting for the other).
template <typename F>
auto unlocked(const IMapperBackend& map, F&& f) -> decltype(f()) {
  refuse_call_from_visitor(map);
  pybind11::gil_scoped_release release;
  const std::lock_guard<std::mutex> lock(map_mutex(map));
  return f();
}

/// A ProgressCallback that calls \p fn(stage, done, total) (stage a str, progress_stage_name())
/// with the GIL held; a call from it into \p map raises RuntimeError, as from a visitor. None
/// gives an empty callback.
ProgressCallback python_progress(const pybind11::object& fn, const IMapperBackend& map);

/// A path argument: str or os.PathLike.
std::string path_from(const pybind11::handle& obj);

void bind_core(pybind11::module_& m);
void bind_sonar(pybind11::module_& m);
void bind_grids(pybind11::module_& m);
void bind_async(pybind11::module_& m);
void bind_octomap(pybind11::module_& m);
void bind_viewer(pybind11::module_& m);
void bind_registration(pybind11::module_& m);
void bind_slam(pybind11::module_& m);

}  // namespace iwlomap::python
