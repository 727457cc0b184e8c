!> The behaviour options of the full model against closed forms.
!> Social distance d_s (&agents social_distance): an agent walking into a standing one ends at
!> gap exactly d_s and then pushes it at the mean of their desired speeds; an agent walking into
!> a pillar and one walking into a wall stop at gap exactly d_s / 2 (each agent carries a ring
!> of width d_s / 2). Density-dependent desired speed (&desired speed_model = 'weidmann'): the
!> kernel density of a hexagonal lattice equals the lattice density within 0.5% (the kernel's
!> stated accuracy, cr_density_speed) and agents inside a uniform crowd walk at Weidmann's speed
!> v0 (1 - exp(-1.913 (1/rho - 1/5.4))) within 1%; a lone agent keeps 99.5% of its free speed.
program test_behaviour
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: config_t
  use cr_fom, only: fom_t, step_record_t
  use cr_density_speed, only: density_speed_t, weidmann_factor
  implicit none
  real(wp), parameter :: R = 0.2_wp

  call test_pair(0.3_wp)
  call test_pair(0.0_wp)
  call test_pillar(0.3_wp)
  call test_wall(0.3_wp)
  call test_lattice_density()
  call test_crowd_speed(2.0_wp, 0.0_wp)
  call test_crowd_speed(3.5_wp, 0.0_wp)
  call test_crowd_speed(2.0_wp, 1.0_wp)
  call test_crowd_speed(3.5_wp, 1.0_wp)
  call test_summary()

