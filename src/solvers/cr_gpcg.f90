!> Exact, matrix-free projection by gradient projection + conjugate gradients on the dual,
!> an active-face method of the GPCG family (More & Toraldo, SIAM J. Optim. 1, 1991) in the
!> proportioning form of Dostal's MPRGP (Dostal & Schoeberl, Comput. Optim. Appl. 30, 2005),
!> which keeps CG running across bound changes and copes with degenerate (jammed) problems:
!>   min_{lambda >= 0} f(lambda) = 1/2 |B^T lambda|^2 - lambda^T (B v - d),
!>   g = grad f = d - B u(lambda),  u(lambda) = v - B^T lambda,  A = B B^T.
!>
!> Jacobi scaling: D = diag A = h^2 |g_l|^2 (2 for agent pairs, 1 for obstacle rows); the method
!> runs in the variables D^{1/2} lambda (bounds unchanged), i.e. with the preconditioner D^{-1}.
!> Free gradient phi_l = g_l where lambda_l > 0 (else 0); chopped gradient beta_l = min(g_l, 0)
!> where lambda_l = 0 (else 0). Each iteration is one of
!> - CG step on the current face (matrix-free A p = B (B^T p), p zero on bound rows), taken when
!>   the face gradient dominates (|beta|^2_{D^-1} <= Gamma^2 phi~^T D^-1 phi) and the CG step stays
!>   feasible;
!> - expansion step, when the CG step would cross a bound: step to the first bound along p, then
!>   one projected gradient step lambda <- max(lambda - abar D^-1 phi, 0) with a fixed step
!>   abar = 1.9 / (Gershgorin bound of ||D^-1/2 A D^-1/2||), which fixes many bounds at once;
!>   CG restarts on the new face;
!> - proportioning step, when bound rows want to leave their bound (beta dominates): exact line
!>   minimisation along -D^-1 beta, releasing all of them at once; CG restarts.
!> f decreases at every step (R-linear convergence for any Gamma > 0, abar in (0, 2/||A||]).
!> Singular faces (B_F B_F^T singular) are consistent and CG converges on them; a direction of
!> zero curvature is followed to the nearest bound (or flags an unbounded dual = infeasible
!> constraints). The gradient is updated by recurrences and recomputed from scratch after every
!> expansion step and whenever the recurrence says converged; the stopping test is the scaled
!> KKT residual of kkt_residuals computed from g (primal from -g, complementarity from lambda g;
!> dual and stationarity vanish by construction). Iterations = CG + expansion + proportioning
!> steps (one product with A each, plus one more per expansion step).
module cr_gpcg
  use cr_kinds, only: wp
  use cr_grow, only: grow => grow_real
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t, velocity_scale
  use cr_projection, only: projection_solver_t, solve_stats_t, finish_stats, check_sizes, add_note
  implicit none
  private
  public :: gpcg_solver_t

  !> proportioning parameter Gamma
  real(wp), parameter :: gamma_prop = 1.0_wp
  !> fixed step of the expansion step, relative to 1 / (bound of ||D^-1/2 A D^-1/2||)
  real(wp), parameter :: abar_factor = 1.9_wp
  !> relative curvature below which a direction counts as a null direction of A
  real(wp), parameter :: curv_tol = 1.0e-14_wp

  !> Gradient projection + conjugate gradients (MPRGP form) on the dual; exact up to tol.
  type, extends(projection_solver_t) :: gpcg_solver_t
    !> work arrays over rows, kept between solves and grown when needed [n rows]
    real(wp), allocatable :: g(:), p(:), ap(:), z(:), dinv(:), best(:)
    !> work arrays over velocities (B^T lambda, B^T p, scratch) [2*n_agents]
    real(wp), allocatable :: w(:), t(:), ut(:)
  contains
    procedure :: solve => gpcg_solve
    procedure :: free => gpcg_free
  end type gpcg_solver_t

  !> The state of one solve shared by its parts: sizes, iteration counts, scaling and the
  !> best fresh KKT residual.
  type :: gpcg_run_t
    !> rows, velocities, agents
    integer :: n = 0, nd = 0, na = 0
    !> iterations; gradients from scratch, expansion and proportioning steps
    integer :: iter = 0, n_refresh = 0, n_exp = 0, n_prop = 0
    !> velocity scale, fixed step of the expansion step, best KKT residual of a fresh gradient
    real(wp) :: sv = 0.0_wp, abar = 0.0_wp, best_kkt = 0.0_wp
    !> a null direction with no bound ahead was found; g is computed from scratch
    logical :: unbounded = .false., fresh = .false.
  end type gpcg_run_t

