!> Unit tests of cr_distance_field: convergence to the exact distance to a segment, descent
!> directions, geodesic distance around an (inflated) disk, blocked and unreachable regions,
!> bad input, and the cost of a room-sized field.
program test_distance_field
  use, intrinsic :: ieee_arithmetic, only: ieee_is_nan
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_shapes, only: obstacle_t, make_disk, make_segment, make_rectangle, point_segment_distance, &
      closest_point_on_segment, obstacle_distance
  use cr_distance_field, only: distance_field_t, NODE_BLOCKED
  implicit none
  real(wp), parameter :: pi = acos(-1.0_wp)

  call test_segment_target()
  call test_disk_obstacle()
  call test_unreachable()
  call test_bad_input()
  call test_room_cost()
  call test_summary()

contains

  subroutine seed_rng()
    integer :: nseed
    integer, allocatable :: seed(:)
    call random_seed(size=nseed)
    allocate(seed(nseed))
    seed = 2024
    call random_seed(put=seed)
  end subroutine seed_rng

  character(len=24) function rtoa(x)
    real(wp), intent(in) :: x
    write(rtoa, '(es10.3)') x
  end function rtoa

  !> No obstacle, target = segment of zero thickness: T -> exact distance, first order.
  subroutine test_segment_target()
    real(wp), parameter :: a(2) = [0.35_wp, 0.3_wp], b(2) = [0.65_wp, 0.3_wp]
    type(obstacle_t) :: seg
    type(obstacle_t), allocatable :: none(:)
    type(distance_field_t) :: f
    type(error_t), allocatable :: error
    real(wp) :: dx, err_node(3), err_dir(3), err_val(3), p(2), dir(2), ex(2), q(2), e, ang
    integer :: level, i, j, k
    logical :: ok, nan_free

    allocate(none(0))
    call make_segment(a, b, 0.0_wp, "exit", seg, error)
    call check(.not. allocated(error), "segment target built")
    do level = 1, 3
      dx = 0.04_wp / 2**(level - 1)
      call f%init([0.0_wp, 0.0_wp], [1.0_wp, 1.0_wp], dx, none, 0.0_wp, [seg], error)
      call check(.not. allocated(error), "field init (segment target)")
      if (allocated(error)) then
        print '(a)', error%message
        return
      end if
      err_node(level) = 0.0_wp
      do j = 1, f%n(2)
        do i = 1, f%n(1)
          e = abs(f%t(i, j) - point_segment_distance(f%node_position(i, j), a, b))
          err_node(level) = max(err_node(level), e)
        end do
      end do
      ! random points away from the segment: value and direction
      call seed_rng()
      err_dir(level) = 0.0_wp
      err_val(level) = 0.0_wp
      nan_free = .true.
      k = 0
      do while (k < 500)
        call random_number(p)
        if (point_segment_distance(p, a, b) < 0.15_wp) cycle
        k = k + 1
        q = closest_point_on_segment(p, a, b)
        ex = (q - p) / norm2(q - p)
        call f%direction(p, dir, ok)
        if (.not. ok) then
          err_dir(level) = huge(1.0_wp)
          cycle
        end if
        nan_free = nan_free .and. .not. any(ieee_is_nan(dir))
        ang = acos(min(1.0_wp, max(-1.0_wp, dot_product(dir, ex)))) * 180.0_wp / pi
        err_dir(level) = max(err_dir(level), ang)
        err_val(level) = max(err_val(level), abs(f%value(p) - point_segment_distance(p, a, b)))
      end do
      call check(nan_free, "directions have no NaN")
      print '(a, f7.4, a, i0, a, es10.3, a, es10.3, a, f6.2, a)', "segment target dx=", dx, " cycles=", &
          f%n_cycles, " max|T-d| nodes=", err_node(level), " points=", err_val(level), &
          " max angle=", err_dir(level), " deg"
      call check(err_node(level) <= 0.5_wp * dx, "segment target: max node error <= dx at dx=" // rtoa(dx))
      call check(err_val(level) <= 0.5_wp * dx, "segment target: interpolated error <= dx at dx=" // rtoa(dx))
      call check(f%n_cycles <= 6, "no obstacle: sweeping converges in <= 6 cycles")
    end do
    call check(err_node(2) < 0.6_wp * err_node(1) .and. err_node(3) < 0.6_wp * err_node(2), &
        "segment target: node error decreases when dx is halved")
    call check(err_val(2) < err_val(1) .and. err_val(3) < err_val(2), &
        "segment target: interpolated error decreases when dx is halved")
    call check(err_dir(3) < 3.0_wp, "segment target: direction within 3 degrees at dx=0.01")
    call check(err_dir(3) < err_dir(1), "segment target: direction error decreases with dx")
    call f%free()
  end subroutine test_segment_target

  !> Exact shortest path length from p to q around the disk (c, rr) (p, q outside the disk).
  pure function geodesic_around_disk(p, q, c, rr) result(l)
    real(wp), intent(in) :: p(2), q(2), c(2), rr
    real(wp) :: l, dp, dq, theta, arc
    if (point_segment_distance(c, p, q) >= rr) then
      l = norm2(q - p)
      return
    end if
    dp = norm2(p - c)
    dq = norm2(q - c)
    theta = acos(min(1.0_wp, max(-1.0_wp, dot_product(p - c, q - c) / (dp * dq))))
    arc = theta - acos(rr / dp) - acos(rr / dq)
    l = sqrt(dp**2 - rr**2) + sqrt(dq**2 - rr**2) + rr * arc
  end function geodesic_around_disk

  !> Disk obstacle between the points and a small disk target: geodesic around the circle
  !> inflated by the clearance; blocked nodes; feasible agent centres see 4 valid nodes.
  subroutine test_disk_obstacle()
    real(wp), parameter :: c(2) = [1.5_wp, 1.0_wp], rdisk = 0.3_wp, qt(2) = [2.6_wp, 1.0_wp]
    real(wp), parameter :: rtarget = 0.05_wp, ragent = 0.2_wp
    type(obstacle_t) :: obst(1), target(1)
    type(distance_field_t) :: f
    type(error_t), allocatable :: error
    real(wp) :: dx, clearance, reff, err(2), errp(2), p(2), e, dobs, dir(2), nrm(2)
    real(wp) :: probes(2, 4)
    integer :: level, i, j, k, nfeas
    logical :: ok, blocked_ok, feasible_ok

    probes = reshape([0.3_wp, 1.0_wp, 0.4_wp, 1.3_wp, 0.6_wp, 0.55_wp, 1.2_wp, 1.7_wp], [2, 4])
    call make_disk(c, rdisk, "pillar", obst(1), error)
    call make_disk(qt, rtarget, "goal", target(1), error)
    do level = 1, 2
      dx = 0.02_wp / level
      clearance = ragent - 1.5_wp * dx
      reff = rdisk + clearance
      call f%init([0.0_wp, 0.0_wp], [3.0_wp, 2.0_wp], dx, obst, clearance, target, error)
      call check(.not. allocated(error), "field init (disk obstacle)")
      if (allocated(error)) then
        print '(a)', error%message
        return
      end if
      ! all valid nodes away from the inflated disk: T = geodesic - rtarget
      err(level) = 0.0_wp
      blocked_ok = .true.
      do j = 1, f%n(2)
        do i = 1, f%n(1)
          p = f%node_position(i, j)
          dobs = norm2(p - c) - rdisk
          blocked_ok = blocked_ok .and. ((f%state(i, j) == NODE_BLOCKED) .eqv. (dobs < clearance))
          if (dobs < clearance + 2 * dx) cycle
          e = abs(f%t(i, j) - max(0.0_wp, geodesic_around_disk(p, qt, c, reff) - rtarget))
          err(level) = max(err(level), e)
        end do
      end do
      call check(blocked_ok, "blocked nodes are exactly those closer than clearance")
      errp(level) = 0.0_wp
      do k = 1, size(probes, 2)
        e = abs(f%value(probes(:, k)) - (geodesic_around_disk(probes(:, k), qt, c, reff) - rtarget))
        errp(level) = max(errp(level), e)
      end do
      print '(a, f7.4, a, i0, a, es10.3, a, es10.3)', "disk obstacle dx=", dx, " cycles=", f%n_cycles, &
          " max node error=", err(level), " probe error=", errp(level)
      ! measured: 2.7 dx and 3.7 dx (nodes, worst just behind the disk), 1.4 dx and 2.0 dx (probes);
      ! the staircase of blocked nodes gives about dx^0.6 convergence next to curved obstacles
      call check(err(level) <= 4.5_wp * dx, "disk obstacle: node error <= 4.5 dx at dx=" // rtoa(dx))
      call check(errp(level) <= 2.5_wp * dx, "disk obstacle: probe error <= 2.5 dx at dx=" // rtoa(dx))
      ! behind the disk the straight line is much shorter than the geodesic: make sure we did not
      ! get the straight line
      call check(f%value([0.3_wp, 1.0_wp]) > norm2(qt - [0.3_wp, 1.0_wp]) - rtarget + 0.05_wp, &
          "disk obstacle: path goes around, not through")
      ! blocked region: disk centre has no valid node, no direction
      call f%direction(c, dir, ok)
      call check(.not. ok, "direction inside blocked region: ok = .false.")
      call check(f%value(c) == huge(1.0_wp), "value inside blocked region is huge")
      ! feasible agent centres (distance >= ragent) always have 4 valid cell nodes and a direction
      call seed_rng()
      feasible_ok = .true.
      nfeas = 0
      do k = 1, 2000
        call random_number(p)
        p = c + (p - 0.5_wp) * 1.2_wp
        call obstacle_distance(obst(1), p, dobs, nrm)
        if (dobs < ragent) cycle
        nfeas = nfeas + 1
        i = floor(p(1) / dx) + 1
        j = floor(p(2) / dx) + 1
        feasible_ok = feasible_ok .and. f%node_valid(i, j) .and. f%node_valid(i + 1, j) &
            .and. f%node_valid(i, j + 1) .and. f%node_valid(i + 1, j + 1)
        call f%direction(p, dir, ok)
        feasible_ok = feasible_ok .and. ok
      end do
      call check(nfeas > 500 .and. feasible_ok, "feasible centres: 4 valid cell nodes and a direction")
      ! direction at a point in front of the disk, on the axis behind it: tangent direction
      call f%direction([0.5_wp, 1.15_wp], dir, ok)
      p = [0.5_wp, 1.15_wp] - c
      ! exact: unit tangent from p to the inflated circle on the upper side
      block
        real(wp) :: dp, alpha, beta, ex(2)
        dp = norm2(p)
        alpha = atan2(p(2), p(1))
        beta = acos(reff / dp)
        ex = c + reff * [cos(alpha - beta), sin(alpha - beta)] - (c + p)
        ! upper tangent point has larger y; choose the one with positive y-offset
        if (ex(2) < 0.0_wp) ex = c + reff * [cos(alpha + beta), sin(alpha + beta)] - (c + p)
        ex = ex / norm2(ex)
        call check(ok .and. acos(min(1.0_wp, dot_product(dir, ex))) * 180 / pi < 5.0_wp, &
            "disk obstacle: direction is the tangent to the inflated disk (5 deg)")
      end block
    end do
    call check(err(2) < 0.8_wp * err(1), "disk obstacle: node error decreases when dx is halved")
    call check(errp(2) < 0.8_wp * errp(1), "disk obstacle: probe error decreases when dx is halved")
    call f%free()
  end subroutine test_disk_obstacle

  !> A wall across the whole box cuts off the right half: unreachable, no NaN.
  subroutine test_unreachable()
    type(obstacle_t) :: wall(1), target(1)
    type(distance_field_t) :: f
    type(error_t), allocatable :: error
    real(wp) :: dir(2), v
    logical :: ok
    call make_segment([1.0_wp, -0.5_wp], [1.0_wp, 1.5_wp], 0.05_wp, "divider", wall(1), error)
    call make_segment([0.1_wp, 0.2_wp], [0.1_wp, 0.8_wp], 0.0_wp, "exit", target(1), error)
    call f%init([0.0_wp, 0.0_wp], [2.0_wp, 1.0_wp], 0.02_wp, wall, 0.05_wp, target, error)
    call check(.not. allocated(error), "field init (unreachable half)")
    if (allocated(error)) return
    call check(.not. any(ieee_is_nan(f%t)), "no NaN in T")
    call f%direction([1.5_wp, 0.5_wp], dir, ok)
    call check(.not. ok, "unreachable point: ok = .false.")
    call check(.not. any(ieee_is_nan(dir)), "unreachable point: no NaN direction")
    v = f%value([1.5_wp, 0.5_wp])
    call check(v == huge(1.0_wp), "unreachable point: value is huge")
    call f%direction([0.5_wp, 0.5_wp], dir, ok)
    call check(ok .and. dir(1) < -0.99_wp, "reachable side: direction points to the exit")
    call check_close(f%value([0.5_wp, 0.5_wp]), 0.4_wp, 0.02_wp, "reachable side: value")
    call f%direction([3.0_wp, 0.5_wp], dir, ok)
    call check(.not. ok, "point off the grid: ok = .false.")
    call f%free()
  end subroutine test_unreachable

  !> Bad input returns errors with messages.
  subroutine test_bad_input()
    type(obstacle_t) :: obst(1), target(1), unset(1)
    type(distance_field_t) :: f
    type(error_t), allocatable :: error
    call make_disk([0.5_wp, 0.5_wp], 0.2_wp, "pillar", obst(1), error)
    call make_segment([0.45_wp, 0.5_wp], [0.55_wp, 0.5_wp], 0.0_wp, "exit", target(1), error)
    call f%init([0.0_wp, 0.0_wp], [1.0_wp, 1.0_wp], 0.0_wp, obst, 0.0_wp, target, error)
    call check(allocated(error), "dx = 0 rejected")
    if (allocated(error)) call check(index(error%message, "dx") > 0, "dx message")
    call f%init([0.0_wp, 0.0_wp], [-1.0_wp, 1.0_wp], 0.1_wp, obst, 0.0_wp, target, error)
    call check(allocated(error), "hi < lo rejected")
    call f%init([0.0_wp, 0.0_wp], [1.0_wp, 1.0_wp], 0.05_wp, obst, 0.0_wp, target, error)
    call check(allocated(error), "target inside an obstacle rejected")
    if (allocated(error)) call check(index(error%message, "target") > 0, "target message")
    call f%init([0.0_wp, 0.0_wp], [1.0_wp, 1.0_wp], 0.05_wp, obst, 0.0_wp, unset, error)
    call check(allocated(error), "unset target rejected")
    call f%init([0.0_wp, 0.0_wp], [1.0_wp, 1.0_wp], 0.05_wp, obst, 0.0_wp, unset(1:0), error)
    call check(allocated(error), "no target rejected")
    call f%free()
  end subroutine test_bad_input

  !> Room 1.3 x 1.5 with walls, an exit of width 0.4 in the top wall and two obstacles,
  !> dx = 0.0125, agent radius 0.1: report build time and per-query cost.
  subroutine test_room_cost()
    integer, parameter :: nq = 200000
    type(obstacle_t) :: walls(7), target(1)
    type(distance_field_t) :: f
    type(error_t), allocatable :: error
    real(wp) :: dx, ragent, dir(2), acc(2), p(2, 1000), t_build, t_query
    integer(i8) :: c0, c1, rate
    integer :: k, nok
    logical :: ok
    dx = 0.0125_wp
    ragent = 0.1_wp
    call make_segment([0.0_wp, 0.0_wp], [1.3_wp, 0.0_wp], 0.0_wp, "wall_south", walls(1), error)
    call make_segment([1.3_wp, 0.0_wp], [1.3_wp, 1.5_wp], 0.0_wp, "wall_east", walls(2), error)
    call make_segment([0.0_wp, 0.0_wp], [0.0_wp, 1.5_wp], 0.0_wp, "wall_west", walls(3), error)
    call make_segment([0.0_wp, 1.5_wp], [0.45_wp, 1.5_wp], 0.0_wp, "wall_north_w", walls(4), error)
    call make_segment([0.85_wp, 1.5_wp], [1.3_wp, 1.5_wp], 0.0_wp, "wall_north_e", walls(5), error)
    call make_disk([0.65_wp, 1.0_wp], 0.15_wp, "pillar", walls(6), error)
    call make_rectangle(0.2_wp, 0.4_wp, 0.7_wp, 0.5_wp, "table", walls(7), error)
    call make_segment([0.45_wp, 1.5_wp], [0.85_wp, 1.5_wp], 0.0_wp, "exit", target(1), error)
    call system_clock(c0, rate)
    call f%init([0.0_wp, 0.0_wp], [1.3_wp, 1.5_wp], dx, walls, ragent - 1.5_wp * dx, target, error)
    call system_clock(c1)
    t_build = real(c1 - c0, wp) / real(rate, wp)
    call check(.not. allocated(error), "room field built")
    if (allocated(error)) then
      print '(a)', error%message
      return
    end if
    call random_number(p)
    p(1, :) = 0.1_wp + 1.1_wp * p(1, :)
    p(2, :) = 0.1_wp + 1.3_wp * p(2, :)
    acc = 0.0_wp
    nok = 0
    call system_clock(c0)
    do k = 1, nq
      call f%direction(p(:, modulo(k, 1000) + 1), dir, ok)
      if (ok) then
        acc = acc + dir
        nok = nok + 1
      end if
    end do
    call system_clock(c1)
    t_query = real(c1 - c0, wp) / real(rate, wp) / nq
    print '(a, i0, a, i0, a, i0, a, es10.3, a, es10.3, a)', "room 1.3 x 1.5, dx=0.0125: nodes ", f%n(1), &
        " x ", f%n(2), ", cycles ", f%n_cycles, ", build ", t_build, " s, direction query ", t_query, " s"
    call check(nok > nq / 2, "room: most random points have a direction")
    call check(all(acc == acc), "room: directions finite")
    call check(t_build < 5.0_wp, "room: field built in < 5 s (Debug)")
    ! at the middle below the exit the direction points up
    call f%direction([0.65_wp, 1.3_wp], dir, ok)
    call check(ok .and. dir(2) > 0.95_wp, "room: below the exit, direction points up")
    call f%free()
  end subroutine test_room_cost
end program test_distance_field
