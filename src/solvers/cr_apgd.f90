!> Accelerated projected gradient on the dual of the projection problem:
!>   min_{lambda >= 0} f(lambda) = 1/2 |B^T lambda|^2 - lambda^T (B v - d),
!>   grad f(lambda) = d - B u(lambda),  u(lambda) = v - B^T lambda,
!> FISTA (Nesterov momentum) with fixed step 1/L, L = lipschitz_bound >= ||B||^2, and the
!> gradient restart of O'Donoghue & Candes: momentum is reset when
!> (y_k - lambda_{k+1})^T (lambda_{k+1} - lambda_k) > 0. The scaled KKT residual of
!> (u(lambda), lambda) is checked every check_every iterations; the best iterate is returned.
module cr_apgd
  use cr_kinds, only: wp
  use cr_grow, only: grow => grow_real
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t, velocity_scale
  use cr_projection, only: projection_solver_t, solve_stats_t, finish_stats, check_sizes, add_note
  implicit none
  private
  public :: apgd_solver_t

  !> iterations between two KKT checks
  integer, parameter :: check_every = 10

  !> Accelerated projected gradient (FISTA with restart) on the dual.
  type, extends(projection_solver_t) :: apgd_solver_t
    !> work arrays kept between solves: [n rows] and [2*n_agents]
    real(wp), allocatable :: y(:), lnew(:), g(:), best(:), w(:)
  contains
    procedure :: solve => apgd_solve
    procedure :: free => apgd_free
  end type apgd_solver_t

contains

  subroutine apgd_solve(this, cs, v, u, lambda, stats, error)
    class(apgd_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer :: n, nd, k, l
    real(wp) :: lb, t, tn, sv, kkt, best_kkt, p, c

    call check_sizes("apgd", cs, v, u, lambda, error)
    if (allocated(error)) return
    n = cs%n; nd = size(v)
    stats%note = ""
    call grow(this%y, n); call grow(this%lnew, n); call grow(this%g, n); call grow(this%best, n)
    call grow(this%w, nd)
    if (.not. this%settings%warm_start) lambda(1:n) = 0.0_wp
    lambda(1:n) = max(lambda(1:n), 0.0_wp)
    lb = cs%lipschitz_bound()
    if (n == 0 .or. .not. (lb > 0.0_wp)) then
      u = v
      lambda(1:n) = 0.0_wp
      stats%converged = .true.
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      return
    end if
    sv = velocity_scale(cs, v)
    this%y(1:n) = lambda(1:n)
    this%best(1:n) = lambda(1:n)
    best_kkt = huge(1.0_wp)
    t = 1.0_wp
    k = 0
    do
      ! KKT check of the current lambda (also at k = 0: a warm start may already be optimal)
      if (mod(k, check_every) == 0 .or. k == this%settings%max_iter) then
        call cs%apply_bt(lambda(1:n), this%w(1:nd))
        u = v - this%w(1:nd)
        call cs%apply_b(u, this%g(1:n))
        kkt = 0.0_wp
        do l = 1, n
          c = this%g(l) - cs%gap(l)
          p = max(c, 0.0_wp) / (cs%h * sv)
          kkt = max(kkt, p, abs(lambda(l) * c) / sv**2)
        end do
        if (kkt < best_kkt) then
          best_kkt = kkt
          this%best(1:n) = lambda(1:n)
        end if
        if (kkt <= this%settings%tol) then
          stats%converged = .true.
          exit
        end if
        if (k == this%settings%max_iter) exit
      end if
      k = k + 1
      ! gradient at y
      call cs%apply_bt(this%y(1:n), this%w(1:nd))
      u = v - this%w(1:nd)
      call cs%apply_b(u, this%g(1:n))
      this%g(1:n) = cs%gap(1:n) - this%g(1:n)
      this%lnew(1:n) = max(0.0_wp, this%y(1:n) - this%g(1:n) / lb)
      if (dot_product(this%y(1:n) - this%lnew(1:n), this%lnew(1:n) - lambda(1:n)) > 0.0_wp) then
        t = 1.0_wp
        this%y(1:n) = this%lnew(1:n)
      else
        tn = 0.5_wp * (1.0_wp + sqrt(1.0_wp + 4.0_wp * t * t))
        this%y(1:n) = this%lnew(1:n) + ((t - 1.0_wp) / tn) * (this%lnew(1:n) - lambda(1:n))
        t = tn
      end if
      lambda(1:n) = this%lnew(1:n)
    end do
    stats%iterations = k
    lambda(1:n) = this%best(1:n)
    call cs%apply_bt(lambda(1:n), this%w(1:nd))
    u = v - this%w(1:nd)
    if (.not. stats%converged) call add_note(stats, "iteration cap reached (" // &
      str(this%settings%max_iter) // "), best KKT residual " // str(best_kkt, "es9.2"))
    call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
  end subroutine apgd_solve

  subroutine apgd_free(this)
    class(apgd_solver_t), intent(inout) :: this
    if (allocated(this%y)) deallocate(this%y, this%lnew, this%g, this%best, this%w)
  end subroutine apgd_free
end module cr_apgd
