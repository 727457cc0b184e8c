!> The driver loop of the sparse dual active-set projection (run): the warm start, the optional
!> primal-dual active-set sweeps, then the block Lawson-Hanson loop (violated rows enter, by row
!> additions or one refactorisation; dependent rows by exchange; the step back of
!> cr_sparse_as_search; iterative refinement at convergence). On the analysis and factor that
!> cr_sparse_as_slots and cr_sparse_as_factor keep; st%why is set when the safe path must
!> take over.
module cr_sparse_as_loop
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t
  use cr_projection, only: projection_settings_t, solve_stats_t
  use cr_sparse_as_settings, only: sparse_as_settings_t, dep_tol
  use cr_sparse_as_state, only: sparse_as_state_t
  use cr_sparse_as_rows, only: velocities, slacks, slacks_violated
  use cr_sparse_as_lists, only: list_from_mask, list_prune, list_merge, list_delete, list_insert, &
    lam_from_z, nonpositive_on_p
  use cr_sparse_as_factor, only: add_row, remove_rows, factor_independent, refresh, solve_p
  use cr_sparse_as_slots, only: enlarge_w
  use cr_sparse_as_search, only: step_back, drop_nonpositive
  implicit none
  private
  public :: run

  !> at most this many refinement steps on P at convergence
  integer, parameter :: n_refine = 3

