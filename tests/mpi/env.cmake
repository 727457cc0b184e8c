# env_t: the collectives and messages (test_env_checked), the variable-size integer gathers,
# text gather, measures, shared counter, nonblocking broadcast and MPI-IO block file (test_env_collectives)
cr_mpi_test(test_env_checked NP 1 2 3 LABELS "mpi;unit")
cr_mpi_test(test_env_collectives NP 1 2)
# MPI errors returned, not fatal (MPI_ERRORS_RETURN on env's communicator and windows): an
# error with code 4 naming the call (where MPI errors are fatal the job aborts: the test fails)
cr_mpi_test(test_env_mpi_error NP 1 2 3)
set_tests_properties(test_env_mpi_error_np1 test_env_mpi_error_np2 test_env_mpi_error_np3 PROPERTIES TIMEOUT 120)
# rank 1 alone fails in a receive while rank 0 waits in the error agreement: its one line is printed and
# MPI_Abort ends the job with status 4 (timeout 60 s: a hang fails the test)
add_test(NAME env_mpi_error_abort_np2
  COMMAND bash -c "out=$(timeout -k 10 60 \"$0\" -np 2 --oversubscribe \"$1\" abort 2>&1); rc=$?; echo \"$out\"; \
echo \"exit status $rc\"; [ $rc -eq 4 ] && \
[ $(grep -c '^error: rank 1 of 2: env: MPI_Recv of 2 integer(s) from rank 0 failed: ' <<<\"$out\") -eq 1 ] && \
[ $(grep -c '^error:' <<<\"$out\") -eq 1 ]"
    ${MPIEXEC_EXECUTABLE} $<TARGET_FILE:test_env_mpi_error>
  WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
set_tests_properties(env_mpi_error_abort_np2 PROPERTIES LABELS mpi ENVIRONMENT "${CR_MPI_ENV}" PROCESSORS 2
  TIMEOUT 90)
# error agreement across ranks (docs/testing.md#careless-and-hostile-use)
cr_mpi_test(test_env_error NP 1 2 3)
# rank 1 alone fails at 2 ranks: its message and rank are printed exactly once
add_test(NAME env_error_printed_np2
  COMMAND bash -c "out=$(\"$0\" -np 2 --oversubscribe \"$1\" print 2>&1); rc=$?; echo \"$out\"; \
[ $rc -eq 3 ] && [ $(grep -c '^error: rank 1 of 2: disk on fire at step 7$' <<<\"$out\") -eq 1 ] && \
[ $(grep -c '^error:' <<<\"$out\") -eq 1 ]"
    ${MPIEXEC_EXECUTABLE} $<TARGET_FILE:test_env_error>
  WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
set_tests_properties(env_error_printed_np2 PROPERTIES LABELS mpi ENVIRONMENT "${CR_MPI_ENV}" PROCESSORS 2)
