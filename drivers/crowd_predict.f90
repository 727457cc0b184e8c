!> crowd_predict: the quantities of interest for any list of parameters, from a ROM file alone.
!>
!>   crowd_predict input.nml [--summary FILE]
!>
!> The input holds the group &predict (docs/queries.md). The run itself (src/predict/
!> cr_predict_run.f90) reads the ROM file and the queries, runs them distributed over the MPI
!> ranks and writes the product; this program reads and checks the input, calls one stage
!> after the other and prints the summary.
program crowd_predict
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_config, only: FOM_GROUPS
  use cr_inputs, only: check_input_groups
  use cr_namelist_text, only: namelist_text_t
  use cr_predict_config, only: predict_cfg_t, read_predict, check_predict
  use cr_predict_run, only: predict_run_t
  implicit none

  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(predict_cfg_t) :: pcfg
  type(namelist_text_t) :: nml
  type(predict_run_t) :: pred
  type(error_t), allocatable :: error
  integer :: code

  call program_start("crowd_predict", env, log, cli, error)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error)) call nml%load(cli%input, env, error)
  if (.not. allocated(error)) call nml%require_groups('crowd_predict', ['predict'], FOM_GROUPS, error)
  if (.not. allocated(error)) call read_predict(nml, pcfg, error)
  if (.not. allocated(error)) call check_input_groups(nml, error)
  if (.not. allocated(error)) call check_predict(cli%input, pcfg, error)
  if (.not. allocated(error)) call pred%init(cli%input, cli%summary, pcfg, log, error)
  call env%agree_error(error)
  if (.not. allocated(error)) call pred%run(env, log, error)
  if (.not. allocated(error)) call pred%write(env, error)
  if (.not. allocated(error)) call pred%print_summary(log)
  if (.not. allocated(error) .and. len(cli%summary) > 0 .and. env%is_root()) call pred%write_summary(cli%summary, error)
  call pred%free()
  code = program_finish(env, log, error)
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: crowd_predict input.nml [--summary FILE]"
    print '(a)', ""
    print '(a)', "Runs a list of parameters (a text or HDF5 file, or a sampling rule with distributions"
    print '(a)', "and a seed) through one reduced setting of a ROM file (crowd_offline; model = 'rom')"
    print '(a)', "or through the full model of its study (model = 'exact'), and writes per query the"
    print '(a)', "quantities of interest (evacuation curve, t50 / t90 / t100, overlaps; positions with"
    print '(a)', "trajectories = .true.), flagging queries outside the training box. No snapshot database"
    print '(a)', "is needed. Namelist group &predict (docs/queries.md). Parallel: run it under mpirun;"
    print '(a)', "the queries are shared dynamically and the output does not depend on the rank count."
    print '(a)', ""
    print '(a)', "  --summary FILE   also write the run summary as JSON"
    print '(a)', "  -h, --help       this text"
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 1 other failure, 4 failed MPI call."
  end subroutine print_help
end program crowd_predict
