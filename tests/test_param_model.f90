!> cr_param_model: the one parameter-to-model mapping. The component names written to the files
!> rebuild the same mapping; apply sets l_exit and the speeds; scene_of moves the exit; unknown
!> components are refused.
program test_param_model
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: config_t
  use cr_scene, only: scene_t
  use cr_desired, only: desired_t
  use cr_param_model, only: param_model_t
  implicit none
  type(param_model_t) :: a, b
  type(config_t) :: cfg
  type(scene_t) :: sc
  type(desired_t) :: des
  type(error_t), allocatable :: error
  real(wp), allocatable :: sp(:)
  real(wp) :: mu(5)

  call a%init_model([character(len=8) :: 'l_exit', 'speeds'], 4)
  call check(a%n_expanded == 5 .and. a%component_names() == "l_exit,speed_1,speed_2,speed_3,speed_4", &
    "expansion and component names")
  call b%init_from_components(a%component_names(), 4, error)
  call check(.not. allocated(error), "components read back")
  call check(b%n_params == 2 .and. all(b%first == a%first) .and. all(b%width == a%width) .and. &
    all(b%names == a%names), "the same mapping from the stored names")
  call b%init_from_components("l_exit,speed", 4, error)
  call check(.not. allocated(error) .and. b%n_expanded == 2, "l_exit and one common speed")
  call b%init_from_components("l_exit,width", 4, error)
  call check(allocated(error), "unknown component refused")
  if (allocated(error)) call check(index(error%message, "'width'") > 0, "message names the component")
  call b%init_from_components("speed_1,speed_2", 4, error)
  call check(allocated(error), "components for another number of agents refused")

  mu = [0.2_wp, 1.0_wp, 2.0_wp, 3.0_wp, 4.0_wp]
  call a%sample_model(mu, cfg, [9.0_wp, 9.0_wp, 9.0_wp, 9.0_wp], 0.05_wp, sc, sp, des, error)
  call check(.not. allocated(error), "sample model built")
  call check(all(sp == mu(2:5)), "speeds of the sample")
  call check_close(sc%x_hi - sc%x_lo, 0.2_wp, 1.0e-14_wp, "exit width of the sample")
  call a%scene_of(mu, cfg, sc, error)
  call check(.not. allocated(error), "scene_of")
  call check_close(sc%l_exit, 0.2_wp, 0.0_wp, "scene_of applies l_exit")
  call test_summary()
end program test_param_model
