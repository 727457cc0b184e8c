!> Initial positions of the agents: random placement followed by overlap removal (the
!> paper's procedure, without an O(N^2) rejection loop), or positions read from a file.
!>
!> Overlap removal: repeat  q <- q + delta  with  delta = argmin |delta|^2  subject to
!> D_l(q) + G_l(q) . delta >= 0  for every pair/obstacle contact with gap <= a small cutoff,
!> solved exactly by the active-set projection (h = 1, zero desired velocity). Gaps are
!> convex functions of q, so every linearised row that holds also holds for the true gap;
!> a few iterations remove all overlaps. The agents are confined to the placement region by
!> four thick walls around it (instead of the hall's walls and exit, through which a deep
!> overlap could push an agent out of the hall), together with the interior obstacles.
!> Failure is reported, never ignored: after placement_max_iter projections, or earlier when
!> the largest overlap has not shrunk for STALL_ITER projections (a crowd too dense for its
!> region jams: its linearised problem becomes infeasible and the overlap stops decreasing).
module cr_placement
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_config, only: agents_cfg_t
  use cr_scene, only: scene_t
  use cr_shapes, only: make_rectangle, obstacle_bbox
  use cr_random, only: rng_t
  use cr_h5file, only: h5file_t
  use cr_xy_text, only: read_xy_text
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  use cr_projection, only: projection_solver_t, projection_settings_t, solve_stats_t, &
    make_projection_solver
    use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: place_agents, read_positions_h5, check_feasible

  !> projections without a 1% decrease of the largest overlap before placement gives up
  integer, parameter :: STALL_ITER = 60
  !> iteration cap of one overlap-removal projection (the loop repeats, exactness not needed)
  integer, parameter :: PROJ_MAX_ITER = 5000

contains

  !> Initial positions q [2*n_agents] from &agents (random + overlap removal, or file).
  subroutine place_agents(cfg, scene, q, iterations, error)
    type(agents_cfg_t), intent(in) :: cfg
    type(scene_t), intent(in) :: scene
    real(wp), allocatable, intent(out) :: q(:)
    integer, intent(out) :: iterations
    type(error_t), allocatable, intent(out) :: error
    type(rng_t) :: rng
    real(wp) :: reg(4)
    integer :: i
    iterations = 0
    if (cfg%init == 'file') then
      if (is_hdf5_name(trim(cfg%init_file))) then
        call read_positions_h5(trim(cfg%init_file), cfg%n_agents, q, error)
      else
        call read_xy_text(trim(cfg%init_file), cfg%n_agents, "&agents: init_file", "x y", q, error)
      end if
      if (allocated(error)) return
      call check_feasible(scene, q, cfg%radius, "&agents: init_file '" // trim(cfg%init_file) // "'", error)
      return
    end if
    reg = cfg%region
    if (all(reg == 0)) reg = [0.0_wp, 0.0_wp, scene%length, scene%width]
    allocate(q(2 * cfg%n_agents))
    call rng%seed(cfg%seed)
    do i = 1, cfg%n_agents
      q(2*i-1) = reg(1) + cfg%radius + rng%uniform() * (reg(3) - reg(1) - 2 * cfg%radius)
      q(2*i) = reg(2) + cfg%radius + rng%uniform() * (reg(4) - reg(2) - 2 * cfg%radius)
    end do
    call separate(scene, reg, q, cfg%radius, cfg%placement_max_iter, iterations, error)
  end subroutine place_agents

  !> The interior obstacles of `scene` and four walls around the region reg [4] (xmin, ymin,
  !> xmax, ymax), thicker than the region is wide so that no projection can push a centre
  !> through one.
  subroutine confined_scene(scene, reg, box, error)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: reg(4)
    type(scene_t), intent(out) :: box
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: t
    integer :: n, k
    t = 2 * max(reg(3) - reg(1), reg(4) - reg(2))
    n = scene%n_interior()
    box%length = scene%length; box%width = scene%width; box%wall = t
    box%x_lo = scene%x_lo; box%x_hi = scene%x_hi; box%l_exit = scene%l_exit
    box%n_walls = 4
    allocate(box%obstacles(4 + n), box%lo(2, 4 + n), box%hi(2, 4 + n))
    call make_rectangle(reg(1) - t, reg(2) - t, reg(1), reg(4) + t, "placement region, left", box%obstacles(1), error)
    if (allocated(error)) return
    call make_rectangle(reg(3), reg(2) - t, reg(3) + t, reg(4) + t, "placement region, right", box%obstacles(2), error)
    if (allocated(error)) return
    call make_rectangle(reg(1), reg(2) - t, reg(3), reg(2), "placement region, bottom", box%obstacles(3), error)
    if (allocated(error)) return
    call make_rectangle(reg(1), reg(4), reg(3), reg(4) + t, "placement region, top", box%obstacles(4), error)
    if (allocated(error)) return
    do k = 1, n
      box%obstacles(4 + k) = scene%obstacles(scene%n_walls + k)
    end do
    do k = 1, 4 + n
      call obstacle_bbox(box%obstacles(k), box%lo(:, k), box%hi(:, k))
    end do
  end subroutine confined_scene

  !> Overlap removal by repeated projections inside the region reg [4] (see module doc).
  subroutine separate(scene, reg, q, radius, max_iter, iterations, error)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: reg(4)
    real(wp), intent(inout) :: q(:)
    real(wp), intent(in) :: radius
    integer, intent(in) :: max_iter
    integer, intent(out) :: iterations
    type(error_t), allocatable, intent(out) :: error
    type(scene_t) :: box
    type(contact_set_t) :: cs
    type(cell_list_t) :: cells
    type(projection_settings_t) :: settings
    class(projection_solver_t), allocatable :: solver
    type(solve_stats_t) :: stats
    real(wp), allocatable :: v(:), delta(:), lambda(:)
    real(wp) :: margin, worst, best
    integer :: na, it, since_best
    character(len=:), allocatable :: why
    na = size(q) / 2
    call confined_scene(scene, reg, box, error)
    if (allocated(error)) return
    ! an iterative sparse solver: any N; exactness is not needed since the loop checks the
    ! true gaps and repeats
    settings%name = 'apgd'
    settings%tol = 1.0e-9_wp
    settings%max_iter = PROJ_MAX_ITER
    call make_projection_solver(settings, solver, error)
    if (allocated(error)) return
    call cs%init(na, 1.0_wp, 8 * na)
    allocate(v(2 * na), delta(2 * na))
    v = 0.0_wp
    margin = 1.0e-9_wp * radius
    worst = 0.0_wp
    best = -huge(1.0_wp)
    since_best = 0
    iterations = 0
    do it = 1, max_iter
      call build_contacts(box, q, radius, 0.05_wp * radius, cells, cs)
      worst = 0.0_wp
      if (cs%n > 0) worst = minval(cs%gap(1:cs%n))
      if (worst >= 0.0_wp) exit
      ! stall: the largest overlap has not shrunk by 1% for STALL_ITER projections
      if (worst > best + 0.01_wp * abs(best)) then
        best = worst; since_best = 0
      else
        since_best = since_best + 1
        if (since_best >= STALL_ITER) exit
      end if
      iterations = it
      cs%gap(1:cs%n) = cs%gap(1:cs%n) - margin
      if (allocated(lambda)) deallocate(lambda)
      allocate(lambda(cs%n))
      lambda = 0.0_wp
      call solver%solve(cs, v, delta, lambda, stats, error)
      if (allocated(error)) return
      q = q + delta
    end do
    if (worst < 0.0_wp) then
      if (since_best >= STALL_ITER) then
        why = "no progress in the last " // str(STALL_ITER) // " projections"
      else
        why = "placement_max_iter = " // str(max_iter)
      end if
      call set_error(error, "&agents: cannot make the initial configuration feasible: " // str(na) // &
        " agents of radius " // str(radius) // " cover " // &
        str(na * acos(-1.0_wp) * radius**2 / ((reg(3) - reg(1)) * (reg(4) - reg(2))), 'f0.3') // &
        " of the region and still overlap by " // str(-worst) // " after " // str(iterations) // &
        " projection iterations (" // why // "); use fewer agents or a larger region", EXIT_BAD_INPUT)
    end if
  end subroutine separate

  logical function is_hdf5_name(path)
    character(len=*), intent(in) :: path
    integer :: n
    n = len(path)
    is_hdf5_name = .false.
    if (n > 3) is_hdf5_name = path(n-2:n) == '.h5'
    if (n > 5) is_hdf5_name = is_hdf5_name .or. path(n-4:n) == '.hdf5'
  end function is_hdf5_name

  !> Read q [2n] from an HDF5 file: dataset 'positions' [2n] (x1, y1, x2, ...) or, in a
  !> crowdrom full-order output, 'agents/initial_positions'.
  subroutine read_positions_h5(path, n, q, error)
    character(len=*), intent(in) :: path
    integer, intent(in) :: n
    real(wp), allocatable, intent(out) :: q(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: name
    call h5%open(path, error)
    if (allocated(error)) then
      error%message = "&agents: init_file: " // error%message; error%code = EXIT_BAD_INPUT; return
    end if
    if (h5%exists("positions")) then
      name = "positions"
    else if (h5%exists("agents/initial_positions")) then
      name = "agents/initial_positions"
    else
      call set_error(error, "&agents: init_file: '" // path // &
        "' has neither a dataset 'positions' nor 'agents/initial_positions'", EXIT_BAD_INPUT)
      call h5%close(e2); return
    end if
    call h5%read(name, q, error)
    call h5%close(e2)
    if (allocated(error)) then
      error%message = "&agents: init_file: " // error%message; error%code = EXIT_BAD_INPUT; return
    end if
    if (size(q) /= 2 * n) then
      call set_error(error, "&agents: init_file: '" // path // "' dataset '" // name // "' has " // &
        str(size(q)) // " values, expected 2 * n_agents = " // str(2 * n), EXIT_BAD_INPUT); return
    end if
    if (any(q /= q) .or. any(abs(q) > huge(1.0_wp) / 4)) &
      call set_error(error, "&agents: init_file: '" // path // "' has a non-finite value", EXIT_BAD_INPUT)
  end subroutine read_positions_h5

  !> Error if an agent starts outside the building (beside or below the hall, not in the
  !> hall, the doorway or the open space beyond the top wall), two agents coincide or
  !> overlap, or an agent overlaps an obstacle, at q.
  subroutine check_feasible(scene, q, radius, where, error)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:)
    real(wp), intent(in) :: radius
    character(len=*), intent(in) :: where
    type(error_t), allocatable, intent(out) :: error
    type(contact_set_t) :: cs
    type(cell_list_t) :: cells
    integer :: l
    real(wp) :: tol
    tol = 1.0e-9_wp * radius
    call cs%init(size(q) / 2, 1.0_wp)
    call build_contacts(scene, q, radius, 0.0_wp, cells, cs)
    do l = 1, cs%n
      if (cs%ib(l) > 0) then
        if (cs%gap(l) <= -2 * radius + tol) then
          call set_error(error, where // ": agents " // str(cs%ia(l)) // " and " // str(cs%ib(l)) // &
            " are at the same position", EXIT_BAD_INPUT); return
        else if (cs%gap(l) < -tol) then
          call set_error(error, where // ": agents " // str(cs%ia(l)) // " and " // str(cs%ib(l)) // &
            " overlap by " // str(-cs%gap(l)), EXIT_BAD_INPUT); return
        end if
      else if (cs%gap(l) < -tol) then
        call set_error(error, where // ": agent " // str(cs%ia(l)) // " starts inside obstacle '" // &
          scene%obstacles(cs%ob(l))%label // "' (gap " // str(cs%gap(l)) // ")", EXIT_BAD_INPUT); return
      end if
    end do
    do l = 1, size(q) / 2
      if (q(2*l) < scene%width + scene%wall .and. &
          (q(2*l-1) < 0.0_wp .or. q(2*l-1) > scene%length .or. q(2*l) < 0.0_wp)) then
        call set_error(error, where // ": agent " // str(l) // " at (" // str(q(2*l-1)) // ", " // &
          str(q(2*l)) // ") starts outside the hall [0, " // str(scene%length) // "] x [0, " // &
          str(scene%width) // "] (agents start in the hall, the doorway or beyond the top wall)", EXIT_BAD_INPUT)
        return
      end if
    end do
  end subroutine check_feasible
end module cr_placement
