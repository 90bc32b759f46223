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

/// Argument types whose only job is the name help() shows for them: any object is accepted and
/// converted by the function itself (array_from(), path_from()), as with py::handle.
class ArrayLike : public pybind11::object {
 public:
  PYBIND11_OBJECT_DEFAULT(ArrayLike, object, [](PyObject*) { return 1; })
};
class PathLike : public pybind11::object {
 public:
  PYBIND11_OBJECT_DEFAULT(PathLike, object, [](PyObject*) { return 1; })
};

}  // namespace iwlomap::python

namespace pybind11::detail {
template <>
struct handle_type_name<iwlomap::python::ArrayLike> {
  static constexpr auto name = const_name("numpy.typing.ArrayLike");
};
template <>
struct handle_type_name<iwlomap::python::PathLike> {
  static constexpr auto name = const_name("str | os.PathLike");
};
}  // namespace pybind11::detail

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

/// Replaces the `name` property and `__str__` pybind11 gives every enum (whose help() signatures
/// read "name(self: handle)") by ones typed with the enum: help() shows "name(self: iwlomap.X)".
template <class E>
void readable_enum_name(pybind11::enum_<E>& e) {
  namespace py = pybind11;
  const py::handle property(reinterpret_cast<PyObject*>(&PyProperty_Type));
  e.attr("name") = property(py::cpp_function(
                                    [](E value) -> py::str {
                                      const py::object self = py::cast(value);
                                      const py::dict entries = py::type::handle_of(self).attr("__entries");
                                      for (const auto& kv : entries)
                                        if (self.equal(py::reinterpret_borrow<py::tuple>(kv.second)[0]))
                                          return py::str(kv.first);
                                      return py::str("???");
                                    },
                                    py::name("name"), py::is_method(e)),
                                py::none(), py::none(), "");
  // pybind11's __str__ ("Type.member") has the same untyped signature.
  e.attr("__str__") = py::cpp_function(
      [](E value) -> py::str {
        const py::object self = py::cast(value);
        return py::str("{}.{}").format(py::type::handle_of(self).attr("__name__"), self.attr("name"));
      },
      py::name("__str__"), py::is_method(e));
}

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
