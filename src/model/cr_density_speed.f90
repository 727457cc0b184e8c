!> Density-dependent desired speed: each agent's speed c_i scaled by a fundamental diagram of
!> its local density, so that agents in a dense crowd want to walk slower.
!>
!> Local density of agent i (persons/m2): a Gaussian kernel of width sigma, shifted to vanish
!> at its cut R = 3 sigma (continuous there), over the agents whose centres lie within R of
!> it, the agent itself included,
!>   rho_i = sum_{j : |x_i - x_j| <= R} w(|x_i - x_j|),
!>   w(d) = C (exp(-d^2 / (2 sigma^2)) - exp(-9/2)),  C = 1 / (2 pi sigma^2 (1 - 11/2 exp(-9/2))),
!> normalised so that w integrates to 1 over the disk of radius R. On a square or hexagonal
!> lattice of density rho with spacing a <= 1.5 sigma the sum equals rho within 0.5% (about
!> 0.1% below a = 1.1 sigma; measured for any lattice offset); a lone agent sees w(0) =
!> 0.34 /m2 for sigma = 0.7 m, where Weidmann's diagram keeps 99.5% of the free speed.
!> Neighbours come from the cell list of the contacts (cr_neighbours, a scene without
!> obstacles and zero radius: a row per pair within the cut).
!>
!> Look-ahead (&desired density_anisotropy = beta in [0, 1]): neighbour j counts with weight
!> w(d) (1 + beta cos theta_ij), theta_ij the angle between agent i's desired direction and
!> x_j - x_i, so that a pedestrian slows for the crowd ahead more than for the crowd behind
!> (beta = 1: nothing straight behind counts). The lattice sums above are unchanged (a lattice
!> is symmetric about each of its points, so the cosines cancel).
!>
!> Fundamental diagram (Weidmann 1993), v0 = the agent's own speed c_i (its free speed):
!>   v(rho) = v0 (1 - exp(-gamma (1/rho - 1/rho_max))), clamped to [0, v0], v(0) = v0.
module cr_density_speed
  use cr_kinds, only: wp
  use cr_config, only: desired_cfg_t
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  implicit none
  private
  public :: density_speed_t, weidmann_factor, DENSITY_CUT

  !> the kernel is cut at DENSITY_CUT sigma
  real(wp), parameter :: DENSITY_CUT = 3.0_wp

  !> Local density estimator and diagram of one run.
  type :: density_speed_t
    logical :: on = .false.
    real(wp) :: sigma = 0.7_wp, gamma = 1.913_wp, rho_max = 5.4_wp, beta = 0.0_wp
    !> local density of each agent at the last call [n_agents]
    real(wp), allocatable :: rho(:)
    type(cell_list_t), private :: cells
    type(contact_set_t), private :: cs
    type(scene_t), private :: open_space
  contains
    procedure :: init
    procedure :: free
    procedure :: density
    procedure :: apply
    procedure :: scale_speeds
  end type density_speed_t

