!> The supremizer enrichments (PGA) already computed in one crowd_offline run, keyed by
!> (N, R): the first N POD modes enriched with supremizers of the first R cone vectors.
!> PGA is deterministic in (N, R) for given data, settings and ranks, so the inf-sup table
!> and the prepared pairs reuse the enrichment of an (N, R) computed before (the main
!> enrichment, the table's grid) instead of computing it again: the reused basis and error
!> history are bitwise those a new computation would give.
module cr_pga_cache
  use cr_kinds, only: wp
  use cr_supremizer, only: pga_result_t
  implicit none
  private
  public :: pga_cache_t

  !> One enrichment: the key and its result.
  type :: pga_entry_t
    integer :: n = -1, r = -1
    !> enriched basis, POD modes then supremizers (replicated): [n_dof, n + n_added]
    real(wp), allocatable :: v(:,:)
    type(pga_result_t) :: res
  end type pga_entry_t

  !> The enrichments computed so far (a handful: the main one, the table's grid, the pairs).
  type, public :: pga_cache_t
    type(pga_entry_t), allocatable :: entries(:)
  contains
    procedure :: add
    procedure :: find
    procedure :: free
  end type pga_cache_t

contains

  !> Remember the enrichment (n, r): basis v [n_dof, n + res%n_added] and its history
  !> (replaces an earlier entry with the same key).
  subroutine add(this, n, r, v, res)
    class(pga_cache_t), intent(inout) :: this
    integer, intent(in) :: n, r
    real(wp), intent(in) :: v(:,:)
    type(pga_result_t), intent(in) :: res
    type(pga_entry_t), allocatable :: grown(:)
    integer :: k
    if (.not. allocated(this%entries)) allocate(this%entries(0))
    k = this%find(n, r)
    if (k == 0) then
      allocate(grown(size(this%entries) + 1))
      grown(1:size(this%entries)) = this%entries
      call move_alloc(grown, this%entries)
      k = size(this%entries)
    end if
    this%entries(k)%n = n
    this%entries(k)%r = r
    this%entries(k)%v = v
    this%entries(k)%res = res
  end subroutine add

  !> Index of the entry (n, r), 0 if there is none.
  integer function find(this, n, r) result(k)
    class(pga_cache_t), intent(in) :: this
    integer, intent(in) :: n, r
    integer :: j
    k = 0
    if (.not. allocated(this%entries)) return
    do j = 1, size(this%entries)
      if (this%entries(j)%n == n .and. this%entries(j)%r == r) then
        k = j; return
      end if
    end do
  end function find

  !> Forget every entry.
  subroutine free(this)
    class(pga_cache_t), intent(inout) :: this
    if (allocated(this%entries)) deallocate(this%entries)
  end subroutine free
end module cr_pga_cache
