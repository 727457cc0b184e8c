# Exact position projection of ML-corrected positions (src/fom/cr_position_projection.f90).
cr_unit_test(test_position_projection)
