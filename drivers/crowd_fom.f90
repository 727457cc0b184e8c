!> crowd_fom: run the full-order crowd model on one scene.
!>
!>   crowd_fom input.nml [--summary FILE]
!>
!> Reads the namelist file, places the agents, steps the model (progress on stdout), writes
!> the HDF5 trajectory (&output file) and prints a summary; --summary also writes it as JSON.
!> The model itself is serial: under mpirun rank 0 computes and the other ranks wait.
program crowd_fom
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish, log_level_of
  use cr_config, only: config_t, check_fom_paths
  use cr_namelist_text, only: namelist_text_t
  use cr_inputs, only: read_model_input
  use cr_fom_run, only: fom_run
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(config_t) :: cfg
  type(namelist_text_t) :: nml
  type(error_t), allocatable :: error
  integer :: code

  call program_start("crowd_fom", env, log, cli, error)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error)) call read_model_input(cli%input, env, 'crowd_fom', &
    [character(len=8) :: 'scene', 'agents'], cfg, nml, error)
  if (.not. allocated(error)) call check_fom_paths(cli%input, cli%summary, cfg, error)
  if (.not. allocated(error)) then
    log%level = log_level_of(cfg%output%log_level)
    if (env%is_root()) call fom_run(cfg, cli%summary, log, error)
  end if
  code = program_finish(env, log, error)
  ! a plain (quiet) stop: the error line was printed; no runtime backtrace on bad input
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: crowd_fom input.nml [--summary FILE]"
    print '(a)', ""
    print '(a)', "Full-order crowd model (Maury-Venel): each step projects the desired velocity onto"
    print '(a)', "the cone of non-overlapping velocities. Namelist groups: &scene &obstacles &agents"
    print '(a)', "&desired &time &solver &contacts &output (see docs/input-reference.md)."
    print '(a)', ""
    print '(a)', "  --summary FILE   also write the run summary as JSON"
    print '(a)', "  -h, --help       this text"
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 1 other failure, 4 failed MPI call."
  end subroutine print_help

end program crowd_fom
