!> The factor of M on the passive set P in the sparse dual active-set projection (through the
!> CHOLMOD binding cr_cholmod): rows entering with the pivot test (add_row, pivot_lower_bound),
!> rows leaving (remove_rows), factorisation without dependent rows (factor_independent), the
!> refresh after many modifications (refresh) and the solve on P (solve_p).
module cr_sparse_as_factor
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_contact_set, only: contact_set_t
  use cr_sparse_as_settings, only: sparse_as_settings_t, dep_tol
  use cr_sparse_as_state, only: sparse_as_state_t
  use cr_sparse_as_lists, only: list_prune, list_delete
  implicit none
  private
  public :: add_row, remove_rows, factor_independent, refresh, solve_p, pivot_lower_bound

contains

  !> Factorise the active rows, leaving out (multiplier zero) the rows whose pivot shows them
  !> dependent on the others, up to four factorisations; bad: the fourth still had such a
  !> row (it is left out too and the factor is rebuilt without it).
  subroutine factor_independent(st, bad, error)
    type(sparse_as_state_t), intent(inout) :: st
    logical, intent(out) :: bad
    type(error_t), allocatable, intent(inout) :: error
    integer :: tr, jj, m
    m = st%m
    bad = .false.
    do tr = 1, 4
      call st%chol%factor(st%act(1:m), error); if (allocated(error)) return
      call st%chol%pivots(st%piv(1:m), error); if (allocated(error)) return
      bad = .false.
      do jj = 1, m
        if (st%act(jj) .and. .not. (st%piv(jj) > dep_tol)) then
          st%act(jj) = .false.; st%lam(jj) = 0.0_wp; bad = .true.
        end if
      end do
      if (.not. bad) return
    end do
    call st%chol%factor(st%act(1:m), error)
  end subroutine factor_independent

  !> Take rows viol(1:n) out of P (row deletions, or one refactorisation when many).
  subroutine remove_rows(st, kn, n, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    integer, intent(in) :: n
    type(error_t), allocatable, intent(inout) :: error
    integer :: q
    if (n > max(kn%bulk_min, st%nact / kn%bulk_div)) then
      st%act(st%viol(1:n)) = .false.
      call list_prune(st)
      call st%chol%factor(st%act(1:st%m), error)
    else
      call st%chol%rowdel(st%viol(1:n), error); if (allocated(error)) return
      do q = 1, n
        st%act(st%viol(q)) = .false.
        if (n <= 4) call list_delete(st, st%viol(q))
      end do
      if (n > 4) call list_prune(st)
    end if
    st%lam(st%viol(1:n)) = 0.0_wp
  end subroutine remove_rows

  !> Row tt enters the factor unless dependent on P: pivot = 1 - w^T M_P^{-1} w (w = M(P, tt),
  !> alpha = M_P^{-1} w left in st%w) is checked before the addition (a near-zero pivot would
  !> spoil the rank-one downdate of the trailing factor); pivot is then the factor's new D(tt,tt).
  subroutine add_row(st, cs, tt, pivot, error, min_pivot, precheck, alpha, schur)
    type(sparse_as_state_t), intent(inout) :: st
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: tt
    real(wp), intent(out) :: pivot
    type(error_t), allocatable, intent(inout) :: error
    !> relative pivot below which tt counts as dependent (default dep_tol)
    real(wp), intent(in), optional :: min_pivot
    !> test the pivot by a solve before the addition (default; leaves alpha in st%w);
    !> otherwise the row is added and, when its pivot or a later one became too small, the
    !> factor is rebuilt without it (cheaper when rows are rarely dependent)
    logical, intent(in), optional :: precheck
    !> present: compute alpha = M_P^{-1} M(P, tt) into st%w by a full solve (the
    !> exchange step needs it); otherwise the test is one sparse forward solve
    logical, intent(in), optional :: alpha
    !> with alpha: the Schur complement M(tt,tt) - M(P,tt)^T alpha the test found
    real(wp), intent(out), optional :: schur
    integer :: q1, q2, q
    real(wp) :: s, dtt, pmin_rel
    logical :: pre
    pre = .true.
    if (present(precheck)) pre = precheck
    pmin_rel = dep_tol
    if (present(min_pivot)) pmin_rel = min_pivot
    q1 = st%fp(tt); q2 = st%fp(tt + 1) - 1
    dtt = 0.0_wp
    do q = q1, q2
      if (st%fi(q) == tt) dtt = st%fv(q)
    end do
    if (pre) then
      if (present(alpha)) then
        ! alpha = M_P^{-1} M(P, tt) in st%w on P: the test's forward solve, then the
        ! backward one
        call st%chol%schur(tt, st%fi(q1:q2), st%fv(q1:q2), s, error, st%w(1:st%m))
        if (allocated(error)) return
      else if (pivot_lower_bound(tt, st%fp, st%fi, st%act, cs%ia, cs%ib, st%c1, &
                                 st%c2) > 1.0e3_wp * pmin_rel * dtt) then
        ! at an agent of tt the active rows leave part of b_t outside the span of B_P:
        ! the pivot is at least that part's norm^2, far above the threshold (no test)
        st%n_free = st%n_free + 1
        s = 0.0_wp
      else
        call st%chol%schur(tt, st%fi(q1:q2), st%fv(q1:q2), s, error)
        if (allocated(error)) return
      end if
      pivot = dtt - s
      if (present(schur)) schur = pivot
      if (.not. (pivot > pmin_rel * dtt)) return
    end if
    call st%chol%rowadd(tt, st%fi(q1:q2), st%fv(q1:q2), pivot, error)
    if (allocated(error)) return
    st%act(tt) = .true.
    ! the addition also lowers the later pivots: if any became tiny, tt depends on P
    if (.not. pre) pivot = min(pivot, st%chol%min_pivot())
    if (.not. (pivot > pmin_rel * dtt)) then
      ! dependent row: the rank-2 update of the trailing factor is unreliable, rebuild
      st%act(tt) = .false.
      call st%chol%factor(st%act(1:st%m), error)
    end if
  end subroutine add_row

  !> z = (B_P B_P^T)^{-1} (B v - d)_P (zero off P).
  subroutine solve_p(st, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(error_t), allocatable, intent(inout) :: error
    call st%chol%solve(st%bp(1:st%m), st%z(1:st%m), error)
  end subroutine solve_p

  !> Refactorise P afresh. With check_drift, first measure the backward error of a solve with
  !> the updated factor, |M_P z - c_P|_inf / (|M_P|_inf |z|_inf + |c_P|_inf) (about eps for a
  !> fresh factor, whatever the conditioning of M_P), into factor_drift (the largest so far).
  subroutine refresh(st, kn, factor_drift, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    real(wp), intent(inout) :: factor_drift
    type(error_t), allocatable, intent(inout) :: error
    real(wp) :: r, rmax, mnorm, rs, zmax, cmax
    integer :: jj, q
    if (kn%check_drift) then
      call solve_p(st, error); if (allocated(error)) return
      rmax = 0.0_wp; mnorm = 0.0_wp; zmax = 0.0_wp; cmax = 0.0_wp
      do jj = 1, st%m
        if (.not. st%act(jj)) cycle
        r = -st%cc(jj); rs = 0.0_wp
        do q = st%fp(jj), st%fp(jj + 1) - 1
          if (st%act(st%fi(q))) then
            r = r + st%fv(q) * st%z(st%fi(q))
            rs = rs + abs(st%fv(q))
          end if
        end do
        rmax = max(rmax, abs(r)); mnorm = max(mnorm, rs)
        zmax = max(zmax, abs(st%z(jj))); cmax = max(cmax, abs(st%cc(jj)))
      end do
      if (mnorm * zmax + cmax > 0.0_wp) &
        factor_drift = max(factor_drift, rmax / (mnorm * zmax + cmax))
    end if
    call st%chol%factor(st%act(1:st%m), error)
  end subroutine refresh

  !> A lower bound of the pivot row tt would get against the active rows (its Schur
  !> complement, the squared distance of b_t to the span of B_P; rows by their coefficients
  !> c1, c2 on the velocity of their first agent ia and -c1, -c2 on that of their second ib,
  !> 0 for a wall), from the active rows at each of tt's agents only: the distance is at least
  !> that of b_t's part on the agent's velocity (norm^2 n2 = c1^2 + c2^2) to the span of the
  !> active rows' parts there, which is n2 with no such row, n2 sin^2(angle) with one, and
  !> unknown (0) with two or more. Column tt of M (fi(fp(tt):fp(tt + 1) - 1)) must list every
  !> row sharing an agent with tt. Public for its test.
  pure real(wp) function pivot_lower_bound(tt, fp, fi, act, ia, ib, c1, c2) result(bnd)
    integer, intent(in) :: tt, fp(*), fi(*), ia(*), ib(*)
    logical, intent(in) :: act(*)
    real(wp), intent(in) :: c1(*), c2(*)
    integer :: ag(2), nr(2), l, p, k, na_t
    real(wp) :: n2, cr(2), nl2(2)
    ag(1) = ia(tt); ag(2) = ib(tt)
    na_t = merge(2, 1, ag(2) > 0)
    nr = 0; cr = 0.0_wp; nl2 = 1.0_wp
    do p = fp(tt), fp(tt + 1) - 1
      l = fi(p)
      if (l == tt .or. .not. act(l)) cycle
      do k = 1, na_t
        if (ia(l) == ag(k) .or. ib(l) == ag(k)) then
          nr(k) = nr(k) + 1
          ! (c1, c2) x (c1_l, c2_l): the sine of the angle times both norms
          cr(k) = c1(tt) * c2(l) - c2(tt) * c1(l)
          nl2(k) = c1(l)**2 + c2(l)**2
        end if
      end do
    end do
    n2 = c1(tt)**2 + c2(tt)**2
    bnd = 0.0_wp
    do k = 1, na_t
      if (nr(k) == 0) then
        bnd = max(bnd, n2)
      else if (nr(k) == 1) then
        bnd = max(bnd, cr(k)**2 / nl2(k))
      end if
    end do
  end function pivot_lower_bound
end module cr_sparse_as_factor
