# The benchmark helper scripts still run (not timed: their figures go to docs/benchmarks.md).
# count_instructions.sh: instructions of the exact projection per step under callgrind, two steps
# of congested150; a non-zero count with no failed step and no fallback, and the one-line refusal
# of a missing input
add_test(NAME count_instructions_congested150
  COMMAND bash ${CMAKE_SOURCE_DIR}/scripts/bench/count_instructions.sh --fom $<TARGET_FILE:crowd_fom> --steps 2
    ${CMAKE_SOURCE_DIR}/inputs/congested150.nml)
set_tests_properties(count_instructions_congested150 PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}"
  PASS_REGULAR_EXPRESSION "instructions/step [0-9]*[1-9][0-9]*\\.[0-9]+ M .*failed 0  fallbacks 0")
add_test(NAME count_instructions_missing_input
  COMMAND bash ${CMAKE_SOURCE_DIR}/scripts/bench/count_instructions.sh --fom $<TARGET_FILE:crowd_fom> missing.nml)
set_tests_properties(count_instructions_missing_input PROPERTIES LABELS regression
  PASS_REGULAR_EXPRESSION "error: count_instructions.sh: cannot read input file 'missing.nml'")
