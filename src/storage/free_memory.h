// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Giving a container's memory back. `v = {}` does not: for a std::vector it picks the
// initializer-list assignment, which empties the vector and keeps its capacity.

#include <utility>

namespace iwlomap::detail {

/// Empties \p v and frees its storage.
template <class Container>
void free_memory(Container& v) {
  Container().swap(v);
}

}  // namespace iwlomap::detail
