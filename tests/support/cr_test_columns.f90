!> Shared helpers of the distributed tests: snapshot matrices of known SVD, and this rank's
!> contiguous block of the columns of a dense matrix (the production split, cr_distribution's
!> block_range), dense or as the sparse columns the cone builders take.
module cr_test_columns
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_random, only: rng_t
  use cr_lapack, only: la_geqrf, la_orgqr
  use cr_distribution, only: block_range
  use cr_cone, only: sparse_columns_t
  implicit none
  private
  public :: random_orthonormal, make_s, local_cols, sparse_cols, distribute

contains

  !> Random orthonormal [n, r] (replicated, n >= r), from the stream (seed, column).
  function random_orthonormal(n, r, seed) result(q)
    integer, intent(in) :: n, r, seed
    real(wp), allocatable :: q(:, :), tau(:)
    type(rng_t) :: rng
    type(error_t), allocatable :: err
    integer :: i, j
    allocate(q(n, r), tau(r))
    do j = 1, r
      call rng%seed(seed, j)
      do i = 1, n
        q(i, j) = rng%normal()
      end do
    end do
    call la_geqrf(q, tau, err)
    if (.not. allocated(err)) call la_orgqr(q, tau, err)
    if (allocated(err)) error stop "random_orthonormal: " // err%message
  end function random_orthonormal

  !> S = U diag(sigma) V^T [n_dof, n_snap] (replicated), left singular vectors in u.
  subroutine make_s(n_dof, n_snap, sigma, seed, s, u)
    integer, intent(in) :: n_dof, n_snap, seed
    real(wp), intent(in) :: sigma(:)
    real(wp), allocatable, intent(out) :: s(:, :), u(:, :)
    real(wp), allocatable :: v(:, :)
    integer :: j
    u = random_orthonormal(n_dof, size(sigma), seed)
    v = random_orthonormal(n_snap, size(sigma), seed + 1000)
    do j = 1, size(sigma)
      v(:, j) = sigma(j) * v(:, j)
    end do
    s = matmul(u, transpose(v))
  end subroutine make_s

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
