!> The desired (spontaneous) velocity of every agent: speed c_i times the direction of
!> steepest descent of the geodesic distance to the exit, or prescribed vectors from a file.
!>
!> Aiming rule: agents aim at the exit opening narrowed by the agent radius on each side,
!> [x_lo + r, x_hi - r] on the inner face y = hall_width (aiming at the full opening lets an
!> agent slide under a door corner and stop there for good). Inside the doorway agents walk
!> straight out (+y); past the wall they keep walking away from the exit centre.
!> With a second exit in the right wall (&scene l_exit2 > 0) every model takes the nearer of
!> the two openings (exact: the smaller of two geodesic distances; grid: one field seeded at
!> both openings; analytic: the nearer narrowed opening), and the same rules hold at the
!> right wall (+x in its doorway, away from its centre beyond it).
!>
!> Inside the hall the direction comes from one of three models (&desired field):
!> - 'analytic': straight to the closest point of the narrowed opening (no obstacle model);
!> - 'exact': the geodesic distance of the agent centres (every obstacle and wall inflated by r)
!>   computed exactly at the agents' positions by a tangent graph built once per scene and
!>   radius (cr_geodesic); it is the limit h -> 0 of the grid field;
!> - 'grid': a fast-sweeping distance field built once per scene (nodes closer than
!>   r - 1.5 dx to an obstacle are blocked, so the field is that of the agent centres).
!> 'auto' keeps 'analytic' when the scene has no interior obstacle, otherwise takes 'exact'
!> when it applies (see exact_applies) and 'grid' when it does not.
module cr_desired
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_config, only: desired_cfg_t
  use cr_scene, only: scene_t
  use cr_shapes, only: obstacle_t, make_segment, segment_obstacle_distance, OBST_DISK, OBST_SEGMENT
  use cr_distance_field, only: distance_field_t
  use cr_geodesic, only: geodesic_t, GEODESIC_MAX_CIRCLES
  use cr_xy_text, only: read_xy_text
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: desired_t, exact_applies

  !> Desired-velocity model of one scene.
  type :: desired_t
    logical :: from_file = .false.
    logical :: use_field = .false.
    type(distance_field_t) :: field
    !> exact geodesic (tangent graph) in use
    logical :: use_exact = .false.
    type(geodesic_t) :: exact
    !> prescribed vectors (file mode) [2*n_agents]
    real(wp), allocatable :: fixed(:)
    real(wp) :: r = 0, y_door = 0, y_top = 0, t_lo = 0, t_hi = 0, x_lo = 0, x_hi = 0
    real(wp) :: centre(2) = 0
    !> second exit (right wall): present, its exact geodesic, x of the wall's inner and outer
    !> faces, narrowed target s_lo..s_hi (y) and centre
    logical :: has2 = .false.
    type(geodesic_t) :: exact2
    real(wp) :: x_door = 0, x_right = 0, s_lo = 0, s_hi = 0
    real(wp) :: centre2(2) = 0
  contains
    procedure :: init
    procedure :: direction
    procedure :: evaluate
    procedure :: evaluate_at
    procedure :: model_name
  end type desired_t

