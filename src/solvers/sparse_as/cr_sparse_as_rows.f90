!> The rows of the sparse dual active-set projection: normalised rows, B v - d, the velocity
!> scale and thresholds (prepare_rows), the Gram matrix M = B B^T (assemble_gram), and the
!> kernels of u = v - B_P^T lambda_P and of the slacks d - B u.
module cr_sparse_as_rows
  use cr_kinds, only: wp
  use cr_grow, only: igrow => grow_int, rgrow => grow_real, lgrow => grow_logical
  use cr_contact_set, only: contact_set_t
  use cr_sparse_as_settings, only: sparse_as_settings_t
  use cr_sparse_as_state, only: sparse_as_state_t
  implicit none
  private
  public :: prepare_rows, assemble_gram, velocities, slacks, slacks_violated, first_violated, slack_of, &
    list_slacks

contains

  !> Normalised rows, B v - d, scale, thresholds; work arrays sized (st%m, st%na set).
  subroutine prepare_rows(st, kn, cs, v, lambda, tol, warm_start)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:), lambda(:), tol
    logical, intent(in) :: warm_start
    integer :: a, b, j, m, na
    real(wp) :: x1, x2, rinv, tolv, sv
    m = st%m; na = st%na
    call rgrow(st%rn, m); call rgrow(st%dd, m); call rgrow(st%cc, m)
    call rgrow(st%lam, m); call rgrow(st%slack, m); call rgrow(st%z, m)
    call rgrow(st%rhs, m); call rgrow(st%piv, m); call rgrow(st%w, m)
    call rgrow(st%l0, m)
    call rgrow(st%md, m); call rgrow(st%gd, m); call rgrow(st%tbk, m); call rgrow(st%tl, m)
    call igrow(st%ord, m); call igrow(st%pstamp, m)
    st%pstamp(1:m) = 0; st%npsearch = 0
    st%l0(1:m) = lambda(1:m)
    call lgrow(st%act, m); call lgrow(st%refused, m); call lgrow(st%newact, m)
    call lgrow(st%inw, m)
    call igrow(st%viol, m); call igrow(st%rem, m)
    call rgrow(st%uu, 2 * na + 2)
    call rgrow(st%c1, m); call rgrow(st%c2, m)
    call igrow(st%ka, m); call igrow(st%kb, m); call igrow(st%alist, m)
    call rgrow(st%bp, m)
    st%bp(1:m) = 0.0_wp
    st%nact = 0
    tolv = max(1.0e-3_wp * tol, 256.0_wp * epsilon(1.0_wp))
    sv = tiny(1.0_wp) * 1.0e10_wp
    if (size(v) > 0) sv = max(sv, maxval(abs(v)))
    do j = 1, m
      ! the row's norm (h |g| with |g| about 1: no scaling needed) and one division
      x1 = -cs%h * cs%g(1, j); x2 = -cs%h * cs%g(2, j)
      st%rn(j) = sqrt(x1 * x1 + x2 * x2)
      if (cs%ib(j) > 0) st%rn(j) = st%rn(j) * sqrt(2.0_wp)
      rinv = 1.0_wp / st%rn(j)
      x1 = x1 * rinv; x2 = x2 * rinv
      st%c1(j) = x1; st%c2(j) = x2
      st%dd(j) = cs%gap(j) * rinv
      sv = max(sv, -st%dd(j))
      a = cs%ia(j); b = cs%ib(j)
      st%ka(j) = 2 * a - 1
      st%cc(j) = x1 * v(2*a - 1) + x2 * v(2*a)
      if (b > 0) then
        st%kb(j) = 2 * b - 1
        st%cc(j) = st%cc(j) - x1 * v(2*b - 1) - x2 * v(2*b)
      else
        st%kb(j) = 2 * na + 1
      end if
      st%cc(j) = st%cc(j) - st%dd(j)
      st%lam(j) = 0.0_wp
      if (warm_start .and. lambda(j) > 0.0_wp) st%lam(j) = lambda(j) * st%rn(j)
      st%act(j) = .false.
      st%refused(j) = .false.
    end do
    st%sv = sv
    st%thr = tolv * sv
    st%wmarg = kn%w_margin
    do j = 1, m
      st%inw(j) = kn%w_margin < 0.0_wp .or. st%lam(j) > 0.0_wp .or. &
        st%cc(j) > -kn%w_margin * sv
    end do
  end subroutine prepare_rows

  !> M = B B^T (normalised rows): full CSC (fp, fi, fv), rows sorted in each column, the
  !> diagonal of column j at fd(j) (so its upper triangle is fp(j):fd(j)).
  subroutine assemble_gram(st, cs)
    type(sparse_as_state_t), intent(inout) :: st
    type(contact_set_t), intent(in) :: cs
    integer :: a, nz, p1, j, m, na
    m = st%m; na = st%na
    ! each agent's rows (CSR astart, arows), each list closed by a sentinel row huge(1)
    call igrow(st%astart, na + 1)
    st%astart(1:na + 1) = 1
    do j = 1, m
      st%astart(cs%ia(j) + 1) = st%astart(cs%ia(j) + 1) + 1
      if (cs%ib(j) > 0) st%astart(cs%ib(j) + 1) = st%astart(cs%ib(j) + 1) + 1
    end do
    st%astart(1) = 1
    do a = 1, na
      st%astart(a + 1) = st%astart(a + 1) + st%astart(a)
    end do
    call igrow(st%arows, st%astart(na + 1))
    call rgrow(st%ae1, st%astart(na + 1)); call rgrow(st%ae2, st%astart(na + 1))
    ! fill pointers live in fp (size na + 1 at least); each agent's rows with their
    ! coefficients signed for the agent, so that M(j, l) = sum over shared agents of the
    ! products of signed coefficients
    call igrow(st%fp, max(m, na) + 1)
    st%fp(1:na) = st%astart(1:na)
    do j = 1, m
      a = cs%ia(j); p1 = st%fp(a); st%fp(a) = p1 + 1
      st%arows(p1) = j; st%ae1(p1) = st%c1(j); st%ae2(p1) = st%c2(j)
      a = cs%ib(j)
      if (a > 0) then
        p1 = st%fp(a); st%fp(a) = p1 + 1
        st%arows(p1) = j; st%ae1(p1) = -st%c1(j); st%ae2(p1) = -st%c2(j)
      end if
    end do
    do a = 1, na
      st%arows(st%astart(a + 1) - 1) = huge(1)
    end do
    ! upper bound of the entries: sum over rows of the rows of their agents
    nz = 0
    do j = 1, m
      nz = nz + st%astart(cs%ia(j) + 1) - st%astart(cs%ia(j)) - 1
      if (cs%ib(j) > 0) nz = nz + st%astart(cs%ib(j) + 1) - st%astart(cs%ib(j)) - 1
    end do
    call igrow(st%fi, nz); call rgrow(st%fv, nz)
    call igrow(st%fd, m)
    call assemble_columns(m, cs%ia, cs%ib, st%c1, st%c2, st%astart, st%arows, &
      st%ae1, st%ae2, st%fp, st%fi, st%fv, st%fd, nz, st%nzu)
    st%fp(m + 1) = nz + 1
  end subroutine assemble_gram

  !> uu = v - B_P^T lambda_P, slack = d - B uu (normalised rows).
  subroutine slacks(st, v)
    type(sparse_as_state_t), intent(inout) :: st
    real(wp), intent(in) :: v(:)
    call velocities(st, v)
    call all_slacks(st%m, st%ka, st%kb, st%c1, st%c2, st%dd, st%uu, st%slack)
  end subroutine slacks

  !> uu = v - B_P^T lambda_P (normalised rows).
  subroutine velocities(st, v)
    type(sparse_as_state_t), intent(inout) :: st
    real(wp), intent(in) :: v(:)
    call active_velocities(st%nact, st%alist, st%ka, st%kb, st%c1, st%c2, &
      st%lam, 2 * st%na, v, st%uu)
  end subroutine velocities

  !> Columns of M = B B^T (assemble_gram): column j (signed + for its first agent a,
  !> - for its second b) is the rows of a (a wall row), or the merge of the rows of a and of b
  !> (each list sorted by row and closed by the sentinel huge(1)), a row met in both (the
  !> same pair twice) summed: sorted columns without marks or sorting. fd(j): position of
  !> the diagonal; nz: entries; nzu: entries of the upper triangle. (Explicit-shape arrays:
  !> in the solver's own arrays the compiler reloaded every descriptor after each store.)
  pure subroutine assemble_columns(m, ia, ib, c1, c2, astart, arows, ae1, ae2, fp, fi, fv, fd, nz, nzu)
    integer, intent(in) :: m, ia(m), ib(m), astart(*), arows(*)
    real(wp), intent(in) :: c1(m), c2(m), ae1(*), ae2(*)
    integer, intent(inout) :: fp(*), fi(*), fd(m)
    real(wp), intent(inout) :: fv(*)
    integer, intent(out) :: nz, nzu
    integer :: j, a, b, l, p1, p2, e1, r1, r2
    real(wp) :: x1, x2
    nz = 0; nzu = 0
    do j = 1, m
      fp(j) = nz + 1
      a = ia(j); b = ib(j)
      x1 = c1(j); x2 = c2(j)
      p1 = astart(a)
      if (b == 0) then
        e1 = astart(a + 1) - 2
        do p1 = p1, e1
          l = arows(p1)
          nz = nz + 1
          fi(nz) = l; fv(nz) = x1 * ae1(p1) + x2 * ae2(p1)
          if (l == j) fd(j) = nz
        end do
      else
        p2 = astart(b)
        r1 = arows(p1); r2 = arows(p2)
        do
          nz = nz + 1
          if (r1 < r2) then
            fi(nz) = r1; fv(nz) = x1 * ae1(p1) + x2 * ae2(p1)
            p1 = p1 + 1; r1 = arows(p1)
          else if (r2 < r1) then
            fi(nz) = r2; fv(nz) = -(x1 * ae1(p2) + x2 * ae2(p2))
            p2 = p2 + 1; r2 = arows(p2)
          else if (r1 == huge(1)) then
            nz = nz - 1; exit
          else
            fi(nz) = r1
            fv(nz) = (x1 * ae1(p1) + x2 * ae2(p1)) - (x1 * ae1(p2) + x2 * ae2(p2))
            if (r1 == j) fd(j) = nz
            p1 = p1 + 1; r1 = arows(p1)
            p2 = p2 + 1; r2 = arows(p2)
          end if
        end do
      end if
      nzu = nzu + fd(j) - fp(j) + 1
    end do
  end subroutine assemble_columns

  !> uu = v - sum over the rows j of P (list alist(1:nact), in increasing order) of lam_j b_j
  !> (normalised rows by components c1, c2, velocity positions ka, kb of their agents: see
  !> sparse_as_state_t); uu [n + 2], v [n], uu(n + 1:n + 2) (wall rows' second agent) zero.
  pure subroutine active_velocities(nact, alist, ka, kb, c1, c2, lam, n, v, uu)
    integer, intent(in) :: nact, n
    integer, intent(in) :: alist(*), ka(*), kb(*)
    real(wp), intent(in) :: c1(*), c2(*), lam(*), v(n)
    real(wp), intent(inout) :: uu(n + 2)
    integer :: q, j, a, b
    real(wp) :: t1, t2
    uu(1:n) = v
    do q = 1, nact
      j = alist(q)
      t1 = lam(j) * c1(j); t2 = lam(j) * c2(j)
      a = ka(j); b = kb(j)
      uu(a) = uu(a) - t1; uu(a + 1) = uu(a + 1) - t2
      uu(b) = uu(b) + t1; uu(b + 1) = uu(b + 1) + t2
    end do
    ! the wall rows' slot took their updates: zero again (only ever read as zero)
    uu(n + 1:n + 2) = 0.0_wp
  end subroutine active_velocities

  !> slack_j = d_j - b_j . uu for every row [m] (as active_velocities).
  pure subroutine all_slacks(m, ka, kb, c1, c2, dd, uu, slack)
    integer, intent(in) :: m
    integer, intent(in) :: ka(m), kb(m)
    real(wp), intent(in) :: c1(m), c2(m), dd(m), uu(*)
    real(wp), intent(inout) :: slack(m)
    integer :: j
    do j = 1, m
      slack(j) = slack_of(j, ka, kb, c1, c2, dd, uu)
    end do
  end subroutine all_slacks

  !> slack_j = d_j - b_j . uu for every row [m] (as all_slacks), and the rows violated
  !> (slack_j < -thr) outside P (act) and not refused, in increasing order: viol(1:nv).
  pure subroutine slacks_violated(m, ka, kb, c1, c2, dd, uu, thr, act, refused, slack, nv, viol)
    integer, intent(in) :: m
    integer, intent(in) :: ka(m), kb(m)
    real(wp), intent(in) :: c1(m), c2(m), dd(m), uu(*), thr
    logical, intent(in) :: act(m), refused(m)
    real(wp), intent(inout) :: slack(m)
    integer, intent(out) :: nv
    integer, intent(inout) :: viol(*)
    integer :: j
    real(wp) :: r
    nv = 0
    do j = 1, m
      r = slack_of(j, ka, kb, c1, c2, dd, uu)
      slack(j) = r
      if (r < -thr) then
        if (.not. (act(j) .or. refused(j))) then
          nv = nv + 1; viol(nv) = j
        end if
      end if
    end do
  end subroutine slacks_violated

  !> slack_j = d_j - b_j . uu for the rows of the list alist(1:nact) (as all_slacks).
  pure subroutine list_slacks(nact, alist, ka, kb, c1, c2, dd, uu, slack)
    integer, intent(in) :: nact, alist(*), ka(*), kb(*)
    real(wp), intent(in) :: c1(*), c2(*), dd(*), uu(*)
    real(wp), intent(inout) :: slack(*)
    integer :: q, jj
    do q = 1, nact
      jj = alist(q)
      slack(jj) = slack_of(jj, ka, kb, c1, c2, dd, uu)
    end do
  end subroutine list_slacks

  !> The first row j with slack_j < -thr (as all_slacks), 0 if none.
  pure integer function first_violated(m, ka, kb, c1, c2, dd, uu, thr) result(jv)
    integer, intent(in) :: m
    integer, intent(in) :: ka(m), kb(m)
    real(wp), intent(in) :: c1(m), c2(m), dd(m), uu(*), thr
    integer :: j
    jv = 0
    do j = 1, m
      if (slack_of(j, ka, kb, c1, c2, dd, uu) < -thr) then
        jv = j; return
      end if
    end do
  end function first_violated

  !> slack_j = d_j - b_j . uu of row j (normalised rows by components c1, c2, velocity
  !> positions ka, kb of the row's agents; a wall row's kb is uu's zero slot): the one formula
  !> of the slack kernels.
  pure real(wp) function slack_of(j, ka, kb, c1, c2, dd, uu) result(r)
    integer, intent(in) :: j, ka(*), kb(*)
    real(wp), intent(in) :: c1(*), c2(*), dd(*), uu(*)
    r = c1(j) * uu(ka(j)) + c2(j) * uu(ka(j) + 1)
    r = r - c1(j) * uu(kb(j)) - c2(j) * uu(kb(j) + 1)
    r = dd(j) - r
  end function slack_of
end module cr_sparse_as_rows
