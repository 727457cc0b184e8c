# Numerical stability at the extremes (docs/testing.md): label `extremes`, one test per case of
# scripts/dev/extremes_cases.py, each run at small size on this build and checked by
# scripts/dev/extremes_report.py --check (the full-size campaign is scripts/dev/extremes_report.py).
set(CR_EXT_SCRIPT ${CMAKE_SOURCE_DIR}/scripts/dev/extremes_report.py)
set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS
  ${CMAKE_SOURCE_DIR}/scripts/dev/extremes_cases.py ${CR_EXT_SCRIPT})
execute_process(COMMAND ${CR_PYTHON} ${CR_EXT_SCRIPT} --list
  OUTPUT_VARIABLE cr_ext_list RESULT_VARIABLE cr_ext_rc ERROR_VARIABLE cr_ext_err)
if(NOT cr_ext_rc EQUAL 0)
  message(FATAL_ERROR "scripts/dev/extremes_report.py --list failed: ${cr_ext_err}")
endif()
# each output line is "name;ranks": the list alternates names and rank counts
string(REPLACE "\n" ";" cr_ext_items "${cr_ext_list}")
list(FILTER cr_ext_items EXCLUDE REGEX "^$")
file(MAKE_DIRECTORY ${CMAKE_BINARY_DIR}/tests/extremes)
list(LENGTH cr_ext_items n)
math(EXPR last "${n} - 1")
foreach(i RANGE 0 ${last} 2)
  math(EXPR j "${i} + 1")
  list(GET cr_ext_items ${i} name)
  list(GET cr_ext_items ${j} np)
  add_test(NAME extremes_${name}
    COMMAND ${CR_PYTHON} ${CR_EXT_SCRIPT} --check ${name} --bin ${CMAKE_BINARY_DIR}/bin
      --workdir ${CMAKE_BINARY_DIR}/tests/extremes
    WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  set_tests_properties(extremes_${name} PROPERTIES LABELS extremes TIMEOUT 300 PROCESSORS ${np}
    ENVIRONMENT "${CR_MPI_ENV}" FAIL_REGULAR_EXPRESSION "0 passed, 1 failed")
endforeach()
