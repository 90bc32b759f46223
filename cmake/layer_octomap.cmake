# SPDX-License-Identifier: BSD-3-Clause
# The OctoMap layer: iwlomap::octomap (OctreeMapper, export_octomap, import_octomap). OctoMap is
# used only in src/octree_mapper.cpp; its headers stay out of iwlomap's public headers, so OctoMap
# is a private dependency. Included by the top-level CMakeLists.txt at top level.
if(IWLOMAP_WITH_OCTOMAP)
  # Debian's liboctomap-dev: config package `octomap`, imported targets `octomap` and `octomath`.
  find_package(octomap REQUIRED)
  add_library(iwlomap_octomap ${PROJECT_SOURCE_DIR}/src/octree_mapper.cpp)
  add_library(iwlomap::octomap ALIAS iwlomap_octomap)
  set_target_properties(iwlomap_octomap PROPERTIES EXPORT_NAME octomap OUTPUT_NAME iwlomap_octomap
    POSITION_INDEPENDENT_CODE ON)
  target_include_directories(iwlomap_octomap PRIVATE ${PROJECT_SOURCE_DIR}/src)
  target_link_libraries(iwlomap_octomap PUBLIC iwlomap::core PRIVATE octomap octomath)
  iwlomap_target_flags(iwlomap_octomap)
  list(APPEND IWLOMAP_EXPORTED_TARGETS iwlomap_octomap)
  # A static iwlomap_octomap carries its private OctoMap link into consumers' link lines.
  string(APPEND IWLOMAP_CONFIG_DEPENDENCIES "find_dependency(octomap)\n")
endif()
