!> Small string helpers (number formatting) used in messages and logs.
module cr_strings
  use cr_kinds, only: wp, i8
  implicit none
  private
  public :: shorten, str, to_lower

  !> Format a number as a trimmed string.
  interface str
    module procedure str_int, str_int8, str_real, str_logical
  end interface str

contains

  pure function str_int(i) result(s)
    integer, intent(in) :: i
    character(len=:), allocatable :: s
    character(len=32) :: buf
    write(buf, '(i0)') i
    s = trim(buf)
  end function str_int

  pure function str_int8(i) result(s)
    integer(i8), intent(in) :: i
    character(len=:), allocatable :: s
    character(len=32) :: buf
    write(buf, '(i0)') i
    s = trim(buf)
  end function str_int8

  !> Real with an optional Fortran edit descriptor (default: g0 with 6 significant digits).
  pure function str_real(x, fmt) result(s)
    real(wp), intent(in) :: x
    character(len=*), intent(in), optional :: fmt
    character(len=:), allocatable :: s
    character(len=64) :: buf
    if (present(fmt)) then
      write(buf, '(' // fmt // ')') x
    else
      write(buf, '(es12.5)') x
    end if
    s = trim(adjustl(buf))
  end function str_real

  pure function str_logical(l) result(s)
    logical, intent(in) :: l
    character(len=:), allocatable :: s
    if (l) then
      s = "true"
    else
      s = "false"
    end if
  end function str_logical

  !> Lower-case copy of a string (ASCII).
  pure function to_lower(s) result(t)
    character(len=*), intent(in) :: s
    character(len=len(s)) :: t
    integer :: k, c
    t = s
    do k = 1, len(s)
      c = iachar(s(k:k))
      if (c >= iachar('A') .and. c <= iachar('Z')) t(k:k) = achar(c + 32)
    end do
  end function to_lower
  !> s cut to at most n characters (the last three replaced by "...").
  pure function shorten(s, n) result(t)
    character(len=*), intent(in) :: s
    integer, intent(in) :: n
    character(len=:), allocatable :: t
    if (len(s) > n) then
      t = s(1:max(n - 3, 0)) // "..."
    else
      t = s
    end if
  end function shorten
end module cr_strings
