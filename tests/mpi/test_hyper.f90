!> Hyper-reduction library: EIM (POD + DEIM) and empirical quadrature (Gramian + greedy).
!> Run at 1, 2 and 4 ranks: every snapshot matrix is generated identically on all ranks and
!> distributed by column blocks (`block_range`), so each check also compares the distributed
!> computation with a serial reference computed on every rank.
program test_hyper
  use mpi_f08
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_random, only: rng_t
  use cr_test_columns, only: local_cols
  use cr_eim, only: eim_t, eim_build, eim_prefix, deim_indices, eim_interp_matrix
  use cr_eq, only: eq_t, eq_gramian, eq_build
  use cr_assert, only: check, check_close, test_summary
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  type(env_t) :: env, env1
  type(MPI_Comm) :: c1
  type(error_t), allocatable :: error
  integer :: ierr

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call MPI_Comm_split(env%comm, merge(0, 1, env%rank == 0), env%rank, c1, ierr)
  call env1%init(c1, error)

  call test_eim_in_span()
  call test_eim_full_rank()
  call test_eim_degenerate()
  call test_eim_prefix()
  call test_deim_and_interp_matrix()
  call test_gramian()
  call test_eq_all_candidates()
  call test_eq_compressible()
  call test_eq_duplicates()
  call test_eq_first_selection()
  call test_eq_scaling()
  call test_eq_ties()
  call test_eq_bad_input()

  call env1%free()
  call MPI_Comm_free(c1, ierr)
  call env%free()
  call test_summary(env%rank)
  call MPI_Finalize(ierr)

