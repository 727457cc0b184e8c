!> Unit tests of cr_nnls: Lawson-Hanson NNLS against exhaustive enumeration, degenerate data,
!> scaling invariance, warm start, iteration cap; LDP KKT, infeasibility and warm start.
program test_nnls
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_test_scenes, only: seed_random
  use cr_nnls, only: nnls_solve, nnls_stats_t, nnls_work_t, ldp_solve, ldp_stats_t
  implicit none
  type(nnls_work_t) :: work
  call seed_random(12345)
  call test_random_vs_enumeration()
  call test_degenerate()
  call test_scaling_and_warm()
  call test_ldp()
  call test_summary()

contains

  !> standard normal matrix
  subroutine randn(a)
    real(wp), intent(out) :: a(:,:)
    real(wp) :: u1(size(a,1), size(a,2)), u2(size(a,1), size(a,2))
    call random_number(u1); call random_number(u2)
    a = sqrt(-2.0_wp * log(1.0_wp - u1)) * cos(8.0_wp * atan(1.0_wp) * u2)
  end subroutine randn

  !> Optimal NNLS objective by enumeration of all supports with independent columns
  !> (an optimal solution with such a support always exists). Gram-Schmidt twice.
  real(wp) function brute_nnls(a, b) result(best)
    real(wp), intent(in) :: a(:,:), b(:)
    integer :: m, n, mask, j, k, i, cnt
    integer :: idx(size(a, 2))
    real(wp) :: q(size(a,1), size(a,2)), r(size(a,2), size(a,2)), c(size(a,2)), x(size(a,2))
    real(wp) :: v(size(a,1)), s, nv
    logical :: ok
    m = size(a, 1); n = size(a, 2)
    best = norm2(b)
    do mask = 1, 2**n - 1
      cnt = 0
      do j = 1, n
        if (btest(mask, j - 1)) then
          cnt = cnt + 1; idx(cnt) = j
        end if
      end do
      if (cnt > m) cycle
      ok = .true.
      r = 0.0_wp
      do k = 1, cnt
        v = a(:, idx(k))
        nv = norm2(v)
        do i = 1, 2
          do j = 1, k - 1
            s = dot_product(q(:, j), v)
            r(j, k) = r(j, k) + s
            v = v - s * q(:, j)
          end do
        end do
        r(k, k) = norm2(v)
        if (r(k, k) <= 1.0e-9_wp * nv) then
          ok = .false.; exit
        end if
        q(:, k) = v / r(k, k)
      end do
      if (.not. ok) cycle
      do k = 1, cnt
        c(k) = dot_product(q(:, k), b)
      end do
      do k = cnt, 1, -1
        x(k) = (c(k) - dot_product(r(k, k+1:cnt), x(k+1:cnt))) / r(k, k)
      end do
      if (any(x(1:cnt) <= 0.0_wp)) cycle
      v = b
      do k = 1, cnt
        v = v - x(k) * a(:, idx(k))
      end do
      best = min(best, norm2(v))
    end do
  end function brute_nnls

  !> solve and run the generic checks (x >= 0, reported residual, KKT certificate, optimum)
  subroutine solve_check(a, b, name, x, st, ref)
    real(wp), intent(in) :: a(:,:), b(:)
    character(len=*), intent(in) :: name
    real(wp), intent(out) :: x(:)
    type(nnls_stats_t), intent(out) :: st
    real(wp), intent(in), optional :: ref
    type(error_t), allocatable :: err
    real(wp) :: res, opt, bn
    call nnls_solve(a, b, x, st, err, work=work)
    call check(.not. allocated(err), name // ": no error")
    call check(st%converged, name // ": converged")
    call check(all(x >= 0.0_wp), name // ": x >= 0")
    res = norm2(b - matmul(a, x))
    bn = max(norm2(b), tiny(1.0_wp))
    call check_close(st%residual / bn, res / bn, 1.0e-13_wp, name // ": reported residual")
    call check(st%kkt_rel <= 1.0e-12_wp, name // ": KKT certificate")
    if (present(ref)) then
      opt = ref
    else
      opt = brute_nnls(a, b)
    end if
    call check_close(res / bn, opt / bn, 1.0e-11_wp, name // ": optimal objective")
  end subroutine solve_check

  subroutine test_random_vs_enumeration()
    integer :: trial, m, n
    real(wp), allocatable :: a(:,:), b(:), x(:), bb(:,:)
    type(nnls_stats_t) :: st
    real(wp) :: rr
    logical :: all_ok
    do trial = 1, 300
      call random_number(rr); m = 1 + int(rr * 8)
      call random_number(rr); n = 1 + int(rr * 8)
      allocate(a(m, n), bb(m, 1), x(n))
      call randn(a); call randn(bb)
      b = bb(:, 1)
      call solve_check(a, b, "random trial", x, st)
      deallocate(a, bb, x)
    end do
    all_ok = .true.
    call check(all_ok, "random problems done")
  end subroutine test_random_vs_enumeration

  subroutine test_degenerate()
    real(wp) :: a(6, 5), b(6), x(5), a2(6, 7), x2(7), bb(6, 1), u(6, 2), w(2, 8), ar(6, 8), xr(8)
    real(wp) :: ref, a0(0, 3), b0(0), x0(3), an(4, 0), xn(0), y(5)
    type(nnls_stats_t) :: st
    type(error_t), allocatable :: err
    call randn(a); call randn(bb); b = bb(:, 1)
    ! duplicate and near-duplicate columns: same optimum as without them
    ref = brute_nnls(a, b)
    a2(:, 1:5) = a
    a2(:, 6) = a(:, 2)
    a2(:, 7) = a(:, 3) * (1.0_wp + 1.0e-9_wp) + 1.0e-10_wp
    call solve_check(a2, b, "duplicate columns", x2, st, ref=min(ref, brute_nnls(a2, b)))
    a2(:, 7) = a(:, 3) + 1.0e-12_wp * a(:, 4)
    call solve_check(a2, b, "near-duplicate column", x2, st, ref=min(ref, brute_nnls(a2, b)))
    ! zero column
    a2(:, 6) = 0.0_wp
    call solve_check(a2, b, "zero column", x2, st)
    call check(x2(6) == 0.0_wp, "zero column: x_j = 0")
    ! b = 0
    b = 0.0_wp
    call solve_check(a, b, "b = 0", x, st, ref=0.0_wp)
    call check(all(x == 0.0_wp) .and. st%residual == 0.0_wp, "b = 0: x = 0")
    ! b in the negative cone of a non-negative A: x = 0
    a = abs(a)
    call random_number(y)
    b = -matmul(a, y)
    call solve_check(a, b, "negative cone", x, st, ref=norm2(b))
    call check(all(x == 0.0_wp), "negative cone: x = 0")
    ! rank-deficient (rank 2, 8 columns)
    call randn(u); call randn(w)
    ar = matmul(u, w)
    call randn(bb); b = bb(:, 1)
    call solve_check(ar, b, "rank deficient", xr, st)
    ! exact fit with a rank-deficient passive set
    b = ar(:, 1) + ar(:, 2)
    call solve_check(ar, b, "rank deficient, exact fit", xr, st, ref=0.0_wp)
    ! m = 0 and n = 0
    call nnls_solve(a0, b0, x0, st, err)
    call check(.not. allocated(err) .and. all(x0 == 0.0_wp) .and. st%converged, "m = 0")
    call nnls_solve(an, b(1:4), xn, st, err)
    call check(.not. allocated(err) .and. st%converged, "n = 0")
    call check_close(st%residual, norm2(b(1:4)), 1.0e-14_wp * norm2(b(1:4)), "n = 0: residual |b|")
    ! inconsistent sizes
    call nnls_solve(a, b(1:3), x, st, err)
    call check(allocated(err), "size mismatch is an error")
  end subroutine test_degenerate

  subroutine test_scaling_and_warm()
    real(wp) :: a(8, 8), b(8), x(8), xs(8), bb(8, 1), xw(8)
    type(nnls_stats_t) :: st, sts, stw
    type(error_t), allocatable :: err
    integer :: trial, k
    real(wp), parameter :: scales(2) = [1.0e-20_wp, 1.0e15_wp]
    logical :: same
    do trial = 1, 20
      call randn(a); call randn(bb); b = bb(:, 1)
      call nnls_solve(a, b, x, st, err)
      do k = 1, 2
        call nnls_solve(a * scales(k), b * scales(k), xs, sts, err)
        same = all((x > 0.0_wp) .eqv. (xs > 0.0_wp))
        call check(same, "scaling: same support")
        call check(maxval(abs(xs - x)) <= 1.0e-12_wp * max(1.0_wp, maxval(abs(x))), "scaling: same x")
        call check(sts%kkt_rel <= 1.0e-12_wp, "scaling: KKT certificate")
      end do
      ! warm start from the solution's support: same answer, at most one iteration
      call nnls_solve(a, b, xw, stw, err, passive0=x > 0.0_wp)
      call check(maxval(abs(xw - x)) <= 1.0e-12_wp * max(1.0_wp, maxval(abs(x))), "warm: same x")
      call check(stw%iterations <= 1, "warm: converged at once")
      ! warm start from a wrong guess: same answer
      call nnls_solve(a, b, xw, stw, err, passive0=x <= 0.0_wp)
      call check(maxval(abs(xw - x)) <= 1.0e-12_wp * max(1.0_wp, maxval(abs(x))), "bad warm: same x")
      ! iteration cap
      if (count(x > 0.0_wp) >= 2) then
        call nnls_solve(a, b, xw, stw, err, max_iter=1)
        call check(.not. stw%converged .and. all(xw >= 0.0_wp), "cap: not converged, x >= 0")
      end if
    end do
  end subroutine test_scaling_and_warm

  subroutine test_ldp()
    integer :: trial, mc, n, j
    real(wp), allocatable :: bm(:,:), d(:), v(:), u(:), lam(:), uw(:), lw(:), dd(:,:), vv(:,:)
    real(wp) :: r, viol, compl, stat, bi(2, 2)
    type(ldp_stats_t) :: st, stw
    type(error_t), allocatable :: err
    do trial = 1, 100
      call random_number(r); mc = 1 + int(r * 12)
      call random_number(r); n = 1 + int(r * 8)
      allocate(bm(mc, n), dd(mc, 1), vv(n, 1), u(n), lam(mc), uw(n), lw(mc))
      call randn(bm); call randn(dd); call randn(vv)
      bm = bm * 1.0e-3_wp
      if (mod(trial, 3) == 0) dd = abs(dd)        ! u = 0 feasible
      d = dd(:, 1) * 1.0e-3_wp; v = vv(:, 1)
      lam = 0.0_wp
      call ldp_solve(bm, d, v, u, lam, st, err, work=work)
      call check(.not. allocated(err), "ldp: no error")
      if (st%infeasible) then
        deallocate(bm, dd, vv, u, lam, uw, lw)
        cycle
      end if
      viol = max(0.0_wp, maxval(matmul(bm, u) - d))
      compl = maxval(abs(lam * (matmul(bm, u) - d)))
      stat = maxval(abs(u - v + matmul(transpose(bm), lam)))
      call check(all(lam >= 0.0_wp), "ldp: lambda >= 0")
      call check(viol <= 1.0e-12_wp * maxval(abs(d)), "ldp: primal feasible")
      call check(stat <= 1.0e-12_wp * max(1.0_wp, maxval(abs(v))), "ldp: stationarity")
      call check(compl <= 1.0e-13_wp * maxval(abs(lam)) * (maxval(abs(d)) + &
        maxval(abs(bm)) * maxval(abs(u))), &
        "ldp: complementarity")
      call check(st%max_violation <= 1.0e-12_wp * maxval(abs(d)), "ldp: reported violation")
      lw = lam
      call ldp_solve(bm, d, v, uw, lw, stw, err, work=work)
      call check(maxval(abs(uw - u)) <= 1.0e-13_wp * max(1.0_wp, maxval(abs(u))), "ldp warm: same u")
      call check(stw%nnls%iterations <= 1, "ldp warm: at most one iteration")
      deallocate(bm, dd, vv, u, lam, uw, lw)
    end do
    ! infeasible: u1 <= -1 and u1 >= 1; least violation is u1 = 0, u2 = v2
    bi = reshape([1.0_wp, -1.0_wp, 0.0_wp, 0.0_wp], [2, 2])
    allocate(u(2), lam(2))
    lam = 0.0_wp
    call ldp_solve(bi, [-1.0_wp, -1.0_wp], [0.3_wp, 0.7_wp], u, lam, st, err)
    call check(.not. allocated(err), "ldp infeasible: no error")
    call check(st%infeasible, "ldp infeasible: detected")
    call check_close(u(1), 0.0_wp, 1.0e-6_wp, "ldp infeasible: least-violation u1")
    call check_close(u(2), 0.7_wp, 1.0e-9_wp, "ldp infeasible: u2 unchanged")
    call check_close(st%max_violation, 1.0_wp, 1.0e-6_wp, "ldp infeasible: violation")
    ! feasible point is its own projection
    call ldp_solve(bi, [1.0_wp, 1.0_wp], [0.3_wp, 0.7_wp], u, lam, st, err)
    call check(all(u == [0.3_wp, 0.7_wp]) .and. all(lam == 0.0_wp), "ldp: feasible v unchanged")
    j = 0
    call ldp_solve(bi, [1.0_wp], [0.3_wp, 0.7_wp], u, lam, st, err)
    call check(allocated(err), "ldp: size mismatch is an error")
  end subroutine test_ldp
end program test_nnls
