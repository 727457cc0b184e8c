!> Exact, matrix-free projection by gradient projection + conjugate gradients on the dual
!> (in the spirit of More & Toraldo's GPCG, SIAM J. Optim. 1 (1991)):
!>   min_{lambda >= 0} f(lambda) = 1/2 |B^T lambda|^2 - lambda^T (B v - d),
!>   g = grad f = d - B u(lambda),  u(lambda) = v - B^T lambda,  A = B B^T.
!>
!> Each outer iteration has two phases.
!> - Gradient projection (GP): projected searches along the Jacobi-scaled steepest descent
!>   direction -D^{-1} g (D = diag A = h^2 (2 for agent pairs, 1 for obstacle rows)):
!>   lambda(a) = max(lambda - a D^{-1} g, 0), first trial a = the exact minimiser of f along the
!>   direction with the blocked components removed, backtracking with safeguarded quadratic
!>   interpolation until the Armijo test f(lambda(a)) <= f(lambda) + mu g^T (lambda(a) - lambda).
!>   Many bounds may change per step. The phase ends when the active set {lambda_l = 0} no longer
!>   changes or the decrease is small compared with the best decrease of the phase.
!> - Conjugate gradients (CG): Jacobi-preconditioned CG on the free variables
!>   F = {lambda_l > 0 or g_l < 0} (products A_FF p = B (B^T p) with p zero outside F), until the
!>   scaled face residual is below tol / 10, a bound is hit (then a projected search along the
!>   CG direction, which may fix several bounds at once, and back to GP) or a per-phase cap.
!>   Singular faces (jammed crowds: B_F B_F^T singular) are consistent, and CG converges on them;
!>   a direction of (numerically) zero curvature is followed to the nearest bound.
!> The gradient and B^T lambda are recomputed from scratch after every CG phase, and the scaled
!> KKT residual of kkt_residuals is evaluated there from them (primal from -g, complementarity
!> from lambda g; dual and stationarity vanish by construction). Iterations = GP steps + CG steps.
module cr_gpcg
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t, velocity_scale
  use cr_projection, only: projection_solver_t, solve_stats_t, finish_stats, check_sizes, add_note
  implicit none
  private
  public :: gpcg_solver_t

  !> Armijo parameter of the projected searches
  real(wp), parameter :: mu = 0.01_wp
  !> GP phase ends when a step decreases f by less than eta_gp times the best decrease of the phase
  real(wp), parameter :: eta_gp = 0.1_wp
  !> at most this many GP steps in one phase
  integer, parameter :: max_gp = 50
  !> at most this many backtracking trials in one projected search
  integer, parameter :: max_trials = 40
  !> CG on a face stops when its scaled residual is below face_factor * tol
  real(wp), parameter :: face_factor = 0.1_wp
  !> relative curvature below which a CG direction counts as a null direction
  real(wp), parameter :: curv_tol = 1.0e-13_wp

  !> Gradient projection + conjugate gradients (GPCG) on the dual; exact up to tol.
  type, extends(projection_solver_t) :: gpcg_solver_t
    !> work arrays over rows, kept between solves and grown when needed [n rows]
    real(wp), allocatable :: g(:), p(:), r(:), z(:), ap(:), s(:), dinv(:), best(:), lt(:)
    !> free-variable mask of the current CG phase [n rows]
    logical, allocatable :: isfree(:)
    !> work arrays over velocities: B^T lambda, B^T (direction) [2*n_agents]
    real(wp), allocatable :: w(:), t(:), ut(:)
  contains
    procedure :: solve => gpcg_solve
    procedure :: free => gpcg_free
  end type gpcg_solver_t

contains

  subroutine gpcg_solve(this, cs, v, u, lambda, stats, error)
    class(gpcg_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer :: n, nd, l, iter, n_gp, n_outer, max_iter
    real(wp) :: sv, kkt, best_kkt, tol, dmax, decrease
    logical :: changed, unbounded, stalled

    call check_sizes("gpcg", cs, v, u, lambda, error)
    if (allocated(error)) return
    n = cs%n; nd = size(v)
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
    call grow(this%g, n); call grow(this%p, n); call grow(this%r, n); call grow(this%z, n)
    call grow(this%ap, n); call grow(this%s, n); call grow(this%dinv, n); call grow(this%best, n)
    call grow(this%lt, n)
    call grow(this%w, nd); call grow(this%t, nd); call grow(this%ut, nd)
    if (allocated(this%isfree)) then
      if (size(this%isfree) < n) deallocate(this%isfree)
    end if
    if (.not. allocated(this%isfree)) allocate(this%isfree(max(n, 16)))

    ! Jacobi preconditioner: diag(B B^T)_l = h^2 |g_l|^2 (1 + [ib(l) > 0])
    do l = 1, n
      if (cs%ib(l) > 0) then
        this%dinv(l) = 1.0_wp / (2.0_wp * cs%h**2 * sum(cs%g(:, l)**2))
      else
        this%dinv(l) = 1.0_wp / (cs%h**2 * sum(cs%g(:, l)**2))
      end if
    end do
    sv = velocity_scale(cs, v)

    iter = 0; n_outer = 0
    unbounded = .false.; stalled = .false.
    best_kkt = huge(1.0_wp)
    call refresh(kkt)
    do
      if (kkt < best_kkt) then
        best_kkt = kkt
        this%best(1:n) = lambda(1:n)
      end if
      if (kkt <= tol) then
        stats%converged = .true.
        exit
      end if
      if (iter >= max_iter .or. unbounded .or. stalled) exit
      n_outer = n_outer + 1
      ! ---- gradient projection phase
      dmax = 0.0_wp
      do n_gp = 1, max_gp
        call gp_step(changed, decrease)
        iter = iter + 1
        if (.not. changed .or. decrease <= eta_gp * dmax .or. iter >= max_iter) exit
        dmax = max(dmax, decrease)
      end do
      ! ---- conjugate gradients on the free variables
      if (iter < max_iter) call cg_phase()
      call refresh(kkt)
      ! no progress at all over many outer iterations: round-off floor above tol
      if (n_outer > 50 .and. kkt >= best_kkt .and. mod(n_outer, 50) == 0) stalled = .true.
    end do

    stats%iterations = iter
    lambda(1:n) = this%best(1:n)
    call cs%apply_bt(lambda(1:n), this%w(1:nd))
    u = v - this%w(1:nd)
    if (.not. stats%converged) then
      if (unbounded) then
        call add_note(stats, "dual unbounded along a null direction: the constraints B u <= d " // &
          "are infeasible")
      else if (stalled) then
        call add_note(stats, "no progress (round-off floor), best KKT residual " // &
          str(best_kkt, "es9.2"))
      else
        call add_note(stats, "iteration cap reached (" // str(max_iter) // &
          "), best KKT residual " // str(best_kkt, "es9.2"))
      end if
    end if
    call finish_stats(cs, v, u, lambda, tol, stats)

  contains

    !> w = B^T lambda and g = d - B (v - w) from scratch; kkt = scaled KKT residual.
    subroutine refresh(kkt)
      real(wp), intent(out) :: kkt
      integer :: k
      call cs%apply_bt(lambda(1:n), this%w(1:nd))
      this%ut(1:nd) = v - this%w(1:nd)
      call cs%apply_b(this%ut(1:nd), this%g(1:n))
      kkt = 0.0_wp
      do k = 1, n
        this%g(k) = cs%gap(k) - this%g(k)
        kkt = max(kkt, -this%g(k) / (cs%h * sv), abs(lambda(k) * this%g(k)) / sv**2)
      end do
    end subroutine refresh

    !> One projected search along -D^{-1} g. changed: the active set changed; decrease >= 0.
    subroutine gp_step(changed, decrease)
      logical, intent(out) :: changed
      real(wp), intent(out) :: decrease
      integer :: k
      real(wp) :: gp, ptap, alpha
      ! direction with the blocked components (lambda = 0, g > 0) removed
      do k = 1, n
        this%p(k) = -this%dinv(k) * this%g(k)
        if (lambda(k) <= 0.0_wp .and. this%p(k) < 0.0_wp) this%p(k) = 0.0_wp
      end do
      gp = dot_product(this%g(1:n), this%p(1:n))
      changed = .false.; decrease = 0.0_wp
      if (.not. (gp < 0.0_wp)) return
      call cs%apply_bt(this%p(1:n), this%t(1:nd))
      ptap = dot_product(this%t(1:nd), this%t(1:nd))
      if (ptap > -curv_tol * gp) then
        alpha = -gp / ptap
      else
        alpha = 1.0_wp
        do k = 1, n
          if (this%p(k) < 0.0_wp) alpha = max(alpha, -lambda(k) / this%p(k))
        end do
      end if
      call projected_search(alpha, 0.0_wp, changed, decrease)
    end subroutine gp_step

    !> Projected search along p from lambda: trial lambda(a) = max(lambda + a p, 0), starting at
    !> a = alpha, backtracking until the Armijo test holds. Steps a <= a_safe (> 0) are known to
    !> decrease f without projection and are accepted at once. Updates lambda, w, g.
    subroutine projected_search(alpha, a_safe, changed, decrease)
      real(wp), intent(in) :: alpha, a_safe
      logical, intent(out) :: changed
      real(wp), intent(out) :: decrease
      integer :: k, trial
      real(wp) :: a, gs, sts, phi, anew
      a = alpha
      changed = .false.; decrease = 0.0_wp
      do trial = 1, max_trials
        if (a_safe > 0.0_wp .and. a <= a_safe) a = a_safe
        do k = 1, n
          this%lt(k) = max(lambda(k) + a * this%p(k), 0.0_wp)
          ! exact zero for every component whose bound is reached (amax is computed the same way)
          if (this%p(k) < 0.0_wp) then
            if (a >= -lambda(k) / this%p(k)) this%lt(k) = 0.0_wp
          end if
          this%s(k) = this%lt(k) - lambda(k)
        end do
        call cs%apply_bt(this%s(1:n), this%t(1:nd))
        gs = dot_product(this%g(1:n), this%s(1:n))
        sts = dot_product(this%t(1:nd), this%t(1:nd))
        phi = gs + 0.5_wp * sts
        if (phi <= mu * gs .and. gs < 0.0_wp) exit
        if (a_safe > 0.0_wp .and. a <= a_safe) exit
        if (.not. (gs < 0.0_wp)) then
          a = 0.5_wp * a
        else
          ! minimiser of the quadratic through phi(0) = 0, slope gs/a, phi(a); safeguarded
          anew = -gs * a / (2.0_wp * (phi - gs))
          a = min(max(anew, 0.1_wp * a), 0.5_wp * a)
        end if
        if (trial == max_trials) return
      end do
      if (.not. (phi < 0.0_wp)) return
      decrease = -phi
      do k = 1, n
        if ((lambda(k) > 0.0_wp) .neqv. (this%lt(k) > 0.0_wp)) changed = .true.
      end do
      lambda(1:n) = this%lt(1:n)
      this%w(1:nd) = this%w(1:nd) + this%t(1:nd)
      this%ut(1:nd) = v - this%w(1:nd)
      call cs%apply_b(this%ut(1:nd), this%g(1:n))
      this%g(1:n) = cs%gap(1:n) - this%g(1:n)
    end subroutine projected_search

    !> Preconditioned CG on A_FF x = -g_F from x = 0 (x added to lambda_F as it goes).
    subroutine cg_phase()
      integer :: k, it, nf, cap
      real(wp) :: rz, rz_new, pap, alpha, amax, beta, res, pdp
      logical :: changed
      real(wp) :: decrease
      nf = 0
      do k = 1, n
        this%isfree(k) = lambda(k) > 0.0_wp .or. this%g(k) < 0.0_wp
        if (this%isfree(k)) then
          nf = nf + 1
          this%r(k) = -this%g(k)
        else
          this%r(k) = 0.0_wp
        end if
        this%z(k) = this%dinv(k) * this%r(k)
      end do
      if (nf == 0) return
      this%p(1:n) = this%z(1:n)
      rz = dot_product(this%r(1:n), this%z(1:n))
      cap = nf + 100
      do it = 1, cap
        res = 0.0_wp
        do k = 1, n
          if (this%isfree(k)) res = max(res, abs(this%r(k)) * max(1.0_wp / (cs%h * sv), &
            lambda(k) / sv**2))
        end do
        if (res <= face_factor * tol .or. .not. (rz > 0.0_wp)) return
        if (iter >= max_iter) return
        iter = iter + 1
        call cs%apply_bt(this%p(1:n), this%t(1:nd))
        pap = dot_product(this%t(1:nd), this%t(1:nd))
        pdp = 0.0_wp
        do k = 1, n
          if (this%isfree(k)) pdp = pdp + this%p(k)**2 / this%dinv(k)
        end do
        ! largest step before a free variable reaches its bound
        amax = huge(1.0_wp)
        do k = 1, n
          if (this%p(k) < 0.0_wp) amax = min(amax, -lambda(k) / this%p(k))
        end do
        if (pap <= curv_tol * pdp) then
          ! null direction of the face: f is linear along p (decreasing, since r^T p = rz > 0)
          if (amax >= huge(1.0_wp)) then
            unbounded = .true.
            return
          end if
          call projected_search(amax, amax, changed, decrease)
          return
        end if
        alpha = rz / pap
        if (alpha >= amax) then
          ! a bound is hit: projected search along p (several bounds may be fixed at once)
          call projected_search(alpha, amax, changed, decrease)
          return
        end if
        call cs%apply_b(this%t(1:nd), this%ap(1:n))
        do k = 1, n
          if (this%isfree(k)) then
            lambda(k) = lambda(k) + alpha * this%p(k)
            this%r(k) = this%r(k) - alpha * this%ap(k)
          end if
        end do
        this%w(1:nd) = this%w(1:nd) + alpha * this%t(1:nd)
        rz_new = 0.0_wp
        do k = 1, n
          if (this%isfree(k)) then
            this%z(k) = this%dinv(k) * this%r(k)
            rz_new = rz_new + this%r(k) * this%z(k)
          end if
        end do
        beta = rz_new / rz
        rz = rz_new
        do k = 1, n
          if (this%isfree(k)) this%p(k) = this%z(k) + beta * this%p(k)
        end do
      end do
    end subroutine cg_phase
  end subroutine gpcg_solve

  subroutine gpcg_free(this)
    class(gpcg_solver_t), intent(inout) :: this
    if (allocated(this%g)) deallocate(this%g, this%p, this%r, this%z, this%ap, this%s, &
      this%dinv, this%best, this%lt)
    if (allocated(this%w)) deallocate(this%w, this%t, this%ut)
    if (allocated(this%isfree)) deallocate(this%isfree)
  end subroutine gpcg_free

  subroutine grow(a, n)
    real(wp), allocatable, intent(inout) :: a(:)
    integer, intent(in) :: n
    if (allocated(a)) then
      if (size(a) >= n) return
      deallocate(a)
    end if
    allocate(a(max(n, 16)))
  end subroutine grow
end module cr_gpcg