contains

  !> Take the model and its parameters from &desired (on when speed_model = 'weidmann').
  subroutine init(this, cfg, n_agents)
    class(density_speed_t), intent(inout) :: this
    type(desired_cfg_t), intent(in) :: cfg
    integer, intent(in) :: n_agents
    call this%free()
    this%on = cfg%speed_model == 'weidmann'
    this%sigma = cfg%density_sigma
    this%gamma = cfg%fd_gamma
    this%rho_max = cfg%fd_rho_max
    this%beta = cfg%density_anisotropy
    allocate(this%rho(n_agents))
    this%rho = 0
    call this%cs%init(n_agents, 1.0_wp, 16 * n_agents)
  end subroutine init

  subroutine free(this)
    class(density_speed_t), intent(inout) :: this
    if (allocated(this%rho)) deallocate(this%rho)
    call this%cs%free()
    this%on = .false.
  end subroutine free

  !> rho [n_agents] = local density of every agent at positions q [2*n_agents] (kernel above);
  !> with dir [2*n_agents] (desired velocities, any length) the look-ahead weights apply.
  subroutine density(this, q, rho, dir)
    class(density_speed_t), intent(inout) :: this
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: rho(:)
    real(wp), intent(in), optional :: dir(:)
    real(wp) :: cut, c, e, two_s2, w, ca, cb, na, nb
    integer :: l
    cut = DENSITY_CUT * this%sigma
    two_s2 = 2 * this%sigma**2
    e = exp(-DENSITY_CUT**2 / 2)
    c = 1 / (acos(-1.0_wp) * two_s2 * (1 - (1 + DENSITY_CUT**2 / 2) * e))
    call build_contacts(this%open_space, q, 0.0_wp, cut, this%cells, this%cs)
    rho = c * (1 - e)
    do l = 1, this%cs%n
      associate (a => this%cs%ia(l), b => this%cs%ib(l), d => this%cs%gap(l))
        if (b > 0 .and. d <= cut) then
          w = c * (exp(-d * d / two_s2) - e)
          ca = 1; cb = 1
          if (present(dir) .and. this%beta > 0 .and. d > 0) then
            ! cosines of the angles between each agent's direction and the other agent
            na = norm2(dir(2*a-1:2*a)); nb = norm2(dir(2*b-1:2*b))
            if (na > 0) ca = 1 + this%beta * dot_product(dir(2*a-1:2*a), q(2*b-1:2*b) - q(2*a-1:2*a)) / (na * d)
            if (nb > 0) cb = 1 + this%beta * dot_product(dir(2*b-1:2*b), q(2*a-1:2*a) - q(2*b-1:2*b)) / (nb * d)
          end if
          rho(a) = rho(a) + w * ca
          rho(b) = rho(b) + w * cb
        end if
      end associate
    end do
  end subroutine density

  !> v [2*n_agents]: desired velocities at positions q [2*n_agents], scaled in place by the
  !> diagram at each agent's local density (unchanged when the model is off).
  subroutine apply(this, q, v)
    class(density_speed_t), intent(inout) :: this
    real(wp), intent(in) :: q(:)
    real(wp), intent(inout) :: v(:)
    integer :: i
    real(wp) :: f
    if (.not. this%on) return
    call this%density(q, this%rho, v)
    do i = 1, size(this%rho)
      f = weidmann_factor(this%rho(i), this%gamma, this%rho_max)
      v(2*i-1:2*i) = f * v(2*i-1:2*i)
    end do
  end subroutine apply

  !> speeds_out [n_agents] = speeds [n_agents] scaled by the diagram at each agent's local
  !> density at positions q [2*n_agents], the look-ahead taking the directions of the desired
  !> velocities v [2*n_agents] (speeds times the desired directions, as `apply` receives them):
  !> the speeds whose desired velocities are those `apply` gives (to round-off: (f c) d against
  !> f (c d)). The reduced models evaluate the density-dependent desired speed this way.
  subroutine scale_speeds(this, q, v, speeds, speeds_out)
    class(density_speed_t), intent(inout) :: this
    real(wp), intent(in) :: q(:), v(:), speeds(:)
    real(wp), intent(out) :: speeds_out(:)
    call this%density(q, this%rho, v)
    speeds_out = speeds * weidmann_factor(this%rho, this%gamma, this%rho_max)
  end subroutine scale_speeds

  !> v(rho) / v0 of Weidmann's diagram: 1 - exp(-gamma (1/rho - 1/rho_max)) in [0, 1]; 1 at rho <= 0.
  elemental real(wp) function weidmann_factor(rho, gamma, rho_max) result(f)
    real(wp), intent(in) :: rho, gamma, rho_max
    if (rho <= 0) then
      f = 1
    else
      f = max(0.0_wp, 1 - exp(-gamma * (1 / rho - 1 / rho_max)))
    end if
  end function weidmann_factor
end module cr_density_speed
