!> Local exact correction of a reduced velocity (issue 14 item 4): no interpenetration
!> without solving the full projection every step.
!>
!> Given positions q, a reduced velocity u_r = V alpha [2 n_a] and the step h, return
!> u = u_r + delta such that every linearised contact row of the full model holds:
!>   D_l(q) + h G_l(q) . u >= 0  (to the solver's KKT tolerance),
!> which implies no overlap at q + h u (the gaps of disks and of convex obstacles are convex in
!> the displacement, so the linearised gap is a lower bound of the true gap).
!>
!> What is projected: u_r itself. Inside the correction set the result is the exact projection
!> of u_r onto the feasible cone (the agents outside enter with their u_r fixed), so
!> delta = 0 where there is no conflict, and delta is the smallest change (Euclidean norm)
!> that removes the conflicts of the set. Projecting the desired velocity v instead would
!> change agents whose u_r is feasible and mix the full model's dynamics into the reduced one.
!>
!> Algorithm (one call):
!> 1. candidate rows with the cell list, gap <= cutoff = cutoff_factor * 2 h max_i |u_r,i|
!>    (as the full model), and the rows that u_r violates (linearised gap after the step < 0);
!> 2. the agents of the violated rows (grouped into conflict clusters, counted with a
!>    union-find) plus their neighbours are free: agents sharing a candidate row with them
!>    whose gap is within the pair's own cutoff, cutoff_factor * 2 h max(|u_r,a|, |u_r,b|)
!>    (neighbours are there so that they can make way; correctness does not depend on them,
!>    since every row between a free and a fixed agent is a constraint of the local solve);
!> 3. exact projection of u_r restricted to the free agents with the full model's solver:
!>    rows between two free agents as they are, rows between a free agent a and a fixed agent b
!>    become one-agent rows with the shifted gap D_l - h G_l(b) . u_r,b, obstacle rows of free
!>    agents as they are; rows between two fixed agents are untouched (not violated);
!> 4. if the local problem is not solved to the tolerance (it can be infeasible when fixed
!>    agents close in on a free one), the free set grows by one ring of neighbours (every
!>    candidate row) and the
!>    solve is repeated (at worst every agent is free: the full projection); if the corrected
!>    velocity is fast enough to reach rows beyond the cutoff, the cutoff grows and the call
!>    restarts, as in the full model.
!> Cost: the cell list O(n_a) plus the solve on the free agents only. The local solve is warm
!> started, as the full model's, from the multipliers of the previous call's rows with the
!> same identity (agent pair or agent-obstacle pair; `reset` forgets them, e.g. at the start
!> of a trajectory).
module cr_local_correction
  use cr_kinds, only: wp, i8
  use cr_sort, only: argsort_i8, bsearch_i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  use cr_projection, only: projection_settings_t, projection_solver_t, solve_stats_t, &
    make_projection_solver
  implicit none
  private
  public :: local_correction_t, local_stats_t

  !> What one correction did.
  type :: local_stats_t
    !> agents whose velocity was solved for (free agents), violated candidate rows of u_r,
    !> conflict clusters (connected groups of violated rows), candidate rows, local rows
    integer :: n_corrected = 0, n_violated = 0, n_clusters = 0, n_rows = 0, n_local_rows = 0
    !> agents of the violated rows (the conflict agents, before neighbours are added)
    integer :: n_seeds = 0
    !> solver iterations (summed over the solves of the call), rings added, cutoff restarts
    integer :: iterations = 0, rings = 0, restarts = 0
    !> scaled KKT residual of the last local solve (0 when nothing was solved)
    real(wp) :: kkt = 0
    !> the last local solve met the tolerance (true when nothing was solved)
    logical :: converged = .true.
    !> wall-clock time of the call [s]
    real(wp) :: t_total = 0
  end type local_stats_t

  !> Local exact correction; holds the solver and work space across calls.
  type :: local_correction_t
    class(projection_solver_t), allocatable :: solver
    real(wp) :: cutoff_factor = 1.5_wp
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs, cs_loc
    !> agents whose velocity the last call solved for [n_a]
    logical, allocatable :: corrected(:)
    !> the last local solve's row identities (sorted) and multipliers, for the warm start
    integer(i8), allocatable :: prev_keys(:)
    real(wp), allocatable :: prev_lambda(:)
  contains
    procedure :: init
    procedure :: free
    procedure :: reset
    procedure :: correct
  end type local_correction_t

contains

  !> Build the exact solver from `settings` (as the full model's &solver) and keep the
  !> full model's cutoff factor (&contacts cutoff_factor, >= 1).
  subroutine init(this, settings, cutoff_factor, error)
    class(local_correction_t), intent(inout) :: this
    type(projection_settings_t), intent(in) :: settings
    real(wp), intent(in) :: cutoff_factor
    type(error_t), allocatable, intent(out) :: error
    call this%free()
    if (.not. (cutoff_factor >= 1.0_wp)) then
      call set_error(error, "local_correction: cutoff_factor must be >= 1, got " // str(cutoff_factor), 2)
      return
    end if
    this%cutoff_factor = cutoff_factor
    call make_projection_solver(settings, this%solver, error)
    if (allocated(error)) call prefix_error(error, "local_correction")
  end subroutine init

  subroutine free(this)
    class(local_correction_t), intent(inout) :: this
    if (allocated(this%solver)) then
      call this%solver%free()
      deallocate(this%solver)
    end if
    call this%cs%free()
    call this%cs_loc%free()
    if (allocated(this%corrected)) deallocate(this%corrected)
    call this%reset()
    this%cells = cell_list_t()
  end subroutine free

  !> Forget the multipliers kept for the warm start (the next solve starts from zero).
  subroutine reset(this)
    class(local_correction_t), intent(inout) :: this
    if (allocated(this%prev_keys)) deallocate(this%prev_keys)
    if (allocated(this%prev_lambda)) deallocate(this%prev_lambda)
  end subroutine reset

  !> u = u_r + delta: the reduced velocity u_r [2 n_a] at positions q [2 n_a] corrected so that
  !> no contact row of the step h is violated (see the module header). delta = 0 outside
  !> this%corrected. error for inconsistent sizes, non-finite input, or a solve that fails
  !> even with every agent free.
  subroutine correct(this, scene, radius, q, u_r, h, u, stats, error)
    class(local_correction_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:), u_r(:), h
    real(wp), intent(out) :: u(:)
    type(local_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer(8) :: c0, c1, rate
    integer :: na, i, l
    real(wp) :: umax, cutoff, need
    logical, allocatable :: seed(:)
    call system_clock(c0, rate)
    if (.not. allocated(this%solver)) then
      call set_error(error, "local_correction: correct called before init"); return
    end if
    na = size(q) / 2
    if (size(q) /= 2 * na .or. size(u_r) /= size(q) .or. size(u) /= size(q)) then
      call set_error(error, "local_correction: inconsistent sizes: q " // str(size(q)) // ", u_r " // &
        str(size(u_r)) // ", u " // str(size(u)), 2); return
    end if
    if (.not. (h > 0 .and. radius > 0) .or. any(q /= q) .or. any(u_r /= u_r) .or. &
        any(abs(q) > huge(1.0_wp)) .or. any(abs(u_r) > huge(1.0_wp))) then
      call set_error(error, "local_correction: h and radius must be > 0, q and u_r finite", 2); return
    end if
    if (allocated(this%corrected)) then
      if (size(this%corrected) /= na) deallocate(this%corrected)
    end if
    if (.not. allocated(this%corrected)) allocate(this%corrected(na))
    allocate(seed(na))
    this%corrected = .false.
    u = u_r
    umax = 0
    do i = 1, na
      umax = max(umax, norm2(u_r(2*i-1:2*i)))
    end do
    cutoff = max(this%cutoff_factor * 2 * h * umax, 1.0e-12_wp * radius)
    call this%cs%init(na, h, 8 * na)
    do
      call build_contacts(scene, q, radius, cutoff, this%cells, this%cs)
      stats%n_rows = this%cs%n
      ! -- rows violated by u_r, their agents and clusters
      seed = .false.
      stats%n_violated = 0
      do l = 1, this%cs%n
        if (lin_gap(this%cs, l, u_r) < 0) then
          stats%n_violated = stats%n_violated + 1
          seed(this%cs%ia(l)) = .true.
          if (this%cs%ib(l) > 0) seed(this%cs%ib(l)) = .true.
        end if
      end do
      if (stats%n_violated == 0) then
        u = u_r; this%corrected = .false.
        exit
      end if
      stats%n_clusters = count_clusters(this%cs, u_r, na)
      stats%n_seeds = count(seed)
      ! -- free set: seeds and their neighbours; grow by rings until the local solve succeeds
      this%corrected = seed
      call add_ring(this%cs, u_r, this%cutoff_factor, this%corrected)
      do
        call solve_local(this, u_r, u, stats, error)
        if (allocated(error)) return
        if (stats%converged) exit
        if (all(this%corrected)) then
          call set_error(error, "local_correction: the projection with every agent free did not reach " // &
            "the tolerance (KKT residual " // str(stats%kkt, "es9.2") // ")"); return
        end if
        seed = this%corrected
        call add_ring(this%cs, u_r, this%cutoff_factor, this%corrected, every_row=.true.)
        ! a ring adds nobody (no row leaves the set): free everyone
        if (all(seed .eqv. this%corrected)) this%corrected = .true.
        stats%rings = stats%rings + 1
      end do
      umax = 0
      do i = 1, na
        umax = max(umax, norm2(u(2*i-1:2*i)))
      end do
      need = 2 * h * umax
      if (need <= cutoff) exit
      stats%restarts = stats%restarts + 1
      cutoff = 1.05_wp * need
      if (stats%restarts > 50) then
        call set_error(error, "local_correction: contact set did not stabilise after 50 restarts"); return
      end if
    end do
    stats%n_corrected = count(this%corrected)
    call system_clock(c1)
    stats%t_total = real(c1 - c0, wp) / real(rate, wp)
  end subroutine correct

  !> Linearised gap of row l after the step with velocity w: D_l + h G_l . w.
  pure real(wp) function lin_gap(cs, l, w) result(s)
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: l
    real(wp), intent(in) :: w(:)
    integer :: a, b
    a = cs%ia(l); b = cs%ib(l)
    s = cs%g(1, l) * w(2*a-1) + cs%g(2, l) * w(2*a)
    if (b > 0) s = s - cs%g(1, l) * w(2*b-1) - cs%g(2, l) * w(2*b)
    s = cs%gap(l) + cs%h * s
  end function lin_gap

  !> Add to `free` every agent that shares a candidate row with an agent already free, when
  !> the row's gap is within the pair's own cutoff cutoff_factor * 2 h max(|u_r,a|, |u_r,b|)
  !> (the global cutoff is set by the fastest agent and would free far too many).
  !> With every_row, any candidate row counts.
  subroutine add_ring(cs, w, cutoff_factor, free, every_row)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: w(:), cutoff_factor
    logical, intent(inout) :: free(:)
    logical, intent(in), optional :: every_row
    logical, allocatable :: old(:)
    integer :: l, a, b
    real(wp) :: reach
    old = free
    do l = 1, cs%n
      a = cs%ia(l); b = cs%ib(l)
      if (b == 0) cycle
      if (old(a) .eqv. old(b)) cycle
      if (.not. present(every_row)) then
        reach = cutoff_factor * 2 * cs%h * max(norm2(w(2*a-1:2*a)), norm2(w(2*b-1:2*b)))
        if (cs%gap(l) > reach) cycle
      end if
      free(a) = .true.; free(b) = .true.
    end do
  end subroutine add_ring

  !> Number of connected groups of agents linked by violated rows (union-find).
  integer function count_clusters(cs, w, na) result(nc)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: w(:)
    integer, intent(in) :: na
    integer, allocatable :: parent(:)
    logical, allocatable :: touched(:)
    integer :: l, ra, rb, i
    allocate(parent(na), touched(na))
    parent = [(i, i = 1, na)]
    touched = .false.
    do l = 1, cs%n
      if (lin_gap(cs, l, w) >= 0) cycle
      touched(cs%ia(l)) = .true.
      if (cs%ib(l) == 0) cycle
      touched(cs%ib(l)) = .true.
      ra = root(cs%ia(l)); rb = root(cs%ib(l))
      if (ra /= rb) parent(max(ra, rb)) = min(ra, rb)
    end do
    nc = 0
    do i = 1, na
      if (touched(i) .and. root(i) == i) nc = nc + 1
    end do
  contains
    integer function root(x) result(r)
      integer, intent(in) :: x
      r = x
      do while (parent(r) /= r)
        parent(r) = parent(parent(r))
        r = parent(r)
      end do
    end function root
  end function count_clusters

  !> Exact projection of u_r restricted to the agents in this%corrected (others fixed at u_r).
  subroutine solve_local(this, u_r, u, stats, error)
    type(local_correction_t), intent(inout) :: this
    real(wp), intent(in) :: u_r(:)
    real(wp), intent(inout) :: u(:)
    type(local_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: map(:), back(:), idx(:)
    integer(i8), allocatable :: keys(:)
    real(wp), allocatable :: v_loc(:), u_loc(:), lambda(:)
    type(solve_stats_t) :: st
    integer :: na, m, i, l, a, b, k, n0
    real(wp) :: h, g(2), s
    na = size(this%corrected)
    h = this%cs%h
    allocate(map(na))
    map = 0; m = 0
    do i = 1, na
      if (this%corrected(i)) then
        m = m + 1; map(i) = m
      end if
    end do
    allocate(back(m), v_loc(2*m), u_loc(2*m))
    do i = 1, na
      if (map(i) > 0) then
        back(map(i)) = i
        v_loc(2*map(i)-1:2*map(i)) = u_r(2*i-1:2*i)
      end if
    end do
    call this%cs_loc%init(m, h, 4 * m)
    allocate(keys(this%cs%n))
    do l = 1, this%cs%n
      a = this%cs%ia(l); b = this%cs%ib(l); g = this%cs%g(:, l)
      n0 = this%cs_loc%n
      if (b == 0) then
        if (map(a) > 0) call this%cs_loc%add(map(a), 0, this%cs%ob(l), g, this%cs%gap(l))
      else if (map(a) > 0 .and. map(b) > 0) then
        call this%cs_loc%add(map(a), map(b), 0, g, this%cs%gap(l))
      else if (map(a) > 0) then
        ! D + h g.(u_a - u_r,b) >= 0: a one-agent row with the shifted gap (ob = 0: no obstacle)
        s = this%cs%gap(l) - h * (g(1) * u_r(2*b-1) + g(2) * u_r(2*b))
        call this%cs_loc%add(map(a), 0, 0, g, s)
      else if (map(b) > 0) then
        s = this%cs%gap(l) + h * (g(1) * u_r(2*a-1) + g(2) * u_r(2*a))
        call this%cs_loc%add(map(b), 0, 0, -g, s)
      end if
      ! the local row's identity: that of the full row it comes from
      if (this%cs_loc%n > n0) keys(this%cs_loc%n) = this%cs%key(l)
    end do
    stats%n_local_rows = this%cs_loc%n
    allocate(lambda(max(this%cs_loc%n, 1)))
    lambda = 0
    ! warm start: multipliers of the previous solve's rows with the same identity
    if (allocated(this%prev_keys)) then
      do k = 1, this%cs_loc%n
        i = bsearch_i8(this%prev_keys, keys(k))
        if (i > 0) lambda(k) = this%prev_lambda(i)
      end do
    end if
    call this%solver%solve(this%cs_loc, v_loc, u_loc, lambda, st, error)
    if (allocated(error)) then
      call prefix_error(error, "local_correction"); return
    end if
    stats%iterations = stats%iterations + st%iterations
    stats%kkt = st%kkt
    allocate(idx(this%cs_loc%n))
    call argsort_i8(keys(1:this%cs_loc%n), idx)
    this%prev_keys = keys(idx)
    this%prev_lambda = lambda(idx)
    stats%converged = st%converged .and. st%kkt <= this%solver%settings%tol
    u = u_r
    do k = 1, m
      i = back(k)
      u(2*i-1:2*i) = u_loc(2*k-1:2*k)
    end do
  end subroutine solve_local
end module cr_local_correction
