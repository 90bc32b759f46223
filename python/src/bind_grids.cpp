// SPDX-License-Identifier: BSD-3-Clause
// The discretised grids and the multi-resolution max grids (Cartographer's precomputation stack),
// with their cells as numpy uint8 arrays indexed [i, j] or [i, j, k] (the grid's cell index).

#include "bindings.h"
#include "numpy_io.h"

#include <iwlomap/precomputation_grid.h>
#include <iwlomap/precomputation_stack.h>
#include <iwlomap/voxel_box.h>

#include <pybind11/stl.h>

#include <cstring>

namespace iwlomap::python {

namespace {

// Cells stored with the first index fastest (DiscreteGrid::offset()) as a numpy array of that
// shape in Fortran order, so a[i, j(, k)] is the cell (i, j(, k)).
template <int D>
py::array_t<std::uint8_t> cells_to_numpy(const std::vector<std::uint8_t>& values, const Eigen::Matrix<int, D, 1>& size) {
  std::vector<py::ssize_t> shape(D), strides(D);
  py::ssize_t stride = 1;
  for (int a = 0; a < D; ++a) {
    shape[static_cast<std::size_t>(a)] = size[a];
    strides[static_cast<std::size_t>(a)] = stride;
    stride *= size[a];
  }
  py::array_t<std::uint8_t> out(shape, strides);
  if (!values.empty()) std::memcpy(out.mutable_data(), values.data(), values.size());
  return out;
}

template <int D>
Eigen::Matrix<int, D, 1> index_from(const py::handle& obj, const char* name) {
  const Eigen::VectorXd v = values_from(obj, name, D);
  Eigen::Matrix<int, D, 1> out;
  for (int a = 0; a < D; ++a) {
    if (v[a] != static_cast<double>(static_cast<int>(v[a])))
      throw py::value_error(std::string(name) + ": expected integer cell indices");
    out[a] = static_cast<int>(v[a]);
  }
  return out;
}

template <int D>
void bind_dim(py::module_& m, const char* grid_name, const char* stack_name) {
  using Grid = DiscreteGrid<D>;
  using Stack = PrecomputationStack<D>;
  py::class_<Grid>(m, grid_name, "A grid of 8-bit occupancy values (0 unknown, 1..255 probability 0.1..0.9).")
      .def(py::init([](const ArrayLike& values, const GridFrame& frame) {
             const py::array a = as_array(values, "values");
             if (a.ndim() != D) throw py::value_error("values: expected " + std::to_string(D) + " dimensions, got " + shape_text(a));
             if (a.dtype().kind() != 'u' || a.itemsize() != 1)
               throw py::value_error("values: expected dtype uint8, got " + py::str(a.dtype()).cast<std::string>());
             typename Grid::Index size;
             for (int d = 0; d < D; ++d) size[d] = static_cast<int>(a.shape(d));
             // Copy in the grid's order (first index fastest), whatever the array's strides.
             const py::array_t<std::uint8_t, py::array::f_style | py::array::forcecast> f =
                 py::array_t<std::uint8_t, py::array::f_style | py::array::forcecast>::ensure(a);
             std::vector<std::uint8_t> cells(static_cast<std::size_t>(f.size()));
             if (!cells.empty()) std::memcpy(cells.data(), f.data(), cells.size());
             return Grid(size, std::move(cells), frame);
           }),
           py::arg("values"), py::arg("frame") = GridFrame{}, "values: a uint8 array, cell (i, j[, k]) at [i, j[, k]]")
      .def_property_readonly("size", [](const Grid& g) { return std::vector<int>(g.size().data(), g.size().data() + D); })
      .def_property_readonly("frame", &Grid::frame)
      .def_property_readonly("values", [](const Grid& g) { return cells_to_numpy<D>(g.values(), g.size()); })
      .def(
          "at", [](const Grid& g, const ArrayLike& cell) { return g.at(index_from<D>(cell, "cell")); },
          py::arg("cell"))
      .def(
          "key_of", [](const Grid& g, const ArrayLike& cell) { return g.key_of(index_from<D>(cell, "cell")); },
          py::arg("cell"), "The map voxel key of a cell.");

  py::class_<Stack>(m, stack_name,
                    "Max grids of widths 1, 2, 4, ... over a discretised grid: level k holds, per cell, the maximum "
                    "over the 2^k-wide window starting there (the upper bounds of a branch-and-bound scan match).")
      .def(py::init([](const Grid& base, int num_levels) {
             py::gil_scoped_release release;
             return Stack(base, num_levels);
           }),
           py::arg("base"), py::arg("num_levels") = Stack::kDefaultLevels)
      .def("num_levels", &Stack::num_levels)
      .def("width", &Stack::width, py::arg("k"))
      .def_property_readonly("base_size",
                             [](const Stack& s) { return std::vector<int>(s.base_size().data(), s.base_size().data() + D); })
      .def_property_readonly("frame", &Stack::frame)
      .def(
          "level",
          [](const Stack& s, int k) {
            const auto& g = s.level(k);
            return cells_to_numpy<D>(g.values(), g.size());
          },
          py::arg("k"), "Level k as a uint8 array, [i, j(, k)] the max over the window starting at that cell.")
      .def_property_readonly("levels",
                             [](const Stack& s) {
                               py::list out;
                               for (int k = 0; k < s.num_levels(); ++k) {
                                 const auto& g = s.level(k);
                                 out.append(cells_to_numpy<D>(g.values(), g.size()));
                               }
                               return out;
                             })
      .def(
          "max_in_box",
          [](const Stack& s, const ArrayLike& lo, const ArrayLike& hi) {
            return s.max_in_box(index_from<D>(lo, "lo"), index_from<D>(hi, "hi"));
          },
          py::arg("lo"), py::arg("hi"), "The maximum base cell value in the box [lo, hi] (cell indices, inclusive).");
}

}  // namespace

void bind_grids(py::module_& m) {
  m.attr("UNKNOWN_VALUE") = kUnknownValue;
  m.def("probability_to_value", &probability_to_value, py::arg("probability"));
  m.def("value_to_probability", &value_to_probability, py::arg("value"));
  py::class_<GridFrame>(m, "GridFrame", "Where cell (0, 0[, 0]) lies: its voxel key and the voxel edge in metres.")
      .def(py::init([](const VoxelKey& origin, double resolution) { return GridFrame{origin, resolution}; }),
           py::arg("origin") = VoxelKey{}, py::arg("resolution") = 1.0)
      .def_readwrite("origin", &GridFrame::origin)
      .def_readwrite("resolution", &GridFrame::resolution);
  bind_dim<2>(m, "DiscreteGrid2D", "PrecomputationStack2D");
  bind_dim<3>(m, "DiscreteGrid3D", "PrecomputationStack3D");
  m.def(
      "discretize_volume",
      [](IMapperBackend& map, const VoxelBox& box) { return unlocked(map, [&] { return discretize_volume(map, box); }); },
      py::arg("map"), py::arg("box"), "The box of the map as a 3-D grid of 8-bit values.");
  m.def(
      "discretize_column_max",
      [](IMapperBackend& map, const VoxelBox& box) {
        return unlocked(map, [&] { return discretize_column_max(map, box); });
      },
      py::arg("map"), py::arg("box"), "Per (x, y) column of the box, the largest value (a 2-D grid).");
  m.def(
      "discretize_slice",
      [](IMapperBackend& map, const VoxelBox& box, double z) {
        return unlocked(map, [&] { return discretize_slice(map, box, z); });
      },
      py::arg("map"), py::arg("box"), py::arg("z"), "The horizontal slice of the box at height z (metres).");
}

}  // namespace iwlomap::python
