# SPDX-License-Identifier: BSD-3-Clause
# The check both install tests end with: a Python run outside the source and build trees, with
# only PYTHONPATH=SITE, imports iwlomap from SITE and maps a point. LABEL names the install in
# the messages.
function(iwlomap_expect_package_maps SITE WORK PYTHON LABEL)
  execute_process(COMMAND ${CMAKE_COMMAND} -E env "PYTHONPATH=${SITE}" ${PYTHON} -c
    "import iwlomap, numpy as np, os; assert iwlomap.__file__.startswith(os.environ['PYTHONPATH']), iwlomap.__file__; m = iwlomap.ProbabilityUpdater(0.1); m.batch_update_iwlo(np.zeros((1, 3)), np.array([200.0]), np.array([True])); print(iwlomap.__version__, m.get_num_nodes())"
    WORKING_DIRECTORY "${WORK}" RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(rc OR NOT out MATCHES " 1\n")
    message(FATAL_ERROR "the ${LABEL} package does not import and map (${rc}): ${out}${err}")
  endif()
  message(STATUS "${LABEL} package: ${out}")
endfunction()
