!> Desired-velocity benchmark: per-sample setup time (what a study pays for every parameter
!> sample) and per-step evaluation time at all agents, for the models 'grid' (fast-sweeping
!> field, grid_dx from the input or radius / 4), 'exact' (tangent graph) and 'auto'; and the
!> largest difference of the desired directions between grid and exact at the initial positions.
!>
!> Usage: crowd_geobench input.nml [repeats]   (serial; default 20 repeats; prints a table)
program crowd_geobench
  use mpi_f08
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t
  use cr_config, only: config_t, read_config, desired_cfg_t
  use cr_config_check, only: check_config
  use cr_scene, only: scene_t
  use cr_desired, only: desired_t
  use cr_placement, only: place_agents
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  type(config_t) :: cfg
  type(scene_t) :: scene
  type(desired_t) :: des
  type(desired_cfg_t) :: dc
  real(wp), allocatable :: q(:), speeds(:), v(:), vgrid(:), vexact(:)
  character(len=512) :: path, arg
  character(len=8), parameter :: models(3) = [character(len=8) :: 'grid', 'exact', 'auto']
  integer :: ierr, repeats, it, m, na, nit, i, n_eval
  real(wp) :: t0, t_setup, t_eval, dmax

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  if (command_argument_count() < 1) then
    write(*, '(a)') "usage: crowd_geobench input.nml [repeats]"
    call MPI_Finalize(ierr)
    stop 2, quiet=.true.
  end if
  call get_command_argument(1, path)
  if (trim(path) == '--help' .or. trim(path) == '-h') then
    write(*, '(a)') "usage: crowd_geobench input.nml [repeats]"
    write(*, '(a)') "times the desired-velocity models 'grid', 'exact' and 'auto' on the scene and initial"
    write(*, '(a)') "placement of input.nml: setup per sample and evaluation at all agents (serial)"
    call MPI_Finalize(ierr)
    stop
  end if
  repeats = 20
  if (command_argument_count() >= 2) then
    call get_command_argument(2, arg)
    read(arg, *, iostat=ierr) repeats
    if (ierr /= 0 .or. repeats < 1) call fail("crowd_geobench: repeats must be a positive integer")
  end if
  call read_config(trim(path), env, cfg, error); if (allocated(error)) call fail(error%message)
  call check_config(cfg, error); if (allocated(error)) call fail(error%message)
  call scene%init(cfg%scene, cfg%obstacles, error); if (allocated(error)) call fail(error%message)
  call place_agents(cfg%agents, scene, q, nit, error); if (allocated(error)) call fail(error%message)
  na = cfg%agents%n_agents
  allocate(speeds(na), v(2 * na), vgrid(2 * na), vexact(2 * na))
  speeds = 1.0_wp
  n_eval = max(1, 2000 / max(na, 1)) * repeats

  write(*, '(a)') "input: " // trim(path) // " (" // trim(adjustl(itoa(na))) // " agents, " // &
    trim(adjustl(itoa(scene%n_interior()))) // " interior obstacles); times per call, mean of " // &
    trim(adjustl(itoa(repeats))) // " setups and " // trim(adjustl(itoa(n_eval))) // " evaluations"
  write(*, '(a)') ""
  write(*, '(a)') "| model | used | setup per sample (ms) | evaluation at all agents (us) | per agent (us) |"
  write(*, '(a)') "|---|---|---:|---:|---:|"
  do m = 1, size(models)
    dc = cfg%desired
    dc%mode = 'geodesic'
    dc%field = models(m)
    t0 = env%wtime()
    do it = 1, repeats
      call des%init(dc, scene, cfg%agents%radius, na, error)
      if (allocated(error)) call fail(error%message)
    end do
    t_setup = (env%wtime() - t0) / repeats
    t0 = env%wtime()
    do it = 1, n_eval
      call des%evaluate(q, speeds, v)
    end do
    t_eval = (env%wtime() - t0) / n_eval
    if (models(m) == 'grid') vgrid = v
    if (models(m) == 'exact') vexact = v
    write(*, '(a, f0.4, a, f0.2, a, f0.3, a)') "| " // trim(models(m)) // " | " // des%model_name() // " | ", &
      1.0e3_wp * t_setup, " | ", 1.0e6_wp * t_eval, " | ", 1.0e6_wp * t_eval / na, " |"
  end do
  dmax = 0.0_wp
  do i = 1, na
    dmax = max(dmax, norm2(vgrid(2*i-1:2*i) - vexact(2*i-1:2*i)))
  end do
  write(*, '(a)') ""
  write(*, '(a, es10.3)') "largest |d_grid - d_exact| over agents at the initial positions: ", dmax
  call env%free()
  call MPI_Finalize(ierr)

contains

  function itoa(k) result(s)
    integer, intent(in) :: k
    character(len=16) :: s
    write(s, '(i0)') k
  end function itoa

  subroutine fail(msg)
    character(len=*), intent(in) :: msg
    write(*, '(a)') "error: " // msg
    call MPI_Finalize(ierr)
    stop 2, quiet=.true.
  end subroutine fail
end program crowd_geobench
