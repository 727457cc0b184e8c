!> Exact position projection (issue 14 item 4, ML part): the closest configuration without
!> overlap to given positions q_in [2 n_a] (agents of radius r in a scene),
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
!> One projection linearised at p with desired displacement w (0 or q_in - p): rows are every
!> pair and agent-obstacle pair whose gap at p is <= cutoff (cutoff_factor * 2 max(|w|_inf,
!> deepest overlap)); after the solve, if 2 max_i |u_i| exceeds the cutoff (a pair outside the set
!> could then touch), the set is rebuilt with the larger cutoff and re-solved, as in the full
!> model's step. Only agents in conflict are solved for: the agents of the rows that w violates
!> are free, the others move by w, and a row between a free and a fixed agent becomes a
!> one-agent row of the free agent (gap shifted by the fixed agent's motion). If such a row is
!> active (multiplier > 0) after the solve, the fixed agent is freed and the problem re-solved,
!> until no coupling row is active: then the fixed agents satisfy the full problem's KKT
!> conditions (u = w, zero multipliers), so the result is the projection over *all* agents, not
!> a local approximation. A local problem the solver cannot meet frees one ring of neighbours.
!> A configuration without overlap is returned unchanged (bit for bit) without a solve.
!> The solver, the candidate rows, the rings and the local problem are cr_local_projection's
!> (shared with the local correction of a reduced velocity, cr_local_correction).
module cr_position_projection
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: build_contacts
  use cr_projection, only: projection_settings_t, solve_stats_t
  use cr_local_projection, only: local_projection_t, max_agent_norm
  implicit none
  private
  public :: position_projection_t, pproj_stats_t

  !> What one projection did.
  type :: pproj_stats_t
    !> overlapping rows of q_in; agents that moved; agents free in the last solve
    integer :: n_overlaps = 0, n_moved = 0, n_free = 0
    !> candidate rows (last contact set) and rows of the last local problem
    integer :: n_rows = 0, n_local_rows = 0
    !> solves, solver iterations (summed), growths of the free set, cutoff restarts,
    !> refinement projections
    integer :: solves = 0, iterations = 0, grows = 0, restarts = 0, refines = 0
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
    !> every candidate row within the cutoff
    type(contact_set_t) :: cs_all
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
      call set_error(error, "position_projection: refine_max must be >= 0 and refine_tol in (0, 1)", 2); return
    end if
    call this%lp%init("position_projection", settings, cutoff_factor, error)
  end subroutine init

  subroutine free(this)
    class(position_projection_t), intent(inout) :: this
    call this%lp%free()
    call this%cs_all%free()
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
        ", q_out " // str(size(q_out)), 2); return
    end if
    if (.not. (ieee_is_finite(radius) .and. radius > 0) .or. .not. all(ieee_is_finite(q_in))) then
      call set_error(error, "position_projection: radius must be finite and > 0, positions finite", 2); return
    end if
    if (present(q_start)) then
      if (size(q_start) /= size(q_in) .or. .not. all(ieee_is_finite(q_start))) then
        call set_error(error, "position_projection: q_start must have " // str(size(q_in)) // &
          " finite entries", 2); return
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
          " m", 2); return
      end if
    else
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

  !> u [2 n_a] = argmin |u - w|^2 s.t. D_l(p) + G_l(p) . u >= 0 for every row (h = 1), solved for
  !> the agents in conflict only (module header). ok: the last local solve met the tolerance.
  subroutine solve_at(this, scene, radius, p, w, u, ok, stats, error)
    type(position_projection_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, p(:), w(:)
    real(wp), intent(out) :: u(:)
    logical, intent(out) :: ok
    type(pproj_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer :: na, i, l, a, b, restarts, n_violated
    real(wp) :: cutoff, depth, reach
    real(wp), allocatable :: lam(:), wn(:)
    logical, allocatable :: free_ag(:), kept(:)
    logical :: added, done
    type(solve_stats_t) :: st
    na = size(p) / 2
    allocate(free_ag(na))
    ok = .true.
    associate (lp => this%lp, cs => this%lp%cs, cs_all => this%cs_all)
      ! the largest motion to expect: the wanted one, or the deepest overlap of p
      call build_contacts(scene, p, radius, 1.0e-12_wp * radius, lp%cells, cs)
      depth = 0
      do l = 1, cs%n
        depth = max(depth, -cs%gap(l))
      end do
      cutoff = max(lp%cutoff_factor * 2 * max(max_agent_norm(w), depth), 1.0e-12_wp * radius)
      free_ag = .false.
      restarts = 0
      allocate(wn(na))
      do i = 1, na
        wn(i) = norm2(w(2*i-1:2*i))
      end do
      do
        ! every row within the global cutoff; the solve keeps a row when its gap is within the
        ! pair's own reach cutoff_factor * (|w_a| + |w_b|) (+ the deepest overlap), the others
        ! are checked after the solve (gap > |u_a| + |u_b|: cannot close) and added if needed
        call build_contacts(scene, p, radius, cutoff, lp%cells, cs_all)
        stats%n_rows = cs_all%n
        if (allocated(kept)) deallocate(kept)
        allocate(kept(cs_all%n))
        do l = 1, cs_all%n
          a = cs_all%ia(l); b = cs_all%ib(l)
          reach = wn(a)
          if (b > 0) reach = reach + wn(b)
          kept(l) = cs_all%gap(l) <= lp%cutoff_factor * (reach + depth) + 1.0e-12_wp * radius
        end do
        do
          call cs%clear()
          do l = 1, cs_all%n
            if (kept(l)) call cs%add(cs_all%ia(l), cs_all%ib(l), cs_all%ob(l), cs_all%g(:, l), cs_all%gap(l))
          end do
          ! agents of the rows that w violates
          call lp%mark_violated(w, free_ag, n_violated)
          if (.not. any(free_ag)) then
            u = w; exit
          end if
          do
            call lp%solve_local(free_ag, w, u, lam, ok, st, error)
            if (allocated(error)) return
            stats%n_local_rows = lp%cs_loc%n
            stats%solves = stats%solves + 1
            stats%iterations = stats%iterations + st%iterations
            stats%kkt = st%kkt
            if (.not. ok) then
              if (all(free_ag)) return
              ! a boxed-in free agent: free one ring over every candidate row
              call lp%grow_ring(w, free_ag)
              stats%grows = stats%grows + 1
              cycle
            end if
            ! an active row between a free and a fixed agent: the fixed one must make way too
            added = .false.
            do l = 1, cs%n
              if (lam(l) <= 0) cycle
              a = cs%ia(l); b = cs%ib(l)
              if (b == 0) cycle
              if (free_ag(a) .neqv. free_ag(b)) then
                free_ag(a) = .true.; free_ag(b) = .true.; added = .true.
              end if
            end do
            if (.not. added) exit
            stats%grows = stats%grows + 1
          end do
          ! a row left out that the solution could close: keep it and solve again
          added = .false.
          do l = 1, cs_all%n
            if (kept(l)) cycle
            a = cs_all%ia(l); b = cs_all%ib(l)
            reach = norm2(u(2*a-1:2*a))
            if (b > 0) reach = reach + norm2(u(2*b-1:2*b))
            if (cs_all%gap(l) <= reach) then
              kept(l) = .true.; added = .true.
            end if
          end do
          if (.not. added) exit
          stats%restarts = stats%restarts + 1
        end do
        ! a row outside the set has gap > cutoff and closes by at most 2 max_i |u_i|
        call lp%next_cutoff(u, cutoff, restarts, done, error)
        if (allocated(error) .or. done) exit
        stats%restarts = stats%restarts + 1
      end do
    end associate
    if (allocated(error)) return
    stats%n_free = max(stats%n_free, count(free_ag))
  end subroutine solve_at
end module cr_position_projection
