!> crowd_project: exact position projection of given configurations (docs/user-guide.md): every
!> configuration of a request file is replaced by the closest configuration without overlap
!> (cr_position_projection), with the full model's exact solver.
!>
!>   crowd_project request.h5 [--summary FILE]
!>
!> The request (written by scripts/pipeline/ml_correct.py; layout in cr_projection_file) names the
!> snapshot database the positions belong to: its configuration gives the scene of each sample
!> (the parameters mapped by cr_param_model, as in every stage), the &solver settings and the
!> &contacts cutoff factor. The result file named by the request is written atomically.
!> The configurations of a sample are a trajectory: the first is projected on its own, each
!> later one starts from the projection of the one before (a configuration without overlap:
!> see cr_position_projection for why deep overlaps need such a start).
program crowd_project
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_project_run, only: project_request
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(error_t), allocatable :: error
  integer :: code

  call program_start("crowd_project", env, log, cli, error)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error) .and. env%is_root()) call project_request(cli%input, cli%summary, log, error)
  code = program_finish(env, log, error)
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: crowd_project request.h5 [--summary FILE]"
    print '(a)', ""
    print '(a)', "Exact position projection: each configuration of the request is replaced by the"
    print '(a)', "closest configuration without overlap (desired velocity 0, h = 1, the full model's"
    print '(a)', "exact solver and cutoff, from the snapshot database the request names). Request and"
    print '(a)', "result layout: docs/file-formats.md."
    print '(a)', ""
    print '(a)', "  --summary FILE   also write the totals as JSON"
    print '(a)', "  -h, --help       this text"
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 1 other failure, 4 failed MPI call."
  end subroutine print_help

end program crowd_project
