!> Unit tests of namelist reading and validation: values, defaults of absent groups,
!> arrays, and every problem reported at once.
program test_config
  use mpi_f08
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: config_t, read_config, config_echo
  use cr_config_check, only: check_config
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  type(env_t) :: env
  type(config_t) :: cfg
  type(error_t), allocatable :: error
  integer :: ierr, u
  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)

  open(newunit=u, file='cfg_good.nml', status='replace')
  write(u, '(a)') "! comment line with &notagroup inside a comment"
  write(u, '(a)') "&scene hall_length = 2.0, l_exit = 0.32 /"
  write(u, '(a)') "&obstacles n_disks = 2, disk_x = 1.0, 1.5, disk_y = 0.6, 0.2, disk_r = 0.15, 0.05"
  write(u, '(a)') "  n_polygons = 1, poly_nv(1) = 3, poly_x(1:3,1) = 0.2, 0.4, 0.3, poly_y(1:3,1) = 0.2, 0.2, 0.4 /"
  write(u, '(a)') "&agents n_agents = 150, speed = 5.0 /"
  write(u, '(a)') "&solver name = 'apgd', tol = 1e-9 /"
  close(u)
  call read_config('cfg_good.nml', env, cfg, error)
  call check(.not. allocated(error), "good file reads")
  call check_close(cfg%scene%hall_length, 2.0_wp, 0.0_wp, "scene value")
  call check_close(cfg%scene%hall_width, 1.0_wp, 0.0_wp, "scene default kept")
  call check(cfg%obstacles%n_disks == 2 .and. cfg%obstacles%disk_x(2) == 1.5_wp, "disk arrays")
  call check(cfg%obstacles%poly_nv(1) == 3 .and. cfg%obstacles%poly_y(3, 1) == 0.4_wp, "polygon arrays")
  call check(cfg%agents%n_agents == 150 .and. cfg%agents%radius == 0.05_wp, "agents values + default")
  call check(trim(cfg%solver%name) == 'apgd' .and. cfg%solver%tol == 1e-9_wp, "solver values")
  call check(cfg%time%dt == 0.05_wp, "absent group keeps defaults")
  call check_config(cfg, error)
  call check(.not. allocated(error), "good file validates")
  ! the echo is a namelist file that reads back to the same configuration
  open(newunit=u, file='cfg_echo.nml', status='replace')
  write(u, '(a)') config_echo(cfg)
  close(u)
  block
    type(config_t) :: again
    call read_config('cfg_echo.nml', env, again, error)
    call check(.not. allocated(error), "echo reads back")
    call check(again%obstacles%poly_x(3, 1) == cfg%obstacles%poly_x(3, 1) .and. &
      again%obstacles%disk_r(2) == cfg%obstacles%disk_r(2) .and. again%scene%l_exit == cfg%scene%l_exit .and. &
      again%agents%n_agents == cfg%agents%n_agents .and. trim(again%solver%name) == 'apgd' .and. &
      again%solver%tol == cfg%solver%tol, "echo round trip is exact")
  end block

  open(newunit=u, file='cfg_bad.nml', status='replace')
  write(u, '(a)') "&agents n_agents = 0, radius = -1 /"
  write(u, '(a)') "&time dt = -0.1 /"
  write(u, '(a)') "&output every = 0 /"
  close(u)
  call read_config('cfg_bad.nml', env, cfg, error)
  call check(.not. allocated(error), "bad values still parse")
  call check_config(cfg, error)
  call check(allocated(error), "bad values rejected")
  if (allocated(error)) then
    call check(index(error%message, "cfg_bad.nml") > 0, "message names the file")
    call check(index(error%message, "&agents: n_agents") > 0, "reports n_agents")
    call check(index(error%message, "&agents: radius") > 0, "reports radius")
    call check(index(error%message, "&time: dt") > 0, "reports dt")
    call check(index(error%message, "&output: every") > 0, "reports every (all problems at once)")
    call check(error%code == EXIT_BAD_INPUT, "bad input code 2")
  end if

  open(newunit=u, file='cfg_twice.nml', status='replace')
  write(u, '(a)') "&time dt = 0.1 /"
  write(u, '(a)') "&time dt = 0.2 /"
  close(u)
  call read_config('cfg_twice.nml', env, cfg, error)
  call check(allocated(error), "group twice rejected")
  if (allocated(error)) call check(index(error%message, "&time appears twice") > 0, "twice message")

  open(newunit=u, file='cfg_type.nml', status='replace')
  write(u, '(a)') "&time n_steps = 'many' /"
  close(u)
  call read_config('cfg_type.nml', env, cfg, error)
  call check(allocated(error), "wrong type rejected")
  if (allocated(error)) call check(index(error%message, "namelist group &time") > 0, "type error names group")

  call env%free()
  call MPI_Finalize(ierr)
  call test_summary()
end program test_config
