cr_mpi_test(test_cone NP 1 2 4 LABELS "mpi;unit")
cr_mpi_test(test_enrichment NP 1 2 4 LABELS "mpi;unit")
