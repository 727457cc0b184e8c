!> Edge-case tests of cr_nnls, the dense NNLS / LDP kernel of the online reduced model.
!>
!> 1. nnls_solve against exhaustive enumeration of passive sets on seeded random problems
!>    (m, n <= 6), with the KKT certificate and the reported statistics recomputed from x.
!> 2. nnls_solve edge cases: duplicate / near-duplicate / zero columns, b = 0, b in the negative
!>    cone, m = 0, n = 0, rank-deficient passive sets, bad scaling, ill-conditioning, warm start
!>    from wrong guesses, iteration cap.
!> 3. ldp_solve against enumeration of active constraint sets; degenerate and zero rows,
!>    mc = 0, feasible v, infeasible systems (least-violation point), near-infeasible feasible
!>    systems, bad scaling, warm start from a wrong lambda, LDP KKT conditions.
!> 4. Non-finite input is an error; iteration caps end every solve.
program test_nnls_edge
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_positive_inf
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_random, only: rng_t
  use cr_strings, only: str
  use cr_assert, only: check, check_close, test_summary
  use cr_nnls, only: nnls_solve, nnls_stats_t, nnls_work_t, ldp_solve, ldp_stats_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  real(wp), parameter :: eps = epsilon(1.0_wp)
  !> relative tolerance of the enumeration's dependence test
  real(wp), parameter :: dep_tol = 1.0e-9_wp
  type(rng_t) :: rng
  type(nnls_work_t) :: work

  call rng%seed(20240611)
  call test_nnls_enumeration()
  call test_nnls_columns()
  call test_nnls_trivial()
  call test_nnls_rank_deficient()
  call test_nnls_ill_conditioned()
  call test_nnls_consistent_family()
  call test_nnls_scaling()
  call test_nnls_warm()
  call test_nnls_cap()
  call test_ldp_enumeration()
  call test_ldp_degenerate()
  call test_ldp_infeasible()
  call test_ldp_near_infeasible()
  call test_ldp_scaling()
  call test_ldp_warm_and_cap()
  call test_non_finite()
  call test_summary()

