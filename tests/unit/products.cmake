# The full-order writer's buffer of output states: buffer sizes 1, 3, 4, large, default
# against the states recorded during the run; abort with buffered states
cr_unit_test(test_fom_buffer)
