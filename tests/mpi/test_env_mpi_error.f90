!> MPI errors are returned through env_t, not fatal: env's communicator and its shared
!> counter's window have the handler MPI_ERRORS_RETURN; a broadcast from an invalid root (every
!> rank) and a receive into a too small buffer (rank 1) return an error with code EXIT_MPI
!> naming the MPI call, and MPI goes on working after them; the code survives prefix_error; the
!> error agreement leaves an MPI failure as it is (no collective); BLACS, which does not check
!> MPI statuses, works on communicators with MPI_ERRORS_ARE_FATAL. Run at 1, 2 and 3 ranks (on
!> code where MPI errors are fatal the job aborts: the test fails by its exit status).
!> After a failed MPI call the rank makes no clean-up collective (cr_env's mpi_failed: the
!> barrier is skipped with an error); this run then ends by MPI_Finalize itself, since
!> program_finish would end it by MPI_Abort (the `abort` run checks that).
!> With the argument `abort` (2 ranks, tests/mpi/env.cmake) rank 1 alone fails in a receive, as in a
!> driver, while rank 0 waits in a barrier (as in the collective that failed) and then in the
!> error agreement: rank 1 frees its shared counter (a collective MPI_Win_free, which would
!> wait for ever beside rank 0's barrier) and calls the barrier, both skipped after its
!> failure, does not enter the agreement; its line is printed and its MPI_Abort ends the job
!> with status 4 instead of a hang.
program test_env_mpi_error
  use mpi_f08, only: MPI_Errhandler, MPI_Comm_get_errhandler, MPI_Win_get_errhandler, &
    MPI_Errhandler_free, MPI_ERRORS_RETURN, MPI_ERRORS_ARE_FATAL, MPI_SUCCESS, MPI_Comm, operator(==), &
    MPI_Finalize
  use cr_error, only: error_t, set_error, prefix_error
  use cr_exit_codes, only: EXIT_MPI, EXIT_FAILURE
  use cr_env, only: env_t, shared_counter_t, mpi_failed
  use cr_distribution, only: blacs_grid_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_strings, only: str
  use cr_kinds, only: i8
  use cr_assert, only: check, test_summary
  implicit none
  interface
    subroutine blacs_get(ctxt, what, val)
      integer, intent(in) :: ctxt, what
      integer, intent(out) :: val
    end subroutine blacs_get
    integer function blacs2sys_handle(handle)
      integer, intent(in) :: handle
    end function blacs2sys_handle
  end interface
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(error_t), allocatable :: error
  type(shared_counter_t) :: counter
  type(MPI_Errhandler) :: eh
  type(blacs_grid_t) :: grid
  type(MPI_Comm) :: bcomm
  integer :: code, ierr, p, r, iv(3), ir(2), one(1), handle
  integer(i8) :: old
  character(len=:), allocatable :: head
  type(error_t), allocatable :: e2

  call program_start("test_env_mpi_error", env, log, cli, error)
  if (allocated(error)) deallocate(error)   ! no input file is fine here
  p = env%size; r = env%rank
  if (allocated(cli%input)) then
    if (cli%input == 'abort') then
      ! rank 0 sends 3 integers, rank 1 receives 2; then rank 0 waits in a barrier and in the
      ! agreement, rank 1 cleans up (window freed, barrier) and goes to program_finish
      call counter%init(env, 1, error)
      if (allocated(error)) stop EXIT_FAILURE
      iv = [1, 2, 3]
      if (r == 0) then
        call env%send(iv, 1, 7, error)
        if (.not. allocated(error)) call env%sync(error)
      else if (r == 1) then
        call env%recv(ir, 0, 7, error)
        call counter%free()
        call env%sync(e2)
      end if
      call env%agree_error(error)
      code = program_finish(env, log, error)
      if (code /= 0) stop code, quiet=.true.
      stop
    end if
  end if

  ! the handlers: env's communicator and the counter's window return errors
  call MPI_Comm_get_errhandler(env%comm, eh, ierr)
  call check(ierr == MPI_SUCCESS .and. eh == MPI_ERRORS_RETURN, "env%comm has MPI_ERRORS_RETURN")
  call MPI_Errhandler_free(eh, ierr)
  call counter%init(env, 2, error)
  call check(.not. allocated(error), "counter init: no error")
  if (.not. allocated(error)) then
    call MPI_Win_get_errhandler(counter%win, eh, ierr)
    call check(ierr == MPI_SUCCESS .and. eh == MPI_ERRORS_RETURN, "the counter's window has MPI_ERRORS_RETURN")
    call MPI_Errhandler_free(eh, ierr)
    old = counter%fetch_add(2, 1_i8, error)
    call check(.not. allocated(error) .and. old >= 0 .and. old < p, "the counter still counts")
  end if
  if (allocated(error)) deallocate(error)
  call counter%free()
  ! BLACS's communicator (blacs_get 10: the system handle of the grid's communicator) does not
  ! inherit env%comm's handler: MPI failures inside BLACS and ScaLAPACK stay fatal
  call grid%init(env, error)
  call check(.not. allocated(error), "blacs grid: no error")
  if (.not. allocated(error)) then
    call blacs_get(grid%context, 10, handle)
    bcomm%MPI_VAL = blacs2sys_handle(handle)
    call MPI_Comm_get_errhandler(bcomm, eh, ierr)
    call check(ierr == MPI_SUCCESS .and. eh == MPI_ERRORS_ARE_FATAL, "BLACS's communicator has MPI_ERRORS_ARE_FATAL")
    call MPI_Errhandler_free(eh, ierr)
  end if
  if (allocated(error)) deallocate(error)
  call grid%free()

  ! a broadcast from rank `size` (no such rank), on every rank: an MPI error, returned
  iv = 0
  call env%bcast(iv, error, root=p)
  call check(allocated(error), "bcast from an invalid root: an error")
  if (allocated(error)) then
    call check(error%code == EXIT_MPI, "bcast from an invalid root: code EXIT_MPI")
    head = "env: MPI_Bcast of 3 integer(s) from rank " // str(p) // " failed: "
    call check(index(error%message, head) == 1 .and. len(error%message) > len(head), &
      "bcast from an invalid root: the message names the call, then MPI's reason")
    ! from now on this rank makes no clean-up collective: the barrier is skipped, with an error
    call check(mpi_failed(), "mpi_failed after the failed broadcast")
    call env%sync(e2)
    call check(allocated(e2), "barrier after a failed MPI call: skipped with an error")
    if (allocated(e2)) then
      call check(e2%code == EXIT_MPI .and. e2%message == &
        "env: MPI_Barrier skipped after a failed MPI call on this rank", "barrier skipped: " // e2%message)
      deallocate(e2)
    end if
    ! the code survives the context added on the way up
    call prefix_error(error, "stage")
    call check(error%code == EXIT_MPI .and. index(error%message, "stage: " // head) == 1, "prefix_error keeps EXIT_MPI")
    ! the agreement leaves an MPI failure as it is (here every rank has one: each keeps its own)
    error%message = "mpi failure on rank " // str(r)
    call env%agree_error(error)
    call check(allocated(error), "agree_error keeps an MPI failure")
    if (allocated(error)) then
      call check(error%message == "mpi failure on rank " // str(r) .and. error%code == EXIT_MPI, &
        "agree_error: an MPI failure is returned unchanged (no agreement)")
    end if
  end if
  if (allocated(error)) deallocate(error)

  ! MPI goes on working after a returned error
  one = 1
  call env%allreduce(one, 'sum', error)
  call check(.not. allocated(error) .and. one(1) == p, "allreduce after the failed broadcast")
  if (allocated(error)) deallocate(error)

  ! a receive into a buffer too small for the message: rank 1 gets the error, rank 0 does not
  if (p > 1) then
    iv = [4, 5, 6]
    if (r == 0) then
      call env%send(iv, 1, 3, error)
      call check(.not. allocated(error), "send of 3 integers: no error")
    else if (r == 1) then
      ir = 0
      call env%recv(ir, 0, 3, error)
      call check(allocated(error), "receive of 3 integers into 2: an error")
      if (allocated(error)) then
        call check(error%code == EXIT_MPI, "truncated receive: code EXIT_MPI")
        call check(index(error%message, "env: MPI_Recv of 2 integer(s) from rank 0 failed: ") == 1, &
          "truncated receive: the message names the call")
      end if
    end if
    if (allocated(error)) deallocate(error)
  end if

  ! program_finish would end this run by MPI_Abort (an MPI call failed on every rank): end here
  call env%free()
  call MPI_Finalize(ierr)
  call test_summary(r)
end program test_env_mpi_error
