# SPDX-License-Identifier: BSD-3-Clause
# Builds and runs tests/consumer/project (CONSUMER = core | octomap | filters | viewer | mpi) against
# iwlomap found the documented way:
#   MODE=install     the build tree BUILD_DIR installed into WORK/prefix first
#   MODE=build-tree  the build tree itself
#   MODE=shared      iwlomap built as shared libraries (every layer but the filter) from
#                    SOURCE_ROOT into SHARED_BUILD_DIR (default WORK/iwlomap; so also checks each
#                    library's SONAME), then installed
# FLAGS: extra compile flags of the consumer (e.g. -march=native); DISABLE: packages the
# consumer's configure must not find (CMAKE_DISABLE_FIND_PACKAGE_<name>), to prove a component
# needs nothing more; LAUNCHER: the compiler launcher of the calling build (ccache), used by both
# builds here.
# Usage: cmake -DMODE=... -DCONSUMER=... -DBUILD_DIR=... -DSOURCE=... -DSOURCE_ROOT=... -DWORK=...
#              [-DFLAGS=...] [-DDISABLE=PCL;VTK;octomap] [-DLAUNCHER=ccache] [-DSHARED_BUILD_DIR=...]
#              -P run_consumer.cmake
file(REMOVE_RECURSE "${WORK}")
if(NOT SHARED_BUILD_DIR)
  set(SHARED_BUILD_DIR "${WORK}/iwlomap")
endif()
set(launcher "-DCMAKE_CXX_COMPILER_LAUNCHER=${LAUNCHER}" "-DCMAKE_C_COMPILER_LAUNCHER=${LAUNCHER}")
function(run)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
  if(rc)
    message(FATAL_ERROR "failed (${rc}): ${ARGN}\n${out}")
  endif()
  set(last_output "${out}" PARENT_SCOPE)
endfunction()

if(MODE STREQUAL "shared")
  file(REMOVE_RECURSE "${SHARED_BUILD_DIR}")
  run(${CMAKE_COMMAND} -S "${SOURCE_ROOT}" -B "${SHARED_BUILD_DIR}" -DCMAKE_BUILD_TYPE=Release -DBUILD_SHARED_LIBS=ON ${launcher}
      -DIWLOMAP_BUILD_TESTS=OFF -DIWLOMAP_BUILD_SAMPLES=OFF -DIWLOMAP_WITH_FILTERS=OFF)
  run(${CMAKE_COMMAND} --build "${SHARED_BUILD_DIR}" -j 2)
  run(${CMAKE_COMMAND} --install "${SHARED_BUILD_DIR}" --prefix "${WORK}/prefix")
  # Every layer built here installs a versioned library with a versioned SONAME.
  file(GLOB_RECURSE built LIST_DIRECTORIES false RELATIVE "${SHARED_BUILD_DIR}" "${SHARED_BUILD_DIR}/libiwlomap_*.so")
  list(TRANSFORM built REPLACE "^(.*/)?libiwlomap_(.*)\\.so$" "\\2")
  list(APPEND built core octomap)
  list(REMOVE_DUPLICATES built)
  foreach(lib IN LISTS built)
    file(GLOB so "${WORK}/prefix/lib*/libiwlomap_${lib}.so.*.*.*")
    if(NOT so)
      message(FATAL_ERROR "no versioned libiwlomap_${lib}.so.X.Y.Z installed")
    endif()
    run(readelf -d ${so})
    if(NOT last_output MATCHES "SONAME\\)[^\n]*\\[libiwlomap_${lib}\\.so\\.[0-9]+\\.[0-9]+\\]")
      message(FATAL_ERROR "libiwlomap_${lib} has no versioned SONAME:\n${last_output}")
    endif()
  endforeach()
  # The Python module of a shared build finds the prefix's libraries through its relative RPATH.
  set(package "${WORK}/prefix/lib/python3/dist-packages")
  if(EXISTS "${package}/iwlomap/__init__.py")
    run(${CMAKE_COMMAND} -E env "PYTHONPATH=${package}" /usr/bin/python3 -c
        "import iwlomap; print(iwlomap.ProbabilityUpdater(0.1).get_resolution())")
  endif()
  set(locate "-DCMAKE_PREFIX_PATH=${WORK}/prefix")
elseif(MODE STREQUAL "install")
  run(${CMAKE_COMMAND} --install "${BUILD_DIR}" --prefix "${WORK}/prefix")
  set(locate "-DCMAKE_PREFIX_PATH=${WORK}/prefix")
else()
  set(locate "-Diwlomap_DIR=${BUILD_DIR}")
endif()

set(disable)
foreach(p IN LISTS DISABLE)
  list(APPEND disable "-DCMAKE_DISABLE_FIND_PACKAGE_${p}=ON")
endforeach()
run(${CMAKE_COMMAND} -S "${SOURCE}" -B "${WORK}/build" ${locate} ${disable} -DCMAKE_BUILD_TYPE=Release ${launcher}
    -DCONSUMER=${CONSUMER} "-DCMAKE_CXX_FLAGS=${FLAGS}" "-DCMAKE_EXE_LINKER_FLAGS=${FLAGS}")
run(${CMAKE_COMMAND} --build "${WORK}/build")
run("${WORK}/build/consumer")
message(STATUS "${last_output}")
