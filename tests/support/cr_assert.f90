!> Minimal assertion module for crowdrom's test programs (test-drive / pFUnit shaped).
!>
!> A test program calls `check*` at least once and ends with `call test_summary()`, which
!> prints "N passed, M failed" and stops with a non-zero code if anything failed or if no check
!> ran at all (a program whose checks were skipped must not pass).
module cr_assert
  use, intrinsic :: iso_fortran_env, only: output_unit
  use cr_kinds, only: wp
  use cr_exit_codes, only: EXIT_FAILURE
  implicit none
  private
  public :: check, check_close, check_rel, test_summary, n_failed

  integer :: n_passed = 0
  integer :: n_failed = 0
  logical :: quiet = .false.
  !> -1 not yet read, 0 off, 1 on: CROWDROM_TEST_MARGINS=1 prints every check_close as
  !> "MARGIN: name | |a-b| tol" (how close each passing check is to its tolerance; used to
  !> compare runs under other BLAS kernels, docs/testing.md#other-cpus-kernels)
  integer :: margins = -1

contains

  !> Record a passing/failing condition with a name.
  subroutine check(cond, name)
    logical, intent(in) :: cond
    character(len=*), intent(in) :: name
    if (cond) then
      n_passed = n_passed + 1
    else
      n_failed = n_failed + 1
      write(output_unit, '(a)') "FAIL: " // name
      flush(output_unit)
    end if
  end subroutine check

  !> |a - b| <= tol (absolute).
  subroutine check_close(a, b, tol, name)
    real(wp), intent(in) :: a, b, tol
    character(len=*), intent(in) :: name
    character(len=200) :: buf
    character(len=8) :: flag
    integer :: stat
    if (margins < 0) then
      call get_environment_variable("CROWDROM_TEST_MARGINS", flag, status=stat)
      margins = merge(1, 0, stat == 0 .and. flag == "1")
    end if
    if (margins == 1) then
      write(buf, '(2(a, es12.4))') " | ", abs(a - b), " ", tol
      write(output_unit, '(a)') "MARGIN: " // name // trim(buf)
    end if
    if (abs(a - b) <= tol) then
      n_passed = n_passed + 1
    else
      n_failed = n_failed + 1
      write(buf, '(3(a, es12.4))') " got ", a, " expected ", b, " tol ", tol
      write(output_unit, '(a)') "FAIL: " // name // trim(buf)
      flush(output_unit)
    end if
  end subroutine check_close

  !> |a - b| <= tol * max(|b|, tiny) (relative).
  subroutine check_rel(a, b, tol, name)
    real(wp), intent(in) :: a, b, tol
    character(len=*), intent(in) :: name
    call check_close(a, b, tol * max(abs(b), tiny(1.0_wp)), name)
  end subroutine check_rel

  !> Print the tally and stop with status 1 if any check failed, or if no check ran on the
  !> printing rank (rank 0 when `rank` is given: the other ranks of an MPI test may leave the
  !> checks to rank 0).
  subroutine test_summary(rank)
    integer, intent(in), optional :: rank
    logical :: show
    show = .true.
    if (present(rank)) show = rank == 0
    if (show .and. .not. quiet) then
      write(output_unit, '(i0, " passed, ", i0, " failed")') n_passed, n_failed
      flush(output_unit)
    end if
    if (n_failed > 0) error stop EXIT_FAILURE
    if (show .and. n_passed == 0) then
      write(output_unit, '(a)') "FAIL: no check ran"
      flush(output_unit)
      error stop EXIT_FAILURE
    end if
  end subroutine test_summary
end module cr_assert
