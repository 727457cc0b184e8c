!> Unit tests of cr_geodesic (exact geodesic distance to the narrowed exit around obstacles
!> inflated by the agent radius): closed forms around one disk and one door corner to 1e-12,
!> convergence of the grid field (cr_distance_field) to it as dx -> 0, points inside an
!> inflated obstacle, unreachable points, the desired velocity at a subset of agents, and the
!> one-line error when 'exact' is forced on a scene where it does not apply.
program test_geodesic
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: scene_cfg_t, obstacles_cfg_t, desired_cfg_t
  use cr_scene, only: scene_t
  use cr_shapes, only: obstacle_t, make_disk, make_segment, make_rectangle, obstacle_distance
  use cr_geodesic, only: geodesic_t
  use cr_distance_field, only: distance_field_t
  use cr_desired, only: desired_t
  implicit none
  !> closed forms are evaluated with a few operations on O(1) numbers: round-off ~ 1e-15
  real(wp), parameter :: tol_exact = 1.0e-12_wp
  !> an agent touching an obstacle lies on its inflated boundary up to round-off eps; the
  !> tangent from a point at distance rho (1 + eps) turns by sqrt(2 eps) ~ 2e-8 rad
  real(wp), parameter :: tol_touch = 1.0e-7_wp

  call test_disk_closed_form()
  call test_corner_closed_form()
  call test_capsule_and_polygon()
  call test_inside_and_unreachable()
  call test_grid_convergence()
  call test_desired_subset()
  call test_summary()

