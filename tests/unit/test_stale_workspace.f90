!> The solvers' results must not depend on what their reusable work space holds on entry.
!>
!> A work space (nnls_work_t, contact_ldp_work_t, the arrays kept in a projection solver) is
!> grown on demand and never shrunk, so between calls it holds the previous problem's numbers
!> (or, freshly allocated, whatever malloc returned: -finit-real=snan does not cover allocatable
!> memory). A solve that reads a part it has not written in this call (an early exit that skips
!> the step computing it, a range wider than the current problem) gives a result that depends on
!> that history. Here two work spaces get the same history (a larger problem first), then one of
!> them is poisoned (reals: signalling NaN, integers: a large negative index, logicals: .true.)
!> and both solve the same small problems on every path: normal, warm start, iteration cap,
!> early exits (no rows, feasible point, b = 0, zero column), infeasible data. The results must
!> be bitwise equal (same arithmetic on the same data). In the Debug build a read of a poisoned
!> real traps (-ffpe-trap=invalid) at the faulty line. scripts/dev/memcheck.sh covers the other half
!> (memory never written since malloc) under valgrind.
program test_stale_workspace
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_signaling_nan, ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_test_scenes, only: seed_random, lattice_scene
  use cr_contact_set, only: contact_set_t
  use cr_nnls, only: nnls_work_t, nnls_stats_t, ldp_stats_t, nnls_solve, ldp_solve
  use cr_contact_ldp, only: contact_ldp_work_t, contact_ldp_stats_t, contact_ldp_solve
  use cr_projection, only: projection_settings_t, solve_stats_t, projection_solver_t, &
    make_projection_solver
  use cr_active_set, only: active_set_solver_t
  use cr_apgd, only: apgd_solver_t
  use cr_uzawa, only: uzawa_solver_t
  use cr_gpcg, only: gpcg_solver_t
  implicit none
  real(wp), parameter :: rad = 0.05_wp, h = 0.01_wp
  integer, parameter :: bad_index = -1073741824
  real(wp) :: snan
  snan = ieee_value(1.0_wp, ieee_signaling_nan)
  call seed_random(2718)
  call test_nnls_paths()
  call test_ldp_paths()
  call test_contact_ldp_paths()
  call test_projection_solvers()
  call test_summary()

