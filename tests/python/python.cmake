# Python post-processing tests (pytest in the project venv), run by ctest like the rest: one
# entry per group of test files, each with a timeout of its own (5 to 10 times the group's time
# on this 2-core machine at low load, docs/testing.md#labels), so that `ctest -j2` runs them side by side.
# Every scripts/tests/test_*.py file runs in exactly one entry: a file no group names runs in
# pytest_scripts_other.
set(CR_PY_ENV "${CR_MPI_ENV};CROWDROM_BIN=${CMAKE_BINARY_DIR}/bin;CROWDROM_ROOT=${CMAKE_SOURCE_DIR}")
set(CR_PY_LISTED "")
# cr_pytest(name TIMEOUT seconds [PROCESSORS n] FILES test_a.py ...): one ctest entry running
# those files of scripts/tests (its own pytest base temp directory); PROCESSORS 2 for groups
# that start 2-rank runs
function(cr_pytest name)
  cmake_parse_arguments(A "" "TIMEOUT;PROCESSORS" "FILES" ${ARGN})
  if(NOT A_PROCESSORS)
    set(A_PROCESSORS 1)
  endif()
  set(paths "")
  foreach(f ${A_FILES})
    list(APPEND paths ${CMAKE_SOURCE_DIR}/scripts/tests/${f})
  endforeach()
  add_test(NAME ${name}
    COMMAND ${CR_PYTHON} -m pytest -q -p no:cacheprovider --basetemp=${CMAKE_BINARY_DIR}/tests/${name}.tmp ${paths}
    WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  set_tests_properties(${name} PROPERTIES LABELS "regression;python" TIMEOUT ${A_TIMEOUT}
    PROCESSORS ${A_PROCESSORS} ENVIRONMENT "${CR_PY_ENV}")
  set(CR_PY_LISTED ${CR_PY_LISTED} ${A_FILES} PARENT_SCOPE)
endfunction()

# groups by running time (measured, docs/testing.md#labels): the error paths of the scripts alone,
# the rest in four groups, so that ctest -j2 runs about half of the total on each core; the
# groups start 2-rank runs only for seconds (oversubscribed), hence PROCESSORS 1
cr_pytest(pytest_script_errors TIMEOUT 600 FILES test_script_errors.py test_hostile_inputs.py)
cr_pytest(pytest_figures TIMEOUT 600 FILES test_figures.py test_plot_scene.py test_study_table.py test_io.py
  test_deim_desired.py test_layout.py test_docs.py test_agreement.py)
cr_pytest(pytest_rom TIMEOUT 300 FILES test_rom.py test_rom_measures.py)
cr_pytest(pytest_stages TIMEOUT 300 FILES test_offline.py test_snapshot_model.py test_fom_run.py test_snapshots.py
  test_checksums.py)
cr_pytest(pytest_ml TIMEOUT 300 FILES test_ml.py test_ml_project.py)
# prediction for new parameters (crowd_predict, ml_correct.py --predict) on the tiny study
cr_pytest(pytest_predict TIMEOUT 300 FILES test_predict.py)
# the answers engine on the real models (crowd_predict on the tiny study, M0 and M3)
cr_pytest(pytest_answers_predict TIMEOUT 180 FILES test_answers_predict.py)
# answers with a stated error: estimators on synthetic models with known moments (no build needed)
cr_pytest(pytest_answers TIMEOUT 600 FILES test_answers.py)
# approximate control variates (ACV-MF, ACV-IS) against closed forms on a synthetic family
cr_pytest(pytest_answers_acv TIMEOUT 300 FILES test_answers_acv.py)
# the scaled-down 1 000-agent study end to end (two exits, run_study.sh on 2 ranks): its own test
cr_pytest(pytest_crowd1000_mini TIMEOUT 1500 PROCESSORS 2 FILES test_crowd1000_mini.py)
# the heterogeneous population (speed_mean, speed_spread) end to end at test size
cr_pytest(pytest_hetero TIMEOUT 900 PROCESSORS 2 FILES test_hetero.py)

# any test file not named above
file(GLOB CR_PY_ALL RELATIVE ${CMAKE_SOURCE_DIR}/scripts/tests CONFIGURE_DEPENDS
  ${CMAKE_SOURCE_DIR}/scripts/tests/test_*.py)
set(CR_PY_REST ${CR_PY_ALL})
if(CR_PY_LISTED)
  list(REMOVE_ITEM CR_PY_REST ${CR_PY_LISTED})
endif()
if(CR_PY_REST)
  cr_pytest(pytest_scripts_other TIMEOUT 1500 FILES ${CR_PY_REST})
endif()
