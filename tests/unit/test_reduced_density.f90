!> The density-dependent desired speed in the reduced step (&desired speed_model = 'weidmann'):
!> the stepper evaluates the local density of the agents the assembly reads only, each step
!> counted (density_speed_t%n_evaluated grows by size(ops%agents), not n_agents), and the speeds
!> it hands the assembly equal, at those agents, the speeds of every agent's density at the
!> reconstructed positions q0 + h V sum alpha to round-off (1e-12 relative: the same kernel
!> terms summed in another order), with the look-ahead on, in a crowd dense enough that the
!> diagram keeps well under 80% of some agents' speed. The density of a few agents alone
!> (density_of) equals every agent's density at them, with and without directions.
module test_reduced_density_ops
  use cr_kinds, only: wp
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t
  implicit none
  private
  public :: record_ops_t

  !> A fixed feasible reduced problem that records, at every step, the positions, the speeds
  !> of its agents and the density counter of the context it is handed.
  type, extends(reduced_ops_t) :: record_ops_t
    real(wp), allocatable :: vh(:)
    integer :: calls = 0
    real(wp), allocatable :: q(:,:), speeds(:,:)
    integer(8), allocatable :: counted(:)
    !> speeds of the agents the assembly does not read differ from the base speeds (any step)
    logical :: others_changed = .false.
    real(wp), allocatable :: base(:)
  contains
    procedure :: assemble
  end type record_ops_t