contains

  !> Set up for `scene` and agents of radius r; reads the vector file in file mode.
  subroutine init(this, cfg, scene, radius, n_agents, error)
    class(desired_t), intent(inout) :: this
    type(desired_cfg_t), intent(in) :: cfg
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius
    integer, intent(in) :: n_agents
    type(error_t), allocatable, intent(out) :: error
    type(obstacle_t) :: target(2)
    real(wp) :: dx
    character(len=:), allocatable :: why
    this%use_field = .false.
    this%use_exact = .false.
    this%r = radius
    this%y_door = scene%width
    this%y_top = scene%width + scene%wall
    this%x_lo = scene%x_lo; this%x_hi = scene%x_hi
    this%t_lo = scene%x_lo + radius; this%t_hi = scene%x_hi - radius
    if (this%t_lo > this%t_hi) then   ! exit narrower than a diameter: aim at its centre
      this%t_lo = (scene%x_lo + scene%x_hi) / 2; this%t_hi = this%t_lo
    end if
    this%centre = scene%exit_center()
    this%has2 = scene%has_exit2()
    this%x_door = scene%length; this%x_right = scene%length + scene%wall
    this%s_lo = scene%y_lo2 + radius; this%s_hi = scene%y_hi2 - radius
    if (this%s_lo > this%s_hi) then
      this%s_lo = (scene%y_lo2 + scene%y_hi2) / 2; this%s_hi = this%s_lo
    end if
    this%centre2 = scene%exit2_center()
    this%from_file = cfg%mode == 'file'
    if (this%from_file) then
      call read_xy_text(trim(cfg%file), n_agents, "&desired: file", "vx vy", this%fixed, error)
      return
    end if
    select case (trim(cfg%field))
    case ('grid')
      this%use_field = .true.
    case ('analytic')
      this%use_field = .false.
    case ('exact')
      if (.not. exact_applies(scene, radius, why)) then
        call set_error(error, "&desired: field = 'exact' does not apply to this scene: " // why, EXIT_BAD_INPUT)
        return
      end if
      this%use_exact = .true.
    case default
      if (scene%n_interior() > 0) then
        this%use_exact = exact_applies(scene, radius, why)
        this%use_field = .not. this%use_exact
      end if
    end select
    if (this%use_exact) then
      call this%exact%init([0.0_wp, 0.0_wp], [scene%length, scene%width], scene%obstacles, radius, &
        [this%t_lo, scene%width], [this%t_hi, scene%width], error)
      if (allocated(error)) call prefix_error(error, "desired velocity: exact geodesic")
      if (allocated(error) .or. .not. this%has2) return
      call this%exact2%init([0.0_wp, 0.0_wp], [scene%length, scene%width], scene%obstacles, radius, &
        [scene%length, this%s_lo], [scene%length, this%s_hi], error)
      if (allocated(error)) call prefix_error(error, "desired velocity: exact geodesic to the second exit")
      return
    end if
    if (.not. this%use_field) return
    dx = cfg%grid_dx
    if (dx <= 0) dx = radius / 4
    call make_segment([scene%x_lo, scene%width], [scene%x_hi, scene%width], 0.0_wp, "exit", target(1), error)
    if (allocated(error)) return
    if (this%has2) then
      call make_segment([scene%length, scene%y_lo2], [scene%length, scene%y_hi2], 0.0_wp, "second exit", &
        target(2), error)
      if (allocated(error)) return
    end if
    call this%field%init([0.0_wp, 0.0_wp], [scene%length, scene%width], dx, scene%obstacles, &
      radius - 1.5_wp * dx, target(1:merge(2, 1, this%has2)), error)
    if (allocated(error)) call prefix_error(error, "desired velocity: distance field")
  end subroutine init

  !> Unit desired direction at position p (geodesic mode).
  subroutine direction(this, p, dir)
    class(desired_t), intent(in) :: this
    real(wp), intent(in) :: p(2)
    real(wp), intent(out) :: dir(2)
    real(wp) :: t(2), t2(2), n, dn, dn2, dir2(2)
    logical :: ok, ok2
    if (p(2) >= this%y_top) then
      ! past the wall: walk away from the exit centre
      dir = p - this%centre
    else if (this%has2 .and. p(1) >= this%x_right) then
      ! past the right wall (second exit): walk away from its centre
      dir = p - this%centre2
    else if (p(2) >= this%y_door - this%r .and. p(1) >= this%t_lo .and. p(1) <= this%t_hi) then
      dir = [0.0_wp, 1.0_wp]
    else if (this%has2 .and. p(1) >= this%x_door - this%r .and. p(2) >= this%s_lo .and. p(2) <= this%s_hi) then
      dir = [1.0_wp, 0.0_wp]
    else
      if (this%use_exact .and. p(2) < this%y_door .and. p(1) < this%x_door) then
        call this%exact%query(p, dn, dir, ok)
        if (this%has2) then
          ! the nearer exit by geodesic distance
          call this%exact2%query(p, dn2, dir2, ok2)
          if (ok2 .and. (.not. ok .or. dn2 < dn)) then
            dir = dir2; ok = .true.
          end if
        end if
        if (ok) return
      end if
      if (this%use_field .and. p(2) < this%y_door - this%r .and. p(1) < this%x_door - this%r) then
        call this%field%direction(p, dir, ok)
        if (ok) return
      end if
      t = [min(max(p(1), this%t_lo), this%t_hi), this%y_door]
      dir = t - p
      if (this%has2) then
        ! straight to the nearer (narrowed) opening
        t2 = [this%x_door, min(max(p(2), this%s_lo), this%s_hi)]
        if (norm2(t2 - p) < norm2(dir)) dir = t2 - p
      end if
    end if
    n = norm2(dir)
    if (n > 0) then
      dir = dir / n
    else
      dir = [0.0_wp, 1.0_wp]
    end if
  end subroutine direction

  !> v = desired velocities at positions q [2*n_agents] for speeds c [n_agents].
  subroutine evaluate(this, q, speeds, v)
    class(desired_t), intent(in) :: this
    real(wp), intent(in) :: q(:), speeds(:)
    real(wp), intent(out) :: v(:)
    integer :: i
    real(wp) :: d(2)
    if (this%from_file) then
      v = this%fixed
      return
    end if
    do i = 1, size(speeds)
      call this%direction(q(2*i-1:2*i), d)
      v(2*i-1:2*i) = speeds(i) * d
    end do
  end subroutine evaluate

  !> v(:, k) = desired velocity of agent idx(k) only, at positions q [2*n_agents] with speeds
  !> [n_agents]: v [2, size(idx)]. For hyper-reduced models that need a few agents; every
  !> model (exact, grid, analytic, file) is evaluated pointwise, so the cost is O(size(idx)).
  subroutine evaluate_at(this, q, speeds, idx, v)
    class(desired_t), intent(in) :: this
    real(wp), intent(in) :: q(:), speeds(:)
    integer, intent(in) :: idx(:)
    real(wp), intent(out) :: v(:,:)
    integer :: k, i
    real(wp) :: d(2)
    do k = 1, size(idx)
      i = idx(k)
      if (this%from_file) then
        v(:, k) = this%fixed(2*i-1:2*i)
      else
        call this%direction(q(2*i-1:2*i), d)
        v(:, k) = speeds(i) * d
      end if
    end do
  end subroutine evaluate_at

  !> Name of the model in use: 'file', 'exact', 'grid' or 'analytic'.
  function model_name(this) result(name)
    class(desired_t), intent(in) :: this
    character(len=:), allocatable :: name
    if (this%from_file) then
      name = 'file'
    else if (this%use_exact) then
      name = 'exact'
    else if (this%use_field) then
      name = 'grid'
    else
      name = 'analytic'
    end if
  end function model_name

  !> .true. if the exact geodesic applies to `scene` and agents of radius r; otherwise `why`
  !> says why not: the opening is narrower than a diameter (no narrowed target), there are
  !> more than GEODESIC_MAX_CIRCLES obstacle vertices and disks, or an interior obstacle
  !> inflated by r meets the narrowed opening (its reachable part would not be a segment).
  function exact_applies(scene, r, why) result(ok)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: r
    character(len=:), allocatable, intent(out) :: why
    logical :: ok
    integer :: k, nc
    real(wp) :: a(2), b(2)
    ok = .false.
    why = ''
    if (scene%x_hi - scene%x_lo <= 2 * r) then
      why = "the exit (width " // str(scene%x_hi - scene%x_lo) // ") is not wider than an agent (diameter " &
        // str(2 * r) // ")"
      return
    end if
    nc = 0
    do k = 1, scene%n_obstacles()
      select case (scene%obstacles(k)%kind)
      case (OBST_DISK); nc = nc + 1
      case (OBST_SEGMENT); nc = nc + 2
      case default; nc = nc + size(scene%obstacles(k)%vertices, 2)
      end select
    end do
    if (nc > GEODESIC_MAX_CIRCLES) then
      why = str(nc) // " obstacle vertices and disks exceed the limit of " // str(GEODESIC_MAX_CIRCLES)
      return
    end if
    if (scene%has_exit2() .and. scene%y_hi2 - scene%y_lo2 <= 2 * r) then
      why = "the second exit (width " // str(scene%y_hi2 - scene%y_lo2) // ") is not wider than an agent (diameter " &
        // str(2 * r) // ")"
      return
    end if
    a = [scene%x_lo + r, scene%width]
    b = [scene%x_hi - r, scene%width]
    do k = scene%n_walls + 1, scene%n_obstacles()
      if (segment_obstacle_distance(scene%obstacles(k), a, b) < r) then
        why = "obstacle '" // scene%obstacles(k)%label // "' comes closer than the agent radius to the exit opening"
        return
      end if
      if (scene%has_exit2()) then
        if (segment_obstacle_distance(scene%obstacles(k), [scene%length, scene%y_lo2 + r], &
            [scene%length, scene%y_hi2 - r]) < r) then
          why = "obstacle '" // scene%obstacles(k)%label // "' comes closer than the agent radius to the second exit"
          return
        end if
      end if
    end do
    ok = .true.
  end function exact_applies
end module cr_desired
