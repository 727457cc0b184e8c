!> Empirical quadrature (EQ) of a projected non-affine term by non-negative / signed
!> orthogonal matching pursuit on a Gramian.
!>
!> The projected quantity is Pi(sigma) = sum_{i=1..p} s_i(sigma) f_i [q] with constant vectors
!> f_i. EQ keeps m candidates I and weights w: Pi(sigma) ~ sum_{i in I} w_i s_i(sigma) f_i, so
!> online only the m entries s_I(sigma) are evaluated (cost O(m q) per evaluation).
!> With g_i(sigma) = s_i(sigma) f_i, everything the offline stage needs is the Gramian
!>   H = sum_sigma G(sigma)^T G(sigma) = (sum_sigma s s^T) o K,  K_ii' = f_i . f_i'  [p, p]
!> (Hadamard product; `eq_gramian`, collective over the snapshot columns) and c = H 1 (row
!> sums). The training error of weights w~ (scattered to p) is
!>   err(w~)^2 = sum_sigma |Pi - G w~|^2 / sum_sigma |Pi|^2 = (w~ - 1)^T H (w~ - 1) / (1^T H 1).
!>
!> `eq_build` (serial, on a replicated H) is the paper's greedy (Algorithm "EQ offline"):
!> * Scaling: H is used through its unit-diagonal form H^ = D H D, D = diag(H_ii^(-1/2))
!>   (entries formed on the fly, H is never copied); candidates with H_ii <= 0 (always-zero
!>   entries, or f_i = 0) are never selected.
!> * Residual r = c - H(:, I) w. Selection among the admissible candidates i not in I:
!>   rule "residual" (default): the largest r_i / sqrt(H_ii) (signed: in magnitude), the
!>   normalised correlation of candidate i with the training residual, i.e. the classical
!>   (NN)OMP choice; the error decrease from candidate i alone is r_i^2 / H_ii.
!>   rule "paper": the largest (H^ D r)_i (signed: in magnitude), the literal H(:,i)^T r of
!>   the paper in the normalised variables; costs one O(p^2) product per selection.
!>   Non-negative weights only admit a positive score (a descent direction). Ties (scores
!>   within a relative sqrt(eps) of the best) go to the lowest index, so the order does not
!>   depend on the rounding of the CPU's BLAS kernels or the number of ranks.
!> * The selected block H^_II = L L^T is kept as an incrementally grown Cholesky factor. A
!>   candidate whose new pivot L_kk^2 = 1 - |L^{-1} H^_I,i|^2 (the squared sine of the angle
!>   between g_i and span{g_j, j in I}) is <= dep_tol is numerically dependent on the selected
!>   ones: it is refused for good and the next best is taken (duplicate candidates never make
!>   the factor singular; no Inf/NaN).
!> * Weights: signed: H_II w = c_I (two triangular solves), the exact minimiser of err over
!>   the support I. Non-negative: the minimiser of err over {w >= 0 on I}, an NNLS
!>   min |L^T w^ - L^{-1} c^_I|, w^ >= 0 (`nnls_solve`, warm started). This has the same
!>   solution as the paper's min |H_II w - c_I| when no bound is active, and otherwise
!>   minimises the reported error itself, so the error history is non-increasing in both
!>   variants.
!> * err_k^2 = (1^T r - w^T r_I) / (1^T H 1) (equal to the quadratic form above), O(p).
!>   Computed from H alone, it cancels: its absolute floor is about sqrt(eps |1|^T|H||1| /
!>   1^T H 1) (~1e-8 for well-scaled data) even when the true error is smaller, so a useful
!>   tolerance is >= 1e-7. A negative rounding value is reported as 0.
!> * Stops at m_max, when err <= tol (tol > 0), or when no admissible candidate is left; the
!>   last two set `note`.
module cr_eq
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_lapack, only: la_syrk
  use cr_pod, only: snapshot_layout
  use cr_nnls, only: nnls_solve, nnls_work_t, nnls_stats_t
  use cr_sort, only: near_max_index
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: eq_t, eq_gramian, eq_build

  !> Default threshold on the squared sine of the angle between a candidate and the span of
  !> the selected ones below which it counts as dependent.
  real(wp), parameter, public :: EQ_DEP_TOL = 1.0e-10_wp

  !> An empirical quadrature of one projected term (replicated).
  type :: eq_t
    !> number of candidates p and of selected candidates m
    integer :: p = 0, m = 0
    !> .true.: weights of any sign (k = 1, 3); .false.: w >= 0 (k = 2)
    logical :: signed = .true.
    !> selected candidates in selection order [m]
    integer, allocatable :: idx(:)
    !> w(1:k, k) = weights of idx(1:k) after k selections [m, m] (upper triangle used)
    real(wp), allocatable :: w(:, :)
    !> relative training error after k selections [m]
    real(wp), allocatable :: err(:)
    !> why the selection stopped before m_max (unallocated when m = m_max)
    character(len=:), allocatable :: note
  contains
    procedure :: free => eq_free
  end type eq_t

  integer, parameter :: ROOT = 0

