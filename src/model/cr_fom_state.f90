!> The state of a full-order simulation as the files between stages hold it (the scene, the
!> contact rows and their multipliers, positions, velocities, inside flags, speeds) and the
!> record of one step. The stepping (`fom_t` of src/fom/cr_fom.f90) extends the state; the
!> products (src/products) read and write it without depending on the stepping.
module cr_fom_state
  use cr_kinds, only: wp
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  implicit none
  private
  public :: fom_state_t, step_record_t

  !> What one step did (stored per step in the output).
  type :: step_record_t
    integer :: step = 0
    integer :: iterations = 0
    !> the solver's stopping test was met *and* the scaled KKT residual is <= &solver tol
    !> (a step whose stopping test was met with a larger residual is not counted as converged)
    logical :: converged = .true.
    real(wp) :: primal = 0, dual = 0, compl = 0, stat = 0, kkt = 0
    integer :: n_rows = 0, n_active = 0, resolves = 0, n_inside = 0
    !> smallest true gap over the candidate rows after the step
    real(wp) :: min_gap = huge(1.0_wp)
    real(wp) :: t_solve = 0, t_step = 0
    !> sparse_active_set: numeric factorisations, factor row additions/deletions, solves handed
    !> to the safe path (summed over the re-solves of the step)
    integer :: n_factor = 0, n_modify = 0, n_fallback = 0
    !> active-set changes of the step: candidate rows active (lambda > 0) in the solution but
    !> not in the warm start, or the reverse (last solve of the step; any solver). An exact
    !> solver that updates a factor needs at least this many row additions and deletions.
    integer :: n_changes = 0
  end type step_record_t

  !> The state of a full-order simulation at its current step.
  type :: fom_state_t
    type(scene_t) :: scene
    !> the contact rows of the current step
    type(contact_set_t) :: cs
    integer :: n_agents = 0, step = 0
    !> body radius r and contact radius r + d_s / 2 (d_s: social distance), time step
    real(wp) :: radius = 0, contact_radius = 0, dt = 0
    !> positions, desired and actual velocities [2*n_agents]
    real(wp), allocatable :: q(:), v(:), u(:)
    !> speeds c_i [n_agents]
    real(wp), allocatable :: speeds(:)
    !> multipliers of the current rows [cs%n]
    real(wp), allocatable :: lambda(:)
    !> agents still in the hall [n_agents]
    logical, allocatable :: inside(:)
  end type fom_state_t
end module cr_fom_state
