!> Start and end of a crowdrom program, shared by the drivers: MPI, the environment on
!> MPI_COMM_WORLD, the root-only logger, the command line; at the end the error is printed
!> once (`error: <message>`), the exit code is agreed by all ranks, MPI is finalised.
!> Only the driver stops (with the code returned by program_finish). After a failed MPI call
!> (EXIT_MPI) the failing rank prints its own line and ends every rank by MPI_Abort instead.
module cr_program
  use, intrinsic :: iso_fortran_env, only: error_unit
  ! MPI's life cycle (init, finalize, abort) is the program's; every other call goes through env_t
  use mpi_f08, only: MPI_Init, MPI_Finalize, MPI_Abort, MPI_COMM_WORLD
  use cr_error, only: error_t
  use cr_exit_codes, only: EXIT_OK, EXIT_FAILURE, EXIT_MPI
  use cr_strings, only: str
  use cr_env, only: env_t, mpi_failed
  use cr_logger, only: logger_t, LOG_ERROR, LOG_WARN, LOG_INFO, LOG_DEBUG
  use cr_cli, only: cli_t, parse_cli
  use cr_h5file, only: h5_library_close
  implicit none
  private
  public :: program_start, program_finish, log_level_of

contains

  !> MPI_Init, env on MPI_COMM_WORLD, logger active on rank 0, parsed command line. With
  !> own_arguments (the benchmark drivers: positional arguments of their own) the command
  !> line is left to the driver and cli stays empty.
  subroutine program_start(name, env, log, cli, error, allow_stop_after, own_arguments)
    character(len=*), intent(in) :: name
    type(env_t), intent(inout) :: env
    type(logger_t), intent(inout) :: log
    type(cli_t), intent(out) :: cli
    type(error_t), allocatable, intent(out) :: error
    logical, intent(in), optional :: allow_stop_after, own_arguments
    integer :: ierr
    call MPI_Init(ierr)
    call env%init(MPI_COMM_WORLD, error)
    call log%init(env%is_root())
    if (allocated(error)) return
    if (present(own_arguments)) then
      if (own_arguments) return
    end if
    call parse_cli(name, cli, error, allow_stop_after=allow_stop_after)
  end subroutine program_start

  !> Print the error (root), agree on the exit code (largest over the ranks), free the
  !> environment and finalise MPI. Returns EXIT_OK or the error code (cr_exit_codes).
  !>
  !> A failed MPI call of this rank (cr_env's mpi_failed; the error has code EXIT_MPI unless a
  !> caller replaced it on the way, e.g. by an input error of a parallel read) may have failed
  !> inside a collective that other ranks still wait in, so no collective follows it (no
  !> agreement on the code, no release of env or of HDF5): this rank prints its error itself,
  !> on any rank (the logger prints on rank 0 only), as `error: rank R of P: <message>` (no
  !> prefix on one rank), and calls MPI_Abort(MPI_COMM_WORLD, EXIT_MPI), which ends every rank with a
  !> non-zero status (mpirun: EXIT_MPI = 4).
  integer function program_finish(env, log, error) result(code)
    type(env_t), intent(inout) :: env
    type(logger_t), intent(in) :: log
    type(error_t), allocatable, intent(in) :: error
    integer :: ierr
    type(error_t), allocatable :: e
    character(len=:), allocatable :: msg
    code = EXIT_OK
    if (mpi_failed()) then
      if (allocated(error)) then
        msg = error%message
      else
        msg = "an MPI call failed on this rank"
      end if
      if (env%size > 1) then
        write(error_unit, '(a)') "error: rank " // str(env%rank) // " of " // str(env%size) // ": " // msg
      else
        write(error_unit, '(a)') "error: " // msg
      end if
      flush(error_unit)
      call MPI_Abort(MPI_COMM_WORLD, EXIT_MPI, ierr)
      ! (not reached: MPI_Abort does not return)
      code = EXIT_MPI
      return
    end if
    if (allocated(error)) then
      call log%error(error%message)
      code = error%code
    end if
    call env%allreduce(code, 'max', e)
    if (allocated(e)) then
      call log%error(e%message)
      code = max(code, EXIT_FAILURE)
    end if
    call env%free()
    ! HDF5 (objects, files, then the library) is shut down before MPI, also after an error
    call h5_library_close()
    call MPI_Finalize(ierr)
  end function program_finish

  !> Logger level of an &output log_level name ('error', 'warn', 'info', 'debug').
  pure integer function log_level_of(name) result(level)
    character(len=*), intent(in) :: name
    select case (trim(name))
    case ('error'); level = LOG_ERROR
    case ('warn'); level = LOG_WARN
    case ('debug'); level = LOG_DEBUG
    case default; level = LOG_INFO
    end select
  end function log_level_of
end module cr_program
