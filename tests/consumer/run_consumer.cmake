# SPDX-License-Identifier: BSD-3-Clause
# Builds and runs tests/consumer/project against iwlomap, either from an install prefix
# (MODE=install: installs the build tree into WORK/prefix first) or from the build tree itself.
# Usage: cmake -DMODE=install|build-tree -DBUILD_DIR=... -DSOURCE=... -DWORK=... -P run_consumer.cmake
file(REMOVE_RECURSE "${WORK}")
if(MODE STREQUAL "install")
  execute_process(COMMAND ${CMAKE_COMMAND} --install "${BUILD_DIR}" --prefix "${WORK}/prefix"
                  RESULT_VARIABLE rc OUTPUT_QUIET)
  if(rc)
    message(FATAL_ERROR "install failed: ${rc}")
  endif()
  set(locate "-DCMAKE_PREFIX_PATH=${WORK}/prefix")
else()
  set(locate "-Diwlomap_DIR=${BUILD_DIR}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} -S "${SOURCE}" -B "${WORK}/build" ${locate} -DCMAKE_BUILD_TYPE=Release
                RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "configuring the consumer failed: ${rc}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build "${WORK}/build" RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "building the consumer failed: ${rc}")
endif()
execute_process(COMMAND "${WORK}/build/consumer" RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "the consumer failed: ${rc}")
endif()
