!> Exact geodesic distance to a target segment in a box with convex obstacles inflated by a
!> radius r, and its steepest-descent direction, evaluated at given points only (no grid).
!>
!> Model (the limit h -> 0 of cr_distance_field with clearance r): the free set is the box
!> minus the obstacles inflated by r (Minkowski sum with a disk of radius r: the set of agent
!> centres of radius r that do not overlap the obstacle). An inflated convex obstacle is the
!> convex hull of its "circles": a disk of radius R gives one circle of radius R + r, a capsule
!> of half-thickness h gives two circles of radius h + r at its endpoints, a polygon gives one
!> circle of radius r at each vertex. Each circle is free only on the arcs that lie on the
!> boundary of its own inflated obstacle, outside every other inflated obstacle and inside the
!> box ("free arcs", computed exactly from the crossing angles with the other boundaries).
!>
!> Shortest paths are made of straight legs tangent to circles and of arcs along free arcs.
!> Their graph (built once per scene and per radius) has as nodes the tangent points of
!> - the common tangents of every pair of circles (outer and inner),
!> - the tangents from the target's endpoints to every circle,
!> - the tangents parallel to the target's normal (legs meeting the target at a right angle),
!> - the target endpoints lying on a circle (an exit corner inflated by r passes through them),
!> with the visible legs and the arcs between angularly consecutive nodes as edges. A node's
!> distance to the target is seeded with its straight leg to the closest target point or to
!> an endpoint when that leg is visible, and Dijkstra's algorithm gives the geodesic
!> distance of every node. A query at x: if the leg to the closest target point is visible it
!> is the answer (the Euclidean distance is a lower bound); otherwise the minimum over the
!> circles of |x - t| + arc(t -> next node, in the sense of travel) + dist(node), t a tangent
!> point from x, and the direction is that of the first leg (the circle's tangent when x lies
!> on it). A point inside an inflated obstacle (contacts are resolved to solver tolerance) is
!> first moved to the nearest boundary point; its distance includes that move.
!>
!> Tolerance: legs passing inside an inflated obstacle by less than tol = 1e-10 times the box
!> size count as visible (tangent legs touch their circles); distances are otherwise exact to
!> round-off. Cost: building O(n_circ^2 n_obst) (common tangents and their visibility) plus
!> Dijkstra O(E log V); a query O(n_obst) when the exit is in sight, O(n_circ (n_obst + nodes
!> per circle)) otherwise.
module cr_geodesic
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_shapes, only: obstacle_t, OBST_DISK, OBST_SEGMENT, OBST_POLYGON, obstacle_distance, &
      obstacle_bbox, segment_obstacle_distance, closest_point_on_segment
      use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: geodesic_t, GEODESIC_MAX_CIRCLES

  !> largest number of obstacle circles (vertices) handled; beyond it the O(n^2) build is
  !> slower than a grid and callers should use cr_distance_field
  integer, parameter :: GEODESIC_MAX_CIRCLES = 400
  real(wp), parameter :: pi = acos(-1.0_wp), twopi = 2.0_wp * acos(-1.0_wp)
  !> relative length tolerance of the visibility tests (times the box size)
  real(wp), parameter :: rtol_len = 1.0e-10_wp
  !> angular tolerance for a point at the end of a free arc: a point touching an obstacle lies
  !> on its inflated boundary up to round-off eps, and its tangent points move by sqrt(2 eps)
  real(wp), parameter :: atol = 1.0e-7_wp
  !> relative margin of the "surely blocked" pre-test of a leg (sure_blocked)
  real(wp), parameter :: sure_margin = 1.0e-6_wp

  !> Geodesic distance of one scene and radius to one target segment.
  type :: geodesic_t
    logical :: ready = .false.
    !> inflation radius (agent radius)
    real(wp) :: r = 0.0_wp
    !> box of the free set
    real(wp) :: lo(2) = 0.0_wp, hi(2) = 0.0_wp
    !> target segment [ta, tb] (ta == tb allowed)
    real(wp) :: ta(2) = 0.0_wp, tb(2) = 0.0_wp
    !> length tolerance of visibility tests
    real(wp) :: tol = 0.0_wp
    !> the obstacles and their bounding boxes [2, n_obst]
    type(obstacle_t), allocatable :: obst(:)
    real(wp), allocatable :: blo(:,:), bhi(:,:)
    !> obstacle k is an axis-aligned rectangle outside the box spanning one of its sides (a
    !> hall wall): the free part of the box is then convex on that side, so a segment between
    !> free points never meets it and visibility tests skip it
    logical, allocatable :: slab(:)
    !> the obstacles that are not slabs, in order: the only ones visibility tests look at
    integer, allocatable :: near_k(:)
    !> bounding boxes grown by r [2, n_obst]: a point outside cannot be inside the obstacle
    !> inflated by r
    real(wp), allocatable :: plo(:,:), phi(:,:)
    !> for each target end, the circle (of an obstacle that is not a slab) nearest to it (0 if
    !> none) and the square of a radius that is surely blocking: a leg passing its centre
    !> closer than that comes closer than r - tol to its obstacle (see sure_blocked)
    integer :: end_c(2) = 0
    real(wp) :: end_r2(2) = 0.0_wp
    !> polygon edges that a segment inside the box can come within r of: obstacle k owns
    !> edges ed_ptr(k) .. ed_ptr(k+1)-1 from ed_a(:, i) to ed_b(:, i)
    integer, allocatable :: ed_ptr(:)
    real(wp), allocatable :: ed_a(:,:), ed_b(:,:)
    !> circles: centres [2, nc], radii [nc]
    integer :: nc = 0
    real(wp), allocatable :: cen(:,:), rho(:)
    !> free arcs: circle i owns arcs iv_ptr(i) .. iv_ptr(i+1)-1, arc k spans the angles
    !> [iv_s(k), iv_e(k)] (0 <= iv_s < 2 pi, iv_s < iv_e <= iv_s + 2 pi); iv_full: whole circle
    integer, allocatable :: iv_ptr(:)
    real(wp), allocatable :: iv_s(:), iv_e(:)
    logical, allocatable :: iv_full(:)
    !> nodes of arc k: nd_ptr(k) .. nd_ptr(k+1)-1, sorted by unwrapped angle nd_u
    integer, allocatable :: nd_ptr(:)
    integer :: nn = 0
    real(wp), allocatable :: nd_pos(:,:), nd_u(:), nd_dist(:)
    !> smallest node distance on each circle (huge if none): a lower bound for pruning [nc]
    real(wp), allocatable :: c_min(:)
    !> the circles with a reachable node, the only ones a query looks at
    integer, allocatable :: act(:)
  contains
    !> build the tangent graph and the node distances
    procedure :: init
    !> release the arrays
    procedure :: free
    !> geodesic distance and descent direction at a point
    procedure :: query
    !> number of graph nodes
    procedure :: n_nodes
    !> .true. if the straight leg a -> b keeps clear of every inflated obstacle
    procedure :: visible
  end type geodesic_t

  !> growable node/edge lists used while building
  type :: build_t
    integer :: nn = 0, ne = 0
    integer, allocatable :: circ(:), arc(:)
    real(wp), allocatable :: pos(:,:), u(:)
    integer, allocatable :: ea(:), eb(:)
    real(wp), allocatable :: ew(:)
  end type build_t

