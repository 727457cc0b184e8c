!> Error object returned by library code (library code never stops).
!>
!> Usage: `type(error_t), allocatable :: error`; a callee that fails allocates it with
!> `call set_error(error, "where: what")`; callers test `if (allocated(error)) return`.
module cr_error
  use cr_exit_codes, only: EXIT_FAILURE, EXIT_BAD_INPUT
  implicit none
  private
  public :: error_t, set_error, prefix_error, problems_t

  !> An error with a human-readable one-line message and a numeric code.
  type :: error_t
    !> message, one line, starting with the place that failed
    character(len=:), allocatable :: message
    !> non-zero exit status, one of cr_exit_codes' EXIT_* (EXIT_FAILURE unless set)
    integer :: code = EXIT_FAILURE
  end type error_t

  !> Collector of input problems: validation checks every rule, then reports all at once.
  type :: problems_t
    integer :: n = 0
    character(len=:), allocatable :: text
  contains
    procedure :: need
    procedure :: to_error
  end type problems_t

contains

  !> Record `msg` unless `ok`.
  subroutine need(this, ok, msg)
    class(problems_t), intent(inout) :: this
    logical, intent(in) :: ok
    character(len=*), intent(in) :: msg
    if (ok) return
    if (this%n == 0) then
      this%text = msg
    else
      this%text = this%text // "; " // msg
    end if
    this%n = this%n + 1
  end subroutine need

  !> If any problem was recorded, an input error (EXIT_BAD_INPUT) "prefix: p1; p2; ...".
  subroutine to_error(this, prefix, error)
    class(problems_t), intent(in) :: this
    character(len=*), intent(in) :: prefix
    type(error_t), allocatable, intent(out) :: error
    if (this%n == 0) return
    if (len(prefix) > 0) then
      call set_error(error, prefix // ": " // this%text, EXIT_BAD_INPUT)
    else
      call set_error(error, this%text, EXIT_BAD_INPUT)
    end if
  end subroutine to_error

  !> Allocate `error` with a message (and optional code, an EXIT_* of cr_exit_codes).
  subroutine set_error(error, message, code)
    type(error_t), allocatable, intent(out) :: error
    character(len=*), intent(in) :: message
    integer, intent(in), optional :: code
    allocate(error)
    error%message = message
    if (present(code)) error%code = code
  end subroutine set_error

  !> Prepend context ("where: ") to an existing error message (the code is kept).
  subroutine prefix_error(error, prefix)
    type(error_t), intent(inout) :: error
    character(len=*), intent(in) :: prefix
    error%message = prefix // ": " // error%message
  end subroutine prefix_error
end module cr_error
