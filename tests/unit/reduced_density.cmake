# reduced density: the reduced step scales the speeds of the assembly's agents only, equal to
# every agent's density to round-off
cr_unit_test(test_reduced_density)
