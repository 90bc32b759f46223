# SPDX-License-Identifier: BSD-3-Clause
# Installs the build tree BUILD_DIR into WORK/prefix and imports the installed package from a
# Python run outside the source and build trees, with only PYTHONPATH pointing at it.
# PACKAGE_DIR is IWLOMAP_PYTHON_INSTALL_DIR without its last folder (the site folder); the
# install must name it in a PYTHONPATH hint, as WORK/prefix is not on the interpreter's path.
# Usage: cmake -DBUILD_DIR=... -DWORK=... -DPYTHON=... -DPACKAGE_DIR=... -P run_installed.cmake
file(REMOVE_RECURSE "${WORK}")
file(MAKE_DIRECTORY "${WORK}")
execute_process(COMMAND ${CMAKE_COMMAND} --install "${BUILD_DIR}" --prefix "${WORK}/prefix"
  RESULT_VARIABLE rc OUTPUT_VARIABLE said ERROR_VARIABLE err)
if(rc)
  message(FATAL_ERROR "install failed: ${err}")
endif()
set(package "${WORK}/prefix/${PACKAGE_DIR}")
string(FIND "${said}" "use PYTHONPATH=${package}\n" hint)
if(hint EQUAL -1)
  message(FATAL_ERROR "the install did not name PYTHONPATH=${package}:\n${said}")
endif()
if(NOT EXISTS "${package}/iwlomap/__init__.py" OR NOT EXISTS "${package}/iwlomap/__init__.pyi")
  message(FATAL_ERROR "no iwlomap package (with its stubs) in ${package}")
endif()
include(${CMAKE_CURRENT_LIST_DIR}/import_check.cmake)
iwlomap_expect_package_maps("${package}" "${WORK}" "${PYTHON}" "installed")
