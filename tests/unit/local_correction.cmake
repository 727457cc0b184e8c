# Local exact correction of a reduced velocity (src/rom/cr_local_correction.f90).
cr_unit_test(test_local_correction)
