# Quantities of interest: closed-form trajectories (per-exit curves, times, censoring, flows, trust).
cr_unit_test(test_qoi)
