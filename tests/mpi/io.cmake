# I/O layer: HDF5 file handle and JSON writer
cr_mpi_test(test_h5file_mpi NP 1 2 4)
