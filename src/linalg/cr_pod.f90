!> Proper orthogonal decomposition of a snapshot matrix distributed by columns.
!>
!> S [n_dof, n_snap]: rank r holds the contiguous columns off_r+1 .. off_r+n_r as
!> s_local [n_dof, n_r] (n_r may be 0; the blocks follow the rank order). The POD modes are
!> the left singular vectors of S. Four methods, one result type:
!>
!> * `pod_tsqr`: exact, by TSQR of S^T (no Gram matrix) and the SVD of its R factor
!>   [min(n_dof, n_snap), n_dof]: S^T = Q R, R = U Sigma W^T, modes = W.
!> * `pod_snapshots`: method of snapshots (eigenvectors of S S^T or S^T S, whichever is
!>   smaller). It squares the condition number: singular values below about
!>   sqrt(eps_machine) sigma_1 are lost, so its numerical rank uses the threshold
!>   sigma_i > sqrt(max(n_dof, n_snap) eps_machine) sigma_1. Kept as a baseline.
!> * `pod_rsvd`: randomized SVD (Halko, Martinsson, Tropp 2011) with a Gaussian or SRFT sketch
!>   that does not depend on the number of ranks, and re-orthonormalised power iterations.
!> * `pod_scalapack`: ScaLAPACK pdgesvd on a 2D block-cyclic copy of S (reference). With
!>   fewer rows than ranks (n_dof < P) pdgesvd's processes compute the singular values by
!>   different algorithms and disagree (info = min + 1, for one row by 17%): S, which then has
!>   fewer than P rows, is gathered on rank 0 and its serial LAPACK SVD taken instead (method
!>   "scalapack-serial").
!>
!> Truncation (all methods): `n_modes` fixed N, else `eps`: the smallest N with
!> 1 - sum_{i<=N} sigma_i^2 / ||S||_F^2 <= eps (eps = 1 gives no mode), else every mode up to
!> the numerical rank; never more than the numerical rank
!> (sigma_i > max(n_dof, n_snap) eps_machine sigma_1, zero matrix: rank 0, no mode).
!> Sign rule: the entry of largest magnitude of each mode is positive (lowest index on ties,
!> magnitudes within a relative sqrt(eps) of the largest counting as tied: `near_max_index`).
!> Results are computed on rank 0 and broadcast: identical on every rank.
module cr_pod
  ! all of iso_c_binding: fftw3.f03 (included below) names many of its kinds
  use, intrinsic :: iso_c_binding
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t, set_error, prefix_error
  use cr_sort, only: near_max_index
  use cr_strings, only: str
  use cr_random, only: rng_t
  use cr_lapack, only: la_geqrf, la_orgqr, la_gesvd, la_syevd, la_gemm, la_pdgesvd
  use cr_tsqr, only: tsqr
  use cr_distribution, only: block_range, blacs_grid_t, cyclic_owner, cyclic_local_index, DLEN
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: pod_result_t, pod_tsqr, pod_snapshots, pod_rsvd, pod_scalapack, pod_compute, rsvd_opts_t, POD_METHODS
  public :: snapshot_layout, sketch_gaussian, sketch_srft

  include 'fftw3.f03'

  !> Result of a POD, replicated on every rank.
  type :: pod_result_t
    !> "tsqr", "snapshots", "rsvd-gaussian", "rsvd-srft" or "scalapack"
    character(len=:), allocatable :: method
    integer :: n_dof = 0, n_snap = 0
    !> numerical rank (of the computed singular values)
    integer :: rank = 0
    !> number of retained modes N
    integer :: n_modes = 0
    !> retained singular values [n_modes], descending
    real(wp), allocatable :: sigma(:)
    !> every computed singular value [min(n_dof, n_snap)] (rsvd: [k + p])
    real(wp), allocatable :: sigma_all(:)
    !> POD modes, orthonormal columns [n_dof, n_modes]
    real(wp), allocatable :: phi(:, :)
    !> ||S||_F^2 computed from the data
    real(wp) :: total_energy = 0.0_wp
    !> retained energy fraction sum(sigma^2) / ||S||_F^2 (0 for a zero matrix)
    real(wp) :: energy = 0.0_wp
  end type pod_result_t

  integer, parameter :: ROOT = 0

  !> the POD methods of pod_compute
  character(len=16), parameter :: POD_METHODS(4) = [character(len=16) :: 'tsqr', 'rsvd', 'scalapack', 'snapshots']

  !> Settings of the randomized SVD (pod_compute with method 'rsvd').
  type :: rsvd_opts_t
    integer :: rank = 50, oversampling = 10, power = 2, seed = 1
    character(len=16) :: sketch = 'gaussian'
  end type rsvd_opts_t

