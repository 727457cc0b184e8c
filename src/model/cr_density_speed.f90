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
!> The density of a few agents only (`density_of`, `scale_speeds_of`: the reduced models, which
!> read the desired velocity of the agents of their sampled points only) bins every agent in a
!> grid of cells of side >= the cut and sums the kernel over the 3 x 3 cells around each listed
!> agent: O(n_agents) integer work plus the listed agents' kernel sums, the same values as
!> `density` up to the order of the sums. `n_evaluated` counts the agents whose density was
!> summed.
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
  use cr_neighbours, only: cell_list_t, build_contacts, bin_agents, pair_contact
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
    !> agents whose local density was summed, over every call since init
    integer(8) :: n_evaluated = 0
    type(cell_list_t), private :: cells, bins
    type(contact_set_t), private :: cs
    type(scene_t), private :: open_space
  contains
    procedure :: init
    procedure :: free
    procedure :: density
    procedure :: apply
    procedure :: scale_speeds
    procedure :: density_of
    procedure :: scale_speeds_of
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
    this%n_evaluated = 0
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
    call kernel_constants(this%sigma, cut, two_s2, e, c)
    this%n_evaluated = this%n_evaluated + size(rho)
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

  !> speeds_out [n_agents]: speeds_out(a) = speeds(a) scaled by the diagram at the local density
  !> of a at positions q [2*n_agents], for the agents a listed in `agents` (their rho stored in
  !> this%rho); the other entries are speeds(:) unchanged. v [2*n_agents]: the desired
  !> velocities of the listed agents (speeds times the desired directions; only their entries
  !> are read), for the look-ahead. At the listed agents the result is scale_speeds' to round-off.
  subroutine scale_speeds_of(this, q, v, agents, speeds, speeds_out)
    class(density_speed_t), intent(inout) :: this
    real(wp), intent(in) :: q(:), v(:), speeds(:)
    integer, intent(in) :: agents(:)
    real(wp), intent(out) :: speeds_out(:)
    real(wp) :: rho(size(agents))
    call this%density_of(q, agents, rho, v)
    speeds_out = speeds
    this%rho(agents) = rho
    speeds_out(agents) = speeds(agents) * weidmann_factor(rho, this%gamma, this%rho_max)
  end subroutine scale_speeds_of

  !> rho [size(agents)] = local density of agents(k) at positions q [2*n_agents] (the kernel
  !> above over every agent within the cut); with dir [2*n_agents] (desired velocities, any
  !> length; only the listed agents' entries are read) the look-ahead weights apply.
  subroutine density_of(this, q, agents, rho, dir)
    class(density_speed_t), intent(inout) :: this
    real(wp), intent(in) :: q(:)
    integer, intent(in) :: agents(:)
    real(wp), intent(out) :: rho(:)
    real(wp), intent(in), optional :: dir(:)
    real(wp) :: cut, c, e, two_s2, na
    integer :: k, a, cx, cy, ix, iy, j
    call kernel_constants(this%sigma, cut, two_s2, e, c)
    call bin_agents(q, cut, this%bins)
    this%n_evaluated = this%n_evaluated + size(agents)
    do k = 1, size(agents)
      a = agents(k)
      na = 0
      if (present(dir) .and. this%beta > 0) na = norm2(dir(2*a-1:2*a))
      rho(k) = c * (1 - e)
      cx = mod(this%bins%cell(a) - 1, this%bins%nx)
      cy = (this%bins%cell(a) - 1) / this%bins%nx
      do iy = max(cy - 1, 0), min(cy + 1, this%bins%ny - 1)
        do ix = max(cx - 1, 0), min(cx + 1, this%bins%nx - 1)
          j = this%bins%head(iy * this%bins%nx + ix + 1)
          do while (j > 0)
            if (j /= a) rho(k) = rho(k) + pair_weight(a, j)
            j = this%bins%next(j)
          end do
        end do
      end do
    end do
  contains
    !> kernel weight of neighbour j in agent a's density (0 beyond the cut), with the look-ahead
    real(wp) function pair_weight(a, j) result(w)
      integer, intent(in) :: a, j
      real(wp) :: dx, dy, d, g(2)
      w = 0
      dx = q(2*a-1) - q(2*j-1); dy = q(2*a) - q(2*j)
      if (abs(dx) > cut .or. abs(dy) > cut) return
      call pair_contact(dx, dy, 0.0_wp, g, d)
      if (.not. d <= cut) return
      w = c * (exp(-d * d / two_s2) - e)
      if (na > 0 .and. d > 0) &
        w = w * (1 + this%beta * dot_product(dir(2*a-1:2*a), q(2*j-1:2*j) - q(2*a-1:2*a)) / (na * d))
    end function pair_weight
  end subroutine density_of

  !> The kernel's cut R = DENSITY_CUT sigma, 2 sigma^2, its shift exp(-R^2 / (2 sigma^2)) and
  !> its normalisation C (module header).
  pure subroutine kernel_constants(sigma, cut, two_s2, e, c)
    real(wp), intent(in) :: sigma
    real(wp), intent(out) :: cut, two_s2, e, c
    cut = DENSITY_CUT * sigma
    two_s2 = 2 * sigma**2
    e = exp(-DENSITY_CUT**2 / 2)
    c = 1 / (acos(-1.0_wp) * two_s2 * (1 - (1 + DENSITY_CUT**2 / 2) * e))
  end subroutine kernel_constants

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
