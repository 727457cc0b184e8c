cr_mpi_test(test_env_checked NP 1 2 3 LABELS "mpi;unit")
