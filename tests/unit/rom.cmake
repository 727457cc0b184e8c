# Reduced-model measures: metrics on a synthetic study with a known answer, divergence guard.
cr_unit_test(test_rom_metrics)
# reduced solvers: the factory builds each named variant and refuses unknown names
cr_unit_test(test_reduced_solver)
