!> Exact analytic geometry of convex obstacles: disks, thick segments (capsules) and convex
!> polygons. Nothing is rasterised: distances and normals are computed in closed form.
!>
!> Conventions: points are `real(wp) :: p(2)`; vertex arrays are `[2, nv]`; polygons are stored
!> counter-clockwise; the signed distance is negative inside the obstacle and its gradient (the
!> "normal") is a unit vector pointing away from the obstacle.
module cr_shapes
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: obstacle_t, OBST_DISK, OBST_SEGMENT, OBST_POLYGON
  public :: make_disk, make_segment, make_polygon, make_rectangle
  public :: obstacle_distance, obstacle_bbox, obstacle_kind_name
  public :: point_segment_distance, closest_point_on_segment, cross2
  public :: segment_segment_distance, segment_obstacle_distance

  !> kind of an obstacle: a disk (1 vertex = centre, radius > 0)
  integer, parameter :: OBST_DISK = 1
  !> kind of an obstacle: all points within `radius` (>= 0) of a segment (2 vertices)
  integer, parameter :: OBST_SEGMENT = 2
  !> kind of an obstacle: convex polygon, nv >= 3 vertices counter-clockwise, radius 0
  integer, parameter :: OBST_POLYGON = 3

  !> relative tolerance for degeneracy tests (collinear vertices, zero-length edges)
  real(wp), parameter :: geom_rtol = 1.0e-10_wp

  !> A convex obstacle. Build it with make_disk/make_segment/make_polygon/make_rectangle.
  type :: obstacle_t
    !> OBST_DISK, OBST_SEGMENT or OBST_POLYGON (0: not built)
    integer :: kind = 0
    !> vertices: disk centre [2,1], segment endpoints [2,2], polygon vertices CCW [2,nv]
    real(wp), allocatable :: vertices(:,:)
    !> disk radius, capsule half-thickness (may be 0), 0 for polygons
    real(wp) :: radius = 0.0_wp
    !> name used in error messages and logs
    character(len=:), allocatable :: label
  end type obstacle_t

