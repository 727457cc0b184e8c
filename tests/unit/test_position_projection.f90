!> Exact position projection (cr_position_projection): closed forms (two disks move apart by
!> half the overlap each, a disk pushed out of a wall), a configuration without overlap is
!> returned bit for bit, random overlapping configurations in the hall (agents pushed into the
!> walls too) have no overlap left and equal the projection with every agent free, bad input.
!>
!> The first-order projection (refine_max = 0) is compared with the all-free projection; the
!> refined one (default) must be without overlap and closer to the input; with a start without
!> overlap (the sequential mode of crowd_project) the same.
!>
!> Tolerances: the solver returns a scaled KKT residual <= tol; with desired velocity 0 and
!> h = 1 its velocity scale is s = the deepest overlap d of the input, so every linearised gap
!> is >= -tol d and the true gap (convex) is >= the linearised one; position round-off adds a
!> few ulps of the hall size. Two KKT points of the same 1-strongly convex projection with
!> residuals <= tol differ by at most s (tol + sqrt(2 m tol)) (m rows; from the stationarity and
!> complementarity residuals), used for the comparison with the all-free projection.
program test_position_projection
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_positive_inf
  use cr_kinds, only: wp
  use cr_assert, only: check, check_close, test_summary
  use cr_test_scenes, only: seed_random, hall_lattice, min_true_gap, full_projection
  use cr_error, only: error_t
  use cr_config, only: scene_cfg_t, obstacles_cfg_t
  use cr_scene, only: scene_t
  use cr_projection, only: projection_settings_t, solve_stats_t
  use cr_position_projection, only: position_projection_t, pproj_stats_t
  implicit none

  real(wp), parameter :: rad = 0.02_wp
  type(scene_t) :: scene
  type(error_t), allocatable :: error
  type(projection_settings_t) :: settings
  type(position_projection_t) :: pp, pp0
  character(len=*), parameter :: solvers(2) = [character(len=20) :: 'sparse_active_set', 'active_set']
  integer :: k

  call scene%init(scene_cfg_t(), obstacles_cfg_t(), error)
  call check(.not. allocated(error), "scene init")
  do k = 1, size(solvers)
    settings = projection_settings_t()
    settings%name = solvers(k)
    call pp%init(settings, 1.5_wp, error)
    call check(.not. allocated(error), "init " // trim(solvers(k)))
    call pp0%init(settings, 1.5_wp, error, refine_max=0)
    call check(.not. allocated(error), "init first-order " // trim(solvers(k)))
    call test_two_disks(trim(solvers(k)))
    call test_wall(trim(solvers(k)))
    call test_feasible(trim(solvers(k)))
    call test_random(trim(solvers(k)))
    call test_far_movers(trim(solvers(k)))
    call test_bad_input(trim(solvers(k)))
    call pp%free(); call pp0%free()
  end do
  call pp%init(settings, 0.5_wp, error)
  call check(allocated(error), "cutoff_factor < 1 refused")
  if (allocated(error)) deallocate(error)
  call pp%init(settings, 1.5_wp, error, refine_max=-1)
  call check(allocated(error), "refine_max < 0 refused")
  if (allocated(error)) deallocate(error)
  call test_summary()

contains

  !> Allowed overlap after projecting a configuration whose deepest overlap is depth.
  real(wp) function gap_tol(depth)
    real(wp), intent(in) :: depth
    gap_tol = settings%tol * depth + 16 * epsilon(1.0_wp) * scene%length
  end function gap_tol

  !> (1) two disks overlapping by d, far from the walls: each moves apart by d/2 along the
  !> line of centres; a bystander nearby does not move.
  subroutine test_two_disks(name)
    character(len=*), intent(in) :: name
    real(wp) :: q(6), qp(6), e(2), d, ulp
    type(pproj_stats_t) :: st
    d = 0.013_wp
    e = [3.0_wp, 4.0_wp] / 5.0_wp
    q(1:2) = [0.6_wp, 0.5_wp]
    q(3:4) = q(1:2) + (2 * rad - d) * e
    q(5:6) = [0.3_wp, 0.3_wp]
    call pp%project(scene, rad, q, qp, st, error)
    call check(.not. allocated(error), name // " two disks: no error")
    ulp = 16 * epsilon(1.0_wp)
    call check_close(maxval(abs(qp(1:2) - (q(1:2) - d / 2 * e))), 0.0_wp, settings%tol * d + ulp, &
      name // " two disks: first moves back by d/2")
    call check_close(maxval(abs(qp(3:4) - (q(3:4) + d / 2 * e))), 0.0_wp, settings%tol * d + ulp, &
      name // " two disks: second moves on by d/2")
    call check(all(qp(5:6) == q(5:6)), name // " two disks: bystander untouched")
    call check(st%n_overlaps == 1 .and. st%n_moved == 2, name // " two disks: one overlap, two agents moved")
    call check_close(st%depth_in, d, ulp, name // " two disks: depth reported")
    call check_close(st%displacement, d / sqrt(2.0_wp), ulp + settings%tol * d, name // " two disks: displacement")
  end subroutine test_two_disks

  !> (2) a disk overlapping the bottom wall by d moves up by d; a disk overlapping it and a
  !> neighbour resting on the wall: the neighbour makes way (the coupling row is active).
  subroutine test_wall(name)
    character(len=*), intent(in) :: name
    real(wp) :: q(2), qp(2), q3(4), qp3(4), d
    type(pproj_stats_t) :: st
    d = 0.007_wp
    q = [0.4_wp, rad - d]
    call pp%project(scene, rad, q, qp, st, error)
    call check(.not. allocated(error), name // " wall: no error")
    call check_close(qp(1), q(1), 16 * epsilon(1.0_wp), name // " wall: x unchanged")
    call check_close(qp(2), rad, settings%tol * d + 16 * epsilon(1.0_wp), name // " wall: pushed out by d")
    ! agent 1 overlapping the left wall, resting on the bottom one; agent 2 almost touching
    ! agent 1 on the right (gap 1e-12, not an overlap), resting on the wall: agent 1 pushes
    ! agent 2 along (the row between them is active)
    q3(1:2) = [rad - d, rad]
    q3(3:4) = [3 * rad - d + 1.0e-12_wp, rad]
    call pp%project(scene, rad, q3, qp3, st, error)
    call check(.not. allocated(error), name // " wall corner: no error")
    call check(min_true_gap(scene, rad, qp3) >= -gap_tol(d), name // " wall corner: no overlap")
    call check_close(qp3(1), rad, settings%tol * d + 16 * epsilon(1.0_wp), name // " wall corner: out of the wall")
    call check_close(qp3(3), 3 * rad, settings%tol * d + 16 * epsilon(1.0_wp), &
      name // " wall corner: the neighbour made way")
    call check(st%n_free == 2, name // " wall corner: both agents moved by the rows")
  end subroutine test_wall

  !> (3) no overlap: the same positions bit for bit, no solve.
  subroutine test_feasible(name)
    character(len=*), intent(in) :: name
    real(wp), allocatable :: q(:), qp(:)
    type(pproj_stats_t) :: st
    call seed_random(7)
    call lattice(10, 8, 1.0e-4_wp, 0.0_wp, q)
    ! two agents touching (gap 1e-12, far above the round-off of the distance)
    q(3:4) = q(1:2) + [2 * rad + 1.0e-12_wp, 0.0_wp]
    allocate(qp(size(q)))
    call check(min_true_gap(scene, rad, q) >= 0, name // " feasible: start without overlap")
    call pp%project(scene, rad, q, qp, st, error)
    call check(.not. allocated(error), name // " feasible: no error")
    call check(all(qp == q), name // " feasible: unchanged bit for bit")
    call check(st%solves == 0 .and. st%n_overlaps == 0 .and. st%n_moved == 0, name // " feasible: nothing solved")
  end subroutine test_feasible

  !> (4) random overlapping lattices, some agents pushed into the walls.
  subroutine test_random(name)
    character(len=*), intent(in) :: name
    real(wp), allocatable :: q(:), qp(:), q_full(:), r(:), qr(:), qs(:)
    type(pproj_stats_t) :: st, st2
    type(solve_stats_t) :: fst
    integer :: trial, na, i, n_partial, n_rows
    logical :: ok_err, ok_gap, ok_full, ok_walls, ok_ref, ok_seq
    real(wp) :: bound
    ok_err = .true.; ok_gap = .true.; ok_full = .true.; ok_walls = .true.; ok_ref = .true.; ok_seq = .true.
    n_partial = 0
    do trial = 1, 12
      call seed_random(300 + trial)
      ! spacing 2 r - 2e-3 + jitter 1e-2: many overlaps up to ~1e-2
      call lattice(14, 11, -6.0e-3_wp, 0.01_wp, q)
      na = size(q) / 2
      allocate(qp(2 * na), r(na), qr(2 * na), qs(2 * na))
      call random_number(r)
      ! agents of the first column into the left wall, of the first row into the bottom wall
      do i = 1, na
        if (mod(i - 1, 14) == 0) q(2*i-1) = rad * (0.5_wp + r(i))
        if (i <= 14) q(2*i) = rad * (0.5_wp + r(i))
      end do
      call pp0%project(scene, rad, q, qp, st, error)
      if (allocated(error)) then
        ok_err = .false.; deallocate(error); deallocate(q, qp, r, qr, qs); cycle
      end if
      ! refined: no overlap, closer to q than the first-order projection
      call pp%project(scene, rad, q, qr, st2, error)
      if (allocated(error)) then
        ok_err = .false.; deallocate(error)
      else
        ok_ref = ok_ref .and. min_true_gap(scene, rad, qr) >= -gap_tol(st%depth_in) .and. &
          norm2(qr - q) <= norm2(qp - q) * (1 + 1.0e-12_wp) .and. st2%refines >= 1
      end if
      ! from a start without overlap (the first-order projection, shifted by 1e-3 away)
      qs = qp
      call pp%project(scene, rad, q, qr, st2, error, q_start=qs)
      if (allocated(error)) then
        ok_err = .false.; deallocate(error)
      else
        ok_seq = ok_seq .and. min_true_gap(scene, rad, qr) >= -gap_tol(st%depth_in) .and. &
          norm2(qr - q) <= norm2(qp - q) * (1 + 1.0e-12_wp)
      end if
      ok_gap = ok_gap .and. min_true_gap(scene, rad, qp) >= -gap_tol(st%depth_in)
      ok_walls = ok_walls .and. st%n_overlaps > 0 .and. st%depth_in > 0.2_wp * rad
      if (st%n_free < na) n_partial = n_partial + 1
      ! reference: every agent free, every row within 2 * the largest move (+ margin)
      allocate(q_full(2 * na))
      call full_projection(scene, settings, q, rad, 1.0_wp, 2.1_wp * st%max_move + 1.0e-3_wp, &
        [(0.0_wp, i = 1, 2 * na)], q_full, fst, n_rows, error)
      if (allocated(error)) then
        ok_err = .false.; deallocate(error)
      else
        bound = st%depth_in * (settings%tol + sqrt(2 * n_rows * settings%tol)) + 16 * epsilon(1.0_wp) * scene%length
        ok_full = ok_full .and. fst%kkt <= settings%tol .and. maxval(abs(qp - q - q_full)) <= bound
      end if
      if (trial == 1) print '(a, 5(a, i0), a, es9.2, a, es9.2, a)', name, ": overlaps ", st%n_overlaps, &
        ", free ", st%n_free, " of ", na, ", solves ", st%solves, ", restarts ", st%restarts, &
        ", depth ", st%depth_in, ", time ", st%t_total, " s"
      deallocate(q, qp, r, q_full, qr, qs)
    end do
    call check(ok_err, name // " random: no error")
    call check(ok_walls, name // " random: the inputs overlap (agents and walls)")
    call check(ok_gap, name // " random: no overlap deeper than tol * depth after the projection")
    call check(ok_full, name // " random: equals the projection with every agent free")
    call check(n_partial >= 1, name // " random: some trials solve for a strict subset")
    call check(ok_ref, name // " random: refined projection without overlap and closer to the input")
    call check(ok_seq, name // " random: from a start without overlap: no overlap, closer to the input")
  end subroutine test_random

  !> (4b) far movers (the ML positions of a jam): from a start without overlap, every agent of a
  !> lattice jittered into its neighbours, one agent of the lattice sent 0.3 m through the
  !> crowd and one agent alone in the hall sent 0.8 m down into the bottom wall (its wall row
  !> is only within its own reach, not within the others'): no overlap, the same result as the
  !> projection over every row within 2.1 x the farthest move (the bound of two KKT points,
  !> velocity scale max |w|), with fewer candidate rows; the lone agent stops on the wall.
  subroutine test_far_movers(name)
    character(len=*), intent(in) :: name
    real(wp), allocatable :: q0(:), qs(:), qin(:), qp(:), r(:), u_full(:), w(:)
    type(pproj_stats_t) :: st
    type(solve_stats_t) :: fst
    integer :: na, n_rows
    real(wp) :: s, bound
    call seed_random(77)
    call lattice(14, 11, 4.0e-3_wp, 2.0e-3_wp, q0)
    na = size(q0) / 2 + 1
    allocate(qs(2 * na), qin(2 * na), qp(2 * na), r(2 * na), u_full(2 * na))
    qs(1:2 * na - 2) = q0
    qs(2 * na - 1:2 * na) = [1.0_wp, 0.6_wp]
    call random_number(r)
    qin = qs + 0.01_wp * (r - 0.5_wp)
    qin(2 * 5) = qin(2 * 5) + 0.3_wp
    qin(2 * na - 1:2 * na) = [1.0_wp, 0.6_wp - 0.8_wp]
    call check(min_true_gap(scene, rad, qs) > 0, name // " far movers: the start has no overlap")
    call pp0%project(scene, rad, qin, qp, st, error, q_start=qs)
    call check(.not. allocated(error), name // " far movers: no error")
    if (allocated(error)) then
      deallocate(error); return
    end if
    w = qin - qs
    s = maxval(abs(w))
    call check(min_true_gap(scene, rad, qp) >= -(settings%tol * s + 16 * epsilon(1.0_wp) * scene%length), &
      name // " far movers: no overlap")
    call full_projection(scene, settings, qs, rad, 1.0_wp, 2.1_wp * 0.8_wp * sqrt(2.0_wp) + 1.0e-3_wp, w, u_full, &
      fst, n_rows, error)
    call check(.not. allocated(error), name // " far movers: reference solved")
    if (allocated(error)) then
      deallocate(error); return
    end if
    bound = s * (settings%tol + sqrt(2 * n_rows * settings%tol)) + 16 * epsilon(1.0_wp) * scene%length
    call check(fst%kkt <= settings%tol .and. maxval(abs(qp - qs - u_full)) <= bound, &
      name // " far movers: equals the projection over every row within the farthest move")
    call check(st%n_rows < n_rows, name // " far movers: fewer candidate rows than one cutoff for all")
    call check_close(qp(2 * na), rad, s * settings%tol + 16 * epsilon(1.0_wp) * scene%length, &
      name // " far movers: the lone agent stops on the wall")
    print '(a, 2(a, i0), a, es9.2)', name, ": far movers: candidate rows ", st%n_rows, " (one cutoff: ", &
      n_rows, "), largest difference ", maxval(abs(qp - qs - u_full))
  end subroutine test_far_movers

  !> (5) bad input: an error, not a stop.
  subroutine test_bad_input(name)
    character(len=*), intent(in) :: name
    real(wp) :: q(4), qp(4), qbad(3)
    type(pproj_stats_t) :: st
    type(position_projection_t) :: blank
    q = [0.5_wp, 0.5_wp, 0.52_wp, 0.5_wp]
    qbad = 0
    call pp%project(scene, rad, qbad, qp(1:3), st, error)
    call check(allocated(error), name // " bad input: odd size refused")
    if (allocated(error)) deallocate(error)
    call pp%project(scene, rad, q, qp(1:2), st, error)
    call check(allocated(error), name // " bad input: size mismatch refused")
    if (allocated(error)) deallocate(error)
    q(2) = ieee_value(1.0_wp, ieee_positive_inf)
    call pp%project(scene, rad, q, qp, st, error)
    call check(allocated(error), name // " bad input: infinite position refused")
    if (allocated(error)) deallocate(error)
    q(2) = 0.5_wp
    call pp%project(scene, -rad, q, qp, st, error)
    call check(allocated(error), name // " bad input: negative radius refused")
    if (allocated(error)) deallocate(error)
    call pp%project(scene, rad, [0.5_wp, 0.5_wp, 0.53_wp, 0.5_wp], qp, st, error, &
      q_start=[0.5_wp, 0.5_wp, 0.52_wp, 0.5_wp])
    call check(allocated(error), name // " bad input: a start that overlaps refused")
    if (allocated(error)) deallocate(error)
    call blank%project(scene, rad, q, qp, st, error)
    call check(allocated(error), name // " bad input: project before init refused")
    if (allocated(error)) deallocate(error)
  end subroutine test_bad_input

  !> Agents on an nx x ny lattice in the hall, spacing 2 rad + gap0 + jit, jitter +-jit/2.
  subroutine lattice(nx, ny, gap0, jit, q)
    integer, intent(in) :: nx, ny
    real(wp), intent(in) :: gap0, jit
    real(wp), allocatable, intent(out) :: q(:)
    call hall_lattice(nx, ny, 0.05_wp, 2 * rad + gap0 + jit, jit, q)
  end subroutine lattice
end program test_position_projection
