# Hyper-reduction: EIM (POD + DEIM) and empirical quadrature (Gramian + greedy), 1, 2, 4 ranks.
cr_mpi_test(test_hyper NP 1 2 4 LABELS "mpi;unit")
cr_mpi_test(test_hyper_methods NP 1 2 LABELS "mpi;unit")
