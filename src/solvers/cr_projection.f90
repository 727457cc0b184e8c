!> Projection of a desired velocity onto the feasible cone of one step:
!>   u = argmin |u - v|^2  s.t.  B u <= d   (B = -h G, rows of a contact_set_t).
!>
!> Variants ('sparse_active_set', 'active_set', 'gpcg', 'apgd', 'uzawa') extend the abstract
!> projection_solver_t; make_projection_solver builds one from its name (the factory lives in
!> the submodule cr_projection_factory so that this module does not depend on the variants).
module cr_projection
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t, kkt_residuals
  use cr_solver_settings, only: projection_settings_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: projection_settings_t, solve_stats_t, projection_solver_t, make_projection_solver, &
    known_projection_solvers, finish_stats, check_sizes, add_note

  !> names accepted by make_projection_solver
  character(len=*), parameter :: known_projection_solvers = &
    "'sparse_active_set', 'active_set', 'gpcg', 'apgd', 'uzawa'"


  !> What a solve did and how good its result is.
  type :: solve_stats_t
    integer :: iterations = 0
    !> the solver's own stopping test was met (see note when the KKT residual is still > tol)
    logical :: converged = .false.
    !> scaled KKT residuals of the returned (u, lambda) (kkt_residuals)
    real(wp) :: primal = 0.0_wp, dual = 0.0_wp, compl = 0.0_wp, stat = 0.0_wp
    !> max of the four residuals
    real(wp) :: kkt = 0.0_wp
    !> Uzawa only: rho > 2 / L (L upper bound of ||B||^2): convergence not guaranteed
    logical :: rho_above_bound = .false.
    !> sparse_active_set: numeric factorisations, factor row additions + deletions, solves
    !> handed to the safe path (failed factorisation, dependent rows, iteration cap)
    integer :: n_factor = 0, n_modify = 0, n_fallback = 0
    !> sparse_active_set (check_drift): largest backward error of a solve with an updated
    !> factor, measured before each refresh
    real(wp) :: factor_drift = 0.0_wp
    !> human-readable remarks (empty when nothing to say)
    character(len=:), allocatable :: note
  end type solve_stats_t

  !> A projection method.
  type, abstract :: projection_solver_t
    type(projection_settings_t) :: settings
  contains
    procedure(solve_iface), deferred :: solve
    procedure :: init => solver_init
    procedure :: free => solver_free
    procedure :: name => solver_name
  end type projection_solver_t

  abstract interface
    !> Project v: u = argmin |u - v|^2 s.t. B u <= d. lambda: warm start in, multipliers out.
    !> Non-convergence is not an error (stats%converged = .false. and a note); the best
    !> iterate found is returned. error only for inconsistent sizes.
    subroutine solve_iface(this, cs, v, u, lambda, stats, error)
      import :: projection_solver_t, contact_set_t, wp, solve_stats_t, error_t
      class(projection_solver_t), intent(inout) :: this
      type(contact_set_t), intent(in) :: cs
      !> desired velocity [2*n_agents]
      real(wp), intent(in) :: v(:)
      !> projected velocity [2*n_agents]
      real(wp), intent(out) :: u(:)
      !> multipliers [cs%n] (>= cs%n entries; the first cs%n are used)
      real(wp), intent(inout) :: lambda(:)
      type(solve_stats_t), intent(out) :: stats
      type(error_t), allocatable, intent(out) :: error
    end subroutine solve_iface
  end interface

  interface
    !> Build the solver named settings%name; unknown names give an error listing the known ones.
    module subroutine make_projection_solver(settings, solver, error)
      type(projection_settings_t), intent(in) :: settings
      class(projection_solver_t), allocatable, intent(out) :: solver
      type(error_t), allocatable, intent(out) :: error
    end subroutine make_projection_solver
  end interface

