!> Workspace arrays that grow and never shrink: the solvers' per-step buffers.
module cr_grow
  use cr_kinds, only: wp
  implicit none
  private
  public :: grow_int, grow_real, grow_logical

contains

  !> Make a [>= n] allocated (at least 16 entries); contents are not kept when it grows.
  subroutine grow_int(a, n)
    integer, allocatable, intent(inout) :: a(:)
    integer, intent(in) :: n
    if (allocated(a)) then
      if (size(a) >= n) return
      deallocate(a)
    end if
    allocate(a(max(n, 16)))
  end subroutine grow_int

  !> Make a [>= n] allocated (at least 16 entries); contents are not kept when it grows.
  subroutine grow_real(a, n)
    real(wp), allocatable, intent(inout) :: a(:)
    integer, intent(in) :: n
    if (allocated(a)) then
      if (size(a) >= n) return
      deallocate(a)
    end if
    allocate(a(max(n, 16)))
  end subroutine grow_real

  !> Make a [>= n] allocated (at least 16 entries); contents are not kept when it grows.
  subroutine grow_logical(a, n)
    logical, allocatable, intent(inout) :: a(:)
    integer, intent(in) :: n
    if (allocated(a)) then
      if (size(a) >= n) return
      deallocate(a)
    end if
    allocate(a(max(n, 16)))
  end subroutine grow_logical
end module cr_grow
