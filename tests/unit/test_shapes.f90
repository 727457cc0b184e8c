!> Unit tests of cr_shapes: exact signed distances and normals of disks, capsules and convex
!> polygons, normals against finite differences, bounding boxes, constructor errors.
program test_shapes
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_shapes, only: obstacle_t, OBST_DISK, OBST_SEGMENT, OBST_POLYGON, make_disk, make_segment, &
      make_polygon, make_rectangle, obstacle_distance, obstacle_bbox, point_segment_distance, &
      segment_obstacle_distance, segment_segment_distance
  implicit none
  real(wp), parameter :: tol = 1.0e-13_wp
  type(obstacle_t) :: disk, caps, rect, tri, tri_cw, wall
  type(error_t), allocatable :: error
  real(wp) :: d, n(2), lo(2), hi(2)

  ! ---- constructors ----
  call make_disk([1.0_wp, 2.0_wp], 0.5_wp, "pillar", disk, error)
  call check(.not. allocated(error), "make_disk ok")
  call check(disk%kind == OBST_DISK, "disk kind")
  call make_segment([0.0_wp, 0.0_wp], [2.0_wp, 0.0_wp], 0.25_wp, "bench", caps, error)
  call check(.not. allocated(error), "make_segment ok")
  call check(caps%kind == OBST_SEGMENT, "segment kind")
  call make_segment([0.0_wp, 0.0_wp], [0.0_wp, 1.0_wp], 0.0_wp, "wall", wall, error)
  call check(.not. allocated(error), "zero-thickness segment ok")
  call make_rectangle(0.0_wp, 0.0_wp, 2.0_wp, 1.0_wp, "table", rect, error)
  call check(.not. allocated(error), "make_rectangle ok")
  call check(rect%kind == OBST_POLYGON .and. size(rect%vertices, 2) == 4, "rectangle is a 4-gon")
  call make_polygon(reshape([0.0_wp, 0.0_wp, 4.0_wp, 0.0_wp, 0.0_wp, 3.0_wp], [2, 3]), "tri", tri, error)
  call check(.not. allocated(error), "make_polygon ccw ok")
  call make_polygon(reshape([0.0_wp, 0.0_wp, 0.0_wp, 3.0_wp, 4.0_wp, 0.0_wp], [2, 3]), "tri_cw", tri_cw, error)
  call check(.not. allocated(error), "make_polygon cw accepted")
  call check(all(abs(tri_cw%vertices - tri%vertices(:, [2, 3, 1])) == 0.0_wp), "cw input reversed to ccw")

  call expect_error_disk(-1.0_wp, "radius must be > 0", "negative radius")
  call expect_error_disk(0.0_wp, "radius must be > 0", "zero radius")
  call expect_error_disk(ieee_nan(), "not finite", "NaN radius")
  call expect_error_segment([1.0_wp, 1.0_wp], [1.0_wp, 1.0_wp], 0.1_wp, "degenerate segment", "a == b")
  call expect_error_segment([0.0_wp, 0.0_wp], [1.0_wp, 1.0_wp], -0.1_wp, "half-thickness must be >= 0", &
      "negative thickness")
  call expect_error_polygon(reshape([0.0_wp, 0.0_wp, 2.0_wp, 0.0_wp, 1.0_wp, 0.5_wp, 2.0_wp, 2.0_wp, &
      0.0_wp, 2.0_wp], [2, 5]), "not convex", "non-convex (dart)")
  call expect_error_polygon(reshape([0.0_wp, 0.0_wp, 1.0_wp, 0.0_wp, 2.0_wp, 0.0_wp, 1.0_wp, 1.0_wp], &
      [2, 4]), "collinear", "collinear vertex")
  call expect_error_polygon(reshape([0.0_wp, 0.0_wp, 1.0_wp, 1.0_wp, 2.0_wp, 2.0_wp], [2, 3]), &
      "zero area", "all collinear")
  call expect_error_polygon(reshape([0.0_wp, 0.0_wp, 1.0_wp, 0.0_wp], [2, 2]), "at least 3", "two vertices")
  call expect_error_polygon(reshape([0.0_wp, 0.0_wp, 1.0_wp, 0.0_wp, 1.0_wp, 0.0_wp, 0.0_wp, 1.0_wp], &
      [2, 4]), "coincide", "repeated vertex")
  ! pentagram: every turn is a left turn but the outline winds twice
  call expect_error_polygon(star(), "winds more than once", "self-intersecting star")
  block
    type(obstacle_t) :: r
    call make_rectangle(1.0_wp, 0.0_wp, 0.0_wp, 1.0_wp, "bad_rect", r, error)
    call check(allocated(error), "inverted rectangle rejected")
  end block

  ! ---- disk ----
  call obstacle_distance(disk, [1.0_wp, 3.0_wp], d, n)
  call check_close(d, 0.5_wp, tol, "disk outside distance")
  call check_vec(n, [0.0_wp, 1.0_wp], "disk outside normal")
  call obstacle_distance(disk, [1.3_wp, 2.4_wp], d, n)
  call check_close(d, 0.0_wp, tol, "disk on boundary")
  call check_vec(n, [0.6_wp, 0.8_wp], "disk boundary normal")
  call obstacle_distance(disk, [0.8_wp, 2.0_wp], d, n)
  call check_close(d, -0.3_wp, tol, "disk inside distance")
  call check_vec(n, [-1.0_wp, 0.0_wp], "disk inside normal")
  call obstacle_distance(disk, [1.0_wp, 2.0_wp], d, n)
  call check_close(d, -0.5_wp, tol, "disk centre distance")
  call check_close(norm2(n), 1.0_wp, tol, "disk centre normal is unit")

  ! ---- capsule [0,0]-[2,0], half-thickness 0.25 ----
  call obstacle_distance(caps, [1.0_wp, 1.0_wp], d, n)
  call check_close(d, 0.75_wp, tol, "capsule above middle")
  call check_vec(n, [0.0_wp, 1.0_wp], "capsule normal above middle")
  call obstacle_distance(caps, [1.5_wp, -0.1_wp], d, n)
  call check_close(d, -0.15_wp, tol, "capsule inside")
  call check_vec(n, [0.0_wp, -1.0_wp], "capsule inside normal")
  call obstacle_distance(caps, [5.0_wp, 4.0_wp], d, n)
  call check_close(d, 4.75_wp, tol, "capsule beyond end b")
  call check_vec(n, [0.6_wp, 0.8_wp], "capsule end-cap normal")
  call obstacle_distance(caps, [-0.3_wp, 0.0_wp], d, n)
  call check_close(d, 0.05_wp, tol, "capsule beyond end a")
  call check_vec(n, [-1.0_wp, 0.0_wp], "capsule end-a normal")
  call obstacle_distance(caps, [1.0_wp, 0.0_wp], d, n)
  call check_close(d, -0.25_wp, tol, "capsule on axis")
  call check_vec(n, [0.0_wp, 1.0_wp], "capsule axis normal is left normal")
  call obstacle_distance(wall, [0.5_wp, 0.5_wp], d, n)
  call check_close(d, 0.5_wp, tol, "zero-thickness wall distance")
  call check_close(point_segment_distance([3.0_wp, 4.0_wp], [0.0_wp, 0.0_wp], [0.0_wp, 0.0_wp]), 5.0_wp, &
      tol, "point_segment_distance with a == b")

  ! ---- rectangle [0,2]x[0,1] ----
  call obstacle_distance(rect, [1.0_wp, 1.5_wp], d, n)
  call check_close(d, 0.5_wp, tol, "rect above top edge")
  call check_vec(n, [0.0_wp, 1.0_wp], "rect top normal")
  call obstacle_distance(rect, [2.3_wp, 0.5_wp], d, n)
  call check_close(d, 0.3_wp, tol, "rect right of right edge")
  call check_vec(n, [1.0_wp, 0.0_wp], "rect right normal")
  call obstacle_distance(rect, [2.3_wp, 1.4_wp], d, n)
  call check_close(d, 0.5_wp, tol, "rect near corner (2,1)")
  call check_vec(n, [0.6_wp, 0.8_wp], "rect corner normal")
  call obstacle_distance(rect, [-0.3_wp, -0.4_wp], d, n)
  call check_close(d, 0.5_wp, tol, "rect near corner (0,0)")
  call check_vec(n, [-0.6_wp, -0.8_wp], "rect corner (0,0) normal")
  call obstacle_distance(rect, [1.0_wp, 0.8_wp], d, n)
  call check_close(d, -0.2_wp, tol, "rect inside near top")
  call check_vec(n, [0.0_wp, 1.0_wp], "rect inside normal top")
  call obstacle_distance(rect, [0.1_wp, 0.5_wp], d, n)
  call check_close(d, -0.1_wp, tol, "rect inside near left")
  call check_vec(n, [-1.0_wp, 0.0_wp], "rect inside normal left")
  call obstacle_distance(rect, [2.0_wp, 1.0_wp], d, n)
  call check_close(d, 0.0_wp, tol, "rect on vertex")
  call check_close(norm2(n), 1.0_wp, tol, "rect vertex normal unit")
  call check(n(1) >= 0.0_wp .and. n(2) >= 0.0_wp .and. maxval(n) == 1.0_wp, "rect vertex normal outward")

  ! ---- triangle (0,0),(4,0),(0,3): hypotenuse normal (3,4)/5 ----
  call obstacle_distance(tri, [4.0_wp, 3.0_wp], d, n)
  call check_close(d, 12.0_wp / 5.0_wp, tol, "triangle outside hypotenuse")
  call check_vec(n, [0.6_wp, 0.8_wp], "triangle hypotenuse normal")
  call obstacle_distance(tri, [1.0_wp, 1.0_wp], d, n)
  call check_close(d, -1.0_wp, tol, "triangle inside (incentre, inradius 1)")
  call obstacle_distance(tri, [1.0_wp, 1.5_wp], d, n)
  call check_close(d, -(12.0_wp - 3.0_wp - 6.0_wp) / 5.0_wp, tol, "triangle inside near hypotenuse")
  call check_vec(n, [0.6_wp, 0.8_wp], "triangle inside normal")
  call obstacle_distance(tri, [5.0_wp, -1.0_wp], d, n)
  call check_close(d, sqrt(2.0_wp), tol, "triangle near vertex (4,0)")
  call check_vec(n, [1.0_wp, -1.0_wp] / sqrt(2.0_wp), "triangle vertex normal")
  call obstacle_distance(tri, [-2.0_wp, 1.0_wp], d, n)
  call check_close(d, 2.0_wp, tol, "triangle left of leg")

  ! ---- normals against central finite differences at random points ----
  call fd_check(disk, "disk")
  call fd_check(caps, "capsule")
  call fd_check(rect, "rectangle")
  call fd_check(tri, "triangle")

  ! ---- segment-to-obstacle distances (line of sight) ----
  call check_close(segment_obstacle_distance(disk, [0.0_wp, 2.0_wp], [3.0_wp, 2.0_wp]), 0.0_wp, tol, &
      "segment through disk")
  call check_close(segment_obstacle_distance(disk, [0.0_wp, 3.0_wp], [3.0_wp, 3.0_wp]), 0.5_wp, tol, &
      "segment passing above disk")
  call check_close(segment_obstacle_distance(caps, [0.0_wp, 1.0_wp], [2.0_wp, 1.0_wp]), 0.75_wp, tol, &
      "segment parallel to capsule")
  call check_close(segment_obstacle_distance(caps, [1.0_wp, -1.0_wp], [1.0_wp, 1.0_wp]), 0.0_wp, tol, &
      "segment crossing capsule")
  call check_close(segment_obstacle_distance(rect, [-1.0_wp, 0.5_wp], [3.0_wp, 0.5_wp]), 0.0_wp, tol, &
      "segment crossing rectangle (endpoints outside)")
  call check_close(segment_obstacle_distance(rect, [1.0_wp, 0.5_wp], [1.2_wp, 0.6_wp]), 0.0_wp, tol, &
      "segment inside rectangle")
  call check_close(segment_obstacle_distance(rect, [3.0_wp, 0.0_wp], [3.0_wp, 2.0_wp]), 1.0_wp, tol, &
      "segment right of rectangle")
  call check_close(segment_obstacle_distance(tri, [2.0_wp, 3.0_wp], [5.0_wp, 0.5_wp]), &
      point_segment_distance([4.0_wp, 0.0_wp], [2.0_wp, 3.0_wp], [5.0_wp, 0.5_wp]), tol, &
      "segment beyond hypotenuse (closest to vertex (4,0))")
  call check_close(segment_segment_distance([0.0_wp, 0.0_wp], [1.0_wp, 0.0_wp], [2.0_wp, 0.0_wp], &
      [3.0_wp, 0.0_wp]), 1.0_wp, tol, "collinear disjoint segments")

  ! ---- bounding boxes ----
  call obstacle_bbox(disk, lo, hi)
  call check_vec(lo, [0.5_wp, 1.5_wp], "disk bbox lo")
  call check_vec(hi, [1.5_wp, 2.5_wp], "disk bbox hi")
  call obstacle_bbox(caps, lo, hi)
  call check_vec(lo, [-0.25_wp, -0.25_wp], "capsule bbox lo")
  call check_vec(hi, [2.25_wp, 0.25_wp], "capsule bbox hi")
  call obstacle_bbox(tri, lo, hi)
  call check_vec(lo, [0.0_wp, 0.0_wp], "triangle bbox lo")
  call check_vec(hi, [4.0_wp, 3.0_wp], "triangle bbox hi")

  call test_summary()

