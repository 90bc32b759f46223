// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Clouds of voxel centres (what 'iwlomap map' writes): their voxel size, and a map made of them.

#include "cloud_io.h"

#include <iwlomap/mapper_backend.h>

#include <Eigen/Core>

#include <memory>
#include <optional>
#include <string>

namespace iwlomap::tool {

/// The voxel edge of a grid of voxel centres (rows x, y, z[, ...]): the smallest gap between
/// distinct centre coordinates along any axis, rounded to 4 significant digits; none for fewer
/// than two distinct centres.
[[nodiscard]] std::optional<double> infer_resolution(const Eigen::MatrixXd& v);

/// True when (nearly) every coordinate lies at a voxel centre, (k + 0.5) * resolution: the cloud
/// is a voxel cloud, not a raw scan whose smallest coordinate gap says nothing about a voxel size.
[[nodiscard]] bool on_voxel_lattice(const Eigen::MatrixXd& v, double resolution);

/// A map from \p cloud, voxel centres read from \p path: each voxel gets the log-odds of its
/// point's intensity when that is a probability in (0, 1) (p 0.9 otherwise), at the resolution
/// the file records (MapCloudInfo), \p resolution, or the inferred voxel size. Throws UsageError
/// naming \p path when the voxel size cannot be told or \p resolution differs from the recorded one.
[[nodiscard]] std::unique_ptr<IMapperBackend> map_from_voxel_cloud(const LoadedCloud& cloud, const std::string& path,
                                                                   std::optional<double> resolution);

}  // namespace iwlomap::tool
