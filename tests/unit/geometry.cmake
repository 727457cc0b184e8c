cr_unit_test(test_shapes)
cr_unit_test(test_distance_field)
cr_unit_test(test_geodesic)
