!> Unit tests of the GPCG projection solver: random disk configurations and jammed, degenerate
!> ones (hexagonal packings of touching disks pushed against a wall or into a funnel: more rows
!> than velocities, zero gaps, B B^T singular), KKT residual, agreement of u with active_set,
!> warm start, iteration cap, cold/warm solves with thousands of agents.
program test_gpcg
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_test_scenes, only: seed_random, lattice_scene
  use cr_contact_set, only: contact_set_t
  use cr_projection, only: projection_settings_t, solve_stats_t, projection_solver_t, &
    make_projection_solver
  implicit none
  real(wp), parameter :: rad = 0.05_wp, h = 0.01_wp
  call seed_random(777)
  call test_random()
  call test_jammed()
  call test_warm_and_cap()
  call test_large()
  call test_summary()

contains

  !> Jammed scene: a hexagonal packing of nx x ny touching disks (pair gaps 0 up to round-off,
  !> clamped at 0), a wall x = 0 touched by the first column (obstacle rows, gap 0). With
  !> funnel, two more walls through (0, y_mid +- w/2) inclined at +-30 degrees towards +x, with
  !> obstacle rows for all disks closer than cutoff. Desired velocity: speed towards -x (wall /
  !> funnel throat) plus noise of relative size noise. Candidate pairs: gap < cutoff.
  subroutine jammed_scene(nx, ny, funnel, cutoff, noise, cs, v)
    integer, intent(in) :: nx, ny
    logical, intent(in) :: funnel
    real(wp), intent(in) :: cutoff, noise
    type(contact_set_t), intent(out) :: cs
    real(wp), allocatable, intent(out) :: v(:)
    real(wp), allocatable :: q(:,:), nz(:)
    real(wp) :: dist, gap, ymid, nrm(2, 2), off(2), dy
    integer :: na, i, j, k, kk, iw
    na = nx * ny
    dy = sqrt(3.0_wp) * rad
    allocate(q(2, na), nz(2 * na))
    do j = 1, ny
      do i = 1, nx
        k = i + (j - 1) * nx
        q(:, k) = [rad + (2 * i - 2 + mod(j - 1, 2)) * rad, rad + (j - 1) * dy]
      end do
    end do
    call cs%init(na, h, 5 * na)
    do k = 1, na
      ! lattice neighbours lie within two rows
      do kk = k + 1, min(na, k + 2 * nx + 2)
        dist = norm2(q(:, k) - q(:, kk))
        gap = dist - 2.0_wp * rad
        if (gap < cutoff) call cs%add(k, kk, 0, (q(:, k) - q(:, kk)) / dist, max(gap, 0.0_wp))
      end do
      gap = q(1, k) - rad
      if (gap < cutoff) call cs%add(k, 0, 1, [1.0_wp, 0.0_wp], max(gap, 0.0_wp))
    end do
    if (funnel) then
      ! walls through (0, ymid +- off) with inward unit normals nrm(:, iw)
      ymid = 0.5_wp * (q(2, 1) + q(2, na))
      off = [-0.25_wp, 0.25_wp] * (q(2, na) - q(2, 1))
      nrm(:, 1) = [-0.5_wp, sqrt(3.0_wp) / 2.0_wp]
      nrm(:, 2) = [-0.5_wp, -sqrt(3.0_wp) / 2.0_wp]
      do iw = 1, 2
        do k = 1, na
          gap = dot_product(q(:, k) - [0.0_wp, ymid + off(iw)], nrm(:, iw)) - rad
          if (gap < cutoff .and. gap > -4.0_wp * rad) &
            call cs%add(k, 0, 1 + iw, nrm(:, iw), max(gap, 0.0_wp))
        end do
      end do
    end if
    call random_number(nz)
    allocate(v(2 * na))
    do k = 1, na
      v(2*k - 1:2*k) = [-1.0_wp, 0.0_wp] + noise * (nz(2*k - 1:2*k) - 0.5_wp)
    end do
  end subroutine jammed_scene

  subroutine build(name, s, solver)
    character(len=*), intent(in) :: name
    type(projection_settings_t), intent(inout) :: s
    class(projection_solver_t), allocatable, intent(out) :: solver
    type(error_t), allocatable :: err
    s%name = name
    call make_projection_solver(s, solver, err)
    call check(.not. allocated(err), "factory builds " // name)
  end subroutine build

  !> Solve with gpcg (cold) and active_set; check KKT <= 1e-10 and u agreement to 1e-9.
  subroutine compare(cs, v, what)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    character(len=*), intent(in) :: what
    real(wp), allocatable :: ua(:), ug(:), la(:), lg(:)
    class(projection_solver_t), allocatable :: sa, sg
    type(projection_settings_t) :: s
    type(solve_stats_t) :: sta, stg
    type(error_t), allocatable :: err
    real(wp) :: du
    allocate(ua(size(v)), ug(size(v)), la(cs%n), lg(cs%n))
    la = 0.0_wp; lg = 0.0_wp
    s = projection_settings_t()
    call build('active_set', s, sa)
    call sa%solve(cs, v, ua, la, sta, err)
    call build('gpcg', s, sg)
    call sg%solve(cs, v, ug, lg, stg, err)
    call check(.not. allocated(err), what // ": gpcg no error")
    call check(stg%converged .and. stg%kkt <= 1.0e-10_wp, what // ": gpcg KKT <= 1e-10")
    call check(all(lg >= 0.0_wp), what // ": gpcg lambda >= 0")
    du = maxval(abs(ug - ua)) / maxval(abs(v))
    if (sta%kkt <= 1.0e-10_wp) then
      call check(du <= 1.0e-9_wp, what // ": gpcg agrees with active_set on u")
    else
      print '(2a, es10.3)', what, ": active_set itself has KKT", sta%kkt
    end if
    print '(a, a, i0, a, i0, a, i0, a, i0, a, es9.2, a, es9.2, a, es9.2)', what, ": ", &
      cs%n_agents, " agents, ", cs%n, " rows, ", count(lg > 0.0_wp), " active, ", &
      stg%iterations, " iterations, kkt ", stg%kkt, " (active_set ", sta%kkt, "), |du| ", du
    if (len(stg%note) > 0) print '(3a)', what, ": note: ", stg%note
  end subroutine compare

  subroutine test_random()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:)
    integer :: trial
    character(len=16) :: tag
    do trial = 1, 6
      call lattice_scene(3 + mod(trial, 3) * 3, 3 + trial, 4, 0.03_wp, rad, h, cs, v)
      write(tag, '(a, i0)') "random ", trial
      call compare(cs, v, trim(tag))
    end do
  end subroutine test_random

  subroutine test_jammed()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:)
    call jammed_scene(8, 6, .false., 0.01_wp, 0.0_wp, cs, v)
    call check(cs%n > size(v), "jam: more rows than velocity components")
    call compare(cs, v, "jam wall, no noise")
    call jammed_scene(10, 9, .false., 0.01_wp, 1.0_wp, cs, v)
    call compare(cs, v, "jam wall, noise")
    call jammed_scene(12, 11, .true., 0.02_wp, 0.5_wp, cs, v)
    call compare(cs, v, "jam funnel")
    call jammed_scene(16, 14, .true., 0.02_wp, 3.0_wp, cs, v)
    call compare(cs, v, "jam funnel, large noise")
  end subroutine test_jammed

  subroutine test_warm_and_cap()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u0(:), u(:), l0(:), l(:)
    class(projection_solver_t), allocatable :: sg
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    call jammed_scene(10, 8, .true., 0.02_wp, 1.0_wp, cs, v)
    allocate(u0(size(v)), u(size(v)), l0(cs%n), l(cs%n))
    s = projection_settings_t()
    call build('gpcg', s, sg)
    l0 = 0.0_wp
    call sg%solve(cs, v, u0, l0, st, err)
    call check(st%converged, "warm: cold solve converged")
    ! warm start from the solution: converged at once
    l = l0
    call sg%solve(cs, v, u, l, st, err)
    call check(st%converged .and. st%iterations == 0, "warm: solution accepted without iterations")
    call check(maxval(abs(u - u0)) <= 1.0e-13_wp * maxval(abs(v)), "warm: same u")
    ! warm start for a slightly different v: few iterations
    l = l0
    call sg%solve(cs, 1.01_wp * v, u, l, st, err)
    call check(st%converged .and. st%kkt <= 1.0e-10_wp, "warm: perturbed v converges")
    print '(a, i0, a)', "warm, v * 1.01: ", st%iterations, " iterations"
    ! warm_start = .false. ignores the given multipliers
    s%warm_start = .false.
    call build('gpcg', s, sg)
    l = 1.0e3_wp
    call sg%solve(cs, v, u, l, st, err)
    call check(st%converged .and. maxval(abs(u - u0)) <= 1.0e-9_wp * maxval(abs(v)), &
      "cold (warm_start = .false.): same u")
    ! iteration cap: not converged, a note, a finite feasible best iterate
    s = projection_settings_t()
    s%max_iter = 3
    call build('gpcg', s, sg)
    l = 0.0_wp
    call sg%solve(cs, v, u, l, st, err)
    call check(.not. allocated(err), "cap: not an error")
    call check(.not. st%converged .and. index(st%note, "cap") > 0, "cap: flagged with a note")
    call check(st%iterations <= 3, "cap: respected")
    call check(all(ieee_is_finite(u)) .and. all(ieee_is_finite(l)) .and. all(l >= 0.0_wp), &
      "cap: finite best iterate")
    ! no rows, size mismatch
    call cs%clear()
    call sg%solve(cs, v, u, l, st, err)
    call check(st%converged .and. all(u == v), "no rows: u = v")
    call sg%solve(cs, v(1:4), u, l, st, err)
    call check(allocated(err), "size mismatch is an error")
  end subroutine test_warm_and_cap

  !> Thousands of agents: jammed funnel with noise (cold, then warm for a perturbed v) and a
  !> random scene; timed.
  subroutine test_large()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u(:), l(:)
    class(projection_solver_t), allocatable :: sg
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    integer(8) :: c0, c1, rate
    call jammed_scene(24, 20, .true., 0.02_wp, 1.0_wp, cs, v)
    allocate(u(size(v)), l(cs%n))
    s = projection_settings_t()
    call build('gpcg', s, sg)
    l = 0.0_wp
    call system_clock(c0, rate)
    call sg%solve(cs, v, u, l, st, err)
    call system_clock(c1)
    call check(st%converged .and. st%kkt <= 1.0e-10_wp, "large jam: KKT <= 1e-10")
    print '(a, i0, a, i0, a, i0, a, i0, a, es9.2, a, f8.3, a)', "large jam: ", cs%n_agents, &
      " agents, ", cs%n, " rows, ", count(l > 0.0_wp), " active, cold ", st%iterations, &
      " iterations, kkt ", st%kkt, ", ", real(c1 - c0, wp) / rate, " s"
    call system_clock(c0)
    call sg%solve(cs, v * 1.01_wp, u, l, st, err)
    call system_clock(c1)
    call check(st%converged .and. st%kkt <= 1.0e-10_wp, "large jam warm: KKT <= 1e-10")
    print '(a, i0, a, es9.2, a, f8.3, a)', "large jam: warm ", st%iterations, &
      " iterations, kkt ", st%kkt, ", ", real(c1 - c0, wp) / rate, " s"
    call lattice_scene(50, 40, 50, 0.03_wp, rad, h, cs, v)
    deallocate(u, l)
    allocate(u(size(v)), l(cs%n))
    l = 0.0_wp
    call system_clock(c0)
    call sg%solve(cs, v, u, l, st, err)
    call system_clock(c1)
    call check(st%converged .and. st%kkt <= 1.0e-10_wp, "large random: KKT <= 1e-10")
    print '(a, i0, a, i0, a, i0, a, es9.2, a, f8.3, a)', "large random: ", cs%n_agents, &
      " agents, ", cs%n, " rows, cold ", st%iterations, " iterations, kkt ", st%kkt, ", ", &
      real(c1 - c0, wp) / rate, " s"
  end subroutine test_large
end program test_gpcg
