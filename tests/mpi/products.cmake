# Inter-stage products (src/products): round trips at 1 and 2 ranks, corrupt-file families
cr_mpi_test(test_products NP 1 2)
