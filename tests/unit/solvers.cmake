# Unit tests of the projection solvers (NNLS / LDP kernels and the three projection methods).
cr_unit_test(test_nnls)
cr_unit_test(test_projection)
cr_unit_test(test_contact_ldp)
# a warm-started problem on which the dense kernel once reported convergence at KKT 1e22
cr_unit_test(test_ldp_replay ARGS ${CMAKE_CURRENT_SOURCE_DIR}/reference/ldp_warm_illconditioned.bin)
cr_unit_test(test_nnls_edge)
# reduced time stepping: infeasible reduced problems, Uzawa caps (also a case of the extremes campaign)
cr_unit_test(test_rom_stepper LABELS "unit;extremes")
# dual active-set reduced solver against the LDP: random, degenerate, infeasible; warm = cold
cr_unit_test(test_dual_qp)
cr_unit_test(test_sparse_as)
