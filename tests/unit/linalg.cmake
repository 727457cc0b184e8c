# Linear algebra: LAPACK wrappers (serial) and the POD methods (same program at 1, 2, 4 ranks).
cr_unit_test(test_lapack)
