!> A warm-started problem on which the dense kernel (cr_contact_ldp, solver active_set) once
!> returned a scaled KKT residual of 9.7e21 while reporting convergence: 456 agents, 2 116 rows,
!> 1 242 warm rows (from a stress trajectory of the sparse solver). The warm set
!> held nearly dependent rows (pivots down to 1.7e-5 of the diagonal), so that yc =
!> L^{-1} (B v - d)_P grew to 1e27; the warm start's deletions rotated it with L, leaving an
!> absolute error of eps |yc| that was never recomputed, and the stopping test looked only at
!> the rows outside P. Now yc is recomputed from the right-hand side after the warm start's
!> deletions and before each refinement, and a solve whose passive slacks exceed the threshold
!> is not converged (the caller's safe path takes it). The test: the warm solve and a cold one
!> both end converged at KKT <= tol, and converged implies KKT <= tol.
!> File (stream, native byte order): n_agents, n_rows (int32), h (real64), then ia, ib, ob
!> [n_rows] (int32), g [2, n_rows], gap [n_rows], v [2 n_agents], warm lambda [n_rows] (real64).
program test_ldp_replay
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_contact_set, only: contact_set_t
  use cr_projection, only: projection_settings_t, solve_stats_t, projection_solver_t, make_projection_solver
  implicit none
  type(contact_set_t) :: cs
  class(projection_solver_t), allocatable :: sa
  type(projection_settings_t) :: s
  type(solve_stats_t) :: st
  type(error_t), allocatable :: err
  integer :: na, n, fu, k, ios, var
  real(wp) :: h
  integer, allocatable :: ia(:), ib(:), ob(:)
  real(wp), allocatable :: g(:, :), gap(:), v(:), lw(:), la(:), u(:)
  character(len=512) :: fn
  call get_command_argument(1, fn)
  open(newunit=fu, file=trim(fn), access='stream', form='unformatted', status='old', action='read', iostat=ios)
  call check(ios == 0, "replay: the problem file opens")
  if (ios /= 0) then
    call test_summary(); stop
  end if
  read(fu) na, n, h
  allocate(ia(n), ib(n), ob(n), g(2, n), gap(n), v(2 * na), lw(n), la(n), u(2 * na))
  read(fu) ia, ib, ob, g, gap, v, lw
  close(fu)
  call cs%init(na, h, n)
  do k = 1, n
    call cs%add(ia(k), ib(k), ob(k), g(:, k), gap(k))
  end do
  s = projection_settings_t(); s%name = 'active_set'
  call make_projection_solver(s, sa, err)
  call check(.not. allocated(err), "replay: active_set made")
  do var = 1, 2
    la = 0
    if (var == 1) la = lw
    call sa%solve(cs, v, u, la, st, err)
    print '(2x,a,a,l2,a,es10.3,a,i0)', merge("warm", "cold", var == 1), ": converged", st%converged, &
      " KKT", st%kkt, " iterations ", st%iterations
    call check(.not. allocated(err), "replay: no error (" // merge("warm", "cold", var == 1) // ")")
    call check(.not. st%converged .or. st%kkt <= s%tol, "replay: converged implies KKT <= tol (" // &
      merge("warm", "cold", var == 1) // ")")
    call check(st%converged .and. st%kkt <= s%tol, "replay: solved to KKT <= tol (" // &
      merge("warm", "cold", var == 1) // ")")
  end do
  call test_summary()
end program test_ldp_replay