contains

  !> Build for obstacles inflated by r > 0 in the box [lo, hi] and the target segment [ta, tb]
  !> (inside the box or on its boundary). Fails (code 2) on bad input or more than
  !> GEODESIC_MAX_CIRCLES circles.
  subroutine init(this, lo, hi, obstacles, r, ta, tb, error)
    class(geodesic_t), intent(inout) :: this
    real(wp), intent(in) :: lo(2), hi(2), r, ta(2), tb(2)
    type(obstacle_t), intent(in) :: obstacles(:)
    type(error_t), allocatable, intent(out) :: error
    character(len=*), parameter :: ctx = "geodesic%init: "
    real(wp), allocatable :: own_s(:), own_span(:)
    integer, allocatable :: owner(:)
    type(build_t) :: b
    integer :: k, i, j, nv, nc

    call this%free()
    if (.not. (all(ieee_is_finite(lo)) .and. all(ieee_is_finite(hi)) .and. ieee_is_finite(r) &
        .and. all(ieee_is_finite(ta)) .and. all(ieee_is_finite(tb)))) then
      call set_error(error, ctx // "box, radius and target must be finite", EXIT_BAD_INPUT); return
    end if
    if (.not. all(hi > lo)) then
      call set_error(error, ctx // "need lo < hi", EXIT_BAD_INPUT); return
    end if
    if (r <= 0.0_wp) then
      call set_error(error, ctx // "radius must be > 0, got " // str(r), EXIT_BAD_INPUT); return
    end if
    nc = 0
    do k = 1, size(obstacles)
      select case (obstacles(k)%kind)
      case (OBST_DISK); nc = nc + 1
      case (OBST_SEGMENT); nc = nc + 2
      case (OBST_POLYGON); nc = nc + size(obstacles(k)%vertices, 2)
      case default
        call set_error(error, ctx // "obstacle " // str(k) // " was not built", EXIT_BAD_INPUT); return
      end select
    end do
    if (nc > GEODESIC_MAX_CIRCLES) then
      call set_error(error, ctx // str(nc) // " obstacle vertices and disks exceed the limit of " &
          // str(GEODESIC_MAX_CIRCLES), EXIT_BAD_INPUT); return
    end if
    this%lo = lo; this%hi = hi; this%r = r; this%ta = ta; this%tb = tb
    this%tol = rtol_len * maxval(hi - lo)
    this%obst = obstacles
    allocate(this%blo(2, size(obstacles)), this%bhi(2, size(obstacles)), this%slab(size(obstacles)))
    do k = 1, size(obstacles)
      call obstacle_bbox(obstacles(k), this%blo(:, k), this%bhi(:, k))
      this%slab(k) = is_slab(k)
    end do
    this%near_k = pack([(k, k = 1, size(obstacles))], .not. this%slab)
    this%plo = this%blo - r
    this%phi = this%bhi + r
    allocate(this%ed_ptr(size(obstacles) + 1), this%ed_a(2, 0), this%ed_b(2, 0))
    this%ed_ptr(1) = 1
    do k = 1, size(obstacles)
      this%ed_ptr(k + 1) = this%ed_ptr(k)
      if (obstacles(k)%kind /= OBST_POLYGON) cycle
      nv = size(obstacles(k)%vertices, 2)
      do j = 1, nv
        associate (va => obstacles(k)%vertices(:, j), vb => obstacles(k)%vertices(:, modulo(j, nv) + 1))
          if (any(min(va, vb) >= hi + r) .or. any(max(va, vb) <= lo - r)) cycle
          this%ed_a = reshape([this%ed_a, va], [2, size(this%ed_a, 2) + 1])
          this%ed_b = reshape([this%ed_b, vb], [2, size(this%ed_b, 2) + 1])
          this%ed_ptr(k + 1) = this%ed_ptr(k + 1) + 1
        end associate
      end do
    end do

    ! circles and the angular range on which each lies on its own inflated obstacle
    this%nc = nc
    allocate(this%cen(2, nc), this%rho(nc), owner(nc), own_s(nc), own_span(nc))
    i = 0
    do k = 1, size(obstacles)
      associate (o => obstacles(k))
        select case (o%kind)
        case (OBST_DISK)
          i = i + 1
          call set_circle(i, k, o%vertices(:, 1), o%radius + r, 0.0_wp, twopi)
        case (OBST_SEGMENT)
          block
            real(wp) :: d(2), nl(2)
            d = o%vertices(:, 2) - o%vertices(:, 1)
            d = d / norm2(d)
            nl = [-d(2), d(1)]
            i = i + 1
            call set_circle(i, k, o%vertices(:, 1), o%radius + r, angle_of(nl), pi)
            i = i + 1
            call set_circle(i, k, o%vertices(:, 2), o%radius + r, angle_of(-nl), pi)
          end block
        case (OBST_POLYGON)
          nv = size(o%vertices, 2)
          do j = 1, nv
            block
              real(wp) :: nin(2), nout(2), a0
              nin = edge_normal(o%vertices(:, modulo(j - 2, nv) + 1), o%vertices(:, j))
              nout = edge_normal(o%vertices(:, j), o%vertices(:, modulo(j, nv) + 1))
              a0 = angle_of(nin)
              i = i + 1
              call set_circle(i, k, o%vertices(:, j), r, a0, modulo(angle_of(nout) - a0, twopi))
            end block
          end do
        end select
      end associate
    end do

    call end_circles(this, owner)
    call free_arcs(this, owner, own_s, own_span)
    call collect_nodes(this, b)
    call sort_nodes(this, b)
    call solve_distances(this, b)
    allocate(this%c_min(nc), source=huge(1.0_wp))
    do i = 1, nc
      do k = this%iv_ptr(i), this%iv_ptr(i + 1) - 1
        if (this%nd_ptr(k + 1) > this%nd_ptr(k)) &
          this%c_min(i) = min(this%c_min(i), minval(this%nd_dist(this%nd_ptr(k):this%nd_ptr(k + 1) - 1)))
      end do
    end do
    this%act = pack([(i, i = 1, nc)], this%c_min < huge(1.0_wp))
    this%ready = .true.

  contains

    !> axis-aligned rectangle, outside the box across one side, spanning that whole side,
    !> with both target ends at least r from it
    logical function is_slab(kk)
      integer, intent(in) :: kk
      real(wp) :: dd, nrm(2)
      integer :: jj, ax
      is_slab = .false.
      associate (o => obstacles(kk), bl => this%blo(:, kk), bh => this%bhi(:, kk))
        if (o%kind /= OBST_POLYGON) return
        if (size(o%vertices, 2) /= 4) return
        do jj = 1, 4
          if (.not. all((o%vertices(:, jj) == bl .or. o%vertices(:, jj) == bh))) return
        end do
        do ax = 1, 2
          if (bh(ax) <= lo(ax) .or. bl(ax) >= hi(ax)) then
            if (bl(3 - ax) <= lo(3 - ax) .and. bh(3 - ax) >= hi(3 - ax)) is_slab = .true.
          end if
        end do
        if (.not. is_slab) return
        call obstacle_distance(o, ta, dd, nrm)
        if (dd < r - this%tol) is_slab = .false.
        call obstacle_distance(o, tb, dd, nrm)
        if (dd < r - this%tol) is_slab = .false.
      end associate
    end function is_slab

    subroutine set_circle(ic, kown, c, rad, s, span)
      integer, intent(in) :: ic, kown
      real(wp), intent(in) :: c(2), rad, s, span
      this%cen(:, ic) = c
      this%rho(ic) = rad
      owner(ic) = kown
      own_s(ic) = s
      own_span(ic) = span
    end subroutine set_circle
  end subroutine init

  !> Outward unit normal of the edge a -> b of a counter-clockwise polygon.
  pure function edge_normal(a, b) result(n)
    real(wp), intent(in) :: a(2), b(2)
    real(wp) :: n(2)
    n = [b(2) - a(2), a(1) - b(1)]
    n = n / norm2(n)
  end function edge_normal

  !> Angle of v in [0, 2 pi).
  pure real(wp) function angle_of(v)
    real(wp), intent(in) :: v(2)
    angle_of = modulo(atan2(v(2), v(1)), twopi)
    if (angle_of >= twopi) angle_of = 0.0_wp
  end function angle_of

  !> Free arcs of every circle: split the circle at its crossings with the boundaries of the
  !> other inflated obstacles, with the box lines and at the ends of its own range; keep the
  !> pieces whose midpoint is free; merge neighbours.
  subroutine free_arcs(this, owner, own_s, own_span)
    type(geodesic_t), intent(inout) :: this
    integer, intent(in) :: owner(:)
    real(wp), intent(in) :: own_s(:), own_span(:)
    real(wp), allocatable :: cand(:), ts(:), te(:)
    logical, allocatable :: piece_free(:)
    integer :: i, k, j, nv, nca, np, m, first, narc
    integer, allocatable :: ptr(:)
    real(wp), allocatable :: as(:), ae(:)
    logical, allocatable :: afull(:)
    real(wp) :: c(2), rho, th, p(2), d, nrm(2), off
    logical :: ok

    allocate(ptr(this%nc + 1), as(0), ae(0), afull(0))
    ptr(1) = 1
    do i = 1, this%nc
      c = this%cen(:, i)
      rho = this%rho(i)
      nca = 0
      allocate(cand(0))
      call add_angle(own_s(i))
      call add_angle(own_s(i) + own_span(i))
      ! box lines
      call line_crossings([this%lo(1), 0.0_wp], [0.0_wp, 1.0_wp])
      call line_crossings([this%hi(1), 0.0_wp], [0.0_wp, 1.0_wp])
      call line_crossings([0.0_wp, this%lo(2)], [1.0_wp, 0.0_wp])
      call line_crossings([0.0_wp, this%hi(2)], [1.0_wp, 0.0_wp])
      do k = 1, size(this%obst)
        if (k == owner(i)) cycle
        if (any(this%blo(:, k) - this%r > c + rho) .or. any(this%bhi(:, k) + this%r < c - rho)) cycle
        associate (o => this%obst(k))
          select case (o%kind)
          case (OBST_DISK)
            call circle_crossings(o%vertices(:, 1), o%radius + this%r)
          case (OBST_SEGMENT)
            off = o%radius + this%r
            call circle_crossings(o%vertices(:, 1), off)
            call circle_crossings(o%vertices(:, 2), off)
            nrm = edge_normal(o%vertices(:, 1), o%vertices(:, 2))
            call line_crossings(o%vertices(:, 1) + off * nrm, o%vertices(:, 2) - o%vertices(:, 1))
            call line_crossings(o%vertices(:, 1) - off * nrm, o%vertices(:, 2) - o%vertices(:, 1))
          case (OBST_POLYGON)
            nv = size(o%vertices, 2)
            do j = 1, nv
              call circle_crossings(o%vertices(:, j), this%r)
              nrm = edge_normal(o%vertices(:, j), o%vertices(:, modulo(j, nv) + 1))
              call line_crossings(o%vertices(:, j) + this%r * nrm, &
                  o%vertices(:, modulo(j, nv) + 1) - o%vertices(:, j))
            end do
          end select
        end associate
      end do
      ! elementary pieces between sorted crossing angles (wrapping around)
      call sort_real(cand)
      np = size(cand)
      allocate(ts(np), te(np), piece_free(np))
      do m = 1, np
        ts(m) = cand(m)
        if (m < np) then
          te(m) = cand(m + 1)
        else
          te(m) = cand(1) + twopi
        end if
        piece_free(m) = .false.
        if (te(m) - ts(m) <= 1.0e-14_wp) cycle
        th = 0.5_wp * (ts(m) + te(m))
        if (modulo(th - own_s(i), twopi) > own_span(i)) cycle
        p = c + rho * [cos(th), sin(th)]
        if (any(p < this%lo - this%tol) .or. any(p > this%hi + this%tol)) cycle
        ok = .true.
        do k = 1, size(this%obst)
          if (k == owner(i)) cycle
          call obstacle_distance(this%obst(k), p, d, nrm)
          if (d < this%r - this%tol) then
            ok = .false.; exit
          end if
        end do
        piece_free(m) = ok
      end do
      ! merge: whole circle, none, or maximal runs starting after a blocked piece
      narc = 0
      if (np > 0) then
        if (all(piece_free .or. te - ts <= 1.0e-14_wp) .and. any(piece_free)) then
          as = [as, 0.0_wp]; ae = [ae, twopi]; afull = [afull, .true.]; narc = 1
        else if (any(piece_free)) then
          first = 1
          do m = 1, np
            if (.not. piece_free(m) .and. te(m) - ts(m) > 1.0e-14_wp) first = m
          end do
          ! walk np pieces starting after the blocked one
          j = 0
          do m = 1, np
            k = modulo(first + m - 1, np) + 1
            if (piece_free(k)) then
              if (j == 0) then
                narc = narc + 1
                as = [as, ts(k)]; ae = [ae, ts(k)]; afull = [afull, .false.]
                j = 1
              end if
              ! extend (unwrap relative to the start)
              ae(size(ae)) = as(size(as)) + modulo(te(k) - as(size(as)), twopi)
              if (ae(size(ae)) <= as(size(as))) ae(size(ae)) = as(size(as)) + twopi
            else if (te(k) - ts(k) > 1.0e-14_wp) then
              j = 0
            end if
          end do
          ! normalise the starts to [0, 2 pi)
          do m = size(as) - narc + 1, size(as)
            th = modulo(as(m), twopi)
            ae(m) = ae(m) + (th - as(m))
            as(m) = th
          end do
        end if
      end if
      ptr(i + 1) = ptr(i) + narc
      deallocate(cand, ts, te, piece_free)
    end do
    call move_alloc(ptr, this%iv_ptr)
    call move_alloc(as, this%iv_s)
    call move_alloc(ae, this%iv_e)
    call move_alloc(afull, this%iv_full)

  contains

    subroutine add_angle(a)
      real(wp), intent(in) :: a
      nca = nca + 1
      cand = [cand, angle_of([cos(a), sin(a)])]
    end subroutine add_angle

    !> crossings with the circle (c2, r2)
    subroutine circle_crossings(c2, r2)
      real(wp), intent(in) :: c2(2), r2
      real(wp) :: w(2), dd, a, h
      w = c2 - c
      dd = norm2(w)
      if (dd <= 0.0_wp .or. dd > rho + r2 .or. dd < abs(rho - r2)) return
      w = w / dd
      a = (dd * dd + rho * rho - r2 * r2) / (2.0_wp * dd)
      h = sqrt(max(rho * rho - a * a, 0.0_wp))
      cand = [cand, angle_of(a * w + h * [-w(2), w(1)]), angle_of(a * w - h * [-w(2), w(1)])]
    end subroutine circle_crossings

    !> crossings with the line through p0 with direction e
    subroutine line_crossings(p0, e)
      real(wp), intent(in) :: p0(2), e(2)
      real(wp) :: aa, bb, cc, disc, t
      aa = dot_product(e, e)
      bb = dot_product(e, p0 - c)
      cc = dot_product(p0 - c, p0 - c) - rho * rho
      disc = bb * bb - aa * cc
      if (disc < 0.0_wp) return
      t = (-bb + sqrt(disc)) / aa
      cand = [cand, angle_of(p0 + t * e - c)]
      t = (-bb - sqrt(disc)) / aa
      cand = [cand, angle_of(p0 + t * e - c)]
    end subroutine line_crossings
  end subroutine free_arcs

  !> Insertion sort (short arrays).
  pure subroutine sort_real(a)
    real(wp), intent(inout) :: a(:)
    integer :: i, j
    real(wp) :: x
    do i = 2, size(a)
      x = a(i)
      j = i - 1
      do while (j >= 1)
        if (a(j) <= x) exit
        a(j + 1) = a(j)
        j = j - 1
      end do
      a(j + 1) = x
    end do
  end subroutine sort_real

  !> Free arc of circle ic holding the angle th (0 if none) and the unwrapped angle u in it.
  pure subroutine locate(this, ic, th, arc, u)
    type(geodesic_t), intent(in) :: this
    integer, intent(in) :: ic
    real(wp), intent(in) :: th
    integer, intent(out) :: arc
    real(wp), intent(out) :: u
    integer :: k
    arc = 0
    u = th
    do k = this%iv_ptr(ic), this%iv_ptr(ic + 1) - 1
      if (this%iv_full(k)) then
        arc = k; u = th; return
      end if
      u = th
      if (u < this%iv_s(k) - atol) u = u + twopi
      if (u >= this%iv_s(k) - atol .and. u <= this%iv_e(k) + atol) then
        arc = k; return
      end if
      ! a node just below 2 pi may belong to an arc starting at 0
      if (th - twopi >= this%iv_s(k) - atol .and. th - twopi <= this%iv_e(k) + atol) then
        arc = k; u = th - twopi; return
      end if
    end do
  end subroutine locate

  !> Tangent points on circle (c, rho) of the lines through x (|x - c| >= rho, clamped):
  !> t(:, s) = c + rho n_s and the unit direction of travel dir(:, s) from x, s = 1 (+), 2 (-);
  !> branch 1 then turns clockwise around the circle, branch 2 counter-clockwise.
  pure subroutine point_tangents(x, c, rho, t, dir)
    real(wp), intent(in) :: x(2), c(2), rho
    real(wp), intent(out) :: t(2, 2), dir(2, 2)
    real(wp) :: w(2), wp_(2), d, cphi, sphi
    integer :: s
    real(wp) :: sg
    w = c - x
    d = norm2(w)
    if (d > 0.0_wp) then
      w = w / d
    else
      w = [1.0_wp, 0.0_wp]
    end if
    wp_ = [-w(2), w(1)]
    cphi = -min(rho / max(d, tiny(1.0_wp)), 1.0_wp)
    sphi = sqrt(max(1.0_wp - cphi * cphi, 0.0_wp))
    do s = 1, 2
      sg = merge(1.0_wp, -1.0_wp, s == 1)
      t(:, s) = c + rho * (cphi * w + sg * sphi * wp_)
      dir(:, s) = sphi * w - sg * cphi * wp_
    end do
  end subroutine point_tangents

  !> Nodes and straight edges: common tangents of circle pairs, tangents from the target
  !> endpoints, tangents normal to the target, target endpoints on circles.
  subroutine collect_nodes(this, b)
    type(geodesic_t), intent(inout) :: this
    type(build_t), intent(inout) :: b
    integer :: i, j, s, a1, a2, k
    real(wp) :: w(2), wq(2), d, cphi, sphi, n(2), p1(2), p2(2), u1, u2, t(2, 2), dir(2, 2), e(2), tv(2)
    logical :: has_i, has_j
    allocate(b%circ(64), b%arc(64), b%pos(2, 64), b%u(64), b%ea(64), b%eb(64), b%ew(64))
    do i = 1, this%nc
      has_i = this%iv_ptr(i + 1) > this%iv_ptr(i)
      if (.not. has_i) cycle
      do j = i + 1, this%nc
        has_j = this%iv_ptr(j + 1) > this%iv_ptr(j)
        if (.not. has_j) cycle
        w = this%cen(:, j) - this%cen(:, i)
        d = norm2(w)
        if (d <= this%tol) cycle
        w = w / d
        wq = [-w(2), w(1)]
        ! outer (same side, n.w = (ri - rj)/d) then inner (n.w = (ri + rj)/d, opposite sides)
        do k = 1, 2
          if (k == 1) then
            cphi = (this%rho(i) - this%rho(j)) / d
          else
            cphi = (this%rho(i) + this%rho(j)) / d
          end if
          if (abs(cphi) > 1.0_wp) cycle
          sphi = sqrt(max(1.0_wp - cphi * cphi, 0.0_wp))
          do s = 1, 2
            n = cphi * w + merge(sphi, -sphi, s == 1) * wq
            p1 = this%cen(:, i) + this%rho(i) * n
            if (k == 1) then
              p2 = this%cen(:, j) + this%rho(j) * n
            else
              p2 = this%cen(:, j) - this%rho(j) * n
            end if
            call locate(this, i, angle_of(p1 - this%cen(:, i)), a1, u1)
            if (a1 == 0) cycle
            call locate(this, j, angle_of(p2 - this%cen(:, j)), a2, u2)
            if (a2 == 0) cycle
            if (.not. this%visible(p1, p2)) cycle
            call add_edge(add_node(i, a1, p1, u1), add_node(j, a2, p2, u2), norm2(p2 - p1))
            if (sphi == 0.0_wp) exit
          end do
        end do
      end do
      ! tangents from the target endpoints, and endpoints lying on the circle
      do k = 1, 2
        e = merge(this%ta, this%tb, k == 1)
        if (abs(norm2(e - this%cen(:, i)) - this%rho(i)) <= this%tol) then
          call locate(this, i, angle_of(e - this%cen(:, i)), a1, u1)
          if (a1 /= 0) j = add_node(i, a1, e, u1)
          cycle
        end if
        if (norm2(e - this%cen(:, i)) < this%rho(i)) cycle
        call point_tangents(e, this%cen(:, i), this%rho(i), t, dir)
        do s = 1, 2
          call locate(this, i, angle_of(t(:, s) - this%cen(:, i)), a1, u1)
          if (a1 /= 0) j = add_node(i, a1, t(:, s), u1)
        end do
      end do
      ! legs normal to the target
      tv = this%tb - this%ta
      if (norm2(tv) > this%tol) then
        tv = tv / norm2(tv)
        do s = 1, 2
          p1 = this%cen(:, i) + merge(1.0_wp, -1.0_wp, s == 1) * this%rho(i) * tv
          call locate(this, i, angle_of(p1 - this%cen(:, i)), a1, u1)
          if (a1 /= 0) j = add_node(i, a1, p1, u1)
        end do
      end if
    end do

  contains

    integer function add_node(ic, arc, p, u) result(id)
      integer, intent(in) :: ic, arc
      real(wp), intent(in) :: p(2), u
      integer :: cap
      if (b%nn == size(b%circ)) then
        cap = size(b%circ)
        b%circ = [b%circ, b%circ]; b%arc = [b%arc, b%arc]; b%u = [b%u, b%u]
        b%pos = reshape([b%pos, b%pos], [2, 2 * cap])
      end if
      b%nn = b%nn + 1
      id = b%nn
      b%circ(id) = ic; b%arc(id) = arc; b%pos(:, id) = p; b%u(id) = u
    end function add_node

    subroutine add_edge(na, nb, wgt)
      integer, intent(in) :: na, nb
      real(wp), intent(in) :: wgt
      if (b%ne == size(b%ea)) then
        b%ea = [b%ea, b%ea]; b%eb = [b%eb, b%eb]; b%ew = [b%ew, b%ew]
      end if
      b%ne = b%ne + 1
      b%ea(b%ne) = na; b%eb(b%ne) = nb; b%ew(b%ne) = wgt
    end subroutine add_edge
  end subroutine collect_nodes

  !> Order the nodes by (arc, unwrapped angle); renumber the edges; store positions.
  subroutine sort_nodes(this, b)
    type(geodesic_t), intent(inout) :: this
    type(build_t), intent(inout) :: b
    integer :: narc, k, m, i, j, pos
    integer, allocatable :: cnt(:), perm(:), newid(:)
    real(wp) :: key
    narc = size(this%iv_s)
    allocate(cnt(narc + 1), source=0)
    do m = 1, b%nn
      cnt(b%arc(m) + 1) = cnt(b%arc(m) + 1) + 1
    end do
    allocate(this%nd_ptr(narc + 1))
    this%nd_ptr(1) = 1
    do k = 1, narc
      this%nd_ptr(k + 1) = this%nd_ptr(k) + cnt(k + 1)
    end do
    ! bucket by arc, then insertion-sort each bucket by u
    allocate(perm(b%nn), newid(b%nn))
    cnt(1:narc) = this%nd_ptr(1:narc)
    do m = 1, b%nn
      perm(cnt(b%arc(m))) = m
      cnt(b%arc(m)) = cnt(b%arc(m)) + 1
    end do
    do k = 1, narc
      do i = this%nd_ptr(k) + 1, this%nd_ptr(k + 1) - 1
        pos = perm(i)
        key = b%u(pos)
        j = i - 1
        do while (j >= this%nd_ptr(k))
          if (b%u(perm(j)) <= key) exit
          perm(j + 1) = perm(j)
          j = j - 1
        end do
        perm(j + 1) = pos
      end do
    end do
    this%nn = b%nn
    allocate(this%nd_pos(2, b%nn), this%nd_u(b%nn), this%nd_dist(b%nn))
    do i = 1, b%nn
      newid(perm(i)) = i
      this%nd_pos(:, i) = b%pos(:, perm(i))
      this%nd_u(i) = b%u(perm(i))
    end do
    do m = 1, b%ne
      b%ea(m) = newid(b%ea(m))
      b%eb(m) = newid(b%eb(m))
    end do
  end subroutine sort_nodes

  !> Seed every node with its visible straight leg to the target; arcs between consecutive
  !> nodes of each free arc; Dijkstra (binary heap, lazy deletion).
  subroutine solve_distances(this, b)
    type(geodesic_t), intent(inout) :: this
    type(build_t), intent(inout) :: b
    integer :: k, i, ic, m, nedge, v, w, top
    integer, allocatable :: ea(:), eb(:), deg(:), adj(:), hp_node(:)
    real(wp), allocatable :: ew(:), wt(:), hp_key(:)
    logical, allocatable :: done(:)
    real(wp) :: dnew
    ! arc edges
    ea = b%ea(1:b%ne); eb = b%eb(1:b%ne); ew = b%ew(1:b%ne)
    do ic = 1, this%nc
      do k = this%iv_ptr(ic), this%iv_ptr(ic + 1) - 1
        do i = this%nd_ptr(k), this%nd_ptr(k + 1) - 2
          ea = [ea, i]; eb = [eb, i + 1]
          ew = [ew, this%rho(ic) * (this%nd_u(i + 1) - this%nd_u(i))]
        end do
        if (this%iv_full(k) .and. this%nd_ptr(k + 1) - this%nd_ptr(k) >= 2) then
          ea = [ea, this%nd_ptr(k + 1) - 1]; eb = [eb, this%nd_ptr(k)]
          ew = [ew, this%rho(ic) * (this%nd_u(this%nd_ptr(k)) + twopi - this%nd_u(this%nd_ptr(k + 1) - 1))]
        end if
      end do
    end do
    nedge = size(ea)
    ! CSR adjacency (both directions)
    allocate(deg(this%nn + 1), source=0)
    do m = 1, nedge
      deg(ea(m) + 1) = deg(ea(m) + 1) + 1
      deg(eb(m) + 1) = deg(eb(m) + 1) + 1
    end do
    deg(1) = 1
    do i = 1, this%nn
      deg(i + 1) = deg(i + 1) + deg(i)
    end do
    allocate(adj(2 * nedge), wt(2 * nedge))
    block
      integer, allocatable :: fill(:)
      fill = deg(1:this%nn)
      do m = 1, nedge
        adj(fill(ea(m))) = eb(m); wt(fill(ea(m))) = ew(m); fill(ea(m)) = fill(ea(m)) + 1
        adj(fill(eb(m))) = ea(m); wt(fill(eb(m))) = ew(m); fill(eb(m)) = fill(eb(m)) + 1
      end do
    end block
    ! seeds
    allocate(hp_node(this%nn + 2 * nedge + 1), hp_key(this%nn + 2 * nedge + 1), done(this%nn))
    done = .false.
    top = 0
    do i = 1, this%nn
      this%nd_dist(i) = leg_to_target(this, this%nd_pos(:, i))
      if (this%nd_dist(i) < huge(1.0_wp)) call push(this%nd_dist(i), i)
    end do
    do while (top > 0)
      v = hp_node(1)
      call pop()
      if (done(v)) cycle
      done(v) = .true.
      do m = deg(v), deg(v + 1) - 1
        w = adj(m)
        dnew = this%nd_dist(v) + wt(m)
        if (dnew < this%nd_dist(w)) then
          this%nd_dist(w) = dnew
          call push(dnew, w)
        end if
      end do
    end do

  contains

    subroutine push(key, node)
      real(wp), intent(in) :: key
      integer, intent(in) :: node
      integer :: c, p
      top = top + 1
      c = top
      do while (c > 1)
        p = c / 2
        if (hp_key(p) <= key) exit
        hp_key(c) = hp_key(p); hp_node(c) = hp_node(p)
        c = p
      end do
      hp_key(c) = key; hp_node(c) = node
    end subroutine push

    subroutine pop()
      integer :: c, p
      real(wp) :: key
      integer :: node
      key = hp_key(top); node = hp_node(top)
      top = top - 1
      p = 1
      do
        c = 2 * p
        if (c > top) exit
        if (c < top) then
          if (hp_key(c + 1) < hp_key(c)) c = c + 1
        end if
        if (key <= hp_key(c)) exit
        hp_key(p) = hp_key(c); hp_node(p) = hp_node(c)
        p = c
      end do
      if (top >= 1) then
        hp_key(p) = key; hp_node(p) = node
      end if
    end subroutine pop
  end subroutine solve_distances

  !> Shortest visible straight leg from x to the target (closest point or an endpoint);
  !> huge if none is visible. s: its target point; closest: .true. if it is the closest point
  !> (then it is the geodesic: the Euclidean distance is a lower bound; an endpoint leg is
  !> only a candidate).
  function leg_to_target(this, x, s, closest) result(d)
    type(geodesic_t), intent(in) :: this
    real(wp), intent(in) :: x(2)
    real(wp), intent(out), optional :: s(2)
    logical, intent(out), optional :: closest
    real(wp) :: d
    real(wp) :: cand(2, 3), l
    integer :: k
    cand(:, 1) = closest_point_on_segment(x, this%ta, this%tb)
    cand(:, 2) = this%ta
    cand(:, 3) = this%tb
    d = huge(1.0_wp)
    if (present(s)) s = cand(:, 1)
    if (present(closest)) closest = .false.
    do k = 1, 3
      ! an endpoint that is the closest point was just found out of sight
      if (k > 1 .and. cand(1, k) == cand(1, 1) .and. cand(2, k) == cand(2, 1)) cycle
      l = norm2(cand(:, k) - x)
      if (l >= d) cycle
      if (.not. this%visible(x, cand(:, k))) cycle
      d = l
      if (present(s)) s = cand(:, k)
      if (present(closest)) closest = k == 1
      if (k == 1) exit   ! the closest point, when visible, is optimal
    end do
  end function leg_to_target

  !> .true. if the segment [a, b] keeps at least r - tol from every obstacle. Both points
  !> must be free (in the box, outside the inflated obstacles, up to tol): then the walls
  !> marked `slab` (see init) cannot be met and are skipped.
  logical function visible(this, a, b)
    class(geodesic_t), intent(in) :: this
    real(wp), intent(in) :: a(2), b(2)
    integer :: kk, k
    real(wp) :: slo(2), shi(2), rr
    visible = .true.
    rr = this%r - this%tol
    slo = min(a, b) - rr
    shi = max(a, b) + rr
    do kk = 1, size(this%near_k)
      k = this%near_k(kk)
      if (this%blo(1, k) > shi(1) .or. this%blo(2, k) > shi(2) .or. &
          this%bhi(1, k) < slo(1) .or. this%bhi(2, k) < slo(2)) cycle
      if (this%obst(k)%kind == OBST_POLYGON) then
        if (edges_blocked(this%ed_a(:, this%ed_ptr(k):this%ed_ptr(k + 1) - 1), &
            this%ed_b(:, this%ed_ptr(k):this%ed_ptr(k + 1) - 1), a, b, rr)) then
          visible = .false.
          return
        end if
      else if (this%obst(k)%kind == OBST_DISK) then
        if (pseg2(this%obst(k)%vertices(:, 1), a, b) < (this%obst(k)%radius + rr)**2) then
          visible = .false.
          return
        end if
      else if (segment_obstacle_distance(this%obst(k), a, b) < rr) then
        visible = .false.
        return
      end if
    end do
  end function visible

  !> For each target end, the circle nearest to it whose obstacle is not a slab (an exit corner
  !> inflated by r passes through the end) and its surely blocking radius (see sure_blocked).
  subroutine end_circles(this, owner)
    type(geodesic_t), intent(inout) :: this
    integer, intent(in) :: owner(:)
    real(wp) :: e(2), gap, best
    integer :: k, i
    this%end_c = 0
    this%end_r2 = 0.0_wp
    do k = 1, 2
      e = merge(this%ta, this%tb, k == 1)
      best = huge(1.0_wp)
      do i = 1, this%nc
        if (this%slab(owner(i))) cycle
        if (this%rho(i) <= this%tol) cycle
        gap = norm2(e - this%cen(:, i)) - this%rho(i)
        if (gap < best) then
          best = gap
          this%end_c(k) = i
        end if
      end do
      if (this%end_c(k) > 0) this%end_r2(k) = (this%rho(this%end_c(k)) - this%tol)**2 * (1.0_wp - sure_margin)
    end do
  end subroutine end_circles

  !> .true. if the leg [a, b] passes the centre of a target end's circle (end_circles) closer than
  !> its surely blocking radius: then it comes closer than r - tol to that circle's obstacle (a
  !> polygon vertex, a disk or a capsule end lies at the centre, rho - r inside the obstacle),
  !> so `visible` would say .false.; the relative margin sure_margin on the squared distance is
  !> far above the round-off of either test, so both always agree. A leg not surely blocked
  !> still needs `visible`.
  pure logical function sure_blocked(this, a, b) result(blocked)
    type(geodesic_t), intent(in) :: this
    real(wp), intent(in) :: a(2), b(2)
    integer :: k
    blocked = .false.
    do k = 1, 2
      if (this%end_c(k) == 0) cycle
      if (pseg2(this%cen(:, this%end_c(k)), a, b) < this%end_r2(k)) then
        blocked = .true.
        return
      end if
    end do
  end function sure_blocked

  !> .true. if the segment [a, b] comes closer than rr to one of the edges [ea(:, i), eb(:, i)].
  !> With both ends outside the polygon this is segment_obstacle_distance < rr: a segment
  !> entering the polygon crosses an edge (edges farther than rr from the box cannot be met by
  !> a segment in the box and are left out by init).
  pure logical function edges_blocked(ea, eb, a, b, rr) result(blocked)
    real(wp), intent(in) :: ea(:,:), eb(:,:), a(2), b(2), rr
    integer :: i
    real(wp) :: r2
    r2 = rr * rr
    blocked = .true.
    do i = 1, size(ea, 2)
      if (segseg_near(a, b, ea(:, i), eb(:, i), r2)) return
    end do
    blocked = .false.
  end function edges_blocked

  !> .true. if the segments [a, b] and [c, d] are closer than sqrt(r2). Quick exit when the
  !> ends of one segment lie on the same side of the other's line, both at least sqrt(r2) away.
  pure logical function segseg_near(a, b, c, d, r2) result(near)
    real(wp), intent(in) :: a(2), b(2), c(2), d(2), r2
    real(wp) :: o1, o2, o3, o4, l2
    near = .false.
    o1 = (b(1) - a(1)) * (c(2) - a(2)) - (b(2) - a(2)) * (c(1) - a(1))
    o2 = (b(1) - a(1)) * (d(2) - a(2)) - (b(2) - a(2)) * (d(1) - a(1))
    if (o1 * o2 > 0.0_wp) then
      l2 = (b(1) - a(1))**2 + (b(2) - a(2))**2
      if (min(o1 * o1, o2 * o2) >= r2 * l2) return
    end if
    o3 = (d(1) - c(1)) * (a(2) - c(2)) - (d(2) - c(2)) * (a(1) - c(1))
    o4 = (d(1) - c(1)) * (b(2) - c(2)) - (d(2) - c(2)) * (b(1) - c(1))
    if (o3 * o4 > 0.0_wp) then
      l2 = (d(1) - c(1))**2 + (d(2) - c(2))**2
      if (min(o3 * o3, o4 * o4) >= r2 * l2) return
    end if
    near = segseg_dist2(a, b, c, d) < r2
  end function segseg_near

  !> Squared distance between the segments [a, b] and [c, d] (0 if they cross).
  pure real(wp) function segseg_dist2(a, b, c, d) result(d2)
    real(wp), intent(in) :: a(2), b(2), c(2), d(2)
    real(wp) :: o1, o2, o3, o4
    o1 = (b(1) - a(1)) * (c(2) - a(2)) - (b(2) - a(2)) * (c(1) - a(1))
    o2 = (b(1) - a(1)) * (d(2) - a(2)) - (b(2) - a(2)) * (d(1) - a(1))
    o3 = (d(1) - c(1)) * (a(2) - c(2)) - (d(2) - c(2)) * (a(1) - c(1))
    o4 = (d(1) - c(1)) * (b(2) - c(2)) - (d(2) - c(2)) * (b(1) - c(1))
    if (((o1 > 0.0_wp .and. o2 < 0.0_wp) .or. (o1 < 0.0_wp .and. o2 > 0.0_wp)) .and. &
        ((o3 > 0.0_wp .and. o4 < 0.0_wp) .or. (o3 < 0.0_wp .and. o4 > 0.0_wp))) then
      d2 = 0.0_wp
      return
    end if
    d2 = min(pseg2(a, c, d), pseg2(b, c, d), pseg2(c, a, b), pseg2(d, a, b))
  end function segseg_dist2

  !> Squared distance from p to the segment [a, b].
  pure real(wp) function pseg2(p, a, b)
    real(wp), intent(in) :: p(2), a(2), b(2)
    real(wp) :: e(2), ee, s, w(2)
    e = b - a
    ee = e(1) * e(1) + e(2) * e(2)
    w = p - a
    s = 0.0_wp
    if (ee > 0.0_wp) s = min(1.0_wp, max(0.0_wp, (w(1) * e(1) + w(2) * e(2)) / ee))
    w = w - s * e
    pseg2 = w(1) * w(1) + w(2) * w(2)
  end function pseg2

  !> Geodesic distance dist from p to the target and unit descent direction dir (first leg).
  !> ok = .false. (dist = huge, dir = 0) if p is outside the box, cannot reach the target,
  !> or is on the target (no direction).
  subroutine query(this, p, dist, dir, ok)
    class(geodesic_t), intent(in) :: this
    real(wp), intent(in) :: p(2)
    real(wp), intent(out) :: dist, dir(2)
    logical, intent(out) :: ok
    real(wp) :: x(2), shift, d, nrm(2), s(2), l, t(2, 2), tdir(2, 2), th, u, best, cost, arcd
    real(wp) :: sc(2), e(2), le_best
    integer :: it, k, ic, br, arc, m, nb
    logical :: moved
    real(wp) :: lb(GEODESIC_MAX_CIRCLES)
    integer :: na

    dist = huge(1.0_wp)
    dir = 0.0_wp
    ok = .false.
    if (.not. this%ready) return
    if (.not. all(ieee_is_finite(p))) return
    if (any(p < this%lo - this%tol) .or. any(p > this%hi + this%tol)) return
    ! move a point inside an inflated obstacle to the nearest boundary point
    x = p
    shift = 0.0_wp
    do it = 1, 4
      moved = .false.
      do k = 1, size(this%obst)
        if (this%plo(1, k) > x(1) .or. this%plo(2, k) > x(2) .or. &
            this%phi(1, k) < x(1) .or. this%phi(2, k) < x(2)) cycle
        call obstacle_distance(this%obst(k), x, d, nrm)
        if (d < this%r) then
          x = x + (this%r - d) * nrm
          moved = moved .or. (this%r - d) > this%tol
        end if
      end do
      if (.not. moved) exit
    end do
    shift = norm2(x - p)
    ! the exit's closest point in sight: the straight leg is the geodesic
    sc = closest_point_on_segment(x, this%ta, this%tb)
    if (.not. sure_blocked(this, x, sc)) then
      if (this%visible(x, sc)) then
        l = norm2(sc - x)
        if (l <= 0.0_wp) return
        dist = l + shift
        dir = (sc - x) / l
        ok = .true.
        return
      end if
    end if
    best = huge(1.0_wp)
    ! around obstacles: first leg tangent to a circle, then along its free arc to a node;
    ! circles in increasing order of a lower bound (tangent length + the circle's smallest node
    ! distance) until the bound reaches the best path found
    na = size(this%act)
    do k = 1, na
      ic = this%act(k)
      lb(k) = sqrt(max(sum((this%cen(:, ic) - x)**2) - this%rho(ic)**2, 0.0_wp)) + this%c_min(ic)
    end do
    do it = 1, na
      k = minloc(lb(1:na), dim=1)
      if (lb(k) >= best) exit
      lb(k) = huge(1.0_wp)
      ic = this%act(k)
      call point_tangents(x, this%cen(:, ic), this%rho(ic), t, tdir)
      do br = 1, 2
        th = angle_of(t(:, br) - this%cen(:, ic))
        call locate(this, ic, th, arc, u)
        if (arc == 0) cycle
        nb = 0
        arcd = huge(1.0_wp)
        if (br == 1) then
          ! clockwise: the node with the largest angle <= u
          do m = this%nd_ptr(arc + 1) - 1, this%nd_ptr(arc), -1
            if (this%nd_u(m) <= u) then
              nb = m; arcd = u - this%nd_u(m); exit
            end if
          end do
          if (nb == 0 .and. this%iv_full(arc) .and. this%nd_ptr(arc + 1) > this%nd_ptr(arc)) then
            nb = this%nd_ptr(arc + 1) - 1; arcd = u + twopi - this%nd_u(nb)
          end if
        else
          do m = this%nd_ptr(arc), this%nd_ptr(arc + 1) - 1
            if (this%nd_u(m) >= u) then
              nb = m; arcd = this%nd_u(m) - u; exit
            end if
          end do
          if (nb == 0 .and. this%iv_full(arc) .and. this%nd_ptr(arc + 1) > this%nd_ptr(arc)) then
            nb = this%nd_ptr(arc); arcd = this%nd_u(nb) + twopi - u
          end if
        end if
        if (nb == 0) cycle
        if (this%nd_dist(nb) >= huge(1.0_wp)) cycle
        l = norm2(t(:, br) - x)
        cost = l + this%rho(ic) * arcd + this%nd_dist(nb)
        if (cost >= best) cycle
        if (.not. this%visible(x, t(:, br))) cycle
        best = cost
        dir = tdir(:, br)
      end do
    end do
    ! a straight leg to an endpoint of the target (the nearer one in sight) is the path when
    ! it is not longer than the best path around obstacles (ties: the leg); endpoints farther
    ! than that best path need no visibility test. Same result as testing the endpoints first
    ! and pruning the circles with their length: the circles are visited in the same order
    ! and a path is kept only when strictly shorter.
    le_best = huge(1.0_wp)
    do k = 1, 2
      if (k == 1) then
        e = this%ta
      else
        e = this%tb
      end if
      if (e(1) == sc(1) .and. e(2) == sc(2)) cycle   ! the closest point, out of sight
      l = norm2(e - x)
      if (l >= le_best .or. l > best) cycle
      if (.not. this%visible(x, e)) cycle
      le_best = l
      s = e
    end do
    if (le_best < huge(1.0_wp) .and. le_best <= best) then
      if (le_best <= 0.0_wp) then   ! on the target: no direction
        dir = 0.0_wp
        return
      end if
      best = le_best
      dir = (s - x) / le_best
    end if
    if (best >= huge(1.0_wp)) return
    dist = best + shift
    ok = .true.
  end subroutine query

  !> Number of nodes of the tangent graph.
  pure integer function n_nodes(this)
    class(geodesic_t), intent(in) :: this
    n_nodes = this%nn
  end function n_nodes

  !> Release the arrays.
  subroutine free(this)
    class(geodesic_t), intent(inout) :: this
    if (allocated(this%obst)) deallocate(this%obst)
    if (allocated(this%blo)) deallocate(this%blo, this%bhi, this%slab)
    if (allocated(this%near_k)) deallocate(this%near_k)
    if (allocated(this%plo)) deallocate(this%plo, this%phi)
    if (allocated(this%ed_ptr)) deallocate(this%ed_ptr, this%ed_a, this%ed_b)
    if (allocated(this%cen)) deallocate(this%cen, this%rho)
    if (allocated(this%iv_ptr)) deallocate(this%iv_ptr, this%iv_s, this%iv_e, this%iv_full)
    if (allocated(this%nd_ptr)) deallocate(this%nd_ptr)
    if (allocated(this%nd_pos)) deallocate(this%nd_pos, this%nd_u, this%nd_dist)
    if (allocated(this%c_min)) deallocate(this%c_min)
    if (allocated(this%act)) deallocate(this%act)
    this%nc = 0
    this%nn = 0
    this%end_c = 0
    this%end_r2 = 0.0_wp
    this%ready = .false.
  end subroutine free
end module cr_geodesic
