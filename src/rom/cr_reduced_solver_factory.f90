!> Factory of the reduced solvers (submodule of cr_reduced_solver, so that the abstract module
!> does not depend on its variants). A new solver adds its name to reduced_solver_names and
!> one `case` here.
submodule (cr_reduced_solver) cr_reduced_solver_factory
  use cr_error, only: set_error
  use cr_reduced_dual, only: reduced_dual_t
  use cr_reduced_nnls, only: reduced_nnls_t
  use cr_reduced_uzawa, only: reduced_uzawa_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
contains
  module subroutine make_reduced_solver(cfg, solver, error)
    type(rom_solver_cfg_t), intent(in) :: cfg
    class(reduced_solver_t), allocatable, intent(out) :: solver
    type(error_t), allocatable, intent(out) :: error
    select case (trim(cfg%name))
    case ('dual')
      allocate(reduced_dual_t :: solver)
    case ('nnls')
      allocate(reduced_nnls_t :: solver)
    case ('uzawa')
      allocate(reduced_uzawa_t :: solver)
    case default
      call set_error(error, "make_reduced_solver: unknown reduced solver '" // trim(cfg%name) // &
        "'; known names: " // known_reduced_solvers, EXIT_BAD_INPUT)
      return
    end select
    call solver%init(cfg)
  end subroutine make_reduced_solver
end submodule cr_reduced_solver_factory
