!> The parameter space of a study and its training / validation samples.
!>
!> mu has n_expanded components (cr_param_model maps them to the model). Every rank generates the full sample lists from the seed
!> (sample k of a set uses its own random stream), so the samples never depend on the number
!> of ranks. Training: uniform random in the box or a tensor grid (first parameter fastest,
!> end points included; one point means the midpoint). Validation: uniform random in the box
!> (streams disjoint from training), checked to be disjoint from the training samples. The
!> speed_seed component of 'speed_spread' is an integer drawn uniformly in 0..SPEED_SEED_MAX from
!> the same stream (its box is that range).
module cr_sampling
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, problems_t, prefix_error
  use cr_config_check, only: check_config
  use cr_sane, only: need_sane, MAX_SPEED
  use cr_strings, only: str
  use cr_random, only: rng_t
  use cr_param_model, only: param_model_t, SPEED_SEED_MAX
  use cr_config, only: config_t
  use cr_study_config, only: study_cfg_t
  implicit none
  private
  public :: param_space_t, sample_set_t, generate_samples

  !> The parameters of a study: the mapping to the model (cr_param_model) and the box.
  type, extends(param_model_t) :: param_space_t
    !> bounds of each component [n_expanded]
    real(wp), allocatable :: lo(:), hi(:)
    !> components that take integer values (the speed_seed components) [n_expanded]
    logical, allocatable :: integral(:)
  contains
    procedure :: init => space_init
    procedure :: check_values
    procedure :: uniform_value
  end type param_space_t

  !> One sample set (training or validation).
  type :: sample_set_t
    character(len=8) :: name = ''
    integer :: n = 0
    !> parameter values [n_expanded, n]
    real(wp), allocatable :: mu(:,:)
  end type sample_set_t

