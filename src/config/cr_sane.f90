!> Sane magnitudes of input values (SI units) and the check every input reader uses for a
!> real value: finite, not beyond a bound, not below a positive floor. Beyond these bounds a
!> run is meaningless and sizes derived from the values (grids, cell lists, step counts)
!> overflow. Problems are collected in a problems_t (cr_error) and reported together.
module cr_sane
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: problems_t
  use cr_strings, only: str
  implicit none
  private
  public :: need_sane, MAX_LENGTH, MIN_LENGTH, MAX_SPEED

  !> the largest length (m), the smallest positive length (m), the largest speed (m/s)
  real(wp), parameter :: MAX_LENGTH = 1.0e4_wp, MIN_LENGTH = 1.0e-6_wp, MAX_SPEED = 1.0e6_wp

contains

  !> Record a problem unless `x` is finite, |x| <= hi and (when given, for x > 0) x >= lo.
  subroutine need_sane(probs, x, what, hi, lo)
    type(problems_t), intent(inout) :: probs
    real(wp), intent(in) :: x, hi
    character(len=*), intent(in) :: what
    real(wp), intent(in), optional :: lo
    if (.not. ieee_is_finite(x)) then
      call probs%need(.false., what // " must be a finite number (got " // num(x) // ")")
    else if (abs(x) > hi) then
      call probs%need(.false., what // " = " // num(x) // " is beyond the sane magnitude " // num(hi))
    else if (present(lo)) then
      if (x > 0 .and. x < lo) call probs%need(.false., what // " = " // num(x) // " is below " // num(lo))
    end if
  end subroutine need_sane

  !> A number for a message, with three exponent digits when needed (1.0E+308).
  function num(x) result(t)
    real(wp), intent(in) :: x
    character(len=:), allocatable :: t
    character(len=32) :: buf
    if (ieee_is_finite(x) .and. x /= 0 .and. (abs(x) >= 1.0e99_wp .or. abs(x) < 1.0e-99_wp)) then
      write(buf, '(es12.4e3)') x
      t = trim(adjustl(buf))
    else
      t = str(x)
    end if
  end function num
end module cr_sane
