!> The exact projection restricted to a set of free agents: the machinery shared by the
!> position projection (cr_position_projection: positions, h = 1) and the local correction of
!> a reduced velocity (cr_local_correction: one step h). It owns the full model's exact solver
!> (the &solver factory), the candidate rows (cell list, gap <= cutoff, step h), the free set
!> (agents of violated rows, rings) and the local problem
!>   u = argmin |u - w|^2  s.t.  D_l + h G_l . u >= 0  for every candidate row l,
!> solved for the free agents only while the others move by w: a row between two free agents
!> as it is, a row between a free agent a and a fixed agent b as a one-agent row of a with the
!> gap shifted by b's motion, D_l - h G_l . w_b (obstacle rows of free agents as they are; rows
!> between two fixed agents are left out). With `warm_start`, each solve starts from the
!> multipliers of the previous solve's rows with the same identity (agent pair or
!> agent-obstacle pair; `reset` forgets them).
module cr_local_projection
  use cr_kinds, only: wp, i8
  use cr_key_map, only: key_map_t
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t
  use cr_projection, only: projection_settings_t, projection_solver_t, solve_stats_t, &
    make_projection_solver
    use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: local_projection_t, lin_gap, add_ring, max_agent_norm

  !> Exact solver, candidate rows and local problem of one user (see the module header).
  type :: local_projection_t
    !> the user's name: the prefix of its messages
    character(len=:), allocatable :: name
    class(projection_solver_t), allocatable :: solver
    !> candidate rows: gap <= cutoff_factor * (expected motion), as &contacts cutoff_factor
    real(wp) :: cutoff_factor = 1.5_wp
    type(cell_list_t) :: cells
    !> candidate rows (step cs%h) and the rows of the local problem
    type(contact_set_t) :: cs, cs_loc
    !> warm start from the previous solve's multipliers, by row identity
    logical :: warm = .false.
    type(key_map_t) :: prev
  contains
    procedure :: init
    procedure :: free
    procedure :: reset
    procedure :: prepare
    procedure :: mark_violated
    procedure :: grow_ring
    procedure :: next_cutoff
    procedure :: solve_local
  end type local_projection_t

