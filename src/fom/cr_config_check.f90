!> Validation of the full model's configuration (src/fom: it asks the solver factory and the model
!> about names and shapes): every range and consistency rule in one place.
!> All problems are collected and reported together in one error.
module cr_config_check
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, problems_t
  use cr_strings, only: str
  use cr_config, only: config_t
  use cr_obstacles, only: check_obstacles_sane, check_obstacles
  use cr_projection, only: projection_solver_t, make_projection_solver
  ! the sane magnitudes and their check (cr_sane) are also offered here to the other readers
  use cr_sane, only: need_sane, MAX_LENGTH, MIN_LENGTH, MAX_SPEED
  implicit none
  private
  public :: check_config, PACKING_LIMIT, MAX_STEPS

  !> the largest number of time steps (records of every step are kept in memory)
  integer, parameter :: MAX_STEPS = 10000000
  !> the largest distance-field grid (cells) and hall size in agent radii (cell lists)
  real(wp), parameter :: MAX_GRID_CELLS = 2.0e8_wp, MAX_RADII = 1.0e6_wp

  !> densest packing of equal disks in the plane (hexagonal), pi / sqrt(12)
  real(wp), parameter :: PACKING_LIMIT = 0.9068996821171089_wp

contains

  !> Check `cfg`; on failure `error` lists every problem ("&group: variable ...; ...").
  subroutine check_config(cfg, error)
    type(config_t), intent(in) :: cfg
    type(error_t), allocatable, intent(out) :: error
    type(problems_t) :: probs
    integer :: k
    real(wp) :: reg(4), area, frac
    class(projection_solver_t), allocatable :: solver
    type(error_t), allocatable :: e2
    associate (s => cfg%scene, o => cfg%obstacles, a => cfg%agents, d => cfg%desired, &
               t => cfg%time, v => cfg%solver, c => cfg%contacts, out => cfg%output)
      ! magnitudes first: every real finite and sane (Inf, NaN or 1e308 would overflow in the
      ! consistency checks below and later in the run); with such values the rest is skipped
      call need_sane(probs, s%hall_length, "&scene: hall_length", MAX_LENGTH, MIN_LENGTH)
      call need_sane(probs, s%hall_width, "&scene: hall_width", MAX_LENGTH, MIN_LENGTH)
      call need_sane(probs, s%l_exit, "&scene: l_exit", MAX_LENGTH, MIN_LENGTH)
      call need_sane(probs, s%exit_center, "&scene: exit_center", MAX_LENGTH)
      call need_sane(probs, s%l_exit2, "&scene: l_exit2", MAX_LENGTH)
      call need_sane(probs, s%exit2_center, "&scene: exit2_center", MAX_LENGTH)
      call need_sane(probs, s%wall_thickness, "&scene: wall_thickness", MAX_LENGTH, MIN_LENGTH)
      call check_obstacles_sane(o, probs)
      call need_sane(probs, a%radius, "&agents: radius", MAX_LENGTH, MIN_LENGTH)
      call need_sane(probs, a%speed, "&agents: speed", MAX_SPEED)
      do k = 1, 4
        call need_sane(probs, a%region(k), "&agents: region(" // str(k) // ")", MAX_LENGTH)
      end do
      call need_sane(probs, d%grid_dx, "&desired: grid_dx", MAX_LENGTH, MIN_LENGTH)
      call need_sane(probs, t%dt, "&time: dt", MAX_LENGTH, 1.0e-9_wp)
      call probs%need(t%n_steps <= MAX_STEPS, "&time: n_steps = " // str(t%n_steps) // " exceeds " // &
        str(MAX_STEPS) // " steps")
      call probs%need(t%max_steps <= MAX_STEPS, "&time: max_steps = " // str(t%max_steps) // " exceeds " // &
        str(MAX_STEPS) // " steps")
      call need_sane(probs, v%tol, "&solver: tol", 1.0_wp)
      call need_sane(probs, v%uzawa_rho_factor, "&solver: uzawa_rho_factor", 1.0e12_wp)
      call need_sane(probs, v%uzawa_eps, "&solver: uzawa_eps", 1.0_wp)
      call need_sane(probs, c%cutoff_factor, "&contacts: cutoff_factor", 1.0e6_wp)
      if (probs%n > 0) then
        call probs%to_error(cfg%source, error); return
      end if
      ! sizes derived from ratios of lengths (cell lists, distance-field grid)
      if (ieee_is_finite(a%radius) .and. a%radius >= MIN_LENGTH .and. ieee_is_finite(s%hall_length) .and. &
          ieee_is_finite(s%hall_width)) then
        call probs%need(max(s%hall_length, s%hall_width) / a%radius <= MAX_RADII, "&agents: radius = " // &
          str(a%radius) // " is below 1e-6 of the hall size (" // str(max(s%hall_length, s%hall_width)) // ")")
        if (d%field == 'grid' .or. (d%field == 'auto' .and. o%count() > 0)) then
          frac = d%grid_dx
          if (frac == 0) frac = a%radius / 4
          if (ieee_is_finite(frac) .and. frac > 0) then
            area = (s%hall_length + 2 * s%wall_thickness) / frac * ((s%hall_width + 2 * s%wall_thickness) / frac)
            call probs%need(area <= MAX_GRID_CELLS, "&desired: the distance field grid (spacing " // str(frac) // &
              ") would have " // str(area) // " cells (at most " // str(MAX_GRID_CELLS) // "): raise grid_dx")
          end if
        end if
      end if
      ! &scene
      call probs%need(s%hall_length > 0, "&scene: hall_length must be > 0 (got " // str(s%hall_length) // ")")
      call probs%need(s%hall_width > 0, "&scene: hall_width must be > 0 (got " // str(s%hall_width) // ")")
      call probs%need(s%wall_thickness > 0, "&scene: wall_thickness must be > 0 (got " // str(s%wall_thickness) // ")")
      call probs%need(s%l_exit > 0, "&scene: l_exit must be > 0 (got " // str(s%l_exit) // ")")
      call probs%need(s%l_exit <= s%hall_length, "&scene: l_exit = " // str(s%l_exit) // &
        " is wider than the wall (hall_length = " // str(s%hall_length) // ")")
      if (s%exit_center >= 0 .and. s%l_exit <= s%hall_length) then
        call probs%need(s%exit_center - s%l_exit / 2 >= 0 .and. s%exit_center + s%l_exit / 2 <= s%hall_length, &
          "&scene: exit_center = " // str(s%exit_center) // " puts the opening outside the wall")
      end if
      call probs%need(s%l_exit2 >= 0, "&scene: l_exit2 must be >= 0 (0: no second exit; got " // str(s%l_exit2) // ")")
      call probs%need(s%l_exit2 <= s%hall_width, "&scene: l_exit2 = " // str(s%l_exit2) // &
        " is wider than the right wall (hall_width = " // str(s%hall_width) // ")")
      if (s%l_exit2 > 0 .and. s%exit2_center >= 0 .and. s%l_exit2 <= s%hall_width) then
        call probs%need(s%exit2_center - s%l_exit2 / 2 >= 0 .and. s%exit2_center + s%l_exit2 / 2 <= s%hall_width, &
          "&scene: exit2_center = " // str(s%exit2_center) // " puts the second opening outside the right wall")
      end if
      call check_obstacles(o, probs)
      ! &agents
      call probs%need(a%n_agents >= 1, "&agents: n_agents must be >= 1 (got " // str(a%n_agents) // ")")
      call probs%need(a%radius > 0, "&agents: radius must be > 0 (got " // str(a%radius) // ")")
      call probs%need(a%speed >= 0, "&agents: speed must be >= 0 (got " // str(a%speed) // ")")
      call probs%need(a%init == 'random' .or. a%init == 'file', "&agents: init must be 'random' or 'file' (got '" // &
        trim(a%init) // "')")
      if (a%init == 'file') call probs%need(len_trim(a%init_file) > 0, "&agents: init = 'file' needs init_file")
      call probs%need(a%placement_max_iter >= 1, "&agents: placement_max_iter must be >= 1")
      reg = a%region
      if (all(reg == 0)) reg = [0.0_wp, 0.0_wp, s%hall_length, s%hall_width]
      if (a%init == 'random') then
        call probs%need(reg(3) > reg(1) .and. reg(4) > reg(2), "&agents: region must have xmin < xmax and ymin < ymax")
        call probs%need(reg(1) >= 0 .and. reg(2) >= 0 .and. reg(3) <= s%hall_length .and. reg(4) <= s%hall_width, &
          "&agents: region must lie inside the hall [0, hall_length] x [0, hall_width]")
        area = max(reg(3) - reg(1), 0.0_wp) * max(reg(4) - reg(2), 0.0_wp)
        if (a%radius > 0 .and. area > 0 .and. a%n_agents > 0) then
          call probs%need(reg(3) - reg(1) >= 2 * a%radius .and. reg(4) - reg(2) >= 2 * a%radius, &
            "&agents: region is narrower than an agent (2 * radius)")
          frac = a%n_agents * acos(-1.0_wp) * a%radius**2 / area
          call probs%need(frac <= PACKING_LIMIT, "&agents: n_agents = " // str(a%n_agents) // " disks of radius " // &
            str(a%radius) // " cover " // str(frac, 'f0.3') // " of the region: more agents than fit (limit " // &
            str(PACKING_LIMIT, 'f0.4') // ")")
        end if
      end if
      ! &desired
      call probs%need(d%mode == 'geodesic' .or. d%mode == 'file', "&desired: mode must be 'geodesic' or 'file' (got '" // &
        trim(d%mode) // "')")
      if (d%mode == 'file') call probs%need(len_trim(d%file) > 0, "&desired: mode = 'file' needs file")
      call probs%need(d%field == 'auto' .or. d%field == 'analytic' .or. d%field == 'grid' .or. d%field == 'exact', &
        "&desired: field must be 'auto', 'analytic', 'grid' or 'exact' (got '" // trim(d%field) // "')")
      call probs%need(d%grid_dx >= 0, "&desired: grid_dx must be >= 0 (0 = radius / 4)")
      if (a%radius > 0) call probs%need(d%grid_dx < a%radius / 2, "&desired: grid_dx must be < radius / 2")
      ! &time
      call probs%need(t%dt > 0, "&time: dt must be > 0 (got " // str(t%dt) // ")")
      call probs%need(t%n_steps >= 1 .or. t%until_empty, "&time: n_steps must be >= 1 (got " // str(t%n_steps) // ")")
      call probs%need(t%max_steps >= 1, "&time: max_steps must be >= 1")
      ! &solver
      call make_projection_solver(v, solver, e2)
      if (allocated(e2)) call probs%need(.false., "&solver: " // e2%message)
      call probs%need(v%tol > 0, "&solver: tol must be > 0 (got " // str(v%tol) // ")")
      call probs%need(v%max_iter >= 1, "&solver: max_iter must be >= 1")
      call probs%need(v%uzawa_rho_factor > 0, "&solver: uzawa_rho_factor must be > 0")
      call probs%need(v%uzawa_eps > 0, "&solver: uzawa_eps must be > 0")
      call probs%need(v%uzawa_max_iter >= 1, "&solver: uzawa_max_iter must be >= 1")
      call probs%need(v%dense_rows >= 0, "&solver: dense_rows must be >= 0 (got " // str(v%dense_rows) // ")")
      call probs%need(v%refresh_every >= 1, "&solver: refresh_every must be >= 1 (got " // &
        str(v%refresh_every) // ")")
      ! &contacts
      call probs%need(c%cutoff_factor >= 1, "&contacts: cutoff_factor must be >= 1 (got " // str(c%cutoff_factor) // ")")
      ! &output
      call probs%need(len_trim(out%file) > 0, "&output: file must not be empty")
      call probs%need(out%every >= 1, "&output: every must be >= 1")
      call probs%need(any(out%log_level == [character(len=16) :: 'error', 'warn', 'info', 'debug']), &
        "&output: log_level must be 'error', 'warn', 'info' or 'debug'")
    end associate
    call check_behaviour(cfg, probs)
    if (allocated(cfg%source)) then
      call probs%to_error(cfg%source, error)
    else      ! a configuration built in code, not read from a file
      call probs%to_error("configuration", error)
    end if

  end subroutine check_config

  !> The behaviour options: social distance (&agents) and the density-dependent desired speed
  !> (&desired speed_model, its kernel and its fundamental diagram).
  subroutine check_behaviour(cfg, probs)
    type(config_t), intent(in) :: cfg
    type(problems_t), intent(inout) :: probs
    real(wp) :: ds, need
    associate (s => cfg%scene, a => cfg%agents, d => cfg%desired)
      ds = a%social_distance
      call need_sane(probs, ds, "&agents: social_distance", MAX_LENGTH)
      call probs%need(.not. (ds < 0), "&agents: social_distance must be >= 0 (got " // str(ds) // ")")
      if (ds > 0 .and. ieee_is_finite(ds)) then
        need = 2 * a%radius + ds
        call probs%need(need < s%l_exit, "&agents: social_distance = " // str(ds) // " leaves no passage through " // &
          "the exit (2 radius + social_distance = " // str(need) // " >= &scene l_exit = " // str(s%l_exit) // ")")
        if (s%l_exit2 > 0) call probs%need(need < s%l_exit2, "&agents: social_distance = " // str(ds) // &
          " leaves no passage through the second exit (2 radius + social_distance = " // str(need) // &
          " >= &scene l_exit2 = " // str(s%l_exit2) // ")")
      end if
      call probs%need(d%speed_model == 'constant' .or. d%speed_model == 'weidmann', &
        "&desired: speed_model must be 'constant' or 'weidmann' (got '" // trim(d%speed_model) // "')")
      if (d%speed_model /= 'weidmann') return
      call need_sane(probs, d%density_sigma, "&desired: density_sigma", MAX_LENGTH, MIN_LENGTH)
      call need_sane(probs, d%fd_gamma, "&desired: fd_gamma", 1.0e6_wp)
      call need_sane(probs, d%fd_rho_max, "&desired: fd_rho_max", 1.0e6_wp)
      call probs%need(d%density_sigma > 0, "&desired: density_sigma must be > 0 (got " // str(d%density_sigma) // ")")
      call probs%need(d%fd_gamma > 0, "&desired: fd_gamma must be > 0 (got " // str(d%fd_gamma) // ")")
      call probs%need(d%fd_rho_max > 0, "&desired: fd_rho_max must be > 0 (got " // str(d%fd_rho_max) // ")")
      call need_sane(probs, d%density_anisotropy, "&desired: density_anisotropy", 1.0_wp)
      call probs%need(d%density_anisotropy >= 0 .and. d%density_anisotropy <= 1, &
        "&desired: density_anisotropy must be in [0, 1] (got " // str(d%density_anisotropy) // ")")
      call probs%need(d%mode == 'geodesic', "&desired: speed_model = 'weidmann' needs mode = 'geodesic' " // &
        "(prescribed vectors have no speed to scale)")
      if (len_trim(a%speed_file) == 0) call probs%need(a%speed > 0, "&agents: speed = " // str(a%speed) // &
        " is the free speed of &desired speed_model = 'weidmann' and must be > 0")
    end associate
  end subroutine check_behaviour

end module cr_config_check
