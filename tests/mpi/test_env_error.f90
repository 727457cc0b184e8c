!> env%agree_error: the first failing rank's message and code reach every rank, with its
!> rank when only some ranks failed. Run at 1, 2 and 3 ranks. With the argument `print` the
!> program instead lets rank 1 alone fail and ends through program_finish, so that a ctest
!> can check the one printed line (tests/regression/iosafe.cmake).
program test_env_error
  use mpi_f08
  use cr_error, only: error_t, set_error
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_strings, only: str
  use cr_assert, only: check, test_summary
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(error_t), allocatable :: error
  integer :: code, last

  call program_start("test_env_error", env, log, cli, error)
  if (allocated(error)) deallocate(error)   ! no input file is fine here
  if (allocated(cli%input)) then
    if (cli%input == 'print') then
      if (env%rank == min(1, env%size - 1)) call set_error(error, "disk on fire at step 7", 3)
      call env%agree_error(error)
      code = program_finish(env, log, error)
      if (code /= 0) stop code, quiet=.true.
      stop
    end if
  end if
  last = env%size - 1

  ! nobody fails: nothing changes
  call env%agree_error(error)
  call check(.not. allocated(error), "no error stays no error")

  ! one rank (the last) fails alone: every rank gets its message, code and rank
  if (env%rank == last) call set_error(error, "only rank " // str(last) // " failed", 3)
  call env%agree_error(error)
  call check(allocated(error), "every rank returns the error")
  if (allocated(error)) then
    call check(index(error%message, "only rank " // str(last) // " failed") > 0, "the failing rank's message")
    call check(error%code == 3, "the failing rank's code")
    if (env%size > 1) then
      call check(index(error%message, "rank " // str(last) // " of " // str(env%size) // ": ") == 1, &
        "the message starts with the failing rank")
    else
      call check(error%message == "only rank 0 failed", "no rank prefix on a single rank")
    end if
    deallocate(error)
  end if

  ! several ranks fail: the lowest failing rank's message wins, identical on every rank
  if (env%rank >= 1 .or. env%size == 1) call set_error(error, "failure on rank " // str(env%rank), EXIT_BAD_INPUT)
  call env%agree_error(error)
  call check(allocated(error), "several failures: every rank returns an error")
  if (allocated(error)) then
    call check(index(error%message, "failure on rank " // str(min(1, last))) > 0, "the lowest failing rank wins")
    call check(error%code == EXIT_BAD_INPUT, "code of the lowest failing rank")
    deallocate(error)
  end if

  ! every rank fails (an error all ranks know about): no rank prefix, rank 0's message
  call set_error(error, "bad input everywhere", EXIT_BAD_INPUT)
  call env%agree_error(error)
  call check(allocated(error), "all failed: error kept")
  if (allocated(error)) then
    call check(error%message == "bad input everywhere", "all failed: the message is not prefixed")
    deallocate(error)
  end if

  code = program_finish(env, log, error)
  call test_summary(env%rank)
end program test_env_error