contains

  character(len=24) function rtoa(x)
    real(wp), intent(in) :: x
    write(rtoa, '(es10.3)') x
  end function rtoa

  !> One disk (radius R, inflated to rho = R + r) under a wide exit: from x below the disk the
  !> geodesic is the tangent from x, the arc to the disk's side point c + rho e_x, then straight
  !> up to the exit line: sqrt(d^2 - rho^2) + rho * (arc angle) + (H - c_y).
  subroutine test_disk_closed_form()
    type(geodesic_t) :: g
    type(obstacle_t) :: o(1)
    type(error_t), allocatable :: error
    real(wp), parameter :: c(2) = [1.0_wp, 1.0_wp], big_r = 0.2_wp, r = 0.05_wp, h = 2.0_wp
    real(wp) :: x(2), rho, d, beta, tht, tp(2), expect, dist, dir(2), edir(2), side
    logical :: ok
    integer :: k
    call make_disk(c, big_r, "disk", o(1), error)
    call g%init([0.0_wp, 0.0_wp], [2.0_wp, h], o, r, [0.5_wp, h], [1.5_wp, h], error)
    call check(.not. allocated(error), "one disk: graph built")
    if (allocated(error)) return
    rho = big_r + r
    do k = 1, 2
      side = merge(1.0_wp, -1.0_wp, k == 1)
      x = [c(1) + side * 0.02_wp, 0.3_wp]
      d = norm2(x - c)
      beta = atan2(x(2) - c(2), side * (x(1) - c(1)))      ! mirrored to the right-hand case
      tht = beta + acos(rho / d)                            ! tangent point angle, in (-pi/2, 0)
      tp = c + rho * [side * cos(tht), sin(tht)]
      expect = sqrt(d * d - rho * rho) + rho * (0.0_wp - tht) + (h - c(2))
      edir = (tp - x) / norm2(tp - x)
      call g%query(x, dist, dir, ok)
      call check(ok, "one disk: point below the disk reaches the exit")
      call check_close(dist, expect, tol_exact, "one disk: closed-form length, side " // trim(rtoa(side)))
      call check(maxval(abs(dir - edir)) <= tol_exact, "one disk: direction to the tangent point, side " &
        // trim(rtoa(side)))
    end do
    ! exactly below the centre both ways tie: the length still matches
    x = [c(1), 0.3_wp]
    d = c(2) - x(2)
    expect = sqrt(d * d - rho * rho) + rho * asin(rho / d) + (h - c(2))
    call g%query(x, dist, dir, ok)
    call check_close(dist, expect, tol_exact, "one disk: symmetric point")
    ! in sight of the exit: straight to the closest point of the target
    x = [0.2_wp, 1.5_wp]
    call g%query(x, dist, dir, ok)
    call check_close(dist, norm2([0.5_wp, h] - x), tol_exact, "one disk: exit in sight, closest point")
    ! on the inflated disk (an agent in contact), below its side point: the arc then up
    x = c + rho * [cos(-0.3_wp), sin(-0.3_wp)]
    call g%query(x, dist, dir, ok)
    call check_close(dist, rho * 0.3_wp + (h - c(2)), tol_exact, "one disk: agent in contact follows the arc")
    call check(maxval(abs(dir - [sin(0.3_wp), cos(0.3_wp)])) <= tol_touch, &
      "one disk: agent in contact walks along the tangent")
  end subroutine test_disk_closed_form

  !> A hall with barrier walls (scene_t): an agent near the top wall left of the door wraps the
  !> door corner inflated by r (circle of radius r around (x_lo, H)) and reaches the narrowed
  !> opening's end (x_lo + r, H) vertically: sqrt(d^2 - r^2) + r * (arc angle).
  subroutine test_corner_closed_form()
    type(scene_t) :: scene
    type(scene_cfg_t) :: sc
    type(geodesic_t) :: g
    type(error_t), allocatable :: error
    real(wp), parameter :: r = 0.05_wp
    real(wp) :: c(2), x(2), d, beta, tht, tp(2), expect, dist, dir(2), edir(2)
    logical :: ok
    integer :: k
    call scene%init(sc, obstacles_cfg_t(), error)
    call check(.not. allocated(error), "corner: scene built")
    if (allocated(error)) return
    call g%init([0.0_wp, 0.0_wp], [scene%length, scene%width], scene%obstacles, r, &
      [scene%x_lo + r, scene%width], [scene%x_hi - r, scene%width], error)
    call check(.not. allocated(error), "corner: graph built")
    if (allocated(error)) return
    c = [scene%x_lo, scene%width]
    do k = 1, 3
      x = [0.2_wp + 0.1_wp * k, scene%width - r - 0.02_wp * k]
      d = norm2(x - c)
      beta = atan2(x(2) - c(2), x(1) - c(1))
      tht = beta + acos(r / d)
      tp = c + r * [cos(tht), sin(tht)]
      expect = sqrt(d * d - r * r) + r * (0.0_wp - tht)
      edir = (tp - x) / norm2(tp - x)
      call g%query(x, dist, dir, ok)
      call check(ok .and. abs(dist - expect) <= tol_exact, "corner: closed-form length at point " // &
        trim(rtoa(x(1))) // " (error " // trim(rtoa(dist - expect)) // ")")
      call check(maxval(abs(dir - edir)) <= tol_exact, "corner: direction to the tangent point")
    end do
    ! touching the top wall: walk along it (+x)
    x = [0.2_wp, scene%width - r]
    call g%query(x, dist, dir, ok)
    call check(ok .and. maxval(abs(dir - [1.0_wp, 0.0_wp])) <= tol_touch, "corner: along the wall when touching it")
    call check_close(dist, (c(1) - x(1)) + r * acos(-1.0_wp) / 2, tol_exact, "corner: flat run then quarter arc")
    ! same point mirrored on the right-hand side
    x = [scene%length - 0.2_wp, scene%width - r - 0.02_wp]
    c = [scene%x_hi, scene%width]
    d = norm2(x - c)
    beta = atan2(x(2) - c(2), c(1) - x(1))
    tht = beta + acos(r / d)
    expect = sqrt(d * d - r * r) + r * (0.0_wp - tht)
    call g%query(x, dist, dir, ok)
    call check_close(dist, expect, tol_exact, "corner: right-hand door corner")
  end subroutine test_corner_closed_form

  !> A capsule (thick segment) and a square: paths along the flat faces and around the rounded
  !> corners; lengths checked against hand-built paths.
  subroutine test_capsule_and_polygon()
    type(geodesic_t) :: g
    type(obstacle_t) :: o(1)
    type(error_t), allocatable :: error
    real(wp), parameter :: r = 0.05_wp, h = 2.0_wp
    real(wp) :: x(2), dist, dir(2), expect, rho, d, tht
    logical :: ok
    ! horizontal capsule from (0.6, 1) to (1.4, 1), half-thickness 0.05, under a narrow exit at x = 1
    call make_segment([0.6_wp, 1.0_wp], [1.4_wp, 1.0_wp], 0.05_wp, "bar", o(1), error)
    call g%init([0.0_wp, 0.0_wp], [2.0_wp, h], o, r, [0.95_wp, h], [1.05_wp, h], error)
    call check(.not. allocated(error), "capsule: graph built")
    if (allocated(error)) return
    rho = 0.1_wp
    ! from just below the right half of the bar: along the lower face, around the end, then to (1.05, h)
    x = [1.2_wp, 1.0_wp - rho]
    ! lower face to (1.4, 0.9), quarter arc to (1.5, 1), then tangent from the end circle to the target end
    d = norm2([1.05_wp, h] - [1.4_wp, 1.0_wp])
    tht = atan2(h - 1.0_wp, 1.05_wp - 1.4_wp) - acos(rho / d)   ! tangent point angle on the end circle
    expect = 0.2_wp + rho * (tht + acos(-1.0_wp) / 2) + sqrt(d * d - rho * rho)
    call g%query(x, dist, dir, ok)
    call check(ok .and. abs(dist - expect) <= tol_exact, "capsule: face, arc, tangent to the exit end (error " &
      // trim(rtoa(dist - expect)) // ")")
    call check(maxval(abs(dir - [1.0_wp, 0.0_wp])) <= tol_touch, "capsule: walks along the face")
    ! a square [0.8, 1.2]^2 -> 0.8..1.2, exit above: from below the centre, around a rounded corner
    call make_rectangle(0.8_wp, 0.8_wp, 1.2_wp, 1.2_wp, "box", o(1), error)
    call g%init([0.0_wp, 0.0_wp], [2.0_wp, h], o, r, [0.5_wp, h], [1.5_wp, h], error)
    call check(.not. allocated(error), "square: graph built")
    if (allocated(error)) return
    x = [1.0_wp, 0.8_wp - r]
    ! along the bottom face 0.2, quarter arc r pi/2, up the side face 0.4, quarter... no: from the
    ! side point (1.25, 0.8) straight up to the exit line at x = 1.25 (inside the target)
    expect = 0.2_wp + r * acos(-1.0_wp) / 2 + (h - 0.8_wp)
    call g%query(x, dist, dir, ok)
    call check(ok, "square: reachable")
    call check_close(dist, expect, tol_exact, "square: bottom face, rounded corner, up the side")
  end subroutine test_capsule_and_polygon

  !> A point slightly inside an inflated obstacle (contacts are resolved to solver tolerance)
  !> gets the distance of its nearest boundary point plus the move; a point enclosed by
  !> obstacles gets ok = .false.; a point outside the box as well.
  subroutine test_inside_and_unreachable()
    type(geodesic_t) :: g
    type(obstacle_t) :: o(4)
    type(error_t), allocatable :: error
    real(wp), parameter :: c(2) = [1.0_wp, 1.0_wp], r = 0.05_wp, h = 2.0_wp
    real(wp) :: x(2), y(2), dx_, dy_, dir(2), dir2(2)
    logical :: ok
    call make_disk(c, 0.2_wp, "disk", o(1), error)
    call g%init([0.0_wp, 0.0_wp], [2.0_wp, h], o(1:1), r, [0.5_wp, h], [1.5_wp, h], error)
    y = c + 0.25_wp * [cos(-1.2_wp), sin(-1.2_wp)]
    x = c + (0.25_wp - 1.0e-9_wp) * [cos(-1.2_wp), sin(-1.2_wp)]
    call g%query(y, dy_, dir, ok)
    call g%query(x, dx_, dir2, ok)
    call check(ok .and. abs(dx_ - (dy_ + 1.0e-9_wp)) <= tol_exact, "inside by 1e-9: boundary distance plus the move")
    call check(maxval(abs(dir - dir2)) <= tol_touch, "inside by 1e-9: same direction")
    call g%query([3.0_wp, 1.0_wp], dx_, dir, ok)
    call check(.not. ok, "outside the box: no answer")
    ! an enclosure: four bars around (0.3, 0.3)
    call make_segment([0.2_wp, 0.2_wp], [0.4_wp, 0.2_wp], 0.01_wp, "s", o(1), error)
    call make_segment([0.4_wp, 0.2_wp], [0.4_wp, 0.4_wp], 0.01_wp, "e", o(2), error)
    call make_segment([0.4_wp, 0.4_wp], [0.2_wp, 0.4_wp], 0.01_wp, "n", o(3), error)
    call make_segment([0.2_wp, 0.4_wp], [0.2_wp, 0.2_wp], 0.01_wp, "w", o(4), error)
    call g%init([0.0_wp, 0.0_wp], [2.0_wp, h], o, r, [0.5_wp, h], [1.5_wp, h], error)
    call check(.not. allocated(error), "enclosure: graph built")
    call g%query([0.3_wp, 0.3_wp], dx_, dir, ok)
    call check(.not. ok, "enclosed point: unreachable")
    call g%query([0.8_wp, 0.3_wp], dx_, dir, ok)
    call check(ok .and. abs(norm2(dir) - 1.0_wp) < 1.0e-14_wp, "outside the enclosure: reachable")
  end subroutine test_inside_and_unreachable

  !> Scenes with the hall walls and (1) congested150's disk, (2) a tilted square, a thick
  !> segment and a disk close together, (3) the disk overlapping the square and the segment
  !> touching the left wall: the fast-sweeping field built as cr_desired builds it
  !> (clearance r - 1.5 dx, full opening as target) converges to the exact distance as
  !> dx -> 0. cr_distance_field states about 3 dx of error next to a disk at dx = 0.01,
  !> converging like dx^0.6: the bound checked is 2 x 0.03 (dx / 0.01)^0.6.
  subroutine test_grid_convergence()
    type(scene_cfg_t) :: sc
    type(obstacles_cfg_t) :: oc
    sc%hall_length = 2.0_wp; sc%hall_width = 1.25_wp; sc%l_exit = 0.32_wp
    oc%n_disks = 1; oc%disk_x(1) = 1.0_wp; oc%disk_y(1) = 0.6_wp; oc%disk_r(1) = 0.15_wp
    call grid_convergence(sc, oc, "one disk")
    oc%disk_x(1) = 1.3_wp; oc%disk_y(1) = 0.45_wp; oc%disk_r(1) = 0.1_wp
    oc%n_segments = 1
    oc%seg_x1(1) = 0.3_wp; oc%seg_y1(1) = 0.8_wp; oc%seg_x2(1) = 0.8_wp; oc%seg_y2(1) = 0.6_wp
    oc%seg_half_thickness(1) = 0.03_wp
    oc%n_polygons = 1; oc%poly_nv(1) = 4
    oc%poly_x(1:4, 1) = [0.9_wp, 1.15_wp, 1.0_wp, 0.75_wp]
    oc%poly_y(1:4, 1) = [0.75_wp, 0.85_wp, 1.05_wp, 0.95_wp]
    call grid_convergence(sc, oc, "square, bar and disk")
    ! overlapping obstacles: the disk covers a corner of the square, the bar touches the wall
    oc%disk_x(1) = 1.2_wp; oc%disk_y(1) = 0.8_wp
    oc%seg_x1(1) = 0.0_wp; oc%seg_y1(1) = 0.5_wp; oc%seg_x2(1) = 0.5_wp; oc%seg_y2(1) = 0.55_wp
    call grid_convergence(sc, oc, "overlapping obstacles")
  end subroutine test_grid_convergence

  subroutine grid_convergence(sc, oc, name)
    type(scene_cfg_t), intent(in) :: sc
    type(obstacles_cfg_t), intent(in) :: oc
    character(len=*), intent(in) :: name
    type(scene_t) :: scene
    type(geodesic_t) :: g
    type(distance_field_t) :: f
    type(obstacle_t) :: target(1)
    type(error_t), allocatable :: error
    real(wp), parameter :: r = 0.05_wp
    real(wp) :: dx, err(0:3), p(2), de, dg, dir(2), dmin, dd, nrm(2)
    logical :: ok
    integer :: level, i, j, k, npts, n_lost, n_lip
    real(wp), parameter :: eps = 1.0e-4_wp
    real(wp) :: d2, dir2(2), worst_step
    n_lost = 0
    n_lip = 0
    worst_step = 0.0_wp
    call scene%init(sc, oc, error)
    call check(.not. allocated(error), name // ": scene built")
    if (allocated(error)) return
    call g%init([0.0_wp, 0.0_wp], [scene%length, scene%width], scene%obstacles, r, &
      [scene%x_lo + r, scene%width], [scene%x_hi - r, scene%width], error)
    call check(.not. allocated(error), name // ": graph built")
    if (allocated(error)) return
    call make_segment([scene%x_lo, scene%width], [scene%x_hi, scene%width], 0.0_wp, "exit", target(1), error)
    do level = 1, 3
      dx = r / 2**level
      call f%init([0.0_wp, 0.0_wp], [scene%length, scene%width], dx, scene%obstacles, r - 1.5_wp * dx, &
        target, error)
      call check(.not. allocated(error), name // ": field built")
      if (allocated(error)) return
      err(level) = 0.0_wp
      npts = 0
      do j = 1, 24
        do i = 1, 39
          p = [0.05_wp * i, 0.05_wp * j]
          ! free points at least r + 0.03 from every obstacle (away from the blocked staircase)
          dmin = huge(1.0_wp)
          do k = 1, size(scene%obstacles)
            call obstacle_distance(scene%obstacles(k), p, dd, nrm)
            dmin = min(dmin, dd)
          end do
          if (dmin < r + 0.03_wp) cycle
          call g%query(p, de, dir, ok)
          if (.not. ok) n_lost = n_lost + 1
          if (.not. ok) cycle
          if (level == 1) then
            ! the direction is the geodesic's first leg: a step eps along it shortens the
            ! distance by eps exactly when the leg is longer than eps (1-Lipschitz otherwise)
            call g%query(p + eps * dir, d2, dir2, ok)
            worst_step = max(worst_step, abs(d2 - (de - eps)))
            if (d2 < de - eps - tol_exact) n_lip = n_lip + 1
          end if
          dg = f%value(p)
          npts = npts + 1
          err(level) = max(err(level), abs(dg - de))
        end do
      end do
      print '(2x, a, a, es10.3, a, es10.3, a, i0, a)', name, ": dx = ", dx, "  max |T_grid - T_exact| = ", &
        err(level), " over ", npts, " points"
      call check(err(level) <= 2.0_wp * 0.03_wp * (dx / 0.01_wp)**0.6_wp, name // ": grid vs exact within the stated grid error")
      if (level > 1) call check(err(level) < err(level - 1), name // ": grid error decreases with dx")
    end do
    call check(n_lost == 0, name // ": every free point reaches the exit")
    print '(2x, a, a, es10.3)', name, ": largest |T(x + eps dir) - (T(x) - eps)|, eps = 1e-4: ", worst_step
    call check(n_lip == 0, name // ": the distance is 1-Lipschitz along the direction")
    call check(worst_step <= tol_exact, name // ": a step along the direction shortens the distance by its length")
  end subroutine grid_convergence

  !> The desired velocity at a subset of agents equals the full evaluation there; the rules at
  !> the top wall, in the doorway, past the wall and outside the hall with 'exact'; forcing
  !> 'exact' on an exit narrower than an agent is refused with one line.
  subroutine test_desired_subset()
    type(scene_t) :: scene, narrow, hall
    type(scene_cfg_t) :: sc
    type(obstacles_cfg_t) :: oc
    type(desired_cfg_t) :: dc
    type(desired_t) :: des
    type(error_t), allocatable :: error
    real(wp) :: q(2 * 12), speeds(12), v(2 * 12), vs(2, 3), dir(2)
    integer :: i
    oc%n_disks = 1; oc%disk_x(1) = 0.65_wp; oc%disk_y(1) = 0.5_wp; oc%disk_r(1) = 0.1_wp
    call scene%init(sc, oc, error)
    call des%init(dc, scene, 0.05_wp, 12, error)
    call check(.not. allocated(error) .and. des%model_name() == 'exact', "auto picks the exact geodesic")
    do i = 1, 12
      q(2*i-1:2*i) = [0.1_wp * i, 0.06_wp + 0.07_wp * i]
      speeds(i) = 1.0_wp + 0.1_wp * i
    end do
    call des%evaluate(q, speeds, v)
    call des%evaluate_at(q, speeds, [2, 7, 11], vs)
    call check(all(vs(:, 1) == v(3:4)) .and. all(vs(:, 2) == v(13:14)) .and. all(vs(:, 3) == v(21:22)), &
      "evaluate_at equals evaluate on the subset")
    ! forced exact in a hall without interior obstacle: an agent touching the top wall left of
    ! the door walks along it (the straight aim would push into the wall); in the doorway it
    ! walks out; past the wall it walks away from the exit; outside the hall it still gets a
    ! unit direction (the analytic rule)
    dc%field = 'exact'
    call hall%init(scene_cfg_t(), obstacles_cfg_t(), error)
    call des%init(dc, hall, 0.05_wp, 1, error)
    call check(.not. allocated(error) .and. des%model_name() == 'exact', "exact forced without interior obstacle")
    call des%direction([0.2_wp, hall%width - 0.05_wp], dir)
    call check(maxval(abs(dir - [1.0_wp, 0.0_wp])) <= tol_touch, "exact: along the top wall towards the door")
    call des%direction([hall%x_lo + 0.1_wp, hall%width - 0.01_wp], dir)
    call check(maxval(abs(dir - [0.0_wp, 1.0_wp])) <= tol_exact, "exact: straight out in the doorway")
    call des%direction([0.9_wp, 1.5_wp], dir)
    call check(dir(1) > 0 .and. dir(2) > 0 .and. abs(norm2(dir) - 1) <= tol_exact, "exact: away past the wall")
    call des%direction([-0.3_wp, 0.5_wp], dir)
    call check(abs(norm2(dir) - 1) <= tol_exact, "exact: unit direction outside the hall")
    dc%field = 'analytic'
    call des%init(dc, hall, 0.05_wp, 1, error)
    call des%direction([0.2_wp, hall%width - 0.05_wp], dir)
    call check(dir(2) > 0.1_wp, "analytic: aims up at the opening from the top wall")
    sc%l_exit = 0.09_wp
    call narrow%init(sc, oc, error)
    dc%field = 'exact'
    call des%init(dc, narrow, 0.05_wp, 12, error)
    call check(allocated(error), "exact forced on an exit narrower than an agent: refused")
    if (allocated(error)) then
      call check(index(error%message, "&desired: field = 'exact' does not apply") == 1 .and. &
        index(error%message, new_line('a')) == 0, "one-line message naming the group and variable")
      print '(a)', "  " // error%message
    end if
  end subroutine test_desired_subset
end program test_geodesic
