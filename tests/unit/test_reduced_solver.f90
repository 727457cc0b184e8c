!> The reduced solvers' factory: each known name builds its own variant (and reports its
!> name), the list of names agrees with is_reduced_solver, and an unknown name is refused with
!> a one-line bad-input error that names it and lists the known ones.
program test_reduced_solver
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_reduced_solver, only: rom_solver_cfg_t, reduced_solver_t, make_reduced_solver, &
    reduced_solver_names, known_reduced_solvers, is_reduced_solver
  use cr_reduced_dual, only: reduced_dual_t
  use cr_reduced_nnls, only: reduced_nnls_t
  use cr_reduced_uzawa, only: reduced_uzawa_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  type(rom_solver_cfg_t) :: cfg
  class(reduced_solver_t), allocatable :: solver
  type(error_t), allocatable :: error
  character(len=8) :: bad(4)
  integer :: i

  do i = 1, size(reduced_solver_names)
    cfg = rom_solver_cfg_t()
    cfg%name = reduced_solver_names(i)
    cfg%nnls_max_iter = 7 * i
    call make_reduced_solver(cfg, solver, error)
    call check(.not. allocated(error), "factory builds '" // trim(cfg%name) // "'")
    if (allocated(error)) cycle
    call check(solver%name() == trim(cfg%name), "'" // trim(cfg%name) // "' reports its name")
    call check(solver%cfg%nnls_max_iter == 7 * i, "'" // trim(cfg%name) // "' keeps its settings")
    call check(is_reduced_solver(cfg%name), "'" // trim(cfg%name) // "' is a known name")
    select type (solver)
    type is (reduced_dual_t)
      call check(cfg%name == 'dual', "'dual' builds reduced_dual_t (got '" // trim(cfg%name) // "')")
    type is (reduced_nnls_t)
      call check(cfg%name == 'nnls', "'nnls' builds reduced_nnls_t (got '" // trim(cfg%name) // "')")
    type is (reduced_uzawa_t)
      call check(cfg%name == 'uzawa', "'uzawa' builds reduced_uzawa_t (got '" // trim(cfg%name) // "')")
    class default
      call check(.false., "'" // trim(cfg%name) // "' builds a known variant")
    end select
    call check(index(known_reduced_solvers, "'" // trim(cfg%name) // "'") > 0, &
      "'" // trim(cfg%name) // "' is listed in the message of unknown names")
  end do
  call check(size(reduced_solver_names) == 3, "three reduced solvers")

  ! unknown names, near misses included: refused, one line, exit code 2 (bad input)
  bad = [character(len=8) :: 'lbfgs', 'Dual', 'nnls_', '']
  do i = 1, size(bad)
    cfg = rom_solver_cfg_t()
    cfg%name = bad(i)
    call make_reduced_solver(cfg, solver, error)
    call check(allocated(error), "unknown name '" // trim(bad(i)) // "' refused")
    call check(.not. is_reduced_solver(bad(i)), "'" // trim(bad(i)) // "' is not a known name")
    if (.not. allocated(error)) cycle
    call check(error%code == EXIT_BAD_INPUT, "unknown name '" // trim(bad(i)) // "': code 2")
    call check(index(error%message, "'" // trim(bad(i)) // "'") > 0, "the message names '" // &
      trim(bad(i)) // "'")
    call check(index(error%message, known_reduced_solvers) > 0, "the message lists the known names")
    call check(index(error%message, new_line('a')) == 0, "the message is one line")
    call check(.not. allocated(solver), "no solver built for '" // trim(bad(i)) // "'")
  end do
  call test_summary()
end program test_reduced_solver
