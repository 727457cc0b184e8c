!> The reduced solvers of the time stepping (cr_rom_stepper): one step's reduced projection
!>   (alpha, beta) = argmin |alpha - vhat|^2  s.t.  bhat alpha <= dhat   (bhat = bt^T)
!> as an abstract type with one deferred `step`, and a factory that builds a variant from its
!> name (the names of `&reduced solver`):
!>  'dual'  warm-started dual active set on the Gram of the active rows (cr_reduced_dual, with
!>          the Lawson-Hanson LDP as certified fallback);
!>  'nnls'  the Lawson-Hanson least-distance solver, warm started (cr_reduced_nnls);
!>  'uzawa' the paper's Uzawa iteration from beta = 0 (cr_reduced_uzawa).
!> Each step adds what it did to a reduced_tally_t (the trajectory extends it). The factory
!> lives in the submodule cr_reduced_solver_factory so that this module does not depend on
!> its variants.
module cr_reduced_solver
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_reduced_base, only: reduced_ops_t
  implicit none
  private
  public :: rom_solver_cfg_t, reduced_tally_t, reduced_solver_t, make_reduced_solver, &
    reduced_solver_names, known_reduced_solvers, is_reduced_solver

  !> names accepted by make_reduced_solver (one `case` each in cr_reduced_solver_factory)
  character(len=5), parameter :: reduced_solver_names(3) = [character(len=5) :: 'dual', 'nnls', 'uzawa']
  !> the same names, quoted, for messages
  character(len=*), parameter :: known_reduced_solvers = "'dual', 'nnls', 'uzawa'"

  !> Reduced solver settings.
  type :: rom_solver_cfg_t
    !> 'dual', 'nnls' or 'uzawa'
    character(len=8) :: name = 'dual'
    !> NNLS iteration cap (0: the solver's default 3 n + 50)
    integer :: nnls_max_iter = 0
    real(wp) :: uzawa_rho_factor = 0.2_wp
    real(wp) :: uzawa_eps = 1.0e-12_wp
    integer :: uzawa_max_iter = 1000000
  end type rom_solver_cfg_t

  !> What the steps of a trajectory did, summed over the steps.
  type :: reduced_tally_t
    !> steps with an infeasible reduced problem / a solve stopped by its cap
    integer :: n_infeasible = 0, n_capped = 0
    !> 'dual': steps answered by the Lawson-Hanson fallback (infeasible ones included),
    !> rows added and dropped by the dual iteration, sum of the final active-set sizes
    integer :: n_fallback = 0, dual_adds = 0, dual_drops = 0, active_sum = 0
    !> why the dual solver handed over: found infeasible, capped or more than 3/4 Nb active
    !> rows, certificate failed
    integer :: dual_why(3) = 0
    !> total solver iterations
    integer :: iterations = 0
    !> largest violation of the reduced constraints by the returned coefficients
    real(wp) :: max_violation = 0
  end type reduced_tally_t

  !> A reduced solver: its settings and the work space it keeps from step to step.
  type, abstract :: reduced_solver_t
    type(rom_solver_cfg_t) :: cfg
  contains
    procedure(step_iface), deferred :: step
    procedure :: init => reduced_init
    procedure :: name => reduced_name
  end type reduced_solver_t

  abstract interface
    !> One reduced step: alpha and the multipliers lam of the rows of bt (lam > 0 on entry:
    !> warm start by contact identity; on exit the step's multipliers). Non-convergence and
    !> infeasibility are counted in tally, not errors; error only from the LDP's input checks.
    subroutine step_iface(this, ops, h, bt, dhat, vhat, alpha, lam, tally, error)
      import :: reduced_solver_t, reduced_ops_t, wp, reduced_tally_t, error_t
      class(reduced_solver_t), intent(inout) :: this
      !> the assembly of the step (Gram entries of its rows when ops%has_gram)
      class(reduced_ops_t), intent(in) :: ops
      !> time step [s]
      real(wp), intent(in) :: h
      !> reduced constraint rows as columns: bhat^T [nb, R]
      real(wp), contiguous, intent(in) :: bt(:,:)
      !> reduced right-hand side [R] and desired coefficients [nb]
      real(wp), intent(in) :: dhat(:)
      real(wp), contiguous, intent(in) :: vhat(:)
      !> coefficients of the step [nb]
      real(wp), contiguous, intent(inout) :: alpha(:)
      !> multipliers [R]
      real(wp), intent(inout) :: lam(:)
      type(reduced_tally_t), intent(inout) :: tally
      type(error_t), allocatable, intent(out) :: error
    end subroutine step_iface
  end interface

  interface
    !> Build the reduced solver named cfg%name; an unknown name gives a one-line error listing
    !> the known ones.
    module subroutine make_reduced_solver(cfg, solver, error)
      type(rom_solver_cfg_t), intent(in) :: cfg
      class(reduced_solver_t), allocatable, intent(out) :: solver
      type(error_t), allocatable, intent(out) :: error
    end subroutine make_reduced_solver
  end interface

contains

  !> Store the settings (variants may extend this to set up work space).
  subroutine reduced_init(this, cfg)
    class(reduced_solver_t), intent(inout) :: this
    type(rom_solver_cfg_t), intent(in) :: cfg
    this%cfg = cfg
  end subroutine reduced_init

  !> Name of the solver, as accepted by the factory.
  function reduced_name(this) result(name)
    class(reduced_solver_t), intent(in) :: this
    character(len=:), allocatable :: name
    name = trim(this%cfg%name)
  end function reduced_name

  !> Whether make_reduced_solver knows name.
  pure logical function is_reduced_solver(name)
    character(len=*), intent(in) :: name
    is_reduced_solver = any(reduced_solver_names == trim(name))
  end function is_reduced_solver
end module cr_reduced_solver
