# I/O layer: HDF5 file handle and JSON writer
cr_unit_test(test_h5file)
cr_unit_test(test_json)
