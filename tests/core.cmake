cr_unit_test(test_core)
cr_unit_test(test_model)
cr_unit_test(test_config)
cr_unit_test(test_key_map)