contains

  ! ---------------------------------------------------------------- helpers

  !> Standard normal matrix [n, m], the same on every rank (stream = column).
  function randn(n, m, seed) result(a)
    integer, intent(in) :: n, m, seed
    real(wp), allocatable :: a(:, :)
    type(rng_t) :: rng
    integer :: i, j
    allocate(a(n, m))
    do j = 1, m
      call rng%seed(seed, j)
      do i = 1, n
        a(i, j) = rng%normal()
      end do
    end do
  end function randn

  logical function finite(x)
    real(wp), intent(in) :: x(:)
    finite = all(abs(x) <= huge(1.0_wp))
  end function finite

  logical function distinct(idx)
    integer, intent(in) :: idx(:)
    integer :: i
    distinct = .true.
    do i = 2, size(idx)
      if (any(idx(1:i - 1) == idx(i))) distinct = .false.
    end do
  end function distinct

  !> .true. when the integer array is the same on every rank.
  logical function same_on_all_ranks(idx)
    integer, intent(in) :: idx(:)
    integer :: mm(2 * size(idx))
    type(error_t), allocatable :: e
    mm = [idx, -idx]
    call env%allreduce(mm, 'max', e)
    call check(.not. allocated(e), "allreduce of the indices")
    same_on_all_ranks = all(mm(1:size(idx)) == -mm(size(idx) + 1:))
  end function same_on_all_ranks

  !> max over the columns of s of |s - interp_k(s)| / |s| with the first k EIM modes, and
  !> max of the interpolation defect at the indices |interp_k(s)_I - s_I| / |s|.
  subroutine eim_direct(eim, k, s, err, err_at_idx)
    type(eim_t), intent(in) :: eim
    integer, intent(in) :: k
    real(wp), intent(in) :: s(:, :)
    real(wp), intent(out) :: err, err_at_idx
    real(wp), allocatable :: minv(:, :), approx(:)
    type(error_t), allocatable :: e
    integer :: j
    err = huge(1.0_wp); err_at_idx = huge(1.0_wp)
    call eim_interp_matrix(eim, k, minv, e)
    call check(.not. allocated(e), "eim_interp_matrix runs for k modes")
    if (allocated(e)) return
    err = 0.0_wp; err_at_idx = 0.0_wp
    do j = 1, size(s, 2)
      if (norm2(s(:, j)) == 0.0_wp) cycle
      approx = matmul(eim%basis(:, 1:k), matmul(minv, s(eim%idx(1:k), j)))
      err = max(err, norm2(s(:, j) - approx) / norm2(s(:, j)))
      err_at_idx = max(err_at_idx, maxval(abs(approx(eim%idx(1:k)) - s(eim%idx(1:k), j))) / &
        & norm2(s(:, j)))
    end do
  end subroutine eim_direct

  !> Direct EQ error: sqrt(sum_sigma |Pi - sum_{i in idx} w_i s_i f_i|^2 / sum_sigma |Pi|^2),
  !> Pi(sigma) = F s(sigma); s [p, n_snap], f [q, p].
  real(wp) function eq_direct(s, f, idx, w) result(err)
    real(wp), intent(in) :: s(:, :), f(:, :), w(:)
    integer, intent(in) :: idx(:)
    real(wp), allocatable :: pi(:, :), approx(:, :)
    integer :: k
    pi = matmul(f, s)
    allocate(approx(size(pi, 1), size(pi, 2)))
    approx = 0.0_wp
    do k = 1, size(idx)
      approx = approx + w(k) * spread(f(:, idx(k)), 2, size(s, 2)) * spread(s(idx(k), :), 1, size(f, 1))
    end do
    err = norm2(pi - approx) / norm2(pi)
  end function eq_direct

  !> Accuracy of the EQ error history eq%err: it comes from the Gramian alone and cancels;
  !> cr_eq.f90 states its absolute floor as about sqrt(eps 1^T|H|1 / 1^T H 1), H = (S S^T) o
  !> (F^T F), 1^T H 1 = sum_sigma |Pi|^2: 10x that (>= 1.5e-7). Whether a run sits at the floor
  !> depends on the BLAS kernels: ~2e-8 with the FMA ones (Haswell, AVX-512), ~2e-14 at one
  !> rank with the SSE/AVX ones (docs/testing.md#other-cpus-kernels).
  real(wp) function eq_err_tol(s, f) result(tol)
    real(wp), intent(in) :: s(:, :), f(:, :)
    tol = 10.0_wp * sqrt(epsilon(1.0_wp) * sum(abs(matmul(s, transpose(s))) * &
      & abs(matmul(transpose(f), f))) / sum(matmul(f, s)**2))
  end function eq_err_tol

  !> Common checks of an EQ result against the data: history non-increasing (up to `slack`),
  !> equal to the direct error, finite weights, distinct indices, same on every rank.
  subroutine check_eq_history(eq, s, f, slack, name)
    type(eq_t), intent(in) :: eq
    real(wp), intent(in) :: s(:, :), f(:, :), slack
    character(len=*), intent(in) :: name
    integer :: k
    real(wp) :: worst_increase, worst_diff, d
    call check(size(eq%idx) == eq%m .and. size(eq%err) == eq%m .and. size(eq%w, 1) == eq%m .and. &
      & size(eq%w, 2) == eq%m, name // ": sizes consistent with m")
    call check(distinct(eq%idx), name // ": selected candidates distinct")
    call check(all(eq%idx >= 1 .and. eq%idx <= eq%p), name // ": indices in 1..p")
    call check(same_on_all_ranks(eq%idx), name // ": same selection on every rank")
    worst_increase = 0.0_wp
    worst_diff = 0.0_wp
    do k = 1, eq%m
      call check(finite(eq%w(1:k, k)), name // ": finite weights")
      if (.not. eq%signed) call check(all(eq%w(1:k, k) >= 0.0_wp), name // ": non-negative weights")
      if (k > 1) worst_increase = max(worst_increase, eq%err(k) - eq%err(k - 1))
      d = eq_direct(s, f, eq%idx(1:k), eq%w(1:k, k))
      worst_diff = max(worst_diff, abs(d - eq%err(k)))
    end do
    call check(finite(eq%err), name // ": finite error history")
    call check_close(worst_increase, 0.0_wp, slack, name // ": error history non-increasing")
    call check_close(worst_diff, 0.0_wp, eq_err_tol(s, f), name // ": error history = direct error")
  end subroutine check_eq_history

  ! ---------------------------------------------------------------- EIM

  !> Snapshots of rank 6: exact interpolation everywhere with 6 modes; clamping; m > p.
  subroutine test_eim_in_span()
    integer, parameter :: p = 40, ns = 30, r = 6
    real(wp), allocatable :: s(:, :)
    type(eim_t) :: eim
    type(error_t), allocatable :: e
    real(wp) :: err, err_idx, worst
    integer :: k
    s = matmul(randn(p, r, 1), randn(r, ns, 2))
    call eim_build(env, local_cols(env, s), r, eim, e)
    call check(.not. allocated(e), "eim in span: builds")
    if (allocated(e)) return
    call check(eim%m == r .and. eim%p == p, "eim in span: m = 6, p = 40")
    call check(.not. allocated(eim%note), "eim in span: no note when m = m_max")
    call check(size(eim%idx) == r .and. distinct(eim%idx), "eim in span: DEIM indices distinct")
    call check(all(eim%idx >= 1 .and. eim%idx <= p), "eim in span: indices in 1..p")
    call check(same_on_all_ranks(eim%idx), "eim in span: same indices on every rank")
    call check(size(eim%sigma) == min(p, ns), "eim in span: every singular value kept")
    call check_close(maxval(abs(matmul(transpose(eim%basis), eim%basis) - identity(r))), 0.0_wp, &
      & 1.0e-13_wp, "eim in span: orthonormal basis")
    call eim_direct(eim, r, s, err, err_idx)
    call check_close(err_idx, 0.0_wp, 1.0e-12_wp, "eim in span: interp(s)_I = s_I")
    call check_close(err, 0.0_wp, 1.0e-10_wp, "eim in span: interp(s) = s everywhere")
    call check_close(eim%err(r), 0.0_wp, 1.0e-10_wp, "eim in span: err(m) ~ 0")
    worst = 0.0_wp
    do k = 1, r
      call eim_direct(eim, k, s, err, err_idx)
      worst = max(worst, abs(err - eim%err(k)))
    end do
    call check_close(worst, 0.0_wp, 1.0e-10_wp, "eim in span: err(k) = direct error for every k")

    call eim_build(env, local_cols(env, s), 10, eim, e)
    call check(.not. allocated(e), "eim clamp: builds")
    if (.not. allocated(e)) then
      call check(eim%m == r, "eim clamp: m reduced to the numerical rank 6")
      call check(allocated(eim%note), "eim clamp: note set")
      if (allocated(eim%note)) call check(index(eim%note, "from 10 to the numerical rank 6") > 0, &
        & "eim clamp: note names both m")
    end if

    call eim_build(env, local_cols(env, s), p + 1, eim, e)
    call check(allocated(e), "eim m > p: error")
    if (allocated(e)) then
      call check(e%code == EXIT_BAD_INPUT, "eim m > p: input error code 2")
      call check(index(e%message, "m = 41") > 0 .and. index(e%message, "p = 40") > 0, &
        & "eim m > p: message names m and p")
    end if
  end subroutine test_eim_in_span

  function identity(n) result(a)
    integer, intent(in) :: n
    real(wp) :: a(n, n)
    integer :: i
    a = 0.0_wp
    do i = 1, n
      a(i, i) = 1.0_wp
    end do
  end function identity

  !> Full-rank snapshots: exact at the indices, distributed error history = direct.
  subroutine test_eim_full_rank()
    integer, parameter :: p = 25, ns = 60, m = 12
    real(wp), allocatable :: s(:, :)
    type(eim_t) :: eim
    type(error_t), allocatable :: e
    real(wp) :: err, err_idx, worst, worst_idx
    integer :: k
    s = randn(p, ns, 3)
    s(5, :) = 10.0_wp * s(5, :)
    call eim_build(env, local_cols(env, s), m, eim, e)
    call check(.not. allocated(e), "eim full rank: builds")
    if (allocated(e)) return
    call check(eim%m == m .and. distinct(eim%idx), "eim full rank: m = 12, distinct indices")
    call check(eim%idx(1) == 5, "eim full rank: first index at the dominant entry")
    worst = 0.0_wp
    worst_idx = 0.0_wp
    do k = 1, m
      call eim_direct(eim, k, s, err, err_idx)
      worst = max(worst, abs(err - eim%err(k)))
      worst_idx = max(worst_idx, err_idx)
    end do
    call check_close(worst_idx, 0.0_wp, 1.0e-12_wp, "eim full rank: interp(s)_I = s_I for every k")
    call check_close(worst, 0.0_wp, 1.0e-10_wp, "eim full rank: err(k) = direct error")
    call check(eim%err(m) > 1.0e-3_wp, "eim full rank: 12 of 25 modes do not interpolate exactly")
  end subroutine test_eim_full_rank

  !> All-zero snapshots, fewer snapshots than modes (a rank without columns at 4 ranks).
  subroutine test_eim_degenerate()
    real(wp), allocatable :: s(:, :)
    type(eim_t) :: eim
    type(error_t), allocatable :: e
    real(wp) :: err, err_idx
    allocate(s(10, 7))
    s = 0.0_wp
    call eim_build(env, local_cols(env, s), 4, eim, e)
    call check(.not. allocated(e), "eim zero snapshots: no error")
    if (.not. allocated(e)) then
      call check(eim%m == 0 .and. size(eim%idx) == 0 .and. size(eim%err) == 0, "eim zero snapshots: m = 0")
      call check(allocated(eim%note), "eim zero snapshots: note set")
      call check(finite(eim%sigma) .and. all(eim%sigma == 0.0_wp), "eim zero snapshots: sigma = 0, finite")
    end if
    call eim%free()
    call check(eim%m == 0 .and. .not. allocated(eim%basis), "eim free")

    s = randn(10, 3, 4)
    call eim_build(env, local_cols(env, s), 5, eim, e)
    call check(.not. allocated(e), "eim 3 snapshots: builds (some rank may hold none)")
    if (allocated(e)) return
    call check(eim%m == 3 .and. allocated(eim%note), "eim 3 snapshots: m clamped to 3 with a note")
    call eim_direct(eim, 3, s, err, err_idx)
    call check_close(err, 0.0_wp, 1.0e-12_wp, "eim 3 snapshots: exact reconstruction")
  end subroutine test_eim_degenerate

  !> eim_prefix: the EIM built for more modes, cut to m, is bitwise the EIM built for m (modes,
  !> nested indices, error history, singular values, note), including m above the numerical
  !> rank and all-zero snapshots; m above the modes requested is refused.
  subroutine test_eim_prefix()
    integer, parameter :: p = 30, ns = 40
    real(wp), allocatable :: s(:, :)
    type(eim_t) :: full, cut, direct
    type(error_t), allocatable :: e
    integer :: m
    s = randn(p, ns, 11)
    call eim_build(env, local_cols(env, s), 20, full, e)
    call check(.not. allocated(e), "eim prefix: full build")
    if (allocated(e)) return
    do m = 1, 20, 6
      call eim_build(env, local_cols(env, s), m, direct, e)
      if (.not. allocated(e)) call eim_prefix(full, 20, m, cut, e)
      call check(.not. allocated(e), "eim prefix m = " // str(m) // ": builds")
      if (allocated(e)) return
      call check(same_eim(cut, direct), "eim prefix m = " // str(m) // ": bitwise the direct build")
    end do
    ! rank 6: m = 10 is clamped with the note of a direct build
    s = matmul(randn(p, 6, 12), randn(6, ns, 13))
    call eim_build(env, local_cols(env, s), 15, full, e)
    if (.not. allocated(e)) call eim_build(env, local_cols(env, s), 10, direct, e)
    if (.not. allocated(e)) call eim_prefix(full, 15, 10, cut, e)
    call check(.not. allocated(e), "eim prefix, rank 6: builds")
    if (allocated(e)) return
    call check(same_eim(cut, direct) .and. allocated(cut%note), "eim prefix, rank 6: clamped, same note")
    if (allocated(cut%note) .and. allocated(direct%note)) &
      call check(cut%note == direct%note, "eim prefix, rank 6: note '" // cut%note // "'")
    s = 0.0_wp
    call eim_build(env, local_cols(env, s), 5, full, e)
    if (.not. allocated(e)) call eim_build(env, local_cols(env, s), 3, direct, e)
    if (.not. allocated(e)) call eim_prefix(full, 5, 3, cut, e)
    call check(.not. allocated(e), "eim prefix, zero snapshots: builds")
    if (allocated(e)) return
    call check(same_eim(cut, direct) .and. cut%m == 0, "eim prefix, zero snapshots: m = 0, same note")
    call eim_prefix(full, 5, 6, cut, e)
    call check(allocated(e), "eim prefix: more modes than built is refused")
    if (allocated(e)) call check(e%code == EXIT_BAD_INPUT, "eim prefix: input error code 2")
  end subroutine test_eim_prefix

  !> Every component of two EIMs bitwise equal.
  logical function same_eim(a, b)
    type(eim_t), intent(in) :: a, b
    same_eim = a%p == b%p .and. a%m == b%m .and. allocated(a%note) .eqv. allocated(b%note)
    if (.not. same_eim) return
    same_eim = all(shape(a%basis) == shape(b%basis)) .and. size(a%idx) == size(b%idx) .and. &
      size(a%err) == size(b%err) .and. size(a%sigma) == size(b%sigma)
    if (.not. same_eim) return
    same_eim = all(a%basis == b%basis) .and. all(a%idx == b%idx) .and. all(a%err == b%err) .and. &
      all(a%sigma == b%sigma)
    if (same_eim .and. allocated(a%note)) same_eim = a%note == b%note
  end function same_eim

  !> DEIM on a permuted identity, bad bases, singular and out-of-range interpolation matrices.
  subroutine test_deim_and_interp_matrix()
    real(wp), allocatable :: u(:, :), minv(:, :)
    integer, allocatable :: idx(:)
    integer, parameter :: perm(4) = [3, 7, 1, 5]
    type(error_t), allocatable :: e
    type(eim_t) :: eim
    real(wp) :: cond
    integer :: k
    allocate(u(8, 4))
    u = 0.0_wp
    do k = 1, 4
      u(perm(k), k) = 1.0_wp
    end do
    call deim_indices(u, idx, e)
    call check(.not. allocated(e), "deim: permuted identity runs")
    if (.not. allocated(e)) call check(all(idx == perm), "deim: permuted identity -> its positions")
    ! near-ties (a relative 1e-12 apart, as rounding leaves exact ties of symmetric data) go to
    ! the lowest index; a relative 1e-6 is a real difference (cr_eim.f90 deim_indices)
    block
      real(wp) :: w(4, 1)
      w(:, 1) = [0.1_wp, 0.6_wp, -0.6_wp * (1.0_wp + 1.0e-12_wp), 0.5_wp]
      call deim_indices(w, idx, e)
      if (.not. allocated(e)) call check(idx(1) == 2, "deim: near-tie -> lowest index")
      w(3, 1) = -0.6_wp * (1.0_wp + 1.0e-6_wp)
      call deim_indices(w, idx, e)
      if (.not. allocated(e)) call check(idx(1) == 3, "deim: 1e-6 apart -> largest")
    end block

    u(:, 3) = u(:, 1)
    call deim_indices(u, idx, e)
    call check(allocated(e), "deim: dependent basis vector is an error")
    deallocate(u)
    allocate(u(3, 4))
    u = 1.0_wp
    call deim_indices(u, idx, e)
    call check(allocated(e), "deim: m > p is an error")
    if (allocated(e)) call check(e%code == EXIT_BAD_INPUT, "deim: m > p, code 2")

    ! a hand-made EIM whose 2 x 2 interpolation matrix [[1, 1], [0, 0]] is singular
    eim%p = 3; eim%m = 2
    allocate(eim%basis(3, 2))
    eim%basis = reshape([1.0_wp, 0.0_wp, 0.0_wp, 1.0_wp, 0.0_wp, 1.0_wp], [3, 2])
    eim%idx = [1, 2]
    call eim_interp_matrix(eim, 2, minv, e, cond)
    call check(allocated(e), "interp matrix: singular is an error")
    if (allocated(e)) call check(index(e%message, "singular") > 0, "interp matrix: message says singular")
    eim%basis(2, 2) = 1.0e-15_wp
    call eim_interp_matrix(eim, 2, minv, e, cond)
    call check(allocated(e), "interp matrix: ill-conditioned is an error")
    if (allocated(e)) call check(index(e%message, "condition number") > 0, &
      & "interp matrix: message reports the condition number")
    eim%idx = [1, 3]
    call eim_interp_matrix(eim, 2, minv, e, cond)
    call check(.not. allocated(e), "interp matrix: regular case runs")
    if (.not. allocated(e)) then
      call check_close(maxval(abs(matmul(minv, eim%basis(eim%idx, :)) - identity(2))), 0.0_wp, 1.0e-14_wp, &
        & "interp matrix: inverse")
      call check(cond >= 1.0_wp .and. cond < 10.0_wp, "interp matrix: condition number returned")
    end if
    call eim_interp_matrix(eim, 3, minv, e)
    call check(allocated(e), "interp matrix: m > eim%m is an error")
    if (allocated(e)) call check(e%code == EXIT_BAD_INPUT, "interp matrix: m > eim%m, code 2")
  end subroutine test_deim_and_interp_matrix

  ! ---------------------------------------------------------------- EQ

  !> Kernel K = F^T F [p, p] of constant vectors f [q, p].
  function kernel(f) result(kmat)
    real(wp), intent(in) :: f(:, :)
    real(wp), allocatable :: kmat(:, :)
    kmat = matmul(transpose(f), f)
  end function kernel

  !> Distributed Gramian = serial (S S^T) o K on every rank; identical on all ranks.
  subroutine test_gramian()
    real(wp), allocatable :: s(:, :), f(:, :), kmat(:, :), h(:, :), href(:, :), hmax(:, :), hmin(:, :)
    real(wp), allocatable :: h1(:, :)
    type(error_t), allocatable :: e
    integer :: ns, it
    do it = 1, 2
      ns = merge(13, 3, it == 1)
      s = randn(9, ns, 10 + it)
      f = randn(4, 9, 20 + it)
      kmat = kernel(f)
      call eq_gramian(env, local_cols(env, s), kmat, h, e)
      call check(.not. allocated(e), "gramian: runs")
      if (allocated(e)) return
      href = matmul(s, transpose(s)) * kmat
      call check_close(maxval(abs(h - href)) / maxval(abs(href)), 0.0_wp, 1.0e-13_wp, &
        & "gramian: distributed = serial product (relative)")
      call check(all(h == transpose(h)), "gramian: exactly symmetric")
      hmax = h; hmin = h
      call MPI_Allreduce(MPI_IN_PLACE, hmax, size(h), MPI_DOUBLE_PRECISION, MPI_MAX, env%comm, ierr)
      call MPI_Allreduce(MPI_IN_PLACE, hmin, size(h), MPI_DOUBLE_PRECISION, MPI_MIN, env%comm, ierr)
      call check(all(hmax == hmin), "gramian: bitwise identical on every rank")
      if (env%rank == 0) then
        call eq_gramian(env1, s, kmat, h1, e)
        call check(.not. allocated(e), "gramian: one-rank run")
        if (.not. allocated(e)) call check_close(maxval(abs(h1 - h)) / maxval(abs(href)), 0.0_wp, &
          & 1.0e-13_wp, "gramian: 1 rank and N ranks agree")
      end if
    end do
    h1 = kmat(1:8, 1:8)
    call eq_gramian(env, local_cols(env, s), h1, h, e)
    call check(allocated(e), "gramian: kernel of the wrong size is an error")
    if (allocated(e)) call check(e%code == EXIT_BAD_INPUT, "gramian: wrong kernel, code 2")
  end subroutine test_gramian

  !> All candidates of a small non-singular problem: Pi reproduced exactly (both variants,
  !> both selection rules); w = 1.
  subroutine test_eq_all_candidates()
    integer, parameter :: p = 12, q = 3, ns = 40
    real(wp), allocatable :: s(:, :), f(:, :), h(:, :)
    type(eq_t) :: eq
    type(error_t), allocatable :: e
    integer :: variant
    logical :: signed
    character(len=:), allocatable :: name, rule
    s = randn(p, ns, 31)
    f = randn(q, p, 32)
    call eq_gramian(env, local_cols(env, s), kernel(f), h, e)
    call check(.not. allocated(e), "eq all: gramian")
    if (allocated(e)) return
    do variant = 1, 4
      signed = variant == 1 .or. variant == 3
      rule = merge("residual", "paper   ", variant <= 2)
      rule = trim(rule)
      name = "eq all (" // merge("signed      ", "non-negative", signed) // ", " // rule // ")"
      call eq_build(h, signed, p, 0.0_wp, eq, e, rule=rule)
      call check(.not. allocated(e), name // ": builds")
      if (allocated(e)) cycle
      call check(eq%m == p .and. .not. allocated(eq%note), name // ": every candidate selected")
      call check(eq%signed .eqv. signed, name // ": variant recorded")
      call check_close(eq_direct(s, f, eq%idx, eq%w(:, p)), 0.0_wp, 1.0e-10_wp, name // ": Pi reproduced")
      call check_close(maxval(abs(eq%w(:, p) - 1.0_wp)), 0.0_wp, 1.0e-8_wp, name // ": w = 1")
      call check_close(eq%err(p), 0.0_wp, eq_err_tol(s, f), name // ": final error ~ 0")
      call check_eq_history(eq, s, f, merge(1.0e-14_wp, 1.0e-12_wp, signed), name)
    end do
  end subroutine test_eq_all_candidates

  !> Rank-3 snapshots, q = 2: the candidates span a 6-dimensional space, so the signed EQ is
  !> exact with 6 candidates and refuses the others as dependent; tolerance stop.
  subroutine test_eq_compressible()
    integer, parameter :: p = 60, q = 2, ns = 50, r = 3
    real(wp), allocatable :: s(:, :), f(:, :), h(:, :)
    type(eq_t) :: eq
    type(error_t), allocatable :: e
    s = matmul(randn(p, r, 41), randn(r, ns, 42))
    f = randn(q, p, 43)
    call eq_gramian(env, local_cols(env, s), kernel(f), h, e)
    call check(.not. allocated(e), "eq compressible: gramian")
    if (allocated(e)) return

    call eq_build(h, .true., 20, 0.0_wp, eq, e)
    call check(.not. allocated(e), "eq compressible signed: builds")
    if (.not. allocated(e)) then
      call check(eq%m == q * r, "eq compressible signed: m = q r = 6, the rest refused")
      call check(allocated(eq%note), "eq compressible signed: note on the early stop")
      call check_close(eq_direct(s, f, eq%idx, eq%w(:, eq%m)), 0.0_wp, 1.0e-9_wp, &
        & "eq compressible signed: Pi reproduced with 6 candidates")
      call check_eq_history(eq, s, f, 1.0e-14_wp, "eq compressible signed")
    end if

    call eq_build(h, .true., 20, 1.0e-2_wp, eq, e)
    call check(.not. allocated(e), "eq tolerance: builds")
    if (.not. allocated(e)) then
      call check(eq%m >= 1 .and. eq%m < 20, "eq tolerance: stops early")
      call check(eq%err(eq%m) <= 1.0e-2_wp, "eq tolerance: last error below tol")
      if (eq%m > 1) call check(eq%err(eq%m - 1) > 1.0e-2_wp, "eq tolerance: previous error above tol")
      call check(allocated(eq%note), "eq tolerance: note")
      if (allocated(eq%note)) call check(index(eq%note, "tolerance") > 0, "eq tolerance: note names it")
    end if

    call eq_build(h, .false., 30, 0.0_wp, eq, e)
    call check(.not. allocated(e), "eq compressible non-negative: builds")
    if (.not. allocated(e)) then
      call check_eq_history(eq, s, f, 1.0e-12_wp, "eq compressible non-negative")
      call check(eq%err(eq%m) < 0.5_wp * eq%err(1), "eq compressible non-negative: error decreases")
    end if
  end subroutine test_eq_compressible

  !> Duplicate candidate (exact and perturbed by 1e-13), an always-zero candidate and one with
  !> f = 0: never selected, no NaN/Inf, the error still reaches ~0.
  subroutine test_eq_duplicates()
    integer, parameter :: p = 13, q = 3, ns = 40
    real(wp), allocatable :: s(:, :), f(:, :), h(:, :), pert(:, :)
    type(eq_t) :: eq
    type(error_t), allocatable :: e
    integer :: variant
    logical :: signed, near
    character(len=:), allocatable :: name
    s = randn(p, ns, 51)
    f = randn(q, p, 52)
    pert = randn(1, ns, 53)
    f(:, 11) = f(:, 3)
    s(12, :) = 0.0_wp
    f(:, 13) = 0.0_wp
    do variant = 1, 4
      signed = mod(variant, 2) == 1
      near = variant > 2
      if (near) then
        s(11, :) = s(3, :) * (1.0_wp + 1.0e-13_wp * pert(1, :))
      else
        s(11, :) = s(3, :)
      end if
      name = "eq " // merge("near-duplicate", "duplicate     ", near) // " (" // &
        & merge("signed      ", "non-negative", signed) // ")"
      call eq_gramian(env, local_cols(env, s), kernel(f), h, e)
      call check(.not. allocated(e), name // ": gramian")
      if (allocated(e)) return
      call eq_build(h, signed, p, 0.0_wp, eq, e)
      call check(.not. allocated(e), name // ": builds")
      if (allocated(e)) cycle
      call check(eq%m == 10, name // ": 10 independent candidates selected")
      call check(.not. (any(eq%idx == 3) .and. any(eq%idx == 11)), name // ": duplicate not selected twice")
      call check(.not. any(eq%idx == 12 .or. eq%idx == 13), name // ": zero-diagonal candidates never selected")
      call check(allocated(eq%note), name // ": note on the early stop")
      call check_close(eq%err(eq%m), 0.0_wp, eq_err_tol(s, f), name // ": error reaches ~0")
      call check_close(eq_direct(s, f, eq%idx, eq%w(:, eq%m)), 0.0_wp, 1.0e-9_wp, name // ": Pi reproduced")
      call check_eq_history(eq, s, f, merge(1.0e-14_wp, 1.0e-12_wp, signed), name)
    end do
  end subroutine test_eq_duplicates

  !> First selection = the best score computed from H directly, for both signs and rules, on
  !> data where the best signed score is negative (a candidate with f pointing against the rest).
  subroutine test_eq_first_selection()
    integer, parameter :: p = 10, q = 3, ns = 30
    real(wp), allocatable :: s(:, :), f(:, :), h(:, :), c(:), dinv(:), res(:), pap(:)
    type(eq_t) :: eq
    type(error_t), allocatable :: e
    integer :: i, expect
    s = abs(randn(p, ns, 81))
    f = randn(q, p, 82) + 2.0_wp
    ! candidate 4: a small multiple of the mean snapshot entry with a reversed mean kernel
    ! vector: the best normalised correlation (negative), but not the largest raw one
    s(4, :) = 0.01_wp * sum(s, dim=1) / real(p, wp)
    f(:, 4) = -3.0_wp * sum(f, dim=2) / real(p, wp)
    call eq_gramian(env, local_cols(env, s), kernel(f), h, e)
    call check(.not. allocated(e), "eq first selection: gramian")
    if (allocated(e)) return
    c = sum(h, dim=2)
    allocate(dinv(p))
    do i = 1, p
      dinv(i) = 1.0_wp / sqrt(h(i, i))
    end do
    res = c * dinv
    pap = dinv * matmul(h, dinv * res)
    expect = maxloc(abs(res), dim=1)
    call check(res(expect) < 0.0_wp, "eq first selection: the data make the best signed score negative")
    call check(maxloc(abs(c), dim=1) /= expect, "eq first selection: the data need the diagonal scaling")
    call eq_build(h, .true., 3, 0.0_wp, eq, e)
    if (.not. allocated(e)) call check(eq%idx(1) == expect, "eq first selection: signed, residual rule")
    call eq_build(h, .false., 3, 0.0_wp, eq, e)
    if (.not. allocated(e)) call check(eq%idx(1) == maxloc(res, dim=1), &
      & "eq first selection: non-negative, residual rule")
    call eq_build(h, .true., 3, 0.0_wp, eq, e, rule="paper")
    if (.not. allocated(e)) call check(eq%idx(1) == maxloc(abs(pap), dim=1), &
      & "eq first selection: signed, paper rule")
    call eq_build(h, .false., 3, 0.0_wp, eq, e, rule="paper")
    if (.not. allocated(e)) call check(eq%idx(1) == maxloc(pap, dim=1), &
      & "eq first selection: non-negative, paper rule")

    ! the rules differ: candidate 1 alone on the first half of the snapshots (amplitude 1),
    ! candidates 2-4 nearly equal on the second half (amplitude 1/4 each). Residual rule: the
    ! normalised correlations are sqrt(15) and (3/4) sqrt(15): candidate 1. Paper rule: the
    ! cluster adds up, 3 (3/4) sqrt(15) > sqrt(15): a cluster member.
    deallocate(s, f)
    allocate(s(4, ns), f(1, 4))
    s = 0.0_wp
    s(1, 1:15) = 1.0_wp
    pap = reshape(randn(3, 15, 83), [45])
    do i = 2, 4
      s(i, 16:30) = 0.25_wp + 0.01_wp * pap((i - 2) * 15 + 1:(i - 1) * 15)
    end do
    f = 1.0_wp
    call eq_gramian(env, local_cols(env, s), kernel(f), h, e)
    call check(.not. allocated(e), "eq rules differ: gramian")
    if (allocated(e)) return
    do i = 1, 2
      call eq_build(h, i == 1, 2, 0.0_wp, eq, e)
      if (.not. allocated(e)) call check(eq%idx(1) == 1, "eq rules differ: residual rule picks the single one")
      call eq_build(h, i == 1, 2, 0.0_wp, eq, e, rule="paper")
      if (.not. allocated(e)) call check(eq%idx(1) >= 2, "eq rules differ: paper rule picks the cluster")
    end do
  end subroutine test_eq_first_selection

  !> Candidates scaled over 24 orders of magnitude: same accuracy thanks to the diagonal scaling.
  subroutine test_eq_scaling()
    integer, parameter :: p = 12, q = 3, ns = 40
    real(wp), allocatable :: s(:, :), f(:, :), h(:, :)
    type(eq_t) :: eq
    type(error_t), allocatable :: e
    integer :: i, variant
    logical :: signed
    s = randn(p, ns, 61)
    f = randn(q, p, 62)
    do i = 1, p
      s(i, :) = s(i, :) * 10.0_wp**(mod(5 * i, 13) - 6)
    end do
    call eq_gramian(env, local_cols(env, s), kernel(f), h, e)
    call check(.not. allocated(e), "eq scaling: gramian")
    if (allocated(e)) return
    do variant = 1, 2
      signed = variant == 1
      call eq_build(h, signed, p, 0.0_wp, eq, e)
      call check(.not. allocated(e), "eq scaling: builds")
      if (allocated(e)) cycle
      call check(eq%m == p, "eq scaling: every candidate selected")
      call check_close(eq_direct(s, f, eq%idx, eq%w(:, p)), 0.0_wp, 1.0e-10_wp, "eq scaling: Pi reproduced")
      call check_eq_history(eq, s, f, merge(1.0e-14_wp, 1.0e-12_wp, signed), "eq scaling")
    end do
  end subroutine test_eq_scaling

  !> m > p, negative tolerance, unknown rule, zero snapshots, non-square H.
  subroutine test_eq_bad_input()
    real(wp), allocatable :: s(:, :), h(:, :), f(:, :)
    type(eq_t) :: eq
    type(error_t), allocatable :: e
    s = randn(5, 8, 71)
    call eq_gramian(env, local_cols(env, s), kernel(randn(2, 5, 72)), h, e)
    call eq_build(h, .true., 6, 0.0_wp, eq, e)
    call check(allocated(e), "eq m > p: error")
    if (allocated(e)) then
      call check(e%code == EXIT_BAD_INPUT, "eq m > p: code 2")
      call check(index(e%message, "m = 6") > 0 .and. index(e%message, "p = 5") > 0, &
        & "eq m > p: message names m and p")
    end if
    call eq_build(h, .true., 3, -1.0_wp, eq, e)
    call check(allocated(e), "eq negative tolerance: error")
    call eq_build(h, .true., 3, 0.0_wp, eq, e, rule="best")
    call check(allocated(e), "eq unknown rule: error")
    call eq_build(h(:, 1:4), .true., 3, 0.0_wp, eq, e)
    call check(allocated(e), "eq non-square Gramian: error")

    s = 0.0_wp
    call eq_gramian(env, local_cols(env, s), kernel(randn(2, 5, 72)), h, e)
    call check(.not. allocated(e), "eq zero snapshots: gramian")
    call eq_build(h, .false., 3, 0.0_wp, eq, e)
    call check(.not. allocated(e), "eq zero snapshots: no error")
    if (.not. allocated(e)) then
      call check(eq%m == 0 .and. size(eq%idx) == 0 .and. size(eq%err) == 0, "eq zero snapshots: m = 0")
      call check(allocated(eq%note), "eq zero snapshots: note")
    end if

    ! Pi = 0 although every candidate contributes: s_2 = 3 s_1, f_2 = -f_1 / 3
    deallocate(s)
    allocate(s(2, 8))
    s(1, :) = reshape(randn(1, 8, 73), [8])
    s(2, :) = 3.0_wp * s(1, :)
    f = reshape([1.0_wp, 0.7_wp, 0.2_wp, 1.0_wp, 0.7_wp, 0.2_wp], [3, 2])
    f(:, 2) = -f(:, 1) / 3.0_wp
    call eq_gramian(env, local_cols(env, s), kernel(f), h, e)
    call check(.not. allocated(e), "eq cancelling target: gramian")
    call eq_build(h, .true., 2, 0.0_wp, eq, e)
    call check(.not. allocated(e), "eq cancelling target: no error")
    if (.not. allocated(e)) call check(eq%m == 0 .and. allocated(eq%note), "eq cancelling target: m = 0, note")
    h = reshape([1.0_wp, -2.0_wp, -2.0_wp, 1.0_wp], [2, 2])
    call eq_build(h, .true., 2, 0.0_wp, eq, e)
    call check(allocated(e), "eq indefinite H with 1^T H 1 < 0: error")

    call eq%free()
    call check(eq%m == 0 .and. .not. allocated(eq%idx), "eq free")
  end subroutine test_eq_bad_input
  !> Near-tied scores go to the lowest index (cr_eq.f90): H = diag(1, 1, 1 + d, 1), c = H 1,
  !> so the first score of candidate i is sqrt(H_ii). d = 2e-12 (rounding-sized, as symmetric
  !> data leaves exact ties) picks candidate 1; d = 2e-6 is a real difference: candidate 3.
  subroutine test_eq_ties()
    real(wp) :: h(4, 4), d
    type(eq_t) :: eq
    type(error_t), allocatable :: e
    integer :: k, variant
    logical :: signed
    do variant = 1, 2
      signed = variant == 1
      do k = 1, 2
        d = merge(2.0e-12_wp, 2.0e-6_wp, k == 1)
        h = 0.0_wp
        h(1, 1) = 1.0_wp; h(2, 2) = 1.0_wp; h(3, 3) = 1.0_wp + d; h(4, 4) = 1.0_wp
        call eq_build(h, signed, 1, 0.0_wp, eq, e)
        call check(.not. allocated(e), "eq ties: builds")
        if (allocated(e)) cycle
        if (k == 1) then
          call check(eq%idx(1) == 1, "eq ties (" // merge("signed      ", "non-negative", signed) // &
            & "): near-tie -> lowest index")
        else
          call check(eq%idx(1) == 3, "eq ties (" // merge("signed      ", "non-negative", signed) // &
            & "): 2e-6 apart -> largest")
        end if
      end do
    end do
  end subroutine test_eq_ties

end program test_hyper
