# Foreign inputs, output paths naming inputs, hostile values, output faults
# (docs/testing.md#careless-and-hostile-use).

# Foreign inputs (empty, blank, binary, HDF5, JSON, CSV, text, another program's
# input) are refused by each program with one line, exit 2, nothing written.
set(CR_EX ${CMAKE_SOURCE_DIR}/inputs)
foreach(p crowd_fom crowd_snapshots crowd_offline crowd_rom crowd_predict)
  if(p STREQUAL crowd_rom OR p STREQUAL crowd_predict)
    set(others ${CR_EX}/hall20.nml ${CR_EX}/hall20_study.nml)
  elseif(p STREQUAL crowd_fom)
    set(others ${CR_EX}/hall20_rom.nml)
  else()
    set(others ${CR_EX}/hall20.nml ${CR_EX}/hall20_rom.nml)
  endif()
  add_test(NAME foreign_input_${p}
    COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/foreign_input.sh $<TARGET_FILE:${p}> ${others})
  set_tests_properties(foreign_input_${p} PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}")
endforeach()

# crowd_podbench takes sizes on the command line: bad ones are refused with one line
# cr_refused(name regex command args...): expect_refusal.sh in an empty scratch directory
function(cr_refused name regex)
  add_test(NAME ${name} COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/expect_refusal.sh "${regex}" ${ARGN})
  set_tests_properties(${name} PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}")
endfunction()
cr_refused(podbench_args_word "argument 1 'x' is not a whole number" $<TARGET_FILE:crowd_podbench> x 3)
cr_refused(podbench_args_odd "arguments are pairs" $<TARGET_FILE:crowd_podbench> 5)
cr_refused(podbench_args_zero "argument 2 = 0 must be in" $<TARGET_FILE:crowd_podbench> 5 0)
cr_refused(podbench_args_negative "argument 1 = -3 must be in" $<TARGET_FILE:crowd_podbench> -3 4)
cr_refused(podbench_args_real "argument 1 '1e99' is not a whole number" $<TARGET_FILE:crowd_podbench> 1e99 5)
cr_refused(podbench_args_huge "n_dof \\* n_snap exceeds" $<TARGET_FILE:crowd_podbench> 100000 100000)
# crowd_geobench (through cr_program like the other drivers): bad command lines, a missing input
cr_refused(geobench_no_input "crowd_geobench: no input file given" $<TARGET_FILE:crowd_geobench>)
cr_refused(geobench_args_repeats "repeats must be a positive integer, got '0'" $<TARGET_FILE:crowd_geobench>
  ${CMAKE_SOURCE_DIR}/inputs/hall20.nml 0)
cr_refused(geobench_missing_input "missing.nml: cannot open input file" $<TARGET_FILE:crowd_geobench> missing.nml)

# Hostile namelist values (Inf, NaN, 1e308, 1e-308, 2147483647, size
# products that overflow), a generated family per program
foreach(p crowd_fom crowd_snapshots crowd_offline crowd_rom crowd_predict)
  add_test(NAME hostile_values_${p}
    COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/hostile_values.sh ${p} $<TARGET_FILE:${p}>)
  set_tests_properties(hostile_values_${p} PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}")
endforeach()

# An output naming an input (./x, dir/../x, absolute, symbolic link), outputs that
# coincide, a missing directory, a directory under the output's name: a family per program
foreach(p crowd_fom crowd_snapshots crowd_offline crowd_rom crowd_predict)
  add_test(NAME output_paths_${p}
    COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/output_paths.sh ${p} $<TARGET_FILE:${p}>)
  set_tests_properties(output_paths_${p} PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}")
endforeach()

# Full disk (a 64 KiB and larger tmpfs) and a read-only file system (root only, skipped
# otherwise): one error line saying
# why, old output kept, no temporary, clean MPI shutdown (no SIGSEGV), every program
add_test(NAME full_disk
  COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/full_disk.sh $<TARGET_FILE_DIR:crowd_fom> ${MPIEXEC_EXECUTABLE}
    ${CMAKE_CURRENT_SOURCE_DIR}/inputs/snap_tiny.nml)
set_tests_properties(full_disk PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}" SKIP_RETURN_CODE 77
  PROCESSORS 2)

# crowd_offline refuses a study that contradicts the database it reads (one
# variable changed per case: scene, obstacles, agents, time, solver, study), accepts its own
add_test(NAME offline_mismatch
  COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/offline_mismatch.sh $<TARGET_FILE_DIR:crowd_fom>
    ${CMAKE_CURRENT_SOURCE_DIR}/inputs/snap_tiny.nml)
set_tests_properties(offline_mismatch PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}")
# crowd_snapbench (through cr_program): bad sizes, and a scratch path that exists is never overwritten
cr_refused(snapbench_args_mb "argument 2 \\(mb\\) must be a positive number of megabytes, got 'abc'"
  $<TARGET_FILE:crowd_snapbench> scratch.tmp abc)
cr_refused(snapbench_args_block "argument 3 \\(block\\) must be a positive multiple of 8 bytes, got '12'"
  $<TARGET_FILE:crowd_snapbench> scratch.tmp 1 12)
cr_refused(snapbench_existing_scratch "scratch file '.*CMakeLists.txt' exists already"
  $<TARGET_FILE:crowd_snapbench> ${CMAKE_CURRENT_SOURCE_DIR}/CMakeLists.txt 1)

# crowd_project's request: files it cannot open (empty, truncated, random bytes, superblock
# zeroed, text, folder, empty argument, namelist, missing, another product) and parameters that
# give no valid scene, each refused with one line and exit 2 (h5py of the project venv)
add_test(NAME project_requests
  COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/helpers/project_requests.sh $<TARGET_FILE_DIR:crowd_project>
    ${CMAKE_CURRENT_SOURCE_DIR}/inputs/snap_tiny.nml ${CR_PYTHON})
set_tests_properties(project_requests PROPERTIES LABELS regression ENVIRONMENT "${CR_MPI_ENV}")
