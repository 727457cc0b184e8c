!> The dual active-set solver (cr_dual_qp) against the Lawson-Hanson LDP (cr_nnls) on random,
!> degenerate (duplicate rows, dependent rows, more active rows than unknowns) and infeasible
!> problems. Two points that both satisfy the KKT conditions to the stated tolerance tau
!> (u = v - Bm^T lambda, lambda >= 0, s = d - Bm u >= -tau, |s_i| <= tau_i where lambda_i > 0)
!> differ by |u1 - u2|^2 <= (tau1 + tau2) . (lambda1 + lambda2), to which the rounding of
!> forming u = v - Bm^T lambda is added: that is the tolerance of every comparison. Warm and
!> cold starts, and Gram entries from a source or from the rows, give the same answer;
!> infeasible problems are never certified and are detected.
module test_dual_qp_src
  use cr_kinds, only: wp
  use cr_dual_qp, only: gram_source_t
  implicit none
  private
  public :: dense_gram_t

  !> Gram entries of a stored matrix (counts the entries asked for).
  type, extends(gram_source_t) :: dense_gram_t
    real(wp), allocatable :: b(:,:)
  contains
    procedure :: gram_entries
  end type dense_gram_t

contains

  subroutine gram_entries(this, p, idx, g)
    class(dense_gram_t), intent(in) :: this
    integer, intent(in) :: p, idx(:)
    real(wp), intent(out) :: g(:)
    integer :: j
    do j = 1, size(idx)
      g(j) = dot_product(this%b(p, :), this%b(idx(j), :))
    end do
  end subroutine gram_entries
end module test_dual_qp_src

program test_dual_qp
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_random, only: rng_t
  use cr_nnls, only: ldp_solve, ldp_stats_t
  use cr_dual_qp, only: dual_qp_t, dual_qp_stats_t, KKT_FACTOR
  use test_dual_qp_src, only: dense_gram_t
  implicit none
  type(rng_t) :: rng
  type(dual_qp_t) :: dqp
  integer :: trial, m, n, i, n_cert
  real(wp), allocatable :: b(:,:), d(:), v(:), x0(:), mu(:)
  character(len=64) :: tag

  call rng%seed(2026, 1)
  ! ---- random feasible problems, square to very tall
  n_cert = 0
  do trial = 1, 60
    n = 2 + mod(trial, 9) * 3
    m = 1 + mod(7 * trial, 4 * n + 5)
    call random_problem(m, n, 0.3_wp)
    write(tag, '(a,i0,a,i0,a,i0)') "random ", trial, ": ", m, " x ", n
    call compare(trim(tag), n_cert)
  end do
  call check(n_cert == 60, "random: every solve certified")

  ! ---- duplicate rows (the same constraint twice)
  n_cert = 0
  do trial = 1, 20
    n = 3 + mod(trial, 5) * 2
    m = 2 * n
    call random_problem(m, n, 0.0_wp)
    b(m / 2 + 1:m, :) = b(1:m / 2, :)
    d(m / 2 + 1:m) = d(1:m / 2)
    write(tag, '(a,i0)') "duplicate rows ", trial
    call compare(trim(tag), n_cert)
  end do
  call check(n_cert == 20, "duplicate rows: every solve certified")

  ! ---- dependent rows: row 3 = row 1 + row 2 (active together), scaled copies
  n_cert = 0
  do trial = 1, 20
    n = 4 + mod(trial, 4)
    m = n + 3
    call random_problem(m, n, 0.0_wp)
    b(3, :) = b(1, :) + b(2, :); d(3) = d(1) + d(2)
    b(m, :) = 4.0_wp * b(4, :); d(m) = 4.0_wp * d(4)
    write(tag, '(a,i0)') "dependent rows ", trial
    call compare(trim(tag), n_cert)
  end do
  call check(n_cert == 20, "dependent rows: every solve certified")

  ! ---- degenerate vertex: m > n rows through x0, v = x0 + Bm^T mu (projection x0)
  do trial = 1, 10
    n = 3 + mod(trial, 4)
    m = 2 * n + 1
    if (allocated(b)) deallocate(b, d, v)
    allocate(b(m, n), d(m), v(n), x0(n), mu(m))
    do i = 1, n
      x0(i) = rng%normal()
    end do
    do i = 1, m
      call fill_row(b(i, :))
      mu(i) = rng%uniform()
    end do
    d = matmul(b, x0)
    v = x0 + matmul(mu, b)
    write(tag, '(a,i0)') "degenerate vertex ", trial
    call compare(trim(tag), n_cert, x0)
    deallocate(x0, mu)
  end do

  ! ---- infeasible problems: never certified, detected
  do trial = 1, 20
    n = 2 + mod(trial, 6)
    m = n + 4
    call random_problem(m, n, 0.3_wp)
    select case (mod(trial, 2))
    case (0)
      ! b_1 u <= d_1 and -b_1 u <= -d_1 - 1
      b(2, :) = -b(1, :); d(2) = -d(1) - 1.0_wp
    case default
      ! a positive combination of three rows is zero with a negative right-hand side
      b(3, :) = -(b(1, :) + 2.0_wp * b(2, :)); d(3) = -(d(1) + 2.0_wp * d(2)) - 0.5_wp
    end select
    write(tag, '(a,i0)') "infeasible ", trial
    call infeasible_case(trim(tag))
  end do

  ! ---- an early exit (overfull warm start, before any sweep) after a solve of another size,
  ! with a work space holding NaN: the reported violation is that of the returned u
  do trial = 1, 10
    n = 3 + mod(trial, 5)
    m = 2 * n + trial
    call random_problem(m, n, 0.3_wp)
    write(tag, '(a,i0)') "early exit ", trial
    call early_exit_case(trim(tag))
  end do
  call test_summary()

