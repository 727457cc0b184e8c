# The parameter-to-model mapping (src/model/cr_param_model)
cr_unit_test(test_param_model)
