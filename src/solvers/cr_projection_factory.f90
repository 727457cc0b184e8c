!> Factory of the projection solvers (submodule of cr_projection, so that the abstract module
!> does not depend on its variants).
submodule (cr_projection) cr_projection_factory
  use cr_strings, only: to_lower
  use cr_uzawa, only: uzawa_solver_t
  use cr_apgd, only: apgd_solver_t
  use cr_active_set, only: active_set_solver_t
  use cr_gpcg, only: gpcg_solver_t
  use cr_sparse_as, only: sparse_as_solver_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
contains
  module subroutine make_projection_solver(settings, solver, error)
    type(projection_settings_t), intent(in) :: settings
    class(projection_solver_t), allocatable, intent(out) :: solver
    type(error_t), allocatable, intent(out) :: error
    type(projection_settings_t) :: s
    s = settings
    s%name = to_lower(adjustl(settings%name))
    select case (trim(s%name))
    case ('uzawa')
      allocate(uzawa_solver_t :: solver)
    case ('apgd')
      allocate(apgd_solver_t :: solver)
    case ('active_set')
      allocate(active_set_solver_t :: solver)
    case ('sparse_active_set')
      allocate(sparse_as_solver_t :: solver)
    case ('gpcg')
      allocate(gpcg_solver_t :: solver)
    case default
      call set_error(error, "make_projection_solver: unknown solver name '" // &
        trim(settings%name) // "'; known names: " // known_projection_solvers, EXIT_BAD_INPUT)
      return
    end select
    call solver%init(s, error)
  end subroutine make_projection_solver
end submodule cr_projection_factory
