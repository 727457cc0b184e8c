!> Dense non-negative least squares (Lawson-Hanson active set) and least-distance programming.
!>
!> nnls_solve:  min |A x - b|_2  s.t.  x >= 0,  A: [m, n], b: [m], x: [n].
!> ldp_solve:   min |u - v|_2^2  s.t.  Bm u <= d, Bm: [mc, n], by the LDP -> NNLS reduction.
!>
!> Numerics (nnls_solve):
!> - The problem is scaled internally: every column of A by a power of two so that its 2-norm is
!>   in [1/2, 1), b by a power of two likewise. Power-of-two scaling is exact, so the iteration
!>   works on the same numbers whatever the units of A and b (up to the rounding of the user's
!>   own rescaling), and the stopping tolerance is relative.
!> - The passive columns A_P = Q R are kept factored with an explicit orthogonal Q [m, m]:
!>   a column that enters is appended with one Householder reflection (O(m (m - k)) flops),
!>   a column that leaves is removed with Givens rotations on R, Q and Q^T b (O(m (k - p))).
!>   There is no refactorisation per iteration.
!> - A column is refused (left at zero) when it is numerically dependent on the passive ones
!>   (new diagonal of R below 16 m eps of its norm) or when, once added, its least-squares
!>   coefficient is not positive (the round-off trap that makes textbook Lawson-Hanson cycle).
!>   Refusals are cleared whenever the passive set changes, so they never hide a real descent
!>   direction for long; the iteration count is capped in any case.
!> - Optimality test (Lawson-Hanson's, in the orthogonal complement of the factorisation): the
!>   residual of the passive least-squares solution is formed as r = Q(:, k+1:m) (Q^T b)(k+1:m)
!>   and w_j = a_j^T r for the inactive columns. Its rounding is about m eps |a_j| |r|, relative
!>   to the current residual (a_j^T (b - A_P x_P) would carry eps |a_j| |b| whatever the true
!>   gradient, and hide the 1e-20..1e-15 gradients of nearly dependent columns of
!>   ill-conditioned problems). A column may enter when w_j > 16 m eps |r| (scaled units, columns
!>   of norm < 1): the cosine between a_j and r exceeds the dependence threshold below, so a
!>   column that passes it is never refused as dependent. At convergence every inactive column
!>   has a_j^T r <= 16 m eps |a_j| |r|, hence (convexity) |r| <= |r*| + 32 m eps sum_j |a_j| x*_j
!>   for any optimal x*, plus the backward error of the factorisation (a few m eps |b|): the
!>   optimal objective to rounding, whatever the conditioning and also when x is not unique.
!> - Columns are held in compressed sparse form (only non-zeros), which costs nothing for dense
!>   data and makes the contact matrices (5 non-zeros per column) cheap.
!> - The returned x is always >= 0 and the statistics (residual, KKT measures, n_passive) are
!>   those of the returned x, also when the iteration cap stops the solve.
!>
!> ldp_solve: the projection u is unique; lambda is not when constraint rows are dependent
!> (any valid multipliers are returned). An infeasible system is detected by a Farkas
!> certificate and answered with the least-squares least-violation point closest to v (two
!> NNLS, no regularisation bias; see ldp_solve). Both routines reject NaN / Inf input (error
!> code 2) and every loop is bounded by the iteration cap.
module cr_nnls
  use cr_kinds, only: wp
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: nnls_work_t, nnls_stats_t, ldp_stats_t, nnls_solve, ldp_solve, lh_step_back

  !> Outcome of one NNLS solve.
  type :: nnls_stats_t
    !> outer (column additions) plus inner (step-back) iterations
    integer :: iterations = 0
    !> .true. when the KKT test was met before the iteration cap
    logical :: converged = .false.
    !> residual norm |A x - b|_2 (original units)
    real(wp) :: residual = 0.0_wp
    !> max(0, w_j) over the active (x_j = 0) set, w = A^T (b - A x) (original units)
    real(wp) :: w_active_max = 0.0_wp
    !> max |w_j| over the passive (x_j > 0) set (original units)
    real(wp) :: w_passive_max = 0.0_wp
    !> dimensionless certificate: max_j violation_j / (|a_j| |b|), violation as above
    real(wp) :: kkt_rel = 0.0_wp
    !> number of passive (positive) entries of x
    integer :: n_passive = 0
  end type nnls_stats_t

  !> Outcome of one LDP solve.
  type :: ldp_stats_t
    !> statistics of the underlying NNLS
    type(nnls_stats_t) :: nnls
    !> .true. when {u : Bm u <= d} was found empty; u is then the least-violation point
    logical :: infeasible = .false.
    !> max_l (Bm u - d)_l^+ of the returned u (original units)
    real(wp) :: max_violation = 0.0_wp
  end type ldp_stats_t

  !> Reusable work space (grown on demand, never shrunk). One per thread of solves.
  type :: nnls_work_t
    integer :: mcap = -1, ncap = -1, nzcap = -1
    !> compressed columns of the scaled A: col(j) .. col(j+1)-1 index row/val
    integer, allocatable :: col(:), row(:)
    real(wp), allocatable :: val(:)
    !> column scales (powers of two) [n]
    real(wp), allocatable :: cs(:)
    !> orthogonal factor [m, m], triangular factor [m, min(m, n)]
    real(wp), allocatable :: q(:,:), r(:,:)
    !> Q^T b, work vectors [m]
    real(wp), allocatable :: qtb(:), z(:), hv(:), res(:), bs(:)
    !> current scaled iterate, trial solution, gradient [n]
    real(wp), allocatable :: x(:), zp(:), w(:)
    !> passive list (order of the columns of R) and position map [n]
    integer, allocatable :: plist(:), pos(:)
    logical, allocatable :: refused(:)
    !> LDP buffers: the (n+1) x mc NNLS matrix, rhs, solution
    real(wp), allocatable :: e(:,:), f(:), y(:)
    logical, allocatable :: p0(:)
  end type nnls_work_t

contains

  !> Make sure `work` can hold an m x n problem with at most nnz non-zeros.
  subroutine reserve(work, m, n, nnz)
    type(nnls_work_t), intent(inout) :: work
    integer, intent(in) :: m, n, nnz
    if (m > work%mcap) then
      if (allocated(work%q)) deallocate(work%q, work%qtb, work%z, work%hv, work%res, work%bs)
      allocate(work%q(m, m), work%qtb(m), work%z(m), work%hv(m), work%res(m), work%bs(m))
    end if
    if (m > work%mcap .or. n > work%ncap) then
      if (allocated(work%r)) deallocate(work%r)
      allocate(work%r(max(m, work%mcap, 1), max(1, min(max(m, work%mcap), max(n, work%ncap)))))
    end if
    if (n > work%ncap) then
      if (allocated(work%col)) deallocate(work%col, work%cs, work%x, work%zp, work%w, &
        work%plist, work%pos, work%refused)
      allocate(work%col(n + 1), work%cs(n), work%x(n), work%zp(n), work%w(n), work%plist(n), &
        work%pos(n), work%refused(n))
    end if
    work%mcap = max(work%mcap, m)
    work%ncap = max(work%ncap, n)
    if (nnz > work%nzcap) then
      if (allocated(work%row)) deallocate(work%row, work%val)
      allocate(work%row(max(nnz, 1)), work%val(max(nnz, 1)))
      work%nzcap = nnz
    end if
  end subroutine reserve

  !> Solve min |A x - b|_2 s.t. x >= 0 (Lawson-Hanson active set with incremental QR).
  !>
  !> On entry `passive0` (optional) marks a guess of the passive set (warm start); the result
  !> does not depend on it, only the iteration count does. `max_iter` caps the iterations
  !> (default 3 n + 50); when reached, stats%converged = .false. and x is the last feasible
  !> iterate (x >= 0 always) and the statistics are those of that x. Errors (code 2) for
  !> inconsistent sizes and for a NaN or Inf in A or b (checked in one pass, before any use).
  subroutine nnls_solve(a, b, x, stats, error, passive0, max_iter, work)
    !> matrix [m, n]
    real(wp), intent(in) :: a(:,:)
    !> right-hand side [m]
    real(wp), intent(in) :: b(:)
    !> solution [n], x >= 0
    real(wp), intent(out) :: x(:)
    type(nnls_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    !> warm-start guess of the passive set [n]
    logical, intent(in), optional :: passive0(:)
    integer, intent(in), optional :: max_iter
    !> reusable work space
    type(nnls_work_t), intent(inout), optional, target :: work
    type(nnls_work_t), target :: local
    type(nnls_work_t), pointer :: wk
    integer :: m, n, j, i, nnz, itmax
    real(wp) :: cmax, bnorm, sb

    m = size(a, 1); n = size(a, 2)
    if (size(b) /= m .or. size(x) /= n) then
      call set_error(error, "nnls_solve: inconsistent sizes: A is " // str(m) // " x " // str(n) &
        // ", b has " // str(size(b)) // ", x has " // str(size(x)), EXIT_BAD_INPUT)
      return
    end if
    if (present(passive0)) then
      if (size(passive0) /= n) then
        call set_error(error, "nnls_solve: passive0 has " // str(size(passive0)) // &
          " entries, expected " // str(n), EXIT_BAD_INPUT)
        return
      end if
    end if
    itmax = 3 * n + 50
    if (present(max_iter)) itmax = max_iter
    if (present(work)) then
      wk => work
    else
      wk => local
    end if

    nnz = 0
    do j = 1, n
      do i = 1, m
        if (.not. ieee_is_finite(a(i, j))) then
          call set_error(error, "nnls_solve: A(" // str(i) // ", " // str(j) // ") is not finite", EXIT_BAD_INPUT)
          return
        end if
        if (a(i, j) /= 0.0_wp) nnz = nnz + 1
      end do
    end do
    do i = 1, m
      if (.not. ieee_is_finite(b(i))) then
        call set_error(error, "nnls_solve: b(" // str(i) // ") is not finite", EXIT_BAD_INPUT)
        return
      end if
    end do
    call reserve(wk, m, n, nnz)
    ! scale b and the columns of A by powers of two (exact)
    bnorm = safe_norm2(b)
    sb = 1.0_wp
    if (bnorm > 0.0_wp) sb = scale(1.0_wp, exponent(bnorm))
    wk%bs(1:m) = b / sb
    nnz = 0
    do j = 1, n
      wk%col(j) = nnz + 1
      cmax = safe_norm2(a(:, j))
      if (cmax > 0.0_wp) then
        wk%cs(j) = scale(1.0_wp, -exponent(cmax))
      else
        wk%cs(j) = 0.0_wp
      end if
      do i = 1, m
        if (a(i, j) /= 0.0_wp) then
          nnz = nnz + 1
          wk%row(nnz) = i
          wk%val(nnz) = a(i, j) * wk%cs(j)
        end if
      end do
    end do
    wk%col(n + 1) = nnz + 1

    call nnls_core(wk, m, n, itmax, stats, passive0)

    ! unscale: x = sb * cs * x'
    do j = 1, n
      x(j) = wk%x(j) * wk%cs(j) * sb
    end do
    stats%residual = stats%residual * sb
    stats%w_active_max = 0.0_wp
    stats%w_passive_max = 0.0_wp
    do j = 1, n
      if (wk%cs(j) == 0.0_wp) cycle
      if (wk%pos(j) > 0) then
        stats%w_passive_max = max(stats%w_passive_max, abs(wk%w(j)) * sb / wk%cs(j))
      else
        stats%w_active_max = max(stats%w_active_max, wk%w(j) * sb / wk%cs(j))
      end if
    end do
  end subroutine nnls_solve

  !> Lawson-Hanson on the scaled compressed data held in wk (columns of norm in [1/2, 1)).
  subroutine nnls_core(wk, m, n, itmax, stats, passive0)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, n, itmax
    type(nnls_stats_t), intent(inout) :: stats
    logical, intent(in), optional :: passive0(:)
    integer :: k, j, p, it
    real(wp) :: bn

    k = 0
    wk%x(1:n) = 0.0_wp
    wk%pos(1:n) = 0
    wk%refused(1:n) = .false.
    if (m > 0) then
      wk%q(1:m, 1:m) = 0.0_wp
      do j = 1, m
        wk%q(j, j) = 1.0_wp
      end do
      wk%qtb(1:m) = wk%bs(1:m)
    end if
    bn = 0.0_wp
    if (m > 0) bn = norm2(wk%bs(1:m))
    stats%iterations = 0
    stats%converged = .true.
    if (m == 0 .or. n == 0 .or. bn == 0.0_wp) then
      if (m > 0) wk%res(1:m) = wk%bs(1:m)
      call nnls_finish(wk, m, n, k, bn, stats)
      return
    end if
    if (present(passive0)) call nnls_warm_start(wk, m, n, k, passive0)
    call nnls_iterate(wk, m, n, itmax, k, it, stats%converged)
    ! after a cap inside the step-back loop the entering column may still sit at x = 0:
    ! drop such columns so that the passive set is exactly {x > 0}
    do p = k, 1, -1
      if (wk%x(wk%plist(p)) <= 0.0_wp) then
        wk%x(wk%plist(p)) = 0.0_wp
        call remove_column_impl(wk, m, p, k)
      end if
    end do
    stats%iterations = it
    call nnls_gradient(wk, m, n, k)
    call nnls_finish(wk, m, n, k, bn, stats)
  end subroutine nnls_core

  !> Warm start of nnls_core: factor the guessed passive set passive0 [n], then drop
  !> non-positive coefficients; x holds the least-squares solution on the k passive columns.
  subroutine nnls_warm_start(wk, m, n, k, passive0)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, n
    integer, intent(inout) :: k
    logical, intent(in) :: passive0(:)
    integer :: j, p
    logical :: ok, changed
    do j = 1, n
      if (passive0(j) .and. wk%cs(j) /= 0.0_wp .and. k < m) call add_column_impl(wk, m, j, k, ok)
    end do
    do
      if (k == 0) exit
      call nnls_solve_r(wk, k)
      changed = .false.
      do p = k, 1, -1
        if (wk%zp(p) <= 0.0_wp) then
          call remove_column_impl(wk, m, p, k)
          changed = .true.
        end if
      end do
      if (.not. changed) exit
    end do
    do p = 1, k
      wk%x(wk%plist(p)) = wk%zp(p)
    end do
  end subroutine nnls_warm_start

  !> Main loop of nnls_core (Lawson-Hanson): add the column of largest gradient, step back
  !> until the least-squares solution on P is positive; it counts the iterations (cap itmax),
  !> converged is set when no column may enter.
  subroutine nnls_iterate(wk, m, n, itmax, k, it, converged)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, n, itmax
    integer, intent(inout) :: k
    integer, intent(out) :: it
    logical, intent(out) :: converged
    integer :: j, t, p
    real(wp) :: wmax, eps, rnorm
    logical :: ok, capped
    eps = epsilon(1.0_wp)
    it = 0
    converged = .false.
    outer: do
      ! optimality test in the orthogonal complement of the factorisation (see nnls_solve)
      call nnls_complement_gradient(wk, m, n, k, rnorm)
      wmax = 16.0_wp * real(m, wp) * eps * rnorm
      t = 0
      do j = 1, n
        if (wk%pos(j) /= 0 .or. wk%refused(j) .or. wk%cs(j) == 0.0_wp) cycle
        if (wk%w(j) > wmax) then
          wmax = wk%w(j); t = j
        end if
      end do
      if (t == 0 .or. k == m) then
        converged = .true.
        exit outer
      end if
      if (it >= itmax) exit outer
      it = it + 1
      call add_column_impl(wk, m, t, k, ok)
      if (.not. ok) then
        wk%refused(t) = .true.
        cycle outer
      end if
      ! inner loop: step back until the least-squares solution on P is positive
      call nnls_solve_r(wk, k)
      if (wk%zp(k) <= 0.0_wp) then
        ! round-off: the entering column does not help; refuse it
        call remove_column_impl(wk, m, k, k)
        wk%refused(t) = .true.
        cycle outer
      end if
      call nnls_step_back(wk, m, itmax, k, it, capped)
      if (capped) exit outer
      do p = 1, k
        wk%x(wk%plist(p)) = wk%zp(p)
      end do
      wk%refused(1:n) = .false.
    end do outer
  end subroutine nnls_iterate

  !> Inner loop of nnls_iterate: move x towards zp until the least-squares solution on P is
  !> positive (columns reaching zero leave P); capped when the cap itmax stops it.
  subroutine nnls_step_back(wk, m, itmax, k, it, capped)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, itmax
    integer, intent(inout) :: k, it
    logical, intent(out) :: capped
    integer :: j, p
    capped = .false.
    do
      if (all(wk%zp(1:k) > 0.0_wp)) exit
      if (it >= itmax) then
        capped = .true.
        return
      end if
      it = it + 1
      call lh_step_back(wk%x, wk%zp(1:k), wk%plist(1:k))
      do p = k, 1, -1
        j = wk%plist(p)
        if (wk%x(j) <= 0.0_wp) then
          wk%x(j) = 0.0_wp
          call remove_column_impl(wk, m, p, k)
        end if
      end do
      if (k == 0) exit
      call nnls_solve_r(wk, k)
    end do
  end subroutine nnls_step_back

  !> back substitution R(1:kk, 1:kk) zp = (Q^T b)(1:kk)
  subroutine nnls_solve_r(wk, kk)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: kk
    integer :: ii
    do ii = kk, 1, -1
      wk%zp(ii) = (wk%qtb(ii) - dot_product(wk%r(ii, ii + 1:kk), wk%zp(ii + 1:kk))) / wk%r(ii, ii)
    end do
  end subroutine nnls_solve_r

  !> The residual of the least-squares solution on the passive set as the factorisation
  !> represents it, res = Q(:, kk+1:m) (Q^T b)(kk+1:m), its norm rn = |(Q^T b)(kk+1:m)|, and
  !> w_j = a_j^T res for the columns not in the passive set (scaled units). Unlike
  !> a_j^T (b - A_P x_P), whose rounding is about eps |a_j| |b| whatever the true gradient,
  !> this is accurate to about m eps |a_j| |res|: a column nearly in the span of A_P has
  !> Q(:, kk+1:m)^T a_j small and a correspondingly small, correctly signed w_j.
  !> O(m (m - kk) + nnz). Valid when x(plist(1:kk)) is that least-squares solution.
  subroutine nnls_complement_gradient(wk, m, n, kk, rn)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, n, kk
    real(wp), intent(out) :: rn
    integer :: cc, jj, ii
    real(wp) :: s
    wk%res(1:m) = 0.0_wp
    do cc = kk + 1, m
      if (wk%qtb(cc) /= 0.0_wp) wk%res(1:m) = wk%res(1:m) + wk%qtb(cc) * wk%q(1:m, cc)
    end do
    rn = 0.0_wp
    if (kk < m) rn = norm2(wk%qtb(kk + 1:m))
    do jj = 1, n
      if (wk%pos(jj) /= 0) cycle
      s = 0.0_wp
      do ii = wk%col(jj), wk%col(jj + 1) - 1
        s = s + wk%val(ii) * wk%res(wk%row(ii))
      end do
      wk%w(jj) = s
    end do
  end subroutine nnls_complement_gradient

  !> res = b - A_P x_P (scaled), w = A^T res (scaled): the statistics of the returned x
  subroutine nnls_gradient(wk, m, n, kk)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, n, kk
    integer :: pp, jj, ii
    real(wp) :: s
    wk%res(1:m) = wk%bs(1:m)
    do pp = 1, kk
      jj = wk%plist(pp)
      s = wk%x(jj)
      do ii = wk%col(jj), wk%col(jj + 1) - 1
        wk%res(wk%row(ii)) = wk%res(wk%row(ii)) - s * wk%val(ii)
      end do
    end do
    do jj = 1, n
      s = 0.0_wp
      do ii = wk%col(jj), wk%col(jj + 1) - 1
        s = s + wk%val(ii) * wk%res(wk%row(ii))
      end do
      wk%w(jj) = s
    end do
  end subroutine nnls_gradient

  !> Statistics of nnls_core: passive columns k, residual norm, relative KKT violation (|b| = bn).
  subroutine nnls_finish(wk, m, n, k, bn, stats)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, n, k
    real(wp), intent(in) :: bn
    type(nnls_stats_t), intent(inout) :: stats
    integer :: jj
    real(wp) :: viol
    stats%n_passive = k
    stats%residual = 0.0_wp
    if (m > 0) stats%residual = norm2(wk%res(1:m))
    if (m == 0 .or. n == 0 .or. bn == 0.0_wp) wk%w(1:n) = 0.0_wp
    stats%kkt_rel = 0.0_wp
    if (bn == 0.0_wp) return
    do jj = 1, n
      if (wk%cs(jj) == 0.0_wp) cycle
      if (wk%pos(jj) > 0) then
        viol = abs(wk%w(jj))
      else
        viol = max(wk%w(jj), 0.0_wp)
      end if
      stats%kkt_rel = max(stats%kkt_rel, viol / (bn * norm2(wk%val(wk%col(jj):wk%col(jj + 1) - 1))))
    end do
  end subroutine nnls_finish

  !> Least-distance programming: min |u - v|_2^2  s.t.  Bm u <= d.
  !>
  !> Derivation (Lawson & Hanson, ch. 23). Put x = u - v and e = d - Bm v, so the problem is
  !> min |x| s.t. G x >= h with G = -Bm, h = -e. The rows are balanced first: x = s x' with
  !> s = 2^(exponent(max|e|) - exponent(max|Bm|)) (exact), i.e. G x' >= h / s.
  !> Solve the NNLS  min |E y - f|, y >= 0, with E = [G^T; (h/s)^T] ((n+1) x mc), f = e_{n+1},
  !> and let r = E y - f. Its optimality conditions are y >= 0, w = -E^T r <= 0, y^T w = 0.
  !> From y^T w = 0: (E y)^T r = 0, i.e. (r + f)^T r = 0, so r_{n+1} = -|r|^2 =: -den.
  !> * den = 0 (r = 0): G^T y = 0 and (h/s)^T y = 1 with y >= 0, a Farkas certificate that
  !>   {G x >= h} is empty: the LDP is infeasible.
  !> * den > 0: put x' = r(1:n) / den = G^T y / den. Then w <= 0 divided by den gives
  !>   G x' - h/s >= 0 (primal feasibility); y_j w_j = 0 gives complementarity; and with
  !>   mu = y / den, x' = G^T mu = -Bm^T mu. Back in the original units, x = s x' = -Bm^T (s mu),
  !>   so the multipliers of  u = v - Bm^T lambda  (the KKT system of min 1/2|u-v|^2 + lambda^T
  !>   (Bm u - d), the convention of the contact model) are  lambda = s y / den.
  !> u is formed as v - Bm^T lambda, so stationarity holds to rounding.
  !> Accuracy: den = 1 / (1 + |x'|^2), and x' carries a relative error ~ eps / den, so when
  !> den < 1/4 the balance s is multiplied by |x'| and the NNLS solved again (warm started);
  !> the LDP is declared infeasible only if den is still at rounding level after that: below
  !> the rounding of its own sum, or below (64 (n + 1) eps sum_j |E_j| y_j)^2, the square of the
  !> residual nnls_solve guarantees on a consistent problem (E y = f solvable: the Farkas case).
  !>
  !> Infeasible systems. The violation sigma = (Bm u - d)^+ is minimised in the least-squares
  !> sense, and among the minimisers the point closest to v is returned:
  !> 1. sigma* = argmin |sigma|_2 over {sigma >= Bm u - d, u free}: an NNLS in (u+, u-, t) >= 0,
  !>    min |[Bm, -Bm, I] (u+, u-, t) - d|, whose residual is unique and equals -sigma*
  !>    (sigma* is then the smallest possible sum of squared violations, and also the vector
  !>    of violations of every least-squares least-violation point);
  !> 2. u = projection of v on {Bm u <= d + sigma* + delta}, an LDP as above, with a margin
  !>    delta_l = 64 eps sqrt(mc) (|d_l| + sigma*_l + |Bm_l|_1 |u*|_inf) at rounding level (u* the
  !>    point of stage 1) so that rounding never makes this set empty.
  !> Then stats%infeasible = .true. (unless sigma* is itself at the rounding level of delta, in
  !> which case the system is feasible to rounding and reported as such), lambda holds the
  !> multipliers of stage 2 (u = v - Bm^T lambda, lambda >= 0, lambda_l > 0 only on rows with
  !> (Bm u - d)_l = sigma*_l + delta_l), and stats%max_violation = max_l (Bm u - d)_l^+.
  !> Should stage 2 fail numerically, u is the point of stage 1 (still least violation, not the
  !> closest to v) and lambda = 0.
  !>
  !> Errors (code 2): inconsistent sizes, a NaN or Inf in Bm, d, v (or in lambda when the
  !> warm start is on). Every NNLS is capped (max_iter each; stats%nnls%iterations sums them).
  subroutine ldp_solve(bm, d, v, u, lambda, stats, error, warm, max_iter, work, gram)
    !> constraint matrix [mc, n]
    real(wp), intent(in) :: bm(:,:)
    !> right-hand side [mc]
    real(wp), intent(in) :: d(:)
    !> point to project [n]
    real(wp), intent(in) :: v(:)
    !> projection [n]
    real(wp), intent(out) :: u(:)
    !> multipliers [mc]; on entry a warm-start guess (lambda > 0 marks the guessed active set)
    real(wp), intent(inout) :: lambda(:)
    type(ldp_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    !> use lambda > 0 on entry as the initial passive set (default .true.)
    logical, intent(in), optional :: warm
    !> NNLS iteration cap
    integer, intent(in), optional :: max_iter
    type(nnls_work_t), intent(inout), optional, target :: work
    !> Bm Bm^T [mc, mc] when the caller can form it more cheaply (warm path only)
    real(wp), intent(in), optional :: gram(:,:)
    type(nnls_work_t), target :: local
    type(nnls_work_t), pointer :: wk
    integer :: mc, n, i, j
    logical :: use_warm, feasible

    mc = size(bm, 1); n = size(bm, 2)
    if (size(d) /= mc .or. size(v) /= n .or. size(u) /= n .or. size(lambda) /= mc) then
      call set_error(error, "ldp_solve: inconsistent sizes: Bm is " // str(mc) // " x " // str(n) &
        // ", d " // str(size(d)) // ", v " // str(size(v)) // ", u " // str(size(u)) // &
        ", lambda " // str(size(lambda)), EXIT_BAD_INPUT)
      return
    end if
    use_warm = .true.
    if (present(warm)) use_warm = warm
    do j = 1, n
      do i = 1, mc
        if (.not. ieee_is_finite(bm(i, j))) then
          call set_error(error, "ldp_solve: Bm(" // str(i) // ", " // str(j) // ") is not finite", EXIT_BAD_INPUT)
          return
        end if
      end do
      if (.not. ieee_is_finite(v(j))) then
        call set_error(error, "ldp_solve: v(" // str(j) // ") is not finite", EXIT_BAD_INPUT)
        return
      end if
    end do
    do i = 1, mc
      if (.not. ieee_is_finite(d(i))) then
        call set_error(error, "ldp_solve: d(" // str(i) // ") is not finite", EXIT_BAD_INPUT)
        return
      end if
      if (use_warm) then
        if (.not. ieee_is_finite(lambda(i))) then
          call set_error(error, "ldp_solve: warm-start lambda(" // str(i) // ") is not finite", EXIT_BAD_INPUT)
          return
        end if
      end if
    end do
    if (present(work)) then
      wk => work
    else
      wk => local
    end if
    stats%infeasible = .false.
    stats%nnls%converged = .true.
    if (mc == 0) then
      u = v
      return
    end if
    call reserve_ldp(wk, mc, n)
    do j = 1, mc
      wk%p0(j) = .false.
      if (use_warm) wk%p0(j) = lambda(j) > 0.0_wp
    end do
    if (use_warm .and. any(wk%p0(1:mc))) then
      ! the guessed active set often is the answer (consecutive time steps): verify it
      if (present(gram)) then
        if (size(gram, 1) /= mc .or. size(gram, 2) /= mc) then
          call set_error(error, "ldp_solve: gram is " // str(size(gram, 1)) // " x " // str(size(gram, 2)) // &
            ", expected " // str(mc) // " x " // str(mc), EXIT_BAD_INPUT)
          return
        end if
        call ldp_active_guess(bm, d, v, u, lambda, wk, feasible, gram)
      else
        call ldp_active_guess(bm, d, v, u, lambda, wk, feasible)
      end if
      if (feasible) stats%nnls%n_passive = count(lambda > 0.0_wp)
    else
      feasible = .false.
    end if
    if (.not. feasible) call ldp_project(bm, d, v, u, lambda, stats, error, max_iter, wk, feasible)
    if (allocated(error)) return
    if (.not. feasible) call least_violation(bm, d, v, u, lambda, stats, error, max_iter, wk)
    if (allocated(error)) return
    stats%max_violation = 0.0_wp
    do i = 1, mc
      stats%max_violation = max(stats%max_violation, dot_product(bm(i, :), u) - d(i))
    end do
  end subroutine ldp_solve

  !> Warm path of ldp_solve: with the rows A = {lambda > 0} of the guess held as equalities,
  !> solve (Bm_A Bm_A^T) beta = Bm_A v - d_A (Cholesky, k = |A|: O(k^2 n + k^3)) and accept
  !> u = v - Bm_A^T beta when it satisfies the KKT conditions of the LDP: beta >= 0 and
  !> Bm u <= d to rounding (256 eps (sum_j |Bm_ij u_j| + |d_i|)). These conditions
  !> characterise the unique projection, so an accepted answer is exact. Otherwise A is
  !> updated by a primal-dual active-set sweep (drop beta < 0, add violated rows), at most 6
  !> sweeps; if none verifies, ok = .false. and u, lambda are untouched (dependent rows make
  !> the factor fail: the NNLS path then handles degenerate and infeasible cases).
  subroutine ldp_active_guess(bm, d, v, u, lambda, wk, ok, gram)
    real(wp), intent(in) :: bm(:,:), d(:), v(:)
    real(wp), intent(inout) :: u(:), lambda(:)
    type(nnls_work_t), intent(inout) :: wk
    logical, intent(out) :: ok
    real(wp), intent(in), optional :: gram(:,:)
    integer, parameter :: MAX_SWEEPS = 10
    integer, allocatable :: act(:)
    logical, allocatable :: in_a(:), next(:)
    real(wp), allocatable :: bt(:,:), ba(:,:), g(:,:), beta(:), ut(:), viol(:), tol(:)
    integer :: k, i, j, mc, n, sweep
    real(wp) :: t
    mc = size(bm, 1); n = size(bm, 2)
    ok = .false.
    in_a = wk%p0(1:mc)
    ! rows of Bm as contiguous columns
    bt = transpose(bm)
    allocate(viol(mc), tol(mc), next(mc))
    do sweep = 1, MAX_SWEEPS
      act = pack([(i, i = 1, mc)], in_a)
      k = size(act)
      if (k > n) return
      ba = bt(:, act)
      ! G = Ba^T Ba, right-hand side Ba^T v - d_A
      if (present(gram)) then
        g = gram(act, act)
      else
        g = matmul(transpose(ba), ba)
      end if
      beta = matmul(v, ba) - d(act)
      ! Cholesky G = R^T R in the upper triangle (column access); a relative pivot below
      ! 1e-10 means (numerically) dependent rows
      do j = 1, k
        do i = 1, j - 1
          g(i, j) = (g(i, j) - dot_product(g(1:i-1, i), g(1:i-1, j))) / g(i, i)
        end do
        t = g(j, j) - dot_product(g(1:j-1, j), g(1:j-1, j))
        if (.not. t > 1.0e-10_wp * g(j, j)) then
          wk%p0(1:mc) = in_a
          return
        end if
        g(j, j) = sqrt(t)
      end do
      ! R^T y = rhs, R beta = y
      do i = 1, k
        beta(i) = (beta(i) - dot_product(g(1:i-1, i), beta(1:i-1))) / g(i, i)
      end do
      do i = k, 1, -1
        beta(i) = beta(i) / g(i, i)
        beta(1:i-1) = beta(1:i-1) - g(1:i-1, i) * beta(i)
      end do
      ut = v - matmul(ba, beta)
      viol = matmul(ut, bt) - d
      ! rounding allowance, needed only where a row is not satisfied exactly
      do i = 1, mc
        tol(i) = 0.0_wp
        if (viol(i) > 0.0_wp) tol(i) = 256.0_wp * epsilon(1.0_wp) * (sum(abs(bt(:, i) * ut)) + abs(d(i)))
      end do
      if (all(beta >= 0.0_wp) .and. all(viol <= tol)) then
        ok = .true.
        u = ut
        lambda = 0.0_wp
        lambda(act) = beta
        return
      end if
      ! primal-dual active-set update: keep rows with beta > 0, add violated rows
      next = viol > tol
      do i = 1, k
        next(act(i)) = beta(i) > 0.0_wp
      end do
      if (all(next .eqv. in_a)) exit
      in_a = next
    end do
    ! not verified: the NNLS starts from the last active set
    wk%p0(1:mc) = in_a
  end subroutine ldp_active_guess

  !> Make sure the LDP buffers of `wk` hold an mc x n problem.
  subroutine reserve_ldp(wk, mc, n)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: mc, n
    integer :: i, j
    if (.not. allocated(wk%e)) allocate(wk%e(0, 0), wk%f(0), wk%y(0), wk%p0(0))
    if (size(wk%e, 1) < n + 1 .or. size(wk%e, 2) < mc) then
      i = max(n + 1, size(wk%e, 1)); j = max(mc, size(wk%e, 2))
      deallocate(wk%e, wk%f, wk%y, wk%p0)
      allocate(wk%e(i, j), wk%f(i), wk%y(j), wk%p0(j))
    end if
  end subroutine reserve_ldp

  !> The LDP -> NNLS reduction of ldp_solve (see there), warm started from wk%p0(1:mc).
  !> feasible = .false. (u, lambda untouched) when the Farkas certificate shows
  !> {Bm u <= d} empty to rounding. Adds its NNLS iterations to stats%nnls%iterations.
  subroutine ldp_project(bm, d, v, u, lambda, stats, error, max_iter, wk, feasible)
    real(wp), intent(in) :: bm(:,:), d(:), v(:)
    real(wp), intent(inout) :: u(:), lambda(:)
    type(ldp_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: max_iter
    type(nnls_work_t), intent(inout) :: wk
    logical, intent(out) :: feasible
    integer :: mc, n, i, j, pass, it1
    real(wp) :: gmax, emax, s, den, cancel, ysum
    type(nnls_stats_t) :: st1

    mc = size(bm, 1); n = size(bm, 2)
    feasible = .true.
    ! e = d - Bm v, kept in wk%y
    do i = 1, mc
      wk%y(i) = d(i) - dot_product(bm(i, :), v)
    end do
    if (all(wk%y(1:mc) >= 0.0_wp)) then
      ! v is feasible: it is its own projection
      u = v
      lambda = 0.0_wp
      return
    end if
    gmax = maxval(abs(bm))
    emax = maxval(abs(wk%y(1:mc)))
    s = 1.0_wp
    if (gmax > 0.0_wp .and. emax > 0.0_wp) s = scale(1.0_wp, exponent(emax) - exponent(gmax))
    do pass = 1, 2
      do j = 1, mc
        wk%e(1:n, j) = -bm(j, :)
        wk%e(n + 1, j) = -(d(j) - dot_product(bm(j, :), v)) / s
      end do
      wk%f(1:n) = 0.0_wp
      wk%f(n + 1) = 1.0_wp
      call nnls_solve(wk%e(1:n + 1, 1:mc), wk%f(1:n + 1), wk%y(1:mc), st1, error, &
        passive0=wk%p0(1:mc), max_iter=max_iter, work=wk)
      if (allocated(error)) then
        call prefix_error(error, "ldp_solve")
        return
      end if
      it1 = stats%nnls%iterations + st1%iterations
      stats%nnls = st1
      stats%nnls%iterations = it1
      ! den = -r_{n+1} = 1 - (E y)_{n+1} = 1 / (1 + |x'|^2); cancel bounds its rounding error
      ! ysum = sum_j |E_j| y_j bounds the rounding-level residual the NNLS can reach (see below)
      den = 1.0_wp
      cancel = 1.0_wp
      ysum = 1.0_wp
      do j = 1, mc
        den = den - wk%e(n + 1, j) * wk%y(j)
        cancel = cancel + abs(wk%e(n + 1, j) * wk%y(j))
        if (wk%y(j) > 0.0_wp) ysum = ysum + norm2(wk%e(1:n + 1, j)) * wk%y(j)
      end do
      ! Infeasible when den cannot be told from 0: below the rounding of its own sum (cancel),
      ! or den = |r|^2 below the square of the residual nnls_solve guarantees for a consistent
      ! problem, |r| <= 32 m eps sum_j |E_j| y_j with m = n + 1 (taken twice as a margin). A
      ! certificate of infeasibility is final: the rescaled pass below can lose it (its
      ! entering gradient, about |gap| / s, falls under the NNLS's relative stopping test)
      feasible = den > max(64.0_wp * epsilon(1.0_wp) * sqrt(real(mc, wp)) * cancel, &
                           (64.0_wp * real(n + 1, wp) * epsilon(1.0_wp) * ysum)**2)
      if (.not. feasible) exit
      ! |x'| >> 1 loses accuracy (relative error ~ eps / den): rescale so that |x'| ~ 1 and
      ! solve again, warm started
      if (den >= 0.25_wp .or. pass == 2) exit
      s = s * min(1.0e8_wp, 1.0_wp / sqrt(max(den, tiny(1.0_wp))))
      s = scale(1.0_wp, exponent(s))
      wk%p0(1:mc) = wk%y(1:mc) > 0.0_wp
    end do
    if (feasible) then
      lambda = (s / den) * wk%y(1:mc)
      u = v
      do j = 1, mc
        if (lambda(j) /= 0.0_wp) u = u - lambda(j) * bm(j, :)
      end do
    end if
  end subroutine ldp_project

  !> Least-violation point of an infeasible {Bm u <= d} (the two stages documented at
  !> ldp_solve). Sets u, lambda and stats%infeasible.
  subroutine least_violation(bm, d, v, u, lambda, stats, error, max_iter, wk)
    real(wp), intent(in) :: bm(:,:), d(:), v(:)
    real(wp), intent(inout) :: u(:), lambda(:)
    type(ldp_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: max_iter
    type(nnls_work_t), intent(inout) :: wk
    real(wp), allocatable :: a(:,:), x(:), ustar(:), sigma(:), delta(:)
    type(nnls_stats_t) :: st1
    integer :: mc, n, l
    real(wp) :: umax
    logical :: feasible, conv0

    mc = size(bm, 1); n = size(bm, 2)
    conv0 = stats%nnls%converged
    ! stage 1: sigma* = A x - d for the NNLS min |A x - d|, A = [Bm, -Bm, I], x >= 0
    allocate(a(mc, 2 * n + mc), x(2 * n + mc), ustar(n), sigma(mc), delta(mc))
    a(:, 1:n) = bm
    a(:, n + 1:2 * n) = -bm
    a(:, 2 * n + 1:) = 0.0_wp
    do l = 1, mc
      a(l, 2 * n + l) = 1.0_wp
    end do
    call nnls_solve(a, d, x, st1, error, max_iter=max_iter, work=wk)
    if (allocated(error)) then
      call prefix_error(error, "ldp_solve: least-violation stage")
      return
    end if
    stats%nnls%iterations = stats%nnls%iterations + st1%iterations
    ustar = x(1:n) - x(n + 1:2 * n)
    umax = 0.0_wp
    if (n > 0) umax = maxval(abs(ustar))
    do l = 1, mc
      sigma(l) = max(0.0_wp, dot_product(bm(l, :), ustar) - d(l) + x(2 * n + l))
      delta(l) = 64.0_wp * epsilon(1.0_wp) * sqrt(real(mc, wp)) * &
        (abs(d(l)) + sigma(l) + sum(abs(bm(l, :))) * umax)
    end do
    ! stage 2: projection of v on the relaxed set, warm started from the violated rows
    wk%p0(1:mc) = sigma > 0.0_wp
    call ldp_project(bm, d + sigma + delta, v, u, lambda, stats, error, max_iter, wk, feasible)
    if (allocated(error)) return
    stats%nnls%converged = conv0 .and. st1%converged .and. stats%nnls%converged
    if (.not. feasible) then
      u = ustar
      lambda = 0.0_wp
    end if
    stats%infeasible = any(sigma > delta)
  end subroutine least_violation

  !> Append column j to the factorisation Q R of A_P (k -> k + 1); ok = .false. (and nothing
  !> changed) when the column is numerically in the span of the passive columns.
  subroutine add_column_impl(wk, m, j, k, ok)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, j
    integer, intent(inout) :: k
    logical, intent(out) :: ok
    integer :: i, ii, c, i0, i1
    real(wp) :: s, alpha, beta, sig, anorm
    ok = .false.
    if (k >= m) return
    i0 = wk%col(j); i1 = wk%col(j + 1) - 1
    anorm = norm2(wk%val(i0:i1))
    ! z = Q^T a_j using the non-zeros of a_j only
    do i = 1, m
      s = 0.0_wp
      do ii = i0, i1
        s = s + wk%q(wk%row(ii), i) * wk%val(ii)
      end do
      wk%z(i) = s
    end do
    sig = norm2(wk%z(k + 1:m))
    if (sig <= 16.0_wp * real(m, wp) * epsilon(1.0_wp) * anorm) return
    ! Pivot: move the largest entry of z(k+1:m) to position k+1 by swapping two columns of Q
    ! (an orthogonal permutation; rows k+1:m of R are zero). With sparse columns this keeps the
    ! reflector's support equal to that of z, so Q fills in slowly and the update stays cheap.
    c = k + maxloc(abs(wk%z(k + 1:m)), dim=1)
    if (c /= k + 1) then
      s = wk%z(c); wk%z(c) = wk%z(k + 1); wk%z(k + 1) = s
      s = wk%qtb(c); wk%qtb(c) = wk%qtb(k + 1); wk%qtb(k + 1) = s
      wk%res(1:m) = wk%q(1:m, c)
      wk%q(1:m, c) = wk%q(1:m, k + 1)
      wk%q(1:m, k + 1) = wk%res(1:m)
    end if
    ! Householder H = I - beta v v^T with H z(k+1:m) = alpha e_1
    alpha = -sign(sig, wk%z(k + 1))
    wk%hv(k + 1:m) = wk%z(k + 1:m)
    wk%hv(k + 1) = wk%z(k + 1) - alpha
    beta = 1.0_wp / (alpha * (alpha - wk%z(k + 1)))
    ! Q(:, k+1:m) <- Q(:, k+1:m) H  (so that the new Q^T = H Q^T)
    wk%res(1:m) = 0.0_wp
    do c = k + 1, m
      if (wk%hv(c) /= 0.0_wp) wk%res(1:m) = wk%res(1:m) + wk%hv(c) * wk%q(1:m, c)
    end do
    do c = k + 1, m
      if (wk%hv(c) /= 0.0_wp) wk%q(1:m, c) = wk%q(1:m, c) - (beta * wk%hv(c)) * wk%res(1:m)
    end do
    s = beta * dot_product(wk%hv(k + 1:m), wk%qtb(k + 1:m))
    wk%qtb(k + 1:m) = wk%qtb(k + 1:m) - s * wk%hv(k + 1:m)
    k = k + 1
    wk%r(1:k - 1, k) = wk%z(1:k - 1)
    wk%r(k, k) = alpha
    wk%plist(k) = j
    wk%pos(j) = k
    ok = .true.
  end subroutine add_column_impl

  !> Remove the column at passive position p (k -> k - 1) with Givens rotations.
  subroutine remove_column_impl(wk, m, p, k)
    type(nnls_work_t), intent(inout) :: wk
    integer, intent(in) :: m, p
    integer, intent(inout) :: k
    integer :: i, c
    real(wp) :: cg, sg, rr, t1, t2
    wk%pos(wk%plist(p)) = 0
    do c = p, k - 1
      wk%r(1:c + 1, c) = wk%r(1:c + 1, c + 1)
      wk%plist(c) = wk%plist(c + 1)
      wk%pos(wk%plist(c)) = c
    end do
    k = k - 1
    do i = p, k
      ! zero r(i+1, i) against r(i, i)
      rr = hypot(wk%r(i, i), wk%r(i + 1, i))
      if (rr == 0.0_wp) cycle
      cg = wk%r(i, i) / rr; sg = wk%r(i + 1, i) / rr
      wk%r(i, i) = rr; wk%r(i + 1, i) = 0.0_wp
      do c = i + 1, k
        t1 = wk%r(i, c); t2 = wk%r(i + 1, c)
        wk%r(i, c) = cg * t1 + sg * t2
        wk%r(i + 1, c) = -sg * t1 + cg * t2
      end do
      t1 = wk%qtb(i); t2 = wk%qtb(i + 1)
      wk%qtb(i) = cg * t1 + sg * t2
      wk%qtb(i + 1) = -sg * t1 + cg * t2
      wk%res(1:m) = wk%q(1:m, i)
      wk%q(1:m, i) = cg * wk%res(1:m) + sg * wk%q(1:m, i + 1)
      wk%q(1:m, i + 1) = -sg * wk%res(1:m) + cg * wk%q(1:m, i + 1)
    end do
  end subroutine remove_column_impl

  !> Lawson-Hanson step back: x(plist) moves towards the passive-set minimiser z along the
  !> segment as far as x stays >= 0 (the largest alpha in [0, 1]); the passive variable that
  !> blocks the step is set to exactly 0. Shared by the NNLS here and the sparse contact kernel.
  !> Euclidean norm of x without underflow or overflow of the squares (gfortran's norm2
  !> squares directly: entries below about 1e-154 give 0): x scaled by the power of two of its
  !> largest entry first, which is exact, so that the result is norm2(x) itself in between.
  pure real(wp) function safe_norm2(x) result(r)
    real(wp), intent(in) :: x(:)
    real(wp) :: amax
    integer :: e
    r = 0.0_wp
    if (size(x) == 0) return
    amax = maxval(abs(x))
    if (.not. (amax > 0.0_wp)) return
    e = exponent(amax)
    r = scale(norm2(scale(x, -e)), e)
  end function safe_norm2

  pure subroutine lh_step_back(x, z, plist)
    real(wp), intent(inout) :: x(:)
    real(wp), intent(in) :: z(:)
    integer, intent(in) :: plist(:)
    real(wp) :: alpha, dn
    integer :: p, j, pmin
    alpha = 1.0_wp
    pmin = 0
    do p = 1, size(z)
      if (z(p) <= 0.0_wp) then
        j = plist(p)
        dn = x(j) - z(p)
        if (dn > 0.0_wp) then
          if (x(j) / dn < alpha .or. pmin == 0) then
            alpha = min(1.0_wp, x(j) / dn); pmin = p
          end if
        else
          alpha = 0.0_wp; pmin = p
        end if
      end if
    end do
    do p = 1, size(z)
      j = plist(p)
      x(j) = x(j) + alpha * (z(p) - x(j))
    end do
    if (pmin > 0) x(plist(pmin)) = 0.0_wp
  end subroutine lh_step_back
end module cr_nnls
