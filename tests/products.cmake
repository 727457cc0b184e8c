# Inter-stage products (src/products): round trips at 1 and 2 ranks, corrupt-file families
cr_mpi_test(test_products NP 1 2)
# The full-order writer's buffer of output states: buffer sizes 1, 3, 4, large, default
# against the states recorded during the run; abort with buffered states
cr_unit_test(test_fom_buffer)
