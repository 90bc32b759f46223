// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Deprecated path, kept for existing code: include <iwlomap/octomap/octree_mapper.h>.

#include <iwlomap/octomap/octree_mapper.h>