contains

  !> Store the settings (variants may extend this to set up work space).
  subroutine solver_init(this, settings, error)
    class(projection_solver_t), intent(inout) :: this
    type(projection_settings_t), intent(in) :: settings
    type(error_t), allocatable, intent(out) :: error
    if (.not. (settings%tol > 0.0_wp)) then
      call set_error(error, "projection solver: tol must be > 0, got " // str(settings%tol), EXIT_BAD_INPUT)
      return
    end if
    if (settings%dense_rows < 0 .or. settings%refresh_every < 1) then
      call set_error(error, "projection solver: dense_rows must be >= 0 and refresh_every >= 1", EXIT_BAD_INPUT)
      return
    end if
    if (settings%max_iter < 1 .or. settings%uzawa_max_iter < 1) then
      call set_error(error, "projection solver: max_iter and uzawa_max_iter must be >= 1", EXIT_BAD_INPUT)
      return
    end if
    if (.not. (settings%uzawa_rho_factor > 0.0_wp)) then
      call set_error(error, "projection solver: uzawa_rho_factor must be > 0, got " // &
        str(settings%uzawa_rho_factor), EXIT_BAD_INPUT)
      return
    end if
    this%settings = settings
  end subroutine solver_init

  subroutine solver_free(this)
    class(projection_solver_t), intent(inout) :: this
    this%settings = projection_settings_t()
  end subroutine solver_free

  !> Name of the method, as accepted by the factory.
  function solver_name(this) result(name)
    class(projection_solver_t), intent(in) :: this
    character(len=:), allocatable :: name
    name = trim(this%settings%name)
  end function solver_name

  !> Check the sizes of a solve call; error names the solver.
  subroutine check_sizes(who, cs, v, u, lambda, error)
    character(len=*), intent(in) :: who
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:), u(:), lambda(:)
    type(error_t), allocatable, intent(out) :: error
    if (size(v) /= 2 * cs%n_agents .or. size(u) /= 2 * cs%n_agents .or. size(lambda) < cs%n) then
      call set_error(error, who // ": inconsistent sizes: " // str(cs%n_agents) // " agents, " // &
        str(cs%n) // " rows, but v has " // str(size(v)) // ", u " // str(size(u)) // &
        ", lambda " // str(size(lambda)) // " entries", EXIT_BAD_INPUT)
    end if
  end subroutine check_sizes

  !> Fill the KKT part of stats for the returned (u, lambda) and append notes.
  subroutine finish_stats(cs, v, u, lambda, tol, stats)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:), u(:), lambda(:)
    real(wp), intent(in) :: tol
    type(solve_stats_t), intent(inout) :: stats
    call kkt_residuals(cs, v, u, lambda(1:cs%n), stats%primal, stats%dual, stats%compl, stats%stat)
    stats%kkt = max(stats%primal, stats%dual, stats%compl, stats%stat)
    ! a NaN must not hide behind max() (here or inside kkt_residuals)
    if (stats%primal /= stats%primal .or. stats%dual /= stats%dual .or. stats%compl /= stats%compl &
        .or. stats%stat /= stats%stat .or. any(u /= u) .or. any(lambda(1:cs%n) /= lambda(1:cs%n))) &
      stats%kkt = ieee_value(1.0_wp, ieee_quiet_nan)
    if (.not. allocated(stats%note)) stats%note = ""
    if (stats%converged .and. stats%kkt > tol) then
      call add_note(stats, "stopping test met but KKT residual " // str(stats%kkt, "es9.2") // &
        " > tol " // str(tol, "es9.2"))
    end if
  end subroutine finish_stats

  subroutine add_note(stats, text)
    type(solve_stats_t), intent(inout) :: stats
    character(len=*), intent(in) :: text
    if (.not. allocated(stats%note)) stats%note = ""
    if (len(stats%note) > 0) then
      stats%note = stats%note // "; " // text
    else
      stats%note = text
    end if
  end subroutine add_note
end module cr_projection
