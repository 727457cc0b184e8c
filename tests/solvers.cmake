# Unit tests of the projection solvers (NNLS / LDP kernels and the three projection methods).
cr_unit_test(test_nnls)
cr_unit_test(test_projection)
cr_unit_test(test_contact_ldp)
cr_unit_test(test_nnls_edge)