contains

  subroutine check_vec(a, b, name)
    real(wp), intent(in) :: a(2), b(2)
    character(len=*), intent(in) :: name
    call check(maxval(abs(a - b)) <= 1.0e-12_wp, name)
    if (maxval(abs(a - b)) > 1.0e-12_wp) print '(a, 4es14.6)', "   got/expected ", a, b
  end subroutine check_vec

  function ieee_nan() result(x)
    use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
    real(wp) :: x
    x = ieee_value(1.0_wp, ieee_quiet_nan)
  end function ieee_nan

  function star() result(v)
    real(wp) :: v(2, 5)
    integer :: k
    real(wp), parameter :: pi = acos(-1.0_wp)
    do k = 0, 4
      v(:, k + 1) = [cos(pi / 2 + 4 * pi * k / 5), sin(pi / 2 + 4 * pi * k / 5)]
    end do
  end function star

  subroutine expect_error_disk(r, text, name)
    real(wp), intent(in) :: r
    character(len=*), intent(in) :: text, name
    type(obstacle_t) :: o
    type(error_t), allocatable :: err
    call make_disk([0.0_wp, 0.0_wp], r, "column_7", o, err)
    call check_message(err, text, name)
  end subroutine expect_error_disk

  subroutine expect_error_segment(a, b, h, text, name)
    real(wp), intent(in) :: a(2), b(2), h
    character(len=*), intent(in) :: text, name
    type(obstacle_t) :: o
    type(error_t), allocatable :: err
    call make_segment(a, b, h, "column_7", o, err)
    call check_message(err, text, name)
  end subroutine expect_error_segment

  subroutine expect_error_polygon(v, text, name)
    real(wp), intent(in) :: v(:,:)
    character(len=*), intent(in) :: text, name
    type(obstacle_t) :: o
    type(error_t), allocatable :: err
    call make_polygon(v, "column_7", o, err)
    call check_message(err, text, name)
  end subroutine expect_error_polygon

  subroutine check_message(err, text, name)
    type(error_t), allocatable, intent(in) :: err
    character(len=*), intent(in) :: text, name
    call check(allocated(err), name // ": error returned")
    if (.not. allocated(err)) return
    call check(index(err%message, text) > 0, name // ": message mentions '" // text // "'")
    call check(index(err%message, "column_7") > 0, name // ": message names the label")
    if (index(err%message, text) == 0) print '(a)', "   message: " // err%message
  end subroutine check_message

  !> Compare the normal with central differences of the distance at random points away from
  !> the medial axis / kinks (the two nearest distances to pieces of the boundary differ).
  subroutine fd_check(obst, name)
    type(obstacle_t), intent(in) :: obst
    character(len=*), intent(in) :: name
    real(wp), parameter :: h = 1.0e-6_wp
    real(wp) :: lo(2), hi(2), p(2), g(2), dp, dm, d0, n0(2), nn(2), dd, err, errmax
    integer :: k, ntested, m
    call obstacle_bbox(obst, lo, hi)
    lo = lo - 1.0_wp
    hi = hi + 1.0_wp
    errmax = 0.0_wp
    ntested = 0
    call random_seed_fixed()
    do k = 1, 400
      call random_number(p)
      p = lo + p * (hi - lo)
      call obstacle_distance(obst, p, d0, n0)
      ! skip points whose normal changes within a small ball (medial axis, kinks)
      err = 0.0_wp
      do m = 1, 4
        call obstacle_distance(obst, p + 1.0e-3_wp * [cos(m * 1.57_wp), sin(m * 1.57_wp)], dd, nn)
        err = max(err, norm2(nn - n0))
      end do
      if (err > 1.0e-2_wp) cycle
      call obstacle_distance(obst, p + [h, 0.0_wp], dp, nn)
      call obstacle_distance(obst, p - [h, 0.0_wp], dm, nn)
      g(1) = (dp - dm) / (2 * h)
      call obstacle_distance(obst, p + [0.0_wp, h], dp, nn)
      call obstacle_distance(obst, p - [0.0_wp, h], dm, nn)
      g(2) = (dp - dm) / (2 * h)
      errmax = max(errmax, norm2(g - n0))
      ntested = ntested + 1
    end do
    call check(ntested > 200, name // ": enough random points tested (" // trim(itoa(ntested)) // ")")
    call check(errmax < 1.0e-6_wp, name // ": normal = finite-difference gradient")
    if (errmax >= 1.0e-6_wp) print '(a, es12.4)', "   max error ", errmax
  end subroutine fd_check

  subroutine random_seed_fixed()
    integer :: nseed
    integer, allocatable :: seed(:)
    call random_seed(size=nseed)
    allocate(seed(nseed))
    seed = 12345
    call random_seed(put=seed)
  end subroutine random_seed_fixed

  function itoa(i) result(s)
    integer, intent(in) :: i
    character(len=16) :: s
    write(s, '(i0)') i
  end function itoa
end program test_shapes
