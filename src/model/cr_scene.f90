!> The geometry of a scene: a rectangular hall closed by thick walls, an exit opening in
!> the top wall (two barrier walls either side, as in the paper's Fig. 'region'), optionally
!> a second exit opening in the right wall (y_lo2..y_hi2, when &scene l_exit2 > 0), and any
!> number of extra convex obstacles. All distances are exact (see cr_shapes).
!>
!>   y = hall_width + wall_thickness  +-------+         +-------+
!>                                    | wall  |  exit   | wall  |
!>   y = hall_width                   +-------+ x_lo..x_hi +----+
!>                                    |          hall          |
!>   y = 0                            +------------------------+
!>                                    x = 0                    x = hall_length
module cr_scene
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_config, only: scene_cfg_t
  use cr_obstacles, only: obstacles_cfg_t, build_obstacles
  use cr_shapes, only: obstacle_t, make_rectangle, obstacle_bbox
  implicit none
  private
  public :: scene_t

  !> Hall, exit and obstacles. Obstacles 1..n_walls are the hall walls, the rest are the
  !> extra (interior) obstacles of the &obstacles group.
  type :: scene_t
    real(wp) :: length = 0, width = 0, wall = 0, l_exit = 0
    !> x range of the exit opening
    real(wp) :: x_lo = 0, x_hi = 0
    !> width and y range of the second exit opening, in the right wall (l_exit2 = 0: none)
    real(wp) :: l_exit2 = 0, y_lo2 = 0, y_hi2 = 0
    type(obstacle_t), allocatable :: obstacles(:)
    integer :: n_walls = 0
    !> bounding boxes of the obstacles [2, n_obst]
    real(wp), allocatable :: lo(:,:), hi(:,:)
  contains
    procedure :: init
    procedure :: n_obstacles
    procedure :: n_interior
    procedure :: exit_center
    procedure :: y_out
    procedure :: has_exit2
    procedure :: exit2_center
    procedure :: is_out
    procedure :: exit_of
    procedure :: n_exits
    procedure :: exit_width
  end type scene_t

contains

  !> Build the walls from &scene and the extra obstacles from &obstacles (cr_obstacles).
  subroutine init(this, sc, oc, error)
    class(scene_t), intent(inout) :: this
    type(scene_cfg_t), intent(in) :: sc
    type(obstacles_cfg_t), intent(in) :: oc
    type(error_t), allocatable, intent(out) :: error
    type(obstacle_t) :: tmp(6)
    type(obstacle_t), allocatable :: interior(:)
    real(wp) :: L, H, t, xc, yc
    integer :: n, k
    L = sc%hall_length; H = sc%hall_width; t = sc%wall_thickness
    xc = sc%exit_center
    if (xc < 0) xc = L / 2
    this%length = L; this%width = H; this%wall = t; this%l_exit = sc%l_exit
    this%x_lo = xc - sc%l_exit / 2
    this%x_hi = xc + sc%l_exit / 2
    this%l_exit2 = max(sc%l_exit2, 0.0_wp)
    yc = sc%exit2_center
    if (yc < 0) yc = H / 2
    this%y_lo2 = yc - this%l_exit2 / 2
    this%y_hi2 = yc + this%l_exit2 / 2
    n = 0
    call add_rect(-t, -t, 0.0_wp, H + t, "left wall"); if (allocated(error)) return
    if (this%has_exit2()) then
      call add_rect(L, -t, L + t, this%y_lo2, "lower right barrier wall"); if (allocated(error)) return
      call add_rect(L, this%y_hi2, L + t, H + t, "upper right barrier wall"); if (allocated(error)) return
    else
      call add_rect(L, -t, L + t, H + t, "right wall"); if (allocated(error)) return
    end if
    call add_rect(-t, -t, L + t, 0.0_wp, "bottom wall"); if (allocated(error)) return
    if (this%x_lo > 0) then
      call add_rect(0.0_wp, H, this%x_lo, H + t, "left barrier wall"); if (allocated(error)) return
    end if
    if (this%x_hi < L) then
      call add_rect(this%x_hi, H, L, H + t, "right barrier wall"); if (allocated(error)) return
    end if
    this%n_walls = n
    call build_obstacles(oc, interior, error)
    if (allocated(error)) return
    this%obstacles = [tmp(1:n), interior]
    n = size(this%obstacles)
    allocate(this%lo(2, n), this%hi(2, n))
    do k = 1, n
      call obstacle_bbox(this%obstacles(k), this%lo(:, k), this%hi(:, k))
    end do

  contains

    subroutine add_rect(x0, y0, x1, y1, label)
      real(wp), intent(in) :: x0, y0, x1, y1
      character(len=*), intent(in) :: label
      n = n + 1
      call make_rectangle(x0, y0, x1, y1, label, tmp(n), error)
      if (allocated(error)) call prefix_error(error, "scene")
    end subroutine add_rect
  end subroutine init

  pure integer function n_obstacles(this)
    class(scene_t), intent(in) :: this
    n_obstacles = 0
    if (allocated(this%obstacles)) n_obstacles = size(this%obstacles)
  end function n_obstacles

  !> Number of extra obstacles (those that are not hall walls).
  pure integer function n_interior(this)
    class(scene_t), intent(in) :: this
    n_interior = this%n_obstacles() - this%n_walls
  end function n_interior

  !> Centre of the exit opening on the inner face of the top wall.
  pure function exit_center(this) result(c)
    class(scene_t), intent(in) :: this
    real(wp) :: c(2)
    c = [(this%x_lo + this%x_hi) / 2, this%width]
  end function exit_center

  !> An agent of radius r whose centre is above this line has left the hall.
  pure real(wp) function y_out(this, r)
    class(scene_t), intent(in) :: this
    real(wp), intent(in) :: r
    y_out = this%width + this%wall + r
  end function y_out

  !> Whether the scene has a second exit (in the right wall).
  pure logical function has_exit2(this)
    class(scene_t), intent(in) :: this
    has_exit2 = this%l_exit2 > 0
  end function has_exit2

  !> Centre of the second exit opening on the inner face of the right wall.
  pure function exit2_center(this) result(c)
    class(scene_t), intent(in) :: this
    real(wp) :: c(2)
    c = [this%length, (this%y_lo2 + this%y_hi2) / 2]
  end function exit2_center

  !> Number of exits: 1 (top wall), 2 with the second exit in the right wall.
  pure integer function n_exits(this)
    class(scene_t), intent(in) :: this
    n_exits = merge(2, 1, this%has_exit2())
  end function n_exits

  !> Width of exit e (1: top wall, 2: right wall) [m].
  pure real(wp) function exit_width(this, e)
    class(scene_t), intent(in) :: this
    integer, intent(in) :: e
    exit_width = merge(this%l_exit2, this%l_exit, e == 2)
  end function exit_width

  !> The "has left" rule, per exit: the exit an agent of radius r centred at p is beyond
  !> (1: above the top wall's outer face + r; 2, with a second exit: right of the right wall's
  !> outer face + r; 1 when both hold), 0 while it has not left the hall.
  pure integer function exit_of(this, p, r)
    class(scene_t), intent(in) :: this
    !> centre [2]
    real(wp), intent(in) :: p(2)
    real(wp), intent(in) :: r
    exit_of = 0
    if (p(2) > this%y_out(r)) then
      exit_of = 1
    else if (this%has_exit2()) then
      if (p(1) > this%length + this%wall + r) exit_of = 2
    end if
  end function exit_of

  !> Whether an agent of radius r centred at p has left the hall (through any exit: exit_of).
  pure logical function is_out(this, p, r)
    class(scene_t), intent(in) :: this
    !> centre [2]
    real(wp), intent(in) :: p(2)
    real(wp), intent(in) :: r
    is_out = this%exit_of(p, r) > 0
  end function is_out
end module cr_scene
