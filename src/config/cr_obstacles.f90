!> The &obstacles group: the extra convex obstacles of a scene (disks, thick segments, convex
!> polygons). One module owns everything a shape needs beyond its geometry (cr_shapes): its
!> namelist variables and their defaults, the read, the echo, the checks of magnitudes and
!> ranges, and the construction of its obstacle_t. A new shape is added here (one block per
!> procedure, in the order of the shapes) and in cr_shapes.
!>
!> The full model's configuration (cr_config) holds an obstacles_cfg_t, its check
!> (cr_config_check) calls check_obstacles_sane and check_obstacles, and the scene
!> (cr_scene) calls build_obstacles.
module cr_obstacles
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, problems_t
  use cr_strings, only: str
  use cr_namelist_text, only: namelist_text_t, nml_status, echo_real, echo_reals
  use cr_sane, only: need_sane, MAX_LENGTH, MIN_LENGTH
  use cr_shapes, only: obstacle_t, make_disk, make_segment, make_polygon
  implicit none
  private
  public :: obstacles_cfg_t, read_obstacles, obstacles_echo, check_obstacles_sane, check_obstacles, &
    build_obstacles, MAX_OBST, MAX_POLY_V

  !> at most this many obstacles of each shape; at most this many vertices per polygon
  integer, parameter :: MAX_OBST = 64, MAX_POLY_V = 16

  !> &obstacles: extra convex obstacles (disks, thick segments, convex polygons).
  type :: obstacles_cfg_t
    integer :: n_disks = 0
    real(wp) :: disk_x(MAX_OBST) = 0.0_wp, disk_y(MAX_OBST) = 0.0_wp, disk_r(MAX_OBST) = 0.0_wp
    integer :: n_segments = 0
    real(wp) :: seg_x1(MAX_OBST) = 0.0_wp, seg_y1(MAX_OBST) = 0.0_wp
    real(wp) :: seg_x2(MAX_OBST) = 0.0_wp, seg_y2(MAX_OBST) = 0.0_wp
    real(wp) :: seg_half_thickness(MAX_OBST) = 0.0_wp
    integer :: n_polygons = 0
    integer :: poly_nv(MAX_OBST) = 0
    !> polygon vertices: poly_x(k, p) is the x of vertex k of polygon p
    real(wp) :: poly_x(MAX_POLY_V, MAX_OBST) = 0.0_wp, poly_y(MAX_POLY_V, MAX_OBST) = 0.0_wp
  contains
    !> number of obstacles of every shape
    procedure :: count => count_obstacles
  end type obstacles_cfg_t

