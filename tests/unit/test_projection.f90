!> Unit tests of the projection solvers on random disk configurations: KKT of each method,
!> agreement of the three, brute-force enumeration on tiny problems, warm start, Uzawa step
!> bound, iteration caps, factory errors.
program test_projection
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_test_scenes, only: seed_random, lattice_scene
  use cr_contact_set, only: contact_set_t
  use cr_projection, only: projection_settings_t, solve_stats_t, projection_solver_t, &
    make_projection_solver
  implicit none
  real(wp), parameter :: rad = 0.05_wp, h = 0.01_wp
  call seed_random(4242)
  call test_agreement()
  call test_brute_force()
  call test_warm_and_caps()
  call test_factory()
  call test_timing()
  call test_summary()

contains

  subroutine build(name, s, solver)
    character(len=*), intent(in) :: name
    type(projection_settings_t), intent(inout) :: s
    class(projection_solver_t), allocatable, intent(out) :: solver
    type(error_t), allocatable :: err
    s%name = name
    call make_projection_solver(s, solver, err)
    call check(.not. allocated(err), "factory builds " // name)
  end subroutine build

  subroutine test_agreement()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), ua(:), ug(:), uu(:), la(:), lg(:), lu(:)
    class(projection_solver_t), allocatable :: sa, sg, su
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    integer :: trial, nx, ny
    real(wp) :: lb
    do trial = 1, 6
      nx = 3 + mod(trial, 3) * 2; ny = 3 + trial / 2
      call lattice_scene(nx, ny, 3, 0.03_wp, rad, h, cs, v, near_touch=.true.)
      allocate(ua(size(v)), ug(size(v)), uu(size(v)), la(cs%n), lg(cs%n), lu(cs%n))
      la = 0.0_wp; lg = 0.0_wp; lu = 0.0_wp
      s = projection_settings_t()
      call build('active_set', s, sa)
      call sa%solve(cs, v, ua, la, st, err)
      call check(.not. allocated(err), "active_set: no error")
      call check(st%converged .and. st%kkt <= 1.0e-12_wp, "active_set: KKT <= 1e-12")
      if (st%kkt > 1.0e-12_wp) print '(a, es10.3, 1x, a)', "  active_set kkt", st%kkt, st%note
      call check(count(la > 0.0_wp) > 0, "scene has active contacts")
      s%tol = 1.0e-12_wp
      call build('apgd', s, sg)
      call sg%solve(cs, v, ug, lg, st, err)
      call check(st%converged .and. st%kkt <= 1.0e-12_wp, "apgd: reaches tol")
      call check(maxval(abs(ug - ua)) <= 1.0e-9_wp * maxval(abs(v)), "apgd agrees with active_set on u")
      if (trial <= 2) then
        ! Uzawa with rho = 1/L (within the bound 2/L), tight stopping test
        lb = cs%lipschitz_bound()
        s%uzawa_rho_factor = h**2 / lb
        s%uzawa_eps = 1.0e-15_wp
        call build('uzawa', s, su)
        call su%solve(cs, v, uu, lu, st, err)
        call check(st%converged .and. .not. st%rho_above_bound, "uzawa: converges")
        call check(maxval(abs(uu - ua)) <= 1.0e-9_wp * maxval(abs(v)), "uzawa agrees on u")
        if (maxval(abs(uu - ua)) > 1.0e-9_wp * maxval(abs(v))) print *, " uzawa", st%iterations, &
          st%kkt, maxval(abs(uu - ua))
      end if
      deallocate(ua, ug, uu, la, lg, lu)
    end do
  end subroutine test_agreement

  !> Tiny problems (<= 10 rows): enumerate all active sets S, lambda_S = (B_S B_S^T)^{-1}
  !> (B_S v - d_S); the one with lambda_S >= 0 and a feasible u is the solution.
  subroutine test_brute_force()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u(:), lam(:), bd(:,:), ub(:), lb(:)
    class(projection_solver_t), allocatable :: sa
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    integer :: trial, n, nd, mask, k, i, info, found
    integer, allocatable :: idx(:)
    real(wp), allocatable :: g(:,:), rhs(:), e(:)
    real(wp) :: piv
    s = projection_settings_t()
    call build('active_set', s, sa)
    do trial = 1, 20
      call lattice_scene(2 + mod(trial, 2), 2, 2, 0.01_wp, rad, h, cs, v, near_touch=.true.)
      n = cs%n; nd = size(v)
      if (n > 10) cycle
      allocate(bd(n, nd), u(nd), lam(n), ub(nd), lb(n), idx(n), e(n))
      do k = 1, nd
        ub = 0.0_wp; ub(k) = 1.0_wp
        call cs%apply_b(ub, bd(:, k))
      end do
      lam = 0.0_wp
      call sa%solve(cs, v, u, lam, st, err)
      found = 0
      do mask = 0, 2**n - 1
        k = 0
        do i = 1, n
          if (btest(mask, i - 1)) then
            k = k + 1; idx(k) = i
          end if
        end do
        g = matmul(bd(idx(1:k), :), transpose(bd(idx(1:k), :)))
        ! rhs allocated with its size: gfortran 12's inlined matmul does not reallocate an
        ! allocatable whose old size equals size(v) (here k varies from subset to subset)
        if (allocated(rhs)) deallocate(rhs)
        allocate(rhs(k))
        rhs(:) = matmul(bd(idx(1:k), :), v) - cs%gap(idx(1:k))
        call chol_solve(g, rhs, info, piv)
        if (info /= 0) cycle
        if (any(rhs < -1.0e-14_wp)) cycle
        lb = 0.0_wp; lb(idx(1:k)) = rhs
        ub = v - matmul(transpose(bd), lb)
        e = matmul(bd, ub) - cs%gap(1:n)
        if (any(e > 1.0e-13_wp * maxval(abs(cs%gap(1:n))))) cycle
        found = found + 1
        call check(maxval(abs(ub - u)) <= 1.0e-12_wp * maxval(abs(v)), "brute force: same u")
        if (piv > 1.0e-6_wp) call check(maxval(abs(lb - lam(1:n))) <= 1.0e-9_wp * &
          max(1.0_wp, maxval(abs(lb))), "brute force: same lambda (independent rows)")
        exit
      end do
      call check(found == 1, "brute force: optimal active set found")
      deallocate(bd, u, lam, ub, lb, idx, e)
    end do
  end subroutine test_brute_force

  !> Cholesky solve of a small SPD system in place; info /= 0 when (numerically) singular;
  !> piv = min pivot^2 / max diagonal (a conditioning indicator).
  subroutine chol_solve(a, b, info, piv)
    real(wp), intent(inout) :: a(:,:), b(:)
    integer, intent(out) :: info
    real(wp), intent(out) :: piv
    integer :: n, j, i
    real(wp) :: dmax
    n = size(b); info = 0; piv = 1.0_wp
    if (n == 0) return
    dmax = maxval([(a(i, i), i = 1, n)])
    do j = 1, n
      a(j, j) = a(j, j) - dot_product(a(j, 1:j-1), a(j, 1:j-1))
      if (a(j, j) <= 1.0e-10_wp * dmax) then
        info = j; return
      end if
      piv = min(piv, a(j, j) / dmax)
      a(j, j) = sqrt(a(j, j))
      do i = j + 1, n
        a(i, j) = (a(i, j) - dot_product(a(i, 1:j-1), a(j, 1:j-1))) / a(j, j)
      end do
    end do
    do i = 1, n
      b(i) = (b(i) - dot_product(a(i, 1:i-1), b(1:i-1))) / a(i, i)
    end do
    do i = n, 1, -1
      b(i) = (b(i) - dot_product(a(i+1:n, i), b(i+1:n))) / a(i, i)
    end do
  end subroutine chol_solve

  subroutine test_warm_and_caps()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u0(:), u(:), l0(:), l(:)
    class(projection_solver_t), allocatable :: sa, sg, su
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    call lattice_scene(5, 4, 3, 0.03_wp, rad, h, cs, v, near_touch=.true.)
    allocate(u0(size(v)), u(size(v)), l0(cs%n), l(cs%n))
    s = projection_settings_t()
    call build('active_set', s, sa)
    l0 = 0.0_wp
    call sa%solve(cs, v, u0, l0, st, err)
    ! warm start from the solution
    l = l0
    call sa%solve(cs, v, u, l, st, err)
    call check(maxval(abs(u - u0)) <= 1.0e-13_wp * maxval(abs(v)), "active_set warm: same u")
    call check(st%iterations <= 1, "active_set warm: <= 1 iteration per cluster")
    call build('apgd', s, sg)
    l = l0
    call sg%solve(cs, v, u, l, st, err)
    call check(maxval(abs(u - u0)) <= 1.0e-9_wp * maxval(abs(v)), "apgd warm: same u")
    call check(st%iterations <= 10, "apgd warm: few iterations")
    ! iteration caps: not converged, a note, finite best iterate
    s%max_iter = 3
    call build('apgd', s, sg)
    l = 0.0_wp
    call sg%solve(cs, v, u, l, st, err)
    call check(.not. allocated(err), "apgd cap: not an error")
    call check(.not. st%converged .and. index(st%note, "cap") > 0, "apgd cap: flagged with a note")
    call check(all(ieee_is_finite(u)) .and. all(l >= 0.0_wp), "apgd cap: finite best iterate")
    s%max_iter = 1
    call build('active_set', s, sa)
    l = 0.0_wp
    call sa%solve(cs, v, u, l, st, err)
    call check(.not. st%converged .and. index(st%note, "cap") > 0, "active_set cap: flagged")
    call check(all(ieee_is_finite(u)) .and. all(l >= 0.0_wp), "active_set cap: finite iterate")
    s = projection_settings_t()
    s%uzawa_max_iter = 5
    call build('uzawa', s, su)
    l = 0.0_wp
    call su%solve(cs, v, u, l, st, err)
    call check(.not. st%converged .and. index(st%note, "cap") > 0, "uzawa cap: flagged")
    call check(all(ieee_is_finite(u)), "uzawa cap: finite iterate")
    ! rho above the bound 2/L
    s%uzawa_rho_factor = 4.0_wp * h**2 / cs%lipschitz_bound()
    call build('uzawa', s, su)
    call su%solve(cs, v, u, l, st, err)
    call check(st%rho_above_bound .and. index(st%note, "bound") > 0, "uzawa: rho above bound flagged")
    ! far above the bound Uzawa diverges: an error naming rho and the bound, before any overflow
    s%uzawa_rho_factor = 200.0_wp * h**2 / cs%lipschitz_bound()
    s%uzawa_max_iter = 1000000
    call build('uzawa', s, su)
    l = 0.0_wp
    call su%solve(cs, v, u, l, st, err)
    call check(allocated(err), "uzawa: divergence is an error")
    if (allocated(err)) call check(index(err%message, "diverged") > 0 .and. &
      index(err%message, "convergence bound") > 0, "uzawa: divergence message names rho and the bound")
    call check(st%iterations < 1000000, "uzawa: divergence detected before the iteration cap")
    ! sizes
    call sa%solve(cs, v(1:4), u, l, st, err)
    call check(allocated(err), "size mismatch is an error")
  end subroutine test_warm_and_caps

  subroutine test_factory()
    type(projection_settings_t) :: s
    class(projection_solver_t), allocatable :: solver
    type(error_t), allocatable :: err
    s%name = 'newton'
    call make_projection_solver(s, solver, err)
    call check(allocated(err), "factory: unknown name rejected")
    if (allocated(err)) then
      call check(index(err%message, "newton") > 0 .and. index(err%message, "'uzawa'") > 0 .and. &
        index(err%message, "'apgd'") > 0 .and. index(err%message, "'active_set'") > 0, &
        "factory: message lists the known names")
    end if
    s%name = 'APGD'
    call make_projection_solver(s, solver, err)
    call check(.not. allocated(err), "factory: case-insensitive")
    if (.not. allocated(err)) call check(solver%name() == 'apgd', "factory: name()")
    s%name = 'uzawa'; s%tol = -1.0_wp
    call make_projection_solver(s, solver, err)
    call check(allocated(err), "factory: bad tol rejected")
  end subroutine test_factory

  !> Largest scene: ~150 agents in one cluster, ~400 rows; time cold and warm solves.
  subroutine test_timing()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u(:), l(:), l0(:)
    class(projection_solver_t), allocatable :: sa
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    integer(8) :: c0, c1, rate
    integer :: k, nrep, it_cold
    real(wp) :: t_cold, t_warm
    call lattice_scene(12, 13, 10, 0.047_wp, rad, h, cs, v, near_touch=.true.)
    allocate(u(size(v)), l(cs%n), l0(cs%n))
    s = projection_settings_t()
    call build('active_set', s, sa)
    nrep = 5
    call system_clock(c0, rate)
    do k = 1, nrep
      l = 0.0_wp
      call sa%solve(cs, v, u, l, st, err)
    end do
    call system_clock(c1)
    t_cold = real(c1 - c0, wp) / rate / nrep
    it_cold = st%iterations
    call check(st%kkt <= 1.0e-12_wp, "large scene: KKT <= 1e-12")
    l0 = l
    ! warm: previous multipliers, slightly perturbed desired velocity
    call system_clock(c0)
    do k = 1, nrep
      l = l0
      call sa%solve(cs, v * (1.0_wp + 1.0e-3_wp * k), u, l, st, err)
    end do
    call system_clock(c1)
    t_warm = real(c1 - c0, wp) / rate / nrep
    call check(st%kkt <= 1.0e-12_wp, "large scene warm: KKT <= 1e-12")
    print '(a, i0, a, i0, a, i0, a, i0, a)', "timing: ", cs%n_agents, " agents, ", cs%n, &
      " rows, ", count(l0 > 0.0_wp), " active; cold ", it_cold, " iterations"
    print '(a, f9.3, a, f9.3, a, i0, a)', "timing: active_set cold ", 1.0e3_wp * t_cold, &
      " ms, warm ", 1.0e3_wp * t_warm, " ms (", st%iterations, " iterations)"
  end subroutine test_timing
end program test_projection
