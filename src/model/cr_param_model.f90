!> The one mapping from a parameter vector mu to the model of a sample: the scene (l_exit, and
!> l_exit2 the width of the second exit in the right wall), the
!> per-agent desired speeds (speed, speeds) and the desired velocity field built on that scene.
!> Used by the sampling (crowd_snapshots), the offline stage (one scene per training sample)
!> and the online stage (scene, speeds and desired velocity per sample); the snapshot database
!> stores each sample's mapped scene, so the Python side never re-implements the geometry.
!>
!> mu has n_expanded components: one per parameter, except 'speeds' which contributes n_agents
!> (speed_1..speed_N) and 'speed_spread' which contributes two (speed_spread, speed_seed). The
!> component names ("l_exit,speed_1,...") are stored in the files and `init_from_components`
!> rebuilds the same mapping from them.
!>
!> A heterogeneous population: 'speed_mean' m and 'speed_spread' s (always together) give agent
!> i the desired speed c_i = m + s (2 u_i - 1), the u_i uniform in (0, 1) drawn in agent order
!> from the generator cr_random seeded with the sample's 'speed_seed' component (an integer in
!> 0..SPEED_SEED_MAX that the sampling draws and the files store): c_i uniform on (m - s, m + s),
!> mean m, standard deviation s / sqrt(3), independent between agents, and the same speeds from
!> the same (m, s, seed) in every program and on every rank.
module cr_param_model
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_config, only: config_t
  use cr_scene, only: scene_t
  use cr_desired, only: desired_t
  use cr_random, only: rng_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: param_model_t, KNOWN_PARAMS, KNOWN_PARAMS_TEXT, SPEED_SEED_MAX, draw_speeds

  !> parameter names a study may vary
  character(len=12), parameter :: KNOWN_PARAMS(6) = [character(len=12) :: 'l_exit', 'speed', 'speeds', &
    'l_exit2', 'speed_mean', 'speed_spread']
  character(len=*), parameter :: KNOWN_PARAMS_TEXT = "l_exit, speed, speeds, l_exit2, speed_mean, speed_spread"
  !> the largest per-sample seed of the speed draw (a component within the sane magnitudes)
  integer, parameter :: SPEED_SEED_MAX = 999999
  !> the generator stream of the per-agent speed draw
  integer, parameter :: SPEED_STREAM = 7

  !> The parameters of a study, expanded to components.
  type :: param_model_t
    integer :: n_params = 0, n_expanded = 0, n_agents = 0
    !> study parameter names [n_params]
    character(len=16), allocatable :: names(:)
    !> first component and number of components of each parameter [n_params]
    integer, allocatable :: first(:), width(:)
  contains
    procedure :: init_model
    procedure :: init_from_components
    procedure :: component_names
    procedure :: apply
    procedure :: scene_of
    procedure :: sample_model
  end type param_model_t

