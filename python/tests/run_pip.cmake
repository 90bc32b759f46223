# SPDX-License-Identifier: BSD-3-Clause
# `pip install --no-build-isolation .` from the source tree, offline (Debian's setuptools and
# wheel), into WORK/target; then imports the package from a Python run outside the source and
# build trees, with only PYTHONPATH pointing at it, and maps a point.
# Usage: cmake -DSOURCE_DIR=... -DWORK=... -DPYTHON=... [-DPIP_BUILD_DIR=...] -P run_pip.cmake
# (PIP_BUILD_DIR: the package's CMake folder, IWLOMAP_PIP_BUILD_DIR; default WORK/build.)
file(REMOVE_RECURSE "${WORK}/target")
file(MAKE_DIRECTORY "${WORK}")
if(NOT PIP_BUILD_DIR)
  set(PIP_BUILD_DIR "${WORK}/build")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} -E env "IWLOMAP_PIP_BUILD_DIR=${PIP_BUILD_DIR}" PIP_NO_INDEX=1
          ${PYTHON} -m pip install --no-build-isolation --no-deps --no-input --target "${WORK}/target" "${SOURCE_DIR}"
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(rc)
  message(FATAL_ERROR "pip install failed (${rc}):\n${out}\n${err}")
endif()
file(GLOB module "${WORK}/target/iwlomap/_iwlomap*.so")
if(NOT module OR NOT EXISTS "${WORK}/target/iwlomap/__init__.pyi")
  message(FATAL_ERROR "pip installed no extension module or stubs in ${WORK}/target/iwlomap")
endif()
include(${CMAKE_CURRENT_LIST_DIR}/import_check.cmake)
iwlomap_expect_package_maps("${WORK}/target" "${WORK}" "${PYTHON}" "pip-installed")
