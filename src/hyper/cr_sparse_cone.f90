!> A reduced cone W_R^+ = span+{psi_1..psi_R} as sparse vectors over the contact dictionary.
!> gIS cones are canonical vectors (psi_r = e_{i_r}); mCPG cones are general non-negative
!> vectors. Both are handled through this one representation.
module cr_sparse_cone
  use cr_kinds, only: wp
  implicit none
  private
  public :: sparse_cone_t

  !> The R cone vectors, column-compressed over the dictionary index space.
  type :: sparse_cone_t
    integer :: r = 0
    integer :: n_dict = 0
    !> 0-based offsets [R + 1]
    integer, allocatable :: ptr(:)
    !> dictionary indices (1-based) and values of the non-zeros [nnz]
    integer, allocatable :: idx(:)
    real(wp), allocatable :: val(:)
  contains
    procedure :: from_indices
    procedure :: from_dense
    procedure :: support
  end type sparse_cone_t

contains

  !> gIS cone: psi_r = e_{indices(r)}.
  subroutine from_indices(this, n_dict, indices)
    class(sparse_cone_t), intent(inout) :: this
    integer, intent(in) :: n_dict, indices(:)
    integer :: r
    this%r = size(indices); this%n_dict = n_dict
    this%ptr = [(r, r = 0, size(indices))]
    this%idx = indices
    this%val = [(1.0_wp, r = 1, size(indices))]
  end subroutine from_indices

  !> mCPG cone: psi [n_dict, R] (entries <= tol * max are dropped).
  subroutine from_dense(this, psi, tol)
    class(sparse_cone_t), intent(inout) :: this
    real(wp), intent(in) :: psi(:,:)
    real(wp), intent(in), optional :: tol
    real(wp) :: t
    integer :: r, i, nnz
    t = 0
    if (present(tol)) t = tol * maxval(abs(psi))
    this%n_dict = size(psi, 1); this%r = size(psi, 2)
    nnz = count(abs(psi) > t)
    if (allocated(this%ptr)) deallocate(this%ptr, this%idx, this%val)
    allocate(this%ptr(this%r + 1), this%idx(nnz), this%val(nnz))
    this%ptr(1) = 0; nnz = 0
    do r = 1, this%r
      do i = 1, this%n_dict
        if (abs(psi(i, r)) > t) then
          nnz = nnz + 1; this%idx(nnz) = i; this%val(nnz) = psi(i, r)
        end if
      end do
      this%ptr(r + 1) = nnz
    end do
  end subroutine from_dense

  !> Sorted list of the dictionary indices used by any cone vector.
  function support(this) result(s)
    class(sparse_cone_t), intent(in) :: this
    integer, allocatable :: s(:)
    logical, allocatable :: used(:)
    integer :: i
    allocate(used(max(this%n_dict, 1)))
    used = .false.
    used(this%idx) = .true.
    s = pack([(i, i = 1, this%n_dict)], used(1:this%n_dict))
  end function support
end module cr_sparse_cone