contains

  !> Expand the study parameters for a scene of n_agents agents.
  subroutine space_init(this, s, n_agents)
    class(param_space_t), intent(out) :: this
    type(study_cfg_t), intent(in) :: s
    integer, intent(in) :: n_agents
    integer :: k, m
    call this%init_model(s%param_name(1:s%n_params), n_agents)
    m = this%n_expanded
    allocate(this%lo(m), this%hi(m), this%integral(m))
    this%integral = .false.
    do k = 1, s%n_params
      this%lo(this%first(k):this%first(k) + this%width(k) - 1) = s%param_min(k)
      this%hi(this%first(k):this%first(k) + this%width(k) - 1) = s%param_max(k)
      if (this%names(k) == 'speed_spread') then
        this%lo(this%first(k) + 1) = 0
        this%hi(this%first(k) + 1) = SPEED_SEED_MAX
        this%integral(this%first(k) + 1) = .true.
      end if
    end do
  end subroutine space_init

  !> Component c at the uniform draw u in [0, 1): linear in the box, or, for an integral
  !> component (the population's seed), an integer uniform on lo..hi.
  pure real(wp) function uniform_value(this, c, u) result(x)
    class(param_space_t), intent(in) :: this
    integer, intent(in) :: c
    real(wp), intent(in) :: u
    if (this%integral(c)) then
      x = min(aint(this%lo(c) + (this%hi(c) - this%lo(c) + 1) * u), this%hi(c))
    else
      x = this%lo(c) + (this%hi(c) - this%lo(c)) * u
    end if
  end function uniform_value

  !> Parameter values usable on the reference configuration `cfg`: every component finite
  !> and of a sane magnitude, and the scene they give valid (check_config: an l_exit wider
  !> than the wall, a speed of 1e308 are refused). Values outside the study's box are allowed
  !> (the reduced model then extrapolates). `what` starts the message.
  subroutine check_values(this, mu, cfg, what, error)
    class(param_space_t), intent(in) :: this
    !> parameter values [n_expanded]
    real(wp), intent(in) :: mu(:)
    type(config_t), intent(in) :: cfg
    character(len=*), intent(in) :: what
    type(error_t), allocatable, intent(out) :: error
    type(problems_t) :: probs
    type(config_t) :: c
    real(wp), allocatable :: speeds(:)
    integer :: k
    do k = 1, size(mu)
      call need_sane(probs, mu(k), "component " // str(k), MAX_SPEED)
    end do
    call probs%to_error(what, error)
    if (allocated(error)) return
    call check_spread_values(this, mu, probs)
    call probs%to_error(what, error)
    if (allocated(error)) return
    c = cfg
    allocate(speeds(max(cfg%agents%n_agents, 0)))
    speeds = cfg%agents%speed
    call this%apply(mu, c, speeds)
    do k = 1, size(speeds)
      call probs%need(speeds(k) >= 0, "agent " // str(k) // ": speed " // str(speeds(k)) // " must be >= 0")
    end do
    call probs%to_error(what, error)
    if (allocated(error)) return
    call check_config(c, error)
    if (allocated(error)) call prefix_error(error, what // " gives an invalid scene")
  end subroutine check_values

  !> The heterogeneous population's components: mean > 0, 0 <= spread <= mean, the seed an
  !> integer in 0..SPEED_SEED_MAX.
  subroutine check_spread_values(this, mu, probs)
    class(param_space_t), intent(in) :: this
    real(wp), intent(in) :: mu(:)
    type(problems_t), intent(inout) :: probs
    integer :: km, ks
    real(wp) :: mean, spread, seed
    km = findloc(this%names, 'speed_mean', dim=1)
    ks = findloc(this%names, 'speed_spread', dim=1)
    if (km == 0 .or. ks == 0) return
    mean = mu(this%first(km)); spread = mu(this%first(ks)); seed = mu(this%first(ks) + 1)
    call probs%need(mean > 0, "speed_mean = " // str(mean) // " must be > 0")
    call probs%need(spread >= 0, "speed_spread = " // str(spread) // " must be >= 0")
    if (mean > 0 .and. spread >= 0) call probs%need(spread <= mean, "speed_spread = " // str(spread) // &
      " must not exceed speed_mean = " // str(mean) // " (a speed would be negative)")
    call probs%need(seed == aint(seed) .and. seed >= 0 .and. seed <= SPEED_SEED_MAX, "speed_seed = " // &
      str(seed) // " must be an integer in 0.." // str(SPEED_SEED_MAX))
  end subroutine check_spread_values

  !> Training and validation samples of the study (identical on every rank).
  subroutine generate_samples(s, space, train, valid, error)
    type(study_cfg_t), intent(in) :: s
    type(param_space_t), intent(in) :: space
    type(sample_set_t), intent(out) :: train, valid
    type(error_t), allocatable, intent(out) :: error
    integer :: k, i, j, m, rem
    m = space%n_expanded
    train%name = 'train'; train%n = s%n_train
    valid%name = 'valid'; valid%n = s%n_valid
    allocate(train%mu(m, train%n), valid%mu(m, valid%n))
    if (s%sampling == 'grid') then
      do k = 1, train%n
        rem = k - 1
        do j = 1, space%n_params
          i = mod(rem, s%grid_n(j))
          rem = rem / s%grid_n(j)
          if (s%grid_n(j) == 1) then
            train%mu(j, k) = 0.5_wp * (space%lo(j) + space%hi(j))
          else
            train%mu(j, k) = space%lo(j) + (space%hi(j) - space%lo(j)) * real(i, wp) / real(s%grid_n(j) - 1, wp)
          end if
        end do
      end do
    else
      do k = 1, train%n
        call draw(k, train%mu(:, k))
      end do
    end if
    do k = 1, valid%n
      call draw(-k, valid%mu(:, k))
      do i = 1, train%n
        if (all(valid%mu(:, k) == train%mu(:, i))) then
          call set_error(error, "sampling: validation sample " // str(k) // " equals training sample " // &
            str(i) // " (change &study seed)"); return
        end if
      end do
    end do

  contains

    !> Uniform sample in the box from the stream of sample `stream`.
    subroutine draw(stream, mu)
      integer, intent(in) :: stream
      real(wp), intent(out) :: mu(:)
      type(rng_t) :: rng
      integer :: c
      call rng%seed(s%seed, stream)
      do c = 1, size(mu)
        mu(c) = space%uniform_value(c, rng%uniform())
      end do
    end subroutine draw
  end subroutine generate_samples
end module cr_sampling