contains

  !> The POD of the distributed snapshots by `method` (one of POD_METHODS; 'rsvd' with the
  !> settings `rsvd`), truncated at n_modes modes or at energy eps (as each method documents).
  subroutine pod_compute(env, method, s_local, result, error, eps, n_modes, rsvd)
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: method
    !> snapshots, columns distributed over ranks [n_dof, n_snap_local]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    type(pod_result_t), intent(out) :: result
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(in), optional :: eps
    integer, intent(in), optional :: n_modes
    type(rsvd_opts_t), intent(in), optional :: rsvd
    type(rsvd_opts_t) :: ro
    if (present(rsvd)) ro = rsvd
    select case (trim(method))
    case ('tsqr')
      call pod_tsqr(env, s_local, result, error, eps=eps, n_modes=n_modes)
    case ('snapshots')
      call pod_snapshots(env, s_local, result, error, eps=eps, n_modes=n_modes)
    case ('scalapack')
      call pod_scalapack(env, s_local, result, error, eps=eps, n_modes=n_modes)
    case ('rsvd')
      call pod_rsvd(env, s_local, ro%rank, ro%oversampling, ro%power, trim(ro%sketch), ro%seed, result, error, &
        eps=eps, n_modes=n_modes)
    case default
      call set_error(error, "pod: unknown method '" // trim(method) // "' (known: tsqr, rsvd, scalapack, snapshots)", &
        EXIT_BAD_INPUT)
    end select
  end subroutine pod_compute

  !> Global layout of the column blocks: number of snapshots and this rank's offset.
  !> Fails (on every rank) if n_dof differs between ranks.
  subroutine snapshot_layout(env, s_local, n_snap, offset, error, counts)
    type(env_t), intent(in) :: env
    !> snapshots, columns distributed over ranks: [n_dof, n_r]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    integer, intent(out) :: n_snap, offset
    type(error_t), allocatable, intent(out) :: error
    !> number of columns of every rank [env%size]
    integer, allocatable, intent(out), optional :: counts(:)
    integer, allocatable :: cnt(:)
    integer :: n_dof, mm(2)
    call env%allgather(size(s_local, 2), cnt, error)
    if (allocated(error)) return
    n_snap = sum(cnt)
    offset = sum(cnt(1:env%rank))
    n_dof = size(s_local, 1)
    mm = [n_dof, -n_dof]
    call env%allreduce(mm, 'max', error)
    if (allocated(error)) return
    if (mm(1) /= -mm(2)) then
      call set_error(error, "pod: the snapshots have different lengths on different ranks")
      return
    end if
    if (present(counts)) call move_alloc(cnt, counts)
  end subroutine snapshot_layout

  !> ||S||_F^2 summed over ranks (every rank receives it).
  subroutine frobenius2(env, s_local, f2, error)
    type(env_t), intent(in) :: env
    real(wp), contiguous, intent(in) :: s_local(:, :)
    real(wp), intent(out) :: f2
    type(error_t), allocatable, intent(out) :: error
    f2 = sum(s_local**2)
    call env%allreduce(f2, 'sum', error)
  end subroutine frobenius2

  !> Check the truncation arguments (same on all ranks).
  subroutine check_truncation(eps, n_modes, error)
    real(wp), intent(in), optional :: eps
    integer, intent(in), optional :: n_modes
    type(error_t), allocatable, intent(out) :: error
    if (present(eps)) then
      if (.not. (eps >= 0.0_wp .and. eps <= 1.0_wp)) then
        call set_error(error, "pod: energy tolerance eps = " // str(eps) // " is not in [0, 1]")
        return
      end if
    end if
    if (present(n_modes)) then
      if (n_modes < 0) call set_error(error, "pod: n_modes = " // str(n_modes) // " is negative")
    end if
  end subroutine check_truncation

  !> On rank 0: rank, truncation and sign rule from sigma_all and the candidate modes
  !> modes [n_dof, >= rank]; then broadcast the result. `rank_tol` is the relative
  !> threshold on sigma_i / sigma_1 for the numerical rank; `n_cap` an extra upper bound.
  subroutine finish(env, result, sigma_all, modes, rank_tol, error, eps, n_modes, n_cap)
    type(env_t), intent(in) :: env
    type(pod_result_t), intent(inout) :: result
    real(wp), intent(in) :: sigma_all(:)
    real(wp), intent(in) :: modes(:, :)
    real(wp), intent(in) :: rank_tol
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(in), optional :: eps
    integer, intent(in), optional :: n_modes, n_cap
    integer :: nr, nk, i, j, nsig, meta(3)
    real(wp) :: cum
    if (env%rank == ROOT) then
      nr = 0
      if (size(sigma_all) > 0) then
        if (sigma_all(1) > 0.0_wp) nr = count(sigma_all > rank_tol * sigma_all(1))
      end if
      nr = min(nr, size(modes, 2))
      nk = nr
      if (present(n_cap)) nk = min(nk, n_cap)
      if (present(n_modes)) then
        nk = min(nk, n_modes)
      else if (present(eps)) then
        cum = 0.0_wp
        if (result%total_energy <= 0.0_wp) then
          nk = 0
        else
          i = 0
          do while (i < nk)
            if (1.0_wp - cum / result%total_energy <= eps) exit
            i = i + 1
            cum = cum + sigma_all(i)**2
          end do
          nk = i
        end if
      end if
      result%rank = nr
      result%n_modes = nk
      nsig = size(sigma_all)
    end if
    if (env%rank == ROOT) meta = [result%rank, result%n_modes, nsig]
    call env%bcast(meta, error, root=ROOT)
    if (allocated(error)) return
    result%rank = meta(1); result%n_modes = meta(2); nsig = meta(3)
    nk = result%n_modes
    allocate(result%sigma_all(nsig), result%phi(result%n_dof, nk))
    if (env%rank == ROOT) then
      result%sigma_all = sigma_all
      result%phi = modes(:, 1:nk)
      do j = 1, nk
        ! entries that tie in exact arithmetic (mirror-symmetric data) come out of LAPACK a few
        ! eps apart in a CPU-dependent order: near_max_index keeps the sign machine-independent
        i = max(1, near_max_index(abs(result%phi(:, j))))
        if (result%phi(i, j) < 0.0_wp) result%phi(:, j) = -result%phi(:, j)
      end do
    end if
    if (nsig > 0) call env%bcast(result%sigma_all, error, root=ROOT)
    if (allocated(error)) return
    if (nk * result%n_dof > 0) call env%bcast(result%phi, error, root=ROOT)
    if (allocated(error)) return
    result%sigma = result%sigma_all(1:nk)
    result%energy = 0.0_wp
    if (result%total_energy > 0.0_wp) result%energy = min(1.0_wp, sum(result%sigma**2) / result%total_energy)
  end subroutine finish

  !> Make an error collective: every rank fails if one does.
  subroutine sync_error(env, error, where)
    type(env_t), intent(in) :: env
    type(error_t), allocatable, intent(inout) :: error
    character(len=*), intent(in) :: where
    if (allocated(error)) call prefix_error(error, where)
    call env%agree_error(error)
  end subroutine sync_error

  !> Exact POD by TSQR of S^T and SVD of the final R factor (no Gram matrix).
  subroutine pod_tsqr(env, s_local, result, error, eps, n_modes)
    type(env_t), intent(in) :: env
    !> snapshots, columns distributed over ranks: [n_dof, n_r]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    type(pod_result_t), intent(out) :: result
    type(error_t), allocatable, intent(out) :: error
    !> energy tolerance in [0, 1]
    real(wp), intent(in), optional :: eps
    !> fixed number of modes N (>= 0)
    integer, intent(in), optional :: n_modes
    integer :: n_snap, offset, n_dof
    real(wp), allocatable :: sigma(:), w(:, :), st(:, :)
    call check_truncation(eps, n_modes, error)
    if (allocated(error)) return
    call snapshot_layout(env, s_local, n_snap, offset, error)
    if (allocated(error)) return
    n_dof = size(s_local, 1)
    result%method = "tsqr"
    result%n_dof = n_dof
    result%n_snap = n_snap
    call frobenius2(env, s_local, result%total_energy, error)
    if (allocated(error)) return
    st = transpose(s_local)
    call right_svd(env, st, sigma, w, error)
    if (allocated(error)) return
    call finish(env, result, sigma, w, real(max(n_dof, n_snap), wp) * epsilon(1.0_wp), error, eps, n_modes)
  end subroutine pod_tsqr

  !> Singular values and right singular vectors of A [n_total, n] distributed by rows
  !> (a_local [n_r, n]) via TSQR; sigma [min(n_total, n)] and w [n, min(n_total, n)] on
  !> rank 0 only (zero-sized elsewhere). Collective errors.
  subroutine right_svd(env, a_local, sigma, w, error)
    type(env_t), intent(in) :: env
    real(wp), contiguous, intent(in) :: a_local(:, :)
    real(wp), allocatable, intent(out) :: sigma(:), w(:, :)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: r(:, :), vt(:, :)
    integer :: m, n
    call tsqr(env, a_local, r, error)
    if (allocated(error)) return
    n = size(a_local, 2)
    m = size(r, 1)
    if (env%rank == ROOT) then
      allocate(sigma(min(m, n)), vt(min(m, n), n))
      call la_gesvd(r, sigma, error, vt=vt)
      if (.not. allocated(error)) w = transpose(vt)
    end if
    call sync_error(env, error, "pod")
    if (allocated(error)) return
    if (.not. allocated(sigma)) allocate(sigma(0), w(n, 0))
  end subroutine right_svd

  !> Method of snapshots: eigen-decomposition of the smaller Gram matrix (S S^T summed
  !> over ranks, or S^T S of the gathered S). Squares the condition number.
  subroutine pod_snapshots(env, s_local, result, error, eps, n_modes)
    type(env_t), intent(in) :: env
    !> snapshots, columns distributed over ranks: [n_dof, n_r]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    type(pod_result_t), intent(out) :: result
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(in), optional :: eps
    integer, intent(in), optional :: n_modes
    integer :: n_snap, offset, n_dof, i, k
    real(wp), allocatable :: c(:, :), lam(:), sigma(:), modes(:, :), s(:, :), v(:, :)
    real(wp) :: tol
    call check_truncation(eps, n_modes, error)
    if (allocated(error)) return
    call snapshot_layout(env, s_local, n_snap, offset, error)
    if (allocated(error)) return
    n_dof = size(s_local, 1)
    result%method = "snapshots"
    result%n_dof = n_dof
    result%n_snap = n_snap
    call frobenius2(env, s_local, result%total_energy, error)
    if (allocated(error)) return
    tol = sqrt(real(max(n_dof, n_snap), wp) * epsilon(1.0_wp))
    k = min(n_dof, n_snap)
    if (n_dof <= n_snap) then
      allocate(c(n_dof, n_dof))
      call la_gemm('N', 'T', 1.0_wp, s_local, s_local, 0.0_wp, c, error)
      call sync_error(env, error, "pod_snapshots")
      if (allocated(error)) return
      call reduce_root(env, c, error)
      if (env%rank == ROOT .and. .not. allocated(error)) then
        allocate(lam(n_dof))
        call la_syevd(c, lam, error)
        if (.not. allocated(error)) then
          sigma = sqrt(max(lam(n_dof:1:-1), 0.0_wp))
          modes = c(:, n_dof:1:-1)
        end if
      end if
    else
      ! n_snap < n_dof: gather S on rank 0, G = S^T S, modes S v_i / sigma_i
      call gather_root(env, s_local, n_snap, s, error)
      if (env%rank == ROOT .and. .not. allocated(error)) then
        allocate(c(n_snap, n_snap), lam(n_snap))
        call la_gemm('T', 'N', 1.0_wp, s, s, 0.0_wp, c, error)
        if (.not. allocated(error)) call la_syevd(c, lam, error)
        if (.not. allocated(error)) then
          sigma = sqrt(max(lam(n_snap:1:-1), 0.0_wp))
          v = c(:, n_snap:1:-1)
          allocate(modes(n_dof, n_snap))
          call la_gemm('N', 'N', 1.0_wp, s, v, 0.0_wp, modes, error)
          do i = 1, n_snap
            if (sigma(i) > tol * sigma(1)) then
              modes(:, i) = modes(:, i) / sigma(i)
            else
              modes(:, i) = 0.0_wp
            end if
          end do
        end if
      end if
    end if
    call sync_error(env, error, "pod_snapshots")
    if (allocated(error)) return
    if (.not. allocated(sigma)) allocate(sigma(k), modes(n_dof, 0))
    call finish(env, result, sigma(1:k), modes, tol, error, eps, n_modes)
  end subroutine pod_snapshots

  !> Gaussian test matrix rows for this rank: omega [n_r, l], row j (global offset + j)
  !> drawn from the stream seeded by (seed, offset + j): independent of the number of ranks.
  subroutine sketch_gaussian(seed, offset, omega)
    integer, intent(in) :: seed, offset
    real(wp), intent(out) :: omega(:, :)
    type(rng_t) :: rng
    integer :: i, j
    do i = 1, size(omega, 1)
      call rng%seed(seed, offset + i)
      do j = 1, size(omega, 2)
        omega(i, j) = rng%normal()
      end do
    end do
  end subroutine sketch_gaussian

  !> Signs d [n_snap] and l distinct frequencies sel [l] (0-based) of the SRFT, drawn from
  !> the stream (seed, 0): the same on every rank.
  subroutine srft_draws(seed, n_snap, l, d, sel)
    integer, intent(in) :: seed, n_snap, l
    real(wp), allocatable, intent(out) :: d(:)
    integer, allocatable, intent(out) :: sel(:)
    type(rng_t) :: rng
    integer, allocatable :: perm(:)
    integer :: i, j, t
    call rng%seed(seed, 0)
    allocate(d(n_snap), perm(n_snap))
    do i = 1, n_snap
      d(i) = merge(1.0_wp, -1.0_wp, rng%uniform() < 0.5_wp)
      perm(i) = i - 1
    end do
    do i = 1, l   ! partial Fisher-Yates
      j = i + min(n_snap - i, int(rng%uniform() * real(n_snap - i + 1, wp)))
      t = perm(i); perm(i) = perm(j); perm(j) = t
    end do
    sel = perm(1:l)
  end subroutine srft_draws

  !> SRFT sketch Y = S Omega [n_dof, l] (replicated), Omega = sqrt(n_snap / l) D F P with
  !> D random signs, F the orthonormal DCT-II of length n_snap (FFTW REDFT10) and P the
  !> choice of l random columns. S is transposed to blocks of rows (all snapshots of a few
  !> dofs per rank), each row is transformed, and the sketch rows are gathered.
  subroutine sketch_srft(env, s_local, l, seed, y, error)
    type(env_t), intent(in) :: env
    real(wp), contiguous, intent(in) :: s_local(:, :)
    integer, intent(in) :: l, seed
    real(wp), allocatable, intent(out) :: y(:, :)
    type(error_t), allocatable, intent(out) :: error
    integer :: n_dof, n_snap, offset, nrow, roff, p, pos, j, ro, rc, c
    integer, allocatable :: counts(:), scount(:), sdispl(:), rcount(:), rdispl(:)
    real(wp), allocatable :: sendbuf(:), rows(:, :), trans(:, :), d(:), yt(:, :), yrows_t(:, :)
    integer, allocatable :: sel(:)
    type(c_ptr) :: plan
    real(wp) :: scale
    call snapshot_layout(env, s_local, n_snap, offset, error, counts)
    if (allocated(error)) return
    n_dof = size(s_local, 1)
    call block_range(n_dof, env%size, env%rank, roff, nrow)
    ! column blocks -> row blocks
    allocate(scount(env%size), sdispl(env%size), rcount(env%size), rdispl(env%size))
    allocate(sendbuf(size(s_local)))
    pos = 0
    do p = 1, env%size
      call block_range(n_dof, env%size, p - 1, ro, rc)
      sdispl(p) = pos
      scount(p) = rc * size(s_local, 2)
      do j = 1, size(s_local, 2)
        sendbuf(pos + 1:pos + rc) = s_local(ro + 1:ro + rc, j)
        pos = pos + rc
      end do
      rcount(p) = nrow * counts(p)
    end do
    rdispl(1) = 0
    do p = 2, env%size
      rdispl(p) = rdispl(p - 1) + rcount(p - 1)
    end do
    allocate(rows(nrow, n_snap))
    call env%alltoallv(sendbuf, scount, sdispl, rows, rcount, rdispl, error)
    if (allocated(error)) return
    deallocate(sendbuf)
    call srft_draws(seed, n_snap, l, d, sel)
    allocate(yrows_t(l, nrow))
    if (nrow > 0 .and. n_snap > 0) then
      do j = 1, n_snap
        rows(:, j) = d(j) * rows(:, j)
      end do
      allocate(trans(nrow, n_snap))
      plan = fftw_plan_many_r2r(1, [int(n_snap, c_int)], int(nrow, c_int), rows, &
        & [int(n_snap, c_int)], int(nrow, c_int), 1_c_int, trans, [int(n_snap, c_int)], &
        & int(nrow, c_int), 1_c_int, [FFTW_REDFT10], FFTW_ESTIMATE)
      call fftw_execute_r2r(plan, rows, trans)
      call fftw_destroy_plan(plan)
      do c = 1, l
        scale = sqrt(1.0_wp / (2.0_wp * real(n_snap, wp)))
        if (sel(c) == 0) scale = sqrt(1.0_wp / (4.0_wp * real(n_snap, wp)))
        yrows_t(c, :) = sqrt(real(n_snap, wp) / real(l, wp)) * scale * trans(:, sel(c) + 1)
      end do
    end if
    ! gather the rows of Y (as columns of Y^T)
    do p = 1, env%size
      call block_range(n_dof, env%size, p - 1, ro, rc)
      rcount(p) = rc * l
      rdispl(p) = ro * l
    end do
    allocate(yt(l, n_dof))
    call env%allgatherv(yrows_t, yt, rcount, rdispl, error)
    if (allocated(error)) return
    y = transpose(yt)
  end subroutine sketch_srft

  !> Orthonormal basis of the columns of y [n, l] (l <= n) computed on rank 0 and
  !> broadcast, replacing y. y must hold the complete matrix on rank 0.
  subroutine root_orthonormalize(env, y, error)
    type(env_t), intent(in) :: env
    real(wp), contiguous, intent(inout) :: y(:, :)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: tau(:)
    if (env%rank == ROOT) then
      allocate(tau(size(y, 2)))
      call la_geqrf(y, tau, error)
      if (.not. allocated(error)) call la_orgqr(y, tau, error)
    end if
    call sync_error(env, error, "rsvd: orthonormalisation")
    if (allocated(error)) return
    if (size(y) > 0) call env%bcast(y, error, root=ROOT)
  end subroutine root_orthonormalize

  !> Sum of y over ranks, on rank 0 (ROOT).
  subroutine reduce_root(env, y, error)
    type(env_t), intent(in) :: env
    real(wp), contiguous, intent(inout) :: y(:, :)
    type(error_t), allocatable, intent(out) :: error
    if (env%size == 1 .or. size(y) == 0) return
    call env%reduce_sum_root(y, error)
  end subroutine reduce_root

  !> Randomized POD: range finder Y = S Omega with l = k + oversampling columns (capped at
  !> min(n_dof, n_snap)), `power_iterations` steps Q <- orth(S orth(S^T Q)) (TSQR for the
  !> distributed orth), B = Q^T S, exact POD of B by TSQR, modes Q W. Keeps k modes by
  !> default (or fewer by eps / n_modes, never more than the numerical rank).
  !> sketch: "gaussian" or "srft". The result does not depend on the number of ranks.
  subroutine pod_rsvd(env, s_local, k, oversampling, power_iterations, sketch, seed, result, &
      & error, eps, n_modes)
    type(env_t), intent(in) :: env
    !> snapshots, columns distributed over ranks: [n_dof, n_r]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    !> target rank k >= 1, oversampling p >= 0, power iterations q >= 0
    integer, intent(in) :: k, oversampling, power_iterations
    character(len=*), intent(in) :: sketch
    integer, intent(in) :: seed
    type(pod_result_t), intent(out) :: result
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(in), optional :: eps
    integer, intent(in), optional :: n_modes
    integer :: n_snap, offset, n_dof, l, n_r, it
    real(wp), allocatable :: omega(:, :), y(:, :), z(:, :), zq(:, :), r(:, :), b(:, :)
    real(wp), allocatable :: sigma(:), w(:, :), modes(:, :)
    call check_truncation(eps, n_modes, error)
    if (allocated(error)) return
    if (k < 1 .or. oversampling < 0 .or. power_iterations < 0) then
      call set_error(error, "pod_rsvd: need k >= 1, oversampling >= 0, power_iterations >= 0; got k = " // &
        & str(k) // ", oversampling = " // str(oversampling) // ", power_iterations = " // &
        & str(power_iterations))
      return
    end if
    if (sketch /= "gaussian" .and. sketch /= "srft") then
      call set_error(error, "pod_rsvd: unknown sketch '" // sketch // "' (known: gaussian, srft)")
      return
    end if
    call snapshot_layout(env, s_local, n_snap, offset, error)
    if (allocated(error)) return
    n_dof = size(s_local, 1)
    n_r = size(s_local, 2)
    result%method = "rsvd-" // sketch
    result%n_dof = n_dof
    result%n_snap = n_snap
    call frobenius2(env, s_local, result%total_energy, error)
    if (allocated(error)) return
    l = min(k + oversampling, n_dof, n_snap)

    ! range finder
    if (sketch == "gaussian") then
      allocate(omega(n_r, l), y(n_dof, l))
      call sketch_gaussian(seed, offset, omega)
      call la_gemm('N', 'N', 1.0_wp, s_local, omega, 0.0_wp, y, error)
      if (allocated(error)) return
      deallocate(omega)
      call reduce_root(env, y, error)
      if (allocated(error)) return
    else
      call sketch_srft(env, s_local, l, seed, y, error)
      if (allocated(error)) return
    end if
    call root_orthonormalize(env, y, error)
    if (allocated(error)) return

    ! power iterations, re-orthonormalised after S^T and after S
    allocate(z(n_r, l))
    do it = 1, power_iterations
      call la_gemm('T', 'N', 1.0_wp, s_local, y, 0.0_wp, z, error)
      if (allocated(error)) return
      call tsqr(env, z, r, error, zq)
      if (allocated(error)) return
      if (size(zq, 2) /= l) then
        call set_error(error, "pod_rsvd: power iteration lost columns")
        return
      end if
      call la_gemm('N', 'N', 1.0_wp, s_local, zq, 0.0_wp, y, error)
      if (allocated(error)) return
      call reduce_root(env, y, error)
      if (allocated(error)) return
      call root_orthonormalize(env, y, error)
      if (allocated(error)) return
    end do

    ! B^T = S^T Q [n_snap, l] by rows; its right singular vectors are B's left ones
    allocate(b(n_r, l))
    call la_gemm('T', 'N', 1.0_wp, s_local, y, 0.0_wp, b, error)
    if (allocated(error)) return
    call right_svd(env, b, sigma, w, error)
    if (allocated(error)) return
    if (env%rank == ROOT) then
      allocate(modes(n_dof, size(w, 2)))
      call la_gemm('N', 'N', 1.0_wp, y, w, 0.0_wp, modes, error)
    else
      allocate(modes(n_dof, 0))
    end if
    call sync_error(env, error, "pod_rsvd")
    if (allocated(error)) return
    call finish(env, result, sigma, modes, real(max(n_dof, n_snap), wp) * epsilon(1.0_wp), error, eps, &
      & n_modes, n_cap=k)
  end subroutine pod_rsvd

  !> S [n_dof, n_snap] gathered on rank 0 from its columns distributed in rank order
  !> (s_local [n_dof, n_r]); s is [1, 1] on the other ranks. Collective; errors are this rank's.
  subroutine gather_root(env, s_local, n_snap, s, error)
    type(env_t), intent(in) :: env
    real(wp), contiguous, intent(in) :: s_local(:, :)
    integer, intent(in) :: n_snap
    real(wp), allocatable, intent(out) :: s(:, :)
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: counts(:), displs(:)
    if (env%rank == ROOT) then
      allocate(s(size(s_local, 1), n_snap))
    else
      allocate(s(1, 1))
    end if
    call env%block_counts(size(s_local), counts, displs, error)
    if (.not. allocated(error)) call env%gatherv(s_local, s, counts, displs, ROOT, error)
  end subroutine gather_root

  !> sigma [min(n_dof, n_snap)] and the left singular vectors modes [n_dof, min] of S on rank 0
  !> (zero-sized elsewhere) by the serial LAPACK SVD of S gathered there, for an S with fewer
  !> rows than ranks (small: n_dof < P). Collective errors.
  subroutine serial_root_pod(env, s_local, n_snap, sigma, modes, error)
    type(env_t), intent(in) :: env
    !> snapshots, columns distributed over ranks in rank order: [n_dof, n_r]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    integer, intent(in) :: n_snap
    real(wp), allocatable, intent(out) :: sigma(:), modes(:, :)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: s(:, :)
    integer :: n_dof
    n_dof = size(s_local, 1)
    call gather_root(env, s_local, n_snap, s, error)
    if (allocated(error)) then
      call prefix_error(error, "pod_scalapack: gathering S (" // str(n_dof) // " x " // str(n_snap) // ")"); return
    end if
    if (env%rank == ROOT) then
      allocate(sigma(min(n_dof, n_snap)), modes(n_dof, min(n_dof, n_snap)))
      call la_gesvd(s, sigma, error, u=modes)
    else
      allocate(sigma(0), modes(n_dof, 0))
    end if
    call sync_error(env, error, "pod_scalapack (serial SVD of S, " // str(n_dof) // " x " // str(n_snap) // ")")
  end subroutine serial_root_pod

  !> Reference POD by ScaLAPACK pdgesvd: S is copied into a 2D block-cyclic layout
  !> (block nb x nb, near-square grid over env%comm) with one MPI_Alltoallv. With n_dof <
  !> env%size, the serial SVD of the gathered S instead (module header; serial_root_pod).
  subroutine pod_scalapack(env, s_local, result, error, eps, n_modes, block)
    type(env_t), intent(in) :: env
    !> snapshots, columns distributed over ranks: [n_dof, n_r]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    type(pod_result_t), intent(out) :: result
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(in), optional :: eps
    integer, intent(in), optional :: n_modes
    !> block size of the block-cyclic layout (default 32)
    integer, intent(in), optional :: block
    type(blacs_grid_t) :: grid
    integer :: n_snap, offset, n_dof, nb, mloc, nloc, kmin, kloc, p, i, j, jg, pos, src
    integer :: desca(DLEN), descu(DLEN), pcol, nk, jl
    integer, allocatable :: counts(:), scount(:), sdispl(:), rcount(:), rdispl(:), rowpr(:), rowli(:)
    integer, allocatable :: fill(:), pn(:, :)
    real(wp), allocatable :: sendbuf(:), recvbuf(:), a(:), u(:), sigma(:), modes(:, :)
    call check_truncation(eps, n_modes, error)
    if (allocated(error)) return
    call snapshot_layout(env, s_local, n_snap, offset, error, counts)
    if (allocated(error)) return
    n_dof = size(s_local, 1)
    result%method = "scalapack"
    result%n_dof = n_dof
    result%n_snap = n_snap
    call frobenius2(env, s_local, result%total_energy, error)
    if (allocated(error)) return
    nb = 32
    if (present(block)) nb = max(1, block)
    kmin = min(n_dof, n_snap)
    if (kmin == 0) then
      allocate(sigma(0), modes(n_dof, 0))
      call finish(env, result, sigma, modes, 1.0_wp, error, eps, n_modes)
      return
    end if
    if (n_dof < env%size) then
      result%method = "scalapack-serial"
      call serial_root_pod(env, s_local, n_snap, sigma, modes, error)
      if (allocated(error)) return
      call finish(env, result, sigma, modes, real(max(n_dof, n_snap), wp) * epsilon(1.0_wp), error, eps, n_modes)
      return
    end if
    call grid%init(env, error)
    if (allocated(error)) return
    allocate(pn(0:grid%nprow - 1, 0:grid%npcol - 1))
    do i = 0, grid%nprow - 1
      do j = 0, grid%npcol - 1
        pn(i, j) = grid%pnum(i, j)
      end do
    end do
    mloc = grid%local_rows(n_dof, nb)
    nloc = grid%local_cols(n_snap, nb)
    kloc = grid%local_cols(kmin, nb)
    call grid%descriptor(n_dof, n_snap, nb, nb, desca, error)
    if (.not. allocated(error)) call grid%descriptor(n_dof, kmin, nb, nb, descu, error)
    if (allocated(error)) then
      call grid%free(); return
    end if
    allocate(rowpr(n_dof), rowli(n_dof))
    do i = 1, n_dof
      rowpr(i) = cyclic_owner(i, nb, grid%nprow)
      rowli(i) = cyclic_local_index(i, nb, grid%nprow)
    end do
    ! pack by destination, columns then rows in order
    allocate(scount(env%size), sdispl(env%size), rcount(env%size), rdispl(env%size), fill(env%size))
    scount = 0
    do jl = 1, size(s_local, 2)
      pcol = cyclic_owner(offset + jl, nb, grid%npcol)
      do i = 1, n_dof
        p = pn(rowpr(i), pcol) + 1
        scount(p) = scount(p) + 1
      end do
    end do
    sdispl(1) = 0
    do p = 2, env%size
      sdispl(p) = sdispl(p - 1) + scount(p - 1)
    end do
    allocate(sendbuf(max(1, sum(scount))))
    fill = sdispl
    do jl = 1, size(s_local, 2)
      pcol = cyclic_owner(offset + jl, nb, grid%npcol)
      do i = 1, n_dof
        p = pn(rowpr(i), pcol) + 1
        fill(p) = fill(p) + 1
        sendbuf(fill(p)) = s_local(i, jl)
      end do
    end do
    call env%alltoall(scount, rcount, error)
    if (allocated(error)) then
      call grid%free(); return
    end if
    rdispl(1) = 0
    do p = 2, env%size
      rdispl(p) = rdispl(p - 1) + rcount(p - 1)
    end do
    allocate(recvbuf(max(1, sum(rcount))))
    call env%alltoallv(sendbuf, scount, sdispl, recvbuf, rcount, rdispl, error)
    if (allocated(error)) then
      call grid%free(); return
    end if
    deallocate(sendbuf)
    allocate(a(max(1, mloc) * max(1, nloc)))
    a = 0.0_wp
    pos = 0
    jg = 0
    do src = 1, env%size
      do j = 1, counts(src)
        jg = jg + 1
        if (cyclic_owner(jg, nb, grid%npcol) /= grid%mycol) cycle
        do i = 1, n_dof
          if (rowpr(i) /= grid%myrow) cycle
          pos = pos + 1
          a(rowli(i) + (cyclic_local_index(jg, nb, grid%npcol) - 1) * max(1, mloc)) = recvbuf(pos)
        end do
      end do
    end do
    deallocate(recvbuf)
    allocate(sigma(kmin), u(max(1, mloc) * max(1, kloc)))
    call la_pdgesvd(n_dof, n_snap, a, desca, sigma, u, descu, error)
    call sync_error(env, error, "pod_scalapack")
    if (allocated(error)) then
      call grid%free(); return
    end if
    ! gather the first nk columns of U on rank 0: at most rank-many are needed
    nk = kmin
    if (sigma(1) > 0.0_wp) then
      nk = count(sigma > real(max(n_dof, n_snap), wp) * epsilon(1.0_wp) * sigma(1))
    else
      nk = 0
    end if
    if (present(n_modes)) nk = min(nk, n_modes)
    allocate(modes(n_dof, nk))
    modes = 0.0_wp
    do j = 1, nk
      if (cyclic_owner(j, nb, grid%npcol) /= grid%mycol) cycle
      jl = cyclic_local_index(j, nb, grid%npcol)
      do i = 1, n_dof
        if (rowpr(i) /= grid%myrow) cycle
        modes(i, j) = u(rowli(i) + (jl - 1) * max(1, mloc))
      end do
    end do
    call grid%free()
    call reduce_root(env, modes, error)
    if (allocated(error)) return
    call finish(env, result, sigma, modes, real(max(n_dof, n_snap), wp) * epsilon(1.0_wp), error, eps, n_modes)
  end subroutine pod_scalapack
end module cr_pod