contains

  ! ------------------------------------------------------------------ random data

  !> standard normal matrix
  subroutine randn(a)
    real(wp), intent(out) :: a(:,:)
    integer :: i, j
    do j = 1, size(a, 2)
      do i = 1, size(a, 1)
        a(i, j) = rng%normal()
      end do
    end do
  end subroutine randn

  !> standard normal vector [n]
  function randv(n) result(v)
    integer, intent(in) :: n
    real(wp) :: v(n)
    integer :: i
    do i = 1, n
      v(i) = rng%normal()
    end do
  end function randv

  !> uniform integer in [lo, hi]
  integer function randint(lo, hi)
    integer, intent(in) :: lo, hi
    randint = lo + min(hi - lo, int(rng%uniform() * real(hi - lo + 1, wp)))
  end function randint

  ! ------------------------------------------------------------------ reference solvers

  !> Thin QR of the columns idx of a by modified Gram-Schmidt with one re-orthogonalisation:
  !> a(:, idx) = q r. ok = .false. when a column is dependent on the previous ones (its new
  !> diagonal is below tol times its norm; zero columns are always dependent).
  subroutine subset_qr(a, idx, q, r, ok, tol)
    real(wp), intent(in) :: a(:,:)
    integer, intent(in) :: idx(:)
    real(wp), intent(out) :: q(:,:), r(:,:)
    logical, intent(out) :: ok
    real(wp), intent(in) :: tol
    real(wp) :: y(size(a, 1)), s
    integer :: k, j, pass
    ok = .false.
    if (size(idx) > size(a, 1)) return
    r = 0.0_wp
    q = 0.0_wp
    do k = 1, size(idx)
      y = a(:, idx(k))
      do pass = 1, 2
        do j = 1, k - 1
          s = dot_product(q(:, j), y)
          r(j, k) = r(j, k) + s
          y = y - s * q(:, j)
        end do
      end do
      r(k, k) = norm2(y)
      if (r(k, k) <= tol * norm2(a(:, idx(k)))) return
      q(:, k) = y / r(k, k)
    end do
    ok = .true.
  end subroutine subset_qr

  !> Unconstrained least squares on the columns idx: c = argmin |a(:, idx) c - b|.
  subroutine subset_ls(a, b, idx, c, ok, tol)
    real(wp), intent(in) :: a(:,:), b(:)
    integer, intent(in) :: idx(:)
    real(wp), intent(out) :: c(:)
    logical, intent(out) :: ok
    real(wp), intent(in) :: tol
    real(wp) :: q(size(a, 1), size(idx)), r(size(idx), size(idx)), y(size(a, 1))
    integer :: k, p
    p = size(idx)
    call subset_qr(a, idx, q, r, ok, tol)
    if (.not. ok) return
    y = b
    do k = 1, p
      c(k) = dot_product(q(:, k), y)
      y = y - c(k) * q(:, k)
    end do
    do k = p, 1, -1
      c(k) = (c(k) - dot_product(r(k, k + 1:p), c(k + 1:p))) / r(k, k)
    end do
  end subroutine subset_ls

  !> Optimal NNLS residual norm by enumeration of all passive sets: the unconstrained least
  !> squares on each, kept when feasible (c >= 0). Sets with dependent columns are skipped:
  !> an optimal x with independent passive columns always exists (Caratheodory).
  real(wp) function enum_nnls(a, b, tol) result(best)
    real(wp), intent(in) :: a(:,:), b(:)
    !> dependence tolerance (default dep_tol)
    real(wp), intent(in), optional :: tol
    integer :: n, mask, cnt, j, idx(size(a, 2))
    real(wp) :: c(size(a, 2)), r(size(a, 1)), t
    logical :: ok
    n = size(a, 2)
    t = dep_tol
    if (present(tol)) t = tol
    best = norm2(b)
    do mask = 1, 2**n - 1
      cnt = 0
      do j = 1, n
        if (btest(mask, j - 1)) then
          cnt = cnt + 1
          idx(cnt) = j
        end if
      end do
      call subset_ls(a, b, idx(1:cnt), c(1:cnt), ok, t)
      if (.not. ok) cycle
      if (any(c(1:cnt) < 0.0_wp)) cycle
      r = b
      do j = 1, cnt
        r = r - c(j) * a(:, idx(j))
      end do
      best = min(best, norm2(r))
    end do
  end function enum_nnls

  !> Projection of v on {u : bm(idx, :) u = d(idx)} (rows idx independent):
  !> u = v - bm(idx,:)^T mu. ok = .false. for dependent rows.
  subroutine affine_projection(bm, d, v, idx, u, mu, ok)
    real(wp), intent(in) :: bm(:,:), d(:), v(:)
    integer, intent(in) :: idx(:)
    real(wp), intent(out) :: u(:), mu(:)
    logical, intent(out) :: ok
    real(wp) :: bt(size(bm, 2), size(bm, 1)), q(size(bm, 2), size(idx)), r(size(idx), size(idx))
    real(wp) :: t(size(idx))
    integer :: k, p
    p = size(idx)
    u = v
    ok = .true.
    if (p == 0) return
    bt = transpose(bm)
    call subset_qr(bt, idx, q, r, ok, dep_tol)
    if (.not. ok) return
    ! B_S = R^T Q^T; B_S (v - Q t) = d_S  <=>  R^T t = B_S v - d_S
    do k = 1, p
      t(k) = (dot_product(bm(idx(k), :), v) - d(idx(k)) - dot_product(r(1:k - 1, k), t(1:k - 1))) &
        / r(k, k)
    end do
    u = v - matmul(q, t)
    ! mu = R^{-1} t
    do k = p, 1, -1
      mu(k) = (t(k) - dot_product(r(k, k + 1:p), mu(k + 1:p))) / r(k, k)
    end do
  end subroutine affine_projection

  !> Projection of v on {u : bm u <= d} by enumeration of the active sets: for every set S of
  !> independent rows, the projection on {B_S u = d_S}; kept when it satisfies the KKT
  !> conditions (feasible, mu >= 0) to a loose tolerance; the closest to v wins. The KKT
  !> point is unique, so every kept candidate is the projection up to that tolerance.
  subroutine enum_ldp(bm, d, v, uref, found)
    real(wp), intent(in) :: bm(:,:), d(:), v(:)
    real(wp), intent(out) :: uref(:)
    logical, intent(out) :: found
    integer :: mc, mask, cnt, l, idx(size(bm, 1))
    real(wp) :: u(size(v)), mu(size(bm, 1)), best, tol
    logical :: ok
    mc = size(bm, 1)
    found = .false.
    best = huge(1.0_wp)
    uref = v
    do mask = 0, 2**mc - 1
      cnt = 0
      do l = 1, mc
        if (btest(mask, l - 1)) then
          cnt = cnt + 1
          idx(cnt) = l
        end if
      end do
      call affine_projection(bm, d, v, idx(1:cnt), u, mu(1:cnt), ok)
      if (.not. ok) cycle
      if (cnt > 0) then
        if (any(mu(1:cnt) < -1.0e-10_wp * (1.0_wp + maxval(abs(mu(1:cnt)))))) cycle
      end if
      ok = .true.
      do l = 1, mc
        tol = 1.0e-10_wp * (sum(abs(bm(l, :))) * maxval(abs(u)) + abs(d(l)))
        if (dot_product(bm(l, :), u) - d(l) > tol) ok = .false.
      end do
      if (.not. ok) cycle
      if (norm2(u - v) < best) then
        best = norm2(u - v)
        uref = u
        found = .true.
      end if
    end do
  end subroutine enum_ldp

  ! ------------------------------------------------------------------ generic checks

  !> Checks of one NNLS result: x >= 0; the reported residual, w_active_max, w_passive_max,
  !> kkt_rel and n_passive equal the values recomputed here from x (relative 1e-10 or at the
  !> rounding level 64 eps of the data scale); the KKT certificate with relative tolerance
  !> kkt_tol (skipped when kkt_tol <= 0, e.g. after an iteration cap); and, given the
  !> optimal residual norm ref, the objective |A x - b|^2 to relative 1e-10 (the scale is
  !> floored at sqrt(eps) |b|^2 so that exact fits, objective 0, compare at rounding level),
  !> or to the rounding level 16 eps sc (|r| + ref) of the objective itself, sc = |b| +
  !> sum_j |a_j| x_j, which only matters when x is much larger than b (ill-conditioned A:
  !> neither the solver nor the enumeration can resolve the objective better than that).
  subroutine check_nnls(a, b, x, st, name, kkt_tol, ref)
    real(wp), intent(in) :: a(:,:), b(:), x(:)
    type(nnls_stats_t), intent(in) :: st
    character(len=*), intent(in) :: name
    real(wp), intent(in) :: kkt_tol
    real(wp), intent(in), optional :: ref
    real(wp) :: r(size(a, 1)), w(size(a, 2)), cn(size(a, 2))
    real(wp) :: bn, sc, res, wact, wpas, krel, viol, f, fref, cmax
    integer :: j, npas
    logical :: ok
    bn = norm2(b)
    do j = 1, size(a, 2)
      cn(j) = norm2(a(:, j))
    end do
    sc = bn + sum(cn * x)
    cmax = 0.0_wp
    if (size(a, 2) > 0) cmax = maxval(cn)
    r = b - matmul(a, x)
    w = matmul(transpose(a), r)
    res = norm2(r)
    wact = 0.0_wp; wpas = 0.0_wp; krel = 0.0_wp; npas = 0
    ok = .true.
    do j = 1, size(a, 2)
      if (cn(j) == 0.0_wp) then
        ok = ok .and. x(j) == 0.0_wp
        cycle
      end if
      if (x(j) > 0.0_wp) then
        npas = npas + 1
        viol = abs(w(j))
        wpas = max(wpas, viol)
      else
        viol = max(w(j), 0.0_wp)
        wact = max(wact, viol)
      end if
      if (bn > 0.0_wp) krel = max(krel, viol / (cn(j) * bn))
    end do
    call check(all(x >= 0.0_wp), name // ": x >= 0")
    call check(ok, name // ": x = 0 on zero columns")
    if (kkt_tol > 0.0_wp) then
      ok = .true.
      do j = 1, size(a, 2)
        if (x(j) > 0.0_wp) then
          ok = ok .and. abs(w(j)) <= kkt_tol * cn(j) * sc
        else
          ok = ok .and. w(j) <= kkt_tol * cn(j) * sc
        end if
      end do
      call check(ok, name // ": KKT certificate (w <= tol active, |w| <= tol passive)")
      call check(st%kkt_rel <= kkt_tol * max(1.0_wp, sc / max(bn, tiny(1.0_wp))), &
        name // ": reported kkt_rel small")
    end if
    call check_close(st%residual, res, max(1.0e-10_wp * res, 64.0_wp * eps * sc), &
      name // ": reported residual = |b - A x|")
    call check_close(st%w_active_max, wact, 64.0_wp * eps * cmax * sc, &
      name // ": reported w_active_max")
    call check_close(st%w_passive_max, wpas, 64.0_wp * eps * cmax * sc, &
      name // ": reported w_passive_max")
    call check_close(st%kkt_rel, krel, 64.0_wp * eps * sc / max(bn, tiny(1.0_wp)), &
      name // ": reported kkt_rel")
    call check(st%n_passive == npas, name // ": reported n_passive = count(x > 0)")
    if (present(ref)) then
      f = res**2
      fref = ref**2
      call check_close(f, fref, max(1.0e-10_wp * max(fref, sqrt(eps) * bn**2), &
        16.0_wp * eps * sc * (res + ref)), name // ": objective = enumeration")
    end if
  end subroutine check_nnls

  !> nnls_solve (shared work space) followed by check_nnls; expects convergence unless
  !> max_iter is given.
  subroutine solve_nnls(a, b, x, st, name, kkt_tol, ref, passive0, max_iter)
    real(wp), intent(in) :: a(:,:), b(:)
    real(wp), intent(out) :: x(:)
    type(nnls_stats_t), intent(out) :: st
    character(len=*), intent(in) :: name
    real(wp), intent(in) :: kkt_tol
    real(wp), intent(in), optional :: ref
    logical, intent(in), optional :: passive0(:)
    integer, intent(in), optional :: max_iter
    type(error_t), allocatable :: err
    x = -1.0_wp
    call nnls_solve(a, b, x, st, err, passive0=passive0, max_iter=max_iter, work=work)
    call check(.not. allocated(err), name // ": no error")
    if (allocated(err)) return
    if (.not. present(max_iter)) call check(st%converged, name // ": converged")
    call check_nnls(a, b, x, st, name, kkt_tol, ref)
  end subroutine solve_nnls

  !> KKT of the LDP min |u - v|^2, Bm u <= d at rounding level: lambda >= 0, stationarity
  !> u = v - Bm^T lambda, feasibility, complementarity (lambda_l > 0 => row l active), and the
  !> reported max_violation equals max(0, max(Bm u - d)) recomputed here. With relaxed
  !> present, d is the relaxed right-hand side of an infeasible system: the infeasible flag
  !> is expected and max_violation is left to the caller.
  subroutine check_ldp(bm, d, v, u, lam, st, name, relaxed)
    real(wp), intent(in) :: bm(:,:), d(:), v(:), u(:), lam(:)
    type(ldp_stats_t), intent(in) :: st
    character(len=*), intent(in) :: name
    logical, intent(in), optional :: relaxed
    real(wp) :: s(size(d)), gl(size(d)), stat_tol, umax, vmax, viol
    integer :: l, i
    logical :: feas, compl
    umax = 0.0_wp; vmax = 0.0_wp
    if (size(u) > 0) umax = maxval(abs(u))
    if (size(v) > 0) vmax = maxval(abs(v))
    s = matmul(bm, u) - d
    do l = 1, size(d)
      gl(l) = sum(abs(bm(l, :))) * umax + abs(d(l))
    end do
    call check(all(lam >= 0.0_wp), name // ": lambda >= 0")
    if (present(relaxed)) then
      call check(st%infeasible .eqv. relaxed, name // ": infeasible flag")
    else
      call check(.not. st%infeasible, name // ": not flagged infeasible")
    end if
    stat_tol = 0.0_wp
    do i = 1, size(u)
      stat_tol = max(stat_tol, sum(abs(bm(:, i)) * lam))
    end do
    stat_tol = 1.0e-13_wp * (stat_tol + umax + vmax)
    if (size(u) > 0) call check(maxval(abs(u - v + matmul(transpose(bm), lam))) <= stat_tol, &
      name // ": stationarity u = v - Bm^T lambda")
    feas = .true.; compl = .true.
    do l = 1, size(d)
      feas = feas .and. s(l) <= 1.0e-12_wp * gl(l)
      if (lam(l) > 0.0_wp) compl = compl .and. abs(s(l)) <= 1.0e-12_wp * gl(l)
    end do
    call check(feas, name // ": primal feasibility")
    call check(compl, name // ": complementarity")
    if (present(relaxed)) return
    viol = 0.0_wp
    if (size(d) > 0) viol = max(0.0_wp, maxval(s))
    call check_close(st%max_violation, viol, 64.0_wp * eps * (maxval([gl, 0.0_wp])), &
      name // ": reported max_violation")
  end subroutine check_ldp

  !> ldp_solve (shared work space, cold start) followed by check_ldp; no error, converged.
  subroutine solve_ldp(bm, d, v, u, lam, st, name)
    real(wp), intent(in) :: bm(:,:), d(:), v(:)
    real(wp), intent(out) :: u(:), lam(:)
    type(ldp_stats_t), intent(out) :: st
    character(len=*), intent(in) :: name
    type(error_t), allocatable :: err
    lam = 0.0_wp
    call ldp_solve(bm, d, v, u, lam, st, err, work=work)
    call check(.not. allocated(err), name // ": no error")
    if (allocated(err)) return
    call check(st%nnls%converged, name // ": converged")
    call check_ldp(bm, d, v, u, lam, st, name)
  end subroutine solve_ldp

  ! ------------------------------------------------------------------ NNLS tests

  !> Requirement 1: random small problems against exhaustive enumeration. Four families:
  !> generic Gaussian, non-negative A (many bound constraints active), small integers (exact
  !> ties and exactly dependent columns), and b = A x0 + noise with a mixed-sign x0.
  subroutine test_nnls_enumeration()
    integer :: trial, m, n, i, j
    real(wp), allocatable :: a(:,:), b(:), x(:), x0(:)
    type(nnls_stats_t) :: st
    character(len=:), allocatable :: name
    do trial = 1, 400
      m = randint(1, 6); n = randint(1, 6)
      allocate(a(m, n), b(m), x(n))
      call randn(a)
      select case (mod(trial, 4))
      case (0)
        b = randv(m)
        name = "enum generic " // str(trial)
      case (1)
        a = abs(a)
        b = randv(m)
        name = "enum A >= 0 " // str(trial)
      case (2)
        do j = 1, n
          do i = 1, m
            a(i, j) = real(randint(-2, 2), wp)
          end do
        end do
        do i = 1, m
          b(i) = real(randint(-3, 3), wp)
        end do
        name = "enum integer " // str(trial)
      case default
        x0 = randv(n)
        b = matmul(a, x0) + 1.0e-3_wp * randv(m)
        name = "enum near fit " // str(trial)
      end select
      call solve_nnls(a, b, x, st, name, 1.0e-12_wp, ref=enum_nnls(a, b))
      deallocate(a, b, x)
    end do
  end subroutine test_nnls_enumeration

  !> Requirement 2: duplicate, near-duplicate and zero columns.
  subroutine test_nnls_columns()
    real(wp) :: a(6, 4), a2(6, 7), b(6), x2(7), pert(6)
    type(nnls_stats_t) :: st
    integer :: trial
    do trial = 1, 10
      call randn(a)
      b = randv(6)
      ! exact duplicates (one column three times, another twice)
      a2(:, 1:4) = a
      a2(:, 5) = a(:, 2)
      a2(:, 6) = a(:, 2)
      a2(:, 7) = a(:, 4)
      call solve_nnls(a2, b, x2, st, "duplicate columns", 1.0e-12_wp, ref=enum_nnls(a, b))
      ! near duplicates, relative difference 1e-12. The enumeration skips sets holding both
      ! copies (dependent at its 1e-9 test); the cone they span exceeds that of one copy by a
      ! relative 1e-12 only, below the 1e-10 objective tolerance.
      pert = randv(6)
      a2(:, 5) = a(:, 2) * (1.0_wp + 1.0e-12_wp * pert)
      pert = randv(6)
      a2(:, 6) = a(:, 3) * (1.0_wp + 1.0e-12_wp * pert)
      a2(:, 7) = a(:, 3) + 1.0e-12_wp * norm2(a(:, 3)) * pert / norm2(pert)
      call solve_nnls(a2, b, x2, st, "near-duplicate columns", 1.0e-12_wp, ref=enum_nnls(a2, b))
      ! zero columns are never used
      a2(:, 5) = 0.0_wp
      a2(:, 7) = 0.0_wp
      call solve_nnls(a2, b, x2, st, "zero columns", 1.0e-12_wp, ref=enum_nnls(a2, b))
      call check(x2(5) == 0.0_wp .and. x2(7) == 0.0_wp, "zero columns: x_j = 0")
    end do
    ! all columns zero: x = 0, residual |b|
    a2 = 0.0_wp
    call solve_nnls(a2, b, x2, st, "A = 0", 1.0e-12_wp, ref=norm2(b))
    call check(all(x2 == 0.0_wp) .and. st%n_passive == 0, "A = 0: x = 0")
  end subroutine test_nnls_columns

  !> Requirement 2: b = 0, b in the negative cone, empty problems.
  subroutine test_nnls_trivial()
    real(wp) :: a(5, 4), b(5), x(4), y(4), a0(0, 3), b0(0), x0(3), an(4, 0), xn(0), ae(0, 0)
    real(wp) :: be(0), xe(0)
    type(nnls_stats_t) :: st
    type(error_t), allocatable :: err
    integer :: trial
    do trial = 1, 10
      call randn(a)
      b = 0.0_wp
      call solve_nnls(a, b, x, st, "b = 0", 1.0e-12_wp, ref=0.0_wp)
      call check(all(x == 0.0_wp) .and. st%residual == 0.0_wp .and. st%kkt_rel == 0.0_wp, &
        "b = 0: x = 0 exactly")
      ! b = -A y, y >= 0, with A >= 0: A^T b = -A^T A y <= 0, so x = 0 is optimal. (For a
      ! general A, -A y need not lie in the polar cone {c : A^T c <= 0} and x = 0 may not be
      ! the answer; the positivity of A makes the requirement well posed.)
      a = abs(a)
      y = abs(randv(4))
      if (trial == 1) y(2:4) = 0.0_wp
      b = -matmul(a, y)
      call solve_nnls(a, b, x, st, "negative cone", 1.0e-12_wp, ref=norm2(b))
      call check(all(x == 0.0_wp) .and. st%n_passive == 0, "negative cone: x = 0 exactly")
    end do
    ! m = 0: nothing to fit, x = 0
    x0 = -1.0_wp
    call nnls_solve(a0, b0, x0, st, err)
    call check(.not. allocated(err), "m = 0: no error")
    call check(all(x0 == 0.0_wp) .and. st%converged .and. st%residual == 0.0_wp, &
      "m = 0: x = 0, converged, residual 0")
    ! n = 0: x is empty, residual |b|
    b = randv(5)
    call nnls_solve(an, b(1:4), xn, st, err)
    call check(.not. allocated(err) .and. st%converged, "n = 0: no error, converged")
    call check_close(st%residual, norm2(b(1:4)), 4.0_wp * eps * norm2(b(1:4)), &
      "n = 0: residual |b|")
    call nnls_solve(ae, be, xe, st, err)
    call check(.not. allocated(err) .and. st%converged .and. st%residual == 0.0_wp, "m = n = 0")
    ! inconsistent sizes are a clear error (code 2)
    call nnls_solve(a, b(1:3), x, st, err)
    call check(allocated(err), "size mismatch is an error")
    if (allocated(err)) call check(err%code == EXIT_BAD_INPUT .and. index(err%message, "nnls_solve") > 0, &
      "size mismatch: code 2, message names nnls_solve")
  end subroutine test_nnls_trivial

  !> Requirement 2: rank-deficient passive sets. The solution x need not be unique there
  !> (A x is), so only the objective (against enumeration) and KKT are tested.
  subroutine test_nnls_rank_deficient()
    real(wp) :: a(3, 6), b3(3), x6(6), u(6, 2), w(2, 6), ar(6, 6), b(6), ad(5, 4), b5(5), x4(4)
    type(nnls_stats_t) :: st
    integer :: trial
    do trial = 1, 20
      ! more columns than rows
      call randn(a)
      b3 = randv(3)
      call solve_nnls(a, b3, x6, st, "wide A", 1.0e-12_wp, ref=enum_nnls(a, b3))
      call check(st%n_passive <= 3, "wide A: at most m passive columns")
      ! rank 2, 6 columns
      call randn(u); call randn(w)
      ar = matmul(u, w)
      b = randv(6)
      call solve_nnls(ar, b, x6, st, "rank 2", 1.0e-12_wp, ref=enum_nnls(ar, b))
      ! exact fit by a rank-deficient combination
      b = ar(:, 1) + ar(:, 2) + ar(:, 5)
      call solve_nnls(ar, b, x6, st, "rank 2, exact fit", 1.0e-12_wp, ref=0.0_wp)
      ! exactly dependent column a3 = a1 + a2
      call randn(ad)
      ad(:, 3) = ad(:, 1) + ad(:, 2)
      b5 = randv(5)
      if (trial <= 5) b5 = ad(:, 3) + 0.1_wp * ad(:, 4)
      call solve_nnls(ad, b5, x4, st, "dependent column", 1.0e-12_wp, ref=enum_nnls(ad, b5))
    end do
  end subroutine test_nnls_rank_deficient

  !> Requirement 2: ill-conditioned A: a Hilbert section (cond ~ 1e7) and U diag(s) V^T with
  !> singular values down to 1e-10. The objective is compared with enumeration; the KKT
  !> tolerance is relative to |a_j| (|b| + sum |a_k| x_k), which covers the rounding of
  !> A x when x is large.
  subroutine test_nnls_ill_conditioned()
    real(wp) :: h(8, 6), b(8), x(6), g(8, 6), q(8, 6), r(6, 6), gv(6, 6), qv(6, 6), rv(6, 6)
    real(wp) :: sv(6)
    type(nnls_stats_t) :: st
    integer :: i, j, trial, idx(6)
    logical :: ok
    do j = 1, 6
      do i = 1, 8
        h(i, j) = 1.0_wp / real(i + j - 1, wp)
      end do
    end do
    idx = [(j, j = 1, 6)]
    do trial = 1, 10
      b = randv(8)
      call solve_nnls(h, b, x, st, "Hilbert " // str(trial), 1.0e-11_wp, ref=enum_nnls(h, b, 1.0e-14_wp))
      call randn(g); call randn(gv)
      call subset_qr(g, idx, q, r, ok, 0.0_wp)
      call subset_qr(gv, idx, qv, rv, ok, 0.0_wp)
      do j = 1, 6
        sv(j) = 10.0_wp**(-2 * (j - 1))
      end do
      do j = 1, 6
        q(:, j) = q(:, j) * sv(j)
      end do
      g = matmul(q, transpose(qv))
      b = randv(8)
      call solve_nnls(g, b, x, st, "cond 1e10 " // str(trial), 1.0e-11_wp, ref=enum_nnls(g, b, 1.0e-14_wp))
    end do
  end subroutine test_nnls_ill_conditioned

  !> Ill-conditioned consistent problems whose optimum is known by construction:
  !> A = U diag(s) V^T [m, n] with U, V orthonormal, singular values log-spaced from 1 to
  !> 1/cond, x* > 0 and b = A x*, so the optimal residual is 0 (up to the rounding of b) and,
  !> when m >= n, x* is the unique solution; for m < n the optimum is not unique and only the
  !> objective is checked (the promise of docs/model.md#dense-nnls--ldp-kernel). Tolerances (from cr_nnls's stated accuracy):
  !> - residual: nnls_solve stops when every inactive column has a_j^T r <= 16 m eps |a_j| |r|
  !>   (r the residual of its factorisation), so by convexity |r|^2 - |r*|^2 <= 2 sum_j w_j x*_j
  !>   gives |r| <= |r*| + 32 m eps sum_j |a_j| x*_j; the backward errors of the Householder
  !>   factorisation and of forming b add a few m eps (|b| + sum_j |a_j| x*_j). Checked:
  !>   |A x - b| <= 64 m eps (|b| + sum_j |a_j| x*_j), independent of the conditioning.
  !> - x (m >= n): first-order perturbation of a consistent full-rank least-squares problem,
  !>   |x - x*| <= cond * 64 m eps (|b| + sum_j |a_j| x*_j) / |A|_2 (with |A|_2 = 1 here),
  !>   checked where that bound is below |x*|.
  !> The old solver (gradient a_j^T (b - A_P x_P), threshold 32 eps sqrt(m) |b|) stopped one to
  !> three columns short here, at residuals of 1e-10 to 1e-7 of |b|, and said converged.
  subroutine test_nnls_consistent_family()
    integer, parameter :: nsize = 6
    integer, parameter :: ms(nsize) = [8, 20, 40, 30, 12, 25], ns(nsize) = [5, 12, 30, 30, 20, 40]
    real(wp), parameter :: conds(4) = [1.0e4_wp, 1.0e8_wp, 1.0e10_wp, 1.0e12_wp]
    real(wp), allocatable :: a(:,:), b(:), x(:), xs(:), u(:,:), v(:,:), g(:,:), rr(:,:), sv(:)
    type(nnls_stats_t) :: st
    type(error_t), allocatable :: err
    integer :: is, ic, m, n, r, j, trial
    real(wp) :: scale_b, tol, res, worst_res, worst_x
    logical :: ok
    character(len=:), allocatable :: name
    worst_res = 0.0_wp; worst_x = 0.0_wp
    do is = 1, nsize
      m = ms(is); n = ns(is); r = min(m, n)
      do ic = 1, size(conds)
        do trial = 1, 3
          name = "consistent " // str(m) // "x" // str(n) // " cond " // str(conds(ic)) // " #" // str(trial)
          allocate(a(m, n), b(m), x(n), xs(n), u(m, r), v(n, r), g(max(m, n), r), rr(r, r), sv(r))
          call randn(g(1:m, :))
          call subset_qr(g(1:m, :), [(j, j = 1, r)], u, rr, ok, 0.0_wp)
          call check(ok, name // ": U orthonormal")
          call randn(g(1:n, :))
          call subset_qr(g(1:n, :), [(j, j = 1, r)], v, rr, ok, 0.0_wp)
          call check(ok, name // ": V orthonormal")
          do j = 1, r
            sv(j) = conds(ic)**(-real(j - 1, wp) / real(max(r - 1, 1), wp))
            u(:, j) = u(:, j) * sv(j)
          end do
          a(:, :) = matmul(u, transpose(v))
          do j = 1, n
            xs(j) = 0.5_wp + rng%uniform()
          end do
          b(:) = matmul(a, xs)
          scale_b = norm2(b)
          do j = 1, n
            scale_b = scale_b + norm2(a(:, j)) * xs(j)
          end do
          x = -1.0_wp
          call nnls_solve(a, b, x, st, err, work=work)
          call check(.not. allocated(err), name // ": no error")
          if (allocated(err)) then
            deallocate(a, b, x, xs, u, v, g, rr, sv); cycle
          end if
          call check(st%converged, name // ": converged")
          call check(all(x >= 0.0_wp), name // ": x >= 0")
          res = norm2(b - matmul(a, x))
          tol = 64.0_wp * m * eps * scale_b
          worst_res = max(worst_res, res / tol)
          call check(res <= tol, name // ": residual " // str(res / norm2(b)) // " |b| > 64 m eps (|b| + sum |a_j| x*_j)")
          call check(abs(st%residual - res) <= 4.0_wp * m * eps * scale_b, name // ": reported residual")
          if (m >= n .and. conds(ic) * tol < norm2(xs)) then
            worst_x = max(worst_x, norm2(x - xs) / (conds(ic) * tol))
            call check(norm2(x - xs) <= conds(ic) * tol, name // ": x = x* to cond * tol")
          end if
          deallocate(a, b, x, xs, u, v, g, rr, sv)
        end do
      end do
    end do
    write(*, '(a, es9.2, a, es9.2)') "consistent family: largest residual / tolerance ", worst_res, &
      ", largest |x - x*| / (cond tol) ", worst_x
  end subroutine test_nnls_consistent_family

  !> Requirement 2: badly scaled data. For A -> c1 A, b -> c2 b the solution is (c2 / c1) x
  !> with the same support; also per-column scales from 1e-20 to 1e15 (x_j -> x_j / D_j).
  !> Full-column-rank problems (unique x). Compared to relative 1e-12 of max |x|.
  subroutine test_nnls_scaling()
    real(wp) :: a(8, 6), b(8), x(6), xs(6), dc(6), as(8, 6)
    real(wp), parameter :: scales(3) = [1.0e-20_wp, 1.0_wp, 1.0e15_wp]
    type(nnls_stats_t) :: st, sts
    type(error_t), allocatable :: err
    real(wp) :: sa, sbb
    integer :: trial, i, k, j
    character(len=:), allocatable :: name
    do trial = 1, 20
      call randn(a)
      b = randv(8)
      call solve_nnls(a, b, x, st, "scaling base", 1.0e-12_wp)
      do i = 1, 3
        do k = 1, 3
          if (i == 2 .and. k == 2) cycle
          name = "scaling A*" // str(scales(i)) // " b*" // str(scales(k))
          call solve_nnls(a * scales(i), b * scales(k), xs, sts, name, 1.0e-12_wp)
          xs = xs * (scales(i) / scales(k))
          call check(all((xs > 0.0_wp) .eqv. (x > 0.0_wp)), name // ": same support")
          call check(maxval(abs(xs - x)) <= 1.0e-12_wp * maxval(abs(x)), name // ": x scaled")
        end do
      end do
      ! the extremes (below about 1e-154 plain squares underflow and a column or b would read
      ! as zero; above about 1e154 they overflow): A and b scaled together and apart
      do i = 1, 4
        select case (i)
        case (1); sa = 1.0e-170_wp; sbb = 1.0e-170_wp; name = "extreme scaling A*1e-170 b*1e-170"
        case (2); sa = 1.0e150_wp; sbb = 1.0e150_wp; name = "extreme scaling A*1e150 b*1e150"
        case (3); sa = 1.0e-170_wp; sbb = 1.0_wp; name = "extreme scaling A*1e-170"
        case (4); sa = 1.0_wp; sbb = 1.0e-170_wp; name = "extreme scaling b*1e-170"
        end select
        call nnls_solve(a * sa, b * sbb, xs, sts, err)
        call check(.not. allocated(err) .and. sts%converged, name // ": converged")
        xs = xs * (sa / sbb)
        call check(all((xs > 0.0_wp) .eqv. (x > 0.0_wp)), name // ": same support")
        call check(maxval(abs(xs - x)) <= 1.0e-12_wp * maxval(abs(x)), name // ": x scaled")
      end do
      do j = 1, 6
        dc(j) = 10.0_wp**(-20.0_wp + 35.0_wp * rng%uniform())
        as(:, j) = a(:, j) * dc(j)
      end do
      call solve_nnls(as, b, xs, sts, "column scaling", 1.0e-12_wp)
      xs = xs * dc
      call check(all((xs > 0.0_wp) .eqv. (x > 0.0_wp)), "column scaling: same support")
      call check(maxval(abs(xs - x)) <= 1.0e-12_wp * maxval(abs(x)), "column scaling: x scaled")
    end do
  end subroutine test_nnls_scaling

  !> Requirement 2: warm start from wrong guesses gives the same solution (unique x when
  !> m >= n; for m < n only A x and the objective are unique, so those are compared).
  subroutine test_nnls_warm()
    real(wp) :: a(8, 6), b(8), x(6), xw(6), aw(4, 8), bw(4), y(8), yw(8)
    logical :: guess(6), gw(8)
    type(nnls_stats_t) :: st, stw
    integer :: trial, g, j
    do trial = 1, 20
      call randn(a)
      b = randv(8)
      call solve_nnls(a, b, x, st, "warm base", 1.0e-12_wp)
      do g = 1, 4
        select case (g)
        case (1)
          guess = x <= 0.0_wp
        case (2)
          guess = .true.
        case (3)
          guess = .false.
        case default
          do j = 1, 6
            guess(j) = rng%uniform() < 0.5_wp
          end do
        end select
        call solve_nnls(a, b, xw, stw, "warm guess " // str(g), 1.0e-12_wp, passive0=guess)
        call check(maxval(abs(xw - x)) <= 1.0e-12_wp * maxval(abs(x)), &
          "warm guess " // str(g) // ": same x")
      end do
      ! the right guess converges at once
      call solve_nnls(a, b, xw, stw, "warm exact", 1.0e-12_wp, passive0=x > 0.0_wp)
      call check(stw%iterations == 0, "warm exact: no iteration")
      call randn(aw)
      bw = randv(4)
      call solve_nnls(aw, bw, y, st, "wide warm base", 1.0e-12_wp)
      gw = y <= 0.0_wp
      call solve_nnls(aw, bw, yw, stw, "wide warm", 1.0e-12_wp, ref=st%residual, passive0=gw)
      call check(maxval(abs(matmul(aw, yw - y))) <= 1.0e-12_wp * (norm2(bw) + &
        sum(abs(matmul(aw, y)))), "wide warm: same A x")
    end do
  end subroutine test_nnls_warm

  !> Requirement 2 and 4: the iteration cap ends the solve with converged = .false. and a
  !> feasible x whose reported statistics are those of x; degenerate problems built to make
  !> textbook Lawson-Hanson cycle end (converged) under the default cap.
  subroutine test_nnls_cap()
    real(wp) :: a(10, 8), b(10), x(8), xc(8), ad(4, 12), bd(4), xd(12), big(30, 30), bb(30)
    real(wp) :: xb(30)
    type(nnls_stats_t) :: st, stc
    integer :: trial, cap, i, j, found
    found = 0
    do trial = 1, 50
      call randn(a)
      b = randv(10)
      if (mod(trial, 2) == 0) b = matmul(a, abs(randv(8)))
      call solve_nnls(a, b, x, st, "cap base", 1.0e-12_wp)
      if (st%iterations < 4) cycle
      found = found + 1
      do cap = -1, st%iterations - 1
        call solve_nnls(a, b, xc, stc, "cap " // str(cap), 0.0_wp, max_iter=cap)
        call check(.not. stc%converged, "cap " // str(cap) // ": not converged")
        call check(stc%iterations <= max(cap, 0), "cap " // str(cap) // ": iterations <= cap")
      end do
      ! with a warm start and no iteration: the warm iterate, feasible
      call solve_nnls(a, b, xc, stc, "cap 0 warm", 0.0_wp, passive0=x > 0.0_wp, max_iter=0)
      call check(stc%converged .and. maxval(abs(xc - x)) <= 1.0e-12_wp * maxval(abs(x)), &
        "cap 0 warm from the solution: converged at once")
    end do
    call check(found >= 5, "cap: enough problems needing several iterations")
    ! degenerate: entries in {-1, 0, 1}, columns repeated with both signs, many ties
    do trial = 1, 30
      do j = 1, 6
        do i = 1, 4
          ad(i, j) = real(randint(-1, 1), wp)
        end do
        ad(:, j + 6) = ad(:, j)
        if (mod(j, 2) == 0) ad(:, j + 6) = -ad(:, j)
      end do
      do i = 1, 4
        bd(i) = real(randint(-2, 2), wp)
      end do
      call solve_nnls(ad, bd, xd, st, "degenerate ties " // str(trial), 1.0e-12_wp, &
        ref=enum_nnls(ad(:, 1:12), bd))
    end do
    ! a larger problem converges within the default cap
    call randn(big)
    bb = randv(30)
    call solve_nnls(big, bb, xb, st, "30 x 30", 1.0e-12_wp)
  end subroutine test_nnls_cap

  ! ------------------------------------------------------------------ LDP tests

  !> Requirement 3: random small LDPs against enumeration of active sets. d = Bm u0 + slack
  !> (feasible), some slacks zero (u0 a degenerate vertex), some rows duplicated with a
  !> positive factor or sums of others (dependent, redundant constraints).
  subroutine test_ldp_enumeration()
    integer :: trial, mc, n, l
    real(wp), allocatable :: bm(:,:), d(:), v(:), u(:), lam(:), u0(:), uref(:), slack(:)
    type(ldp_stats_t) :: st
    logical :: found
    character(len=:), allocatable :: name
    do trial = 1, 400
      mc = randint(1, 6); n = randint(1, 6)
      ! every array of the trial is allocated with its size: gfortran 12's inlined matmul
      ! (-O1 and above) does not reallocate d in d = matmul(bm, u0) + slack when d's old
      ! size equals size(u0)
      allocate(bm(mc, n), u(n), lam(mc), uref(n), u0(n), slack(mc), d(mc), v(n))
      call randn(bm)
      u0 = randv(n)
      slack = abs(randv(mc))
      do l = 1, mc
        if (rng%uniform() < 0.3_wp) slack(l) = 0.0_wp
      end do
      if (mod(trial, 5) == 0 .and. mc >= 2) then
        bm(2, :) = 2.5_wp * bm(1, :)
        slack(2) = 2.5_wp * slack(1)
      end if
      if (mod(trial, 7) == 0 .and. mc >= 3) then
        bm(3, :) = bm(1, :) + bm(2, :)
        slack(3) = slack(1) + slack(2)
      end if
      d(:) = matmul(bm, u0) + slack
      v(:) = u0 + 2.0_wp * randv(n)
      name = "ldp enum " // str(trial)
      call enum_ldp(bm, d, v, uref, found)
      call check(found, name // ": enumeration found the projection")
      call solve_ldp(bm, d, v, u, lam, st, name)
      call check_close(norm2(u - v)**2, norm2(uref - v)**2, &
        1.0e-10_wp * max(norm2(uref - v)**2, sqrt(eps) * (1.0_wp + norm2(v)**2)), &
        name // ": objective = enumeration")
      call check(maxval(abs(u - uref)) <= 1.0e-8_wp * (1.0_wp + maxval(abs(v))), &
        name // ": u = enumeration")
      deallocate(bm, u, lam, uref, u0, slack, d, v)
    end do
  end subroutine test_ldp_enumeration

  !> Requirement 3: degenerate rows, zero rows, mc = 0, v feasible.
  subroutine test_ldp_degenerate()
    real(wp) :: bm(4, 3), d(4), v(3), u(3), lam(4), b1(3), p(3), u1(3), l1(1), bz(3, 3), dz(3)
    real(wp) :: lz(3), e0(0, 3), d0(0), l0(0), uz(3)
    type(ldp_stats_t) :: st
    type(error_t), allocatable :: err
    integer :: trial
    logical :: found
    do trial = 1, 10
      ! one halfspace written four times (twice scaled): u is the projection on it; the
      ! individual multipliers are not unique, only sum_l lambda_l |b_l| (stationarity)
      b1 = randv(3)
      v = randv(3)
      d(1) = dot_product(b1, v) - 1.0_wp
      bm(1, :) = b1; bm(2, :) = b1; bm(3, :) = 3.0_wp * b1; bm(4, :) = 0.5_wp * b1
      d(2) = d(1); d(3) = 3.0_wp * d(1); d(4) = 0.5_wp * d(1)
      call solve_ldp(bm, d, v, u, lam, st, "repeated row")
      p = v - (dot_product(b1, v) - d(1)) / dot_product(b1, b1) * b1
      call check(maxval(abs(u - p)) <= 1.0e-13_wp * (1.0_wp + maxval(abs(v))), &
        "repeated row: u = projection on the halfspace")
      ! dependent rows meeting at a degenerate vertex: b3 = b1 + b2 and d3 = d1 + d2
      call randn(bm)
      bm(3, :) = bm(1, :) + bm(2, :)
      u1 = randv(3)
      d = matmul(bm, u1)
      d(4) = d(4) + 1.0_wp
      v = u1 + matmul(transpose(bm(1:2, :)), abs(randv(2)))
      call solve_ldp(bm, d, v, u, lam, st, "dependent rows")
      call enum_ldp(bm, d, v, p, found)
      call check(found .and. maxval(abs(u - p)) <= 1.0e-9_wp * (1.0_wp + maxval(abs(v))), &
        "dependent rows: u = enumeration")
      ! zero rows with d >= 0 change nothing
      b1 = randv(3)
      v = randv(3)
      u1 = 0.0_wp
      l1 = 0.0_wp
      call ldp_solve(reshape(b1, [1, 3]), [dot_product(b1, v) - 0.5_wp], v, u1, l1, st, err)
      bz = 0.0_wp
      bz(2, :) = b1
      dz = [0.0_wp, dot_product(b1, v) - 0.5_wp, 2.0_wp]
      call solve_ldp(bz, dz, v, uz, lz, st, "zero rows, d >= 0")
      call check(maxval(abs(uz - u1)) <= 1.0e-14_wp * (1.0_wp + maxval(abs(v))) .and. &
        lz(1) == 0.0_wp .and. lz(3) == 0.0_wp, "zero rows, d >= 0: harmless")
    end do
    ! mc = 0: u = v
    v = randv(3)
    call ldp_solve(e0, d0, v, u, l0, st, err)
    call check(.not. allocated(err) .and. all(u == v) .and. .not. st%infeasible .and. &
      st%max_violation == 0.0_wp, "mc = 0: u = v")
    ! v feasible (strictly, and on the boundary): u = v exactly, lambda = 0, warm guess ignored
    call randn(bm)
    v = randv(3)
    d = matmul(bm, v) + abs(randv(4))
    lam = 1.0_wp
    call ldp_solve(bm, d, v, u, lam, st, err)
    call check(.not. allocated(err) .and. all(u == v) .and. all(lam == 0.0_wp) .and. &
      .not. st%infeasible .and. st%max_violation <= 0.0_wp .and. st%nnls%iterations == 0, &
      "v strictly feasible: u = v exactly, lambda = 0 exactly")
    ! on the boundary (d = Bm v up to the rounding of the product): u = v and lambda = 0 up
    ! to rounding
    d = matmul(bm, v)
    lam = 1.0_wp
    call ldp_solve(bm, d, v, u, lam, st, err)
    call check(.not. allocated(err) .and. maxval(abs(u - v)) <= 1.0e-14_wp * maxval(abs(v)) &
      .and. maxval(lam) <= 1.0e-14_wp .and. .not. st%infeasible, &
      "v on the boundary: u = v, lambda = 0")
  end subroutine test_ldp_degenerate

  !> sum of squared violations phi(u) = |(Bm u - d)^+|^2
  real(wp) function phi(bm, d, u)
    real(wp), intent(in) :: bm(:,:), d(:), u(:)
    phi = sum(max(matmul(bm, u) - d, 0.0_wp)**2)
  end function phi

  !> Checks of an infeasible LDP result against the documented least-violation point: u
  !> minimises phi(u) = |(Bm u - d)^+|^2 and, among the minimisers {u : Bm u <= d + sigma*},
  !> is the one closest to v. Tested by (i) phi(u) <= phi(c) (to rounding) at candidate
  !> points c: least-squares solutions of row subsets of full column rank (these include the
  !> minimiser whenever its violated rows have full column rank), projections of v on the
  !> affine sets of independent row subsets, random perturbations of u; (ii) the LDP KKT
  !> conditions of the projection of v on {Bm u <= d + (Bm u - d)^+} with the returned lambda;
  !> (iii) the reported max_violation is max (Bm u - d)^+.
  subroutine check_least_violation(bm, d, v, u, lam, st, name)
    real(wp), intent(in) :: bm(:,:), d(:), v(:), u(:), lam(:)
    type(ldp_stats_t), intent(in) :: st
    character(len=*), intent(in) :: name
    real(wp) :: s(size(d)), c(size(u)), mu(size(d)), ju, jc, t
    real(wp) :: rows(size(d), size(u))
    integer :: mc, n, mask, cnt, l, idx(size(d)), k, i
    logical :: ok, better
    mc = size(d); n = size(u)
    s = matmul(bm, u) - d
    ju = phi(bm, d, u)
    better = .false.
    do mask = 1, 2**mc - 1
      cnt = 0
      do l = 1, mc
        if (btest(mask, l - 1)) then
          cnt = cnt + 1
          idx(cnt) = l
        end if
      end do
      do k = 1, 2
        if (k == 1) then
          rows(1:cnt, :) = bm(idx(1:cnt), :)
          call subset_ls(rows(1:cnt, :), d(idx(1:cnt)), [(i, i = 1, n)], c, ok, dep_tol)
        else
          call affine_projection(bm, d, v, idx(1:cnt), c, mu(1:cnt), ok)
        end if
        if (.not. ok) cycle
        jc = phi(bm, d, c)
        if (ju > jc + 1.0e-12_wp * (1.0_wp + jc)) better = .true.
      end do
    end do
    do k = 1, 20
      c = u + 10.0_wp**(-randint(1, 6)) * randv(n)
      jc = phi(bm, d, c)
      if (ju > jc + 1.0e-12_wp * (1.0_wp + jc)) better = .true.
    end do
    call check(.not. better, name // ": least violation (no candidate does better)")
    call check_ldp(bm, d + max(s, 0.0_wp), v, u, lam, st, name // " (relaxed)", relaxed=.true.)
    t = max(0.0_wp, maxval(s))
    call check_close(st%max_violation, t, 64.0_wp * eps * (1.0_wp + maxval(abs(d)) + &
      maxval(abs(bm)) * sum(abs(u))), name // ": reported max_violation")
  end subroutine check_least_violation

  !> ldp_solve expected to find an infeasible system; runs check_least_violation.
  subroutine solve_infeasible(bm, d, v, u, lam, st, name)
    real(wp), intent(in) :: bm(:,:), d(:), v(:)
    real(wp), intent(out) :: u(:), lam(:)
    type(ldp_stats_t), intent(out) :: st
    character(len=*), intent(in) :: name
    type(error_t), allocatable :: err
    lam = 0.0_wp
    call ldp_solve(bm, d, v, u, lam, st, err, work=work)
    call check(.not. allocated(err), name // ": no error")
    if (allocated(err)) return
    call check(st%nnls%converged, name // ": converged")
    call check_least_violation(bm, d, v, u, lam, st, name)
  end subroutine solve_infeasible

  !> Requirement 3: infeasible systems.
  subroutine test_ldp_infeasible()
    real(wp) :: u2(2), l2(2), l3(3), bt(3, 2), bz(3, 3), dz(3), uz(3), pz(3), u1(3), l1(2)
    real(wp) :: b0(2, 3), lb(2), un(0)
    real(wp), allocatable :: bm(:,:), d(:), v(:), u(:), lam(:)
    type(ldp_stats_t) :: st
    type(error_t), allocatable :: err
    integer :: trial, mc, n, k
    real(wp) :: c, gap
    ! u1 <= -1 and -u1 <= -1: least violation u1 = 0 (both violated by 1), u2 = v2
    call solve_infeasible(reshape([1.0_wp, -1.0_wp, 0.0_wp, 0.0_wp], [2, 2]), [-1.0_wp, -1.0_wp], &
      [0.3_wp, 0.7_wp], u2, l2, st, "opposite halfspaces")
    call check(abs(u2(1)) <= 1.0e-12_wp .and. abs(u2(2) - 0.7_wp) <= 1.0e-14_wp, &
      "opposite halfspaces: u = (0, v2)")
    call check(abs(st%max_violation - 1.0_wp) <= 1.0e-12_wp, "opposite halfspaces: max violation 1")
    ! triangle u1 <= -1, u2 <= -1, u1 + u2 >= 1: least squares and least max violation at 0,
    ! every row violated by 1
    bt = reshape([1.0_wp, 0.0_wp, -1.0_wp, 0.0_wp, 1.0_wp, -1.0_wp], [3, 2])
    call solve_infeasible(bt, [-1.0_wp, -1.0_wp, -1.0_wp], [2.0_wp, -3.0_wp], u2, l3, st, &
      "inconsistent triangle")
    call check(maxval(abs(u2)) <= 1.0e-12_wp, "inconsistent triangle: u = 0")
    call check(abs(st%max_violation - 1.0_wp) <= 1.0e-12_wp .and. &
      abs(phi(bt, [-1.0_wp, -1.0_wp, -1.0_wp], u2) - 3.0_wp) <= 1.0e-12_wp, &
      "inconsistent triangle: max violation 1, sum of squares 3")
    ! a zero row with d < 0 among feasible rows: u is the projection on the other rows, and
    ! the violation is -d of the zero row
    do trial = 1, 5
      bz = 0.0_wp
      bz(2, :) = randv(3)
      bz(3, :) = randv(3)
      uz = randv(3)
      dz = [-2.0_wp, dot_product(bz(2, :), uz) - 1.0_wp, dot_product(bz(3, :), uz) + 0.5_wp]
      call solve_infeasible(bz, dz, uz, pz, l3, st, "zero row, d < 0")
      call check_close(st%max_violation, 2.0_wp, 1.0e-14_wp, "zero row, d < 0: violation 2")
      u1 = 0.0_wp; l1 = 0.0_wp
      call ldp_solve(bz(2:3, :), dz(2:3), uz, u1, l1, st, err)
      call check(maxval(abs(pz - u1)) <= 1.0e-13_wp * (1.0_wp + maxval(abs(uz))), &
        "zero row, d < 0: u = projection on the other rows")
    end do
    ! an empty slab of width |gap| between two opposite rows, v far away (a certificate of
    ! infeasibility found by the first pass must stay final for |gap| down to 1e-12 of the data,
    ! never a feasible answer with row 2 violated by |gap|):
    ! infeasible at every width, both rows violated by |gap| / 2 (the least squares split)
    do k = 3, 12
      gap = -10.0_wp**(-k)
      call ldp_solve(reshape([1.0_wp, -1.0_wp, 0.5_wp, -0.5_wp], [2, 2]), [1.0_wp, -1.0_wp + gap], &
        [3.0_wp, 2.0_wp], u2, l2, st, err, warm=.false.)
      call check(.not. allocated(err) .and. st%infeasible, &
        "empty slab of width 1e" // str(-k) // ": infeasible")
      ! (to 1e-12, as the other least-violation splits here: about 1e3 eps of the data)
      call check(abs(st%max_violation - 0.5_wp * abs(gap)) <= 1.0e-12_wp, &
        "empty slab of width 1e" // str(-k) // ": each row violated by |gap| / 2")
    end do
    ! all rows zero, one d < 0: nothing can move, u = v
    b0 = 0.0_wp
    lb = 0.0_wp
    call ldp_solve(b0, [1.0_wp, -2.0_wp], [0.1_wp, 0.2_wp, 0.3_wp], uz, lb, st, err)
    call check(.not. allocated(err), "Bm = 0, d < 0: no error")
    if (.not. allocated(err)) then
      call check(st%infeasible .and. all(uz == [0.1_wp, 0.2_wp, 0.3_wp]) .and. &
        st%max_violation == 2.0_wp, "Bm = 0, d < 0: infeasible, u = v, violation 2")
    end if
    ! n = 0: only the signs of d matter
    call ldp_solve(reshape([real(wp) ::], [2, 0]), [1.0_wp, -2.0_wp], [real(wp) ::], un, lb, st, err)
    call check(.not. allocated(err), "n = 0, d < 0: no error")
    if (.not. allocated(err)) call check(st%infeasible .and. st%max_violation == 2.0_wp, &
      "n = 0, d < 0: infeasible, violation 2")
    call ldp_solve(reshape([real(wp) ::], [2, 0]), [1.0_wp, 0.0_wp], [real(wp) ::], un, lb, st, err)
    call check(.not. allocated(err) .and. .not. st%infeasible .and. all(lb == 0.0_wp), &
      "n = 0, d >= 0: feasible")
    ! badly scaled infeasible system (rows times 1e-20 and 1e15): same least-violation point
    do k = 1, 2
      c = merge(1.0e-20_wp, 1.0e15_wp, k == 1)
      call solve_infeasible(c * reshape([1.0_wp, -1.0_wp, 0.0_wp, 0.0_wp], [2, 2]), &
        [-c, -c], [0.3_wp, 0.7_wp], u2, l2, st, "scaled opposite halfspaces " // str(k))
      call check(abs(u2(1)) <= 1.0e-12_wp .and. abs(u2(2) - 0.7_wp) <= 1.0e-14_wp, &
        "scaled opposite halfspaces " // str(k) // ": u = (0, v2)")
      call check(abs(st%max_violation / c - 1.0_wp) <= 1.0e-12_wp, &
        "scaled opposite halfspaces " // str(k) // ": max violation c")
    end do
    ! random infeasible systems: a random system plus the reverse of its first row shifted
    do trial = 1, 60
      mc = randint(2, 6); n = randint(1, 5)
      allocate(bm(mc, n), u(n), lam(mc), d(mc))
      call randn(bm)
      d(:) = matmul(bm, randv(n)) + abs(randv(mc))
      c = 0.5_wp + rng%uniform()
      gap = 0.1_wp + rng%uniform()
      bm(mc, :) = -c * bm(1, :)
      d(mc) = -c * (d(1) + gap)
      v = 3.0_wp * randv(n)
      call solve_infeasible(bm, d, v, u, lam, st, "random infeasible " // str(trial))
      deallocate(bm, u, lam, d)
    end do
  end subroutine test_ldp_infeasible

  !> Requirement 3: near-infeasible but feasible systems are not flagged infeasible.
  subroutine test_ldp_near_infeasible()
    real(wp) :: bm(2, 2), d(2), u(2), lam(2), b3(3, 2), l3(3), bw(3, 3), dw(3), uw(3), lw(3)
    real(wp) :: pw(3), v(2)
    real(wp), parameter :: widths(5) = [1.0e-4_wp, 1.0e-8_wp, 1.0e-12_wp, 1.0e-15_wp, 0.0_wp]
    real(wp), parameter :: levels(3) = [1.0_wp, 1.0e3_wp, 1.0e-6_wp]
    type(ldp_stats_t) :: st
    integer :: i, k, side
    logical :: found
    character(len=:), allocatable :: name
    ! slab (1 - w) L <= u1 <= L of relative width w, from either side
    bm = reshape([1.0_wp, -1.0_wp, 0.0_wp, 0.0_wp], [2, 2])
    do k = 1, 3
      do i = 1, 5
        do side = 1, 2
          name = "slab L=" // str(levels(k)) // " w=" // str(widths(i)) // " side " // str(side)
          d = [levels(k), -(1.0_wp - widths(i)) * levels(k)]
          v = [merge(3.0_wp, -2.0_wp, side == 1) * levels(k), 0.5_wp]
          call solve_ldp(bm, d, v, u, lam, st, name)
          if (side == 1) then
            call check_close(u(1), levels(k), 1.0e-13_wp * levels(k), name // ": u1 = L")
          else
            call check_close(u(1), (1.0_wp - widths(i)) * levels(k), 1.0e-13_wp * levels(k), &
              name // ": u1 = (1 - w) L")
          end if
          call check(u(2) == 0.5_wp, name // ": u2 unchanged")
        end do
      end do
    end do
    ! a single feasible point cut out by three lines: u1 + u2 <= 2, u1 >= 1, u2 >= 1
    b3 = reshape([1.0_wp, -1.0_wp, 0.0_wp, 1.0_wp, 0.0_wp, -1.0_wp], [3, 2])
    call solve_ldp(b3, [2.0_wp, -1.0_wp, -1.0_wp], [0.0_wp, 0.0_wp], u, l3, st, "single point")
    call check(maxval(abs(u - 1.0_wp)) <= 1.0e-14_wp, "single point: u = (1, 1)")
    ! a thin feasible wedge far from v (3 constraints in 3D, nearly parallel)
    do i = 1, 4
      bw = reshape([1.0_wp, -1.0_wp, 0.0_wp, 0.0_wp, 10.0_wp**(-2 * i), 0.0_wp, &
        0.0_wp, 0.0_wp, 1.0_wp], [3, 3])
      dw = [1.0_wp, -1.0_wp + 10.0_wp**(-2 * i), 5.0_wp]
      name = "thin wedge " // str(i)
      call solve_ldp(bw, dw, [-4.0_wp, 0.0_wp, 7.0_wp], uw, lw, st, name)
      call enum_ldp(bw, dw, [-4.0_wp, 0.0_wp, 7.0_wp], pw, found)
      call check(found .and. maxval(abs(uw - pw)) <= 1.0e-12_wp * 8.0_wp, name // ": u = enumeration")
    end do
  end subroutine test_ldp_near_infeasible

  !> Requirement 3: badly scaled LDPs. Rows scaled by c (Bm -> c Bm, d -> c d): same u,
  !> lambda / c. Units scaled by c (d -> c d, v -> c v): u -> c u, lambda -> c lambda.
  subroutine test_ldp_scaling()
    integer :: trial, mc, n, k, kind
    real(wp), allocatable :: bm(:,:), d(:), v(:), u(:), lam(:), us(:), ls(:)
    real(wp), parameter :: scales(2) = [1.0e-20_wp, 1.0e15_wp]
    type(ldp_stats_t) :: st, sts
    character(len=:), allocatable :: name
    real(wp) :: c
    do trial = 1, 30
      mc = randint(1, 8); n = randint(1, 6)
      allocate(bm(mc, n), u(n), lam(mc), us(n), ls(mc), d(mc))
      call randn(bm)
      d(:) = matmul(bm, randv(n)) + abs(randv(mc))
      v = 2.0_wp * randv(n)
      call solve_ldp(bm, d, v, u, lam, st, "ldp scaling base")
      do k = 1, 2
        c = scales(k)
        do kind = 1, 2
          if (kind == 1) then
            name = "ldp rows*" // str(c)
            call solve_ldp(c * bm, c * d, v, us, ls, sts, name)
            call check(maxval(abs(us - u)) <= 1.0e-12_wp * (1.0_wp + maxval(abs(v))), &
              name // ": same u")
            call check(maxval(abs(ls * c - lam)) <= 1.0e-10_wp * (1.0_wp + maxval(lam)), &
              name // ": lambda / c")
          else
            name = "ldp units*" // str(c)
            call solve_ldp(bm, c * d, c * v, us, ls, sts, name)
            call check(maxval(abs(us / c - u)) <= 1.0e-12_wp * (1.0_wp + maxval(abs(v))), &
              name // ": u * c")
            call check(maxval(abs(ls / c - lam)) <= 1.0e-10_wp * (1.0_wp + maxval(lam)), &
              name // ": lambda * c")
          end if
        end do
      end do
      deallocate(bm, u, lam, us, ls, d)
    end do
  end subroutine test_ldp_scaling

  !> Requirement 3 and 4: warm start from a wrong lambda gives the same u; the iteration cap
  !> ends the solve.
  subroutine test_ldp_warm_and_cap()
    integer :: trial, mc, n, g
    real(wp), allocatable :: bm(:,:), d(:), v(:), u(:), lam(:), uw(:), lw(:)
    type(ldp_stats_t) :: st, stw
    type(error_t), allocatable :: err
    character(len=:), allocatable :: name
    do trial = 1, 30
      mc = randint(2, 10); n = randint(1, 6)
      allocate(bm(mc, n), u(n), lam(mc), uw(n), lw(mc), d(mc))
      call randn(bm)
      d(:) = matmul(bm, randv(n)) + abs(randv(mc))
      v = 3.0_wp * randv(n)
      call solve_ldp(bm, d, v, u, lam, st, "ldp warm base")
      do g = 1, 3
        name = "ldp wrong warm " // str(g)
        select case (g)
        case (1)
          lw = merge(1.0_wp, 0.0_wp, lam == 0.0_wp)
        case (2)
          lw = abs(randv(mc))
        case default
          lw = 1.0e6_wp
        end select
        call ldp_solve(bm, d, v, uw, lw, stw, err, work=work)
        call check(.not. allocated(err), name // ": no error")
        call check(stw%nnls%converged, name // ": converged")
        call check_ldp(bm, d, v, uw, lw, stw, name)
        call check(maxval(abs(uw - u)) <= 1.0e-12_wp * (1.0_wp + maxval(abs(v))), name // ": same u")
      end do
      ! warm = .false. ignores whatever lambda holds
      lw = -7.0_wp
      call ldp_solve(bm, d, v, uw, lw, stw, err, warm=.false., work=work)
      call check(.not. allocated(err) .and. maxval(abs(uw - u)) <= 1.0e-12_wp * &
        (1.0_wp + maxval(abs(v))), "ldp warm=.false.: same u")
      ! iteration cap 0 from a cold start: no column enters, so u = v, lambda = 0, and the
      ! solve reports that it did not converge
      lw = 0.0_wp
      call ldp_solve(bm, d, v, uw, lw, stw, err, max_iter=0, work=work)
      call check(.not. allocated(err), "ldp cap 0: no error")
      if (any(matmul(bm, v) > d)) call check(.not. stw%nnls%converged .and. all(lw == 0.0_wp) &
        .and. all(uw == v) .and. stw%max_violation > 0.0_wp, &
        "ldp cap 0: not converged, u = v, violation reported")
      ! cap 1: returns with lambda >= 0 (the LDP may take two warm-started NNLS passes, each
      ! capped, so convergence is not asserted either way)
      lw = 0.0_wp
      call ldp_solve(bm, d, v, uw, lw, stw, err, max_iter=1, work=work)
      call check(.not. allocated(err) .and. all(lw >= 0.0_wp), "ldp cap 1: no error, lambda >= 0")
      deallocate(bm, u, lam, uw, lw, d)
    end do
  end subroutine test_ldp_warm_and_cap

  ! ------------------------------------------------------------------ non-finite input

  !> Requirement 4: NaN or Inf in the input is an error (code 2), never propagated.
  subroutine test_non_finite()
    real(wp) :: a(4, 3), b(4), x(3), nan, inf, bm(3, 2), d(3), v(2), u(2), lam(3)
    type(nnls_stats_t) :: st
    type(ldp_stats_t) :: lst
    type(error_t), allocatable :: err
    integer :: k
    nan = ieee_value(1.0_wp, ieee_quiet_nan)
    inf = ieee_value(1.0_wp, ieee_positive_inf)
    do k = 1, 3
      call randn(a)
      b = randv(4)
      select case (k)
      case (1)
        a(2, 3) = nan
      case (2)
        b(4) = nan
      case default
        a(1, 1) = -inf
      end select
      call nnls_solve(a, b, x, st, err)
      call check(allocated(err), "nnls non-finite " // str(k) // ": error")
      if (allocated(err)) call check(err%code == EXIT_BAD_INPUT .and. index(err%message, "finite") > 0, &
        "nnls non-finite " // str(k) // ": code 2, message")
    end do
    do k = 1, 5
      call randn(bm)
      v = randv(2)
      d = matmul(bm, v) - 1.0_wp
      lam = 0.0_wp
      select case (k)
      case (1)
        bm(3, 2) = nan
      case (2)
        d(1) = nan
      case (3)
        v(2) = nan
      case (4)
        d(2) = inf
      case default
        lam(2) = nan
      end select
      call ldp_solve(bm, d, v, u, lam, lst, err)
      call check(allocated(err), "ldp non-finite " // str(k) // ": error")
      if (allocated(err)) call check(err%code == EXIT_BAD_INPUT .and. index(err%message, "finite") > 0, &
        "ldp non-finite " // str(k) // ": code 2, message")
    end do
    ! a NaN warm-start lambda is fine when the warm start is off
    call randn(bm)
    v = randv(2)
    d = matmul(bm, v) - 1.0_wp
    lam = nan
    call ldp_solve(bm, d, v, u, lam, lst, err, warm=.false.)
    call check(.not. allocated(err), "ldp NaN lambda, warm = .false.: no error")
    if (.not. allocated(err)) call check(all(lam >= 0.0_wp), "ldp NaN lambda, warm off: lambda set")
  end subroutine test_non_finite
end program test_nnls_edge