contains

  !> Read &obstacles from `t` (absent group: `c` unchanged).
  subroutine read_obstacles(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(obstacles_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    integer :: n_disks, n_segments, n_polygons, poly_nv(MAX_OBST)
    real(wp) :: disk_x(MAX_OBST), disk_y(MAX_OBST), disk_r(MAX_OBST)
    real(wp) :: seg_x1(MAX_OBST), seg_y1(MAX_OBST), seg_x2(MAX_OBST), seg_y2(MAX_OBST)
    real(wp) :: seg_half_thickness(MAX_OBST)
    real(wp) :: poly_x(MAX_POLY_V, MAX_OBST), poly_y(MAX_POLY_V, MAX_OBST)
    namelist /obstacles/ n_disks, disk_x, disk_y, disk_r, n_segments, seg_x1, seg_y1, seg_x2, &
      seg_y2, seg_half_thickness, n_polygons, poly_nv, poly_x, poly_y
    integer :: ios
    character(len=512) :: msg
    n_disks = c%n_disks; disk_x = c%disk_x; disk_y = c%disk_y; disk_r = c%disk_r
    n_segments = c%n_segments; seg_x1 = c%seg_x1; seg_y1 = c%seg_y1; seg_x2 = c%seg_x2
    seg_y2 = c%seg_y2; seg_half_thickness = c%seg_half_thickness
    n_polygons = c%n_polygons; poly_nv = c%poly_nv; poly_x = c%poly_x; poly_y = c%poly_y
    msg = ''
    read(t%lines, nml=obstacles, iostat=ios, iomsg=msg)
    call nml_status(t, 'obstacles', ios, msg, error); if (allocated(error)) return
    c%n_disks = n_disks; c%disk_x = disk_x; c%disk_y = disk_y; c%disk_r = disk_r
    c%n_segments = n_segments; c%seg_x1 = seg_x1; c%seg_y1 = seg_y1; c%seg_x2 = seg_x2
    c%seg_y2 = seg_y2; c%seg_half_thickness = seg_half_thickness
    c%n_polygons = n_polygons; c%poly_nv = poly_nv; c%poly_x = poly_x; c%poly_y = poly_y
  end subroutine read_obstacles

  !> The group as namelist text that reads back exactly (part of the effective configuration).
  function obstacles_echo(o) result(s)
    type(obstacles_cfg_t), intent(in) :: o
    character(len=:), allocatable :: s
    integer :: k
    s = "&obstacles n_disks = " // str(o%n_disks) // ", n_segments = " // str(o%n_segments) // &
      ", n_polygons = " // str(o%n_polygons)
    do k = 1, o%n_disks
      s = s // new_line('a') // "  disk_x(" // str(k) // ") = " // echo_real(o%disk_x(k)) // ", disk_y(" // &
        str(k) // ") = " // echo_real(o%disk_y(k)) // ", disk_r(" // str(k) // ") = " // &
        echo_real(o%disk_r(k))
    end do
    do k = 1, o%n_segments
      s = s // new_line('a') // "  seg_x1(" // str(k) // ") = " // echo_real(o%seg_x1(k)) // ", seg_y1(" // &
        str(k) // ") = " // echo_real(o%seg_y1(k)) // ", seg_x2(" // str(k) // ") = " // &
        echo_real(o%seg_x2(k)) // ", seg_y2(" // str(k) // ") = " // echo_real(o%seg_y2(k)) // &
        ", seg_half_thickness(" // str(k) // ") = " // echo_real(o%seg_half_thickness(k))
    end do
    do k = 1, o%n_polygons
      s = s // new_line('a') // "  poly_nv(" // str(k) // ") = " // str(o%poly_nv(k)) // ", poly_x(:," // &
        str(k) // ") = " // echo_reals(o%poly_x(1:o%poly_nv(k), k)) // ", poly_y(:," // str(k) // &
        ") = " // echo_reals(o%poly_y(1:o%poly_nv(k), k))
    end do
    s = s // " /" // new_line('a')
  end function obstacles_echo

  !> Magnitudes: every coordinate finite and within MAX_LENGTH, sizes not below MIN_LENGTH.
  subroutine check_obstacles_sane(o, probs)
    type(obstacles_cfg_t), intent(in) :: o
    type(problems_t), intent(inout) :: probs
    integer :: k
    do k = 1, min(max(o%n_disks, 0), MAX_OBST)
      call need_sane(probs, o%disk_x(k), "&obstacles: disk_x(" // str(k) // ")", MAX_LENGTH)
      call need_sane(probs, o%disk_y(k), "&obstacles: disk_y(" // str(k) // ")", MAX_LENGTH)
      call need_sane(probs, o%disk_r(k), "&obstacles: disk_r(" // str(k) // ")", MAX_LENGTH, MIN_LENGTH)
    end do
    do k = 1, min(max(o%n_segments, 0), MAX_OBST)
      call need_sane(probs, o%seg_x1(k), "&obstacles: seg_x1(" // str(k) // ")", MAX_LENGTH)
      call need_sane(probs, o%seg_y1(k), "&obstacles: seg_y1(" // str(k) // ")", MAX_LENGTH)
      call need_sane(probs, o%seg_x2(k), "&obstacles: seg_x2(" // str(k) // ")", MAX_LENGTH)
      call need_sane(probs, o%seg_y2(k), "&obstacles: seg_y2(" // str(k) // ")", MAX_LENGTH)
      call need_sane(probs, o%seg_half_thickness(k), "&obstacles: seg_half_thickness(" // str(k) // ")", &
        MAX_LENGTH, MIN_LENGTH)
    end do
    do k = 1, min(max(o%n_polygons, 0), MAX_OBST)
      if (.not. (all(ieee_is_finite(o%poly_x(:, k))) .and. all(ieee_is_finite(o%poly_y(:, k))))) then
        call probs%need(.false., "&obstacles: poly_x/poly_y of polygon " // str(k) // " must be finite")
      else
        call probs%need(all(abs(o%poly_x(:, k)) <= MAX_LENGTH) .and. all(abs(o%poly_y(:, k)) <= MAX_LENGTH), &
          "&obstacles: vertices of polygon " // str(k) // " must lie within " // str(MAX_LENGTH) // " m")
      end if
    end do
  end subroutine check_obstacles_sane

  !> Ranges and consistency: counts, positive sizes, distinct endpoints, vertex counts.
  !> (Convexity and orientation are checked when the obstacles are built.)
  subroutine check_obstacles(o, probs)
    type(obstacles_cfg_t), intent(in) :: o
    type(problems_t), intent(inout) :: probs
    integer :: k
    call probs%need(o%n_disks >= 0 .and. o%n_disks <= MAX_OBST, "&obstacles: n_disks must be in 0.." // str(MAX_OBST))
    call probs%need(o%n_segments >= 0 .and. o%n_segments <= MAX_OBST, "&obstacles: n_segments must be in 0.." // &
      str(MAX_OBST))
    call probs%need(o%n_polygons >= 0 .and. o%n_polygons <= MAX_OBST, "&obstacles: n_polygons must be in 0.." // &
      str(MAX_OBST))
    do k = 1, min(max(o%n_disks, 0), MAX_OBST)
      call probs%need(o%disk_r(k) > 0, "&obstacles: disk_r(" // str(k) // ") must be > 0 (got " // &
        str(o%disk_r(k)) // ")")
    end do
    do k = 1, min(max(o%n_segments, 0), MAX_OBST)
      call probs%need(o%seg_half_thickness(k) >= 0, "&obstacles: seg_half_thickness(" // str(k) // ") must be >= 0")
      call probs%need(o%seg_x1(k) /= o%seg_x2(k) .or. o%seg_y1(k) /= o%seg_y2(k), &
        "&obstacles: segment " // str(k) // " has equal endpoints (seg_x1/seg_y1 = seg_x2/seg_y2)")
    end do
    do k = 1, min(max(o%n_polygons, 0), MAX_OBST)
      call probs%need(o%poly_nv(k) >= 3 .and. o%poly_nv(k) <= MAX_POLY_V, "&obstacles: poly_nv(" // str(k) // &
        ") must be in 3.." // str(MAX_POLY_V) // " (got " // str(o%poly_nv(k)) // ")")
    end do
  end subroutine check_obstacles

  !> The obstacles of the group, in the order disks, segments, polygons [o%count()]; the
  !> error names the obstacle ("&obstacles polygon 2: ...").
  subroutine build_obstacles(o, obst, error)
    type(obstacles_cfg_t), intent(in) :: o
    type(obstacle_t), allocatable, intent(out) :: obst(:)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: verts(:,:)
    integer :: n, k
    allocate(obst(max(o%count(), 0)))
    n = 0
    do k = 1, o%n_disks
      n = n + 1
      call make_disk([o%disk_x(k), o%disk_y(k)], o%disk_r(k), "&obstacles disk " // str(k), obst(n), error)
      if (allocated(error)) return
    end do
    do k = 1, o%n_segments
      n = n + 1
      call make_segment([o%seg_x1(k), o%seg_y1(k)], [o%seg_x2(k), o%seg_y2(k)], &
        o%seg_half_thickness(k), "&obstacles segment " // str(k), obst(n), error)
      if (allocated(error)) return
    end do
    do k = 1, o%n_polygons
      n = n + 1
      allocate(verts(2, o%poly_nv(k)))
      verts(1, :) = o%poly_x(1:o%poly_nv(k), k)
      verts(2, :) = o%poly_y(1:o%poly_nv(k), k)
      call make_polygon(verts, "&obstacles polygon " // str(k), obst(n), error)
      deallocate(verts)
      if (allocated(error)) return
    end do
  end subroutine build_obstacles

  !> Number of obstacles of every shape (the counts as given; checked by check_obstacles).
  pure integer function count_obstacles(this) result(n)
    class(obstacles_cfg_t), intent(in) :: this
    n = this%n_disks + this%n_segments + this%n_polygons
  end function count_obstacles
end module cr_obstacles
