!> Least-distance projection for contact rows, by a Lawson-Hanson active-set method on the dual:
!>
!>   min |u - v|^2  s.t.  B u <= d   <=>   min_{lambda >= 0} 1/2 |B^T lambda|^2 - lambda^T (B v - d),
!>   u = v - B^T lambda.
!>
!> Row j of B has coef(:, j) in the two slots of agent ia(j) and -coef(:, j) in those of agent
!> ib(j) (ib(j) = 0: one agent only), i.e. at most 4 non-zeros: the contact matrices of
!> cr_contact_set (coef = -h g).
!>
!> Numerics:
!> - Rows are normalised to unit 2-norm (exactly the same problem, lambda rescaled on exit).
!> - The passive rows P are kept linearly independent; their Gram matrix B_P B_P^T = L L^T is
!>   held as a dense Cholesky factor [k, k] (no orthogonal factor: a row that enters costs one
!>   sparse-start forward solve, O(k^2); a row that leaves costs a rank-one update of the
!>   trailing block, O((k - p)^2)). The dense last row of the classical LDP -> NNLS reduction
!>   does not exist here, which is what made the Householder updates of cr_nnls expensive.
!> - A row whose new pivot delta = |b_t|^2 - |L^{-1} B_P b_t|^2 is below dep_tol |b_t|^2 is
!>   dependent on P (jammed crowds have many such rows). Write b_t = B_P^T alpha. Then the
!>   equality problem on P + t is inconsistent and t enters by exchange (Goldfarb-Idnani
!>   partial step): lambda_P <- lambda_P - tau alpha, lambda_t = tau, where tau is the ratio
!>   test over alpha_i > 0; the row that reaches zero leaves, u does not move. When no
!>   alpha_i > 0 exists, {B u <= d} is empty (Farkas) and stats%infeasible is set.
!> - Every solve is backward stable, so B_P u - d_P (the primal and complementarity residuals)
!>   stays at rounding level even when the Gram matrix is ill-conditioned; at convergence one
!>   step of iterative refinement (lambda_P <- lambda_P - (L L^T)^{-1} slack_P) is applied and
!>   the optimality test repeated. yc = L^{-1} (B v - d)_P, kept up to date by the row
!>   updates, is recomputed from B v - d after the warm start's deletions and before each
!>   refinement: nearly dependent warm rows can make it huge, and its rotated updates then
!>   carry an error of eps |yc| (a stored case of 2 116 rows reported convergence at a KKT
!>   residual of 1e22 before). A solve whose slacks on P exceed the violation threshold at the
!>   end is not converged (the caller's safe path takes it).
module cr_contact_ldp
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_nnls, only: lh_step_back
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: contact_ldp_work_t, contact_ldp_stats_t, contact_ldp_solve, contact_ldp_bytes

  !> relative pivot threshold below which an entering row counts as dependent
  real(wp), parameter :: dep_tol = 1.0e-10_wp

  !> Outcome of one contact_ldp_solve.
  type :: contact_ldp_stats_t
    !> row additions, exchanges and step-backs
    integer :: iterations = 0
    !> the optimality test was met before the iteration cap
    logical :: converged = .false.
    !> a Farkas certificate was found: {B u <= d} is empty (u, lambda are then meaningless)
    logical :: infeasible = .false.
    !> number of rows in the final passive set
    integer :: n_passive = 0
    !> number of dependent rows that entered by exchange
    integer :: n_exchanges = 0
    !> max_j (B u - d)_j^+ of the returned u (original units)
    real(wp) :: max_violation = 0.0_wp
  end type contact_ldp_stats_t

  !> Reusable work space (grown on demand, never shrunk).
  type :: contact_ldp_work_t
    integer :: kcap = -1, mcap = -1, ncap = -1
    !> Cholesky factor of the passive Gram matrix [kcap, kcap] (lower triangle used)
    real(wp), allocatable :: l(:,:)
    !> work vectors [kcap]
    real(wp), allocatable :: h(:), r(:), z(:), y(:), x(:)
    !> L^{-1} (B v - d)_P, kept up to date by append and remove [kcap]
    real(wp), allocatable :: yc(:)
    !> passive list [kcap]
    integer, allocatable :: plist(:)
    !> position in the passive list (0: not passive) [mcap]
    integer, allocatable :: pos(:)
    logical, allocatable :: refused(:)
    !> normalised rows [2, mcap], their rhs, multipliers, slacks, B v - d, row norms [mcap]
    real(wp), allocatable :: c(:,:), dd(:), lam(:), slack(:), cc(:), rn(:)
  end type contact_ldp_work_t

  !> The state of one solve shared by its parts (the work space holds the arrays).
  type :: cldp_run_t
    !> rows, unknowns, passive rows, their cap, iterations and their cap
    integer :: m = 0, nd = 0, k = 0, kmax = 0, it = 0, itmax = 0
    !> violation threshold (normalised rows)
    real(wp) :: thr = 0.0_wp
  end type cldp_run_t

  !> what the main loop does after a row entered (enter_row)
  integer, parameter :: NEXT_GO = 0, NEXT_CYCLE = 1, NEXT_STOP = 2

contains

  !> Bytes of dense storage contact_ldp_solve needs for m rows and n_dof unknowns.
  pure real(wp) function contact_ldp_bytes(m, n_dof) result(bytes)
    integer, intent(in) :: m, n_dof
    bytes = 8.0_wp * real(min(m, n_dof), wp)**2
  end function contact_ldp_bytes

  subroutine reserve(wk, m, k)
    type(contact_ldp_work_t), intent(inout) :: wk
    integer, intent(in) :: m, k
    if (k > wk%kcap) then
      if (allocated(wk%l)) deallocate(wk%l, wk%h, wk%r, wk%z, wk%y, wk%x, wk%yc, wk%plist)
      allocate(wk%l(max(k, 1), max(k, 1)), wk%h(max(k, 1)), wk%r(max(k, 1)), wk%z(max(k, 1)), &
        wk%y(max(k, 1)), wk%x(max(k, 1)), wk%yc(max(k, 1)), wk%plist(max(k, 1)))
      wk%kcap = k
    end if
    if (m > wk%mcap) then
      if (allocated(wk%pos)) deallocate(wk%pos, wk%refused, wk%c, wk%dd, wk%lam, wk%slack, wk%cc, wk%rn)
      allocate(wk%pos(m), wk%refused(m), wk%c(2, m), wk%dd(m), wk%lam(m), wk%slack(m), wk%cc(m), &
        wk%rn(m))
      wk%mcap = m
    end if
  end subroutine reserve

  !> Project v onto {u : B u <= d} for contact rows (see the module header).
  !>
  !> lambda on entry: warm start (lambda > 0 marks the guessed passive set); on exit the
  !> multipliers (u = v - B^T lambda). When stats%converged is .false. or stats%infeasible is
  !> .true., the caller should fall back to a more robust method (ldp_solve). Errors only for
  !> inconsistent input.
  subroutine contact_ldp_solve(ia, ib, coef, d, v, u, lambda, stats, error, warm, max_iter, tol, &
      work)
    !> first agent of each row, 1 .. size(v)/2 [m]
    integer, intent(in) :: ia(:)
    !> second agent of each row, 0 for none [m]
    integer, intent(in) :: ib(:)
    !> coefficients of the first agent (the second has their negatives) [2, m]
    real(wp), intent(in) :: coef(:,:)
    !> right-hand side [m]
    real(wp), intent(in) :: d(:)
    !> point to project [2 * n_agents]
    real(wp), intent(in) :: v(:)
    !> projection [2 * n_agents]
    real(wp), intent(out) :: u(:)
    !> multipliers [m]; warm-start guess on entry
    real(wp), intent(inout) :: lambda(:)
    type(contact_ldp_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    !> use lambda > 0 on entry as the initial passive set (default .true.)
    logical, intent(in), optional :: warm
    !> iteration cap (default 10 m + 100)
    integer, intent(in), optional :: max_iter
    !> relative optimality tolerance on the violations (default 1e-13)
    real(wp), intent(in), optional :: tol
    type(contact_ldp_work_t), intent(inout), optional, target :: work
    type(contact_ldp_work_t), target :: local
    type(contact_ldp_work_t), pointer :: wk
    type(cldp_run_t) :: rs
    integer :: m, nd
    real(wp) :: sv, tolv
    logical :: use_warm

    call check_input(ia, ib, coef, d, v, u, lambda, error)
    if (allocated(error)) return
    m = size(d); nd = size(v)
    rs%m = m; rs%nd = nd
    use_warm = .true.
    if (present(warm)) use_warm = warm
    rs%itmax = 10 * m + 100
    if (present(max_iter)) rs%itmax = max_iter
    tolv = 1.0e-13_wp
    if (present(tol)) tolv = tol
    tolv = max(tolv, 256.0_wp * epsilon(1.0_wp))
    if (present(work)) then
      wk => work
    else
      wk => local
    end if
    rs%kmax = min(m, nd)
    call reserve(wk, m, rs%kmax)
    call normalise_rows(wk, ia, ib, coef, d, v, lambda, use_warm, sv)
    rs%thr = tolv * sv
    stats%infeasible = .false.
    stats%converged = .false.
    rs%k = 0
    u = v
    if (m == 0) then
      stats%converged = .true.
      return
    end if
    if (all(wk%cc(1:m) <= rs%thr)) then
      ! v is feasible: it is its own projection
      wk%lam(1:m) = 0.0_wp
      wk%slack(1:m) = -wk%cc(1:m)
      stats%converged = .true.
      call finish(wk, rs, lambda, stats)
      return
    end if
    call warm_start(wk, rs, ia, ib)
    call ldp_iterate(wk, rs, ia, ib, v, u, stats)
    stats%iterations = rs%it
    if (stats%infeasible) return
    call slacks(wk, rs, ia, ib, v, u)
    ! the stopping test only looks at the rows outside P: B_P u = d_P must hold as well
    if (stats%converged .and. rs%k > 0) then
      if (maxval(abs(wk%slack(wk%plist(1:rs%k)))) > rs%thr) stats%converged = .false.
    end if
    call finish(wk, rs, lambda, stats)
  end subroutine contact_ldp_solve

  !> Sizes and rows of a contact_ldp_solve call (error names the first bad one).
  subroutine check_input(ia, ib, coef, d, v, u, lambda, error)
    integer, intent(in) :: ia(:), ib(:)
    real(wp), intent(in) :: coef(:,:), d(:), v(:), u(:), lambda(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: m, nd, na, j
    m = size(d); nd = size(v); na = nd / 2
    if (size(ia) /= m .or. size(ib) /= m .or. size(coef, 1) /= 2 .or. size(coef, 2) /= m .or. &
        size(u) /= nd .or. size(lambda) /= m .or. mod(nd, 2) /= 0) then
      call set_error(error, "contact_ldp_solve: inconsistent sizes: " // str(m) // " rows, ia " // &
        str(size(ia)) // ", ib " // str(size(ib)) // ", coef " // str(size(coef, 1)) // " x " // &
        str(size(coef, 2)) // ", lambda " // str(size(lambda)) // ", v " // str(nd) // ", u " // &
        str(size(u)), EXIT_BAD_INPUT)
      return
    end if
    do j = 1, m
      if (ia(j) < 1 .or. ia(j) > na .or. ib(j) < 0 .or. ib(j) > na .or. ia(j) == ib(j)) then
        call set_error(error, "contact_ldp_solve: row " // str(j) // " has agents " // &
          str(ia(j)) // ", " // str(ib(j)) // " (expected 1 <= ia /= ib <= " // str(na) // &
          ", ib = 0 for none)", EXIT_BAD_INPUT)
        return
      end if
      if (.not. (norm2(coef(:, j)) > 0.0_wp)) then
        call set_error(error, "contact_ldp_solve: row " // str(j) // " is zero or not finite", EXIT_BAD_INPUT)
        return
      end if
    end do
  end subroutine check_input

  !> Normalised rows c, rhs dd, c = B v - d, warm-start multipliers (normalised), empty
  !> passive set; sv the scale of the velocities.
  subroutine normalise_rows(wk, ia, ib, coef, d, v, lambda, use_warm, sv)
    type(contact_ldp_work_t), intent(inout) :: wk
    integer, intent(in) :: ia(:), ib(:)
    real(wp), intent(in) :: coef(:,:), d(:), v(:), lambda(:)
    logical, intent(in) :: use_warm
    real(wp), intent(out) :: sv
    integer :: j, nd
    nd = size(v)
    sv = tiny(1.0_wp) * 1.0e10_wp
    if (nd > 0) sv = max(sv, maxval(abs(v)))
    do j = 1, size(d)
      wk%rn(j) = norm2(coef(:, j))
      if (ib(j) > 0) wk%rn(j) = wk%rn(j) * sqrt(2.0_wp)
      wk%c(:, j) = coef(:, j) / wk%rn(j)
      wk%dd(j) = d(j) / wk%rn(j)
      sv = max(sv, -wk%dd(j))
      wk%cc(j) = rowdot_v(wk, ia, ib, j, v) - wk%dd(j)
      wk%lam(j) = 0.0_wp
      if (use_warm .and. lambda(j) > 0.0_wp) wk%lam(j) = lambda(j) * wk%rn(j)
      wk%pos(j) = 0
      wk%refused(j) = .false.
    end do
  end subroutine normalise_rows

  !> Warm start: factor the guessed passive set, drop non-positive coefficients.
  subroutine warm_start(wk, rs, ia, ib)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(inout) :: rs
    integer, intent(in) :: ia(:), ib(:)
    integer :: j, p
    logical :: ok, changed
    do j = 1, rs%m
      if (wk%lam(j) > 0.0_wp) then
        call append(wk, rs, ia, ib, j, ok)
        if (.not. ok) wk%lam(j) = 0.0_wp
      end if
    end do
    do
      if (rs%k == 0) exit
      call solve_p(wk, rs)
      changed = .false.
      do p = rs%k, 1, -1
        if (wk%z(p) <= 0.0_wp) then
          wk%lam(wk%plist(p)) = 0.0_wp
          call remove(wk, rs, p)
          changed = .true.
        end if
      end do
      if (.not. changed) exit
      ! (the deletions rotated yc with L)
      call refresh_yc(wk, rs)
    end do
    do p = 1, rs%k
      wk%lam(wk%plist(p)) = wk%z(p)
    end do
  end subroutine warm_start

  !> Main loop: the most violated row outside P enters (enter_row); when none is violated,
  !> one step of iterative refinement on P and the test again.
  subroutine ldp_iterate(wk, rs, ia, ib, v, u, stats)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(inout) :: rs
    integer, intent(in) :: ia(:), ib(:)
    real(wp), intent(in) :: v(:)
    real(wp), intent(inout) :: u(:)
    type(contact_ldp_stats_t), intent(inout) :: stats
    integer :: j, t, next
    real(wp) :: worst
    logical :: refined
    rs%it = 0
    refined = .false.
    outer: do
      call slacks(wk, rs, ia, ib, v, u)
      worst = -rs%thr
      t = 0
      do j = 1, rs%m
        if (wk%pos(j) /= 0 .or. wk%refused(j)) cycle
        if (wk%slack(j) < worst) then
          worst = wk%slack(j); t = j
        end if
      end do
      if (t == 0) then
        if (refined .or. rs%k == 0) then
          stats%converged = .true.
          exit outer
        end if
        ! one step of iterative refinement on P, then test again
        refined = .true.
        call refine(wk, rs)
        cycle outer
      end if
      refined = .false.
      if (rs%it >= rs%itmax) exit outer
      rs%it = rs%it + 1
      call enter_row(wk, rs, ia, ib, t, stats, next)
      if (next == NEXT_STOP) exit outer
    end do outer
  end subroutine ldp_iterate

  !> One step of iterative refinement on P: lambda_P <- lambda_P - (L L^T)^{-1} slack_P when
  !> it keeps lambda_P > 0.
  subroutine refine(wk, rs)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(inout) :: rs
    integer :: p
    call refresh_yc(wk, rs)
    do p = 1, rs%k
      wk%x(p) = wk%slack(wk%plist(p))
    end do
    call solve_rhs(wk, rs, wk%x)
    if (all(wk%lam(wk%plist(1:rs%k)) - wk%x(1:rs%k) > 0.0_wp)) then
      do p = 1, rs%k
        wk%lam(wk%plist(p)) = wk%lam(wk%plist(p)) - wk%x(p)
      end do
    end if
  end subroutine refine

  !> Row t enters P (a dependent row by exchange), then the step-back loop; next tells the
  !> main loop to go on (NEXT_GO, NEXT_CYCLE) or stop (NEXT_STOP: infeasible).
  subroutine enter_row(wk, rs, ia, ib, t, stats, next)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(inout) :: rs
    integer, intent(in) :: ia(:), ib(:)
    integer, intent(in) :: t
    type(contact_ldp_stats_t), intent(inout) :: stats
    integer, intent(out) :: next
    logical :: ok
    next = NEXT_CYCLE
    call append(wk, rs, ia, ib, t, ok)
    if (ok) then
      call solve_p(wk, rs)
      if (wk%z(rs%k) <= 0.0_wp) then
        ! round-off: the entering row does not help; refuse it
        call remove(wk, rs, rs%k)
        wk%refused(t) = .true.
        return
      end if
    else
      call exchange(wk, rs, ia, ib, t, stats, next)
      if (next /= NEXT_GO) return
    end if
    call step_back(wk, rs)
    wk%refused(1:rs%m) = .false.
    next = NEXT_GO
  end subroutine enter_row

  !> Dependent row t: b_t = B_P^T alpha with L^T alpha = r (r left by append); the ratio test
  !> over alpha_i > 0 gives the row that leaves (Goldfarb-Idnani partial step); none: the
  !> constraints are infeasible (NEXT_STOP).
  subroutine exchange(wk, rs, ia, ib, t, stats, next)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(inout) :: rs
    integer, intent(in) :: ia(:), ib(:)
    integer, intent(in) :: t
    type(contact_ldp_stats_t), intent(inout) :: stats
    integer, intent(out) :: next
    integer :: p, pmin
    real(wp) :: tau, q, xmax
    logical :: ok
    next = NEXT_CYCLE
    wk%x(1:rs%k) = wk%r(1:rs%k)
    call back(wk, rs, wk%x)
    xmax = maxval(abs(wk%x(1:rs%k)))
    tau = huge(1.0_wp); pmin = 0
    do p = 1, rs%k
      if (wk%x(p) > 1.0e-12_wp * xmax) then
        q = wk%lam(wk%plist(p)) / wk%x(p)
        if (q < tau) then
          tau = q; pmin = p
        end if
      end if
    end do
    if (pmin == 0) then
      stats%infeasible = .true.
      next = NEXT_STOP
      return
    end if
    stats%n_exchanges = stats%n_exchanges + 1
    do p = 1, rs%k
      wk%lam(wk%plist(p)) = max(0.0_wp, wk%lam(wk%plist(p)) - tau * wk%x(p))
    end do
    wk%lam(wk%plist(pmin)) = 0.0_wp
    call remove(wk, rs, pmin)
    wk%lam(t) = tau
    call append(wk, rs, ia, ib, t, ok)
    if (.not. ok) then
      wk%lam(t) = 0.0_wp
      wk%refused(t) = .true.
    end if
    ! rows at zero leave P (keeps lambda_P > 0 before the step-back loop)
    do p = rs%k, 1, -1
      if (wk%lam(wk%plist(p)) <= 0.0_wp) then
        wk%lam(wk%plist(p)) = 0.0_wp
        call remove(wk, rs, p)
      end if
    end do
    if (rs%k == 0) return
    call solve_p(wk, rs)
    if (.not. ok) then
      call step_back(wk, rs)
      return
    end if
    next = NEXT_GO
  end subroutine exchange

  !> LH inner loop: move lambda towards z (the minimiser on P) until positive; on exit
  !> lambda_P = z > 0.
  subroutine step_back(wk, rs)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(inout) :: rs
    integer :: pp, jj
    do
      if (rs%k == 0) return
      if (all(wk%z(1:rs%k) > 0.0_wp)) exit
      if (rs%it >= rs%itmax) exit
      rs%it = rs%it + 1
      call lh_step_back(wk%lam, wk%z(1:rs%k), wk%plist(1:rs%k))
      do pp = rs%k, 1, -1
        jj = wk%plist(pp)
        if (wk%lam(jj) <= 0.0_wp) then
          wk%lam(jj) = 0.0_wp
          call remove(wk, rs, pp)
        end if
      end do
      if (rs%k == 0) return
      call solve_p(wk, rs)
    end do
    do pp = 1, rs%k
      wk%lam(wk%plist(pp)) = max(wk%z(pp), 0.0_wp)
    end do
  end subroutine step_back

  !> u = v - B_P^T lambda_P, slack = d - B u (normalised rows)
  subroutine slacks(wk, rs, ia, ib, v, u)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(in) :: rs
    integer, intent(in) :: ia(:), ib(:)
    real(wp), intent(in) :: v(:)
    real(wp), intent(inout) :: u(:)
    integer :: pp, jj, a, b
    u = v
    do pp = 1, rs%k
      jj = wk%plist(pp)
      a = ia(jj); b = ib(jj)
      u(2*a - 1:2*a) = u(2*a - 1:2*a) - wk%lam(jj) * wk%c(:, jj)
      if (b > 0) u(2*b - 1:2*b) = u(2*b - 1:2*b) + wk%lam(jj) * wk%c(:, jj)
    end do
    do jj = 1, rs%m
      wk%slack(jj) = wk%dd(jj) - rowdot_v(wk, ia, ib, jj, u)
    end do
  end subroutine slacks

  !> Multipliers in the original units, passive rows and largest violation.
  subroutine finish(wk, rs, lambda, stats)
    type(contact_ldp_work_t), intent(in) :: wk
    type(cldp_run_t), intent(in) :: rs
    real(wp), intent(inout) :: lambda(:)
    type(contact_ldp_stats_t), intent(inout) :: stats
    integer :: jj
    stats%n_passive = rs%k
    stats%max_violation = 0.0_wp
    do jj = 1, rs%m
      lambda(jj) = wk%lam(jj) / wk%rn(jj)
      stats%max_violation = max(stats%max_violation, -wk%slack(jj) * wk%rn(jj))
    end do
  end subroutine finish

  !> yc = L^{-1} (B v - d)_P from scratch (the updates of remove lose accuracy when yc is large)
  subroutine refresh_yc(wk, rs)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(in) :: rs
    integer :: pp
    do pp = 1, rs%k
      wk%yc(pp) = wk%cc(wk%plist(pp))
    end do
    call forward(wk, rs, wk%yc)
  end subroutine refresh_yc

  !> z = (B_P B_P^T)^{-1} (B v - d)_P = L^{-T} yc
  subroutine solve_p(wk, rs)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(in) :: rs
    wk%z(1:rs%k) = wk%yc(1:rs%k)
    call back(wk, rs, wk%z)
  end subroutine solve_p

  !> b = (L L^T)^{-1} b
  subroutine solve_rhs(wk, rs, b)
    type(contact_ldp_work_t), intent(in) :: wk
    type(cldp_run_t), intent(in) :: rs
    real(wp), intent(inout) :: b(:)
    call forward(wk, rs, b)
    call back(wk, rs, b)
  end subroutine solve_rhs

  !> b = L^{-1} b (column oriented, skips zeros)
  subroutine forward(wk, rs, b)
    type(contact_ldp_work_t), intent(in) :: wk
    type(cldp_run_t), intent(in) :: rs
    real(wp), intent(inout) :: b(:)
    integer :: ii, k
    k = rs%k
    do ii = 1, k
      if (b(ii) /= 0.0_wp) then
        b(ii) = b(ii) / wk%l(ii, ii)
        b(ii + 1:k) = b(ii + 1:k) - b(ii) * wk%l(ii + 1:k, ii)
      end if
    end do
  end subroutine forward

  !> b = L^{-T} b
  subroutine back(wk, rs, b)
    type(contact_ldp_work_t), intent(in) :: wk
    type(cldp_run_t), intent(in) :: rs
    real(wp), intent(inout) :: b(:)
    integer :: ii, k
    k = rs%k
    do ii = k, 1, -1
      b(ii) = (b(ii) - dot_product(wk%l(ii + 1:k, ii), b(ii + 1:k))) / wk%l(ii, ii)
    end do
  end subroutine back

  !> Append row jt to P (k -> k + 1) unless dependent (okk = .false.; then wk%r(1:k) holds
  !> L^{-1} B_P b_jt).
  subroutine append(wk, rs, ia, ib, jt, okk)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(inout) :: rs
    integer, intent(in) :: ia(:), ib(:)
    integer, intent(in) :: jt
    logical, intent(out) :: okk
    integer :: pp, k
    real(wp) :: delta, btt
    okk = .false.
    k = rs%k
    do pp = 1, k
      wk%r(pp) = rowdot(wk, ia, ib, wk%plist(pp), jt)
    end do
    call forward(wk, rs, wk%r)
    btt = rowdot(wk, ia, ib, jt, jt)
    delta = btt - sum(wk%r(1:k)**2)
    if (delta <= dep_tol * btt .or. k >= rs%kmax) return
    k = k + 1
    rs%k = k
    wk%l(k, 1:k - 1) = wk%r(1:k - 1)
    wk%l(k, k) = sqrt(delta)
    wk%yc(k) = (wk%cc(jt) - dot_product(wk%r(1:k - 1), wk%yc(1:k - 1))) / wk%l(k, k)
    wk%plist(k) = jt
    wk%pos(jt) = k
    okk = .true.
  end subroutine append

  !> Remove passive position pr (k -> k - 1): delete row and column pr of L and restore the
  !> factor of the trailing block by a rank-one update with the deleted column.
  subroutine remove(wk, rs, pr)
    type(contact_ldp_work_t), intent(inout) :: wk
    type(cldp_run_t), intent(inout) :: rs
    integer, intent(in) :: pr
    integer :: cc2, ii, k
    real(wp) :: rr, cg, sg, eta, t1
    k = rs%k
    wk%pos(wk%plist(pr)) = 0
    ! yc: the trailing part goes through the same rotations as [L33, l32] (eta = old yc(pr))
    eta = wk%yc(pr)
    wk%yc(pr:k - 1) = wk%yc(pr + 1:k)
    wk%y(pr:k - 1) = wk%l(pr + 1:k, pr)
    do cc2 = 1, pr - 1
      wk%l(pr:k - 1, cc2) = wk%l(pr + 1:k, cc2)
    end do
    do cc2 = pr + 1, k
      wk%l(cc2 - 1:k - 1, cc2 - 1) = wk%l(cc2:k, cc2)
      wk%plist(cc2 - 1) = wk%plist(cc2)
      wk%pos(wk%plist(cc2 - 1)) = cc2 - 1
    end do
    k = k - 1
    rs%k = k
    do ii = pr, k
      rr = hypot(wk%l(ii, ii), wk%y(ii))
      t1 = wk%yc(ii)
      wk%yc(ii) = (wk%l(ii, ii) * t1 + wk%y(ii) * eta) / rr
      eta = (-wk%y(ii) * t1 + wk%l(ii, ii) * eta) / rr
      cg = rr / wk%l(ii, ii); sg = wk%y(ii) / wk%l(ii, ii)
      wk%l(ii, ii) = rr
      wk%l(ii + 1:k, ii) = (wk%l(ii + 1:k, ii) + sg * wk%y(ii + 1:k)) / cg
      wk%y(ii + 1:k) = cg * wk%y(ii + 1:k) - sg * wk%l(ii + 1:k, ii)
    end do
  end subroutine remove

  !> b_j1 . b_j2 (normalised rows)
  pure real(wp) function rowdot(wk, ia, ib, j1, j2) result(s)
    type(contact_ldp_work_t), intent(in) :: wk
    integer, intent(in) :: ia(:), ib(:)
    integer, intent(in) :: j1, j2
    real(wp) :: cd
    s = 0.0_wp
    cd = wk%c(1, j1) * wk%c(1, j2) + wk%c(2, j1) * wk%c(2, j2)
    if (ia(j1) == ia(j2)) s = s + cd
    if (ib(j1) > 0) then
      if (ib(j1) == ia(j2)) s = s - cd
      if (ib(j1) == ib(j2)) s = s + cd
    end if
    if (ib(j2) > 0) then
      if (ia(j1) == ib(j2)) s = s - cd
    end if
  end function rowdot

  !> b_j . w (normalised row)
  pure real(wp) function rowdot_v(wk, ia, ib, j, w) result(s)
    type(contact_ldp_work_t), intent(in) :: wk
    integer, intent(in) :: ia(:), ib(:)
    integer, intent(in) :: j
    real(wp), intent(in) :: w(:)
    integer :: a, b
    a = ia(j); b = ib(j)
    s = wk%c(1, j) * w(2*a - 1) + wk%c(2, j) * w(2*a)
    if (b > 0) s = s - wk%c(1, j) * w(2*b - 1) - wk%c(2, j) * w(2*b)
  end function rowdot_v

end module cr_contact_ldp
