!> Error object returned by library code (library code never stops).
!>
!> Usage: `type(error_t), allocatable :: error`; a callee that fails allocates it with
!> `call set_error(error, "where: what")`; callers test `if (allocated(error)) return`.
module cr_error
  implicit none
  private
  public :: error_t, set_error, prefix_error

  !> An error with a human-readable one-line message and a numeric code.
  type :: error_t
    !> message, one line, starting with the place that failed
    character(len=:), allocatable :: message
    !> non-zero status (1: generic failure, 2: bad input)
    integer :: code = 1
  end type error_t

contains

  !> Allocate `error` with a message (and optional code).
  subroutine set_error(error, message, code)
    type(error_t), allocatable, intent(out) :: error
    character(len=*), intent(in) :: message
    integer, intent(in), optional :: code
    allocate(error)
    error%message = message
    if (present(code)) error%code = code
  end subroutine set_error

  !> Prepend context ("where: ") to an existing error message.
  subroutine prefix_error(error, prefix)
    type(error_t), intent(inout) :: error
    character(len=*), intent(in) :: prefix
    error%message = prefix // ": " // error%message
  end subroutine prefix_error
end module cr_error
