# Quantities of interest: closed-form trajectories (per-exit curves, times, censoring, flows, trust);
# the QoI product and group: round trip, refusals (sizes, schema version, checksum).
cr_unit_test(test_qoi)
cr_unit_test(test_qoi_file)