contains

  !> A 10 x 10 m hall with a 2 m exit at x = 5 (straight-line aiming), step 0.05 s.
  function hall(ds) result(cfg)
    real(wp), intent(in) :: ds
    type(config_t) :: cfg
    cfg%source = "test"
    cfg%scene%hall_length = 10; cfg%scene%hall_width = 10; cfg%scene%l_exit = 2
    cfg%scene%exit_center = 5; cfg%scene%wall_thickness = 0.3_wp
    cfg%agents%radius = R; cfg%agents%social_distance = ds
    cfg%desired%field = 'analytic'
    cfg%time%dt = 0.05_wp
    cfg%solver%name = 'sparse_active_set'; cfg%solver%tol = 1.0e-12_wp
  end function hall

  subroutine run(fom, n, error)
    type(fom_t), intent(inout) :: fom
    integer, intent(in) :: n
    type(error_t), allocatable, intent(out) :: error
    type(step_record_t) :: rec
    integer :: k
    do k = 1, n
      call fom%advance(rec, error)
      if (allocated(error)) return
    end do
  end subroutine run

  !> Agent 1 (speed 1) walks up into agent 2 (speed 0) on the exit's axis.
  subroutine test_pair(ds)
    real(wp), intent(in) :: ds
    type(config_t) :: cfg
    type(fom_t) :: fom
    type(error_t), allocatable :: error
    character(len=:), allocatable :: tag
    tag = " (d_s = " // str(ds) // ")"
    cfg = hall(ds); cfg%agents%n_agents = 2
    call fom%init(cfg, error, q0=[5.0_wp, 2.0_wp, 5.0_wp, 4.0_wp], speeds=[1.0_wp, 0.0_wp])
    call check(.not. allocated(error), "pair: init" // tag)
    if (allocated(error)) return
    call run(fom, 60, error)
    call check(.not. allocated(error), "pair: 60 steps" // tag)
    if (allocated(error)) return
    call check_close(fom%q(4) - fom%q(2) - 2 * R, ds, 1.0e-9_wp, "pair: gap equals d_s" // tag)
    call check_close(fom%u(2), 0.5_wp, 1.0e-9_wp, "pair: the walker pushes at the mean speed" // tag)
    call check_close(fom%u(4), 0.5_wp, 1.0e-9_wp, "pair: the pushed agent moves at the mean speed" // tag)
  end subroutine test_pair

  !> An agent walks up into a pillar (disk of radius 0.5) on the exit's axis.
  subroutine test_pillar(ds)
    real(wp), intent(in) :: ds
    type(config_t) :: cfg
    type(fom_t) :: fom
    type(error_t), allocatable :: error
    cfg = hall(ds); cfg%agents%n_agents = 1
    cfg%obstacles%n_disks = 1
    cfg%obstacles%disk_x(1) = 5; cfg%obstacles%disk_y(1) = 5; cfg%obstacles%disk_r(1) = 0.5_wp
    call fom%init(cfg, error, q0=[5.0_wp, 3.0_wp], speeds=[1.0_wp])
    call check(.not. allocated(error), "pillar: init")
    if (allocated(error)) return
    call run(fom, 60, error)
    call check(.not. allocated(error), "pillar: 60 steps")
    if (allocated(error)) return
    call check_close(5 - fom%q(2) - 0.5_wp - R, ds / 2, 1.0e-9_wp, "pillar: gap equals d_s / 2")
    call check_close(fom%u(2), 0.0_wp, 1.0e-9_wp, "pillar: the agent stands")
  end subroutine test_pillar

  !> An agent walks up into a wall: a horizontal wall (a 4 m x 0.2 m polygon) across the
  !> exit's axis, 3.8 m below the top wall.
  subroutine test_wall(ds)
    real(wp), intent(in) :: ds
    type(config_t) :: cfg
    type(fom_t) :: fom
    type(error_t), allocatable :: error
    cfg = hall(ds); cfg%agents%n_agents = 1
    cfg%obstacles%n_polygons = 1; cfg%obstacles%poly_nv(1) = 4
    cfg%obstacles%poly_x(1:4, 1) = [2.0_wp, 6.0_wp, 6.0_wp, 2.0_wp]
    cfg%obstacles%poly_y(1:4, 1) = [6.0_wp, 6.0_wp, 6.2_wp, 6.2_wp]
    ! straight up from (5, 3) to the exit above: the wall's lower face y = 6 blocks it
    call fom%init(cfg, error, q0=[5.0_wp, 3.0_wp], speeds=[1.0_wp])
    call check(.not. allocated(error), "wall: init")
    if (allocated(error)) return
    call run(fom, 80, error)
    call check(.not. allocated(error), "wall: 80 steps")
    if (allocated(error)) return
    call check_close(6 - fom%q(2) - R, ds / 2, 1.0e-9_wp, "wall: gap equals d_s / 2")
    call check_close(fom%q(1), 5.0_wp, 1.0e-12_wp, "wall: no sideways drift")
  end subroutine test_wall

  !> Hexagonal lattices of density 2 .. 5 /m2 (spacing <= 1.1 sigma, sigma = 0.7 m): the kernel
  !> density of agents at least 3 sigma inside the lattice is the lattice density within 0.5%.
  subroutine test_lattice_density()
    type(density_speed_t) :: ds
    type(config_t) :: cfg
    real(wp), allocatable :: q(:), rho(:)
    real(wp) :: dens, worst
    integer :: k, n_in
    logical, allocatable :: interior(:)
    call ds%init(cfg%desired, 1)
    call check(.not. ds%on, "density model off by default")
    do k = 2, 5
      dens = real(k, wp)
      call hex_lattice(dens, [0.0_wp, 0.0_wp], 17, q, interior)
      allocate(rho(size(q) / 2))
      call ds%init(cfg%desired, size(rho))
      call ds%density(q, rho)
      n_in = count(interior)
      worst = maxval(abs(rho / dens - 1), mask=interior)
      call check(n_in > 10 .and. worst <= 5.0e-3_wp, "lattice density " // str(dens) // ": " // str(n_in) // &
        " interior agents within 0.5% (worst " // str(worst) // ")")
      deallocate(rho)
    end do
  end subroutine test_lattice_density

  !> A uniform crowd at density `dens` in a large hall, all with free speed 1.34: after one step
  !> the agents at least 3 sigma inside the crowd walk at Weidmann's speed within 1%, with or
  !> without look-ahead `beta`; an isolated agent far from the crowd keeps 99.5% of its free
  !> speed (its own kernel weight); with look-ahead the front row walks faster than the back row.
  subroutine test_crowd_speed(dens, beta)
    real(wp), intent(in) :: dens, beta
    type(config_t) :: cfg
    type(fom_t) :: fom
    type(error_t), allocatable :: error
    type(step_record_t) :: rec
    real(wp), allocatable :: q(:), sp(:), spd(:)
    logical, allocatable :: interior(:)
    real(wp) :: want, worst, ylo, yhi, vf, vb
    integer :: n, i
    character(len=:), allocatable :: tag
    tag = " (density " // str(dens) // ", look-ahead " // str(beta) // ")"
    call hex_lattice(dens, [15.0_wp, 12.0_wp], 15, q, interior)
    n = size(q) / 2 + 1
    q = [q, 15.0_wp, 35.0_wp]          ! a lone agent far from the crowd
    interior = [interior, .false.]
    cfg = hall(0.0_wp)
    cfg%scene%hall_length = 30; cfg%scene%hall_width = 40; cfg%scene%exit_center = 15
    cfg%agents%n_agents = n
    cfg%desired%speed_model = 'weidmann'
    cfg%desired%density_anisotropy = beta
    allocate(sp(n)); sp = 1.34_wp
    call fom%init(cfg, error, q0=q, speeds=sp)
    call check(.not. allocated(error), "crowd: init" // tag)
    if (allocated(error)) return
    call fom%advance(rec, error)
    call check(.not. allocated(error), "crowd: one step" // tag)
    if (allocated(error)) return
    want = 1.34_wp * (1 - exp(-1.913_wp * (1 / dens - 1 / 5.4_wp)))
    spd = [(norm2(fom%u(2*i-1:2*i)), i = 1, n)]
    worst = maxval(abs(spd / want - 1), mask=interior)
    call check(worst <= 1.0e-2_wp, "crowd: interior agents walk at Weidmann's speed " // str(want) // &
      " within 1%" // tag // " (worst " // str(worst) // ")")
    call check(abs(spd(n) / 1.34_wp - 1) <= 6.0e-3_wp, "crowd: a lone agent keeps 99.5% of its free speed" // &
      tag // " (" // str(spd(n)) // ")")
    ! mean speeds of the front row (largest y: the exit is above) and of the back row (the
    ! lattice is symmetric under y -> -y)
    ylo = minval(q(2:2*n-2:2)); yhi = maxval(q(2:2*n-2:2))
    vf = sum(spd(1:n-1), mask=q(2:2*n-2:2) > yhi - 1.0e-6_wp) / count(q(2:2*n-2:2) > yhi - 1.0e-6_wp)
    vb = sum(spd(1:n-1), mask=q(2:2*n-2:2) < ylo + 1.0e-6_wp) / count(q(2:2*n-2:2) < ylo + 1.0e-6_wp)
    if (beta > 0) then
      call check(vf > 1.3_wp * vb, "crowd: with look-ahead the front row walks faster than the back row" // tag)
    else
      call check_close(vf, vb, 1.0e-9_wp, "crowd: isotropic, front and back rows alike" // tag)
    end if
  end subroutine test_crowd_speed

  !> m x m hexagonal lattice of density dens centred at c: positions q [2 m^2] and the agents
  !> at least 3 sigma (sigma = 0.7 m) from the lattice's edge.
  subroutine hex_lattice(dens, c, m, q, interior)
    real(wp), intent(in) :: dens, c(2)
    integer, intent(in) :: m
    real(wp), allocatable, intent(out) :: q(:)
    logical, allocatable, intent(out) :: interior(:)
    real(wp) :: a, x, y, lo(2), hi(2)
    integer :: i, j, k
    a = sqrt(2 / (sqrt(3.0_wp) * dens))
    allocate(q(2 * m * m), interior(m * m))
    k = 0
    do j = 0, m - 1
      do i = 0, m - 1
        k = k + 1
        x = a * (i + 0.5_wp * mod(j, 2)); y = a * sqrt(3.0_wp) / 2 * j
        q(2*k-1:2*k) = [x, y]
      end do
    end do
    lo = [minval(q(1::2)), minval(q(2::2))]; hi = [maxval(q(1::2)), maxval(q(2::2))]
    do k = 1, m * m
      q(2*k-1:2*k) = q(2*k-1:2*k) - (lo + hi) / 2 + c
    end do
    lo = [minval(q(1::2)), minval(q(2::2))]; hi = [maxval(q(1::2)), maxval(q(2::2))]
    do k = 1, m * m
      interior(k) = all(q(2*k-1:2*k) - lo >= 2.1_wp) .and. all(hi - q(2*k-1:2*k) >= 2.1_wp)
    end do
  end subroutine hex_lattice
end program test_behaviour
