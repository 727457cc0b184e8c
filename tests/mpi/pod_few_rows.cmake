# ScaLAPACK POD with fewer rows than ranks (pdgesvd's processes disagree in the last bits)
cr_mpi_test(test_pod_few_rows NP 1 2 4 LABELS "mpi;unit")
