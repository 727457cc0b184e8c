!> Unit tests of the sparse dual active-set kernel (cr_contact_ldp) and of the active_set
!> solver built on it: degenerate jammed packings (exact hexagonal lattice pushed against a wall,
!> many dependent rows), agreement with the dense LDP of cr_nnls, warm starts, infeasible
!> clusters, and the memory guard for huge clusters.
program test_contact_ldp
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_test_scenes, only: seed_random, hex_scene
  use cr_contact_set, only: contact_set_t, kkt_residuals
  use cr_contact_ldp, only: contact_ldp_solve, contact_ldp_stats_t, contact_ldp_work_t
  use cr_nnls, only: ldp_solve, ldp_stats_t
  use cr_projection, only: projection_settings_t, solve_stats_t
  use cr_active_set, only: active_set_solver_t
  implicit none
  real(wp), parameter :: rad = 0.05_wp, h = 0.01_wp
  call seed_random(777)
  call test_hex_wall(0.0_wp, "exact hex")
  call test_hex_wall(1.0e-9_wp, "hex jitter 1e-9")
  call test_hex_wall(1.0e-5_wp, "hex jitter 1e-5")
  call test_infeasible()
  call test_memory_guard()
  call test_summary()

contains

  !> Dense B of a contact set [n, 2 n_agents].
  subroutine dense_b(cs, bm)
    type(contact_set_t), intent(in) :: cs
    real(wp), allocatable, intent(out) :: bm(:,:)
    integer :: l, a, b
    allocate(bm(cs%n, 2 * cs%n_agents))
    bm = 0.0_wp
    do l = 1, cs%n
      a = cs%ia(l); b = cs%ib(l)
      bm(l, 2*a - 1:2*a) = -cs%h * cs%g(:, l)
      if (b > 0) bm(l, 2*b - 1:2*b) = cs%h * cs%g(:, l)
    end do
  end subroutine dense_b

  subroutine test_hex_wall(jitter, name)
    real(wp), intent(in) :: jitter
    character(len=*), intent(in) :: name
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u(:), ud(:), lam(:), ld(:), bm(:,:), coef(:,:)
    integer, allocatable :: ia(:), ib(:)
    type(contact_ldp_stats_t) :: st
    type(contact_ldp_work_t) :: work
    type(ldp_stats_t) :: sd
    type(active_set_solver_t) :: solver
    type(solve_stats_t) :: ss
    type(error_t), allocatable :: err
    real(wp) :: p, du, cp, s
    integer :: l, rows_before
    call hex_scene(12, 10, jitter, rad, h, cs, v)
    call check(cs%n > 3 * cs%n_agents - 30, name // ": many redundant rows (" // &
      trim(adjustl(itoa(cs%n))) // " rows, 240 dof)")
    allocate(u(size(v)), ud(size(v)), lam(cs%n), ld(cs%n), ia(cs%n), ib(cs%n), coef(2, cs%n))
    do l = 1, cs%n
      ia(l) = cs%ia(l); ib(l) = cs%ib(l); coef(:, l) = -h * cs%g(:, l)
    end do
    ! cold start
    lam = 0.0_wp
    call contact_ldp_solve(ia, ib, coef, cs%gap(1:cs%n), v, u, lam, st, err, work=work)
    call check(.not. allocated(err), name // ": no error")
    call check(st%converged .and. .not. st%infeasible, name // ": converged")
    call kkt_residuals(cs, v, u, lam, p, du, cp, s)
    call check(max(p, du, cp, s) <= 1.0e-12_wp, name // ": cold KKT <= 1e-12")
    ! the projection is unique: compare with the dense LDP
    call dense_b(cs, bm)
    ld = 0.0_wp
    call ldp_solve(bm, cs%gap(1:cs%n), v, ud, ld, sd, err)
    call check(maxval(abs(u - ud)) <= 1.0e-9_wp * maxval(abs(v)), name // ": same u as dense LDP")
    ! warm start from the solution: no iteration, same u
    ld = lam
    call contact_ldp_solve(ia, ib, coef, cs%gap(1:cs%n), v, ud, ld, st, err, work=work)
    call check(st%converged .and. st%iterations == 0, name // ": warm start from the solution")
    call check(maxval(abs(u - ud)) <= 1.0e-12_wp * maxval(abs(v)), name // ": warm start same u")
    ! warm start from a poor guess (every row): dependent rows are dropped, still exact
    ld = 1.0_wp
    call contact_ldp_solve(ia, ib, coef, cs%gap(1:cs%n), v, ud, ld, st, err, work=work)
    call kkt_residuals(cs, v, ud, ld, p, du, cp, s)
    call check(st%converged .and. max(p, du, cp, s) <= 1.0e-12_wp, name // ": all-rows warm start")
    call check(maxval(abs(u - ud)) <= 1.0e-9_wp * maxval(abs(v)), name // ": all-rows same u")
    ! through the solver, on overlapping agents too (negative gaps)
    rows_before = cs%n
    cs%gap(1:cs%n) = cs%gap(1:cs%n) - 1.0e-4_wp
    call solver%init(projection_settings_t(), err)
    lam = 0.0_wp
    call solver%solve(cs, v, u, lam, ss, err)
    call check(.not. allocated(err) .and. ss%converged .and. ss%kkt <= 1.0e-10_wp, &
      name // ": active_set solver, overlapping, KKT <= 1e-10")
    call check(cs%n == rows_before, name // ": rows unchanged")
  end subroutine test_hex_wall

  !> Two agents pushed apart by rows that cannot hold together: Farkas certificate, and the
  !> solver still returns (least-violation point, with a note).
  subroutine test_infeasible()
    type(contact_set_t) :: cs
    real(wp) :: v(4), u(4), lam(3)
    type(contact_ldp_stats_t) :: st
    type(active_set_solver_t) :: solver
    type(solve_stats_t) :: ss
    type(error_t), allocatable :: err
    call cs%init(2, h, 4)
    ! agent 1 between two walls that overlap it by more than h can fix... plus agent 2 coupled
    call cs%add(1, 0, 1, [0.0_wp, 1.0_wp], -0.01_wp)
    call cs%add(1, 0, 2, [0.0_wp, -1.0_wp], -0.01_wp)
    call cs%add(1, 2, 0, [1.0_wp, 0.0_wp], 0.0_wp)
    v = [0.0_wp, 0.0_wp, -1.0_wp, 0.0_wp]
    lam = 0.0_wp
    call contact_ldp_solve(cs%ia(1:3), cs%ib(1:3), -h * cs%g(:, 1:3), cs%gap(1:3), v, u, lam, &
      st, err)
    call check(.not. allocated(err) .and. st%infeasible, "infeasible rows: Farkas certificate")
    call solver%init(projection_settings_t(), err)
    lam = 0.0_wp
    call solver%solve(cs, v, u, lam, ss, err)
    call check(.not. allocated(err), "infeasible cluster: not an error")
    call check(index(ss%note, "infeasible") > 0, "infeasible cluster: noted")
    ! feasible desired velocity with a stale warm start: u = v and lambda = 0
    cs%gap(1:3) = [0.1_wp, 0.1_wp, 0.1_wp]
    lam = 1.0_wp
    call solver%solve(cs, v, u, lam, ss, err)
    call check(all(u == v) .and. all(lam == 0.0_wp) .and. ss%kkt == 0.0_wp, &
      "feasible v, stale warm start: u = v, lambda = 0")
  end subroutine test_infeasible

  !> A cluster whose dense data would exceed the limit is an error, not an allocation.
  subroutine test_memory_guard()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u(:), lam(:)
    type(active_set_solver_t) :: solver
    type(solve_stats_t) :: ss
    type(error_t), allocatable :: err
    call hex_scene(6, 5, 0.0_wp, rad, h, cs, v)
    allocate(u(size(v)), lam(cs%n))
    call solver%init(projection_settings_t(), err)
    solver%max_dense_bytes = 1000.0_wp
    lam = 0.0_wp
    call solver%solve(cs, v, u, lam, ss, err)
    call check(allocated(err), "memory guard: error")
    if (allocated(err)) then
      call check(index(err%message, "contact cluster of 30 agents") > 0 .and. &
        index(err%message, "use solver 'gpcg'") > 0, "memory guard: clear message: " // &
        err%message)
    end if
    solver%max_dense_bytes = 1.0e9_wp
    call solver%solve(cs, v, u, lam, ss, err)
    call check(.not. allocated(err) .and. ss%kkt <= 1.0e-10_wp, "memory guard: fine below limit")
  end subroutine test_memory_guard

  pure function itoa(i) result(s)
    integer, intent(in) :: i
    character(len=12) :: s
    write(s, '(i0)') i
  end function itoa
end program test_contact_ldp
