!> crowd_snapshots: run a parameter study of the full-order model over MPI ranks and write one
!> resumable snapshot database (the stage itself: src/study/cr_study_run.f90).
!>
!>   mpirun -np P crowd_snapshots study.nml [--summary FILE] [--stop-after K]
!>                                          [--quarantine-bad-pieces] [--batch-seconds S]
program crowd_snapshots
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish, log_level_of
  use cr_config, only: config_t, read_config
  use cr_inputs, only: check_input_groups
  use cr_config_check, only: check_config
  use cr_namelist_text, only: namelist_text_t
  use cr_study_config, only: study_cfg_t, read_study, check_study, check_study_paths
  use cr_study_run, only: study_run_t, run_options_t
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(config_t) :: cfg
  type(study_cfg_t) :: study
  type(namelist_text_t) :: nml
  type(study_run_t) :: run
  type(run_options_t) :: opts
  type(error_t), allocatable :: error, e2
  integer :: code

  call program_start("crowd_snapshots", env, log, cli, error, allow_stop_after=.true.)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error)) call read_config(cli%input, env, cfg, error, nml, &
    program='crowd_snapshots', needed=[character(len=8) :: 'scene', 'agents', 'study'])
  if (.not. allocated(error)) call check_input_groups(nml, error)
  if (.not. allocated(error)) call check_config(cfg, error)
  if (.not. allocated(error)) call read_study(nml, study, error)
  if (.not. allocated(error)) call check_study(study, cfg, error)
  if (.not. allocated(error)) call check_study_paths(cli%input, cli%summary, cfg, study, error)
  if (.not. allocated(error)) then
    log%level = log_level_of(cfg%output%log_level)
    opts%stop_after = cli%stop_after
    opts%quarantine = cli%quarantine
    if (cli%batch_seconds >= 0) opts%batch_seconds = cli%batch_seconds
    call run%execute(env, log, cfg, study, opts, error)
  end if
  if (.not. allocated(error) .and. .not. run%no_op) then
    call log%info(run%summary_text())
    if (len(cli%summary) > 0 .and. env%is_root()) then
      call run%write_summary(cli%summary, cfg%source, e2)
      if (allocated(e2)) call log%warn(e2%message)
    end if
  end if
  code = program_finish(env, log, error)
  ! a plain (quiet) stop: the error line was printed; no runtime backtrace on bad input
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: mpirun -np P crowd_snapshots study.nml [--summary FILE] [--stop-after K]"
    print '(a)', "         [--quarantine-bad-pieces] [--batch-seconds S]"
    print '(a)', ""
    print '(a)', "Parameter study of the full-order crowd model: samples the parameters of &study,"
    print '(a)', "spreads the runs over the MPI ranks (dynamic assignment) and writes one snapshot"
    print '(a)', "database (&study database; schema in docs/file-formats.md)."
    print '(a)', "A killed run resumes where it stopped when the same command is run again."
    print '(a)', ""
    print '(a)', "  --summary FILE   also write the run summary as JSON"
    print '(a)', "  --stop-after K   testing hook: compute at most K samples, then exit with status 3"
    print '(a)', "                   without assembling the database (a rerun resumes)"
    print '(a)', "  --quarantine-bad-pieces  move pieces that fail their checks (checksum, identity,"
    print '(a)', "                   finiteness) to <database>.pieces/quarantine/ and recompute them;"
    print '(a)', "                   without it a bad piece stops the run (status 2) naming it"
    print '(a)', "  --batch-seconds S  time slice of one piece file (default 2 s; 0: one sample per piece)"
    print '(a)', "  -h, --help       this text"
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 3 stopped by --stop-after, 1 other failure, 4 failed MPI call."
  end subroutine print_help

end program crowd_snapshots
