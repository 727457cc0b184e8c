# Reduced-model measures: metrics on a synthetic study with a known answer, divergence guard.
cr_unit_test(test_rom_metrics)