contains

  !> The active-set iteration from st%lam (warm start) on the current analysis.
  subroutine run(st, kn, ps, cs, v, stats, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(projection_settings_t), intent(in) :: ps
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    type(solve_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(inout) :: error
    st%why = ""
    st%it = 0
    st%itmax = min(ps%max_iter, 10 * st%m + 100)
    call warm_phase(st, kn, v, stats, error)
    if (allocated(error)) return
    if (len(st%why) > 0) return
    call pdas_sweeps(st, kn, cs, v, stats, error); if (allocated(error)) return
    call outer_loop(st, kn, ps, cs, v, stats, error)
  end subroutine run

  !> Warm start: factor the guessed passive set (rows with lambda > 0), drop dependent rows,
  !> then move by the step back (warm_search) or drop the rows whose minimiser is not positive.
  subroutine warm_phase(st, kn, v, stats, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    real(wp), intent(in) :: v(:)
    type(solve_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(inout) :: error
    integer :: j, k, m
    logical :: bad
    m = st%m
    do j = 1, m
      st%act(j) = st%lam(j) > 0.0_wp
    end do
    call list_from_mask(st)
    k = st%nact
    if (k > 0 .and. kn%warm_search .and. m < kn%warm_search_rows) then
      ! from the warm multipliers (feasible, positive on P) by the step back: rows leave P
      ! only where f still falls with them at zero (monotone from here on)
      call factor_independent(st, bad, error); if (allocated(error)) return
      call list_prune(st)
      call step_back(st, kn, v, .false., .false., stats%iterations, error)
      if (allocated(error)) return
      if (len(st%why) > 0) return
    else if (k > 0) then
      call factor_independent(st, bad, error); if (allocated(error)) return
      call list_prune(st)
      call drop_nonpositive(st, kn, error); if (allocated(error)) return
    else
      st%lam(1:m) = 0.0_wp
      call st%chol%factor(st%act(1:m), error); if (allocated(error)) return
    end if
    st%refused(1:m) = .false.
  end subroutine warm_phase

  !> Primal-dual active-set sweeps (semismooth Newton on the dual): all violated rows enter and
  !> all rows with a non-positive minimiser leave at once. Not monotone, so at most pdas_max
  !> sweeps; a dependent pivot ends them. The block Lawson-Hanson loop then finishes from
  !> lambda = z > 0 on P (usually with nothing left to do).
  subroutine pdas_sweeps(st, kn, cs, v, stats, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    type(solve_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(inout) :: error
    integer :: ntry, nrem, j
    logical :: stop
    do ntry = 1, merge(kn%pdas_max, 0, st%m >= kn%pdas_rows)
      ! lambda = z on P (signs unrestricted), then the slacks it gives
      call list_from_mask(st)
      call solve_p(st, error); if (allocated(error)) return
      call lam_from_z(st)
      call slacks(st, v)
      st%nv = 0; nrem = 0
      do j = 1, st%m
        if (st%act(j)) then
          if (st%z(j) <= 0.0_wp) then
            nrem = nrem + 1; st%rem(nrem) = j
          end if
        else if (st%slack(j) < -st%thr) then
          st%nv = st%nv + 1; st%viol(st%nv) = j
        end if
      end do
      if (st%nv == 0 .and. nrem == 0) exit
      if (st%nv > 0) then
        call enlarge_w(st, kn, cs, v, st%nv, error); if (allocated(error)) return
      end if
      st%it = st%it + 1
      stats%iterations = stats%iterations + 1
      call sweep_update(st, kn, cs, nrem, stop, error); if (allocated(error)) return
      if (stop) exit
    end do
    ! back to the invariant of the monotone loop: lambda = z > 0 on P (the warm start
    ! already ends there: only the sweeps leave it)
    if (st%m >= kn%pdas_rows .and. kn%pdas_max > 0) then
      call list_from_mask(st)
      call drop_nonpositive(st, kn, error)
    end if
  end subroutine pdas_sweeps

  !> One sweep's change of P: rows viol(1:nv) enter, rows rem(1:nrem) leave (one
  !> refactorisation when many, otherwise row modifications); stop: a dependent pivot ends
  !> the sweeps.
  subroutine sweep_update(st, kn, cs, nrem, stop, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: nrem
    logical, intent(out) :: stop
    type(error_t), allocatable, intent(inout) :: error
    integer :: k, q, j, t, m
    real(wp) :: pivot
    logical :: bad
    stop = .false.
    m = st%m
    k = st%nact
    st%newact(1:m) = st%act(1:m)
    st%newact(st%viol(1:st%nv)) = .true.
    st%newact(st%rem(1:nrem)) = .false.
    if (st%nv + nrem > max(kn%bulk_min, k / kn%bulk_div)) then
      call st%chol%factor(st%newact(1:m), error); if (allocated(error)) return
      call st%chol%pivots(st%piv(1:m), error); if (allocated(error)) return
      ! rows with a dependent pivot stay out (sweeps are heuristic; the monotone loop
      ! settles them); refactorise without them
      do q = 1, 3
        bad = .false.
        do j = 1, m
          if (st%newact(j) .and. .not. (st%piv(j) > dep_tol)) then
            st%newact(j) = .false.; bad = .true.
          end if
        end do
        if (.not. bad) exit
        call st%chol%factor(st%newact(1:m), error); if (allocated(error)) return
        call st%chol%pivots(st%piv(1:m), error); if (allocated(error)) return
      end do
      if (bad) then
        call st%chol%factor(st%act(1:m), error); if (allocated(error)) return
        stop = .true.; return
      end if
      st%act(1:m) = st%newact(1:m)
    else
      if (nrem > 0) then
        call st%chol%rowdel(st%rem(1:nrem), error); if (allocated(error)) return
      end if
      st%act(st%rem(1:nrem)) = .false.
      bad = .false.
      do q = 1, st%nv
        ! with the pivot pre-test: a row dependent on the ones added before it is never
        ! added (CHOLMOD's next update would divide by its zero pivot)
        t = st%viol(q)
        call add_row(st, cs, t, pivot, error); if (allocated(error)) return
        if (.not. st%act(t)) then
          bad = .true.
          exit
        end if
      end do
      ! an addition also lowers the later pivots (and a bad one spoils the factor)
      if (.not. bad) bad = .not. (st%chol%min_pivot() > dep_tol)
      if (bad) then
        ! refactorise the current set, leaving out the rows with a dependent pivot
        call factor_independent(st, bad, error); if (allocated(error)) return
        if (bad) stop = .true.
      end if
    end if
  end subroutine sweep_update

  !> The block Lawson-Hanson loop: until no row is violated, the most violated rows enter
  !> (add_frac), lambda steps back towards the minimiser on P; at convergence refinement.
  subroutine outer_loop(st, kn, ps, cs, v, stats, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(projection_settings_t), intent(in) :: ps
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    type(solve_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(inout) :: error
    integer :: n_ref, nv_all, nadd
    real(wp) :: frac, r_ref
    !> some row may be refused (refused(1:m) not all false); z holds the minimiser on P
    logical :: any_ref, exch, zset, stop
    any_ref = .false.
    frac = merge(kn%add_frac, 0.0_wp, st%m < kn%add_frac_rows)
    n_ref = 0; r_ref = huge(1.0_wp)
    outer: do
      if (st%chol%n_since >= ps%refresh_every) then
        call refresh(st, kn, stats%factor_drift, error); if (allocated(error)) return
      end if
      call select_entering(st, v, frac, any_ref, nv_all)
      if (st%nv > 0) then
        call enlarge_w(st, kn, cs, v, st%nv, error); if (allocated(error)) return
      end if
      exch = st%nv > 0 .and. all(st%refused(st%viol(1:st%nv)))
      if (st%nv == 0) then
        if (st%nact == 0) exit outer
        call refine(st, n_ref, r_ref, stop, error); if (allocated(error)) return
        if (stop) exit outer
        cycle outer
      end if
      n_ref = 0; r_ref = huge(1.0_wp)
      if (st%it >= st%itmax) then
        st%why = "iteration cap " // str(st%itmax) // " reached"
        return
      end if
      st%it = st%it + 1
      stats%iterations = stats%iterations + 1
      nadd = 0
      zset = .false.
      if (.not. exch .and. st%nv > max(kn%bulk_min, st%nact / kn%bulk_div)) then
        call enter_block(st, nadd, error); if (allocated(error)) return
      end if
      if (nadd == 0 .and. .not. exch) then
        call enter_each(st, cs, nadd, zset, any_ref, error); if (allocated(error)) return
      end if
      if (nadd == 0 .and. .not. exch .and. st%nv < nv_all) then
        ! the most violated rows are dependent on P: from here on every violated row enters
        ! (the classical rule; a dependent block is where degenerate exchanges could cycle)
        frac = 0.0_wp
        cycle outer
      end if
      if (nadd == 0) then
        ! every violated row is dependent on P: exchange the most violated one
        frac = 0.0_wp
        call exchange(st, kn, cs, v, any_ref, stats, error); if (allocated(error)) return
      else
        if (any_ref) st%refused(1:st%m) = .false.
        any_ref = .false.
        ! lambda has not moved since the slacks above (entering rows have lambda = 0)
        call step_back(st, kn, v, .true., zset, stats%iterations, error)
        if (allocated(error)) return
      end if
      if (len(st%why) > 0) return
    end do outer
  end subroutine outer_loop

  !> The slacks at lambda and the violated rows outside P, viol(1:nv): rows refused as
  !> dependent join when no other row is violated (exchange); with frac > 0 only the rows
  !> violated by at least frac times the largest violation stay (nv_all: before that cut).
  subroutine select_entering(st, v, frac, any_ref, nv_all)
    type(sparse_as_state_t), intent(inout) :: st
    real(wp), intent(in) :: v(:)
    real(wp), intent(in) :: frac
    logical, intent(in) :: any_ref
    integer, intent(out) :: nv_all
    integer :: j, q, nadd
    real(wp) :: r
    call velocities(st, v)
    call slacks_violated(st%m, st%ka, st%kb, st%c1, st%c2, st%dd, st%uu, st%thr, &
      st%act, st%refused, st%slack, st%nv, st%viol)
    if (st%nv == 0 .and. any_ref) then
      ! rows refused as dependent but still violated: exchange them in
      do j = 1, st%m
        if (st%slack(j) < -st%thr) then
          if (st%refused(j) .and. .not. st%act(j)) then
            st%nv = st%nv + 1; st%viol(st%nv) = j
          end if
        end if
      end do
    end if
    nv_all = st%nv
    if (st%nv > 0 .and. frac > 0.0_wp) then
      ! only the rows violated by at least add_frac times the largest violation enter
      r = 0.0_wp
      do q = 1, st%nv
        r = min(r, st%slack(st%viol(q)))
      end do
      nadd = 0
      do q = 1, st%nv
        if (st%slack(st%viol(q)) <= frac * r) then
          nadd = nadd + 1; st%viol(nadd) = st%viol(q)
        end if
      end do
      st%nv = nadd
    end if
  end subroutine select_entering

  !> Iterative refinement on P at convergence (at most n_refine steps while the slacks on P
  !> shrink and exceed thr: 1e-3 of the tolerance; polishing them to round-off, 1e-2 thr, took
  !> 1.3 solves per step on congested150 for KKT residuals up to 5x smaller, all 140x below
  !> tol). stop: the loop ends here.
  subroutine refine(st, n_ref, r_ref, stop, error)
    type(sparse_as_state_t), intent(inout) :: st
    integer, intent(inout) :: n_ref
    real(wp), intent(inout) :: r_ref
    logical, intent(out) :: stop
    type(error_t), allocatable, intent(inout) :: error
    integer :: q, j, k
    real(wp) :: r
    logical :: ok
    stop = .true.
    k = st%nact
    r = 0.0_wp
    do q = 1, k
      r = max(r, abs(st%slack(st%alist(q))))
    end do
    if (n_ref >= n_refine .or. r <= st%thr .or. r >= 0.5_wp * r_ref) return
    n_ref = n_ref + 1; r_ref = r
    st%rhs(1:st%m) = 0.0_wp
    do q = 1, k
      j = st%alist(q); st%rhs(j) = st%slack(j)
    end do
    call st%chol%solve(st%rhs(1:st%m), st%z(1:st%m), error); if (allocated(error)) return
    ok = .true.
    do q = 1, k
      j = st%alist(q)
      if (.not. (st%lam(j) - st%z(j) > 0.0_wp)) ok = .false.
    end do
    if (.not. ok) return
    do q = 1, k
      j = st%alist(q); st%lam(j) = st%lam(j) - st%z(j)
    end do
    stop = .false.
  end subroutine refine

  !> Many entering rows: one refactorisation of P + V (nadd = nv), unless some are dependent
  !> (back to P, nadd = 0: they are added one at a time).
  subroutine enter_block(st, nadd, error)
    type(sparse_as_state_t), intent(inout) :: st
    integer, intent(inout) :: nadd
    type(error_t), allocatable, intent(inout) :: error
    integer :: j, m
    logical :: bad
    m = st%m
    st%newact(1:m) = st%act(1:m)
    st%newact(st%viol(1:st%nv)) = .true.
    call st%chol%factor(st%newact(1:m), error); if (allocated(error)) return
    call st%chol%pivots(st%piv(1:m), error); if (allocated(error)) return
    bad = .false.
    do j = 1, m
      if (st%newact(j) .and. .not. (st%piv(j) > dep_tol)) bad = .true.
    end do
    if (bad) then
      ! dependent rows among them: back to P, and add one at a time
      call st%chol%factor(st%act(1:m), error); if (allocated(error)) return
    else
      st%act(1:m) = st%newact(1:m)
      call list_from_mask(st)
      nadd = st%nv
    end if
  end subroutine enter_block

  !> The rows viol(1:nv) enter one by one (factor row additions; a dependent one is refused);
  !> they join the list of P together at the end (rem: scratch). One row entering gives the
  !> minimiser on P + t from lambda (the minimiser on P) and alpha = M_P^{-1} M(P, t) (the
  !> backward half of a solve after the test's forward half): z_t = -slack_t / pivot,
  !> z_P = lambda_P - z_t alpha (zset).
  subroutine enter_each(st, cs, nadd, zset, any_ref, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(contact_set_t), intent(in) :: cs
    integer, intent(inout) :: nadd
    logical, intent(inout) :: zset, any_ref
    type(error_t), allocatable, intent(inout) :: error
    integer :: q, j, t, i1
    real(wp) :: pivot, tau, r
    do q = 1, st%nv
      t = st%viol(q)
      if (st%nv == 1) then
        call add_row(st, cs, t, pivot, error, alpha=.true., schur=r); if (allocated(error)) return
        if (st%act(t)) then
          tau = -st%slack(t) / r
          do j = 1, st%nact
            i1 = st%alist(j); st%z(i1) = st%lam(i1) - tau * st%w(i1)
          end do
          st%z(t) = tau
          zset = .true.
        end if
      else
        call add_row(st, cs, t, pivot, error); if (allocated(error)) return
      end if
      if (st%act(t)) then
        nadd = nadd + 1; st%rem(nadd) = t
      else
        st%refused(t) = .true.; any_ref = .true.
      end if
    end do
    call list_merge(st, nadd, st%rem)
  end subroutine enter_each

  !> Every violated row is dependent on P: the most violated one t enters by exchange
  !> (b_t = B_P^T alpha: lambda_P -= tau alpha, lambda_t = tau, the row reaching zero leaves;
  !> u does not move), then the step back. No alpha > 0: the constraints are infeasible
  !> (Farkas; st%why).
  subroutine exchange(st, kn, cs, v, any_ref, stats, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    logical, intent(inout) :: any_ref
    type(solve_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(inout) :: error
    integer :: q, t, j, pmin
    real(wp) :: pivot, tau
    t = st%viol(1)
    do q = 2, st%nv
      if (st%slack(st%viol(q)) < st%slack(t)) t = st%viol(q)
    end do
    st%refused(t) = .false.
    ! alpha = M_P^{-1} B_P b_t (st%w, left by add_row)
    call add_row(st, cs, t, pivot, error, precheck=.true., alpha=.true.); if (allocated(error)) return
    if (st%act(t)) then
      call list_insert(st, t)
      call step_back(st, kn, v, .false., .false., stats%iterations, error)
      return
    end if
    call exchange_ratio(st, tau, pmin)
    if (pmin == 0) then
      st%why = "constraints infeasible (Farkas certificate)"
      return
    end if
    do q = 1, st%nact
      j = st%alist(q); st%lam(j) = max(0.0_wp, st%lam(j) - tau * st%w(j))
    end do
    st%lam(pmin) = 0.0_wp
    call st%chol%rowdel([pmin], error); if (allocated(error)) return
    st%act(pmin) = .false.
    call list_delete(st, pmin)
    call add_row(st, cs, t, pivot, error, 1.0e3_wp * epsilon(1.0_wp), precheck=.true.)
    if (allocated(error)) return
    if (st%act(t)) then
      call list_insert(st, t)
      st%lam(t) = tau
    else
      st%refused(t) = .true.; any_ref = .true.
      st%lam(t) = 0.0_wp
    end if
    call nonpositive_on_p(st, st%lam)
    if (st%nv > 0) then
      call remove_rows(st, kn, st%nv, error); if (allocated(error)) return
    end if
    call step_back(st, kn, v, .false., .false., stats%iterations, error)
  end subroutine exchange

  !> The ratio test of the exchange: the row pmin of P reaching zero first along -alpha
  !> (alpha = st%w, entries above 1e-12 of its largest), at tau = lambda_pmin / alpha_pmin;
  !> pmin = 0 when alpha has no such entry.
  subroutine exchange_ratio(st, tau, pmin)
    type(sparse_as_state_t), intent(in) :: st
    real(wp), intent(out) :: tau
    integer, intent(out) :: pmin
    integer :: q, j
    real(wp) :: xmax, r
    xmax = 0.0_wp
    do q = 1, st%nact
      xmax = max(xmax, abs(st%w(st%alist(q))))
    end do
    tau = huge(1.0_wp); pmin = 0
    do q = 1, st%nact
      j = st%alist(q)
      if (st%w(j) > 1.0e-12_wp * xmax) then
        r = st%lam(j) / st%w(j)
        if (r < tau) then
          tau = r; pmin = j
        end if
      end if
    end do
  end subroutine exchange_ratio
end module cr_sparse_as_loop
