!> Shared helpers of the distributed tests: this rank's contiguous block of the columns of a
!> dense matrix (the production split, cr_distribution's block_range), dense or as the sparse
!> columns the cone builders take.
module cr_test_columns
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_distribution, only: block_range
  use cr_cone, only: sparse_columns_t
  implicit none
  private
  public :: local_cols, sparse_cols, distribute

contains

  !> This rank's block of columns of s.
  function local_cols(env, s) result(sl)
    type(env_t), intent(in) :: env
    real(wp), intent(in) :: s(:, :)
    real(wp), allocatable :: sl(:, :)
    integer :: off, cnt
    call block_range(size(s, 2), env%size, env%rank, off, cnt)
    sl = s(:, off + 1:off + cnt)
  end function local_cols

  !> Columns c0 + 1 .. c0 + nc of the dense x [n, m] as sparse columns (zeros left out).
  subroutine sparse_cols(x, c0, nc, lam)
    real(wp), intent(in) :: x(:, :)
    integer, intent(in) :: c0, nc
    type(sparse_columns_t), intent(out) :: lam
    integer :: k, i, nnz
    lam%n_rows = size(x, 1); lam%n_cols = nc; lam%col_offset = c0
    allocate(lam%ptr(nc + 1))
    nnz = count(x(:, c0 + 1:c0 + nc) /= 0)
    allocate(lam%idx(nnz), lam%val(nnz))
    lam%ptr(1) = 0; nnz = 0
    do k = 1, nc
      do i = 1, size(x, 1)
        if (x(i, c0 + k) /= 0) then
          nnz = nnz + 1; lam%idx(nnz) = i; lam%val(nnz) = x(i, c0 + k)
        end if
      end do
      lam%ptr(k + 1) = nnz
    end do
  end subroutine sparse_cols

  !> This rank's block of the dense columns x [n, m] as sparse columns.
  subroutine distribute(env, x, lam)
    type(env_t), intent(in) :: env
    real(wp), intent(in) :: x(:, :)
    type(sparse_columns_t), intent(out) :: lam
    integer :: c0, nc
    call block_range(size(x, 2), env%size, env%rank, c0, nc)
    call sparse_cols(x, c0, nc, lam)
  end subroutine distribute
end module cr_test_columns
