# Near ties broken by index in the distributed selections (env_t allreduce_near_maxloc, gIS, mCPG)
cr_mpi_test(test_ties NP 1 2 4 LABELS "mpi;unit")
