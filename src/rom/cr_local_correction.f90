!> Local exact correction of a reduced velocity (docs/model.md#local-exact-correction): no
!> interpenetration without solving the full projection every step.
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
!>    candidate row) and the solve is repeated (at worst every agent is free: the full
!>    projection; if even that misses the tolerance, the step is reported with
!>    stats%converged = .false. and the solver's best iterate, as the full model's step
!>    reports it, not as an error); if the corrected velocity is fast enough to reach rows
!>    beyond the cutoff, the cutoff grows and the call restarts, as in the full model.
!> Cost: the cell list O(n_a) plus the solve on the free agents only. The local solve is warm
!> started, as the full model's, from the multipliers of the previous call's rows with the
!> same identity (agent pair or agent-obstacle pair; `reset` forgets them, e.g. at the start
!> of a trajectory). The solver, the candidate rows, the rings and the local problem are
!> cr_local_projection's (shared with the position projection of cr_position_projection).
module cr_local_correction
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: build_contacts
  use cr_projection, only: projection_settings_t, solve_stats_t
  use cr_local_projection, only: local_projection_t, lin_gap, add_ring, max_agent_norm
  use cr_exit_codes, only: EXIT_BAD_INPUT
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
    !> the last local solve met the tolerance (true when nothing was solved); .false. only when
    !> even the projection with every agent free missed it (a step to check: see correct)
    logical :: converged = .true.
    !> wall-clock time of the call [s]
    real(wp) :: t_total = 0
  end type local_stats_t

  !> Local exact correction; holds the solver and work space across calls.
  type :: local_correction_t
    !> the exact solver, candidate rows (this%lp%cs) and local problem, warm started
    type(local_projection_t) :: lp
    !> agents whose velocity the last call solved for [n_a]
    logical, allocatable :: corrected(:)
  contains
    procedure :: init
    procedure :: free
    procedure :: reset
    procedure :: correct
  end type local_correction_t

contains

  !> Build the exact solver from `settings` (as the full model's &solver) and keep the
  !> full model's cutoff factor (&contacts cutoff_factor, finite, >= 1).
  subroutine init(this, settings, cutoff_factor, error)
    class(local_correction_t), intent(inout) :: this
    type(projection_settings_t), intent(in) :: settings
    real(wp), intent(in) :: cutoff_factor
    type(error_t), allocatable, intent(out) :: error
    call this%free()
    call this%lp%init("local_correction", settings, cutoff_factor, error, warm_start=.true.)
  end subroutine init

  subroutine free(this)
    class(local_correction_t), intent(inout) :: this
    call this%lp%free()
    if (allocated(this%corrected)) deallocate(this%corrected)
  end subroutine free

  !> Forget the multipliers kept for the warm start (the next solve starts from zero).
  subroutine reset(this)
    class(local_correction_t), intent(inout) :: this
    call this%lp%reset()
  end subroutine reset

  !> u = u_r + delta: the reduced velocity u_r [2 n_a] at positions q [2 n_a] corrected so that
  !> no contact row of the step h is violated (see the module header). delta = 0 outside
  !> this%corrected. error for inconsistent sizes or non-finite input; a solve that misses the
  !> tolerance even with every agent free is reported as stats%converged = .false. with the
  !> solver's best iterate (as the full model's step), not as an error.
  subroutine correct(this, scene, radius, q, u_r, h, u, stats, error)
    class(local_correction_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:), u_r(:), h
    real(wp), intent(out) :: u(:)
    type(local_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer(8) :: c0, c1, rate
    integer :: na
    real(wp) :: cutoff
    real(wp), allocatable :: lam(:)
    logical, allocatable :: seed(:)
    logical :: done
    call system_clock(c0, rate)
    if (.not. allocated(this%lp%solver)) then
      call set_error(error, "local_correction: correct called before init"); return
    end if
    na = size(q) / 2
    if (size(q) /= 2 * na .or. size(u_r) /= size(q) .or. size(u) /= size(q)) then
      call set_error(error, "local_correction: inconsistent sizes: q " // str(size(q)) // ", u_r " // &
        str(size(u_r)) // ", u " // str(size(u)), EXIT_BAD_INPUT); return
    end if
    if (.not. (ieee_is_finite(h) .and. ieee_is_finite(radius) .and. h > 0 .and. radius > 0)) then
      call set_error(error, "local_correction: h and radius must be finite and > 0", EXIT_BAD_INPUT); return
    end if
    if (.not. (all(ieee_is_finite(q)) .and. all(ieee_is_finite(u_r)))) then
      call set_error(error, "local_correction: q and u_r must be finite", EXIT_BAD_INPUT); return
    end if
    if (allocated(this%corrected)) then
      if (size(this%corrected) /= na) deallocate(this%corrected)
    end if
    if (.not. allocated(this%corrected)) allocate(this%corrected(na))
    allocate(seed(na))
    this%corrected = .false.
    u = u_r
    associate (lp => this%lp, cs => this%lp%cs)
      cutoff = max(lp%cutoff_factor * 2 * h * max_agent_norm(u_r), 1.0e-12_wp * radius)
      call lp%prepare(na, h)
      do
        call build_contacts(scene, q, radius, cutoff, lp%cells, cs)
        stats%n_rows = cs%n
        ! -- rows violated by u_r, their agents and clusters
        seed = .false.
        call lp%mark_violated(u_r, seed, stats%n_violated)
        if (stats%n_violated == 0) then
          u = u_r; this%corrected = .false.
          exit
        end if
        stats%n_clusters = count_clusters(cs, u_r, na)
        stats%n_seeds = count(seed)
        ! -- free set: seeds and their neighbours; grow by rings until the local solve succeeds
        this%corrected = seed
        call add_ring(cs, u_r, lp%cutoff_factor, this%corrected)
        do
          call solve(this%corrected)
          if (allocated(error)) return
          if (stats%converged) exit
          ! every agent free and still not solved: the full projection itself misses the
          ! tolerance (reported as in the full model: stats%converged = .false., best iterate)
          if (all(this%corrected)) exit
          call lp%grow_ring(u_r, this%corrected)
          stats%rings = stats%rings + 1
        end do
        call lp%next_cutoff(u, cutoff, stats%restarts, done, error)
        if (allocated(error) .or. done) exit
      end do
    end associate
    if (allocated(error)) return
    stats%n_corrected = count(this%corrected)
    call system_clock(c1)
    stats%t_total = real(c1 - c0, wp) / real(rate, wp)

  contains

    !> Exact projection of u_r restricted to the agents in `free` (others fixed at u_r).
    subroutine solve(free)
      logical, intent(in) :: free(:)
      type(solve_stats_t) :: st
      call this%lp%solve_local(free, u_r, u, lam, stats%converged, st, error)
      if (allocated(error)) return
      stats%n_local_rows = this%lp%cs_loc%n
      stats%iterations = stats%iterations + st%iterations
      stats%kkt = st%kkt
    end subroutine solve
  end subroutine correct

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
end module cr_local_correction
