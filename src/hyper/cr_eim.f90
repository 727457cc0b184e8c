!> Empirical interpolation (EIM) of a non-affine term s(sigma) [p]: POD basis + DEIM indices.
!>
!> Offline (`eim_build`, collective): the snapshot matrix S [p, n_snap] (columns distributed
!> over the ranks) is compressed by an exact POD (`pod_tsqr`); its leading m modes U [p, m] are
!> the interpolation basis and the greedy DEIM (Chaturantabut and Sorensen 2010) picks m
!> interpolation indices I: index k is where the k-th mode is worst interpolated by the first
!> k - 1 modes. The indices are nested, so any m' <= m can be used online.
!>
!> Online: only s_I(sigma) [m] is evaluated; s(sigma) ~ U c with c = (U_I)^{-1} s_I, where
!> U_I = U(I, 1:m) [m, m] (`eim_interp_matrix` returns its inverse and checks its condition).
!> A projected term W^T s costs O(m q) per evaluation with the offline product W^T U (U_I)^{-1}.
!>
!> Training error `err(k)`: max over the training snapshots of |s - interp_k(s)|_2 / |s|_2.
!> It is computed without any k x k solve by the Newton form of the interpolant: with the DEIM
!> residuals rho_k = u_k - interp_{k-1}(u_k) (rho_k vanishes on I_{k-1}, its largest entry is
!> at i_k), interp_k(s) = interp_{k-1}(s) + (r_{k-1}(i_k) / rho_k(i_k)) rho_k, where r_{k-1} =
!> s - interp_{k-1}(s). Each snapshot costs O(p m) for the whole history.
module cr_eim
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_lapack, only: la_gesvd
  use cr_pod, only: pod_result_t, pod_tsqr, snapshot_layout
  use cr_sort, only: near_max_index
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: eim_t, eim_build, eim_prefix, deim_indices, eim_interp_matrix

  !> An EIM approximation of one non-affine term, replicated on every rank.
  type :: eim_t
    !> number of candidate entries p and of kept modes m
    integer :: p = 0, m = 0
    !> leading POD modes of the snapshots, orthonormal columns [p, m]
    real(wp), allocatable :: basis(:, :)
    !> DEIM interpolation indices in 1..p [m]; nested: idx(1:k) are the k-mode indices
    integer, allocatable :: idx(:)
    !> every singular value of the snapshot matrix [min(p, n_snap)], descending
    real(wp), allocatable :: sigma(:)
    !> max over the training snapshots of |s - interp_k(s)| / |s| with k modes [m]
    real(wp), allocatable :: err(:)
    !> why m is smaller than requested (unallocated when m = m_max)
    character(len=:), allocatable :: note
  contains
    procedure :: free => eim_free
  end type eim_t