contains

  !> Name of an obstacle kind ("disk", "segment", "polygon" or "unset").
  pure function obstacle_kind_name(kind) result(name)
    integer, intent(in) :: kind
    character(len=:), allocatable :: name
    select case (kind)
    case (OBST_DISK); name = "disk"
    case (OBST_SEGMENT); name = "segment"
    case (OBST_POLYGON); name = "polygon"
    case default; name = "unset"
    end select
  end function obstacle_kind_name

  !> z-component of the cross product of two 2D vectors.
  pure function cross2(u, v) result(c)
    real(wp), intent(in) :: u(2), v(2)
    real(wp) :: c
    c = u(1) * v(2) - u(2) * v(1)
  end function cross2

  !> Closest point to p on the segment [a, b] (a == b allowed).
  pure function closest_point_on_segment(p, a, b) result(q)
    real(wp), intent(in) :: p(2), a(2), b(2)
    real(wp) :: q(2)
    real(wp) :: e(2), ee, s
    e = b - a
    ee = dot_product(e, e)
    if (ee > 0.0_wp) then
      s = min(1.0_wp, max(0.0_wp, dot_product(p - a, e) / ee))
    else
      s = 0.0_wp
    end if
    q = a + s * e
  end function closest_point_on_segment

  !> Euclidean distance from p to the segment [a, b].
  pure function point_segment_distance(p, a, b) result(d)
    real(wp), intent(in) :: p(2), a(2), b(2)
    real(wp) :: d
    d = norm2(p - closest_point_on_segment(p, a, b))
  end function point_segment_distance

  !> Distance between the segments [a, b] and [c, d] (0 if they intersect).
  pure function segment_segment_distance(a, b, c, d) result(dist)
    real(wp), intent(in) :: a(2), b(2), c(2), d(2)
    real(wp) :: dist
    real(wp) :: o1, o2, o3, o4
    o1 = cross2(b - a, c - a)
    o2 = cross2(b - a, d - a)
    o3 = cross2(d - c, a - c)
    o4 = cross2(d - c, b - c)
    if (((o1 > 0.0_wp .and. o2 < 0.0_wp) .or. (o1 < 0.0_wp .and. o2 > 0.0_wp)) .and. &
        ((o3 > 0.0_wp .and. o4 < 0.0_wp) .or. (o3 < 0.0_wp .and. o4 > 0.0_wp))) then
      dist = 0.0_wp   ! proper crossing
      return
    end if
    ! otherwise the minimum is attained at an endpoint (touching and collinear cases give 0)
    dist = min(point_segment_distance(a, c, d), point_segment_distance(b, c, d), &
               point_segment_distance(c, a, b), point_segment_distance(d, a, b))
  end function segment_segment_distance

  !> Unsigned distance between the segment [a, b] and the obstacle set (0 if they meet).
  !> Used for line-of-sight tests. Cost: O(1) for disks and capsules, O(nv) for polygons.
  pure function segment_obstacle_distance(obst, a, b) result(dist)
    type(obstacle_t), intent(in) :: obst
    real(wp), intent(in) :: a(2), b(2)
    real(wp) :: dist
    real(wp) :: da, db, n(2)
    integer :: i, nv
    select case (obst%kind)
    case (OBST_DISK)
      dist = max(0.0_wp, point_segment_distance(obst%vertices(:, 1), a, b) - obst%radius)
    case (OBST_SEGMENT)
      dist = max(0.0_wp, segment_segment_distance(a, b, obst%vertices(:, 1), obst%vertices(:, 2)) &
          - obst%radius)
    case (OBST_POLYGON)
      call obstacle_distance(obst, a, da, n)
      call obstacle_distance(obst, b, db, n)
      if (da <= 0.0_wp .or. db <= 0.0_wp) then
        dist = 0.0_wp
        return
      end if
      nv = size(obst%vertices, 2)
      dist = huge(1.0_wp)
      do i = 1, nv
        dist = min(dist, segment_segment_distance(a, b, obst%vertices(:, i), &
            obst%vertices(:, modulo(i, nv) + 1)))
      end do
    case default
      dist = huge(1.0_wp)
    end select
  end function segment_obstacle_distance

  !> Disk of centre c and radius r > 0.
  subroutine make_disk(c, r, label, obst, error)
    real(wp), intent(in) :: c(2), r
    character(len=*), intent(in) :: label
    type(obstacle_t), intent(out) :: obst
    type(error_t), allocatable, intent(out) :: error
    if (.not. all(ieee_is_finite(c)) .or. .not. ieee_is_finite(r)) then
      call set_error(error, "make_disk: obstacle '" // label // "': centre or radius is not finite", EXIT_BAD_INPUT)
      return
    end if
    if (r <= 0.0_wp) then
      call set_error(error, "make_disk: obstacle '" // label // "': radius must be > 0, got " // str(r), EXIT_BAD_INPUT)
      return
    end if
    obst%kind = OBST_DISK
    obst%vertices = reshape(c, [2, 1])
    obst%radius = r
    obst%label = label
  end subroutine make_disk

  !> Thick segment (capsule): all points within half_thickness >= 0 of the segment [a, b], a /= b.
  subroutine make_segment(a, b, half_thickness, label, obst, error)
    real(wp), intent(in) :: a(2), b(2), half_thickness
    character(len=*), intent(in) :: label
    type(obstacle_t), intent(out) :: obst
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: scale
    if (.not. all(ieee_is_finite(a)) .or. .not. all(ieee_is_finite(b)) &
        .or. .not. ieee_is_finite(half_thickness)) then
      call set_error(error, "make_segment: obstacle '" // label // "': endpoint or thickness is not finite", EXIT_BAD_INPUT)
      return
    end if
    if (half_thickness < 0.0_wp) then
      call set_error(error, "make_segment: obstacle '" // label // "': half-thickness must be >= 0, got " &
          // str(half_thickness), EXIT_BAD_INPUT)
      return
    end if
    scale = max(maxval(abs(a)), maxval(abs(b)), tiny(1.0_wp))
    if (norm2(b - a) <= geom_rtol * scale) then
      call set_error(error, "make_segment: obstacle '" // label // "': degenerate segment (endpoints coincide)", EXIT_BAD_INPUT)
      return
    end if
    obst%kind = OBST_SEGMENT
    obst%vertices = reshape([a, b], [2, 2])
    obst%radius = half_thickness
    obst%label = label
  end subroutine make_segment

  !> Convex polygon from vertices [2, nv], nv >= 3, in either orientation (stored CCW).
  !> Rejected: non-finite values, repeated vertices, collinear consecutive vertices,
  !> non-convex or self-intersecting outlines.
  subroutine make_polygon(vertices, label, obst, error)
    real(wp), intent(in) :: vertices(:,:)
    character(len=*), intent(in) :: label
    type(obstacle_t), intent(out) :: obst
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: v(:,:)
    real(wp) :: area2, scale, e1(2), e2(2), c
    integer :: nv, i, k, inext, iprev
    character(len=:), allocatable :: ctx

    ctx = "make_polygon: obstacle '" // label // "': "
    if (size(vertices, 1) /= 2) then
      call set_error(error, ctx // "vertices must have shape [2, nv], got first extent " &
          // str(size(vertices, 1)), EXIT_BAD_INPUT)
      return
    end if
    nv = size(vertices, 2)
    if (nv < 3) then
      call set_error(error, ctx // "a polygon needs at least 3 vertices, got " // str(nv), EXIT_BAD_INPUT)
      return
    end if
    if (.not. all(ieee_is_finite(vertices))) then
      call set_error(error, ctx // "a vertex is not finite", EXIT_BAD_INPUT)
      return
    end if
    ! orientation from the shoelace formula; reverse clockwise input
    area2 = 0.0_wp
    do i = 1, nv
      inext = modulo(i, nv) + 1
      area2 = area2 + cross2(vertices(:, i), vertices(:, inext))
    end do
    if (area2 < 0.0_wp) then
      v = vertices(:, nv:1:-1)
    else
      v = vertices
    end if
    scale = max(maxval(maxval(vertices, dim=2) - minval(vertices, dim=2)), tiny(1.0_wp))
    if (abs(area2) <= geom_rtol * scale**2) then
      call set_error(error, ctx // "degenerate polygon (zero area)", EXIT_BAD_INPUT)
      return
    end if
    do i = 1, nv
      inext = modulo(i, nv) + 1
      iprev = modulo(i - 2, nv) + 1
      e1 = v(:, i) - v(:, iprev)
      e2 = v(:, inext) - v(:, i)
      if (norm2(e2) <= geom_rtol * scale) then
        call set_error(error, ctx // "vertices " // str(i) // " and " // str(inext) // " coincide", EXIT_BAD_INPUT)
        return
      end if
      c = cross2(e1, e2)
      if (abs(c) <= geom_rtol * norm2(e1) * norm2(e2)) then
        call set_error(error, ctx // "vertex " // str(i) // " is collinear with its neighbours", EXIT_BAD_INPUT)
        return
      end if
      if (c < 0.0_wp) then
        call set_error(error, ctx // "polygon is not convex (reflex turn at vertex " // str(i) // ")", EXIT_BAD_INPUT)
        return
      end if
    end do
    ! all turns are left turns; reject self-intersecting (star) outlines: every vertex must lie
    ! on the inner side of every edge
    do i = 1, nv
      inext = modulo(i, nv) + 1
      e2 = v(:, inext) - v(:, i)
      do k = 1, nv
        if (k == i .or. k == inext) cycle
        if (cross2(e2, v(:, k) - v(:, i)) <= 0.0_wp) then
          call set_error(error, ctx // "polygon is not convex (outline winds more than once)", EXIT_BAD_INPUT)
          return
        end if
      end do
    end do
    obst%kind = OBST_POLYGON
    call move_alloc(v, obst%vertices)
    obst%radius = 0.0_wp
    obst%label = label
  end subroutine make_polygon

  !> Axis-aligned rectangle [xmin, xmax] x [ymin, ymax] as a polygon.
  subroutine make_rectangle(xmin, ymin, xmax, ymax, label, obst, error)
    real(wp), intent(in) :: xmin, ymin, xmax, ymax
    character(len=*), intent(in) :: label
    type(obstacle_t), intent(out) :: obst
    type(error_t), allocatable, intent(out) :: error
    if (.not. (xmax > xmin .and. ymax > ymin)) then
      call set_error(error, "make_rectangle: obstacle '" // label // "': need xmin < xmax and ymin < ymax, got [" &
          // str(xmin) // ", " // str(xmax) // "] x [" // str(ymin) // ", " // str(ymax) // "]", EXIT_BAD_INPUT)
      return
    end if
    call make_polygon(reshape([xmin, ymin, xmax, ymin, xmax, ymax, xmin, ymax], [2, 4]), label, obst, error)
  end subroutine make_rectangle

  !> Signed Euclidean distance from p to the obstacle (negative inside) and its gradient
  !> with respect to p (unit vector from the closest boundary point towards p; outward).
  !> Where the gradient is not unique (disk centre, capsule axis, polygon medial axis,
  !> polygon boundary) a well-defined outward normal is returned: +x at a disk centre, the
  !> left normal of the axis a->b on a capsule axis, the first closest edge's outward normal
  !> inside/on a polygon. An unset obstacle (kind 0) gives dist = huge, normal = (1, 0).
  !> Cost: O(1) for disks and capsules, O(nv) for polygons.
  pure subroutine obstacle_distance(obst, p, dist, normal)
    type(obstacle_t), intent(in) :: obst
    real(wp), intent(in) :: p(2)
    real(wp), intent(out) :: dist, normal(2)
    real(wp) :: d(2), r, q(2), e(2), s, smax, dbest, dq
    integer :: i, inext, nv, ibest
    select case (obst%kind)
    case (OBST_DISK)
      d = p - obst%vertices(:, 1)
      r = norm2(d)
      dist = r - obst%radius
      if (r > 0.0_wp) then
        normal = d / r
      else
        normal = [1.0_wp, 0.0_wp]
      end if
    case (OBST_SEGMENT)
      q = closest_point_on_segment(p, obst%vertices(:, 1), obst%vertices(:, 2))
      d = p - q
      r = norm2(d)
      dist = r - obst%radius
      if (r > 0.0_wp) then
        normal = d / r
      else
        e = obst%vertices(:, 2) - obst%vertices(:, 1)
        normal = [-e(2), e(1)] / norm2(e)
      end if
    case (OBST_POLYGON)
      nv = size(obst%vertices, 2)
      ! signed distances to the edge lines; inside iff all <= 0
      smax = -huge(1.0_wp)
      ibest = 1
      do i = 1, nv
        inext = modulo(i, nv) + 1
        e = obst%vertices(:, inext) - obst%vertices(:, i)
        e = e / norm2(e)
        s = cross2(e, p - obst%vertices(:, i))   ! > 0 on the left (inside) for CCW
        if (-s > smax) then
          smax = -s
          ibest = i
        end if
      end do
      if (smax <= 0.0_wp) then
        ! inside or on the boundary: distance to the nearest edge line
        inext = modulo(ibest, nv) + 1
        e = obst%vertices(:, inext) - obst%vertices(:, ibest)
        e = e / norm2(e)
        dist = smax
        normal = [e(2), -e(1)]
      else
        ! outside: nearest point over all edges (positive distance since smax > 0, except
        ! for a point on an edge whose signed distance rounds to a tiny positive value)
        dbest = huge(1.0_wp)
        do i = 1, nv
          inext = modulo(i, nv) + 1
          d = p - closest_point_on_segment(p, obst%vertices(:, i), obst%vertices(:, inext))
          dq = norm2(d)
          if (dq < dbest) then
            dbest = dq
            normal = d
          end if
        end do
        dist = dbest
        if (dbest > 0.0_wp) then
          normal = normal / dbest
        else
          inext = modulo(ibest, nv) + 1
          e = obst%vertices(:, inext) - obst%vertices(:, ibest)
          e = e / norm2(e)
          normal = [e(2), -e(1)]
        end if
      end if
    case default
      dist = huge(1.0_wp)
      normal = [1.0_wp, 0.0_wp]
    end select
  end subroutine obstacle_distance

  !> Axis-aligned bounding box [lo, hi] of the obstacle (empty box lo > hi if unset).
  pure subroutine obstacle_bbox(obst, lo, hi)
    type(obstacle_t), intent(in) :: obst
    real(wp), intent(out) :: lo(2), hi(2)
    if (obst%kind == 0 .or. .not. allocated(obst%vertices)) then
      lo = huge(1.0_wp)
      hi = -huge(1.0_wp)
      return
    end if
    lo = minval(obst%vertices, dim=2) - obst%radius
    hi = maxval(obst%vertices, dim=2) + obst%radius
  end subroutine obstacle_bbox
end module cr_shapes