contains

  subroutine assemble(this, ctx, q, vhat, bt, dhat)
    class(record_ops_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    logical, allocatable :: read(:)
    this%calls = this%calls + 1
    this%q(:, this%calls) = q
    this%speeds(:, this%calls) = ctx%speeds(this%agents)
    this%counted(this%calls) = ctx%density%n_evaluated
    allocate(read(size(ctx%speeds)))
    read = .false.; read(this%agents) = .true.
    if (any(.not. read .and. ctx%speeds /= this%base)) this%others_changed = .true.
    vhat = this%vh
    if (allocated(bt)) deallocate(bt, dhat)
    allocate(bt(this%nb, 1), dhat(1))
    bt = 0; bt(1, 1) = 1
    dhat = 100
  end subroutine assemble
end module test_reduced_density_ops

program test_reduced_density
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_exit_codes, only: EXIT_FAILURE
  use cr_assert, only: check, test_summary
  use cr_config, only: scene_cfg_t, obstacles_cfg_t, desired_cfg_t
  use cr_reduced_ops, only: eval_ctx_t
  use cr_rom_stepper, only: rom_solver_cfg_t, rom_traj_t, run_trajectory, reduced_positions
  use cr_density_speed, only: density_speed_t
  use cr_random, only: rng_t
  use test_reduced_density_ops, only: record_ops_t
  implicit none
  integer, parameter :: NA = 300, NB = 4, NSTEPS = 6, NSEL = 37
  type(record_ops_t) :: ops
  type(eval_ctx_t) :: ctx
  type(rom_solver_cfg_t) :: scfg
  type(rom_traj_t) :: traj
  type(error_t), allocatable :: error
  type(desired_cfg_t) :: dc
  type(scene_cfg_t) :: sc
  type(density_speed_t) :: ref
  type(rng_t) :: rng
  real(wp) :: q0(2 * NA), vd(2 * NA), sref(NA), u(2)
  real(wp), allocatable :: qs(:,:)
  integer :: i, nu
  real(wp) :: err, fmin

  call rng%seed(38, 1)
  ! a hall of 16 m x 10 m, 300 agents (1.9 /m2 on average), the first 100 packed in 3 m x 3 m
  sc%hall_length = 16; sc%hall_width = 10; sc%l_exit = 2
  call ctx%scene%init(sc, obstacles_cfg_t(), error)
  call check(.not. allocated(error), "scene")
  if (allocated(error)) error stop EXIT_FAILURE
  do i = 1, NA
    u = [rng%uniform(), rng%uniform()]
    if (i <= 100) then
      q0(2*i-1:2*i) = [6.0_wp, 3.0_wp] + 3 * u
    else
      q0(2*i-1:2*i) = [0.5_wp, 0.5_wp] + [15.0_wp, 9.0_wp] * u
    end if
  end do
  ctx%radius = 0.2_wp; ctx%h = 0.1_wp
  ctx%speeds = [(1.0_wp + 0.002_wp * i, i = 1, NA)]
  dc%speed_model = 'weidmann'; dc%density_anisotropy = 1
  call ctx%desired%init(dc, ctx%scene, ctx%radius, NA, error)
  call check(.not. allocated(error), "desired velocity")
  if (allocated(error)) error stop EXIT_FAILURE
  call ctx%density%init(dc, NA)
  call ref%init(dc, NA)
  call check_density_of()

  ! the reduced problem: a random basis, agents read: every 8th agent (some in the packed block)
  ops%nb = NB; ops%r = 1
  allocate(ops%v(2 * NA, NB))
  do i = 1, NB
    ops%v(:, i) = [(0.3_wp * (rng%uniform() - 0.5_wp), nu = 1, 2 * NA)]
  end do
  ops%vt = transpose(ops%v)
  ops%agents = [(1 + 8 * (i - 1), i = 1, NSEL)]
  ops%m = 0
  ops%vh = [0.8_wp, -0.5_wp, 0.3_wp, 0.2_wp]
  ops%base = ctx%speeds
  allocate(ops%q(2 * NA, NSTEPS), ops%speeds(NSEL, NSTEPS), ops%counted(NSTEPS))
  call run_trajectory(ops, ctx, q0, NSTEPS, scfg, traj, error)
  call check(.not. allocated(error), "reduced trajectory: no error")
  if (allocated(error)) error stop EXIT_FAILURE
  call check(ops%calls == NSTEPS, "one assembly per step")
  ! the positions the density read: every agent, q0 + h V sum alpha
  qs = reduced_positions(q0, ops%v, traj%alpha, ctx%h)
  call check(maxval(abs(ops%q - qs(:, 1:NSTEPS))) <= 1.0e-13_wp, "every agent's reconstructed position")
  call check(maxval(abs(qs(:, NSTEPS) - q0)) > 0.1_wp, "the agents move")
  ! the density of the assembly's agents only: counted
  call check(ops%counted(1) == NSEL, "first step: the density of the assembly's agents only")
  call check(all(ops%counted(2:) - ops%counted(:NSTEPS-1) == NSEL), &
    "each step: the density of the assembly's agents only (not every agent's)")
  call check(.not. ops%others_changed, "the other agents' speeds untouched")
  ! the speeds equal those of every agent's density, at the agents read
  err = 0; fmin = 1
  do nu = 1, NSTEPS
    call ctx%desired%evaluate(ops%q(:, nu), ctx%speeds, vd)
    call ref%scale_speeds(ops%q(:, nu), vd, ctx%speeds, sref)
    err = max(err, maxval(abs(ops%speeds(:, nu) - sref(ops%agents)) / max(sref(ops%agents), tiny(1.0_wp))))
    fmin = min(fmin, minval(sref(ops%agents) / ctx%speeds(ops%agents)))
  end do
  call check(err <= 1.0e-12_wp, "speeds of the agents read = every agent's density's, to round-off")
  call check(fmin < 0.8_wp, "the diagram slows agents down (test not trivial)")
  call test_summary()

contains

  !> density_of at a few agents (one pair of coincident agents among them) equals density at
  !> every agent, with and without the look-ahead directions; both counted.
  subroutine check_density_of()
    type(density_speed_t) :: d1
    real(wp) :: rho(NA), rs(NSEL), q(2 * NA), v(2 * NA)
    integer :: sel(NSEL)
    q = q0
    q(3:4) = q(1:2)
    sel = [(1 + 8 * (i - 1), i = 1, NSEL)]
    sel(2) = 2
    call d1%init(dc, NA)
    call ctx%desired%evaluate(q, ctx%speeds, v)
    call d1%density(q, rho, v)
    call check(d1%n_evaluated == NA, "density: every agent counted")
    call d1%density_of(q, sel, rs, v)
    call check(d1%n_evaluated == NA + NSEL, "density_of: the listed agents counted")
    call check(maxval(abs(rs - rho(sel)) / rho(sel)) <= 1.0e-12_wp, "density_of = density, look-ahead")
    call check(maxval(rho(sel)) > 2.5_wp, "a dense agent among the listed")
    call d1%density(q, rho)
    call d1%density_of(q, sel, rs)
    call check(maxval(abs(rs - rho(sel)) / rho(sel)) <= 1.0e-12_wp, "density_of = density, isotropic")
    call d1%free()
  end subroutine check_density_of
end program test_reduced_density
