# SPDX-License-Identifier: BSD-3-Clause
# The PCL layer: iwlomap::filters (OccupancyFilter). PCL is used only here and in samples/.
option(IWLOMAP_WITH_FILTERS "Build the PCL filter iwlomap::filters" ON)
if(IWLOMAP_WITH_FILTERS)
  find_package(PCL 1.10 REQUIRED COMPONENTS common io filters)
  add_library(iwlomap_filters filters/src/occupancy_filter.cpp)
  add_library(iwlomap::filters ALIAS iwlomap_filters)
  set_target_properties(iwlomap_filters PROPERTIES EXPORT_NAME filters OUTPUT_NAME iwlomap_filters
    POSITION_INDEPENDENT_CODE ON)
  target_include_directories(iwlomap_filters PUBLIC
    $<BUILD_INTERFACE:${CMAKE_CURRENT_SOURCE_DIR}/filters/include>
    $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>)
  target_link_libraries(iwlomap_filters PUBLIC iwlomap::core pcl_common pcl_filters)
  iwlomap_target_flags(iwlomap_filters)
  install(DIRECTORY filters/include/iwlomap/filters DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/iwlomap)
  list(APPEND IWLOMAP_EXPORTED_TARGETS iwlomap_filters)
  string(APPEND IWLOMAP_CONFIG_DEPENDENCIES "find_dependency(PCL COMPONENTS common io filters)\n")
endif()
