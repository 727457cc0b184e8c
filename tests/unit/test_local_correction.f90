!> Local exact correction of a reduced velocity (cr_local_correction): nothing changes without
!> a conflict, no overlap after any correction, agents outside the correction set untouched,
!> the full projection when every agent is in the set, a jam against a wall, an overlap found
!> only by the cutoff restart, a step that even the full projection cannot solve (reported,
!> not an error), bad input.
!>
!> Tolerances: the solver is asked for a scaled KKT residual <= tol; the primal part bounds
!> every linearised gap after the step below by -tol h s, with s <= 2 max|u_r| here (initial
!> gaps >= 0; a shifted gap adds at most sqrt(2) max|u_r| h), and the true gap is >= the
!> linearised one (convex gaps). Position round-off adds a few ulps of the hall size.
program test_local_correction
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_positive_inf, ieee_quiet_nan, ieee_is_finite
  use cr_kinds, only: wp
  use cr_assert, only: check, check_close, test_summary
  use cr_test_scenes, only: seed_random, hall_lattice, min_true_gap, full_projection
  use cr_error, only: error_t
  use cr_config, only: scene_cfg_t, obstacles_cfg_t
  use cr_scene, only: scene_t
  use cr_projection, only: projection_settings_t, solve_stats_t
  use cr_local_correction, only: local_correction_t, local_stats_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none

  real(wp), parameter :: rad = 0.02_wp, h = 0.01_wp, cutoff_factor = 1.5_wp
  type(scene_t) :: scene
  type(error_t), allocatable :: error
  type(projection_settings_t) :: settings
  type(local_correction_t) :: lc
  character(len=*), parameter :: solvers(2) = [character(len=20) :: 'sparse_active_set', 'active_set']
  integer :: k

  call scene%init(scene_cfg_t(), obstacles_cfg_t(), error)
  call check(.not. allocated(error), "scene init")
  do k = 1, size(solvers)
    settings = projection_settings_t()
    settings%name = solvers(k)
    call lc%init(settings, cutoff_factor, error)
    call check(.not. allocated(error), "init " // trim(solvers(k)))
    call test_no_conflict(trim(solvers(k)))
    call test_random(trim(solvers(k)))
    call test_full_cover(trim(solvers(k)))
    call test_wall_jam(trim(solvers(k)))
    call test_overlap_restart(trim(solvers(k)))
    call test_unsolvable(trim(solvers(k)))
    call test_bad_input(trim(solvers(k)))
    call lc%free()
  end do
  ! bad input is an error, not a stop
  call lc%init(settings, 0.5_wp, error)
  call check(allocated(error), "cutoff_factor < 1 refused")
  if (allocated(error)) deallocate(error)
  call lc%init(settings, ieee_value(1.0_wp, ieee_positive_inf), error)
  call check(allocated(error), "infinite cutoff_factor refused")
  call test_summary()

contains

  !> Agents on a jittered lattice in the hall with gaps in [gap0, gap0 + 2 jit].
  subroutine lattice(nx, ny, gap0, jit, q)
    integer, intent(in) :: nx, ny
    real(wp), intent(in) :: gap0, jit
    real(wp), allocatable, intent(out) :: q(:)
    real(wp) :: dx
    dx = 2 * rad + gap0 + 2 * jit
    call hall_lattice(nx, ny, 0.1_wp + dx, dx, jit, q)
  end subroutine lattice

  !> Allowed overlap after a correction of u_r (see the header).
  real(wp) function gap_tol(u_r)
    real(wp), intent(in) :: u_r(:)
    gap_tol = settings%tol * h * 2 * maxval(abs(u_r)) + 16 * epsilon(1.0_wp) * scene%length
  end function gap_tol

  !> (1) no conflict: delta is exactly zero, nothing solved.
  subroutine test_no_conflict(name)
    character(len=*), intent(in) :: name
    real(wp), allocatable :: q(:), u_r(:), u(:)
    type(local_stats_t) :: st
    call seed_random(11)
    ! gaps in [3e-3, 4e-3]; |u_r,i| <= 0.1 sqrt(2): candidate rows within the cutoff
    ! 1.5 * 2 h max|u_r| = 4.2e-3, but relative displacements <= 2.9e-3 < gaps
    call lattice(6, 5, 3.0e-3_wp, 5.0e-4_wp, q)
    allocate(u_r(size(q)), u(size(q)))
    call random_number(u_r)
    u_r = 0.2_wp * (u_r - 0.5_wp)
    call lc%correct(scene, rad, q, u_r, h, u, st, error)
    call check(.not. allocated(error), name // " no conflict: no error")
    call check(all(u == u_r), name // " no conflict: delta == 0 exactly")
    call check(st%n_violated == 0 .and. st%n_corrected == 0 .and. st%iterations == 0, &
      name // " no conflict: nothing violated, corrected or solved")
    call check(st%n_rows > 0, name // " no conflict: the cell list found candidate rows")
  end subroutine test_no_conflict

  !> (2) random scenes, random u_r: no overlap after the step; agents outside untouched.
  subroutine test_random(name)
    character(len=*), intent(in) :: name
    real(wp), allocatable :: q(:), u_r(:), u(:), r(:)
    type(local_stats_t) :: st
    integer :: trial, na, i, n_part
    logical :: ok_gap, ok_out, ok_err, ok_conv
    ok_gap = .true.; ok_out = .true.; ok_err = .true.; ok_conv = .true.
    n_part = 0
    do trial = 1, 20
      call seed_random(100 + trial)
      call lattice(16, 12, 0.002_wp, 0.001_wp, q)
      na = size(q) / 2
      allocate(u_r(2 * na), u(2 * na), r(na))
      call random_number(u_r)
      u_r = 0.1_wp * (u_r - 0.5_wp)
      ! a few fast agents in random directions make the conflicts
      call random_number(r)
      do i = 1, na
        if (r(i) < 0.05_wp) u_r(2*i-1:2*i) = 40 * u_r(2*i-1:2*i)
      end do
      call check(min_true_gap(scene, rad, q) > 0, name // " random: start without overlap")
      call lc%correct(scene, rad, q, u_r, h, u, st, error)
      if (allocated(error)) then
        ok_err = .false.; deallocate(error)
      else
        ok_conv = ok_conv .and. st%converged .and. st%kkt <= settings%tol
        ok_gap = ok_gap .and. min_true_gap(scene, rad, q + h * u) >= -gap_tol(u_r)
        do i = 1, na
          if (.not. lc%corrected(i)) ok_out = ok_out .and. all(u(2*i-1:2*i) == u_r(2*i-1:2*i))
        end do
        if (st%n_violated > 0 .and. st%n_corrected < na) n_part = n_part + 1
        if (trial == 1) print '(a, 4(a, i0), a, es9.2, a, es9.2, a)', name, ": corrected ", st%n_corrected, &
          " of ", na, ", violated ", st%n_violated, ", iterations ", st%iterations, ", kkt ", st%kkt, &
          ", time ", st%t_total, " s"
      end if
      deallocate(u_r, u, r)
    end do
    call check(ok_err, name // " random: no error")
    call check(ok_conv, name // " random: local solves reach the tolerance")
    call check(ok_gap, name // " random: no gap below -tol after the correction")
    call check(ok_out, name // " random: agents outside the clusters untouched")
    call check(n_part >= 10, name // " random: most trials correct a strict subset of the agents")
  end subroutine test_random

  !> (3) every agent in the set: the result is the full projection of u_r.
  subroutine test_full_cover(name)
    character(len=*), intent(in) :: name
    real(wp), allocatable :: q(:), u_r(:), u(:), u_full(:)
    type(local_stats_t) :: st
    type(solve_stats_t) :: fst
    integer :: na, i, n_rows
    real(wp) :: xc, s
    ! a row of 6 agents, gaps 1e-3, squeezed towards its centre (every adjacent pair violated)
    na = 6
    allocate(q(2 * na), u_r(2 * na), u(2 * na), u_full(2 * na))
    xc = 0.65_wp
    do i = 1, na
      q(2*i-1) = xc + (i - 3.5_wp) * (2 * rad + 1.0e-3_wp)
      q(2*i) = 0.5_wp + 1.0e-4_wp * i
      u_r(2*i-1) = -10 * (q(2*i-1) - xc)
      u_r(2*i) = 0.3_wp * (-1)**i
    end do
    call lc%correct(scene, rad, q, u_r, h, u, st, error)
    call check(.not. allocated(error), name // " full cover: no error")
    call check(all(lc%corrected), name // " full cover: every agent corrected")
    call check(st%n_clusters == 1, name // " full cover: one cluster")
    ! reference: the full model's projection of u_r on every row within a cutoff that holds
    ! every pair of the row (rows that cannot bind do not move the optimum)
    call full_projection(scene, settings, q, rad, h, 0.5_wp, u_r, u_full, fst, n_rows, error)
    call check(.not. allocated(error) .and. fst%kkt <= settings%tol, name // " full cover: reference solved")
    ! both are KKT points of the same strongly convex projection with independent active rows
    ! (a chain) to the scaled tolerance tol: they agree to O(tol) s
    s = 2 * maxval(abs(u_r))
    call check_close(maxval(abs(u - u_full)), 0.0_wp, 100 * settings%tol * s, &
      name // " full cover: equals the full projection of u_r")
    call check(maxval(abs(u - u_r)) > 1.0e-3_wp, name // " full cover: the correction is not trivial")
    call check(min_true_gap(scene, rad, q + h * u) >= -gap_tol(u_r), name // " full cover: no overlap")
  end subroutine test_full_cover

  !> (4) a column of agents driven into the bottom wall, bystanders far away.
  subroutine test_wall_jam(name)
    character(len=*), intent(in) :: name
    real(wp), allocatable :: q(:), u_r(:), u(:)
    type(local_stats_t) :: st
    integer :: na, i
    real(wp) :: gap0
    na = 8
    gap0 = 5.0e-4_wp
    allocate(q(2 * na), u_r(2 * na), u(2 * na))
    ! agents 1..5: a vertical column at x = 0.3 resting on gaps gap0 above the wall y = 0, all pushed down
    do i = 1, 5
      q(2*i-1) = 0.3_wp
      q(2*i) = rad + gap0 + (i - 1) * (2 * rad + gap0)
      u_r(2*i-1) = 0.0_wp
      u_r(2*i) = -1.0_wp - 0.2_wp * i
    end do
    ! agents 6..8: far away, walking freely
    do i = 6, 8
      q(2*i-1) = 1.0_wp; q(2*i) = 0.2_wp * (i - 5)
      u_r(2*i-1) = 0.5_wp; u_r(2*i) = 0.1_wp
    end do
    call lc%correct(scene, rad, q, u_r, h, u, st, error)
    call check(.not. allocated(error), name // " wall jam: no error")
    call check(all(lc%corrected(1:5)) .and. .not. any(lc%corrected(6:8)), name // " wall jam: the column is corrected")
    call check(all(u(11:16) == u_r(11:16)), name // " wall jam: bystanders untouched")
    call check(min_true_gap(scene, rad, q + h * u) >= -gap_tol(u_r), name // " wall jam: no overlap, no wall penetration")
    ! the bottom agent can only close its gap to the wall: u_y >= -gap0 / h
    call check(u(2) >= -gap0 / h - settings%tol * 2 * maxval(abs(u_r)), name // " wall jam: stopped by the wall")
    ! each agent moves down by at most the gaps below it
    do i = 1, 5
      call check(u(2*i) >= -i * gap0 / h - i * settings%tol * 2 * maxval(abs(u_r)), &
        name // " wall jam: agent stopped by the column below")
    end do
  end subroutine test_wall_jam

  !> (5) an overlapping pair at rest must separate; the agent it then pushes is beyond the first
  !> cutoff (set by u_r = 0): only the restart with the larger cutoff finds its row.
  subroutine test_overlap_restart(name)
    character(len=*), intent(in) :: name
    real(wp) :: q(6), u_r(6), u(6), s
    type(local_stats_t) :: st
    q = [0.6_wp, 0.5_wp, 0.6_wp + 2 * rad - 0.01_wp, 0.5_wp, 0.6_wp + 4 * rad - 0.007_wp, 0.5_wp]
    u_r = 0
    call lc%correct(scene, rad, q, u_r, h, u, st, error)
    call check(.not. allocated(error), name // " overlap: no error")
    if (allocated(error)) then
      deallocate(error); return
    end if
    call check(st%restarts >= 1 .and. st%converged, name // " overlap: the cutoff grew, solved")
    ! agent 3 is at rest (its pair's own cutoff is 0): fixed, a constraint that stops agent 2;
    ! without the restart its row would be missing and agent 2 would move 0.005 into its gap 0.003
    call check(lc%corrected(1) .and. lc%corrected(2) .and. .not. lc%corrected(3) .and. all(u(5:6) == 0), &
      name // " overlap: the pair is corrected, the agent at rest is a fixed constraint")
    ! velocity scale of the local problems: the overlap 0.01 / h = 1 m/s, shifted gaps no larger
    s = 0.01_wp / h
    call check(u(3) <= 0.003_wp / h + settings%tol * s, name // " overlap: stopped by the agent at rest")
    call check(min_true_gap(scene, rad, q + h * u) >= -(settings%tol * h * s + 16 * epsilon(1.0_wp) * scene%length), &
      name // " overlap: removed without creating another")
  end subroutine test_overlap_restart

  !> (6) a disk wider than the hall (radius 0.55 in a hall 1 m wide) overlaps the bottom and the
  !> top wall: no velocity removes both overlaps, so even the projection with every agent free
  !> misses the tolerance. Reported (converged = .false., finite best iterate), not an error.
  subroutine test_unsolvable(name)
    character(len=*), intent(in) :: name
    real(wp) :: q(2), u_r(2), u(2)
    type(local_stats_t) :: st
    q = [0.3_wp, 0.5_wp]
    u_r = 0
    call lc%correct(scene, 0.55_wp, q, u_r, h, u, st, error)
    call check(.not. allocated(error), name // " unsolvable: not an error")
    if (allocated(error)) then
      deallocate(error); return
    end if
    call check(.not. st%converged .and. st%kkt > settings%tol, name // " unsolvable: reported as not converged")
    call check(all(lc%corrected) .and. all(ieee_is_finite(u)), name // " unsolvable: every agent free, finite iterate")
  end subroutine test_unsolvable

  !> (7) inconsistent sizes, non-finite or non-positive input: errors (code 2), not stops.
  subroutine test_bad_input(name)
    character(len=*), intent(in) :: name
    real(wp) :: q(4), u_r(4), u(4), u3(3)
    type(local_stats_t) :: st
    type(local_correction_t) :: blank
    q = [0.5_wp, 0.5_wp, 0.7_wp, 0.5_wp]; u_r = 0
    call lc%correct(scene, rad, q, u_r, h, u3, st, error)
    call check(allocated(error), name // " bad input: inconsistent sizes refused")
    if (allocated(error)) deallocate(error)
    u_r(1) = ieee_value(1.0_wp, ieee_positive_inf)
    call lc%correct(scene, rad, q, u_r, h, u, st, error)
    call check(allocated(error), name // " bad input: infinite u_r refused")
    if (allocated(error)) deallocate(error)
    u_r(1) = 0
    q(3) = ieee_value(1.0_wp, ieee_quiet_nan)
    call lc%correct(scene, rad, q, u_r, h, u, st, error)
    call check(allocated(error), name // " bad input: NaN position refused")
    if (allocated(error)) deallocate(error)
    q(3) = 0.7_wp
    call lc%correct(scene, rad, q, u_r, -h, u, st, error)
    call check(allocated(error), name // " bad input: negative step refused")
    if (allocated(error)) then
      call check(error%code == EXIT_BAD_INPUT, name // " bad input: an input error (code 2)")
      deallocate(error)
    end if
    call lc%correct(scene, rad, q, u_r, ieee_value(1.0_wp, ieee_positive_inf), u, st, error)
    call check(allocated(error), name // " bad input: infinite step refused")
    if (allocated(error)) deallocate(error)
    call blank%correct(scene, rad, q, u_r, h, u, st, error)
    call check(allocated(error), name // " bad input: correct before init refused")
    if (allocated(error)) deallocate(error)
  end subroutine test_bad_input
end program test_local_correction