contains

  !> Release the storage and reset the sizes.
  subroutine eq_free(this)
    class(eq_t), intent(inout) :: this
    if (allocated(this%idx)) deallocate(this%idx)
    if (allocated(this%w)) deallocate(this%w)
    if (allocated(this%err)) deallocate(this%err)
    if (allocated(this%note)) deallocate(this%note)
    this%p = 0
    this%m = 0
    this%signed = .true.
  end subroutine eq_free

  !> Gramian H = (sum over the snapshots of all ranks of s s^T) o kmat (collective). Each rank
  !> forms its local s s^T (dsyrk, upper triangle), the triangles are summed on rank 0 and
  !> broadcast: H is bitwise identical on every rank and exactly symmetric.
  subroutine eq_gramian(env, s_local, kmat, h, error)
    type(env_t), intent(in) :: env
    !> snapshots of the candidate entries, columns distributed over ranks: [p, n_local]
    real(wp), contiguous, intent(in) :: s_local(:, :)
    !> kernel K_ii' = f_i . f_i', symmetric, upper triangle used, replicated [p, p]
    real(wp), contiguous, intent(in) :: kmat(:, :)
    !> the Gramian, replicated [p, p]
    real(wp), allocatable, intent(out) :: h(:, :)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: packed(:)
    integer :: p, n_snap, offset, i, j, pos, n

    call snapshot_layout(env, s_local, n_snap, offset, error)
    if (allocated(error)) then
      call prefix_error(error, "eq_gramian"); return
    end if
    p = size(s_local, 1)
    if (size(kmat, 1) /= p .or. size(kmat, 2) /= p) then
      call set_error(error, "eq_gramian: the kernel is " // str(size(kmat, 1)) // " x " // &
        & str(size(kmat, 2)) // " but there are p = " // str(p) // " candidates", EXIT_BAD_INPUT)
    end if
    call env%agree_error(error)
    if (allocated(error)) return
    allocate(h(p, p))
    call la_syrk('U', 'N', 1.0_wp, s_local, 0.0_wp, h, error)
    if (allocated(error)) then
      call prefix_error(error, "eq_gramian"); return
    end if
    if (env%size > 1 .and. p > 0) then
      n = p * (p + 1) / 2
      allocate(packed(n))
      pos = 0
      do j = 1, p
        packed(pos + 1:pos + j) = h(1:j, j)
        pos = pos + j
      end do
      call env%reduce_sum_root(packed, error)
      if (.not. allocated(error)) call env%bcast(packed, error, root=ROOT)
      if (allocated(error)) then
        call prefix_error(error, "eq_gramian: summing the " // str(p) // " x " // str(p) // &
          & " Gramian over the ranks")
        return
      end if
      pos = 0
      do j = 1, p
        h(1:j, j) = packed(pos + 1:pos + j)
        pos = pos + j
      end do
    end if
    do j = 1, p
      do i = 1, j
        h(i, j) = h(i, j) * kmat(i, j)
        h(j, i) = h(i, j)
      end do
    end do
  end subroutine eq_gramian

  !> Greedy empirical quadrature on the Gramian h [p, p] (serial; see the module header).
  !> Errors (code 2): m_max < 0 or m_max > p, tol < 0, h not square or not finite, an unknown
  !> rule, 1^T H 1 < 0 (not a Gramian). A zero target (1^T H 1 = 0 up to rounding, p eps
!> sum |H_ij|) gives m = 0 and a note. Steps: the arguments (eq_check), the target and the
  !> admissible candidates (eq_target), then per selection the candidate (eq_pick), the
  !> weights (eq_weights), the residual and the error.
  subroutine eq_build(h, signed, m_max, tol, eq, error, rule, dep_tol)
    !> Gramian (symmetric positive semi-definite), replicated [p, p]
    real(wp), contiguous, intent(in) :: h(:, :)
    !> .true.: weights of any sign; .false.: non-negative weights
    logical, intent(in) :: signed
    !> maximum number of candidates to select, 0 <= m_max <= p
    integer, intent(in) :: m_max
    !> stop as soon as err <= tol (tol = 0: never stop early)
    real(wp), intent(in) :: tol
    type(eq_t), intent(out) :: eq
    type(error_t), allocatable, intent(out) :: error
    !> selection rule: "residual" (default) or "paper"
    character(len=*), intent(in), optional :: rule
    !> dependence threshold on the squared sine (default EQ_DEP_TOL)
    real(wp), intent(in), optional :: dep_tol
    real(wp), allocatable :: c(:), dinv(:), r(:), rs(:), lf(:, :), y(:), wh(:), col(:)
    real(wp), allocatable :: score(:)
    logical, allocatable :: usable(:), passive(:)
    integer, allocatable :: idx(:)
    real(wp), allocatable :: wall(:, :), errk(:)
    real(wp) :: total, dtol, dpiv, e2
    character(len=:), allocatable :: rl
    integer :: p, k, j, ibest, n_refused, n_zero
    type(nnls_work_t) :: nwork

    p = size(h, 1)
    eq%p = p
    eq%signed = signed
    eq%m = 0
    rl = "residual"
    if (present(rule)) rl = rule
    dtol = EQ_DEP_TOL
    if (present(dep_tol)) dtol = dep_tol
    call eq_check(h, m_max, tol, dtol, rl, error)
    if (allocated(error)) return
    call eq_target(h, c, dinv, usable, n_zero, total)
    allocate(eq%idx(0), eq%w(0, 0), eq%err(0))
    if (total < 0.0_wp) then
      call set_error(error, "eq_build: 1^T H 1 = " // str(total) // " < 0: H is not a Gramian " // &
        & "(not positive semi-definite)", EXIT_BAD_INPUT)
      return
    end if
    if (m_max == 0) return
    if (total == 0.0_wp) then
      eq%note = "the projected quantity is zero on every training snapshot (1^T H 1 = 0): m = 0"
      return
    end if

    allocate(idx(m_max), wall(m_max, m_max), errk(m_max), lf(m_max, m_max), y(m_max), wh(m_max))
    allocate(r(p), rs(p), col(m_max), score(p), passive(m_max))
    wall = 0.0_wp
    lf = 0.0_wp
    r = c
    n_refused = 0
    k = 0
    select_loop: do while (k < m_max)
      ! scores of the admissible candidates (r and the score are in normalised variables)
      rs = dinv * r
      if (rl == "paper") then
        score = dinv * matmul(h, dinv * rs)
      else
        score = rs
      end if
      call eq_pick(h, signed, score, dinv, idx, lf, k, dtol, usable, col, dpiv, n_refused, ibest)
      if (ibest == 0) exit select_loop
      k = k + 1
      idx(k) = ibest
      lf(k, 1:k - 1) = col(1:k - 1)
      lf(k, k) = sqrt(dpiv)
      ! y = L^{-1} c^_I (one new entry)
      y(k) = (c(ibest) * dinv(ibest) - dot_product(lf(k, 1:k - 1), y(1:k - 1))) / lf(k, k)
      call eq_weights(signed, lf, y, k, wh, passive, nwork, error)
      if (allocated(error)) return
      do j = 1, k
        wall(j, k) = wh(j) * dinv(idx(j))
      end do

      ! residual and error
      r = c
      do j = 1, k
        if (wall(j, k) /= 0.0_wp) r = r - wall(j, k) * h(:, idx(j))
      end do
      e2 = sum(r)
      do j = 1, k
        e2 = e2 - wall(j, k) * r(idx(j))
      end do
      errk(k) = sqrt(max(0.0_wp, e2 / total))
      if (tol > 0.0_wp .and. errk(k) <= tol .and. k < m_max) then
        eq%note = "stopped at m = " // str(k) // " < " // str(m_max) // ": error " // str(errk(k)) // &
          & " <= tolerance " // str(tol)
        exit select_loop
      end if
    end do select_loop

    if (k < m_max .and. .not. allocated(eq%note)) then
      eq%note = "stopped at m = " // str(k) // " < " // str(m_max) // ": no admissible candidate left (" // &
        & str(n_refused) // " refused as numerically dependent on the selected ones, " // &
        & str(n_zero) // " with a zero diagonal, " // str(count(usable)) // " with a score "
      if (signed) then
        eq%note = eq%note // "of 0)"
      else
        eq%note = eq%note // "<= 0, i.e. no descent direction for w >= 0)"
      end if
    end if
    eq%m = k
    eq%idx = idx(1:k)
    eq%w = wall(1:k, 1:k)
    eq%err = errk(1:k)
  end subroutine eq_build

  !> The arguments of eq_build checked (code 2 on failure).
  subroutine eq_check(h, m_max, tol, dtol, rl, error)
    real(wp), intent(in) :: h(:, :)
    integer, intent(in) :: m_max
    real(wp), intent(in) :: tol, dtol
    character(len=*), intent(in) :: rl
    type(error_t), allocatable, intent(out) :: error
    integer :: p
    p = size(h, 1)
    if (size(h, 2) /= p) then
      call set_error(error, "eq_build: the Gramian is " // str(p) // " x " // str(size(h, 2)) // &
        & ", expected a square matrix", EXIT_BAD_INPUT)
      return
    end if
    if (m_max < 0 .or. m_max > p) then
      call set_error(error, "eq_build: m = " // str(m_max) // " candidates requested but there are p = " // &
        & str(p) // " candidates (need 0 <= m <= p)", EXIT_BAD_INPUT)
      return
    end if
    if (.not. (tol >= 0.0_wp)) then
      call set_error(error, "eq_build: tolerance " // str(tol) // " is negative", EXIT_BAD_INPUT)
      return
    end if
    if (.not. (dtol > 0.0_wp .and. dtol < 1.0_wp)) then
      call set_error(error, "eq_build: dependence threshold " // str(dtol) // " is not in (0, 1)", EXIT_BAD_INPUT)
      return
    end if
    if (rl /= "residual" .and. rl /= "paper") then
      call set_error(error, "eq_build: unknown selection rule '" // rl // "' (known: residual, paper)", EXIT_BAD_INPUT)
      return
    end if
    if (.not. all(abs(h) <= huge(1.0_wp))) then
      call set_error(error, "eq_build: the Gramian has non-finite entries (p = " // str(p) // ")", EXIT_BAD_INPUT)
      return
    end if
  end subroutine eq_check

  !> The target c = H 1 and total = 1^T H 1 (0 at the rounding level of the sum: a zero
  !> target), the scaling dinv = 1 / sqrt(H_ii) and the admissible candidates (H_ii > 0; n_zero
  !> are not).
  subroutine eq_target(h, c, dinv, usable, n_zero, total)
    real(wp), intent(in) :: h(:, :)
    real(wp), allocatable, intent(out) :: c(:), dinv(:)
    logical, allocatable, intent(out) :: usable(:)
    integer, intent(out) :: n_zero
    real(wp), intent(out) :: total
    integer :: i, j, p
    p = size(h, 1)
    allocate(c(p), dinv(p), usable(p))
    c = 0.0_wp
    do j = 1, p
      c = c + h(:, j)
    end do
    total = sum(c)
    n_zero = 0
    do i = 1, p
      usable(i) = h(i, i) > 0.0_wp
      if (usable(i)) then
        dinv(i) = 1.0_wp / sqrt(h(i, i))
      else
        dinv(i) = 0.0_wp
        n_zero = n_zero + 1
      end if
    end do
    ! 1^T H 1 = sum_sigma |Pi|^2 at the rounding level of the sum is a zero target
    if (abs(total) <= real(p, wp) * epsilon(1.0_wp) * sum(abs(h))) total = 0.0_wp
  end subroutine eq_target

  !> The best admissible candidate ibest (0: none) that is independent of the k selected ones
  !> idx(1:k) (Cholesky factor lf): its new Cholesky row col(1:k) and squared pivot dpiv;
  !> candidates found dependent are refused (n_refused) and every one tried leaves usable.
  !> Ties: scores within a relative sqrt(eps) of the best count as equal and the lowest index
  !> wins. Symmetric data has candidates whose scores are equal in exact arithmetic; they come
  !> out a few eps apart in an order set by the BLAS kernels (CPU) and the number of ranks, and
  !> a strict "largest" then took them in another order on another machine (rom_tiny s2:
  !> 9 candidates, the same error history, the order different at 1 and 2 ranks and under
  !> each kernel). sqrt(eps) is far above that rounding and far below real differences.
  subroutine eq_pick(h, signed, score, dinv, idx, lf, k, dtol, usable, col, dpiv, n_refused, ibest)
    real(wp), intent(in) :: h(:, :), score(:), dinv(:), lf(:, :), dtol
    logical, intent(in) :: signed
    integer, intent(in) :: idx(:), k
    logical, intent(inout) :: usable(:)
    real(wp), intent(inout) :: col(:)
    real(wp), intent(out) :: dpiv
    integer, intent(inout) :: n_refused
    integer, intent(out) :: ibest
    integer :: j, p
    p = size(h, 1)
    dpiv = 0
    do
      if (signed) then
        ibest = near_max_index(abs(score(1:p)), mask=usable(1:p))
      else
        ibest = near_max_index(score(1:p), mask=usable(1:p))
      end if
      ! only a positive score is a descent direction
      if (ibest > 0) then
        if (.not. merge(abs(score(ibest)), score(ibest), signed) > 0.0_wp) ibest = 0
      end if
      if (ibest == 0) return
      ! new Cholesky row: L(1:k,1:k) col = H^(I, ibest), pivot^2 = H^_ii - |col|^2
      do j = 1, k
        col(j) = (h(idx(j), ibest) * dinv(idx(j)) * dinv(ibest) - &
          & dot_product(lf(j, 1:j - 1), col(1:j - 1))) / lf(j, j)
      end do
      dpiv = h(ibest, ibest) * dinv(ibest)**2 - dot_product(col(1:k), col(1:k))
      usable(ibest) = .false.
      if (dpiv > dtol) return
      n_refused = n_refused + 1
    end do
  end subroutine eq_pick

  !> The normalised weights wh(1:k) of the k selected candidates: signed, L^T w^ = y; else
  !> min |L^T w^ - y|, w^ >= 0, warm started from the previous positive set.
  subroutine eq_weights(signed, lf, y, k, wh, passive, nwork, error)
    logical, intent(in) :: signed
    real(wp), intent(in) :: lf(:, :), y(:)
    integer, intent(in) :: k
    real(wp), intent(inout) :: wh(:)
    logical, intent(inout) :: passive(:)
    type(nnls_work_t), intent(inout) :: nwork
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: a(:, :), wk(:)
    type(nnls_stats_t) :: nstats
    integer :: j
    if (signed) then
      do j = k, 1, -1
        wh(j) = (y(j) - dot_product(lf(j + 1:k, j), wh(j + 1:k))) / lf(j, j)
      end do
      return
    end if
    a = transpose(lf(1:k, 1:k))
    passive(1:k - 1) = wh(1:k - 1) > 0.0_wp
    passive(k) = .true.
    allocate(wk(k))
    call nnls_solve(a, y(1:k), wk, nstats, error, passive0=passive(1:k), &
      & max_iter=10 * k + 100, work=nwork)
    if (allocated(error)) then
      call prefix_error(error, "eq_build: weights after " // str(k) // " selections"); return
    end if
    if (.not. nstats%converged) then
      call set_error(error, "eq_build: the non-negative least-squares solve for the weights " // &
        & "did not converge after " // str(k) // " selections (" // str(nstats%iterations) // &
        & " iterations)")
      return
    end if
    wh(1:k) = wk
  end subroutine eq_weights
end module cr_eq
