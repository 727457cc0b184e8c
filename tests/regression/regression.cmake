# Regression tier: drivers on small inputs, bad-input cases that must fail cleanly.
set(CR_INPUTS ${CMAKE_CURRENT_SOURCE_DIR}/inputs)
file(GLOB CR_INPUT_TEMPLATES ${CR_INPUTS}/*.nml.in)
foreach(t ${CR_INPUT_TEMPLATES})
  get_filename_component(n ${t} NAME)
  string(REPLACE ".in" "" n ${n})
  configure_file(${t} ${CMAKE_BINARY_DIR}/tests/inputs/${n} @ONLY)
endforeach()

# cr_bad_input(case regex): crowd_fom on inputs/bad_<case>.nml must fail with a message
function(cr_bad_input case regex)
  if(EXISTS ${CR_INPUTS}/bad_${case}.nml)
    set(input ${CR_INPUTS}/bad_${case}.nml)
  else()
    set(input ${CMAKE_BINARY_DIR}/tests/inputs/bad_${case}.nml)
  endif()
  add_test(NAME bad_input_${case}
    COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/expect_fail.sh "${regex}" bad_out.h5 $<TARGET_FILE:crowd_fom> ${input}
    WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  set_tests_properties(bad_input_${case} PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}"
    RESOURCE_LOCK bad_out)
endfunction()

cr_bad_input(misspelt "namelist group &agents.*radus")
cr_bad_input(negative_radius "&agents: radius must be > 0")
cr_bad_input(too_many "&agents: n_agents = 1000.*more agents than fit")
cr_bad_input(missing_file "&agents: init_file: cannot open 'no_such_positions.txt'")
cr_bad_input(exit_wider "&scene: l_exit = .* is wider than the wall")
cr_bad_input(unknown_group "unknown namelist group &agent ")
# a group or a variable no program reads is refused by every program (crowd_fom used to accept
# "&hyper eq_tol = 1e-3 /" silently); a variable in the wrong group names that group
cr_bad_input(unread_group "unknown namelist group &basis ")
cr_bad_input(unread_variable "namelist group &hyper: .*eq_toll")
cr_bad_input(misplaced "namelist group &cone: .*energy")
cr_bad_input(solver "&solver: .*newton.*uzawa")
cr_bad_input(same_position "agents 1 and 3 are at the same position")
cr_bad_input(inside_obstacle "agent 2 starts inside obstacle '&obstacles disk 1'")
cr_bad_input(desired_field "&desired: field must be 'auto', 'analytic', 'grid' or 'exact' \\(got 'exakt'\\)")
cr_bad_input(desired_exact "&desired: field = 'exact' does not apply to this scene: the exit")
cr_bad_input(dt "&time: dt must be > 0")
cr_bad_input(dense_rows "&solver: .*dense_rows must be >= 0")
cr_bad_input(refresh_every "&solver: .*refresh_every must be >= 1")
cr_bad_input(social_negative "&agents: social_distance must be >= 0 \\(got -1.0")
cr_bad_input(social_exit "&agents: social_distance = 2.5.* leaves no passage through the exit \\(2 radius")
cr_bad_input(diagram_speed "&agents: speed = 0.* is the free speed of &desired speed_model = 'weidmann' and must be > 0")
cr_bad_input(diagram_model "&desired: speed_model must be 'constant' or 'weidmann' \\(got 'weidman'\\)")
add_test(NAME bad_input_missing_namelist
  COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/expect_fail.sh "no_such_input.nml: cannot open input file" bad_out.h5
    $<TARGET_FILE:crowd_fom> no_such_input.nml
  WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
add_test(NAME bad_input_unknown_option
  COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/expect_fail.sh "unknown option '--frobnicate'" bad_out.h5
    $<TARGET_FILE:crowd_fom> ${CR_INPUTS}/bad_dt.nml --frobnicate
  WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
set_tests_properties(bad_input_missing_namelist bad_input_unknown_option PROPERTIES LABELS regression
  ENVIRONMENT "${CR_MPI_ENV}" RESOURCE_LOCK bad_out)

add_executable(test_fom_scenes ${CMAKE_CURRENT_LIST_DIR}/test_fom_scenes.f90)
target_link_libraries(test_fom_scenes PRIVATE cr_assert)
set_target_properties(test_fom_scenes PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
add_test(NAME test_fom_scenes COMMAND test_fom_scenes ${CMAKE_SOURCE_DIR}/inputs
  WORKING_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
set_tests_properties(test_fom_scenes PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}")
