!> Desired-velocity benchmark: per-sample setup time (what a study pays for every parameter
!> sample) and per-step evaluation time at all agents, for the models 'grid' (fast-sweeping
!> field, grid_dx from the input or radius / 4), 'exact' (tangent graph) and 'auto'; and the
!> largest difference of the desired directions between grid and exact at the initial positions.
!>
!> Usage: crowd_geobench input.nml [repeats]   (serial; default 20 repeats; prints a table)
!> Start and end through cr_program (MPI, one `error:` line, exit 2 for bad input).
program crowd_geobench
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_config, only: config_t, read_config, desired_cfg_t
  use cr_config_check, only: check_config
  use cr_scene, only: scene_t
  use cr_desired, only: desired_t
  use cr_placement, only: place_agents
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(error_t), allocatable :: error
  character(len=:), allocatable :: path
  integer :: repeats, code
  logical :: help

  call program_start("crowd_geobench", env, log, cli, error, own_arguments=.true.)
  if (.not. allocated(error)) call read_arguments(path, repeats, help, error)
  if (.not. allocated(error)) then
    if (help) then
      if (env%is_root()) then
        write(*, '(a)') "usage: crowd_geobench input.nml [repeats]"
        write(*, '(a)') "times the desired-velocity models 'grid', 'exact' and 'auto' on the scene and initial"
        write(*, '(a)') "placement of input.nml: setup per sample and evaluation at all agents (serial)"
      end if
    else
      call run(path, repeats, error)
    end if
  end if
  code = program_finish(env, log, error)
  if (code /= 0) stop code, quiet=.true.

contains

  !> The command line: input.nml [repeats] (repeats >= 1, default 20), or -h / --help.
  subroutine read_arguments(path, repeats, help, error)
    character(len=:), allocatable, intent(out) :: path
    integer, intent(out) :: repeats
    logical, intent(out) :: help
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: arg
    integer :: ios
    help = .false.
    repeats = 20
    if (command_argument_count() < 1) then
      call set_error(error, "crowd_geobench: no input file given (usage: crowd_geobench input.nml [repeats])", EXIT_BAD_INPUT)
      return
    end if
    path = argument(1)
    if (path == '--help' .or. path == '-h') then
      help = .true.; return
    end if
    if (command_argument_count() >= 2) then
      arg = argument(2)
      read(arg, *, iostat=ios) repeats
      if (ios /= 0 .or. repeats < 1) then
        call set_error(error, "crowd_geobench: repeats must be a positive integer, got '" // arg // "'", EXIT_BAD_INPUT); return
      end if
    end if
  end subroutine read_arguments

  !> Command-line argument k.
  function argument(k) result(arg)
    integer, intent(in) :: k
    character(len=:), allocatable :: arg
    integer :: length
    call get_command_argument(k, length=length)
    allocate(character(len=length) :: arg)
    call get_command_argument(k, arg)
  end function argument

  !> The benchmark of the input `path`, `repeats` setups per model (the table on rank 0).
  subroutine run(path, repeats, error)
    character(len=*), intent(in) :: path
    integer, intent(in) :: repeats
    type(error_t), allocatable, intent(out) :: error
    character(len=8), parameter :: models(3) = [character(len=8) :: 'grid', 'exact', 'auto']
    type(config_t) :: cfg
    type(scene_t) :: scene
    type(desired_t) :: des
    type(desired_cfg_t) :: dc
    real(wp), allocatable :: q(:), speeds(:), v(:), vgrid(:), vexact(:)
    integer :: it, m, na, nit, i, n_eval
    real(wp) :: t0, t_setup, t_eval, dmax
    logical :: root
    root = env%is_root()
    call read_config(path, env, cfg, error); if (allocated(error)) return
    call check_config(cfg, error); if (allocated(error)) return
    call scene%init(cfg%scene, cfg%obstacles, error); if (allocated(error)) return
    call place_agents(cfg%agents, scene, q, nit, error); if (allocated(error)) return
    na = cfg%agents%n_agents
    allocate(speeds(na), v(2 * na), vgrid(2 * na), vexact(2 * na))
    speeds = 1.0_wp
    n_eval = max(1, 2000 / max(na, 1)) * repeats
    if (root) then
      write(*, '(a)') "input: " // path // " (" // str(na) // " agents, " // str(scene%n_interior()) // &
        " interior obstacles); times per call, mean of " // str(repeats) // " setups and " // str(n_eval) // &
        " evaluations"
      write(*, '(a)') ""
      write(*, '(a)') "| model | used | setup per sample (ms) | evaluation at all agents (us) | per agent (us) |"
      write(*, '(a)') "|---|---|---:|---:|---:|"
    end if
    do m = 1, size(models)
      dc = cfg%desired
      dc%mode = 'geodesic'
      dc%field = models(m)
      t0 = env%wtime()
      do it = 1, repeats
        call des%init(dc, scene, cfg%agents%radius, na, error)
        if (allocated(error)) return
      end do
      t_setup = (env%wtime() - t0) / repeats
      t0 = env%wtime()
      do it = 1, n_eval
        call des%evaluate(q, speeds, v)
      end do
      t_eval = (env%wtime() - t0) / n_eval
      if (models(m) == 'grid') vgrid = v
      if (models(m) == 'exact') vexact = v
      if (root) write(*, '(a, f0.4, a, f0.2, a, f0.3, a)') "| " // trim(models(m)) // " | " // des%model_name() // &
        " | ", 1.0e3_wp * t_setup, " | ", 1.0e6_wp * t_eval, " | ", 1.0e6_wp * t_eval / na, " |"
    end do
    dmax = 0.0_wp
    do i = 1, na
      dmax = max(dmax, norm2(vgrid(2*i-1:2*i) - vexact(2*i-1:2*i)))
    end do
    if (root) then
      write(*, '(a)') ""
      write(*, '(a, es10.3)') "largest |d_grid - d_exact| over agents at the initial positions: ", dmax
    end if
  end subroutine run
end program crowd_geobench