contains

  subroutine gpcg_solve(this, cs, v, u, lambda, stats, error)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    type(gpcg_run_t) :: rs
    integer :: n, nd, max_iter
    real(wp) :: kkt, tol

    call check_sizes("gpcg", cs, v, u, lambda, error)
    if (allocated(error)) return
    n = cs%n; nd = size(v)
    rs%n = n; rs%nd = nd; rs%na = cs%n_agents
    tol = this%settings%tol
    max_iter = this%settings%max_iter
    stats%note = ""
    if (.not. this%settings%warm_start) lambda(1:n) = 0.0_wp
    lambda(1:n) = max(lambda(1:n), 0.0_wp)
    if (n == 0) then
      u = v
      stats%converged = .true.
      call finish_stats(cs, v, u, lambda, tol, stats)
      return
    end if
    call grow(this%g, n); call grow(this%p, n); call grow(this%ap, n); call grow(this%z, n)
    call grow(this%dinv, n); call grow(this%best, n)
    call grow(this%w, nd); call grow(this%t, nd); call grow(this%ut, nd)
    call jacobi_scaling(this, cs, rs)
    rs%sv = velocity_scale(cs, v)
    call gpcg_iterate(this, cs, v, lambda, tol, max_iter, rs, stats%converged)

    ! the last iterate may be better than the best fresh one
    if (.not. stats%converged .and. .not. rs%fresh) then
      call refresh(this, cs, v, lambda, rs)
      kkt = kkt_of_g(this, cs, lambda, rs)
      if (kkt < rs%best_kkt) then
        rs%best_kkt = kkt
        this%best(1:n) = lambda(1:n)
      end if
    end if
    stats%iterations = rs%iter
    lambda(1:n) = this%best(1:n)
    call cs%apply_bt(lambda(1:n), this%w(1:nd))
    u = v - this%w(1:nd)
    if (.not. stats%converged) then
      if (rs%unbounded) then
        call add_note(stats, "dual unbounded along a null direction: the constraints B u <= d " // &
          "are infeasible")
      else
        call add_note(stats, "iteration cap reached (" // str(max_iter) // &
          "), best KKT residual " // str(rs%best_kkt, "es9.2"))
      end if
    end if
    call finish_stats(cs, v, u, lambda, tol, stats)
  end subroutine gpcg_solve

  !> Jacobi scaling dinv = D^-1 and the fixed step abar from the Gershgorin bound of
  !> ||D^-1/2 A D^-1/2||: |A_lm| <= h^2 |g_l| |g_m|, so row l sums to at most c_l (S_ia + S_ib)
  !> with c_l = h |g_l| D_l^-1/2, S_a = sum of c_m over the rows m touching agent a.
  subroutine jacobi_scaling(this, cs, rs)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    type(gpcg_run_t), intent(inout) :: rs
    integer :: l, a, b
    real(wp) :: sa, bound
    this%ut(1:rs%na) = 0.0_wp
    do l = 1, rs%n
      if (cs%ib(l) > 0) then
        this%dinv(l) = 1.0_wp / (2.0_wp * cs%h**2 * sum(cs%g(:, l)**2))
      else
        this%dinv(l) = 1.0_wp / (cs%h**2 * sum(cs%g(:, l)**2))
      end if
      sa = cs%h * norm2(cs%g(:, l)) * sqrt(this%dinv(l))
      a = cs%ia(l); b = cs%ib(l)
      this%ut(a) = this%ut(a) + sa
      if (b > 0) this%ut(b) = this%ut(b) + sa
    end do
    bound = 0.0_wp
    do l = 1, rs%n
      sa = this%ut(cs%ia(l))
      if (cs%ib(l) > 0) sa = sa + this%ut(cs%ib(l))
      bound = max(bound, cs%h * norm2(cs%g(:, l)) * sqrt(this%dinv(l)) * sa)
    end do
    rs%abar = abar_factor / bound
  end subroutine jacobi_scaling

  !> The iteration from lambda: CG, expansion and proportioning steps until the KKT residual
  !> of a fresh gradient is <= tol (converged), the cap max_iter or an unbounded dual; the
  !> best fresh iterate is kept in this%best.
  subroutine gpcg_iterate(this, cs, v, lambda, tol, max_iter, rs, converged)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(inout) :: lambda(:)
    real(wp), intent(in) :: tol
    integer, intent(in) :: max_iter
    type(gpcg_run_t), intent(inout) :: rs
    logical, intent(inout) :: converged
    integer :: l, n
    real(wp) :: kkt, beta2, prop
    n = rs%n
    rs%iter = 0; rs%n_refresh = 0; rs%n_exp = 0; rs%n_prop = 0
    rs%unbounded = .false.
    rs%best_kkt = huge(1.0_wp)
    call refresh(this, cs, v, lambda, rs)
    rs%fresh = .true.
    call new_direction(this, lambda, rs)
    do
      kkt = kkt_of_g(this, cs, lambda, rs)
      if (kkt <= tol .and. .not. rs%fresh) then
        ! confirm with a gradient computed from scratch
        call refresh(this, cs, v, lambda, rs)
        rs%fresh = .true.
        kkt = kkt_of_g(this, cs, lambda, rs)
        call new_direction(this, lambda, rs)
      end if
      if (rs%fresh) then
        if (kkt < rs%best_kkt) then
          rs%best_kkt = kkt
          this%best(1:n) = lambda(1:n)
        end if
      end if
      if (kkt <= tol) then
        converged = .true.
        exit
      end if
      if (rs%iter >= max_iter .or. rs%unbounded) exit
      rs%iter = rs%iter + 1
      rs%fresh = .false.
      ! proportionality test: |beta|^2 <= Gamma^2 phi~^T phi (all in the D^-1 metric)
      beta2 = 0.0_wp; prop = 0.0_wp
      do l = 1, n
        if (lambda(l) > 0.0_wp) then
          prop = prop + min(lambda(l) / (rs%abar * this%dinv(l)), this%g(l)) * this%g(l) * this%dinv(l)
        else if (this%g(l) < 0.0_wp) then
          beta2 = beta2 + this%g(l)**2 * this%dinv(l)
        end if
      end do
      if (beta2 <= gamma_prop**2 * prop) then
        call cg_step(this, cs, v, lambda, rs)
      else
        call proportioning_step(this, cs, lambda, beta2, rs)
      end if
    end do
  end subroutine gpcg_iterate

  !> CG step along p on the face; when it would cross a bound, an expansion step: to the
  !> first bound, then a fixed-step projected gradient step (CG restarts).
  subroutine cg_step(this, cs, v, lambda, rs)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(inout) :: lambda(:)
    type(gpcg_run_t), intent(inout) :: rs
    integer :: l, n
    real(wp) :: gp, pap, pdp, acg, af, gam
    n = rs%n
    gp = dot_product(this%g(1:n), this%p(1:n))
    if (.not. (gp > 0.0_wp)) then
      call new_direction(this, lambda, rs)
      gp = dot_product(this%g(1:n), this%p(1:n))
      if (.not. (gp > 0.0_wp)) return
    end if
    call product(this, cs, this%p, rs, pap, pdp)
    af = huge(1.0_wp)
    do l = 1, n
      if (this%p(l) > 0.0_wp) af = min(af, lambda(l) / this%p(l))
    end do
    if (pap > curv_tol * pdp) then
      acg = gp / pap
    else
      acg = huge(1.0_wp)
    end if
    ! (acg = af = huge: a null direction with no bound ahead, the expansion branch below
    ! reports the dual unbounded; a step of huge length would overflow)
    if (acg <= af .and. acg < huge(1.0_wp)) then
      lambda(1:n) = lambda(1:n) - acg * this%p(1:n)
      where (this%p(1:n) > 0.0_wp .and. lambda(1:n) < 0.0_wp) lambda(1:n) = 0.0_wp
      this%g(1:n) = this%g(1:n) - acg * this%ap(1:n)
      ! p <- D^-1 phi - gamma p, gamma = (D^-1 phi)^T A p / p^T A p
      gam = 0.0_wp
      do l = 1, n
        if (lambda(l) > 0.0_wp) then
          this%z(l) = this%dinv(l) * this%g(l)
        else
          this%z(l) = 0.0_wp
        end if
        gam = gam + this%z(l) * this%ap(l)
      end do
      gam = gam / pap
      this%p(1:n) = this%z(1:n) - gam * this%p(1:n)
    else
      ! ---- expansion step: to the first bound, then a fixed-step projected gradient step
      if (af >= huge(1.0_wp)) then
        rs%unbounded = .true.
        return
      end if
      rs%n_exp = rs%n_exp + 1
      call projected_cg_step(this, cs, v, lambda, rs, min(acg, 1.0e3_wp * af + rs%abar), af)
      do l = 1, n
        if (lambda(l) > 0.0_wp) lambda(l) = max(lambda(l) - rs%abar * this%dinv(l) * this%g(l), &
          0.0_wp)
      end do
      call refresh(this, cs, v, lambda, rs)
      rs%fresh = .true.
      call new_direction(this, lambda, rs)
    end if
  end subroutine cg_step

  !> Proportioning step along -D^-1 beta (|beta|^2_{D^-1} = beta2): releases the rows that
  !> want to leave the bound; CG restarts.
  subroutine proportioning_step(this, cs, lambda, beta2, rs)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(inout) :: lambda(:)
    real(wp), intent(in) :: beta2
    type(gpcg_run_t), intent(inout) :: rs
    integer :: l, n
    real(wp) :: pap, pdp, acg
    n = rs%n
    rs%n_prop = rs%n_prop + 1
    do l = 1, n
      this%z(l) = 0.0_wp
      if (lambda(l) <= 0.0_wp .and. this%g(l) < 0.0_wp) this%z(l) = this%dinv(l) * this%g(l)
    end do
    call product(this, cs, this%z, rs, pap, pdp)
    if (.not. (pap > curv_tol * pdp)) then
      rs%unbounded = .true.
      return
    end if
    acg = beta2 / pap
    lambda(1:n) = lambda(1:n) - acg * this%z(1:n)
    this%g(1:n) = this%g(1:n) - acg * this%ap(1:n)
    call new_direction(this, lambda, rs)
  end subroutine proportioning_step

  !> g = d - B (v - B^T lambda) from scratch (also w = B^T lambda).
  subroutine refresh(this, cs, v, lambda, rs)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(in) :: lambda(:)
    type(gpcg_run_t), intent(inout) :: rs
    integer :: n, nd
    n = rs%n; nd = rs%nd
    rs%n_refresh = rs%n_refresh + 1
    call cs%apply_bt(lambda(1:n), this%w(1:nd))
    this%ut(1:nd) = v - this%w(1:nd)
    call cs%apply_b(this%ut(1:nd), this%g(1:n))
    this%g(1:n) = cs%gap(1:n) - this%g(1:n)
  end subroutine refresh

  !> Projected search along -p: lambda(a) = max(lambda - a p, 0) from a = a0, halving until the
  !> Armijo test f(lambda(a)) <= f(lambda) + mu g^T (lambda(a) - lambda) holds; a <= af (the
  !> first bound) is accepted at once (no projection but for the blocking rows, f decreases).
  !> Several bounds may be fixed in one step. Updates lambda and g (w, ut, z, t used as scratch).
  subroutine projected_cg_step(this, cs, v, lambda, rs, a0, af)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(inout) :: lambda(:)
    type(gpcg_run_t), intent(inout) :: rs
    real(wp), intent(in) :: a0, af
    real(wp), parameter :: mu = 1.0e-4_wp
    real(wp) :: a, gs, sts
    integer :: k, trial, n, nd
    n = rs%n; nd = rs%nd
    a = a0
    do trial = 1, 60
      if (a <= af) a = af
      do k = 1, n
        this%z(k) = lambda(k) - a * this%p(k)
        if (this%p(k) > 0.0_wp) then
          if (a >= lambda(k) / this%p(k)) this%z(k) = 0.0_wp
        end if
        this%z(k) = max(this%z(k), 0.0_wp) - lambda(k)
      end do
      if (a <= af) exit
      call cs%apply_bt(this%z(1:n), this%t(1:nd))
      gs = dot_product(this%g(1:n), this%z(1:n))
      sts = dot_product(this%t(1:nd), this%t(1:nd))
      if (gs + 0.5_wp * sts <= mu * gs) exit
      a = 0.5_wp * a
    end do
    lambda(1:n) = lambda(1:n) + this%z(1:n)
    call refresh(this, cs, v, lambda, rs)
  end subroutine projected_cg_step

  !> Scaled KKT residual from g and lambda >= 0.
  real(wp) function kkt_of_g(this, cs, lambda, rs) result(r)
    class(gpcg_solver_t), intent(in) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: lambda(:)
    type(gpcg_run_t), intent(in) :: rs
    integer :: k
    r = 0.0_wp
    do k = 1, rs%n
      r = max(r, -this%g(k) / (cs%h * rs%sv), abs(lambda(k) * this%g(k)) / rs%sv**2)
    end do
  end function kkt_of_g

  !> p = D^-1 phi (restart of CG on the current face).
  subroutine new_direction(this, lambda, rs)
    class(gpcg_solver_t), intent(inout) :: this
    real(wp), intent(in) :: lambda(:)
    type(gpcg_run_t), intent(in) :: rs
    integer :: k
    do k = 1, rs%n
      if (lambda(k) > 0.0_wp) then
        this%p(k) = this%dinv(k) * this%g(k)
      else
        this%p(k) = 0.0_wp
      end if
    end do
  end subroutine new_direction

  !> ap = A x = B (B^T x); xax = x^T A x = |B^T x|^2; xdx = x^T D x.
  subroutine product(this, cs, x, rs, xax, xdx)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: x(:)
    type(gpcg_run_t), intent(in) :: rs
    real(wp), intent(out) :: xax, xdx
    integer :: n, nd
    n = rs%n; nd = rs%nd
    call cs%apply_bt(x(1:n), this%t(1:nd))
    call cs%apply_b(this%t(1:nd), this%ap(1:n))
    xax = dot_product(this%t(1:nd), this%t(1:nd))
    xdx = sum(x(1:n)**2 / this%dinv(1:n))
  end subroutine product

  subroutine gpcg_free(this)
    class(gpcg_solver_t), intent(inout) :: this
    if (allocated(this%g)) deallocate(this%g, this%p, this%ap, this%z, this%dinv, this%best)
    if (allocated(this%w)) deallocate(this%w, this%t, this%ut)
  end subroutine gpcg_free
end module cr_gpcg