contains

  subroutine poison_r1(a)
    real(wp), allocatable, intent(inout) :: a(:)
    if (allocated(a)) a = snan
  end subroutine poison_r1

  subroutine poison_r2(a)
    real(wp), allocatable, intent(inout) :: a(:,:)
    if (allocated(a)) a = snan
  end subroutine poison_r2

  subroutine poison_i1(a)
    integer, allocatable, intent(inout) :: a(:)
    if (allocated(a)) a = bad_index
  end subroutine poison_i1

  subroutine poison_l1(a)
    logical, allocatable, intent(inout) :: a(:)
    if (allocated(a)) a = .true.
  end subroutine poison_l1

  !> every array of an NNLS work space (capacities kept)
  subroutine poison_nnls(w)
    type(nnls_work_t), intent(inout) :: w
    call poison_i1(w%col); call poison_i1(w%row); call poison_r1(w%val); call poison_r1(w%cs)
    call poison_r2(w%q); call poison_r2(w%r)
    call poison_r1(w%qtb); call poison_r1(w%z); call poison_r1(w%hv); call poison_r1(w%res)
    call poison_r1(w%bs); call poison_r1(w%x); call poison_r1(w%zp); call poison_r1(w%w)
    call poison_i1(w%plist); call poison_i1(w%pos); call poison_l1(w%refused)
    call poison_r2(w%e); call poison_r1(w%f); call poison_r1(w%y); call poison_l1(w%p0)
  end subroutine poison_nnls

  subroutine poison_cldp(w)
    type(contact_ldp_work_t), intent(inout) :: w
    call poison_r2(w%l); call poison_r1(w%h); call poison_r1(w%r); call poison_r1(w%z)
    call poison_r1(w%y); call poison_r1(w%x); call poison_r1(w%yc); call poison_i1(w%plist)
    call poison_i1(w%pos); call poison_l1(w%refused); call poison_r2(w%c); call poison_r1(w%dd)
    call poison_r1(w%lam); call poison_r1(w%slack); call poison_r1(w%cc); call poison_r1(w%rn)
  end subroutine poison_cldp

  !> the work arrays a projection solver keeps between solves
  subroutine poison_solver(s)
    class(projection_solver_t), intent(inout) :: s
    select type (s)
    type is (active_set_solver_t)
      call poison_nnls(s%work); call poison_cldp(s%cwork)
      call poison_i1(s%parent); call poison_i1(s%comp); call poison_i1(s%local)
      call poison_i1(s%agents); call poison_i1(s%astart); call poison_i1(s%rows)
      call poison_i1(s%rstart); call poison_r2(s%bm); call poison_r1(s%dl); call poison_r1(s%vl)
      call poison_r1(s%ul); call poison_r1(s%ll); call poison_i1(s%ial); call poison_i1(s%ibl)
      call poison_r2(s%cl)
    type is (apgd_solver_t)
      call poison_r1(s%y); call poison_r1(s%lnew); call poison_r1(s%g); call poison_r1(s%best)
      call poison_r1(s%w)
    type is (uzawa_solver_t)
      call poison_r1(s%uold); call poison_r1(s%lold); call poison_r1(s%bu); call poison_r1(s%btl)
    type is (gpcg_solver_t)
      call poison_r1(s%g); call poison_r1(s%p); call poison_r1(s%ap); call poison_r1(s%z)
      call poison_r1(s%dinv); call poison_r1(s%best); call poison_r1(s%w); call poison_r1(s%t)
      call poison_r1(s%ut)
    class default
      call check(.false., "poison_solver: no poisoning for solver " // s%name())
    end select
  end subroutine poison_solver

  !> bitwise equality of two real arrays (NaN never equal)
  logical function same(a, b)
    real(wp), intent(in) :: a(:), b(:)
    same = size(a) == size(b)
    if (same) same = all(a == b)
  end function same

  ! ------------------------------------------------------------------ NNLS
  subroutine test_nnls_paths()
    type(nnls_work_t) :: w1, w2
    character(len=*), parameter :: what(6) = [character(len=16) :: "cold", "warm", "cap", "b = 0", &
      "zero column", "equal columns"]
    integer :: c
    ! the same history: a larger problem grows both work spaces
    call nnls_pair(w1, w2, 30, 25, 0, "history")
    do c = 1, 6
      call nnls_pair(w1, w2, 12, 9, c, trim(what(c)))
    end do
  end subroutine test_nnls_paths

  subroutine nnls_pair(w1, w2, m, n, kase, what)
    type(nnls_work_t), intent(inout) :: w1, w2
    integer, intent(in) :: m, n, kase
    character(len=*), intent(in) :: what
    real(wp), allocatable :: a(:,:), b(:), x1(:), x2(:)
    logical, allocatable :: p0(:)
    type(nnls_stats_t) :: s1, s2
    type(error_t), allocatable :: e1, e2
    allocate(a(m, n), b(m), x1(n), x2(n), p0(n))
    call random_number(a); a = a - 0.3_wp
    call random_number(b); b = b - 0.2_wp
    p0 = .false.
    select case (kase)
    case (4); b = 0                    ! b = 0: early exit
    case (5); a(:, 3) = 0              ! a zero column (scale 0, never entered)
    case (6); a(:, 2) = a(:, 1)        ! duplicate column (refused as dependent)
    end select
    if (kase > 0) call poison_nnls(w2)
    select case (kase)
    case (2)                           ! warm start
      p0(1:n:2) = .true.
      call nnls_solve(a, b, x1, s1, e1, passive0=p0, work=w1)
      call nnls_solve(a, b, x2, s2, e2, passive0=p0, work=w2)
    case (3)                           ! iteration cap
      call nnls_solve(a, b, x1, s1, e1, max_iter=2, work=w1)
      call nnls_solve(a, b, x2, s2, e2, max_iter=2, work=w2)
    case default
      call nnls_solve(a, b, x1, s1, e1, work=w1)
      call nnls_solve(a, b, x2, s2, e2, work=w2)
    end select
    if (kase > 0) then
      call check(.not. (allocated(e1) .or. allocated(e2)), "nnls " // what // ": no error")
      call check(same(x1, x2) .and. s1%iterations == s2%iterations .and. &
        (s1%converged .eqv. s2%converged) .and. s1%n_passive == s2%n_passive .and. &
        same([s1%residual, s1%w_active_max, s1%w_passive_max, s1%kkt_rel], &
        [s2%residual, s2%w_active_max, s2%w_passive_max, s2%kkt_rel]), &
        "nnls " // what // ": result independent of the work space's content")
    end if
  end subroutine nnls_pair

  ! ------------------------------------------------------------------ dense LDP
  subroutine test_ldp_paths()
    type(nnls_work_t) :: w1, w2
    call ldp_pair(w1, w2, 20, 12, 0, "history")
    call ldp_pair(w1, w2, 8, 6, 1, "cold")
    call ldp_pair(w1, w2, 8, 6, 2, "warm")
    call ldp_pair(w1, w2, 8, 6, 3, "cap")
    call ldp_pair(w1, w2, 8, 6, 4, "infeasible")
    call ldp_pair(w1, w2, 8, 6, 5, "feasible v")
  end subroutine test_ldp_paths

  subroutine ldp_pair(w1, w2, m, n, kase, what)
    type(nnls_work_t), intent(inout) :: w1, w2
    integer, intent(in) :: m, n, kase
    character(len=*), intent(in) :: what
    real(wp), allocatable :: bm(:,:), d(:), v(:), u1(:), u2(:), l1(:), l2(:)
    type(ldp_stats_t) :: s1, s2
    type(error_t), allocatable :: e1, e2
    allocate(bm(m, n), d(m), v(n), u1(n), u2(n), l1(m), l2(m))
    call random_number(bm); bm = bm - 0.5_wp
    call random_number(d); d = d - 0.5_wp
    call random_number(v); v = 2 * v
    l1 = 0; l2 = 0
    select case (kase)
    case (2)
      call random_number(l1); l1 = l1 - 0.5_wp; l2 = l1
    case (4)                           ! x1 <= -1 and -x1 <= -1
      bm(1:2, :) = 0; bm(1, 1) = 1; bm(2, 1) = -1; d(1:2) = -1
    case (5)
      d = abs(d) + 1; v = 0
    end select
    if (kase > 0) call poison_nnls(w2)
    if (kase == 3) then
      call ldp_solve(bm, d, v, u1, l1, s1, e1, warm=.true., max_iter=2, work=w1)
      call ldp_solve(bm, d, v, u2, l2, s2, e2, warm=.true., max_iter=2, work=w2)
    else
      call ldp_solve(bm, d, v, u1, l1, s1, e1, warm=.true., work=w1)
      call ldp_solve(bm, d, v, u2, l2, s2, e2, warm=.true., work=w2)
    end if
    if (kase > 0) then
      call check(.not. (allocated(e1) .or. allocated(e2)), "ldp " // what // ": no error")
      if (kase == 4) call check(s1%infeasible, "ldp infeasible: flagged")
      call check(same(u1, u2) .and. same(l1, l2) .and. (s1%infeasible .eqv. s2%infeasible) .and. &
        s1%nnls%iterations == s2%nnls%iterations .and. same([s1%max_violation], [s2%max_violation]), &
        "ldp " // what // ": result independent of the work space's content")
    end if
  end subroutine ldp_pair

  ! ------------------------------------------------------------------ sparse dual LDP
  subroutine test_contact_ldp_paths()
    type(contact_ldp_work_t) :: w1, w2
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:)
    call lattice_scene(7, 6, 5, 0.03_wp, rad, h, cs, v, near_touch=.true.)
    call cldp_pair(w1, w2, cs, v, 0, "history")
    call lattice_scene(4, 3, 3, 0.03_wp, rad, h, cs, v, near_touch=.true.)
    call cldp_pair(w1, w2, cs, v, 1, "cold")
    call cldp_pair(w1, w2, cs, v, 2, "warm")
    call cldp_pair(w1, w2, cs, v, 3, "cap")
    call cldp_pair(w1, w2, cs, v, 4, "feasible v")
    call cldp_pair(w1, w2, cs, v, 5, "infeasible")
    call cldp_pair(w1, w2, cs, v, 6, "no rows")
  end subroutine test_contact_ldp_paths

  subroutine cldp_pair(w1, w2, cs, v, kase, what)
    type(contact_ldp_work_t), intent(inout) :: w1, w2
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    integer, intent(in) :: kase
    character(len=*), intent(in) :: what
    integer, allocatable :: ia(:), ib(:)
    real(wp), allocatable :: coef(:,:), d(:), vv(:), u1(:), u2(:), l1(:), l2(:)
    type(contact_ldp_stats_t) :: s1, s2
    type(error_t), allocatable :: e1, e2
    integer :: m
    m = cs%n
    ia = cs%ia(1:m); ib = cs%ib(1:m); coef = -h * cs%g(:, 1:m); d = cs%gap(1:m); vv = v
    select case (kase)
    case (4)
      vv = 0; d = abs(d) + 1.0e-3_wp
    case (5)                           ! agent 1 between two overlapping opposite walls
      ib(1:2) = 0; ia(1:2) = 1; coef(:, 1) = [h, 0.0_wp]; coef(:, 2) = [-h, 0.0_wp]
      d(1:2) = -1.0e-2_wp
    case (6)
      m = 0
      ia = ia(1:0); ib = ib(1:0); d = d(1:0)
      coef = reshape([real(wp) ::], [2, 0])
    end select
    allocate(u1(size(vv)), u2(size(vv)), l1(m), l2(m))
    l1 = 0; l2 = 0
    if (kase == 2) then
      call random_number(l1); l1 = l1 - 0.3_wp; l2 = l1
    end if
    if (kase > 0) call poison_cldp(w2)
    if (kase == 3) then
      call contact_ldp_solve(ia, ib, coef, d, vv, u1, l1, s1, e1, max_iter=2, work=w1)
      call contact_ldp_solve(ia, ib, coef, d, vv, u2, l2, s2, e2, max_iter=2, work=w2)
    else
      call contact_ldp_solve(ia, ib, coef, d, vv, u1, l1, s1, e1, work=w1)
      call contact_ldp_solve(ia, ib, coef, d, vv, u2, l2, s2, e2, work=w2)
    end if
    if (kase > 0) then
      call check(.not. (allocated(e1) .or. allocated(e2)), "contact_ldp " // what // ": no error")
      if (kase == 3) call check(.not. s1%converged, "contact_ldp cap: not converged")
      if (kase == 5) call check(s1%infeasible, "contact_ldp infeasible: flagged")
      call check(same(u1, u2) .and. (s1%infeasible .or. same(l1, l2)) .and. &
        (s1%converged .eqv. s2%converged) .and. (s1%infeasible .eqv. s2%infeasible) .and. &
        s1%iterations == s2%iterations .and. s1%n_passive == s2%n_passive .and. &
        same([s1%max_violation], [s2%max_violation]), &
        "contact_ldp " // what // ": result independent of the work space's content")
    end if
  end subroutine cldp_pair

  ! ------------------------------------------------------------------ projection solvers
  subroutine test_projection_solvers()
    character(len=10), parameter :: names(4) = [character(len=10) :: 'active_set', 'apgd', 'uzawa', 'gpcg']
    integer :: k
    do k = 1, size(names)
      call solver_pair(trim(names(k)))
    end do
  end subroutine test_projection_solvers

  subroutine solver_pair(name)
    character(len=*), intent(in) :: name
    class(projection_solver_t), allocatable :: s1, s2
    type(projection_settings_t) :: set
    type(error_t), allocatable :: err
    type(contact_set_t) :: cs
    real(wp), allocatable :: v(:)
    set = projection_settings_t()
    set%name = name
    set%tol = 1.0e-9_wp
    set%uzawa_max_iter = 3000
    call make_projection_solver(set, s1, err)
    call check(.not. allocated(err), name // ": built")
    if (allocated(err)) return
    call make_projection_solver(set, s2, err)
    call lattice_scene(7, 6, 5, 0.03_wp, rad, h, cs, v, near_touch=.true.)
    call run(s1, s2, set, cs, v, 0, name // " history")
    call lattice_scene(4, 3, 3, 0.03_wp, rad, h, cs, v, near_touch=.true.)
    call run(s1, s2, set, cs, v, 1, name // " cold")
    call run(s1, s2, set, cs, v, 2, name // " warm from the solution")
    call run(s1, s2, set, cs, v, 3, name // " cap")
    call run(s1, s2, set, cs, v, 4, name // " no rows")
    call run(s1, s2, set, cs, v, 5, name // " infeasible")
  end subroutine solver_pair

  subroutine run(s1, s2, set, cs, v, kase, what)
    class(projection_solver_t), intent(inout) :: s1, s2
    type(projection_settings_t), intent(in) :: set
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    integer, intent(in) :: kase
    character(len=*), intent(in) :: what
    type(contact_set_t) :: c
    real(wp), allocatable :: u1(:), u2(:), l1(:), l2(:)
    type(solve_stats_t) :: st1, st2
    type(error_t), allocatable :: e1, e2
    integer :: cap
    c = cs
    if (kase == 4) call c%init(cs%n_agents, h, 4)
    if (kase == 5) then                  ! agent 1 between two overlapping opposite walls
      call c%init(cs%n_agents, h, 4)
      call c%add(1, 0, 1, [1.0_wp, 0.0_wp], -1.0e-3_wp)
      call c%add(1, 0, 2, [-1.0_wp, 0.0_wp], -1.0e-3_wp)
    end if
    allocate(u1(size(v)), u2(size(v)), l1(max(c%n, 1)), l2(max(c%n, 1)))
    l1 = 0; l2 = 0
    if (kase == 2) then                  ! warm start from the solution
      call s1%solve(c, v, u1, l1, st1, e1)
      l2 = l1
    end if
    cap = s1%settings%max_iter
    if (kase == 3) then
      s1%settings%max_iter = 2; s2%settings%max_iter = 2
      s1%settings%uzawa_max_iter = 2; s2%settings%uzawa_max_iter = 2
    end if
    if (kase > 0) call poison_solver(s2)
    call s1%solve(c, v, u1, l1, st1, e1)
    call s2%solve(c, v, u2, l2, st2, e2)
    s1%settings%max_iter = cap; s2%settings%max_iter = cap
    s1%settings%uzawa_max_iter = set%uzawa_max_iter; s2%settings%uzawa_max_iter = set%uzawa_max_iter
    if (kase > 0) then
      call check(.not. (allocated(e1) .or. allocated(e2)), what // ": no error")
      call check(all(ieee_is_finite(u1)) .and. all(ieee_is_finite(l1(1:c%n))), what // ": u and lambda finite")
      ! gpcg: the infeasible pair of walls makes its dual unbounded along a null direction
      ! (it once took a step of length huge(1.0) there: overflow, SIGFPE in the Debug build)
      if (kase == 5 .and. s1%name() == 'gpcg') call check(.not. st1%converged .and. &
        index(st1%note, "unbounded") > 0, what // ": dual unbounded reported")
      call check(same(u1, u2) .and. same(l1(1:c%n), l2(1:c%n)) .and. &
        st1%iterations == st2%iterations .and. (st1%converged .eqv. st2%converged) .and. &
        same([st1%kkt], [st2%kkt]), what // ": result independent of the work space's content")
    end if
  end subroutine run

end program test_stale_workspace
