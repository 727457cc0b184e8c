!> The step back of the sparse dual active-set projection: lambda moves towards the minimiser z
!> on P until z > 0, by projected searches along max(0, lambda + t (z - lambda)) (past every
!> breakpoint where f still falls) or to the first breakpoint; the rows reaching zero leave P
!> (except the violated ones kept by keep_violated).
module cr_sparse_as_search
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_sparse_as_settings, only: sparse_as_settings_t
  use cr_sparse_as_state, only: sparse_as_state_t
  use cr_sparse_as_rows, only: velocities, list_slacks
  use cr_sparse_as_lists, only: copy_on_list, nonpositive_on_p, lam_from_z
  use cr_sparse_as_factor, only: solve_p, remove_rows
  implicit none
  private
  public :: step_back, drop_nonpositive

contains

  !> Move lambda towards the minimiser z on P until z > 0 (rows reaching zero leave P, except
  !> the violated ones kept by keep_violated in the first keep_searches searches).
  !> fresh: uu and the slacks are those of lambda on entry (no need to compute them again).
  !> st%why is set when the iteration cap is reached; iterations counts the steps.
  subroutine step_back(st, kn, v, fresh, have_z, iterations, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    real(wp), intent(in) :: v(:)
    logical, intent(in) :: fresh
    !> z already holds the minimiser on P
    logical, intent(in) :: have_z
    integer, intent(inout) :: iterations
    type(error_t), allocatable, intent(inout) :: error
    real(wp) :: alpha
    integer :: nsearch
    logical :: have_u, zok, done
    have_u = fresh
    nsearch = 0
    zok = have_z
    do
      if (.not. zok) then
        call solve_p(st, error); if (allocated(error)) return
      end if
      zok = .false.
      alpha = step_length(st)
      if (alpha >= 1.0_wp) then
        call copy_on_list(st%nact, st%alist, st%z, st%lam)
        return
      end if
      if (st%it >= st%itmax) then
        st%why = "iteration cap " // str(st%itmax) // " reached"
        return
      end if
      st%it = st%it + 1
      iterations = iterations + 1
      if (kn%proj_search) then
        call projected_step(st, v, have_u, kn%keep_violated .and. nsearch < kn%keep_searches)
        if (allocated(error)) return
        nsearch = nsearch + 1
        have_u = .false.
        call after_search(st, kn, zok, done, error); if (allocated(error)) return
        if (done) cycle
      end if
      call classical_step(st, alpha)
      call remove_rows(st, kn, st%nv, error); if (allocated(error)) return
    end do
  end subroutine step_back

  !> The largest alpha <= 1 with lambda + alpha (z - lambda) >= 0 on P (a row at zero with
  !> z <= 0 blocks at once: alpha = 0).
  real(wp) function step_length(st) result(alpha)
    type(sparse_as_state_t), intent(in) :: st
    integer :: q, jj
    real(wp) :: r
    alpha = 1.0_wp
    do q = 1, st%nact
      jj = st%alist(q)
      if (st%z(jj) <= 0.0_wp) then
        ! a row at zero (lambda = 0, e.g. entered with z = 0) blocks at once: alpha = 0
        r = 0.0_wp
        if (st%lam(jj) > 0.0_wp) r = st%lam(jj) / (st%lam(jj) - st%z(jj))
        alpha = min(alpha, r)
      end if
    end do
  end function step_length

  !> After a projected search: done when the step back goes on with the next search (only
  !> kept rows reached zero: solve again on P; or the frozen rows left P). One row leaving
  !> alone gives the minimiser on P without it from the one on P by a column of the inverse,
  !> z - (z_k / (M_P^{-1})_kk) M_P^{-1} e_k (half a solve less; zok).
  subroutine after_search(st, kn, zok, done, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    logical, intent(inout) :: zok
    logical, intent(out) :: done
    type(error_t), allocatable, intent(inout) :: error
    integer :: jj, q, i1
    real(wp) :: r
    done = .true.
    if (st%nv == 0 .and. st%nkept > 0) return
    if (st%nv == 1 .and. st%nkept == 0) then
      jj = st%viol(1)
      call st%chol%unit_solve(jj, st%rhs(1:st%m), r, error); if (allocated(error)) return
      r = st%z(jj) / r
      do q = 1, st%nact
        i1 = st%alist(q); st%z(i1) = st%z(i1) - r * st%rhs(i1)
      end do
      st%z(jj) = 0.0_wp
      zok = .true.
    end if
    if (st%nv > 0) then
      call remove_rows(st, kn, st%nv, error)
      return
    end if
    done = .false.
  end subroutine after_search

  !> The classical step to the first breakpoint: lambda += alpha (z - lambda) on P; the rows
  !> reaching zero (or, by round-off, the one that defined alpha) in viol(1:nv).
  subroutine classical_step(st, alpha)
    type(sparse_as_state_t), intent(inout) :: st
    real(wp), intent(in) :: alpha
    integer :: q, jj
    real(wp) :: lmax
    lmax = 0.0_wp
    do q = 1, st%nact
      jj = st%alist(q)
      st%lam(jj) = st%lam(jj) + alpha * (st%z(jj) - st%lam(jj))
      lmax = max(lmax, st%lam(jj))
    end do
    st%nv = 0
    do q = 1, st%nact
      jj = st%alist(q)
      if (st%z(jj) <= 0.0_wp .and. st%lam(jj) <= 64.0_wp * epsilon(1.0_wp) * lmax) then
        st%lam(jj) = 0.0_wp
        st%nv = st%nv + 1; st%viol(st%nv) = jj
      end if
    end do
    if (st%nv == 0) then
      ! round-off: take out the row that defined alpha
      do q = 1, st%nact
        jj = st%alist(q)
        if (st%z(jj) <= 0.0_wp) then
          if (st%lam(jj) <= 0.0_wp .or. st%nv == 0) then
            if (st%nv == 0) then
              st%nv = 1; st%viol(1) = jj
            else if (st%lam(jj) < st%lam(st%viol(1))) then
              st%viol(1) = jj
            end if
          end if
        end if
      end do
      st%lam(st%viol(1)) = 0.0_wp
    end if
  end subroutine classical_step

  !> Projected search from lambda (feasible, zero off P) towards the minimiser z on P (some
  !> z_j <= 0): f along the path lambda(t) = max(0, lambda + t d), d = z - lambda, t in [0, 1],
  !> is a convex piecewise quadratic whose pieces end where a row reaches zero (breakpoints
  !> t_j = lambda_j / (lambda_j - z_j), sorted). Walk the pieces while f still falls; at each
  !> breakpoint the row is frozen at zero (d_j = 0; M d and the slope are updated from column
  !> j of M). lambda becomes lambda(t*), the frozen rows are returned in viol(1:nv) (they
  !> leave P). f(lambda(t*)) <= f at the first breakpoint (the classical step), so the
  !> method stays monotone and finite. nv = 0 (round-off: no descent) leaves lambda as is.
  !> have_u: st%slack already holds the slacks at lambda. keep: frozen rows that had
  !> lambda > 0 when the search began and are violated at lambda(t*) (slack = gradient there
  !> below -thr) stay in P at zero (nkept of them; the next solve on P includes them, and a
  !> row at zero with z <= 0 then leaves at once, never kept again).
  subroutine projected_step(st, v, have_u, keep)
    type(sparse_as_state_t), intent(inout) :: st
    real(wp), intent(in) :: v(:)
    logical, intent(in) :: have_u, keep
    integer :: q, jj, nb, kb, ps
    real(wp) :: ts, lmax
    ! d = z - lambda on P (in st%w); the gradient g = M lambda - c on P is the slack of the
    ! rows at u(lambda), and M d = M_P z - M_P lambda = -g on P (z solves M_P z = c_P)
    if (.not. have_u) then
      call velocities(st, v)
      call list_slacks(st%nact, st%alist, st%ka, st%kb, st%c1, st%c2, st%dd, st%uu, st%slack)
    end if
    st%nkept = 0
    ! gd = slack, md = -slack, tl = 0 on P, set when a row is first met in the walk (ps)
    st%npsearch = st%npsearch + 1
    ps = st%npsearch
    call walk_breakpoints(st, ps, nb, kb, ts)
    st%nv = 0
    if (kb == 0) return
    ! lambda(t*): frozen rows (and rows that reach zero at t* by round-off) leave
    call move_on_list(st%nact, st%alist, st%lam, st%w, ts, lmax)
    do q = 1, kb
      st%lam(st%ord(q)) = 0.0_wp
    end do
    st%n_proj = st%n_proj + 1
    do q = 1, st%nact
      jj = st%alist(q)
      if (st%z(jj) <= 0.0_wp .and. st%lam(jj) <= 64.0_wp * epsilon(1.0_wp) * lmax) then
        st%lam(jj) = 0.0_wp
        st%nv = st%nv + 1; st%viol(st%nv) = jj
      end if
    end do
    if (keep) call keep_violated_rows(st, ps, ts)
    st%n_proj_rows = st%n_proj_rows + st%nv
  end subroutine projected_step

  !> projected_step's walk: from t = 0 along the sorted breakpoints (ord(1:nb)) while the slope
  !> of f stays negative; kb rows frozen, ts the step found.
  subroutine walk_breakpoints(st, ps, nb, kb, ts)
    type(sparse_as_state_t), intent(inout) :: st
    integer, intent(in) :: ps
    integer, intent(out) :: nb, kb
    real(wp), intent(out) :: ts
    integer :: q, p1, p2, l, i
    real(wp) :: sl, qq, ta, tn, dj
    call search_start(st%nact, st%alist, st%z, st%lam, st%slack, st%w, st%ord, &
      st%tbk, sl, nb)
    qq = -sl
    ta = 0.0_wp; kb = 0; ts = 0.0_wp
    do
      tn = 1.0_wp
      if (kb < nb) then
        ! next breakpoint: the smallest left (selection: the walk usually stops after a few)
        p2 = kb + 1
        do p1 = kb + 2, nb
          if (st%tbk(st%ord(p1)) < st%tbk(st%ord(p2))) p2 = p1
        end do
        l = st%ord(p2); st%ord(p2) = st%ord(kb + 1); st%ord(kb + 1) = l
        tn = min(1.0_wp, st%tbk(l))
      end if
      if (.not. (sl < 0.0_wp)) then
        ts = ta; exit
      end if
      if (qq > 0.0_wp) then
        if (ta - sl / qq <= tn) then
          ts = ta - sl / qq; exit
        end if
      end if
      if (kb >= nb .or. tn >= 1.0_wp) then
        ts = tn; exit
      end if
      ! move to the breakpoint, freeze its row: the slope there with d, then without d_l;
      ! the gradient of a row is brought up to date (gd + (t - tl) M d) only when its M d
      ! changes, so that a breakpoint costs one column of M
      sl = sl + (tn - ta) * qq
      kb = kb + 1
      l = st%ord(kb)
      if (st%pstamp(l) /= ps) then
        st%gd(l) = st%slack(l); st%md(l) = -st%slack(l); st%tl(l) = 0.0_wp
        st%pstamp(l) = ps
      end if
      dj = st%w(l)
      sl = sl - dj * (st%gd(l) + (tn - st%tl(l)) * st%md(l))
      ! q' = (d - dj e_l)' M (d - dj e_l) = q - 2 dj (M d)_l + dj^2 M_ll, then M d -= dj M(:, l)
      qq = qq - 2.0_wp * dj * st%md(l)
      do q = st%fp(l), st%fp(l + 1) - 1
        i = st%fi(q)
        if (i == l) qq = qq + dj * dj * st%fv(q)
        if (st%act(i)) then
          if (st%pstamp(i) /= ps) then
            st%gd(i) = st%slack(i); st%md(i) = -st%slack(i); st%tl(i) = 0.0_wp
            st%pstamp(i) = ps
          end if
          st%gd(i) = st%gd(i) + (tn - st%tl(i)) * st%md(i)
          st%tl(i) = tn
          st%md(i) = st%md(i) - dj * st%fv(q)
        end if
      end do
      st%w(l) = 0.0_wp
      ta = tn
    end do
  end subroutine walk_breakpoints

  !> keep_violated: of the frozen rows viol(1:nv), those violated at lambda(t*) (the gradient
  !> gd + (t* - tl) M d; a row the walk did not meet: slack + t* (-slack)) that were positive
  !> when the search began (tbk > 0) stay in P at zero (nkept); the others remain in viol.
  subroutine keep_violated_rows(st, ps, ts)
    type(sparse_as_state_t), intent(inout) :: st
    integer, intent(in) :: ps
    real(wp), intent(in) :: ts
    integer :: q, jj, p1
    real(wp) :: r
    p1 = 0
    do q = 1, st%nv
      jj = st%viol(q)
      if (st%pstamp(jj) == ps) then
        r = st%gd(jj) + (ts - st%tl(jj)) * st%md(jj)
      else
        r = st%slack(jj) * (1.0_wp - ts)
      end if
      if (r < -st%thr .and. st%tbk(jj) > 0.0_wp) then
        st%nkept = st%nkept + 1
      else
        p1 = p1 + 1; st%viol(p1) = jj
      end if
    end do
    st%nv = p1
    st%n_kept = st%n_kept + st%nkept
  end subroutine keep_violated_rows

  !> The minimiser z on P; rows with z <= 0 leave P until none is left, then lambda = z on P
  !> (zero elsewhere).
  subroutine drop_nonpositive(st, kn, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(error_t), allocatable, intent(inout) :: error
    do
      call solve_p(st, error); if (allocated(error)) return
      call nonpositive_on_p(st, st%z)
      if (st%nv == 0) exit
      call remove_rows(st, kn, st%nv, error); if (allocated(error)) return
    end do
    call lam_from_z(st)
  end subroutine drop_nonpositive

  !> projected_step's start: d = z - lambda on the list of P (into w), the slope
  !> sl = slack' d, and the rows with z <= 0 (ord(1:nb)) with their breakpoints tbk.
  pure subroutine search_start(nact, alist, z, lam, slack, w, ord, tbk, sl, nb)
    integer, intent(in) :: nact, alist(nact)
    real(wp), intent(in) :: z(*), lam(*), slack(*)
    real(wp), intent(inout) :: w(*), tbk(*)
    integer, intent(inout) :: ord(*)
    real(wp), intent(out) :: sl
    integer, intent(out) :: nb
    integer :: q, jj
    sl = 0.0_wp; nb = 0
    do q = 1, nact
      jj = alist(q)
      w(jj) = z(jj) - lam(jj)
      sl = sl + slack(jj) * w(jj)
      if (z(jj) <= 0.0_wp) then
        nb = nb + 1; ord(nb) = jj
        if (lam(jj) > 0.0_wp) then
          tbk(jj) = lam(jj) / (lam(jj) - z(jj))
        else
          tbk(jj) = 0.0_wp
        end if
      end if
    end do
  end subroutine search_start

  !> lam = max(0, lam + t w) on the list of P; lmax its largest value there.
  pure subroutine move_on_list(nact, alist, lam, w, t, lmax)
    integer, intent(in) :: nact, alist(nact)
    real(wp), intent(inout) :: lam(*)
    real(wp), intent(in) :: w(*), t
    real(wp), intent(out) :: lmax
    integer :: q, jj
    lmax = 0.0_wp
    do q = 1, nact
      jj = alist(q)
      lam(jj) = max(0.0_wp, lam(jj) + t * w(jj))
      lmax = max(lmax, lam(jj))
    end do
  end subroutine move_on_list
end module cr_sparse_as_search
