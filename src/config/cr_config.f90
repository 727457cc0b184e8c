!> The configuration of a crowdrom run: one derived type per namelist group, gathered in
!> config_t, read from a namelist file (rank 0 reads, every rank parses the same text).
!>
!> Units: lengths in metres, times in seconds, speeds in metres per second.
!> Validation of ranges and consistency lives in cr_config_check (one place).
module cr_config
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_env, only: env_t
  use cr_strings, only: str
  use cr_namelist_text, only: namelist_text_t, nml_status, echo_real, echo_reals, echo_logical
  ! &obstacles (its variables, read, echo, checks, construction) is owned by cr_obstacles
  use cr_obstacles, only: obstacles_cfg_t, read_obstacles, obstacles_echo, MAX_OBST, MAX_POLY_V
  use cr_solver_settings, only: projection_settings_t
  use cr_paths, only: io_paths_t
  implicit none
  private
  public :: config_t, scene_cfg_t, obstacles_cfg_t, agents_cfg_t, desired_cfg_t, time_cfg_t, &
    contacts_cfg_t, output_cfg_t, read_config, parse_config, config_echo, MAX_OBST, MAX_POLY_V, MAX_PATH, &
    FOM_GROUPS, nml_status, model_inputs, check_fom_paths

  integer, parameter :: MAX_PATH = 512

  !> Every namelist group a crowdrom program reads (one file may hold the groups of every stage;
  !> any other group is refused): the full model (read here), &study (crowd_snapshots,
  !> cr_study_config), the groups of crowd_offline (cr_offline_config) and of crowd_rom
  !> (cr_rom_config).
  character(len=16), parameter :: FOM_GROUPS(*) = [character(len=16) :: 'scene', 'obstacles', &
    'agents', 'desired', 'time', 'solver', 'contacts', 'output', 'study', &
    'offline', 'pod', 'cone', 'pga', 'infsup', 'pairs', 'hyper', &
    'rom', 'sweep', 'reduced', 'fom_timing', 'predict']

  !> &scene: rectangular hall [0, hall_length] x [0, hall_width] closed by walls of thickness
  !> wall_thickness; the top wall has an opening of width l_exit centred at exit_center, and
  !> the right wall a second opening of width l_exit2 centred at y = exit2_center if l_exit2 > 0.
  type :: scene_cfg_t
    real(wp) :: hall_length = 1.3_wp
    real(wp) :: hall_width = 1.0_wp
    real(wp) :: l_exit = 0.3_wp
    !> x of the exit centre; negative means centred (hall_length / 2)
    real(wp) :: exit_center = -1.0_wp
    !> width of the second exit, in the right wall; 0 means none
    real(wp) :: l_exit2 = 0.0_wp
    !> y of the second exit's centre; negative means centred (hall_width / 2)
    real(wp) :: exit2_center = -1.0_wp
    real(wp) :: wall_thickness = 0.1_wp
  end type scene_cfg_t

  !> &agents: count, radius, speed and initial placement.
  type :: agents_cfg_t
    integer :: n_agents = 20
    real(wp) :: radius = 0.05_wp
    !> desired speed c of every agent (overridden per agent by speed_file)
    real(wp) :: speed = 1.0_wp
    character(len=MAX_PATH) :: speed_file = ''
    !> 'random' (placement + overlap removal) or 'file' (plain text "x y" lines, or HDF5)
    character(len=16) :: init = 'random'
    character(len=MAX_PATH) :: init_file = ''
    !> placement region xmin, ymin, xmax, ymax; all zero means the whole hall
    real(wp) :: region(4) = 0.0_wp
    integer :: seed = 1
    integer :: placement_max_iter = 1000
    !> social distance d_s [m]: each agent carries an exclusion ring of width d_s / 2, so two
    !> agents stop at gap d_s and an agent stops at d_s / 2 from a wall or pillar (0: the
    !> paper's model, contact at gap 0)
    real(wp) :: social_distance = 0.0_wp
  end type agents_cfg_t

  !> &desired: the spontaneous velocity.
  type :: desired_cfg_t
    !> 'geodesic' (towards the exit) or 'file' (prescribed per-agent vectors)
    character(len=16) :: mode = 'geodesic'
    character(len=MAX_PATH) :: file = ''
    !> 'auto' (straight lines without interior obstacles, else 'exact' where it applies, else
    !> 'grid'), 'analytic' (straight lines), 'grid' (fast-sweeping field), 'exact' (tangent graph)
    character(len=16) :: field = 'auto'
    !> grid spacing of the distance field; 0 means radius / 4
    real(wp) :: grid_dx = 0.0_wp
    !> desired speed: 'constant' (each agent's speed, the paper's model) or 'weidmann' (each
    !> agent's speed times Weidmann's fundamental diagram of its local density, cr_density_speed)
    character(len=16) :: speed_model = 'constant'
    !> width sigma [m] of the Gaussian kernel of the local density (cut at 3 sigma)
    real(wp) :: density_sigma = 0.7_wp
    !> look-ahead beta in [0, 1]: a neighbour counts with weight (1 + beta cos theta), theta its
    !> angle from the agent's desired direction (0: isotropic)
    real(wp) :: density_anisotropy = 0.0_wp
    !> the diagram v(rho) = v0 (1 - exp(-fd_gamma (1/rho - 1/fd_rho_max))): gamma [1/m2] and
    !> the jam density [1/m2] (Weidmann 1993: 1.913 and 5.4)
    real(wp) :: fd_gamma = 1.913_wp
    real(wp) :: fd_rho_max = 5.4_wp
  end type desired_cfg_t

  !> &time: step and horizon.
  type :: time_cfg_t
    real(wp) :: dt = 0.05_wp
    integer :: n_steps = 40
    !> run until every agent has left (capped by max_steps) instead of n_steps
    logical :: until_empty = .false.
    integer :: max_steps = 100000
  end type time_cfg_t

  !> &contacts: candidate contact selection.
  type :: contacts_cfg_t
    !> candidate rows: agent pairs with gap <= m_a + m_b, agent-obstacle pairs with gap <= 2 m_a,
    !> where m_i = cutoff_factor * h * (a bound of agent i's speed in the step: max|v| on the first
    !> step, then min(max|v|, |u_i| + 0.5 |v_i|)); an a-posteriori check adds any row the solution
    !> could violate, so any value >= 1 is safe (larger: fewer re-solves, more rows)
    real(wp) :: cutoff_factor = 1.5_wp
  end type contacts_cfg_t

  !> &output: files and verbosity.
  type :: output_cfg_t
    character(len=MAX_PATH) :: file = 'fom.h5'
    integer :: every = 1
    logical :: store_multipliers = .true.
    character(len=16) :: log_level = 'info'
    !> trajectories in the Pedestrian Dynamics Data Archive HDF5 layout (PedPy reads it in one
    !> call); empty: none
    character(len=MAX_PATH) :: pdda_file = ''
  end type output_cfg_t

  !> Everything a run needs, read from one namelist file.
  type :: config_t
    character(len=:), allocatable :: source
    character(len=:), allocatable :: text
    type(scene_cfg_t) :: scene
    type(obstacles_cfg_t) :: obstacles
    type(agents_cfg_t) :: agents
    type(desired_cfg_t) :: desired
    type(time_cfg_t) :: time
    type(projection_settings_t) :: solver
    type(contacts_cfg_t) :: contacts
    type(output_cfg_t) :: output
  end type config_t

contains

  !> Read every group of the full-order model from `path` into `cfg` (defaults for absent
  !> optional groups). Errors name the file, the group and (from the runtime) the variable.
  !> A program passes the groups it cannot run without (`needed`, e.g. scene and agents):
  !> a file without them (empty, binary, another program's input) is refused, never run
  !> with the defaults.
  subroutine read_config(path, env, cfg, error, nml, program, needed)
    character(len=*), intent(in) :: path
    type(env_t), intent(in) :: env
    type(config_t), intent(out) :: cfg
    type(error_t), allocatable, intent(out) :: error
    !> the loaded text, for programs that read further groups
    type(namelist_text_t), intent(out), optional :: nml
    !> name of the calling program (for the message about missing groups)
    character(len=*), intent(in), optional :: program
    !> groups that must be present
    character(len=*), intent(in), optional :: needed(:)
    type(namelist_text_t) :: t
    call t%load(path, env, error)
    if (allocated(error)) return
    if (present(needed)) then
      if (present(program)) then
        call t%require_groups(program, needed, FOM_GROUPS, error)
      else
        call t%require_groups("this program", needed, FOM_GROUPS, error)
      end if
      if (allocated(error)) return
    end if
    call parse_config(t, cfg, error)
    if (allocated(error)) return
    if (present(nml)) nml = t
  end subroutine read_config

  !> Add the files the model reads (positions, speeds, desired velocities) to `paths`.
  subroutine model_inputs(cfg, paths)
    type(config_t), intent(in) :: cfg
    type(io_paths_t), intent(inout) :: paths
    if (cfg%agents%init == 'file') call paths%input("&agents init_file", cfg%agents%init_file)
    call paths%input("&agents speed_file", cfg%agents%speed_file)
    if (cfg%desired%mode == 'file') call paths%input("&desired file", cfg%desired%file)
  end subroutine model_inputs

  !> crowd_fom's outputs (&output file, the --summary file) checked against its inputs and
  !> each other, before any work (see cr_paths).
  subroutine check_fom_paths(input, summary, cfg, error)
    character(len=*), intent(in) :: input, summary
    type(config_t), intent(in) :: cfg
    type(error_t), allocatable, intent(out) :: error
    type(io_paths_t) :: paths
    call paths%input("file", input)
    call model_inputs(cfg, paths)
    call paths%output("&output file", cfg%output%file)
    if (len_trim(cfg%output%pdda_file) > 0) call paths%output("&output pdda_file", cfg%output%pdda_file)
    call paths%output("--summary", summary)
    call paths%check(input, error)
  end subroutine check_fom_paths

  !> Parse the groups of the full-order model from loaded namelist text `t` (a file, or the
  !> effective configuration stored in an output file).
  subroutine parse_config(t, cfg, error)
    type(namelist_text_t), intent(in) :: t
    type(config_t), intent(out) :: cfg
    type(error_t), allocatable, intent(out) :: error
    call t%check_groups(FOM_GROUPS, error)
    if (allocated(error)) return
    cfg%source = t%path
    cfg%text = t%text
    call read_scene(t, cfg%scene, error); if (allocated(error)) return
    call read_obstacles(t, cfg%obstacles, error); if (allocated(error)) return
    call read_agents(t, cfg%agents, error); if (allocated(error)) return
    call read_desired(t, cfg%desired, error); if (allocated(error)) return
    call read_time(t, cfg%time, error); if (allocated(error)) return
    call read_solver(t, cfg%solver, error); if (allocated(error)) return
    call read_contacts(t, cfg%contacts, error); if (allocated(error)) return
    call read_output(t, cfg%output, error); if (allocated(error)) return
  end subroutine parse_config

  subroutine read_scene(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(scene_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: hall_length, hall_width, l_exit, exit_center, wall_thickness, l_exit2, exit2_center
    namelist /scene/ hall_length, hall_width, l_exit, exit_center, wall_thickness, l_exit2, exit2_center
    integer :: ios
    character(len=512) :: msg
    hall_length = c%hall_length; hall_width = c%hall_width; l_exit = c%l_exit
    exit_center = c%exit_center; wall_thickness = c%wall_thickness
    l_exit2 = c%l_exit2; exit2_center = c%exit2_center
    msg = ''
    read(t%lines, nml=scene, iostat=ios, iomsg=msg)
    call nml_status(t, 'scene', ios, msg, error); if (allocated(error)) return
    c%hall_length = hall_length; c%hall_width = hall_width; c%l_exit = l_exit
    c%exit_center = exit_center; c%wall_thickness = wall_thickness
    c%l_exit2 = l_exit2; c%exit2_center = exit2_center
  end subroutine read_scene

  subroutine read_agents(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(agents_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    integer :: n_agents, seed, placement_max_iter
    real(wp) :: radius, speed, region(4), social_distance
    character(len=MAX_PATH) :: speed_file, init_file
    character(len=16) :: init
    namelist /agents/ n_agents, radius, speed, speed_file, init, init_file, region, seed, &
      placement_max_iter, social_distance
    integer :: ios
    character(len=512) :: msg
    n_agents = c%n_agents; radius = c%radius; speed = c%speed; speed_file = c%speed_file
    init = c%init; init_file = c%init_file; region = c%region; seed = c%seed
    placement_max_iter = c%placement_max_iter; social_distance = c%social_distance
    msg = ''
    read(t%lines, nml=agents, iostat=ios, iomsg=msg)
    call nml_status(t, 'agents', ios, msg, error); if (allocated(error)) return
    c%n_agents = n_agents; c%radius = radius; c%speed = speed; c%speed_file = speed_file
    c%init = init; c%init_file = init_file; c%region = region; c%seed = seed
    c%placement_max_iter = placement_max_iter; c%social_distance = social_distance
  end subroutine read_agents

  subroutine read_desired(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(desired_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    character(len=16) :: mode, field, speed_model
    character(len=MAX_PATH) :: file
    real(wp) :: grid_dx, density_sigma, fd_gamma, fd_rho_max, density_anisotropy
    namelist /desired/ mode, file, field, grid_dx, speed_model, density_sigma, fd_gamma, fd_rho_max, &
      density_anisotropy
    integer :: ios
    character(len=512) :: msg
    mode = c%mode; file = c%file; field = c%field; grid_dx = c%grid_dx
    speed_model = c%speed_model; density_sigma = c%density_sigma; fd_gamma = c%fd_gamma
    fd_rho_max = c%fd_rho_max; density_anisotropy = c%density_anisotropy
    msg = ''
    read(t%lines, nml=desired, iostat=ios, iomsg=msg)
    call nml_status(t, 'desired', ios, msg, error); if (allocated(error)) return
    c%mode = mode; c%file = file; c%field = field; c%grid_dx = grid_dx
    c%speed_model = speed_model; c%density_sigma = density_sigma; c%fd_gamma = fd_gamma
    c%fd_rho_max = fd_rho_max; c%density_anisotropy = density_anisotropy
  end subroutine read_desired

  subroutine read_time(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(time_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: dt
    integer :: n_steps, max_steps
    logical :: until_empty
    namelist /time/ dt, n_steps, until_empty, max_steps
    integer :: ios
    character(len=512) :: msg
    dt = c%dt; n_steps = c%n_steps; until_empty = c%until_empty; max_steps = c%max_steps
    msg = ''
    read(t%lines, nml=time, iostat=ios, iomsg=msg)
    call nml_status(t, 'time', ios, msg, error); if (allocated(error)) return
    c%dt = dt; c%n_steps = n_steps; c%until_empty = until_empty; c%max_steps = max_steps
  end subroutine read_time

  subroutine read_solver(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(projection_settings_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    character(len=32) :: name
    real(wp) :: tol, uzawa_rho_factor, uzawa_eps
    integer :: max_iter, uzawa_max_iter, dense_rows, refresh_every
    logical :: warm_start
    namelist /solver/ name, tol, max_iter, uzawa_rho_factor, uzawa_eps, uzawa_max_iter, warm_start, &
      dense_rows, refresh_every
    integer :: ios
    character(len=512) :: msg
    name = c%name; tol = c%tol; max_iter = c%max_iter; uzawa_rho_factor = c%uzawa_rho_factor
    uzawa_eps = c%uzawa_eps; uzawa_max_iter = c%uzawa_max_iter; warm_start = c%warm_start
    dense_rows = c%dense_rows; refresh_every = c%refresh_every
    msg = ''
    read(t%lines, nml=solver, iostat=ios, iomsg=msg)
    call nml_status(t, 'solver', ios, msg, error); if (allocated(error)) return
    c%name = name; c%tol = tol; c%max_iter = max_iter; c%uzawa_rho_factor = uzawa_rho_factor
    c%uzawa_eps = uzawa_eps; c%uzawa_max_iter = uzawa_max_iter; c%warm_start = warm_start
    c%dense_rows = dense_rows; c%refresh_every = refresh_every
  end subroutine read_solver

  subroutine read_contacts(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(contacts_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: cutoff_factor
    namelist /contacts/ cutoff_factor
    integer :: ios
    character(len=512) :: msg
    cutoff_factor = c%cutoff_factor
    msg = ''
    read(t%lines, nml=contacts, iostat=ios, iomsg=msg)
    call nml_status(t, 'contacts', ios, msg, error); if (allocated(error)) return
    c%cutoff_factor = cutoff_factor
  end subroutine read_contacts

  subroutine read_output(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(output_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    character(len=MAX_PATH) :: file
    integer :: every
    logical :: store_multipliers
    character(len=16) :: log_level
    character(len=MAX_PATH) :: pdda_file
    namelist /output/ file, every, store_multipliers, log_level, pdda_file
    integer :: ios
    character(len=512) :: msg
    file = c%file; every = c%every; store_multipliers = c%store_multipliers
    log_level = c%log_level; pdda_file = c%pdda_file
    msg = ''
    read(t%lines, nml=output, iostat=ios, iomsg=msg)
    call nml_status(t, 'output', ios, msg, error); if (allocated(error)) return
    c%file = file; c%every = every; c%store_multipliers = store_multipliers
    c%log_level = log_level; c%pdda_file = pdda_file
  end subroutine read_output

  !> The effective configuration as a namelist file that crowdrom can read back.
  function config_echo(cfg) result(s)
    type(config_t), intent(in) :: cfg
    character(len=:), allocatable :: s
    s = "! effective configuration (source: " // cfg%source // ")" // new_line('a')
    associate (c => cfg%scene)
      s = s // "&scene hall_length = " // echo_real(c%hall_length) // ", hall_width = " // echo_real(c%hall_width) // &
        ", l_exit = " // echo_real(c%l_exit) // ", exit_center = " // echo_real(c%exit_center) // &
        ", wall_thickness = " // echo_real(c%wall_thickness)
      ! the second exit only when there is one (one-exit configurations keep their text and hash)
      if (c%l_exit2 /= 0) s = s // ", l_exit2 = " // echo_real(c%l_exit2) // ", exit2_center = " // echo_real(c%exit2_center)
      s = s // " /" // new_line('a')
    end associate
    s = s // obstacles_echo(cfg%obstacles)
    associate (a => cfg%agents)
      s = s // "&agents n_agents = " // str(a%n_agents) // ", radius = " // echo_real(a%radius) // ", speed = " // &
        echo_real(a%speed) // ", speed_file = '" // trim(a%speed_file) // "', init = '" // trim(a%init) // &
        "', init_file = '" // trim(a%init_file) // "', region = " // echo_reals(a%region) // ", seed = " // &
        str(a%seed) // ", placement_max_iter = " // str(a%placement_max_iter)
      ! the social distance only when set (the paper's configurations keep their text and hash)
      if (a%social_distance /= 0) s = s // ", social_distance = " // echo_real(a%social_distance)
      s = s // " /" // new_line('a')
    end associate
    associate (d => cfg%desired)
      s = s // "&desired mode = '" // trim(d%mode) // "', file = '" // trim(d%file) // "', field = '" // &
        trim(d%field) // "', grid_dx = " // echo_real(d%grid_dx)
      ! the speed model only when not the paper's (its configurations keep their text and hash)
      if (d%speed_model /= 'constant') s = s // ", speed_model = '" // trim(d%speed_model) // &
        "', density_sigma = " // echo_real(d%density_sigma) // ", fd_gamma = " // echo_real(d%fd_gamma) // &
        ", fd_rho_max = " // echo_real(d%fd_rho_max) // ", density_anisotropy = " // &
        echo_real(d%density_anisotropy)
      s = s // " /" // new_line('a')
    end associate
    associate (t => cfg%time)
      s = s // "&time dt = " // echo_real(t%dt) // ", n_steps = " // str(t%n_steps) // ", until_empty = " // &
        echo_logical(t%until_empty) // ", max_steps = " // str(t%max_steps) // " /" // new_line('a')
    end associate
    associate (v => cfg%solver)
      s = s // "&solver name = '" // trim(v%name) // "', tol = " // echo_real(v%tol) // ", max_iter = " // &
        str(v%max_iter) // ", uzawa_rho_factor = " // echo_real(v%uzawa_rho_factor) // ", uzawa_eps = " // &
        echo_real(v%uzawa_eps) // ", uzawa_max_iter = " // str(v%uzawa_max_iter) // ", warm_start = " // &
        echo_logical(v%warm_start) // ", dense_rows = " // str(v%dense_rows) // &
        ", refresh_every = " // str(v%refresh_every) // " /" // new_line('a')
    end associate
    s = s // "&contacts cutoff_factor = " // echo_real(cfg%contacts%cutoff_factor) // " /" // new_line('a')
    associate (o => cfg%output)
      s = s // "&output file = '" // trim(o%file) // "', every = " // str(o%every) // ", store_multipliers = " // &
        echo_logical(o%store_multipliers) // ", log_level = '" // trim(o%log_level) // "'"
      if (len_trim(o%pdda_file) > 0) s = s // ", pdda_file = '" // trim(o%pdda_file) // "'"
      s = s // " /" // new_line('a')
    end associate

  end function config_echo
end module cr_config
