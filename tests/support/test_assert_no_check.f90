!> A test program whose checks were all skipped: it calls test_summary without any check.
!> Registered (tests/assert.cmake) as a test that must end with a non-zero status and the line
!> "FAIL: no check ran": a program that checked nothing never counts as passed.
program test_assert_no_check
  use cr_assert, only: check, test_summary
  implicit none
  integer :: n_cases
  character(len=16) :: arg
  ! the number of cases comes from the command line (none given: zero cases, so no check runs)
  n_cases = 0
  if (command_argument_count() > 0) then
    call get_command_argument(1, arg)
    read(arg, *) n_cases
  end if
  call run_cases(n_cases)
  call test_summary()
contains
  subroutine run_cases(n)
    integer, intent(in) :: n
    integer :: k
    do k = 1, n
      call check(k >= 1, "case index")
    end do
  end subroutine run_cases
end program test_assert_no_check