contains

  !> Unit-ish random row.
  subroutine fill_row(r)
    real(wp), intent(out) :: r(:)
    integer :: j
    do j = 1, size(r)
      r(j) = rng%normal()
    end do
  end subroutine fill_row

  !> Random Bm [m, n], v, and d = Bm x0 + slack: a feasible set containing x0, with a
  !> fraction `loose` of the rows given a positive slack and v outside for most rows.
  subroutine random_problem(m, n, loose)
    integer, intent(in) :: m, n
    real(wp), intent(in) :: loose
    integer :: i, j
    if (allocated(b)) deallocate(b, d, v)
    allocate(b(m, n), d(m), v(n), x0(n))
    do j = 1, n
      x0(j) = rng%normal()
      v(j) = x0(j) + 3.0_wp * rng%normal()
    end do
    do i = 1, m
      call fill_row(b(i, :))
      ! rows of very different scales
      b(i, :) = b(i, :) * 10.0_wp**(2 * rng%uniform() - 1)
    end do
    d = matmul(b, x0)
    do i = 1, m
      if (rng%uniform() < loose) d(i) = d(i) + abs(rng%normal()) * norm2(b(i, :))
    end do
    deallocate(x0)
  end subroutine random_problem

  !> tau_i of the stated KKT certificate at u.
  function kkt_tau(u) result(tau)
    real(wp), intent(in) :: u(:)
    real(wp) :: tau(size(d))
    integer :: i
    do i = 1, size(d)
      tau(i) = KKT_FACTOR * epsilon(1.0_wp) * (norm2(b(i, :)) * norm2(u) + abs(d(i)))
    end do
  end function kkt_tau

  !> Tolerance of |u1 - u2| for two KKT points to tau (see the header): the bound plus the
  !> rounding of forming u = v - Bm^T lambda (n eps (|v| + sum lambda_i |b_i|) each).
  real(wp) function dist_tol(u1, l1, u2, l2) result(t)
    real(wp), intent(in) :: u1(:), l1(:), u2(:), l2(:)
    real(wp) :: form
    integer :: i
    form = 2 * norm2(v)
    do i = 1, size(d)
      form = form + (l1(i) + l2(i)) * norm2(b(i, :))
    end do
    t = sqrt(sum((kkt_tau(u1) + kkt_tau(u2)) * (l1 + l2))) + size(v) * epsilon(1.0_wp) * form
  end function dist_tol

  !> The certificate checked independently of the solver.
  logical function kkt_ok(u, lam) result(ok)
    real(wp), intent(in) :: u(:), lam(:)
    real(wp) :: s(size(d)), tau(size(d))
    s = d - matmul(b, u)
    tau = kkt_tau(u)
    ok = all(lam >= 0) .and. all(s >= -tau) .and. all(lam == 0 .or. abs(s) <= tau)
  end function kkt_ok

  !> Dual active set (cold, warm from its own answer, warm from a wrong guess, with a Gram
  !> source) against the LDP; counts certified cold solves. With x_exact, also against it.
  subroutine compare(tag, n_cert, x_exact)
    character(len=*), intent(in) :: tag
    integer, intent(inout) :: n_cert
    real(wp), intent(in), optional :: x_exact(:)
    real(wp) :: u(size(v)), lam(size(d)), u2(size(v)), lam2(size(d)), ur(size(v)), lr(size(d))
    type(dual_qp_stats_t) :: st, st2
    type(ldp_stats_t) :: lst
    type(error_t), allocatable :: error
    type(dense_gram_t) :: src
    real(wp), allocatable :: bt(:,:)
    integer :: i
    bt = transpose(b)
    lam = 0
    call dqp%solve(bt, d, v, u, lam, st, warm=.false.)
    if (st%certified) n_cert = n_cert + 1
    call check(st%certified .and. .not. st%infeasible, tag // ": certified")
    call check(kkt_ok(u, lam), tag // ": KKT to the stated tolerance")
    lr = 0
    call ldp_solve(b, d, v, ur, lr, lst, error, warm=.false.)
    call check(.not. allocated(error) .and. .not. lst%infeasible, tag // ": reference LDP solved")
    call check(norm2(u - ur) <= dist_tol(u, lam, ur, lr), tag // ": same projection as the LDP")
    if (present(x_exact)) call check(norm2(u - x_exact) <= dist_tol(u, lam, x_exact, lam), &
      tag // ": the known projection")
    ! warm from its own answer: no iteration, same point
    lam2 = lam
    call dqp%solve(bt, d, v, u2, lam2, st2, warm=.true.)
    call check(st2%certified .and. st2%adds == 0, tag // ": warm from the answer adds nothing")
    call check(norm2(u2 - u) <= dist_tol(u, lam, u2, lam2), tag // ": warm = cold")
    ! warm from a wrong guess (every other row)
    lam2 = [(merge(1.0_wp, 0.0_wp, mod(i, 2) == 0), i = 1, size(d))]
    call dqp%solve(bt, d, v, u2, lam2, st2, warm=.true.)
    call check(st2%certified, tag // ": warm from a wrong guess certified")
    call check(norm2(u2 - u) <= dist_tol(u, lam, u2, lam2), tag // ": wrong guess = cold")
    ! an active-set bound below the answer's size hands over (not certified)
    if (st%n_active > 0) then
      lam2 = 0
      call dqp%solve(bt, d, v, u2, lam2, st2, warm=.false., max_active=st%n_active - 1)
      call check(st2%overfull .and. .not. st2%certified, tag // ": max_active below the answer: handed over")
      lam2 = lam
      call dqp%solve(bt, d, v, u2, lam2, st2, warm=.true., max_active=st%n_active)
      call check(st2%certified .and. .not. st2%overfull, tag // ": max_active = the answer's size: certified")
    end if
    ! Gram entries from a source
    src%b = b
    lam2 = 0
    call dqp%solve(bt, d, v, u2, lam2, st2, warm=.false., gsrc=src)
    call check(st2%certified, tag // ": Gram source certified")
    call check(norm2(u2 - u) <= dist_tol(u, lam, u2, lam2), tag // ": Gram source = rows")
  end subroutine compare

  !> Infeasible: never certified, detected as infeasible, and the LDP agrees it is.
  subroutine infeasible_case(tag)
    character(len=*), intent(in) :: tag
    real(wp) :: u(size(v)), lam(size(d)), ur(size(v)), lr(size(d))
    type(dual_qp_stats_t) :: st
    type(ldp_stats_t) :: lst
    type(error_t), allocatable :: error
    real(wp), allocatable :: bt(:,:)
    bt = transpose(b)
    lam = 0
    call dqp%solve(bt, d, v, u, lam, st, warm=.false.)
    call check(.not. st%certified, tag // ": not certified")
    call check(st%infeasible, tag // ": detected")
    call check(all(lam >= 0) .and. all(abs(u) < huge(1.0_wp)), tag // ": finite iterate")
    lr = 0
    call ldp_solve(b, d, v, ur, lr, lst, error, warm=.false.)
    call check(.not. allocated(error) .and. lst%infeasible, tag // ": LDP flags it too")
  end subroutine infeasible_case

  !> Overfull warm start (more guessed rows than max_active): handed over with u = v, and
  !> max_violation = max_i (Bm v - d)_i^+ even when the work space holds NaN from before
  !> (tolerance: the rounding of Bm v - d, m eps (|b_i| |v| + |d_i|)).
  subroutine early_exit_case(tag)
    use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
    character(len=*), intent(in) :: tag
    real(wp) :: u(size(v)), lam(size(d)), ref, tol
    type(dual_qp_stats_t) :: st
    real(wp), allocatable :: bt(:,:)
    integer :: i
    bt = transpose(b)
    ! a solve first, so the work space exists, then NaN in it
    lam = 0
    call dqp%solve(bt, d, v, u, lam, st, warm=.false.)
    dqp%s = ieee_value(1.0_wp, ieee_quiet_nan)
    dqp%tau = ieee_value(1.0_wp, ieee_quiet_nan)
    lam = 1
    call dqp%solve(bt, d, v, u, lam, st, warm=.true., max_active=1)
    call check(st%overfull .and. .not. st%certified, tag // ": overfull, handed over")
    call check(all(u == v) .and. all(lam == 0), tag // ": u = v, lambda = 0")
    ref = 0; tol = 0
    do i = 1, size(d)
      ref = max(ref, dot_product(b(i, :), v) - d(i))
      tol = max(tol, size(d) * epsilon(1.0_wp) * (norm2(b(i, :)) * norm2(v) + abs(d(i))))
    end do
    call check(abs(st%max_violation - ref) <= tol, tag // ": max_violation of u = v")
  end subroutine early_exit_case
end program test_dual_qp