contains

  !> Expand the parameter names (each one of KNOWN_PARAMS) for a scene of n_agents agents.
  subroutine init_model(this, names, n_agents)
    class(param_model_t), intent(inout) :: this
    character(len=*), intent(in) :: names(:)
    integer, intent(in) :: n_agents
    integer :: k, m
    this%n_params = size(names)
    this%n_agents = n_agents
    if (allocated(this%names)) deallocate(this%names, this%first, this%width)
    allocate(this%names(size(names)), this%first(size(names)), this%width(size(names)))
    m = 0
    do k = 1, size(names)
      this%names(k) = names(k)
      this%first(k) = m + 1
      this%width(k) = 1
      if (names(k) == 'speeds') this%width(k) = n_agents
      if (names(k) == 'speed_spread') this%width(k) = 2
      m = m + this%width(k)
    end do
    this%n_expanded = m
  end subroutine init_model

  !> The mapping of stored component names ("l_exit,speed_1,...,speed_N", as written by
  !> `component_names`); an error names the component that is not understood.
  subroutine init_from_components(this, csv, n_agents, error)
    class(param_model_t), intent(inout) :: this
    character(len=*), intent(in) :: csv
    integer, intent(in) :: n_agents
    type(error_t), allocatable, intent(out) :: error
    character(len=16) :: names(64)
    character(len=:), allocatable :: tok
    integer :: i0, i1, n, j, ios
    n = 0; i0 = 1
    do while (i0 <= len(csv))
      i1 = index(csv(i0:), ",")
      if (i1 == 0) then
        i1 = len(csv) + 1
      else
        i1 = i0 + i1 - 1
      end if
      tok = trim(adjustl(csv(i0:i1 - 1)))
      i0 = i1 + 1
      if (tok == 'l_exit' .or. tok == 'speed' .or. tok == 'l_exit2' .or. tok == 'speed_mean' .or. &
        tok == 'speed_spread') then
        n = n + 1; names(n) = tok
      else if (tok == 'speed_seed') then
        ! the second component of 'speed_spread' (the comparison at the end refuses it anywhere else)
      else if (index(tok, 'speed_') == 1) then
        read(tok(7:), *, iostat=ios) j
        if (ios /= 0) then
          call set_error(error, "parameter component '" // tok // "' is not understood", EXIT_BAD_INPUT); return
        end if
        if (j == 1) then
          n = n + 1; names(n) = 'speeds'
        end if
      else if (len(tok) > 0) then
        call set_error(error, "parameter component '" // tok // "' is not a known parameter (known: " // &
          KNOWN_PARAMS_TEXT // ")", EXIT_BAD_INPUT); return
      end if
      if (n >= size(names)) exit
    end do
    call this%init_model(names(1:n), n_agents)
    if (any(names(1:n) == 'speed_mean') .neqv. any(names(1:n) == 'speed_spread')) then
      call set_error(error, "parameter components '" // csv // "': speed_mean and speed_spread go together", EXIT_BAD_INPUT)
      return
    end if
    if (this%component_names() /= csv) call set_error(error, "parameter components '" // csv // &
      "' do not describe " // str(n_agents) // " agents", EXIT_BAD_INPUT)
  end subroutine init_from_components

  !> Comma-separated component names, e.g. "l_exit,speed_1,...,speed_20".
  function component_names(this) result(s)
    class(param_model_t), intent(in) :: this
    character(len=:), allocatable :: s
    integer :: k, i
    s = ""
    do k = 1, this%n_params
      if (this%names(k) == 'speed_spread') then
        s = s // "speed_spread,speed_seed,"
      else if (this%names(k) /= 'speeds') then
        s = s // trim(this%names(k)) // ","
      else
        do i = 1, this%width(k)
          s = s // "speed_" // str(i) // ","
        end do
      end if
    end do
    if (len(s) > 0) s = s(1:len(s) - 1)
  end function component_names

  !> Set the model inputs of sample mu: cfg%scene%l_exit, cfg%scene%l_exit2 and the per-agent speeds.
  subroutine apply(this, mu, cfg, speeds)
    class(param_model_t), intent(in) :: this
    !> parameter values [n_expanded]
    real(wp), intent(in) :: mu(:)
    !> configuration to modify (a copy of the reference)
    type(config_t), intent(inout) :: cfg
    !> speeds [n_agents]: reference speeds on entry, the sample's speeds on return
    real(wp), intent(inout) :: speeds(:)
    integer :: k, j, js, jm
    js = 0; jm = 0
    do k = 1, this%n_params
      j = this%first(k)
      select case (trim(this%names(k)))
      case ('l_exit')
        cfg%scene%l_exit = mu(j)
      case ('l_exit2')
        cfg%scene%l_exit2 = mu(j)
      case ('speed')
        speeds = mu(j)
      case ('speed_mean')
        jm = j
      case ('speeds')
        speeds = mu(j:j + this%width(k) - 1)
      case ('speed_spread')
        js = j
      end select
    end do
    ! 'speed_mean' and 'speed_spread' come together (check_study, init_from_components)
    if (jm > 0 .and. js > 0) then
      call draw_speeds(mu(jm), mu(js), nint(mu(js + 1)), speeds)
    else if (jm > 0) then
      speeds = mu(jm)
    end if
  end subroutine apply

  !> Each agent's desired speed c_i = mean + spread (2 u_i - 1), u_i uniform in (0, 1) drawn in
  !> agent order from the generator seeded with (seed, SPEED_STREAM): uniform on
  !> (mean - spread, mean + spread).
  subroutine draw_speeds(mean, spread, seed, speeds)
    real(wp), intent(in) :: mean, spread
    integer, intent(in) :: seed
    !> the agents' speeds [n_agents]
    real(wp), intent(out) :: speeds(:)
    type(rng_t) :: rng
    integer :: i
    call rng%seed(seed, SPEED_STREAM)
    do i = 1, size(speeds)
      speeds(i) = mean + spread * (2.0_wp * rng%uniform() - 1.0_wp)
    end do
  end subroutine draw_speeds

  !> The scene of sample mu (reference configuration cfg_ref).
  subroutine scene_of(this, mu, cfg_ref, scene, error)
    class(param_model_t), intent(in) :: this
    real(wp), intent(in) :: mu(:)
    type(config_t), intent(in) :: cfg_ref
    type(scene_t), intent(out) :: scene
    type(error_t), allocatable, intent(out) :: error
    type(config_t) :: c
    real(wp) :: sp(this%n_agents)
    c = cfg_ref
    sp = 0
    call this%apply(mu, c, sp)
    call scene%init(c%scene, c%obstacles, error)
  end subroutine scene_of

  !> Scene, speeds and desired velocity of sample mu: the reference configuration cfg_ref and
  !> speeds ref_speeds [n_agents] with the parameters applied; agents of radius `radius`.
  subroutine sample_model(this, mu, cfg_ref, ref_speeds, radius, scene, speeds, desired, error)
    class(param_model_t), intent(in) :: this
    real(wp), intent(in) :: mu(:)
    type(config_t), intent(in) :: cfg_ref
    real(wp), intent(in) :: ref_speeds(:)
    real(wp), intent(in) :: radius
    type(scene_t), intent(out) :: scene
    real(wp), allocatable, intent(out) :: speeds(:)
    type(desired_t), intent(out) :: desired
    type(error_t), allocatable, intent(out) :: error
    type(config_t) :: c
    c = cfg_ref
    speeds = ref_speeds
    call this%apply(mu, c, speeds)
    call scene%init(c%scene, c%obstacles, error)
    if (allocated(error)) then
      call prefix_error(error, "scene of the sample"); return
    end if
    call desired%init(c%desired, scene, radius, size(speeds), error)
  end subroutine sample_model
end module cr_param_model
