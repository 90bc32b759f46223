// SPDX-License-Identifier: BSD-3-Clause
// The iwlomap._iwlomap extension module: the C++ API with the same names, numpy in and out.
//
// Exceptions: std::invalid_argument, std::out_of_range, std::length_error and std::domain_error
// become ValueError (a bad argument, named with its value); StorageError and OculusFormatError
// become iwlomap.StorageError / iwlomap.OculusFormatError, subclasses of OSError carrying the
// path in `filename`; MemoryLimitError becomes iwlomap.MemoryLimitError (a MemoryError with
// needed, in_use and limit); every other exception becomes RuntimeError with its message.

#include "bindings.h"

#include <iwlomap/map_memory.h>
#include <iwlomap/oculus_reader.h>
#include <iwlomap/outofcore_tile_mapper.h>
#include <iwlomap/version.h>

#include <pybind11/pybind11.h>

#include <cstddef>
#include <stdexcept>
#include <string>

namespace py = pybind11;

namespace {

// LZF (the compression of PCL's binary_compressed PCD): \p in expands to exactly \p size bytes,
// or std::invalid_argument says where it goes wrong. Each control byte starts either a literal
// run (c < 32: the next c + 1 bytes) or a back reference (length c >> 5, plus a byte when that is
// 7, plus 2; distance ((c & 31) << 8) + the next byte + 1).
py::bytes lzf_decompress(const py::bytes& data, std::size_t size) {
  const std::string in = data;
  std::string out(size, '\0');
  std::size_t ip = 0, op = 0;
  const auto fail = [&](const std::string& why) {
    throw std::invalid_argument("LZF data: " + why + " at input byte " + std::to_string(ip));
  };
  while (ip < in.size()) {
    const unsigned ctrl = static_cast<unsigned char>(in[ip++]);
    if (ctrl < 32) {
      const std::size_t n = ctrl + 1;
      if (ip + n > in.size()) fail("a literal run passes the end of the input");
      if (op + n > size) fail("a literal run passes the promised size");
      out.replace(op, n, in, ip, n);
      ip += n;
      op += n;
      continue;
    }
    std::size_t n = ctrl >> 5;
    if (n == 7) {
      if (ip >= in.size()) fail("the input ends inside a back reference");
      n += static_cast<unsigned char>(in[ip++]);
    }
    if (ip >= in.size()) fail("the input ends inside a back reference");
    const std::size_t back = ((ctrl & 31u) << 8) + static_cast<unsigned char>(in[ip++]) + 1;
    n += 2;
    if (back > op) fail("a back reference points before the start");
    if (op + n > size) fail("a back reference passes the promised size");
    for (std::size_t k = 0; k < n; ++k, ++op) out[op] = out[op - back];  // may overlap: byte by byte
  }
  if (op != size) fail("the data expands to " + std::to_string(op) + " bytes, not " + std::to_string(size));
  return py::bytes(out);
}

// Raises \p type (an OSError subclass) with errno None, the message and the path as filename.
void raise_os_error(const py::object& type, const std::string& message, const std::string& path) {
  const py::object error = type(py::none(), message, path);
  PyErr_SetObject(type.ptr(), error.ptr());
}

}  // namespace

PYBIND11_MODULE(_iwlomap, m) {
  m.doc() = "iwlomap: intensity-weighted log-odds occupancy maps (C++ library bindings)";
  // Classes are created under the package's name, so help() and the signatures say
  // iwlomap.ProbabilityUpdater (where users find them), not iwlomap._iwlomap.ProbabilityUpdater.
  m.attr("__name__") = "iwlomap";
  m.attr("__version__") = iwlomap::version();

  // Exception classes, created once and kept alive by the module.
  static py::object storage_error = py::reinterpret_borrow<py::object>(
      py::handle(PyErr_NewExceptionWithDoc("iwlomap.StorageError",
                                           "A map directory or tile file could not be used (OSError; filename: the path).",
                                           PyExc_OSError, nullptr)));
  static py::object oculus_error = py::reinterpret_borrow<py::object>(py::handle(PyErr_NewExceptionWithDoc(
      "iwlomap.OculusFormatError", "An Oculus recording is malformed (OSError; filename: the file).", PyExc_OSError,
      nullptr)));
  static py::object memory_error = py::reinterpret_borrow<py::object>(py::handle(PyErr_NewExceptionWithDoc(
      "iwlomap.MemoryLimitError", "The map memory limit would be passed (MemoryError; needed, in_use, limit in bytes).",
      PyExc_MemoryError, nullptr)));
  m.attr("StorageError") = storage_error;
  m.attr("OculusFormatError") = oculus_error;
  m.attr("MemoryLimitError") = memory_error;

  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const iwlomap::StorageError& e) {
      raise_os_error(storage_error, e.what(), e.path());
    } catch (const iwlomap::OculusFormatError& e) {
      raise_os_error(oculus_error, e.what(), e.source());
    } catch (const iwlomap::MemoryLimitError& e) {
      const py::object error = memory_error(e.what());
      error.attr("needed") = e.needed();
      error.attr("in_use") = e.in_use();
      error.attr("limit") = e.limit();
      PyErr_SetObject(memory_error.ptr(), error.ptr());
    } catch (const std::invalid_argument& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const std::out_of_range& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const std::length_error& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const std::domain_error& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const iwlomap::python::FileError& e) {
      raise_os_error(py::reinterpret_borrow<py::object>(PyExc_OSError), e.what(), e.path);
    }
  });

  m.def("_lzf_decompress", &lzf_decompress, py::arg("data"), py::arg("size"),
        "LZF-decompresses data to exactly size bytes (PCD binary_compressed); ValueError when it does not.");

  iwlomap::python::bind_core(m);
  iwlomap::python::bind_sonar(m);
  iwlomap::python::bind_grids(m);
  iwlomap::python::bind_async(m);
  iwlomap::python::bind_registration(m);
  iwlomap::python::bind_slam(m);
#ifdef IWLOMAP_PYTHON_OCTOMAP
  iwlomap::python::bind_octomap(m);
  m.attr("HAS_OCTOMAP") = true;
#else
  m.attr("HAS_OCTOMAP") = false;
#endif
#ifdef IWLOMAP_PYTHON_VIEWER
  iwlomap::python::bind_viewer(m);
  m.attr("HAS_VIEWER") = true;
#else
  m.attr("HAS_VIEWER") = false;
#endif
  m.attr("__name__") = "iwlomap._iwlomap";
}
