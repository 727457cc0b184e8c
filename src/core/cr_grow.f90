!> Arrays that grow and never shrink: the solvers' per-step work spaces (contents not kept)
!> and buffers that keep what they hold (grow_kept_*).
module cr_grow
  use cr_kinds, only: wp
  implicit none
  private
  public :: grow_int, grow_real, grow_logical, grow_kept_int, grow_kept_real

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
  !> a [cap] keeping its first n entries (n <= both sizes).
  subroutine grow_kept_int(a, cap, n)
    integer, allocatable, intent(inout) :: a(:)
    integer, intent(in) :: cap, n
    integer, allocatable :: t(:)
    allocate(t(cap))
    if (n > 0) t(1:n) = a(1:n)
    call move_alloc(t, a)
  end subroutine grow_kept_int
  !> a [cap] keeping its first n entries (n <= both sizes).
  subroutine grow_kept_real(a, cap, n)
    real(wp), allocatable, intent(inout) :: a(:)
    integer, intent(in) :: cap, n
    real(wp), allocatable :: t(:)
    allocate(t(cap))
    if (n > 0) t(1:n) = a(1:n)
    call move_alloc(t, a)
  end subroutine grow_kept_real
end module cr_grow
