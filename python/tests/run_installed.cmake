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
execute_process(COMMAND ${CMAKE_COMMAND} -E env "PYTHONPATH=${package}" ${PYTHON} -c
  "import iwlomap, numpy as np, os; assert iwlomap.__file__.startswith(os.environ['PYTHONPATH']), iwlomap.__file__; m = iwlomap.ProbabilityUpdater(0.1); m.batch_update_iwlo(np.zeros((1, 3)), np.array([200.0]), np.array([True])); print(iwlomap.__version__, m.get_num_nodes())"
  WORKING_DIRECTORY "${WORK}" RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(rc OR NOT out MATCHES " 1\n")
  message(FATAL_ERROR "the installed package does not import and map (${rc}): ${out}${err}")
endif()
message(STATUS "installed package: ${out}")
