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
module cr_position_projection
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  use cr_projection, only: projection_settings_t, projection_solver_t, solve_stats_t, &
    make_projection_solver
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
    class(projection_solver_t), allocatable :: solver
    !> candidate rows: gap <= cutoff_factor * (expected displacement), as &contacts cutoff_factor
    real(wp) :: cutoff_factor = 1.5_wp
    !> refinement: at most refine_max projections, stopped when max_i |u_i| <= refine_tol * radius
    integer :: refine_max = 50
    real(wp) :: refine_tol = 1.0e-6_wp
    type(cell_list_t) :: cells
    !> every candidate row within the cutoff (cs_all), the rows kept for the solve (cs), the
    !> rows of the local problem (cs_loc)
    type(contact_set_t) :: cs_all, cs, cs_loc
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
    if (.not. (cutoff_factor >= 1.0_wp .and. cutoff_factor < huge(1.0_wp))) then
      call set_error(error, "position_projection: cutoff_factor must be finite and >= 1, got " // &
        str(cutoff_factor), 2); return
    end if
    this%cutoff_factor = cutoff_factor
    call make_projection_solver(settings, this%solver, error)
    if (allocated(error)) call prefix_error(error, "position_projection")
  end subroutine init

  subroutine free(this)
    class(position_projection_t), intent(inout) :: this
    if (allocated(this%solver)) then
      call this%solver%free()
      deallocate(this%solver)
    end if
    call this%cs%free()
    call this%cs_all%free()
    call this%cs_loc%free()
    this%cells = cell_list_t()
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
    if (.not. allocated(this%solver)) then
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
    if (this%cs%n_agents /= na .or. .not. allocated(this%cs%ia)) call this%cs%init(na, 1.0_wp, 8 * na)
    if (this%cs_all%n_agents /= na .or. .not. allocated(this%cs_all%ia)) call this%cs_all%init(na, 1.0_wp, 8 * na)
    ! -- overlaps of q_in
    call build_contacts(scene, q_in, radius, 1.0e-12_wp * radius, this%cells, this%cs)
    do l = 1, this%cs%n
      if (this%cs%gap(l) < 0) then
        stats%n_overlaps = stats%n_overlaps + 1
        stats%depth_in = max(stats%depth_in, -this%cs%gap(l))
      end if
    end do
    stats%n_rows = this%cs%n
    if (stats%n_overlaps == 0) then
      call finish(); return
    end if
    allocate(u(2 * na), w(2 * na))
    ! -- start: q_start, or the first-order projection linearised at q_in
    if (present(q_start)) then
      p = q_start
      call build_contacts(scene, p, radius, 1.0e-12_wp * radius, this%cells, this%cs)
      depth_start = 0
      do l = 1, this%cs%n
        depth_start = max(depth_start, -this%cs%gap(l))
      end do
      if (depth_start > max(this%solver%settings%tol, 1.0e-9_wp) * radius) then
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
    integer :: na, i, l, a, b, restarts
    real(wp) :: cutoff, need, umax, depth, reach
    real(wp), allocatable :: lam(:), wn(:)
    logical, allocatable :: free_ag(:), before(:), kept(:)
    logical :: added
    na = size(p) / 2
    allocate(free_ag(na))
    ok = .true.
    ! the largest motion to expect: the wanted one, or the deepest overlap of p
    call build_contacts(scene, p, radius, 1.0e-12_wp * radius, this%cells, this%cs)
    depth = 0
    do l = 1, this%cs%n
      depth = max(depth, -this%cs%gap(l))
    end do
    umax = 0
    do i = 1, na
      umax = max(umax, norm2(w(2*i-1:2*i)))
    end do
    cutoff = max(this%cutoff_factor * 2 * max(umax, depth), 1.0e-12_wp * radius)
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
      call build_contacts(scene, p, radius, cutoff, this%cells, this%cs_all)
      stats%n_rows = this%cs_all%n
      if (allocated(kept)) deallocate(kept)
      allocate(kept(this%cs_all%n))
      do l = 1, this%cs_all%n
        a = this%cs_all%ia(l); b = this%cs_all%ib(l)
        reach = wn(a)
        if (b > 0) reach = reach + wn(b)
        kept(l) = this%cs_all%gap(l) <= this%cutoff_factor * (reach + depth) + 1.0e-12_wp * radius
      end do
      do
        call this%cs%clear()
        do l = 1, this%cs_all%n
          if (kept(l)) call this%cs%add(this%cs_all%ia(l), this%cs_all%ib(l), this%cs_all%ob(l), &
            this%cs_all%g(:, l), this%cs_all%gap(l))
        end do
        ! agents of the rows that w violates
        do l = 1, this%cs%n
          if (lin_gap(this%cs, l, w) < 0) then
            free_ag(this%cs%ia(l)) = .true.
            if (this%cs%ib(l) > 0) free_ag(this%cs%ib(l)) = .true.
          end if
        end do
        if (.not. any(free_ag)) then
          u = w; exit
        end if
        do
          call solve_local(this, free_ag, w, u, lam, ok, stats, error)
          if (allocated(error)) return
          if (.not. ok) then
            if (all(free_ag)) return
            ! a boxed-in free agent: free one ring over every candidate row
            before = free_ag
            do l = 1, this%cs%n
              a = this%cs%ia(l); b = this%cs%ib(l)
              if (b == 0) cycle
              if (before(a) .neqv. before(b)) then
                free_ag(a) = .true.; free_ag(b) = .true.
              end if
            end do
            if (all(before .eqv. free_ag)) free_ag = .true.
            stats%grows = stats%grows + 1
            cycle
          end if
          ! an active row between a free and a fixed agent: the fixed one must make way too
          added = .false.
          do l = 1, this%cs%n
            if (lam(l) <= 0) cycle
            a = this%cs%ia(l); b = this%cs%ib(l)
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
        do l = 1, this%cs_all%n
          if (kept(l)) cycle
          a = this%cs_all%ia(l); b = this%cs_all%ib(l)
          reach = norm2(u(2*a-1:2*a))
          if (b > 0) reach = reach + norm2(u(2*b-1:2*b))
          if (this%cs_all%gap(l) <= reach) then
            kept(l) = .true.; added = .true.
          end if
        end do
        if (.not. added) exit
        stats%restarts = stats%restarts + 1
      end do
      umax = 0
      do i = 1, na
        umax = max(umax, norm2(u(2*i-1:2*i)))
      end do
      ! a row outside the set has gap > cutoff and closes by at most 2 umax
      need = 2 * umax
      if (need <= cutoff) exit
      restarts = restarts + 1
      stats%restarts = stats%restarts + 1
      cutoff = 1.05_wp * need
      if (restarts > 50) then
        call set_error(error, "position_projection: contact set did not stabilise after 50 restarts"); return
      end if
    end do
    stats%n_free = max(stats%n_free, count(free_ag))
  end subroutine solve_at

  !> Linearised gap of row l after the displacement w (h = 1): D_l + G_l . w.
  pure real(wp) function lin_gap(cs, l, w) result(s)
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: l
    real(wp), intent(in) :: w(:)
    integer :: a, b
    a = cs%ia(l); b = cs%ib(l)
    s = cs%g(1, l) * w(2*a-1) + cs%g(2, l) * w(2*a)
    if (b > 0) s = s - cs%g(1, l) * w(2*b-1) - cs%g(2, l) * w(2*b)
    s = cs%gap(l) + s
  end function lin_gap

  !> Solve for the displacement u [2 n_a] of the free agents (desired displacement w, the others
  !> moving by w) under the rows of this%cs; lam [this%cs%n]: the multiplier of each row in the
  !> local problem (0 for rows left out: between fixed agents). converged: the solver met its
  !> stopping test and tol.
  subroutine solve_local(this, free_ag, w, u, lam, converged, stats, error)
    type(position_projection_t), intent(inout) :: this
    logical, intent(in) :: free_ag(:)
    real(wp), intent(in) :: w(:)
    real(wp), intent(out) :: u(:)
    real(wp), allocatable, intent(out) :: lam(:)
    logical, intent(out) :: converged
    type(pproj_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: map(:), back(:), row_of(:)
    real(wp), allocatable :: v_loc(:), u_loc(:), lam_loc(:)
    type(solve_stats_t) :: st
    integer :: na, m, i, l, a, b, k
    na = size(free_ag)
    allocate(map(na))
    map = 0; m = 0
    do i = 1, na
      if (free_ag(i)) then
        m = m + 1; map(i) = m
      end if
    end do
    allocate(back(m), v_loc(2 * m), u_loc(2 * m), row_of(this%cs%n))
    do i = 1, na
      if (map(i) > 0) then
        back(map(i)) = i
        v_loc(2*map(i)-1:2*map(i)) = w(2*i-1:2*i)
      end if
    end do
    ! rows of the local problem (h = 1): free-free as they are, free-fixed as one-agent rows
    ! of the free agent with the gap shifted by the fixed agent's motion w
    call this%cs_loc%init(m, 1.0_wp, max(4 * m, this%cs%n))
    row_of = 0
    do l = 1, this%cs%n
      a = this%cs%ia(l); b = this%cs%ib(l)
      if (b == 0) then
        if (map(a) > 0) call this%cs_loc%add(map(a), 0, this%cs%ob(l), this%cs%g(:, l), this%cs%gap(l))
      else if (map(a) > 0 .and. map(b) > 0) then
        call this%cs_loc%add(map(a), map(b), 0, this%cs%g(:, l), this%cs%gap(l))
      else if (map(a) > 0) then
        call this%cs_loc%add(map(a), 0, 0, this%cs%g(:, l), &
          this%cs%gap(l) - this%cs%g(1, l) * w(2*b-1) - this%cs%g(2, l) * w(2*b))
      else if (map(b) > 0) then
        call this%cs_loc%add(map(b), 0, 0, -this%cs%g(:, l), &
          this%cs%gap(l) + this%cs%g(1, l) * w(2*a-1) + this%cs%g(2, l) * w(2*a))
      else
        cycle
      end if
      row_of(l) = this%cs_loc%n
    end do
    stats%n_local_rows = this%cs_loc%n
    allocate(lam_loc(max(this%cs_loc%n, 1)))
    lam_loc = 0
    call this%solver%solve(this%cs_loc, v_loc, u_loc, lam_loc, st, error)
    if (allocated(error)) then
      call prefix_error(error, "position_projection"); return
    end if
    stats%solves = stats%solves + 1
    stats%iterations = stats%iterations + st%iterations
    stats%kkt = st%kkt
    converged = st%converged .and. st%kkt <= this%solver%settings%tol
    u = w
    do k = 1, m
      i = back(k)
      u(2*i-1:2*i) = u_loc(2*k-1:2*k)
    end do
    allocate(lam(this%cs%n))
    lam = 0
    do l = 1, this%cs%n
      if (row_of(l) > 0) lam(l) = lam_loc(row_of(l))
    end do
  end subroutine solve_local
end module cr_position_projection
