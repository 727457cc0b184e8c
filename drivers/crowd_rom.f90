!> crowd_rom: the online reduced model and its accuracy/speed sweep (serial).
!>
!>   crowd_rom input.nml [--summary FILE]
!>
!> The input holds the groups &rom, &sweep, &reduced, &fom_timing (docs/input-reference.md). The
!> sweep itself (src/rom/cr_rom_sweep.f90) reads the ROM file and its study, times the full-order
!> model, runs every setting and writes the ROM-run file and the table; this program reads and
!> checks the input, calls one stage after the other and prints the summary.
program crowd_rom
  use cr_error, only: error_t, set_error
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_config, only: FOM_GROUPS
  use cr_inputs, only: check_input_groups
  use cr_namelist_text, only: namelist_text_t
  use cr_rom_config, only: rom_cfg_t, read_rom, check_rom, check_rom_paths
  use cr_rom_sweep, only: rom_sweep_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none

  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(rom_cfg_t) :: rcfg
  type(namelist_text_t) :: nml
  type(rom_sweep_t) :: sweep
  type(error_t), allocatable :: error
  integer :: code

  call program_start("crowd_rom", env, log, cli, error)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error) .and. env%size > 1) call set_error(error, "crowd_rom is serial: run it " // &
    "without mpirun (or with -np 1); the parallel stages are crowd_snapshots and crowd_offline", EXIT_BAD_INPUT)
  if (.not. allocated(error)) call nml%load(cli%input, env, error)
  if (.not. allocated(error)) call nml%require_groups('crowd_rom', ['rom'], FOM_GROUPS, error)
  if (.not. allocated(error)) call read_rom(nml, rcfg, error)
  if (.not. allocated(error)) call check_input_groups(nml, error)
  if (.not. allocated(error)) call check_rom(cli%input, rcfg, error)
  if (.not. allocated(error)) call check_rom_paths(cli%input, cli%summary, rcfg, trim(rcfg%database), error)
  if (.not. allocated(error)) call sweep%init(cli%input, cli%summary, rcfg, log, error)
  if (.not. allocated(error)) call sweep%time_reference(env, log, error)
  if (.not. allocated(error)) call sweep%run(env, log, error)
  if (.not. allocated(error)) call sweep%print_table(log)
  if (.not. allocated(error) .and. len(cli%summary) > 0) call sweep%write_summary(cli%summary, error)
  call sweep%free()
  code = program_finish(env, log, error)
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: crowd_rom input.nml [--summary FILE]"
    print '(a)', ""
    print '(a)', "Runs the reduced model of a ROM file (crowd_offline) for the validation (or training,"
    print '(a)', "or given) parameters of its study, for every setting of the &sweep (N, R,"
    print '(a)', "hyper-reduction none | eim | eq, contacts cone | online, m_v, m_b, m_d); reports"
    print '(a)', "E_avg, overlaps, agents that fail to leave, time per step and the speedup over the"
    print '(a)', "full-order model; writes &rom output (HDF5) and &rom table (CSV). Serial."
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 1 other failure, 4 failed MPI call."
  end subroutine print_help
end program crowd_rom
