# crowd_snapshots: parameter studies. Tests run in ${CMAKE_BINARY_DIR}/tests/snap.
set(CR_SNAP_DIR ${CMAKE_BINARY_DIR}/tests/snap)
file(MAKE_DIRECTORY ${CR_SNAP_DIR})
set(CR_SNAP_CHECK ${CMAKE_CURRENT_SOURCE_DIR}/helpers/snap_check.sh)
set(CR_SNAP_IN ${CMAKE_CURRENT_SOURCE_DIR}/inputs)
set(CR_SNAP_ENV "${CR_MPI_ENV};MPIEXEC=${MPIEXEC_EXECUTABLE}")

# the same study at 1, 2 and 4 ranks gives bitwise identical snapshots (np1 is the reference)
foreach(np 1 2 4)
  add_test(NAME snapshots_ranks_np${np}
    COMMAND bash ${CR_SNAP_CHECK} ranks ${np} $<TARGET_FILE:crowd_snapshots> ${CR_SNAP_IN}/snap_tiny.nml
    WORKING_DIRECTORY ${CR_SNAP_DIR})
  set_tests_properties(snapshots_ranks_np${np} PROPERTIES LABELS mpi ENVIRONMENT "${CR_SNAP_ENV}"
    PROCESSORS ${np})
endforeach()
set_tests_properties(snapshots_ranks_np1 PROPERTIES FIXTURES_SETUP snap_ref)
set_tests_properties(snapshots_ranks_np2 snapshots_ranks_np4 PROPERTIES FIXTURES_REQUIRED snap_ref)

# --stop-after, resume at another rank count; SIGKILL of a running mpirun, resume;
# a database or pieces of another configuration are refused
add_test(NAME snapshots_stop_resume
  COMMAND bash ${CR_SNAP_CHECK} stop_resume $<TARGET_FILE:crowd_snapshots> ${CR_SNAP_IN}/snap_tiny.nml
  WORKING_DIRECTORY ${CR_SNAP_DIR})
add_test(NAME snapshots_kill_resume
  COMMAND bash ${CR_SNAP_CHECK} kill_resume $<TARGET_FILE:crowd_snapshots> ${CR_SNAP_IN}/snap_kill.nml
  WORKING_DIRECTORY ${CR_SNAP_DIR})
add_test(NAME snapshots_mismatch
  COMMAND bash ${CR_SNAP_CHECK} mismatch $<TARGET_FILE:crowd_snapshots> ${CR_SNAP_IN}/snap_tiny.nml
    ${CR_SNAP_IN}/snap_tiny_other.nml
  WORKING_DIRECTORY ${CR_SNAP_DIR})
set_tests_properties(snapshots_stop_resume snapshots_kill_resume snapshots_mismatch PROPERTIES
  LABELS mpi ENVIRONMENT "${CR_SNAP_ENV}" PROCESSORS 2)
set_tests_properties(snapshots_stop_resume snapshots_mismatch PROPERTIES FIXTURES_REQUIRED snap_ref)

# pieces that cannot lie: corrupted, scaled, renamed and NaN pieces refused by name, then moved
# aside with --quarantine-bad-pieces and recomputed (h5py of the project venv)
add_test(NAME snapshots_corrupt_pieces
  COMMAND bash ${CR_SNAP_CHECK} corrupt $<TARGET_FILE:crowd_snapshots> ${CR_SNAP_IN}/snap_tiny.nml ${CR_PYTHON}
  WORKING_DIRECTORY ${CR_SNAP_DIR})
set_tests_properties(snapshots_corrupt_pieces PROPERTIES LABELS "mpi;regression" ENVIRONMENT "${CR_SNAP_ENV}"
  PROCESSORS 2 FIXTURES_REQUIRED snap_ref)

# bad input: clear message, nothing created, an existing file survives
function(cr_snap_bad case regex)
  add_test(NAME snapshots_bad_${case}
    COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/snap_expect_fail.sh "${regex}" bad_out.h5
      $<TARGET_FILE:crowd_snapshots> ${CR_SNAP_IN}/bad_study_${case}.nml
    WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  set_tests_properties(snapshots_bad_${case} PROPERTIES LABELS "regression;mpi" ENVIRONMENT "${CR_MPI_ENV}"
    RESOURCE_LOCK bad_out)
endfunction()
cr_snap_bad(param "&study: param_name\\(2\\) = 'exit_speed' is not a known parameter")
cr_snap_bad(range "&study: empty range for parameter 1 'l_exit'")
cr_snap_bad(zero "&study: n_train must be >= 1 \\(got 0: zero samples\\)")
cr_snap_bad(grid "&study: grid_n gives 6 training samples but n_train = 5")
cr_snap_bad(until_empty "&time: until_empty = .true. is not allowed in a study")
cr_snap_bad(spread "&study: param_min\\(2\\) = -1.00000E-01: the speed_spread range must be >= 0")
add_test(NAME snapshots_bad_stop_after_fom
  COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/expect_fail.sh "unknown option '--stop-after'" bad_out.h5
    $<TARGET_FILE:crowd_fom> ${CR_INPUTS}/bad_dt.nml --stop-after 2
  WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
set_tests_properties(snapshots_bad_stop_after_fom PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}"
  RESOURCE_LOCK bad_out)

