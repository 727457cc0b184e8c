!> crowd_offline: reduced bases from a snapshot database.
!>
!>   mpirun -np P crowd_offline input.nml [--summary FILE]
!>
!> Stages: read the training snapshots (each rank its block of samples), velocity POD
!> (&pod method), multiplier cone (gIS or mCPG, optionally both for comparison),
!> supremizer enrichment (PGA), reduced inf-sup table, ROM file (&offline rom_file).
program crowd_offline
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish, log_level_of
  use cr_config, only: config_t
  use cr_inputs, only: read_model_input
  use cr_namelist_text, only: namelist_text_t
  use cr_study_match, only: check_database_matches
  use cr_offline_config, only: offline_cfg_t, read_offline, check_offline, check_offline_paths
  use cr_offline_run, only: offline_run_t
  use cr_json, only: json_writer_t
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(config_t) :: cfg
  type(offline_cfg_t) :: ocfg
  type(namelist_text_t) :: nml
  type(error_t), allocatable :: error
  integer :: code

  call program_start("crowd_offline", env, log, cli, error)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error)) call read_model_input(cli%input, env, 'crowd_offline', &
    [character(len=8) :: 'scene', 'agents', 'offline'], cfg, nml, error)
  if (.not. allocated(error)) call read_offline(nml, ocfg, error)
  if (.not. allocated(error)) call check_offline(cli%input, ocfg, error)
  if (.not. allocated(error)) call check_offline_paths(cli%input, cli%summary, ocfg, error)
  if (.not. allocated(error)) call check_database_matches(env, cli%input // ": &offline", trim(ocfg%database), &
    cfg, nml, error)
  if (.not. allocated(error)) then
    log%level = log_level_of(cfg%output%log_level)
    call run(error)
  end if
  code = program_finish(env, log, error)
  ! a plain (quiet) stop: the error line was printed; no runtime backtrace on bad input
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: [mpirun -np P] crowd_offline input.nml [--summary FILE]"
    print '(a)', ""
    print '(a)', "Builds the reduced bases from the snapshot database named in &offline: velocity POD"
    print '(a)', "(tsqr | rsvd | scalapack | snapshots), multiplier cone (gis | mcpg), supremizer"
    print '(a)', "enrichment (PGA), reduced inf-sup table; writes the ROM file (&offline rom_file)."
    print '(a)', "The input is the study's namelist file plus an &offline group (docs/input-reference.md)."
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 1 other failure, 4 failed MPI call."
  end subroutine print_help

  !> One call per stage of the offline run (each collective), then the summary.
  subroutine run(error)
    type(error_t), allocatable, intent(out) :: error
    type(offline_run_t) :: off
    call off%init(cli%input, cfg, ocfg)
    call off%read_training(env, log, error); if (allocated(error)) return
    call off%build_pod(env, log, error); if (allocated(error)) return
    call off%build_cone(env, log, error); if (allocated(error)) return
    call off%enrich(env, log, error); if (allocated(error)) return
    call off%infsup(env, log, error); if (allocated(error)) return
    call off%build_pairs(env, log, error); if (allocated(error)) return
    call off%write_rom(env, log, error); if (allocated(error)) return
    call log%info(off%summary_line())
    if (len(cli%summary) > 0 .and. env%is_root()) then
      block
        type(json_writer_t) :: js
        call js%add("program", "crowd_offline")
        call off%add_summary(env, js)
        call js%write_file(cli%summary, error)
      end block
    end if
    call env%agree_error(error)
  end subroutine run
end program crowd_offline