contains

  !> Build the exact solver from `settings` (the full model's &solver) and keep the full
  !> model's cutoff factor (&contacts cutoff_factor: finite, >= 1); `name` prefixes every
  !> message (code 2 for a bad cutoff_factor).
  subroutine init(this, name, settings, cutoff_factor, error, warm_start)
    class(local_projection_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    type(projection_settings_t), intent(in) :: settings
    real(wp), intent(in) :: cutoff_factor
    type(error_t), allocatable, intent(out) :: error
    logical, intent(in), optional :: warm_start
    call this%free()
    this%name = name
    this%warm = .false.
    if (present(warm_start)) this%warm = warm_start
    if (.not. (cutoff_factor >= 1.0_wp .and. cutoff_factor < huge(1.0_wp))) then
      call set_error(error, name // ": cutoff_factor must be finite and >= 1, got " // str(cutoff_factor), EXIT_BAD_INPUT)
      return
    end if
    this%cutoff_factor = cutoff_factor
    call make_projection_solver(settings, this%solver, error)
    if (allocated(error)) call prefix_error(error, name)
  end subroutine init

  subroutine free(this)
    class(local_projection_t), intent(inout) :: this
    if (allocated(this%solver)) then
      call this%solver%free()
      deallocate(this%solver)
    end if
    call this%cs%free()
    call this%cs_loc%free()
    call this%prev%free()
    this%cells = cell_list_t()
  end subroutine free

  !> Forget the multipliers kept for the warm start (the next solve starts from zero).
  subroutine reset(this)
    class(local_projection_t), intent(inout) :: this
    call this%prev%clear()
  end subroutine reset

  !> Candidate rows for n_a agents and the step h (kept across calls when they match).
  subroutine prepare(this, na, h)
    class(local_projection_t), intent(inout) :: this
    integer, intent(in) :: na
    real(wp), intent(in) :: h
    if (this%cs%n_agents /= na .or. this%cs%h /= h .or. .not. allocated(this%cs%ia)) &
      call this%cs%init(na, h, 8 * na)
  end subroutine prepare

  !> Mark in free [n_a] the agents of the candidate rows that the motion w [2 n_a] violates
  !> (linearised gap after the step < 0); n_violated: the number of such rows.
  subroutine mark_violated(this, w, free, n_violated)
    class(local_projection_t), intent(in) :: this
    real(wp), intent(in) :: w(:)
    logical, intent(inout) :: free(:)
    integer, intent(out) :: n_violated
    integer :: l
    n_violated = 0
    do l = 1, this%cs%n
      if (lin_gap(this%cs, l, w) < 0) then
        n_violated = n_violated + 1
        free(this%cs%ia(l)) = .true.
        if (this%cs%ib(l) > 0) free(this%cs%ib(l)) = .true.
      end if
    end do
  end subroutine mark_violated

  !> A local problem the solver could not meet: free one ring of neighbours over every
  !> candidate row (every agent when the ring adds nobody).
  subroutine grow_ring(this, w, free)
    class(local_projection_t), intent(in) :: this
    real(wp), intent(in) :: w(:)
    logical, intent(inout) :: free(:)
    logical, allocatable :: before(:)
    before = free
    call add_ring(this%cs, w, this%cutoff_factor, free, every_row=.true.)
    if (all(before .eqv. free)) free = .true.
  end subroutine grow_ring

  !> After a solve with the candidate rows within `cutoff`: done when no row beyond it can
  !> close during the step (2 h max_i |u_i| <= cutoff); otherwise the cutoff grows to 1.05
  !> times that and `restarts` is counted (an error after 50).
  subroutine next_cutoff(this, u, cutoff, restarts, done, error)
    class(local_projection_t), intent(in) :: this
    real(wp), intent(in) :: u(:)
    real(wp), intent(inout) :: cutoff
    integer, intent(inout) :: restarts
    logical, intent(out) :: done
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: need
    need = 2 * this%cs%h * max_agent_norm(u)
    done = need <= cutoff
    if (done) return
    restarts = restarts + 1
    cutoff = 1.05_wp * need
    if (restarts > 50) call set_error(error, this%name // ": contact set did not stabilise after 50 restarts")
  end subroutine next_cutoff

  !> Solve the local problem (module header) for the agents in free [n_a], desired motion
  !> w [2 n_a]: u [2 n_a] (= w outside free), lam [this%cs%n] the multiplier of each candidate
  !> row in the local problem (0 for rows left out), st the solver's statistics; converged:
  !> the solver met its stopping test and its tolerance. this%cs_loc holds the local rows.
  subroutine solve_local(this, free, w, u, lam, converged, st, error)
    class(local_projection_t), intent(inout) :: this
    logical, intent(in) :: free(:)
    real(wp), intent(in) :: w(:)
    real(wp), intent(out) :: u(:)
    real(wp), allocatable, intent(out) :: lam(:)
    logical, intent(out) :: converged
    type(solve_stats_t), intent(out) :: st
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: map(:), back(:), row_of(:)
    integer(i8), allocatable :: keys(:)
    real(wp), allocatable :: v_loc(:), u_loc(:), lam_loc(:)
    integer :: na, m, i, l, a, b, k
    real(wp) :: h, g(2), s
    converged = .false.
    na = size(free)
    h = this%cs%h
    allocate(map(na))
    map = 0; m = 0
    do i = 1, na
      if (free(i)) then
        m = m + 1; map(i) = m
      end if
    end do
    allocate(back(m), v_loc(2 * m), u_loc(2 * m), row_of(this%cs%n), keys(this%cs%n))
    do i = 1, na
      if (map(i) > 0) then
        back(map(i)) = i
        v_loc(2*map(i)-1:2*map(i)) = w(2*i-1:2*i)
      end if
    end do
    call this%cs_loc%init(m, h, max(4 * m, this%cs%n))
    row_of = 0
    do l = 1, this%cs%n
      a = this%cs%ia(l); b = this%cs%ib(l); g = this%cs%g(:, l)
      if (b == 0) then
        if (map(a) == 0) cycle
        call this%cs_loc%add(map(a), 0, this%cs%ob(l), g, this%cs%gap(l))
      else if (map(a) > 0 .and. map(b) > 0) then
        call this%cs_loc%add(map(a), map(b), 0, g, this%cs%gap(l))
      else if (map(a) > 0) then
        ! D + h g.(u_a - w_b) >= 0: a one-agent row with the shifted gap (ob = 0: no obstacle)
        s = this%cs%gap(l) - h * (g(1) * w(2*b-1) + g(2) * w(2*b))
        call this%cs_loc%add(map(a), 0, 0, g, s)
      else if (map(b) > 0) then
        s = this%cs%gap(l) + h * (g(1) * w(2*a-1) + g(2) * w(2*a))
        call this%cs_loc%add(map(b), 0, 0, -g, s)
      else
        cycle
      end if
      row_of(l) = this%cs_loc%n
      ! the local row's identity: that of the candidate row it comes from
      keys(this%cs_loc%n) = this%cs%key(l)
    end do
    allocate(lam_loc(max(this%cs_loc%n, 1)))
    lam_loc = 0
    ! warm start: multipliers of the previous solve's rows with the same identity
    if (this%warm) call this%prev%lookup(keys(1:this%cs_loc%n), lam_loc, 0.0_wp)
    call this%solver%solve(this%cs_loc, v_loc, u_loc, lam_loc, st, error)
    if (allocated(error)) then
      call prefix_error(error, this%name); return
    end if
    if (this%warm) call this%prev%fill(keys(1:this%cs_loc%n), lam_loc(1:this%cs_loc%n))
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

  !> Linearised gap of row l after the step with motion w [2 n_a]: D_l + h G_l . w.
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
  !> the row's gap is within the pair's own cutoff cutoff_factor * 2 h max(|w_a|, |w_b|)
  !> (a global cutoff set by the fastest agent would free far too many). With every_row, any
  !> candidate row counts.
  subroutine add_ring(cs, w, cutoff_factor, free, every_row)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: w(:), cutoff_factor
    logical, intent(inout) :: free(:)
    logical, intent(in), optional :: every_row
    logical, allocatable :: old(:)
    integer :: l, a, b
    real(wp) :: reach
    logical :: all_rows
    all_rows = .false.
    if (present(every_row)) all_rows = every_row
    old = free
    do l = 1, cs%n
      a = cs%ia(l); b = cs%ib(l)
      if (b == 0) cycle
      if (old(a) .eqv. old(b)) cycle
      if (.not. all_rows) then
        reach = cutoff_factor * 2 * cs%h * max(norm2(w(2*a-1:2*a)), norm2(w(2*b-1:2*b)))
        if (cs%gap(l) > reach) cycle
      end if
      free(a) = .true.; free(b) = .true.
    end do
  end subroutine add_ring

  !> Largest motion of an agent: max_i |w_i| over w [2 n_a] (0 for no agent).
  pure real(wp) function max_agent_norm(w) result(wmax)
    real(wp), intent(in) :: w(:)
    integer :: i
    wmax = 0
    do i = 1, size(w) / 2
      wmax = max(wmax, norm2(w(2*i-1:2*i)))
    end do
  end function max_agent_norm
end module cr_local_projection
