!> The full-order model: time stepping of the crowd (the paper's scheme, section 2.1).
!>
!> Step nu: v = desired(q^{nu-1}); u^nu = projection of v onto
!> { u : D_l(q) + h G_l(q) . u >= 0 for every contact l }; q^nu = q^{nu-1} + h u^nu.
!> Only contacts that can become active during the step are rows. Each agent has a margin m_i,
!> how far it may close a gap in the step: m_i = cutoff_factor h s_i with s_i = max_j |v_j| on
!> the first step and s_i = min(max_j |v_j|, |u_i| + speed_allowance |v_i|) after it (u: the
!> previous step's velocity), so that a jammed agent, which barely moves, does not bring in
!> every pair its desired speed could reach. Candidates: agent pairs with gap <= m_a + m_b,
!> agent-obstacle pairs with gap <= 2 m_a. After the solve, a pair left out with gap
!> <= h (|u_a| + |u_b|) (an obstacle: gap <= h |u_a|) could be violated (rows_missing): the
!> margins grow to 1.05 h |u_i| where they fall short, the set is rebuilt and the step
!> re-solved (warm started), so that the linearised constraint holds for *every* pair and
!> obstacle.
!> Multipliers are warm-started across steps by contact identity.
!>
!> Behaviour options (defaults off: the paper's model): with a social distance d_s (&agents)
!> the contacts use the radius r + d_s / 2 (two agents stop at gap d_s, an agent stops at d_s / 2
!> from an obstacle), and so do the aiming at the exits and the random placement; "out of the
!> hall" keeps the body radius r. With &desired speed_model = 'weidmann' each agent's desired velocity is scaled by
!> the fundamental diagram of its local density at the start of the step (cr_density_speed).
module cr_fom
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_config, only: config_t, agents_cfg_t
  use cr_scene, only: scene_t
  use cr_desired, only: desired_t
  use cr_density_speed, only: density_speed_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts, rows_missing
  use cr_placement, only: place_agents
  use cr_projection, only: projection_solver_t, solve_stats_t, make_projection_solver
  use cr_key_map, only: key_map_t
  use cr_fom_state, only: fom_state_t, step_record_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: fom_t, step_record_t

  !> State of a full-order simulation: what the output holds (fom_state_t: scene, rows,
  !> positions, velocities, multipliers, inside flags) and what the stepping keeps.
  type, extends(fom_state_t) :: fom_t
    type(desired_t) :: desired
    class(projection_solver_t), allocatable :: solver
    type(cell_list_t) :: cells
    real(wp) :: cutoff_factor = 1.5_wp
    !> density-dependent desired speed (off: the speeds c_i as given)
    type(density_speed_t) :: density
    !> share of the desired speed added to the previous speed in the margins (a predictor only: any
    !> value >= 0 is exact, the check after the solve adds what it misses). Measured
    !> (docs/benchmarks.md#tuned-parameters-of-sparse_active_set, speed_allowance): 0.4-0.6 take the
    !> least solver time on congested150 and congested1000; 0.2 re-solves more and 0.8 keeps more
    !> rows
    real(wp) :: speed_allowance = 0.5_wp
    logical :: warm_start = .true.
    !> candidate-row margin of each agent in the current step, and h |u_i| [n_agents]
    real(wp), allocatable :: margin(:), need(:)
    !> the warm start of the current solve (for step_record_t%n_changes)
    real(wp), allocatable :: lambda_warm(:)
    !> multipliers of the previous step's rows by identity (warm start), and the identities
    !> of the current rows [>= cs%n]
    type(key_map_t) :: prev
    integer(i8), allocatable :: keys(:)
    integer :: placement_iterations = 0
  contains
    procedure :: init
    procedure :: advance
    procedure :: n_inside
  end type fom_t

contains

  !> Build scene, desired velocity and solver from `cfg`; place the agents (or take q0).
  subroutine init(this, cfg, error, q0, speeds)
    class(fom_t), intent(inout) :: this
    type(config_t), intent(in) :: cfg
    type(error_t), allocatable, intent(out) :: error
    !> initial positions [2*n_agents] (default: from &agents)
    real(wp), intent(in), optional :: q0(:)
    !> per-agent speeds [n_agents] (default: &agents speed / speed_file)
    real(wp), intent(in), optional :: speeds(:)
    integer :: i
    type(agents_cfg_t) :: agents_cfg
    this%n_agents = cfg%agents%n_agents
    this%radius = cfg%agents%radius
    this%contact_radius = cfg%agents%radius + cfg%agents%social_distance / 2
    this%dt = cfg%time%dt
    this%cutoff_factor = cfg%contacts%cutoff_factor
    this%warm_start = cfg%solver%warm_start
    this%step = 0
    call this%scene%init(cfg%scene, cfg%obstacles, error)
    if (allocated(error)) return
    call this%desired%init(cfg%desired, this%scene, this%contact_radius, this%n_agents, error)
    if (allocated(error)) return
    call make_projection_solver(cfg%solver, this%solver, error)
    if (allocated(error)) return
    if (present(q0)) then
      if (size(q0) /= 2 * this%n_agents) then
        call set_error(error, "fom: q0 has " // str(size(q0)) // " entries, expected 2 * n_agents = " // &
          str(2 * this%n_agents)); return
      end if
      this%q = q0
    else
      ! with a social distance the agents are placed with their contact radius (a start
      ! that keeps d_s: from a start that does not, the first steps push a dense crowd apart)
      agents_cfg = cfg%agents
      agents_cfg%radius = this%contact_radius
      call place_agents(agents_cfg, this%scene, this%q, this%placement_iterations, error)
      if (allocated(error)) return
    end if
    allocate(this%speeds(this%n_agents))
    if (present(speeds)) then
      if (size(speeds) /= this%n_agents) then
        call set_error(error, "fom: speeds has " // str(size(speeds)) // " entries, expected n_agents = " // &
          str(this%n_agents)); return
      end if
      this%speeds = speeds
    else if (len_trim(cfg%agents%speed_file) > 0) then
      call read_speeds(trim(cfg%agents%speed_file), this%speeds, error)
      if (allocated(error)) return
    else
      this%speeds = cfg%agents%speed
    end if
    call this%density%init(cfg%desired, this%n_agents)
    allocate(this%v(2 * this%n_agents), this%u(2 * this%n_agents), this%inside(this%n_agents))
    allocate(this%margin(this%n_agents), this%need(this%n_agents))
    this%v = 0; this%u = 0
    do i = 1, this%n_agents
      this%inside(i) = .not. this%scene%is_out(this%q(2*i-1:2*i), this%radius)
    end do
    call this%cs%init(this%n_agents, this%dt, 8 * this%n_agents)
    allocate(this%lambda(0))
    call this%prev%init()
  end subroutine init

  !> Number of agents that have not left the hall.
  pure integer function n_inside(this)
    class(fom_t), intent(in) :: this
    n_inside = count(this%inside)
  end function n_inside

  !> Advance one time step; `rec` reports what happened.
  subroutine advance(this, rec, error)
    class(fom_t), intent(inout) :: this
    type(step_record_t), intent(out) :: rec
    type(error_t), allocatable, intent(out) :: error
    type(solve_stats_t) :: st
    real(wp) :: vmax, floor_m, d(2), dist
    integer(8) :: c0, c1, c2, rate
    integer :: i, l, a, b
    call system_clock(c0, rate)
    this%step = this%step + 1
    rec%step = this%step
    call this%desired%evaluate(this%q, this%speeds, this%v)
    if (this%density%on) call this%density%apply(this%q, this%v)
    ! each agent's margin: how far it may close a gap in this step, bounded from its speed in
    ! the previous step (cutoff_factor * h * (|u_i| + speed_allowance |v_i|)); on the first
    ! step, from the fastest desired speed (cutoff_factor * h * max |v|)
    vmax = 0
    do i = 1, this%n_agents
      vmax = max(vmax, norm2(this%v(2*i-1:2*i)))
    end do
    floor_m = 0.5e-12_wp * this%contact_radius
    do i = 1, this%n_agents
      if (this%step == 1) then
        this%margin(i) = this%cutoff_factor * this%dt * vmax
      else
        this%margin(i) = this%cutoff_factor * this%dt * min(vmax, norm2(this%u(2*i-1:2*i)) + &
          this%speed_allowance * norm2(this%v(2*i-1:2*i)))
      end if
      this%margin(i) = max(this%margin(i), floor_m)
    end do
    rec%t_solve = 0
    do
      call build_contacts(this%scene, this%q, this%contact_radius, 2 * maxval(this%margin), this%cells, this%cs, &
        margin=this%margin)
      call warm_start_multipliers(this)
      this%lambda_warm = this%lambda(1:this%cs%n)
      call system_clock(c1)
      call this%solver%solve(this%cs, this%v, this%u, this%lambda, st, error)
      call system_clock(c2)
      rec%n_changes = count((this%lambda_warm > 0.0_wp) .neqv. (this%lambda(1:this%cs%n) > 0.0_wp))
      rec%t_solve = rec%t_solve + real(c2 - c1, wp) / real(rate, wp)
      if (allocated(error)) then
        call prefix_error(error, "fom: step " // str(this%step)); return
      end if
      rec%iterations = rec%iterations + st%iterations
      rec%n_factor = rec%n_factor + st%n_factor
      rec%n_modify = rec%n_modify + st%n_modify
      rec%n_fallback = rec%n_fallback + st%n_fallback
      ! a pair left out could only be violated if its gap < h (|u_a| + |u_b|) (an obstacle:
      ! h |u_a|): re-solve with larger margins if the solution reaches such a pair
      do i = 1, this%n_agents
        this%need(i) = this%dt * norm2(this%u(2*i-1:2*i))
      end do
      if (.not. rows_missing(this%scene, this%q, this%contact_radius, this%cells, this%margin, this%need)) exit
      rec%resolves = rec%resolves + 1
      do i = 1, this%n_agents
        this%margin(i) = max(this%margin(i), 1.05_wp * this%need(i))
      end do
      call remember_multipliers(this)
      if (rec%resolves > 50) then
        call set_error(error, "fom: step " // str(this%step) // ": contact set did not stabilise after 50 re-solves")
        return
      end if
    end do
    rec%converged = st%converged .and. st%kkt <= this%solver%settings%tol
    rec%primal = st%primal; rec%dual = st%dual; rec%compl = st%compl; rec%stat = st%stat
    rec%kkt = st%kkt
    rec%n_rows = this%cs%n
    rec%n_active = count(this%lambda(1:this%cs%n) > 0)
    call remember_multipliers(this)
    this%q = this%q + this%dt * this%u
    ! true gaps of the candidate rows after the step (of the contact radius)
    rec%min_gap = huge(1.0_wp)
    do l = 1, this%cs%n
      a = this%cs%ia(l); b = this%cs%ib(l)
      if (b > 0) then
        d = this%q(2*a-1:2*a) - this%q(2*b-1:2*b)
        dist = norm2(d) - 2 * this%contact_radius
        rec%min_gap = min(rec%min_gap, dist)
      end if
    end do
    call obstacle_gaps(this, rec%min_gap)
    do i = 1, this%n_agents
      if (this%scene%is_out(this%q(2*i-1:2*i), this%radius)) this%inside(i) = .false.
    end do
    rec%n_inside = count(this%inside)
    call system_clock(c2)
    rec%t_step = real(c2 - c0, wp) / real(rate, wp)
  end subroutine advance

  !> Smallest agent-obstacle gap over the current rows at the new positions.
  subroutine obstacle_gaps(this, gmin)
    use cr_shapes, only: obstacle_distance
    type(fom_t), intent(in) :: this
    real(wp), intent(inout) :: gmin
    integer :: l, a
    real(wp) :: dist, nrm(2)
    do l = 1, this%cs%n
      if (this%cs%ib(l) == 0) then
        a = this%cs%ia(l)
        call obstacle_distance(this%scene%obstacles(this%cs%ob(l)), this%q(2*a-1:2*a), dist, nrm)
        gmin = min(gmin, dist - this%contact_radius)
      end if
    end do
  end subroutine obstacle_gaps

  !> Initial multipliers of the current rows from the previous ones, matched by identity.
  subroutine warm_start_multipliers(this)
    type(fom_t), intent(inout) :: this
    integer :: n
    n = this%cs%n
    if (allocated(this%lambda)) then
      if (size(this%lambda) /= n) deallocate(this%lambda)
    end if
    if (.not. allocated(this%lambda)) allocate(this%lambda(n))
    if (allocated(this%keys)) then
      if (size(this%keys) < n) deallocate(this%keys)
    end if
    if (.not. allocated(this%keys)) allocate(this%keys(max(2 * n, 16)))
    call this%cs%keys_of(this%keys)
    if (.not. this%warm_start) then
      this%lambda = 0
      return
    end if
    call this%prev%lookup(this%keys(1:n), this%lambda, 0.0_wp)
  end subroutine warm_start_multipliers

  !> Keep the current multipliers by identity for the next warm start.
  subroutine remember_multipliers(this)
    type(fom_t), intent(inout) :: this
    call this%prev%fill(this%keys(1:this%cs%n), this%lambda(1:this%cs%n))
  end subroutine remember_multipliers

  !> Read n_agents speeds (one per line).
  subroutine read_speeds(path, speeds, error)
    character(len=*), intent(in) :: path
    real(wp), intent(out) :: speeds(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: u, ios, k
    character(len=256) :: msg
    open(newunit=u, file=path, status='old', action='read', iostat=ios, iomsg=msg)
    if (ios /= 0) then
      call set_error(error, "&agents: speed_file: cannot open '" // path // "' (" // trim(msg) // ")", EXIT_BAD_INPUT)
      return
    end if
    do k = 1, size(speeds)
      read(u, *, iostat=ios, iomsg=msg) speeds(k)
      if (ios /= 0) then
        call set_error(error, "&agents: speed_file: '" // path // "' line " // str(k) // &
          ": expected one speed per agent for n_agents = " // str(size(speeds)), EXIT_BAD_INPUT)
        close(u); return
      end if
      if (.not. (speeds(k) >= 0 .and. speeds(k) < huge(1.0_wp))) then
        call set_error(error, "&agents: speed_file: '" // path // "' line " // str(k) // &
          ": speed must be finite and >= 0", EXIT_BAD_INPUT)
        close(u); return
      end if
    end do
    close(u)
  end subroutine read_speeds
end module cr_fom
