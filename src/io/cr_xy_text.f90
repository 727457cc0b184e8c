!> The one reader of plain-text per-agent pairs: n lines "a b" (positions of `&agents
!> init_file`, fixed desired velocities of `&desired file`), with the open, the read of each
!> line and the finiteness checked and reported as bad input (code 2) naming the variable.
module cr_xy_text
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: read_xy_text

contains

  !> Read n lines of two numbers into v [2n] (a1, b1, a2, ...). `what` names the input
  !> variable ("&agents: init_file"), `pair` the two numbers of a line ("x y").
  subroutine read_xy_text(path, n, what, pair, v, error)
    character(len=*), intent(in) :: path, what, pair
    integer, intent(in) :: n
    real(wp), allocatable, intent(out) :: v(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: u, ios, k
    character(len=256) :: msg
    allocate(v(2 * n))
    open(newunit=u, file=path, status='old', action='read', iostat=ios, iomsg=msg)
    if (ios /= 0) then
      call set_error(error, what // ": cannot open '" // path // "' (" // trim(msg) // ")", EXIT_BAD_INPUT)
      return
    end if
    do k = 1, n
      read(u, *, iostat=ios, iomsg=msg) v(2*k-1), v(2*k)
      if (ios /= 0) then
        call set_error(error, what // ": '" // path // "' line " // str(k) // &
          ": expected two numbers '" // pair // "' per agent for n_agents = " // str(n) // &
          " (" // trim(msg) // ")", EXIT_BAD_INPUT)
        close(u); return
      end if
    end do
    close(u)
    if (any(v /= v) .or. any(abs(v) > huge(1.0_wp) / 4)) &
      call set_error(error, what // ": '" // path // "' has a non-finite value", EXIT_BAD_INPUT)
  end subroutine read_xy_text
end module cr_xy_text
