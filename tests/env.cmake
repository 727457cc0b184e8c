# env_t: the collectives and messages (test_env_checked), the variable-size integer gathers,
# text gather, measures, shared counter, nonblocking broadcast and MPI-IO block file (test_env_collectives)
cr_mpi_test(test_env_checked NP 1 2 3 LABELS "mpi;unit")
cr_mpi_test(test_env_collectives NP 1 2)
