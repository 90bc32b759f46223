# SPDX-License-Identifier: BSD-3-Clause
# The VTK layer: iwlomap::viewer (SnapshotRenderer, off-screen PNG snapshots). VTK is used only in
# viewer/src/; the public headers need Eigen and the standard library only.
if(IWLOMAP_WITH_VIEWER)
  set(IWLOMAP_VIEWER_VTK_COMPONENTS
    CommonCore CommonDataModel CommonExecutionModel FiltersSources IOImage InteractionStyle
    RenderingAnnotation RenderingCore RenderingFreeType RenderingOpenGL2)
  find_package(VTK 9 REQUIRED COMPONENTS ${IWLOMAP_VIEWER_VTK_COMPONENTS})
  # Xlib is used directly only to test that a display can be opened before VTK touches X (VTK 9.1
  # aborts the process when it cannot open one).
  find_package(X11 REQUIRED)

  add_library(iwlomap_viewer
    viewer/src/color_map.cpp
    viewer/src/rgb_image.cpp
    viewer/src/snapshot_options.cpp
    viewer/src/snapshot_renderer.cpp
    viewer/src/x_display.cpp)
  add_library(iwlomap::viewer ALIAS iwlomap_viewer)
  set_target_properties(iwlomap_viewer PROPERTIES EXPORT_NAME viewer OUTPUT_NAME iwlomap_viewer
    POSITION_INDEPENDENT_CODE ON)
  target_include_directories(iwlomap_viewer PUBLIC
    $<BUILD_INTERFACE:${CMAKE_CURRENT_SOURCE_DIR}/viewer/include>
    $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>)
  set(_iwlomap_vtk_targets)
  foreach(component IN LISTS IWLOMAP_VIEWER_VTK_COMPONENTS)
    list(APPEND _iwlomap_vtk_targets VTK::${component})
  endforeach()
  target_link_libraries(iwlomap_viewer PUBLIC iwlomap::core PRIVATE ${_iwlomap_vtk_targets} X11::X11)
  # Registers the OpenGL render window, the FreeType text renderer and the interactor styles with
  # VTK's object factories; without it vtkRenderWindow::New() returns an abstract window and
  # rendering segfaults.
  vtk_module_autoinit(TARGETS iwlomap_viewer MODULES ${_iwlomap_vtk_targets})
  iwlomap_target_flags(iwlomap_viewer)

  install(DIRECTORY viewer/include/iwlomap/viewer DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/iwlomap)
  list(APPEND IWLOMAP_EXPORTED_TARGETS iwlomap_viewer)
  # A static iwlomap_viewer carries its private VTK and X11 link dependencies to consumers.
  list(JOIN IWLOMAP_VIEWER_VTK_COMPONENTS " " _iwlomap_vtk_components)
  string(APPEND IWLOMAP_CONFIG_DEPENDENCIES
    "find_dependency(X11)\nfind_dependency(VTK COMPONENTS ${_iwlomap_vtk_components})\n")
  unset(_iwlomap_vtk_components)
  unset(_iwlomap_vtk_targets)
endif()
