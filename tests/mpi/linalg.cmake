# Linear algebra: LAPACK wrappers (serial) and the POD methods (same program at 1, 2, 4 ranks).
cr_mpi_test(test_pod NP 1 2 4)
