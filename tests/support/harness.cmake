# The test harness itself. The assertion module: a test program that ran no check fails
# (test_summary), and the same program with one check passes.
add_executable(test_assert_no_check ${CMAKE_CURRENT_LIST_DIR}/test_assert_no_check.f90)
target_link_libraries(test_assert_no_check PRIVATE cr_assert)
set_target_properties(test_assert_no_check PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
add_test(NAME assert_no_check_fails
  COMMAND sh -c "out=$(\"$0\" 2>&1); rc=$?; echo \"$out\"; [ $rc -ne 0 ] && echo \"$out\" | grep -q '^FAIL: no check ran$'"
    $<TARGET_FILE:test_assert_no_check>)
add_test(NAME assert_one_check_passes COMMAND test_assert_no_check 1)
set_tests_properties(assert_no_check_fails assert_one_check_passes PROPERTIES LABELS unit)

# A missing test prerequisite stops the configuration of the tests with one message naming it
# and scripts/setup.sh (here: a Python that does not exist), instead of leaving tests out.
add_test(NAME tests_need_their_prerequisites
  COMMAND sh -c "out=$(\"$0\" -S \"$1\" -B \"$2\" -G \"$3\" -DCROWDROM_TEST_PYTHON=/nonexistent/python 2>&1); rc=$?; rm -rf \"$2\"; echo \"$out\"; [ $rc -ne 0 ] && echo \"$out\" | tr -s ' \\n' ' ' | grep -q 'crowdrom tests: missing the Python venv /nonexistent/python.*scripts/setup.sh'"
    ${CMAKE_COMMAND} ${CMAKE_SOURCE_DIR} ${CMAKE_BINARY_DIR}/tests/prerequisites.tmp ${CMAKE_GENERATOR})
set_tests_properties(tests_need_their_prerequisites PROPERTIES LABELS regression TIMEOUT 300)
