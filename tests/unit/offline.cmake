cr_unit_test(test_hertz)
