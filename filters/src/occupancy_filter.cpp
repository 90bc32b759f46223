// SPDX-License-Identifier: BSD-3-Clause
// The precompiled point types; any other type with x, y and z compiles by including
// iwlomap/filters/impl/occupancy_filter.hpp (also with PCL_NO_PRECOMPILE).
#include "iwlomap/filters/impl/occupancy_filter.hpp"

template class iwlomap::OccupancyFilter<pcl::PointXYZI>;
template class iwlomap::OccupancyFilter<pcl::PointXYZINormal>;
template class iwlomap::OccupancyFilter<pcl::PointXYZ>;
template class iwlomap::OccupancyFilter<pcl::PointXYZRGB>;
template class iwlomap::OccupancyFilter<pcl::PointXYZRGBA>;
template class iwlomap::OccupancyFilter<pcl::PointXYZL>;
