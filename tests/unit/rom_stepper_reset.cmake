# reduced stepper: each step judged by its own dual solver flags (statistics reset every step)
cr_unit_test(test_rom_stepper_reset)
