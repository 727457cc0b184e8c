# Unit tests of the GPCG projection solver.
cr_unit_test(test_gpcg)
