!> Unit tests of the sparse dual active-set projection (cr_sparse_as, CHOLMOD factor updates):
!> agreement with the dense active_set solver on random and jammed scenes, degenerate active
!> sets, factor drift over long sequences of updates, and the new options' bad input.
program test_sparse_as
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_assert, only: check, test_summary
  use cr_test_scenes, only: seed_random, lattice_scene, hex_scene
  use cr_contact_set, only: contact_set_t
  use cr_projection, only: projection_settings_t, solve_stats_t, projection_solver_t, &
    make_projection_solver
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
  use cr_sparse_as, only: sparse_as_solver_t, sparse_as_settings_t, pivot_lower_bound
  use cr_cholmod, only: chol_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  real(wp), parameter :: rad = 0.05_wp, h = 0.01_wp
  call seed_random(2024)
  call test_random()
  call test_degenerate()
  call test_warm()
  call test_drift()
  call test_analysed_set()
  call test_step_back()
  call test_reuse()
  call test_tail_slots()
  call test_rowdel_refusal()
  call test_zero_pivot_factor()
  call test_sweeps_dependent()
  call test_options()
  call test_knobs()
  call test_kernels()
  call test_pivot_bound()
  call test_summary()

contains

  !> Solve with active_set and sparse_active_set (sparse path forced); compare. Both solve to
  !> scaled KKT <= tol; the projection is unique and the dual problem's solution u depends
  !> Lipschitz-continuously (constant 1) on the data, so two tol-accurate answers agree on u to
  !> a small multiple of tol |v| (checked at 10 tol: primal, stationarity and complementarity
  !> errors of both add up).
  subroutine compare(cs, v, name, tol)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    character(len=*), intent(in) :: name
    real(wp), intent(in) :: tol
    class(projection_solver_t), allocatable :: sa
    type(sparse_as_solver_t) :: sp
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st, sta, std
    type(projection_settings_t) :: defaults
    type(error_t), allocatable :: err
    real(wp), allocatable :: ua(:), us(:), ud(:), la(:), ls(:)
    allocate(ua(size(v)), us(size(v)), ud(size(v)), la(cs%n), ls(cs%n))
    s = projection_settings_t(); s%tol = tol; s%name = 'active_set'
    call make_projection_solver(s, sa, err)
    la = 0; ls = 0
    call sa%solve(cs, v, ua, la, sta, err)
    call check(.not. allocated(err) .and. sta%kkt <= tol, name // ": active_set reaches tol")
    s%name = 'sparse_active_set'; s%dense_rows = 0
    call sp%init(s, err)
    call sp%solve(cs, v, us, ls, st, err)
    call check(.not. allocated(err), name // ": sparse no error")
    call check(st%converged .and. st%kkt <= tol, name // ": sparse reaches tol")
    call check(st%n_fallback == 0, name // ": sparse path, no fallback")
    call check(maxval(abs(us - ua)) <= 10.0_wp * tol * max(maxval(abs(v)), 1.0_wp), &
      name // ": same u as active_set")
    ! the default split (small clusters to the dense kernel, the rest sparse): same u
    s%dense_rows = defaults%dense_rows
    call sp%free()
    call sp%init(s, err)
    ls = 0
    call sp%solve(cs, v, ud, ls, std, err)
    call check(.not. allocated(err) .and. std%converged .and. std%kkt <= tol, &
      name // ": default dense_rows reaches tol")
    call check(maxval(abs(ud - ua)) <= 10.0_wp * tol * max(maxval(abs(v)), 1.0_wp), &
      name // ": default dense_rows, same u")
    print '(2x,a,": rows ",i0," active ",i0," it ",i0," fac ",i0," mod ",i0," kkt ",es9.2," |du| ",es9.2, 1x, a)', &
      name, cs%n, count(ls > 0), st%iterations, st%n_factor, st%n_modify, st%kkt, &
      maxval(abs(us - ua)) / maxval(abs(v)), st%note
  end subroutine compare

  subroutine test_random()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:)
    integer :: trial
    do trial = 1, 6
      call lattice_scene(3 + mod(trial, 3) * 4, 3 + trial, 3, 0.03_wp, rad, h, cs, v, near_touch=.true.)
      call compare(cs, v, "lattice " // achar(48 + trial), 1.0e-10_wp)
    end do
    call hex_scene(12, 10, 0.0_wp, rad, h, cs, v)
    call compare(cs, v, "hex exact", 1.0e-10_wp)
    call hex_scene(12, 10, 1.0e-9_wp, rad, h, cs, v)
    call compare(cs, v, "hex 1e-9", 1.0e-10_wp)
  end subroutine test_random

  !> Degenerate active sets: duplicate rows, an agent wedged between two door corners, rows
  !> that cannot hold together (infeasible: flagged and handed to the safe path), a jammed
  !> hexagonal packing with overlaps.
  subroutine test_degenerate()
    type(contact_set_t) :: cs, cs2
    real(wp), allocatable :: v(:), u(:), l(:)
    type(sparse_as_solver_t) :: sp
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    integer :: j
    ! duplicate contacts: every row of a jittered lattice twice
    call lattice_scene(8, 8, 4, 0.03_wp, rad, h, cs, v)
    call cs2%init(cs%n_agents, h, 2 * cs%n)
    do j = 1, cs%n
      call cs2%add(cs%ia(j), cs%ib(j), cs%ob(j), cs%g(:, j), cs%gap(j))
      call cs2%add(cs%ia(j), cs%ib(j), cs%ob(j), cs%g(:, j), cs%gap(j))
    end do
    call compare(cs2, v, "duplicate rows", 1.0e-10_wp)
    ! wedged: agent 1 between two door corners (normals at +-60 degrees from the y axis, both
    ! touching), pushed down into the gap, neighbours 2 and 3 above pushing down on it
    call cs%init(3, h, 8)
    call cs%add(1, 0, 1, [sin(1.0_wp), cos(1.0_wp)], 0.0_wp)
    call cs%add(1, 0, 2, [-sin(1.0_wp), cos(1.0_wp)], 0.0_wp)
    call cs%add(2, 1, 0, [0.5_wp, sqrt(0.75_wp)], 0.0_wp)
    call cs%add(3, 1, 0, [-0.5_wp, sqrt(0.75_wp)], 0.0_wp)
    call cs%add(2, 3, 0, [1.0_wp, 0.0_wp], 0.0_wp)
    v = [0.0_wp, -1.0_wp, 0.1_wp, -2.0_wp, -0.1_wp, -2.0_wp]
    call compare(cs, v, "wedged in a door", 1.0e-10_wp)
    ! infeasible: agent 1 overlapping two opposite walls
    call cs%init(1, h, 4)
    call cs%add(1, 0, 1, [1.0_wp, 0.0_wp], -1.0e-3_wp)
    call cs%add(1, 0, 2, [-1.0_wp, 0.0_wp], -1.0e-3_wp)
    v = [0.0_wp, 0.0_wp]
    allocate(u(2), l(2)); l = 0
    s = projection_settings_t(); s%name = 'sparse_active_set'; s%dense_rows = 0
    call sp%init(s, err)
    call sp%solve(cs, v, u, l, st, err)
    call check(.not. allocated(err), "infeasible: no error")
    call check(.not. (st%converged .and. st%kkt <= s%tol) .and. st%n_fallback == 1 .and. &
      index(st%note, "infeasible") > 0, "infeasible: flagged, counted, noted")
    ! jammed hexagonal packing, overlapping by 1e-4 (negative gaps)
    call hex_scene(12, 10, 0.0_wp, rad, h, cs, v)
    cs%gap(1:cs%n) = cs%gap(1:cs%n) - 1.0e-4_wp
    call compare(cs, v, "hex overlapping", 1.0e-10_wp)
    call hex_scene(12, 10, 1.0e-5_wp, rad, h, cs, v)
    call compare(cs, v, "hex 1e-5", 1.0e-10_wp)
  end subroutine test_degenerate

  !> Warm start from the solution: it already meets the KKT test, so no iteration and no
  !> factorisation (counted in n_warm_exact), same u.
  subroutine test_warm()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u(:), u2(:), l(:)
    type(sparse_as_solver_t) :: sp
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    call lattice_scene(10, 10, 5, 0.03_wp, rad, h, cs, v)
    allocate(u(size(v)), u2(size(v)), l(cs%n)); l = 0
    s = projection_settings_t(); s%name = 'sparse_active_set'; s%dense_rows = 0
    call sp%init(s, err)
    call sp%solve(cs, v, u, l, st, err)
    call sp%solve(cs, v, u2, l, st, err)
    call check(st%converged .and. st%kkt <= s%tol .and. st%iterations == 0 .and. st%n_factor == 0 &
      .and. st%n_modify == 0 .and. sp%state%n_warm_exact == 1, &
      "warm start from the solution: no iteration, no factorisation")
    call check(maxval(abs(u - u2)) <= 1.0e-12_wp * maxval(abs(v)), "warm start: same u")
    ! cold start through the dense kernel (dense_rows above the row count): same u
    s%dense_rows = cs%n
    call sp%free()
    call sp%init(s, err)
    l = 0
    call sp%solve(cs, v, u2, l, st, err)
    call check(st%converged .and. st%n_factor == 0, "dense kernel for small problems")
    call check(maxval(abs(u - u2)) <= 10.0_wp * s%tol * maxval(abs(v)), "dense kernel: same u")
  end subroutine test_warm

  !> A long trajectory (agents pulled into a jam, contacts rebuilt every step, warm started by
  !> identity) with many active-set changes. With refresh_every = 7 the updated factor is
  !> checked every 7 modifications before a fresh factorisation replaces it
  !> (stats%factor_drift: backward error |M_P z - c_P| / (|M_P| |z| + |c_P|) of a solve with
  !> the updated factor; a fresh factor gives about eps). The solver relies on updated factors
  !> being backward stable to well within sqrt(eps) (the final iterative refinement and the KKT
  !> check with a fresh refactorisation cover the rest); the test checks that bound and that
  !> every step agrees with active_set. The Schur pivot tests take the elimination-tree reach
  !> (reach_min = 0), the path used on large problems, so that a pattern outside it would show.
  subroutine test_drift()
    integer, parameter :: na = 144, nsteps = 60
    type(contact_set_t) :: cs
    type(sparse_as_solver_t) :: sp
    class(projection_solver_t), allocatable :: sa
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st, sta
    type(error_t), allocatable :: err
    real(wp) :: q(2, na), v(2 * na), u(2 * na), ua(2 * na), c(2), d(2), dist, drift, du, hh
    real(wp), allocatable :: l(:), la(:), lprev(:)
    integer, allocatable :: kprev(:, :)
    integer :: i, j, k, step, nmod, nfail, nprev, p
    hh = 0.005_wp
    do j = 1, 12
      do i = 1, 12
        q(:, i + 12 * (j - 1)) = [i, j] * (2.0_wp * rad + 0.02_wp)
      end do
    end do
    c = sum(q, dim=2) / na
    s = projection_settings_t(); s%name = 'sparse_active_set'; s%dense_rows = 0; s%refresh_every = 7
    call sp%init(s, err)
    sp%knobs%check_drift = .true.
    ! the Schur pivot tests through the elimination-tree reach and factorisations from the
    ! packed identity (the paths of large problems)
    sp%state%chol%reach_min = 0; sp%state%chol%pack_min = 0
    s%name = 'active_set'
    call make_projection_solver(s, sa, err)
    drift = 0; du = 0; nmod = 0; nfail = 0; nprev = 0
    allocate(lprev(0), kprev(2, 0))
    do step = 1, nsteps
      call cs%init(na, hh, 8 * na)
      do i = 1, na
        do j = i + 1, na
          dist = norm2(q(:, i) - q(:, j))
          if (dist - 2.0_wp * rad < 0.05_wp) call cs%add(i, j, 0, (q(:, i) - q(:, j)) / dist, &
            dist - 2.0_wp * rad)
        end do
        d = q(:, i) - c
        v(2*i - 1:2*i) = -3.0_wp * d / max(norm2(d), 1.0e-3_wp) + 0.5_wp * [cos(0.3_wp * step + i), &
          sin(0.7_wp * step - i)]
      end do
      allocate(l(cs%n), la(cs%n))
      l = 0
      do k = 1, cs%n
        do p = 1, nprev
          if (kprev(1, p) == cs%ia(k) .and. kprev(2, p) == cs%ib(k)) l(k) = lprev(p)
        end do
      end do
      la = l
      call sp%solve(cs, v, u, l, st, err)
      call sa%solve(cs, v, ua, la, sta, err)
      if (.not. (st%converged .and. st%kkt <= s%tol) .or. st%n_fallback > 0) nfail = nfail + 1
      drift = max(drift, st%factor_drift)
      du = max(du, maxval(abs(u - ua)) / maxval(abs(v)))
      nmod = nmod + st%n_modify
      nprev = cs%n
      deallocate(lprev, kprev)
      allocate(lprev(nprev), kprev(2, nprev))
      lprev = l(1:nprev); kprev(1, :) = cs%ia(1:nprev); kprev(2, :) = cs%ib(1:nprev)
      q = q + hh * reshape(u, [2, na])
      deallocate(l, la)
    end do
    print '(2x,a,i0,a,i0,a,es9.2,a,es9.2)', "drift: ", nsteps, " steps, ", nmod, &
      " factor modifications, largest backward error of an updated factor ", drift, ", largest |u - u_active_set| ", du
    call check(nfail == 0, "drift: every step converged on the sparse path")
    call check(nmod > 5 * nsteps, "drift: many active-set changes")
    print '(2x,a,i0)', "drift: additions without the Schur pre-test (an agent in no active row): ", sp%state%n_free
    call check(sp%state%n_free > 0, "drift: rows with a free agent enter without the pre-test")
    print '(2x,a,i0)', "drift: Schur tests whose factor reach missed a fill (done by the scan): ", &
      sp%state%chol%n_schur_scan()
    call check(sp%state%chol%n_schur_scan() == 0, "drift: the elimination tree of the factor bounds every Schur solve")
    print '(2x,a,i0,a,i0,a,i0)', "drift: rows given tail slots ", sp%state%n_tail, ", fresh analyses ", sp%state%n_analyse, &
      ", enlargements of W ", sp%state%n_reanalyse
    call check(sp%state%n_tail > 0, "drift: rows new to the analysis took tail slots (updated factors checked with them)")
    call check(drift <= sqrt(epsilon(1.0_wp)), "drift: backward error of updated factors <= sqrt(eps)")
    call check(du <= 10.0_wp * s%tol, "drift: agrees with active_set on every step")
  end subroutine test_drift

  !> The analysed row set W (rows that can become active): with w_margin = 0 it holds only the
  !> warm-start rows and the rows violated at u = v, so rows violated later must enlarge it
  !> (re-analysis); the answer is the same as active_set's and as with every row analysed.
  !> The shim refuses a row outside W (an error, never a wrong factor).
  subroutine test_analysed_set()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), ua(:), u0(:), uall(:), la(:), l0(:), lall(:)
    type(sparse_as_solver_t) :: sp, spall
    class(projection_solver_t), allocatable :: sa
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st, sta, stall
    type(error_t), allocatable :: err
    type(chol_t) :: ch
    real(wp) :: pivot
    call hex_scene(12, 10, 1.0e-5_wp, rad, h, cs, v)
    allocate(ua(size(v)), u0(size(v)), uall(size(v)), la(cs%n), l0(cs%n), lall(cs%n))
    s = projection_settings_t(); s%name = 'active_set'
    call make_projection_solver(s, sa, err)
    la = 0
    call sa%solve(cs, v, ua, la, sta, err)
    s%name = 'sparse_active_set'; s%dense_rows = 0
    call sp%init(s, err); call spall%init(s, err)
    sp%knobs%w_margin = 0.0_wp; sp%knobs%a_margin = 0.0_wp; spall%knobs%w_margin = -1.0_wp
    l0 = 0; lall = 0
    call sp%solve(cs, v, u0, l0, st, err)
    call spall%solve(cs, v, uall, lall, stall, err)
    print '(2x,a,i0,a,i0,a,es9.2)', "analysed set: re-analyses ", sp%state%n_reanalyse, " (all rows: ", &
      spall%state%n_reanalyse, "), |u - u_active_set| ", maxval(abs(u0 - ua)) / maxval(abs(v))
    call check(.not. allocated(err) .and. st%converged .and. st%kkt <= s%tol .and. st%n_fallback == 0, &
      "analysed set w_margin = 0: converged on the sparse path")
    call check(sp%state%n_reanalyse > 0, "analysed set w_margin = 0: W enlarged by violated rows")
    call check(spall%state%n_reanalyse == 0 .and. stall%kkt <= s%tol, "w_margin < 0: every row analysed")
    call check(maxval(abs(u0 - ua)) <= 10.0_wp * s%tol * maxval(abs(v)), "analysed set: same u as active_set")
    call check(maxval(abs(u0 - uall)) <= 10.0_wp * s%tol * maxval(abs(v)), "analysed set: same u as all rows")
    ! the same through the primal-dual sweeps (used on large problems): W enlarged there too
    call sp%free(); call sp%init(s, err)
    sp%knobs%w_margin = 0.0_wp; sp%knobs%a_margin = 0.0_wp; sp%knobs%pdas_rows = 0
    l0 = 0
    call sp%solve(cs, v, u0, l0, st, err)
    call check(.not. allocated(err) .and. st%kkt <= s%tol .and. st%n_fallback == 0 .and. sp%state%n_reanalyse > 0, &
      "analysed set with sweeps: converged, W enlarged")
    call check(maxval(abs(u0 - ua)) <= 10.0_wp * s%tol * maxval(abs(v)), "analysed set with sweeps: same u")
    ! the shim: M = [2 1; 1 2] analysed with row 2 outside the set
    call ch%analyze(2, [1, 2, 4], [1, 1, 2], [2.0_wp, 1.0_wp, 2.0_wp], err, inset=[.true., .false.])
    call check(.not. allocated(err), "shim: analysis with a restricted set")
    call ch%factor([.true., .false.], err)
    call check(.not. allocated(err), "shim: factor of the analysed row")
    call ch%rowadd(2, [1, 2], [1.0_wp, 2.0_wp], pivot, err)
    call check(allocated(err), "shim: row outside the analysed set refused by rowadd")
    if (allocated(err)) call check(index(err%message, "outside the analysed set") > 0, "shim: message says why")
    call ch%factor([.true., .true.], err)
    call check(allocated(err), "shim: row outside the analysed set refused by factor")
    call ch%free()
  end subroutine test_analysed_set

  !> The step back by projected search (proj_search) and the partial entry of violated rows
  !> (add_frac) against the classical step back with every violated row entering: on jammed
  !> scenes (many dependent rows) and a lattice, warm started from a perturbed solution so
  !> that rows enter and leave, every variant solves to scaled KKT <= tol on the sparse path
  !> and gives the same u as active_set to 10 tol |v| (as in compare). The projected searches
  !> must have run and, at least once, frozen several rows in one step (else the test would
  !> not exercise the walk over breakpoints). Variant 4 is variant 3 without keep_violated
  !> (frozen rows violated at the new point leave P as before); with it (variants 2 and 3)
  !> some row must have been kept at least once.
  subroutine test_step_back()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), ua(:), u(:), la(:), l(:), lw(:)
    type(sparse_as_solver_t) :: sp
    class(projection_solver_t), allocatable :: sa
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st, sta
    type(error_t), allocatable :: err
    integer :: sc, var, nproj, nrows, nkept
    logical :: proj(4) = [.false., .true., .true., .true.], keep(4) = [.true., .true., .true., .false.]
    real(wp) :: frac(4) = [0.0_wp, 0.0_wp, 0.5_wp, 0.5_wp]
    character(len=16) :: tag
    nproj = 0; nrows = 0; nkept = 0
    do sc = 1, 3
      select case (sc)
      case (1)
        call hex_scene(12, 10, 1.0e-5_wp, rad, h, cs, v)
      case (2)
        call hex_scene(12, 10, 0.0_wp, rad, h, cs, v)
        cs%gap(1:cs%n) = cs%gap(1:cs%n) - 1.0e-4_wp
      case default
        call lattice_scene(9, 9, 4, 0.03_wp, rad, h, cs, v, near_touch=.true.)
      end select
      if (allocated(ua)) deallocate(ua, u, la, l, lw)
      allocate(ua(size(v)), u(size(v)), la(cs%n), l(cs%n), lw(cs%n))
      s = projection_settings_t(); s%name = 'active_set'
      call make_projection_solver(s, sa, err)
      la = 0
      call sa%solve(cs, v, ua, la, sta, err)
      ! warm start: the solution with every other multiplier dropped and the rest scaled
      lw = la
      lw(1:cs%n:2) = 0.0_wp
      lw = 1.5_wp * lw
      s%name = 'sparse_active_set'; s%dense_rows = 0
      do var = 1, 4
        write(tag, '(a,i0,a,i0)') "scene ", sc, " var ", var
        call sp%init(s, err)
        sp%knobs%proj_search = proj(var); sp%knobs%add_frac = frac(var); sp%knobs%add_frac_rows = huge(1)
        sp%knobs%keep_violated = keep(var)
        sp%state%n_proj = 0; sp%state%n_proj_rows = 0; sp%state%n_kept = 0
        l = lw
        call sp%solve(cs, v, u, l, st, err)
        call check(.not. allocated(err) .and. st%converged .and. st%kkt <= s%tol .and. &
          st%n_fallback == 0, "step back " // trim(tag) // ": converged on the sparse path")
        call check(maxval(abs(u - ua)) <= 10.0_wp * s%tol * max(maxval(abs(v)), 1.0_wp), &
          "step back " // trim(tag) // ": same u as active_set")
        if (.not. proj(var)) call check(sp%state%n_proj == 0, "step back " // trim(tag) // ": no projected search")
        if (proj(var)) then
          nproj = nproj + sp%state%n_proj; nrows = nrows + sp%state%n_proj_rows
        end if
        if (.not. (proj(var) .and. keep(var))) call check(sp%state%n_kept == 0, "step back " // trim(tag) // &
          ": no row kept")
        if (proj(var) .and. keep(var)) nkept = nkept + sp%state%n_kept
        print '(2x,a,": it ",i0," fac ",i0," mod ",i0," projected searches ",i0," rows frozen ",i0," kept ",i0,&
          &" kkt ",es9.2)', trim(tag), st%iterations, st%n_factor, st%n_modify, sp%state%n_proj, sp%state%n_proj_rows, &
          sp%state%n_kept, st%kkt
        call sp%free()
      end do
    end do
    call check(nproj > 0, "step back: projected searches ran")
    call check(nrows > nproj, "step back: some projected search froze several rows")
    call check(nkept > 0, "step back: some frozen row violated at the new point stayed in P")
  end subroutine test_step_back

  !> Analysis reused across solves by contact identity (reuse_analysis) and the warm start by
  !> the step back (warm_search): along a trajectory whose contacts appear and disappear (agents
  !> pulled into a jam, rows rebuilt every step, warm started by identity), every combination
  !> solves each step to scaled KKT <= tol on the sparse path with the same u as active_set to
  !> 10 tol |v| (as in compare); with reuse most steps keep the previous analysis, and some
  !> must analyse afresh (new rows among those that may become active). Variant 4: variant 1
  !> without keep_violated. Rows new to a reused analysis take tail slots; variant 5 (variant
  !> 1 without tail slots) enlarges W instead.
  subroutine test_reuse()
    integer, parameter :: na = 100, nsteps = 40
    type(contact_set_t) :: cs
    type(sparse_as_solver_t) :: sp
    class(projection_solver_t), allocatable :: sa
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st, sta
    type(error_t), allocatable :: err
    type(chol_t) :: ch
    real(wp) :: q(2, na), q0(2, na), v(2 * na), u(2 * na), ua(2 * na), c(2), d(2), dist, du, hh
    real(wp), allocatable :: l(:), la(:), lprev(:)
    integer(i8), allocatable :: kprev(:)
    integer :: i, j, k, step, nfail, var, p
    logical :: reuse(5) = [.true., .false., .true., .true., .true.]
    logical :: warm(5) = [.true., .true., .false., .true., .true.]
    logical :: keep(5) = [.true., .true., .true., .false., .true.]
    integer :: tails(5) = [16, 16, 16, 16, 0]
    character(len=16) :: tag
    hh = 0.005_wp
    do j = 1, 10
      do i = 1, 10
        q0(:, i + 10 * (j - 1)) = [i, j] * (2.0_wp * rad + 0.03_wp) + 0.01_wp * [sin(1.0_wp * i * j), cos(3.0_wp * i + j)]
      end do
    end do
    c = sum(q0, dim=2) / na
    s = projection_settings_t(); s%name = 'active_set'
    call make_projection_solver(s, sa, err)
    do var = 1, 5
      write(tag, '(a,i0)') "reuse var ", var
      s = projection_settings_t(); s%name = 'sparse_active_set'; s%dense_rows = 0
      call sp%init(s, err)
      sp%knobs%reuse_analysis = reuse(var); sp%knobs%warm_search = warm(var); sp%knobs%keep_violated = keep(var)
      sp%knobs%tail_slots = tails(var)
      sp%state%n_kept = 0
      q = q0; du = 0; nfail = 0
      allocate(lprev(0), kprev(0))
      do step = 1, nsteps
        ! candidate rows: pairs closer than 3 h |v|max (the FOM's cutoff), so rows come and go
        call cs%init(na, hh, 8 * na)
        do i = 1, na
          d = q(:, i) - c
          v(2*i - 1:2*i) = -4.0_wp * d / max(norm2(d), 1.0e-3_wp) + 0.5_wp * [cos(0.3_wp * step + i), &
            sin(0.7_wp * step - i)]
        end do
        do i = 1, na
          do j = i + 1, na
            dist = norm2(q(:, i) - q(:, j))
            if (dist - 2.0_wp * rad < 3.0_wp * hh * 4.5_wp) call cs%add(i, j, 0, (q(:, i) - q(:, j)) / dist, &
              dist - 2.0_wp * rad)
          end do
        end do
        allocate(l(cs%n), la(cs%n))
        l = 0
        do k = 1, cs%n
          do p = 1, size(kprev)
            if (kprev(p) == cs%key(k)) l(k) = lprev(p)
          end do
        end do
        la = l
        call sp%solve(cs, v, u, l, st, err)
        call sa%solve(cs, v, ua, la, sta, err)
        if (allocated(err) .or. .not. (st%converged .and. st%kkt <= s%tol) .or. st%n_fallback > 0) nfail = nfail + 1
        du = max(du, maxval(abs(u - ua)) / maxval(abs(v)))
        deallocate(lprev, kprev)
        allocate(lprev(cs%n), kprev(cs%n))
        lprev = l; kprev = cs%key([(k, k = 1, cs%n)])
        q = q + hh * reshape(u, [2, na])
        deallocate(l, la)
      end do
      deallocate(lprev, kprev)
      print '(2x,a,": analyses ",i0," reused ",i0," re-analyses ",i0," tail slots ",i0,", rows kept ",i0,&
        &", largest |u - u_active_set| ",es9.2)', trim(tag), sp%state%n_analyse, sp%state%n_reuse, sp%state%n_reanalyse, &
        sp%state%n_tail, sp%state%n_kept, du
      call check(nfail == 0, trim(tag) // ": every step converged on the sparse path")
      if (.not. keep(var)) call check(sp%state%n_kept == 0, trim(tag) // ": no row kept when keep_violated is off")
      call check(du <= 10.0_wp * s%tol, trim(tag) // ": agrees with active_set on every step")
      if (tails(var) > 0 .and. reuse(var)) then
        call check(sp%state%n_tail > 0, trim(tag) // ": rows new to a reused analysis take tail slots")
      else if (tails(var) == 0) then
        call check(sp%state%n_tail == 0 .and. sp%state%n_reanalyse > 0, trim(tag) // &
          ": without tail slots new rows enlarge W (re-analysis)")
      end if
      if (reuse(var)) then
        call check(sp%state%n_reuse > nsteps / 2, trim(tag) // ": most steps reuse the analysis")
        call check(sp%state%n_analyse > 1, trim(tag) // ": new rows force fresh analyses")
      else
        call check(sp%state%n_reuse == 0, trim(tag) // ": no reuse when off")
      end if
      call sp%free()
    end do
    ! the shim: new values on the analysed pattern (an entry absent now is a zero), two rows
    ! on one slot refused
    call ch%analyze(3, [1, 2, 4, 5], [1, 1, 2, 3], [2.0_wp, 1.0_wp, 2.0_wp, 2.0_wp], err)
    call check(.not. allocated(err), "shim: analysis of a 3 x 3 matrix")
    call ch%set_analysed_values([2.0_wp, 0.0_wp, 2.0_wp, 2.0_wp], err)
    call check(.not. allocated(err), "shim: values with a zero entry on the analysed pattern accepted")
    call ch%set_rows([2, 0, 2], err)
    call check(allocated(err), "shim: two rows on one slot refused")
    call ch%set_rows([3, 0, 1, 2], err)
    call check(.not. allocated(err), "shim: rows mapped to slots")
    call ch%factor([.true., .false., .true., .true.], err)
    call check(.not. allocated(err), "shim: factor through the row map")
    block
      real(wp) :: x(4)
      call ch%solve([4.0_wp, 7.0_wp, 2.0_wp, 2.0_wp], x, err)
      ! slots: row 1 -> 3, row 3 -> 1, row 4 -> 2; M on slots = 2 I (off-diagonals were set to
      ! zero pattern), row 2 has no slot (identity)
      call check(.not. allocated(err) .and. maxval(abs(x - [2.0_wp, 7.0_wp, 1.0_wp, 1.0_wp])) <= &
        4.0_wp * epsilon(1.0_wp), "shim: solve through the row map")
      ! values on the analysed pattern itself (entries (1,1), (1,2), (2,2), (3,3) of the slots):
      ! a wrong count is refused; slots 1 and 2 coupled, M on slots = [2 1 0; 1 2 0; 0 0 2]
      call ch%set_analysed_values([2.0_wp, 1.0_wp, 2.0_wp], err)
      call check(allocated(err), "shim: analysed values of the wrong length refused")
      if (allocated(err)) call check(index(err%message, "analysed entries") > 0, "shim: message says so (length)")
      call ch%set_analysed_values([2.0_wp, 1.0_wp, 2.0_wp, 2.0_wp], err)
      call check(.not. allocated(err), "shim: values on the analysed pattern accepted")
      call ch%factor([.true., .false., .true., .true.], err)
      call check(.not. allocated(err), "shim: factor of the analysed values")
      ! x on slots = [1, 1, 1] for slot right-hand side [3, 3, 2]: rows 3, 4, 1 (row 2: identity)
      call ch%solve([2.0_wp, 7.0_wp, 3.0_wp, 3.0_wp], x, err)
      call check(.not. allocated(err) .and. maxval(abs(x - [1.0_wp, 7.0_wp, 1.0_wp, 1.0_wp])) <= &
        8.0_wp * epsilon(1.0_wp), "shim: solve with coupled slots (factor order, row map)")
      ! slot 2 alone: slot 1 inactive, M on the active slots 2, 3 = 2 I
      call ch%factor([.false., .false., .false., .true.], err)
      call ch%solve([2.0_wp, 7.0_wp, 3.0_wp, 4.0_wp], x, err)
      call check(.not. allocated(err) .and. maxval(abs(x - [2.0_wp, 7.0_wp, 3.0_wp, 2.0_wp])) <= &
        4.0_wp * epsilon(1.0_wp), "shim: inactive slots are identity rows in the factor")
    end block
    call ch%free()
  end subroutine test_reuse

  !> Tail slots (chol%add_slot): M on three rows analysed with two empty tail slots; rows 4
  !> and 5, new to the analysis, take the tail slots and enter by rowadd; after every addition
  !> and deletion (the deletions bound row patterns by the grown elimination tree) a solve
  !> through the row map matches a dense solve of M on the active rows (identity elsewhere)
  !> to 64 eps |x| (both solves are backward stable: their error is a small multiple of
  !> n kappa eps with n = 5 and kappa <= 4.4 on every active subset here; a wrong pattern or a
  !> missed fill gives errors of order one); a fresh factorisation on the grown analysis agrees
  !> too. Bad calls (no tail
  !> left, a row that has a slot, a column not ending at its diagonal, a tail column that is
  !> not empty at the analysis) are refused with a message.
  subroutine test_tail_slots()
    type(chol_t) :: ch
    type(error_t), allocatable :: err
    real(wp) :: mf(5, 5), b(5), pivot
    logical :: act(5)
    ! M (rows 1..5): chain 1-2-3 analysed; 4 couples with 1 and 3, 5 with 2 and 4
    mf = 0
    mf(1, 1) = 4; mf(2, 2) = 4; mf(3, 3) = 4; mf(4, 4) = 4; mf(5, 5) = 4
    mf(1, 2) = 1; mf(2, 3) = 1; mf(1, 4) = 1; mf(3, 4) = -1; mf(2, 5) = 0.5_wp; mf(4, 5) = 2
    mf(2, 1) = mf(1, 2); mf(3, 2) = mf(2, 3); mf(4, 1) = mf(1, 4); mf(4, 3) = mf(3, 4)
    mf(5, 2) = mf(2, 5); mf(5, 4) = mf(4, 5)
    b = [1.0_wp, 2.0_wp, 3.0_wp, 4.0_wp, 5.0_wp]
    call ch%analyze(5, [1, 2, 4, 6, 6, 6], [1, 1, 2, 2, 3], [4.0_wp, 1.0_wp, 4.0_wp, 1.0_wp, 4.0_wp], err, &
      ntail=2)
    call check(.not. allocated(err) .and. ch%tail_free() == 2, "tail slots: analysis with two tail slots")
    call ch%set_rows([1, 2, 3, 0, 0], err)
    act = [.true., .true., .true., .false., .false.]
    call ch%factor(act, err)
    call tail_agree(ch, mf, act, b, err, "three analysed rows")
    call ch%add_slot(4, [1, 3, 4], [1.0_wp, -1.0_wp, 4.0_wp], 4, err)
    call check(.not. allocated(err) .and. ch%tail_free() == 1, "tail slots: row 4 takes slot 4")
    call ch%rowadd(4, [1, 3, 4], [1.0_wp, -1.0_wp, 4.0_wp], pivot, err)
    act(4) = .true.
    call tail_agree(ch, mf, act, b, err, "row 4 added on its tail slot")
    call ch%rowdel([1], err)
    act(1) = .false.
    call tail_agree(ch, mf, act, b, err, "row 1 deleted (its fill reaches the tail row)")
    call check(ch%row_entries(1) == 0, "tail slots: the deleted row 1 keeps no entry in the factor")
    call ch%add_slot(5, [2, 4, 5], [0.5_wp, 2.0_wp, 4.0_wp], 5, err)
    call check(.not. allocated(err) .and. ch%tail_free() == 0, "tail slots: row 5 takes slot 5")
    call ch%rowadd(5, [2, 4, 5], [0.5_wp, 2.0_wp, 4.0_wp], pivot, err)
    act(5) = .true.
    call tail_agree(ch, mf, act, b, err, "row 5 added on its tail slot")
    call ch%rowadd(1, [1, 2, 4], [4.0_wp, 1.0_wp, 1.0_wp], pivot, err)
    act(1) = .true.
    call tail_agree(ch, mf, act, b, err, "row 1 back")
    ! the tail row, ordered after every analysed slot, couples with rows 1 and 3: entries in
    ! its row of L
    call check(ch%row_entries(4) >= 2, "tail slots: the tail row 4 has entries before its deletion")
    call ch%rowdel([4], err)
    act(4) = .false.
    call tail_agree(ch, mf, act, b, err, "tail row 4 deleted (row pattern from the grown tree)")
    call check(ch%row_entries(4) == 0, "tail slots: the deleted tail row 4 keeps no entry")
    call ch%rowdel([2], err)
    act(2) = .false.
    call tail_agree(ch, mf, act, b, err, "row 2 deleted")
    call check(ch%row_entries(2) == 0, "tail slots: the deleted row 2 keeps no entry")
    act = .true.
    call ch%factor(act, err)
    call tail_agree(ch, mf, act, b, err, "fresh factorisation on the grown analysis")
    ! refusals
    call ch%add_slot(5, [2, 5], [0.5_wp, 4.0_wp], 3, err)
    call check(allocated(err), "tail slots: a slot when none is left refused")
    call ch%analyze(5, [1, 2, 4, 6, 6, 6], [1, 1, 2, 2, 3], [4.0_wp, 1.0_wp, 4.0_wp, 1.0_wp, 4.0_wp], err, &
      ntail=2)
    call ch%set_rows([1, 2, 3, 0, 0], err)
    call ch%add_slot(4, [1, 3], [1.0_wp, -1.0_wp], 4, err)
    call check(allocated(err), "tail slots: a column not ending at its diagonal refused")
    if (allocated(err)) call check(index(err%message, "diagonal") > 0, "tail slots: message names the diagonal")
    call ch%add_slot(4, [1, 3, 4], [1.0_wp, -1.0_wp, 4.0_wp], 2, err)
    call check(allocated(err), "tail slots: a row that has a slot refused")
    call ch%add_slot(5, [1, 5], [1.0_wp, 4.0_wp], 4, err)
    call check(allocated(err), "tail slots: a tail slot out of turn refused")
    call ch%analyze(5, [1, 2, 4, 6, 6, 7], [1, 1, 2, 2, 3, 5], [4.0_wp, 1.0_wp, 4.0_wp, 1.0_wp, 4.0_wp, 1.0_wp], &
      err, ntail=2)
    call check(allocated(err), "tail slots: a tail column with entries at the analysis refused")
    call ch%free()

  end subroutine test_tail_slots

  !> A deletion naming a row whose pivot is not positive is refused before the factor is
  !> touched: M = [4 2; 2 1] is singular, its factor has the pivots 4 and 0 (exact in binary
  !> arithmetic); deleting the good row together with the bad one (the good one first) leaves
  !> every pivot as it was.
  subroutine test_rowdel_refusal()
    type(chol_t) :: ch
    type(error_t), allocatable :: err
    real(wp) :: d0(2), d1(2), pivot
    ! M = [4 2; 2 1] in the natural order: row 1 factorised alone, row 2 added last, whose
    ! pivot is exactly 1 - 2 * 2 / 4 = 0 (rowadd keeps it: the factorisation would bound it)
    call ch%analyze(2, [1, 2, 4], [1, 1, 2], [4.0_wp, 2.0_wp, 1.0_wp], err, perm=[1, 2])
    call check(.not. allocated(err), "rowdel refusal: analysis")
    call ch%factor([.true., .false.], err)
    call check(.not. allocated(err), "rowdel refusal: factorisation of row 1")
    call ch%rowadd(2, [1, 2], [2.0_wp, 1.0_wp], pivot, err)
    call check(.not. allocated(err) .and. pivot == 0.0_wp, "rowdel refusal: the dependent row added, pivot 0")
    call ch%pivots(d0, err)
    call check(d0(2) == 0.0_wp .and. d0(1) == 4.0_wp, "rowdel refusal: pivots exactly 4 and 0")
    call ch%rowdel([1, 2], err)
    call check(allocated(err), "rowdel refusal: a zero pivot in the list refused")
    if (allocated(err)) then
      call check(index(err%message, "not positive") > 0, "rowdel refusal: the message names the pivot")
      deallocate(err)
    end if
    call ch%pivots(d1, err)
    call check(.not. allocated(err) .and. all(d1 == d0), "rowdel refusal: the factor left as it was")
    call ch%free()
  end subroutine test_rowdel_refusal

  !> A row dependent on earlier ones in a factorisation: its pivot is an exact zero here (two
  !> equal rows), after which CHOLMOD's factorisation would set every later pivot to zero and
  !> the independent rows after it would read as dependent (factor_independent would drop
  !> them). The shim bounds such pivots (1e-14 of the largest diagonal entry): M = rows 1 and
  !> 2 equal, then an independent pair, natural order; true pivots 1, 0, 2, 2.5. The later
  !> ones must be exact to a few eps, the dependent one below dep_tol, positive.
  subroutine test_zero_pivot_factor()
    type(chol_t) :: ch
    type(error_t), allocatable :: err
    real(wp) :: d(4)
    call ch%analyze(4, [1, 2, 4, 5, 7], [1, 1, 2, 3, 3, 4], [1.0_wp, 1.0_wp, 1.0_wp, 2.0_wp, 1.0_wp, 3.0_wp], &
      err, perm=[1, 2, 3, 4])
    call check(.not. allocated(err), "zero pivot: analysis")
    call ch%factor([.true., .true., .true., .true.], err)
    call check(.not. allocated(err), "zero pivot: factorisation with an exactly dependent row")
    call ch%pivots(d, err)
    print '(2x,a,4es11.3)', "zero pivot: pivots ", d
    call check(.not. allocated(err) .and. d(1) == 1.0_wp, "zero pivot: first pivot 1")
    call check(d(2) > 0.0_wp .and. d(2) <= 1.0e-13_wp, "zero pivot: the dependent row's pivot bounded, tiny")
    call check(abs(d(3) - 2.0_wp) <= 4.0_wp * epsilon(1.0_wp) .and. abs(d(4) - 2.5_wp) <= 4.0_wp * epsilon(1.0_wp), &
      "zero pivot: the independent rows after it keep their pivots 2 and 2.5")
    call check(ch%n_bounded() == 1, "zero pivot: the factorisation redone once with bounded pivots")
    call ch%factor([.true., .false., .true., .true.], err)
    call check(.not. allocated(err) .and. ch%n_bounded() == 1, "zero pivot: not redone without the dependent row")
    ! a failed analysis leaves nothing half built: the next calls refuse, no crash
    call ch%analyze(3, [1, 2, 3, 3], [1, 2], [1.0_wp, 1.0_wp], err, perm=[3, 1, 2], ntail=1)
    call check(allocated(err), "failed analysis: a tail slot not ordered last refused")
    if (allocated(err)) deallocate(err)
    call ch%factor([.true., .true., .false.], err)
    call check(allocated(err), "failed analysis: the next factorisation refused")
    if (allocated(err)) deallocate(err)
    call ch%pivots(d(1:3), err)
    call check(allocated(err), "failed analysis: no pivots")
    call ch%free()
  end subroutine test_zero_pivot_factor

  !> Test of test_tail_slots: x from the factor against a dense solve of M (mf) on the active
  !> rows (identity elsewhere).
  subroutine tail_agree(ch, mf, act, b, err, what)
    type(chol_t), intent(inout) :: ch
    real(wp), intent(in) :: mf(5, 5), b(5)
    logical, intent(in) :: act(5)
    type(error_t), allocatable, intent(inout) :: err
    character(len=*), intent(in) :: what
    real(wp) :: a(5, 5), y(5), x(5), piv
    integer :: i, j, k
    call check(.not. allocated(err), "tail slots: " // what // ": no error")
    if (allocated(err)) then
      print '(4x,a)', err%message; deallocate(err); return
    end if
    call ch%solve(b, x, err)
    a = 0; y = b
    do i = 1, 5
      do j = 1, 5
        if (act(i) .and. act(j)) a(i, j) = mf(i, j)
      end do
      if (.not. act(i)) a(i, i) = 1
    end do
    ! Gaussian elimination (M is SPD on the active rows: no pivoting needed)
    do k = 1, 5
      piv = a(k, k)
      do i = k + 1, 5
        y(i) = y(i) - a(i, k) / piv * y(k)
        a(i, k + 1:5) = a(i, k + 1:5) - a(i, k) / piv * a(k, k + 1:5)
      end do
    end do
    do k = 5, 1, -1
      y(k) = (y(k) - sum(a(k, k + 1:5) * y(k + 1:5))) / a(k, k)
    end do
    call check(.not. allocated(err) .and. maxval(abs(x - y)) <= 64.0_wp * epsilon(1.0_wp) * maxval(abs(y)), &
      "tail slots: " // what // ": solve matches the dense one")
  end subroutine tail_agree

  !> The primal-dual sweeps (pdas_rows = 0: on every problem) on a column of 30 agents pushed
  !> into a wall, every pair contact given twice (the second with the reversed normal: an
  !> exactly dependent row) and every row violated: the sweeps add many rows at once, and a
  !> row dependent on those added before it must be refused by the pivot pre-test (added, its
  !> zero pivot made CHOLMOD's next update divide by zero: Debug builds trapped it). The
  !> solve must end on the sparse path at KKT <= tol with the u of active_set (to 10 tol |v|,
  !> as in compare); then a warm restart from garbage multipliers (1e6 on a third of the rows).
  subroutine test_sweeps_dependent()
    type(contact_set_t) :: cs
    type(sparse_as_solver_t) :: sp
    class(projection_solver_t), allocatable :: sa
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st, sta
    type(error_t), allocatable :: err
    real(wp), allocatable :: v(:), u(:), ua(:), l(:), la(:)
    real(wp) :: nrm(2)
    integer :: i, n, var
    n = 30
    call cs%init(n, h, 4 * n)
    allocate(v(2 * n), u(2 * n), ua(2 * n))
    call cs%add(1, 0, 1, [0.0_wp, 1.0_wp], 0.0_wp)
    do i = 2, n
      nrm = [0.01_wp * sin(real(i, wp)), 1.0_wp]; nrm = nrm / norm2(nrm)
      call cs%add(i, i - 1, 0, nrm, 0.0_wp)
      call cs%add(i - 1, i, 0, -nrm, 0.0_wp)
      if (i > 2) call cs%add(i, i - 2, 0, [0.0_wp, 1.0_wp], 0.0_wp)
    end do
    do i = 1, n
      v(2*i - 1:2*i) = [0.1_wp * cos(real(i, wp)), -1.0_wp - 0.01_wp * i]
    end do
    s = projection_settings_t(); s%name = 'active_set'
    call make_projection_solver(s, sa, err)
    allocate(la(cs%n)); la = 0
    call sa%solve(cs, v, ua, la, sta, err)
    call check(.not. allocated(err) .and. sta%kkt <= s%tol, "sweeps, dependent rows: active_set reference")
    s%name = 'sparse_active_set'; s%dense_rows = 0
    call sp%init(s, err)
    sp%knobs%pdas_rows = 0
    allocate(l(cs%n))
    do var = 1, 2
      l = 0
      if (var == 2) l = [(1.0e6_wp * mod(i, 3), i = 1, cs%n)]
      call sp%solve(cs, v, u, l, st, err)
      call check(.not. allocated(err) .and. st%kkt <= s%tol .and. st%n_fallback == 0, &
        "sweeps, dependent rows: converged on the sparse path (" // merge("cold", "warm", var == 1) // ")")
      call check(maxval(abs(u - ua)) <= 10.0_wp * s%tol * maxval(abs(v)), &
        "sweeps, dependent rows: same u as active_set (" // merge("cold", "warm", var == 1) // ")")
    end do
    call sp%free()
  end subroutine test_sweeps_dependent

  !> The new options: bad values give an error naming them.
  subroutine test_options()
    type(projection_settings_t) :: s
    class(projection_solver_t), allocatable :: solver
    type(error_t), allocatable :: err
    s = projection_settings_t()
    call check(s%name == 'sparse_active_set', "sparse_active_set is the default solver")
    s%dense_rows = -1
    call make_projection_solver(s, solver, err)
    call check(allocated(err), "dense_rows < 0 refused")
    if (allocated(err)) call check(index(err%message, "dense_rows") > 0, "message names dense_rows")
    s = projection_settings_t(); s%refresh_every = 0
    call make_projection_solver(s, solver, err)
    call check(allocated(err), "refresh_every < 1 refused")
    if (allocated(err)) call check(index(err%message, "refresh_every") > 0, "message names refresh_every")
  end subroutine test_options

  !> Bad tuning knobs of sparse_active_set are refused before any arithmetic (bulk_div = 0 once
  !> divided by zero): the solve returns an error (code 2) naming the knob, and the defaults
  !> solve.
  subroutine test_knobs()
    integer, parameter :: ncase = 15
    character(len=16), parameter :: names(ncase) = [character(len=16) :: "bulk_div", "bulk_min", &
      "pdas_max", "pdas_rows", "add_frac", "add_frac", "add_frac_rows", "warm_search_rows", &
      "keep_searches", "tail_slots", "reuse_fill", "w_margin", "a_margin", "r_margin", "bulk_div"]
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:), u(:), l(:)
    type(sparse_as_solver_t) :: sp
    type(sparse_as_settings_t) :: kn
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st
    type(error_t), allocatable :: err
    real(wp) :: nan
    integer :: c
    nan = ieee_value(1.0_wp, ieee_quiet_nan)
    call lattice_scene(6, 6, 2, 0.03_wp, rad, h, cs, v)
    allocate(u(size(v)), l(cs%n))
    s = projection_settings_t(); s%name = 'sparse_active_set'; s%dense_rows = 0
    do c = 1, ncase
      kn = sparse_as_settings_t()
      select case (c)
      case (1); kn%bulk_div = 0
      case (2); kn%bulk_min = -1
      case (3); kn%pdas_max = -1
      case (4); kn%pdas_rows = -1
      case (5); kn%add_frac = 1.5_wp
      case (6); kn%add_frac = nan
      case (7); kn%add_frac_rows = -1
      case (8); kn%warm_search_rows = -1
      case (9); kn%keep_searches = -1
      case (10); kn%tail_slots = -1
      case (11); kn%reuse_fill = 2.0_wp
      case (12); kn%w_margin = nan
      case (13); kn%a_margin = -1.0_wp
      case (14); kn%r_margin = -1.0_wp
      case (15); kn%bulk_div = -3
      end select
      call kn%validate(err)
      call check(allocated(err), "knob " // trim(names(c)) // " (case " // str(c) // "): validate refuses")
      call sp%init(s, err)
      sp%knobs = kn
      l = 0
      call sp%solve(cs, v, u, l, st, err)
      call check(allocated(err), "knob " // trim(names(c)) // " (case " // str(c) // "): the solve refuses")
      if (allocated(err)) then
        call check(index(err%message, trim(names(c))) > 0 .and. err%code == EXIT_BAD_INPUT, "knob " // &
          trim(names(c)) // ": the message names it, code 2 (" // err%message // ")")
      end if
      call sp%free()
    end do
    kn = sparse_as_settings_t()
    call kn%validate(err)
    call check(.not. allocated(err), "default knobs are valid")
    call sp%init(s, err)
    sp%knobs = kn
    l = 0
    call sp%solve(cs, v, u, l, st, err)
    call check(.not. allocated(err) .and. st%kkt <= s%tol, "default knobs: the solve reaches tol")
    call sp%free()
  end subroutine test_knobs

  !> The factor's own kernels against plain arithmetic: cr_chol_solve and the Schur pre-test
  !> (by scan and by elimination-tree reach) on random sparse SPD matrices M = B B^T + I whose
  !> factor columns hold from none to many off-diagonal entries (every remainder of the
  !> unrolled loops), with a random subset of rows active (identity elsewhere). Residuals of a
  !> backward-stable LDL' solve: |M_P x - b|_inf <= 1e3 n eps |M|_inf |x|_inf; the Schur value
  !> against w' x with M_P x = w from the same factor: two roundings of one quantity, apart by
  !> a few n eps cond(M_P) relative, and cond(M_P) <= 1 + |B|_2^2 stays below about 10 here
  !> (entries of B in [-0.5, 0.5], at most 3 per row): 1e3 n eps relative.
  subroutine test_kernels()
    integer, parameter :: n = 60, nc = 45
    real(wp) :: bm(n, nc), m(n, n), rhs(n), x(n), u, sref, sval, worst, worst_s
    real(wp) :: xa(n), sval2, worst_a, worst_u, worst_d
    integer :: colptr(n + 1), rowind(n * n), i, j, k, t, trial, nz, nw
    integer :: idx(n)
    real(wp) :: val(n * n), wv(n)
    logical :: act(n)
    type(chol_t) :: ch
    type(error_t), allocatable :: err
    integer :: reach_default
    reach_default = ch%reach_min
    worst = 0; worst_s = 0; worst_a = 0; worst_u = 0; worst_d = 0
    do trial = 1, 6
      bm = 0
      do i = 1, n
        do k = 1, 1 + mod(trial + i, 3)
          call random_number(u); j = 1 + int(u * nc)
          call random_number(u); bm(i, j) = u - 0.5_wp
        end do
      end do
      m = matmul(bm, transpose(bm))
      do i = 1, n
        m(i, i) = m(i, i) + 1.0_wp
      end do
      nz = 0
      do j = 1, n
        colptr(j) = nz + 1
        do i = 1, j
          if (m(i, j) /= 0.0_wp) then
            nz = nz + 1; rowind(nz) = i; val(nz) = m(i, j)
          end if
        end do
      end do
      colptr(n + 1) = nz + 1
      do i = 1, n
        call random_number(u); act(i) = u < 0.7_wp
      end do
      call ch%free()
      ! even trials: the Schur test through the elimination-tree reach (large problems' path)
      ch%reach_min = merge(0, reach_default, mod(trial, 2) == 0)
      call ch%analyze(n, colptr, rowind(1:nz), val(1:nz), err)
      if (.not. allocated(err)) call ch%factor(act, err)
      call check(.not. allocated(err), "kernels: analysis and factor")
      if (allocated(err)) return
      call random_number(rhs); rhs = rhs - 0.5_wp
      call ch%solve(rhs, x, err)
      call check(.not. allocated(err), "kernels: solve")
      worst = max(worst, solve_residual(m, act, x, rhs))
      ! Schur value of an inactive row t against the active rows
      do t = 1, n
        if (act(t)) cycle
        nw = 0
        do i = 1, n
          if (m(i, t) /= 0.0_wp) then
            nw = nw + 1; idx(nw) = i; wv(nw) = m(i, t)
          end if
        end do
        call ch%schur(t, idx(1:nw), wv(1:nw), sval, err)
        call check(.not. allocated(err), "kernels: Schur value")
        ! the same test with alpha = M_P^{-1} w (its forward half, then the backward one)
        xa = huge(1.0_wp)
        call ch%schur(t, idx(1:nw), wv(1:nw), sval2, err, xa)
        call check(.not. allocated(err) .and. sval2 == sval, "kernels: Schur value with alpha unchanged")
        rhs = 0
        do i = 1, nw
          if (act(idx(i)) .and. idx(i) /= t) rhs(idx(i)) = wv(i)
        end do
        call ch%solve(rhs, x, err)
        call check(.not. allocated(err), "kernels: solve for the Schur reference")
        sref = dot_product(rhs, merge(x, 0.0_wp, act))
        worst_s = max(worst_s, abs(sval - sref) / max(abs(sref), 1.0_wp))
        if (any(act)) worst_a = max(worst_a, maxval(abs(xa - x), mask=act) / max(maxval(abs(x), mask=act), 1.0_wp))
      end do
      ! a column of the inverse by a forward solve along one path: against the solve of e_t
      do t = 1, n
        if (.not. act(t)) cycle
        xa = huge(1.0_wp)
        call ch%unit_solve(t, xa, sval, err)
        call check(.not. allocated(err), "kernels: unit solve")
        rhs = 0; rhs(t) = 1
        call ch%solve(rhs, x, err)
        worst_u = max(worst_u, maxval(abs(xa - x), mask=act) / maxval(abs(x), mask=act), &
          abs(sval - x(t)) / abs(x(t)))
      end do
      ! several rows deleted by one update of the factor: solve residual on the rows left,
      ! and no entry of the factor left in a deleted row
      nw = 0
      do i = 1, n
        call random_number(u)
        if (act(i) .and. u < 0.3_wp) then
          nw = nw + 1; idx(nw) = i
        end if
      end do
      if (nw > 0) then
        call ch%rowdel(idx(1:nw), err)
        call check(.not. allocated(err), "kernels: deletion of several rows at once")
        act(idx(1:nw)) = .false.
        do i = 1, nw
          if (ch%row_entries(idx(i)) /= 0) call check(.false., "kernels: a deleted row keeps no entry")
        end do
        call random_number(rhs); rhs = rhs - 0.5_wp
        call ch%solve(rhs, x, err)
        worst_d = max(worst_d, solve_residual(m, act, x, rhs))
      end if
      ! deleting a row twice in one call, or an inactive row, is refused
      if (nw > 0) then
        call ch%rowdel([idx(1)], err)
        call check(allocated(err), "kernels: deletion of an inactive row refused")
      end if
      do i = 1, n
        if (act(i)) then
          call ch%rowdel([i, i], err)
          call check(allocated(err), "kernels: a row given twice in one deletion refused")
          exit
        end if
      end do
    end do
    call ch%free()
    print '(2x,a,es9.2,a,es9.2)', "kernels: largest scaled residual of the solve ", worst, &
      ", of the Schur value ", worst_s
    print '(2x,a,es9.2,a,es9.2,a,es9.2)', "kernels: alpha of the Schur test against the solve ", &
      worst_a, ", inverse column ", worst_u, ", solve residual after a multiple deletion ", worst_d
    call check(worst <= 1.0e3_wp * n * epsilon(1.0_wp), "kernels: solve residual at rounding level")
    call check(worst_s <= 1.0e3_wp * n * epsilon(1.0_wp), "kernels: Schur value at rounding level")
    call check(worst_a <= 1.0e3_wp * n * epsilon(1.0_wp), "kernels: alpha of the Schur test at rounding level")
    call check(worst_u <= 1.0e3_wp * n * epsilon(1.0_wp), "kernels: inverse column at rounding level")
    call check(worst_d <= 1.0e3_wp * n * epsilon(1.0_wp), "kernels: solve after a multiple deletion at rounding level")
  end subroutine test_kernels

  !> The pivot bound that lets an entering row skip the Schur test (pivot_lower_bound, from the
  !> active rows at the row's agents) against the exact squared distance of b_t to the span of
  !> the active rows (two-pass Gram-Schmidt in velocity space), on random small crowds whose
  !> normals come from eight directions (exact parallels occur) with random active sets: the
  !> bound never exceeds the distance (up to 64 eps), is positive for some rows and comes from
  !> an agent with exactly one active row (the angle case) for some.
  subroutine test_pivot_bound()
    integer, parameter :: na = 5, m = 10, ntrial = 300
    integer :: ia(m), ib(m), fp(m + 1), fi(m * m), trial, t, l, k, nq, nz, n_pos, n_one, cnt
    real(wp) :: c1(m), c2(m), bv(2 * na, m), q(2 * na, m), u, ang, bnd, d2, x(2 * na), worst
    logical :: act(m)
    worst = -huge(1.0_wp); n_pos = 0; n_one = 0
    do trial = 1, ntrial
      do t = 1, m
        call random_number(u); ia(t) = 1 + int(u * na)
        call random_number(u); ib(t) = int(u * (na + 1))
        if (ib(t) == ia(t)) ib(t) = 0
        call random_number(u); ang = 2.0_wp * acos(-1.0_wp) * real(int(8 * u), wp) / 8.0_wp
        c1(t) = cos(ang); c2(t) = sin(ang)
        if (ib(t) > 0) then
          c1(t) = c1(t) / sqrt(2.0_wp); c2(t) = c2(t) / sqrt(2.0_wp)
        end if
        call random_number(u); act(t) = u < 0.5_wp
        bv(:, t) = 0.0_wp
        bv(2 * ia(t) - 1, t) = c1(t); bv(2 * ia(t), t) = c2(t)
        if (ib(t) > 0) then
          bv(2 * ib(t) - 1, t) = -c1(t); bv(2 * ib(t), t) = -c2(t)
        end if
      end do
      ! columns of M: every row sharing an agent with t
      nz = 0
      do t = 1, m
        fp(t) = nz + 1
        do l = 1, m
          if (ia(l) == ia(t) .or. (ib(l) > 0 .and. ib(l) == ia(t)) .or. &
              (ib(t) > 0 .and. (ia(l) == ib(t) .or. ib(l) == ib(t)))) then
            nz = nz + 1; fi(nz) = l
          end if
        end do
      end do
      fp(m + 1) = nz + 1
      ! orthonormal basis of the active rows' span
      nq = 0
      do l = 1, m
        if (.not. act(l)) cycle
        x = bv(:, l)
        do k = 1, 2
          x = x - matmul(q(:, 1:nq), matmul(transpose(q(:, 1:nq)), x))
        end do
        if (norm2(x) > 1.0e-8_wp) then
          nq = nq + 1; q(:, nq) = x / norm2(x)
        end if
      end do
      do t = 1, m
        if (act(t)) cycle
        bnd = pivot_lower_bound(t, fp, fi, act, ia, ib, c1, c2)
        x = bv(:, t)
        do k = 1, 2
          x = x - matmul(q(:, 1:nq), matmul(transpose(q(:, 1:nq)), x))
        end do
        d2 = dot_product(x, x)
        worst = max(worst, bnd - d2)
        if (bnd > 0.0_wp) n_pos = n_pos + 1
        ! an agent of t with exactly one active row, the bound positive: the angle case
        do k = 1, 2
          l = merge(ia(t), ib(t), k == 1)
          if (l == 0) cycle
          cnt = count(act .and. (ia == l .or. ib == l))
          if (cnt == 1 .and. bnd > 0.0_wp .and. bnd < dot_product(bv(:, t), bv(:, t)) / 2 - 1.0e-12_wp) &
            n_one = n_one + 1
        end do
      end do
    end do
    print '(2x,a,es10.2,a,i0,a,i0)', "pivot bound: largest bound - distance^2 ", worst, &
      "; positive bounds ", n_pos, ", from one active row at an angle ", n_one
    call check(worst <= 64.0_wp * epsilon(1.0_wp), "pivot bound: never above the squared distance to the active span")
    call check(n_pos > 0, "pivot bound: positive for some entering rows")
    call check(n_one > 0, "pivot bound: the one-active-row (angle) case occurs")
  end subroutine test_pivot_bound

  !> Test of test_kernels: |M_P x_P - b_P| on the active rows, |x - b| elsewhere, scaled by
  !> |M|_inf |x|_inf (the backward error of a solve with the factor of M_P).
  real(wp) function solve_residual(m, act, x, rhs) result(res)
    real(wp), intent(in) :: m(:, :), x(:), rhs(:)
    logical, intent(in) :: act(:)
    real(wp) :: r(size(x))
    integer :: i
    do i = 1, size(x)
      if (act(i)) then
        r(i) = dot_product(merge(m(i, :), 0.0_wp, act), x) - rhs(i)
      else
        r(i) = x(i) - rhs(i)
      end if
    end do
    res = maxval(abs(r)) / (maxval(sum(abs(m), dim=2)) * maxval(abs(x)))
  end function solve_residual

end program test_sparse_as