contains

  !> Release the storage and reset the sizes.
  subroutine eim_free(this)
    class(eim_t), intent(inout) :: this
    if (allocated(this%basis)) deallocate(this%basis)
    if (allocated(this%idx)) deallocate(this%idx)
    if (allocated(this%sigma)) deallocate(this%sigma)
    if (allocated(this%err)) deallocate(this%err)
    if (allocated(this%note)) deallocate(this%note)
    this%p = 0
    this%m = 0
  end subroutine eim_free

  !> Build the EIM of a term from its snapshots (collective; the result is identical on every
  !> rank). m_max > p is an input error (code 2); an m_max above the numerical rank of the
  !> snapshots is reduced to that rank and `note` says so; all-zero (or no) snapshots give
  !> m = 0 with a note.
  subroutine eim_build(env, s_local, m_max, eim, error)
    type(env_t), intent(in) :: env
    !> snapshots of the candidate entries, columns distributed over ranks: [p, n_local]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    !> requested number of modes, 0 <= m_max <= p
    integer, intent(in) :: m_max
    type(eim_t), intent(out) :: eim
    type(error_t), allocatable, intent(out) :: error
    type(pod_result_t) :: pod
    integer, parameter :: NB = 32
    real(wp), allocatable :: rho(:, :), r(:, :), err_local(:), snorm(:)
    real(wp) :: alpha, est
    integer :: p, m, n_snap, offset, i, j, j0, k, nb_here

    p = size(s_local, 1)
    if (m_max < 0 .or. m_max > p) then
      call set_error(error, "eim_build: m = " // str(m_max) // " modes requested but there are p = " // &
        & str(p) // " candidate entries (need 0 <= m <= p)", EXIT_BAD_INPUT)
      return
    end if
    call snapshot_layout(env, s_local, n_snap, offset, error)
    if (allocated(error)) then
      call prefix_error(error, "eim_build"); return
    end if
    eim%p = p
    call pod_tsqr(env, s_local, pod, error, n_modes=m_max)
    if (allocated(error)) then
      call prefix_error(error, "eim_build"); return
    end if
    eim%sigma = pod%sigma_all
    m = pod%n_modes
    eim%m = m
    if (n_snap == 0) then
      eim%note = "no snapshot: m = 0 (no mode)"
    else if (pod%rank == 0) then
      eim%note = "the snapshots are all zero: m = 0 (no mode)"
    else if (m < m_max) then
      eim%note = "m reduced from " // str(m_max) // " to the numerical rank " // str(m)
    end if
    eim%basis = pod%phi(:, 1:m)
    allocate(eim%err(m))
    if (m == 0) then
      allocate(eim%idx(0))
      return
    end if

    call deim_indices(eim%basis, eim%idx, error, newton=rho)
    if (allocated(error)) then
      call prefix_error(error, "eim_build"); return
    end if

    ! training error history on this rank's snapshots (Newton form), then max over ranks;
    ! blocks of NB snapshots so that each residual vector rho_k is read once per block
    allocate(err_local(m), r(p, NB), snorm(NB))
    err_local = 0.0_wp
    do j0 = 1, size(s_local, 2), NB
      nb_here = min(NB, size(s_local, 2) - j0 + 1)
      do j = 1, nb_here
        r(:, j) = s_local(:, j0 + j - 1)
        snorm(j) = norm2(r(:, j))
      end do
      do k = 1, m
        i = eim%idx(k)
        do j = 1, nb_here
          if (snorm(j) == 0.0_wp) cycle
          alpha = r(i, j) / rho(i, k)
          if (alpha /= 0.0_wp) r(:, j) = r(:, j) - alpha * rho(:, k)
          r(i, j) = 0.0_wp
          ! norm2 (scaled, slow) only where it can raise the maximum: the plain sum of squares
          ! is within p eps of it, far inside the margin, so the maximum is bitwise the same
          est = sqrt(sum_squares(r(:, j))) / snorm(j)
          if (.not. (est < (1.0_wp - 1.0e-8_wp) * err_local(k))) &
            err_local(k) = max(err_local(k), norm2(r(:, j)) / snorm(j))
        end do
      end do
    end do
    eim%err = err_local
    if (env%size > 1) then
      call env%allreduce(eim%err(1:m), 'max', error)
      if (allocated(error)) then
        call prefix_error(error, "eim_build: the error history (m = " // str(m) // ")")
        return
      end if
    end if
  end subroutine eim_build

  !> Sum of squares of x in four interleaved partial sums: a fast estimate of norm2(x)**2,
  !> accurate to size(x) eps in relative terms. Below 1e-250 (where squares of the entries may
  !> have underflowed) it returns huge(), so that the caller falls back to norm2; overflow gives
  !> +Inf and NaN stays NaN, which also send the caller to norm2.
  pure real(wp) function sum_squares(x) result(t)
    real(wp), intent(in) :: x(:)
    real(wp) :: a(4)
    integer :: n, i
    n = size(x)
    a = 0.0_wp
    do i = 1, n - 3, 4
      a = a + x(i:i+3)**2
    end do
    do i = 4 * (n / 4) + 1, n
      a(1) = a(1) + x(i)**2
    end do
    t = (a(1) + a(2)) + (a(3) + a(4))
    if (t < 1.0e-250_wp) t = huge(1.0_wp)
  end function sum_squares

  !> The EIM eim_build would give for m_max modes, taken from one built for more (full, built
  !> by eim_build with m_full >= m_max requested modes): the POD modes, the nested DEIM indices
  !> and the training error history of the first k modes do not depend on how many modes were
  !> requested, so this is bitwise eim_build's result (singular values, note included) without
  !> a second TSQR and SVD. Errors (code 2): m_max < 0 or m_max > m_full.
  subroutine eim_prefix(full, m_full, m_max, eim, error)
    type(eim_t), intent(in) :: full
    !> the number of modes requested when full was built
    integer, intent(in) :: m_full
    integer, intent(in) :: m_max
    type(eim_t), intent(out) :: eim
    type(error_t), allocatable, intent(out) :: error
    integer :: m
    if (m_max < 0 .or. m_max > m_full) then
      call set_error(error, "eim_prefix: m = " // str(m_max) // " modes requested from an EIM built for " // &
        & str(m_full), EXIT_BAD_INPUT)
      return
    end if
    eim%p = full%p
    eim%sigma = full%sigma
    m = min(full%m, m_max)
    eim%m = m
    if (full%m == 0) then
      ! no snapshot, or all zero: the same note whatever was requested
      if (allocated(full%note)) eim%note = full%note
    else if (m < m_max) then
      eim%note = "m reduced from " // str(m_max) // " to the numerical rank " // str(m)
    end if
    eim%basis = full%basis(:, 1:m)
    eim%idx = full%idx(1:m)
    eim%err = full%err(1:m)
  end subroutine eim_prefix

  !> Greedy DEIM indices of a basis u [p, m] (orthonormal columns expected): idx(1) is the
  !> entry of largest magnitude of u(:, 1); idx(k) that of the residual of u(:, k) after
  !> interpolation by u(:, 1:k-1) at idx(1:k-1) (lowest index on ties, magnitudes within a
  !> relative sqrt(eps) of the largest counting as tied: the choice does not depend on the
  !> rounding of the CPU's BLAS kernels or the number of ranks). The indices are
  !> distinct. Fails (code 2) if m > p or a column is numerically in the span of the previous
  !> ones (its interpolation residual is below p eps |u_k|).
  subroutine deim_indices(u, idx, error, newton)
    !> interpolation basis [p, m]
    real(wp), contiguous, intent(in) :: u(:, :)
    !> interpolation indices in 1..p [m]
    integer, allocatable, intent(out) :: idx(:)
    type(error_t), allocatable, intent(out) :: error
    !> the DEIM residuals rho_k = u_k - interp_{k-1}(u_k), zero on idx(1:k-1) [p, m]
    real(wp), allocatable, intent(out), optional :: newton(:, :)
    real(wp), allocatable :: rho(:, :)
    real(wp) :: alpha, big, unorm
    integer :: p, m, k, j, i

    p = size(u, 1)
    m = size(u, 2)
    if (m > p) then
      call set_error(error, "deim_indices: m = " // str(m) // " basis vectors but only p = " // &
        & str(p) // " entries", EXIT_BAD_INPUT)
      return
    end if
    allocate(idx(m), rho(p, m))
    do k = 1, m
      rho(:, k) = u(:, k)
      do j = 1, k - 1
        alpha = rho(idx(j), k) / rho(idx(j), j)
        if (alpha /= 0.0_wp) rho(:, k) = rho(:, k) - alpha * rho(:, j)
        rho(idx(j), k) = 0.0_wp
      end do
      ! ties: magnitudes within a relative sqrt(eps) of the largest count as equal and the
      ! lowest index wins. Entries equal in exact arithmetic (symmetric contacts) come out a
      ! few eps apart in an order set by the BLAS kernels (CPU) and the number of ranks; a
      ! plain maxloc picked index 15 or 13 (|rho| equal to 2 eps) for the s2 term of the
      ! rom_tiny study at 1 and 2 ranks. sqrt(eps) is far above that rounding and far below
      ! real differences; any entry that large is an equally good DEIM pivot.
      i = max(1, near_max_index(abs(rho(:, k))))
      big = abs(rho(i, k))
      unorm = norm2(u(:, k))
      if (.not. (big > real(p, wp) * epsilon(1.0_wp) * unorm)) then
        call set_error(error, "deim_indices: basis vector " // str(k) // " of " // str(m) // &
          & " is numerically in the span of the previous ones (largest interpolation residual " // &
          & str(big) // ", |u_k| = " // str(unorm) // ")", EXIT_BAD_INPUT)
        return
      end if
      idx(k) = i
    end do
    if (present(newton)) call move_alloc(rho, newton)
  end subroutine deim_indices

  !> Inverse of the interpolation matrix U_I = basis(idx(1:m), 1:m) [m, m] for the first m
  !> modes (0 <= m <= eim%m): the online coefficients are c = minv s(idx(1:m)). Computed by
  !> an SVD; fails if U_I is singular or its 2-norm condition number exceeds 1 / (1000 m eps)
  !> (the message reports it). `cond` returns the condition number.
  subroutine eim_interp_matrix(eim, m, minv, error, cond)
    type(eim_t), intent(in) :: eim
    integer, intent(in) :: m
    !> (U_I)^{-1} [m, m]
    real(wp), allocatable, intent(out) :: minv(:, :)
    type(error_t), allocatable, intent(out) :: error
    !> 2-norm condition number of U_I (1 for m = 0)
    real(wp), intent(out), optional :: cond
    real(wp), allocatable :: a(:, :), u(:, :), vt(:, :), s(:)
    real(wp) :: kappa, limit
    integer :: j

    if (present(cond)) cond = 1.0_wp
    if (m < 0 .or. m > eim%m) then
      call set_error(error, "eim_interp_matrix: m = " // str(m) // " but the EIM has " // &
        & str(eim%m) // " modes", EXIT_BAD_INPUT)
      return
    end if
    allocate(minv(m, m))
    if (m == 0) return
    a = eim%basis(eim%idx(1:m), 1:m)
    allocate(s(m), u(m, m), vt(m, m))
    call la_gesvd(a, s, error, u=u, vt=vt)
    if (allocated(error)) then
      call prefix_error(error, "eim_interp_matrix"); return
    end if
    limit = 1.0_wp / (1000.0_wp * real(m, wp) * epsilon(1.0_wp))
    if (s(m) > 0.0_wp .and. s(1) <= huge(1.0_wp) * s(m)) then
      kappa = s(1) / s(m)
    else
      kappa = huge(1.0_wp)
    end if
    if (present(cond)) cond = kappa
    if (.not. (kappa <= limit)) then
      if (s(m) > 0.0_wp) then
        call set_error(error, "eim_interp_matrix: the " // str(m) // " x " // str(m) // &
          & " interpolation matrix is ill-conditioned (2-norm condition number " // str(kappa) // &
          & " > " // str(limit) // ")")
      else
        call set_error(error, "eim_interp_matrix: the " // str(m) // " x " // str(m) // &
          & " interpolation matrix is singular (smallest singular value 0, largest " // &
          & str(s(1)) // ")")
      end if
      return
    end if
    ! minv = V diag(1/s) U^T
    do j = 1, m
      u(:, j) = u(:, j) / s(j)
    end do
    minv = matmul(transpose(vt), transpose(u))
  end subroutine eim_interp_matrix
end module cr_eim
