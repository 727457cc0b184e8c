!> Exact position projection (docs/model.md#exact-position-projection): the closest configuration
!> without overlap to given positions q_in [2 n_a] (agents of radius r in a scene),
!>   q_out = argmin |q - q_in|^2  s.t.  every gap (agent-agent, agent-obstacle) >= 0,
!> solved as projections of the full model's kind (h = 1) with its exact solver (the &solver
!> factory). The gaps of two disks and of a disk and a convex obstacle are convex in the
!> positions, so a linearised gap D_l(p) + G_l(p) . u is a lower bound of the true gap at p + u:
!> a displacement that satisfies the linearised rows leaves no overlap deeper than the solver's
!> primal residual.
!>
!> 1. Start. Without a start: one projection linearised at q_in (desired displacement 0),
!>    u = argmin |u|^2 s.t. D_l(q_in) + G_l(q_in) . u >= 0, p = q_in + u (the first-order
!>    projection; two overlapping disks move apart by half the overlap each). With a start
!>    q_start (a configuration without overlap, e.g. the projection of the previous time step)
!>    p = q_start; this is what makes deep, piled-up overlaps tractable: linearised at q_in the
!>    rows of agents jammed into a wall or into each other can be infeasible (measured: agents
!>    of ML-corrected hall20 positions inside the barrier walls of the exit).
!>    From a start, the first-order projection is the first projection of step 2 (towards q_in).
!> 2. Refinement (sequential convex projections): from the configuration p without overlap,
!>    repeat u = argmin |u - (q_in - p)|^2 s.t. D_l(p) + G_l(p) . u >= 0, p = p + u, until
!>    max_i |u_i| <= refine_tol * r (or refine_max times). u = 0 is feasible, so every iterate has
!>    no overlap and is closer to q_in than the one before; a fixed point is a KKT point of the
!>    (non-convex) projection itself, not of its linearisation.
!>
!> One projection linearised at p with desired displacement w (0 or q_in - p), exact over every
!> agent, in one solve of the exact solver warm started from the multipliers of the previous
!> solve (the previous configuration's, matched by row identity):
!> - candidate rows: each agent has a reach rho_i = cutoff_factor * max(|w_i|, deepest overlap of
!>   p, 3 mean_j |w_j|); every agent pair with gap <= rho_a + rho_b and agent-obstacle pair with
!>   gap <= rho_a (one cell-list pass with the cutoff 2 min rho, then a scan for the few far
!>   movers: no O(n_a^2) rows because one agent must move metres). After the solve an agent
!>   that moved further than its reach widens it and the rows are rebuilt (a row beyond the
!>   reaches cannot close: gap > rho_a + rho_b >= |u_a| + |u_b|), as the full model's cutoff;
!> - rows of the solve: the candidate rows that w violates with gap <= 0.05 min rho (the
!>   touching ones) and the rows active in the previous solve; after the solve every other
!>   candidate row the solution violates is added and the problem solved again (warm), until
!>   none is: then the solution of the rows kept is the solution over all of them (feasible for
!>   all, optimal for fewer), and the agents that no kept row touches move exactly by w.
!>   Starting with every violated row instead makes the rows of an agent that must move metres
!>   through the crowd enter first (the most violated) and costs 2.5x more (crowd1000 benchmark).
!> A configuration without overlap is returned unchanged (bit for bit) without a solve.
!> The solver and the local problem (here with every agent free) are cr_local_projection's
!> (shared with the local correction of a reduced velocity, cr_local_correction).
module cr_position_projection
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: build_contacts, cell_list_t, pair_contact
  use cr_projection, only: projection_settings_t, solve_stats_t
  use cr_local_projection, only: local_projection_t, max_agent_norm, lin_gap
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: position_projection_t, pproj_stats_t

  !> What one projection did.
  type :: pproj_stats_t
    !> overlapping rows of q_in; agents that moved; agents whose motion the rows changed
    !> (largest over the solves)
    integer :: n_overlaps = 0, n_moved = 0, n_free = 0
    !> candidate rows (last contact set) and rows of the last local problem
    integer :: n_rows = 0, n_local_rows = 0
    !> solves, solver iterations (summed), re-solves with more rows or wider reaches,
    !> refinement projections
    integer :: solves = 0, iterations = 0, restarts = 0, refines = 0
    !> the refinement stopped on its tolerance (not on refine_max or a failed solve)
    logical :: refined = .true.
    !> deepest overlap of q_in [m]; |q_out - q_in|_2 and max_i |q_out,i - q_in,i| [m]
    real(wp) :: depth_in = 0, displacement = 0, max_move = 0
    !> scaled KKT residual of the last solve (0 when nothing was solved)
    real(wp) :: kkt = 0
    !> wall-clock time of the call [s]
    real(wp) :: t_total = 0
  end type pproj_stats_t

  !> Position projection; holds the exact solver and work space across calls.
  type :: position_projection_t
    !> the exact solver, the rows kept for the solve (this%lp%cs, h = 1) and the local problem
    type(local_projection_t) :: lp
    !> refinement: at most refine_max projections, stopped when max_i |u_i| <= refine_tol * radius
    integer :: refine_max = 50
    real(wp) :: refine_tol = 1.0e-6_wp
    !> every candidate row within the agents' reaches; the rows of the far movers' pass
    type(contact_set_t) :: cs_all, cs_far
    !> cell list of the far movers' pass
    type(cell_list_t) :: cells_far
  contains
    procedure :: init
    procedure :: free
    procedure :: project
  end type position_projection_t

contains

  !> Build the exact solver from `settings` (the full model's &solver) and keep the full
  !> model's cutoff factor (&contacts cutoff_factor, >= 1).
  !> refine_max (default 50; 0: the first-order projection only) and refine_tol (default 1e-6)
  !> set the refinement (module header).
  subroutine init(this, settings, cutoff_factor, error, refine_max, refine_tol)
    class(position_projection_t), intent(inout) :: this
    type(projection_settings_t), intent(in) :: settings
    real(wp), intent(in) :: cutoff_factor
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: refine_max
    real(wp), intent(in), optional :: refine_tol
    call this%free()
    if (present(refine_max)) this%refine_max = refine_max
    if (present(refine_tol)) this%refine_tol = refine_tol
    if (this%refine_max < 0 .or. .not. (this%refine_tol > 0 .and. this%refine_tol < 1)) then
      call set_error(error, "position_projection: refine_max must be >= 0 and refine_tol in (0, 1)", EXIT_BAD_INPUT); return
    end if
    call this%lp%init("position_projection", settings, cutoff_factor, error, warm_start=.true.)
  end subroutine init

  subroutine free(this)
    class(position_projection_t), intent(inout) :: this
    call this%lp%free()
    call this%cs_all%free()
    call this%cs_far%free()
    this%cells_far = cell_list_t()
  end subroutine free

  !> q_out [2 n_a]: the projection of q_in [2 n_a] (agents of radius `radius` in `scene`)
  !> onto the configurations without overlap (module header); q_start [2 n_a]: an optional
  !> start without overlap. error for inconsistent sizes, non-finite input, a start that
  !> overlaps, or a first-order projection the solver cannot meet with every agent free.
  subroutine project(this, scene, radius, q_in, q_out, stats, error, q_start)
    class(position_projection_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q_in(:)
    real(wp), intent(out) :: q_out(:)
    type(pproj_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(in), optional :: q_start(:)
    integer(8) :: c0, c1, rate
    integer :: na, i, l, k, n0
    real(wp), allocatable :: p(:), u(:), w(:)
    real(wp) :: depth_start
    logical :: ok
    call system_clock(c0, rate)
    if (.not. allocated(this%lp%solver)) then
      call set_error(error, "position_projection: project called before init"); return
    end if
    na = size(q_in) / 2
    if (size(q_in) /= 2 * na .or. size(q_out) /= size(q_in)) then
      call set_error(error, "position_projection: inconsistent sizes: q_in " // str(size(q_in)) // &
        ", q_out " // str(size(q_out)), EXIT_BAD_INPUT); return
    end if
    if (.not. (ieee_is_finite(radius) .and. radius > 0) .or. .not. all(ieee_is_finite(q_in))) then
      call set_error(error, "position_projection: radius must be finite and > 0, positions finite", EXIT_BAD_INPUT); return
    end if
    if (present(q_start)) then
      if (size(q_start) /= size(q_in) .or. .not. all(ieee_is_finite(q_start))) then
        call set_error(error, "position_projection: q_start must have " // str(size(q_in)) // &
          " finite entries", EXIT_BAD_INPUT); return
      end if
    end if
    q_out = q_in
    call this%lp%prepare(na, 1.0_wp)
    if (this%cs_all%n_agents /= na .or. .not. allocated(this%cs_all%ia)) call this%cs_all%init(na, 1.0_wp, 8 * na)
    ! -- overlaps of q_in
    call build_contacts(scene, q_in, radius, 1.0e-12_wp * radius, this%lp%cells, this%lp%cs)
    do l = 1, this%lp%cs%n
      if (this%lp%cs%gap(l) < 0) then
        stats%n_overlaps = stats%n_overlaps + 1
        stats%depth_in = max(stats%depth_in, -this%lp%cs%gap(l))
      end if
    end do
    stats%n_rows = this%lp%cs%n
    if (stats%n_overlaps == 0) then
      call finish(); return
    end if
    allocate(u(2 * na), w(2 * na))
    ! -- start: q_start, or the first-order projection linearised at q_in
    if (present(q_start)) then
      p = q_start
      call build_contacts(scene, p, radius, 1.0e-12_wp * radius, this%lp%cells, this%lp%cs)
      depth_start = 0
      do l = 1, this%lp%cs%n
        depth_start = max(depth_start, -this%lp%cs%gap(l))
      end do
      if (depth_start > max(this%lp%solver%settings%tol, 1.0e-9_wp) * radius) then
        call set_error(error, "position_projection: the start overlaps by " // str(depth_start, "es9.2") // &
          " m", EXIT_BAD_INPUT); return
      end if
    else
      ! a configuration on its own: no multipliers carried over from another one
      call this%lp%reset()
      p = q_in
      w = 0
      call solve_at(this, scene, radius, p, w, u, ok, stats, error)
      if (allocated(error)) return
      if (.not. ok) then
        call set_error(error, "position_projection: the projection with every agent free did not " // &
          "reach the tolerance (KKT residual " // str(stats%kkt, "es9.2") // ", " // str(stats%n_overlaps) // &
          " overlapping pairs, deepest " // str(stats%depth_in, "es9.2") // " m; a start without overlap " // &
          "makes it tractable)"); return
      end if
      p = p + u
    end if
    ! -- refinement: projections linearised at p towards q_in; every iterate without overlap.
    ! From a start, the first of them is the first-order projection (not counted as refinement).
    n0 = merge(1, 0, present(q_start))
    stats%refined = this%refine_max == 0
    do k = 1, this%refine_max + n0
      w = q_in - p
      call solve_at(this, scene, radius, p, w, u, ok, stats, error)
      if (allocated(error)) return
      if (.not. ok) exit
      stats%refines = k - n0
      ! agents that got the wanted move are exactly at q_in (p + (q_in - p) may round off)
      do i = 1, na
        if (all(u(2*i-1:2*i) == w(2*i-1:2*i))) then
          p(2*i-1:2*i) = q_in(2*i-1:2*i)
        else
          p(2*i-1:2*i) = p(2*i-1:2*i) + u(2*i-1:2*i)
        end if
      end do
      if (maxval(abs(u)) <= this%refine_tol * radius) then
        stats%refined = .true.; exit
      end if
    end do
    q_out = p
    u = q_out - q_in
    stats%displacement = norm2(u)
    do i = 1, na
      stats%max_move = max(stats%max_move, norm2(u(2*i-1:2*i)))
      if (any(u(2*i-1:2*i) /= 0)) stats%n_moved = stats%n_moved + 1
    end do
    call finish()

  contains

    subroutine finish()
      call system_clock(c1)
      stats%t_total = real(c1 - c0, wp) / real(rate, wp)
    end subroutine finish
  end subroutine project

  !> u [2 n_a] = argmin |u - w|^2 s.t. D_l(p) + G_l(p) . u >= 0 for every row (h = 1), one
  !> exact solve over every agent on the rows that can close (module header), warm started from
  !> the multipliers of the previous solve. ok: the last solve met the tolerance.
  subroutine solve_at(this, scene, radius, p, w, u, ok, stats, error)
    type(position_projection_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, p(:), w(:)
    real(wp), intent(out) :: u(:)
    logical, intent(out) :: ok
    type(pproj_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer :: na, i, l, restarts, n_violated
    real(wp) :: depth, rho_min, un, near
    real(wp), allocatable :: lam(:), wn(:), rho(:)
    logical, allocatable :: free_ag(:), kept(:)
    logical :: added
    type(solve_stats_t) :: st
    na = size(p) / 2
    allocate(free_ag(na), wn(na), rho(na))
    ok = .true.
    associate (lp => this%lp, cs => this%lp%cs, cs_all => this%cs_all)
      ! the motion to expect of each agent: its wanted one, or the deepest overlap of p
      call build_contacts(scene, p, radius, 1.0e-12_wp * radius, lp%cells, cs)
      depth = 0
      do l = 1, cs%n
        depth = max(depth, -cs%gap(l))
      end do
      do i = 1, na
        wn(i) = norm2(w(2*i-1:2*i))
      end do
      ! reach of agent i: cutoff_factor x its expected motion, at least cutoff_factor x three
      ! times the mean motion (a few agents that must move metres do not widen every agent's)
      rho_min = lp%cutoff_factor * max(depth, 3 * sum(wn) / max(na, 1), 1.0e-12_wp * radius)
      rho = max(lp%cutoff_factor * wn, rho_min)
      ! rows the solve starts with: those that w violates among the near ones (gap <= near)
      ! and those active in the previous solve; the rows of a far mover beyond its neighbours
      ! enter only when the solution still violates them (measured on the crowd1000 benchmark:
      ! starting with every violated row makes the rows of agents that must move metres through
      ! the crowd enter first, as the most violated, and costs 2.5x more)
      near = 0.05_wp * rho_min
      restarts = 0
      do
        ! every row that can close: gap <= rho_a + rho_b (pairs), gap <= rho_a (obstacles);
        ! the solve keeps the rows that w violates, the others are checked after the solve and
        ! added when the solution violates them (then the solution of the kept rows is the
        ! solution of all of them: it is feasible for all and optimal for fewer)
        call candidate_rows(this, scene, radius, p, rho, rho_min)
        stats%n_rows = cs_all%n
        if (allocated(kept)) deallocate(kept)
        allocate(kept(cs_all%n))
        do l = 1, cs_all%n
          kept(l) = cs_all%gap(l) <= near .and. lin_gap(cs_all, l, w) < 0
        end do
        ! and the rows active in the previous solve (the warm start's; their multipliers are
        ! the solver's start)
        if (lp%prev%n > 0) then
          do l = 1, cs_all%n
            if (kept(l)) cycle
            kept(l) = lp%prev%get(cs_all%key(l), 0.0_wp) > 0
          end do
        end if
        do
          call cs%clear()
          do l = 1, cs_all%n
            if (kept(l)) call cs%add(cs_all%ia(l), cs_all%ib(l), cs_all%ob(l), cs_all%g(:, l), cs_all%gap(l))
          end do
          if (cs%n == 0) then
            u = w
          else
            ! every agent free: the rows that w satisfies with room to spare cost the solver
            ! next to nothing, and the problem is feasible whenever p has no overlap (u = 0)
            free_ag = .true.
            call lp%solve_local(free_ag, w, u, lam, ok, st, error)
            if (allocated(error)) return
            stats%n_local_rows = lp%cs_loc%n
            stats%solves = stats%solves + 1
            stats%iterations = stats%iterations + st%iterations
            stats%kkt = st%kkt
            if (.not. ok) return
          end if
          ! a row left out that the solution violates: keep it and solve again
          added = .false.
          do l = 1, cs_all%n
            if (kept(l)) cycle
            if (lin_gap(cs_all, l, u) < 0) then
              kept(l) = .true.; added = .true.
            end if
          end do
          if (.not. added) exit
          stats%restarts = stats%restarts + 1
        end do
        ! a row outside the candidates has gap > rho_a + rho_b and cannot close while every
        ! agent moves within its reach; an agent that moved further widens its reach
        added = .false.
        do i = 1, na
          un = norm2(u(2*i-1:2*i))
          if (un > rho(i)) then
            rho(i) = 1.05_wp * lp%cutoff_factor * un; added = .true.
          end if
        end do
        if (.not. added) exit
        restarts = restarts + 1
        stats%restarts = stats%restarts + 1
        if (restarts > 50) then
          call set_error(error, "position_projection: the candidate rows did not stabilise after 50 restarts")
          return
        end if
      end do
    end associate
    ! agents whose motion the rows changed
    n_violated = 0
    do i = 1, na
      if (any(u(2*i-1:2*i) /= w(2*i-1:2*i))) n_violated = n_violated + 1
    end do
    stats%n_free = max(stats%n_free, n_violated)
  end subroutine solve_at

  !> this%cs_all: every agent pair with gap <= rho_a + rho_b and every agent-obstacle pair
  !> with gap <= rho_a at p [2 n_a] (rho [n_a] >= rho_min > 0, the agents' reaches; h = 1). One
  !> cell-list pass with the cutoff 2 rho_min, then for the few far movers (rho_a > rho_min)
  !> the pairs beyond it: agents by a scan of all agents, obstacles by a cell-list pass over
  !> the far movers only. Cost O(n_a + n_far n_a) instead of the O(n_a^2) rows of one cutoff
  !> set by the farthest mover.
  subroutine candidate_rows(this, scene, radius, p, rho, rho_min)
    type(position_projection_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, p(:), rho(:), rho_min
    integer :: na, a, b, l, ia, ib
    real(wp) :: c0, dx, dy, gap, g(2)
    logical, allocatable :: far(:)
    na = size(rho)
    c0 = 2 * rho_min
    call build_contacts(scene, p, radius, c0, this%lp%cells, this%cs_all)
    far = rho > rho_min
    if (.not. any(far)) return
    do a = 1, na
      if (.not. far(a)) cycle
      do b = 1, na
        if (b == a) cycle
        if (far(b) .and. b < a) cycle   ! a pair of two far movers once
        dx = p(2*a-1) - p(2*b-1); dy = p(2*a) - p(2*b)
        if (abs(dx) > rho(a) + rho(b) + 2 * radius .or. abs(dy) > rho(a) + rho(b) + 2 * radius) cycle
        ia = min(a, b); ib = max(a, b)
        call pair_contact(p(2*ia-1) - p(2*ib-1), p(2*ia) - p(2*ib), radius, g, gap)
        if (gap <= c0 .or. gap > rho(a) + rho(b)) cycle
        call this%cs_all%add(ia, ib, 0, g, gap)
      end do
    end do
    if (this%cs_far%n_agents /= na .or. .not. allocated(this%cs_far%ia)) call this%cs_far%init(na, 1.0_wp, 64)
    call build_contacts(scene, p, radius, maxval(rho, mask=far), this%cells_far, this%cs_far, active=far)
    do l = 1, this%cs_far%n
      a = this%cs_far%ia(l)
      if (this%cs_far%ib(l) /= 0) cycle
      if (this%cs_far%gap(l) <= c0 .or. this%cs_far%gap(l) > rho(a)) cycle
      call this%cs_all%add(a, 0, this%cs_far%ob(l), this%cs_far%g(:, l), this%cs_far%gap(l))
    end do
  end subroutine candidate_rows
end module cr_position_projection
