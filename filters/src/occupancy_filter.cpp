// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/filters/impl/occupancy_filter.hpp"

template class iwlomap::OccupancyFilter<pcl::PointXYZI>;
template class iwlomap::OccupancyFilter<pcl::PointXYZINormal>;
template class iwlomap::OccupancyFilter<pcl::PointXYZ>;
