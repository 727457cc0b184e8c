# Python post-processing tests (pytest in the project venv), run by ctest like the rest.
set(CR_VENV_PY ${CMAKE_SOURCE_DIR}/.venv/bin/python)
if(EXISTS ${CR_VENV_PY})
  add_test(NAME pytest_scripts
    COMMAND ${CR_VENV_PY} -m pytest -q -p no:cacheprovider ${CMAKE_SOURCE_DIR}/scripts/tests
      --ignore=${CMAKE_SOURCE_DIR}/scripts/tests/test_crowd1000_mini.py
    WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  set_tests_properties(pytest_scripts PROPERTIES LABELS "regression;python"
    ENVIRONMENT "${CR_MPI_ENV};CROWDROM_BIN=${CMAKE_BINARY_DIR}/bin;CROWDROM_ROOT=${CMAKE_SOURCE_DIR}")
  # the scaled-down 1 000-agent study end to end (two exits, run_study.sh on 2 ranks): its own test
  add_test(NAME pytest_crowd1000_mini
    COMMAND ${CR_VENV_PY} -m pytest -q -p no:cacheprovider ${CMAKE_SOURCE_DIR}/scripts/tests/test_crowd1000_mini.py
    WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  set_tests_properties(pytest_crowd1000_mini PROPERTIES LABELS "regression;python" PROCESSORS 2
    ENVIRONMENT "${CR_MPI_ENV};CROWDROM_BIN=${CMAKE_BINARY_DIR}/bin;CROWDROM_ROOT=${CMAKE_SOURCE_DIR}")
else()
  message(WARNING "no .venv: the Python tests are not registered (run scripts/setup.sh)")
endif()
