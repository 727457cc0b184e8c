!> Warm-started dual active-set solver (Goldfarb-Idnani) for the least-distance problem
!>   min 1/2 |u - v|_2^2  s.t.  Bm u <= d,   Bm: [m, n], given as its transpose bt [n, m]
!> (rows as contiguous columns), the reduced projection of the reduced-order model
!> (u = alpha, v = vhat, Bm = bhat).
!>
!> Method. The Hessian is the identity, so the whole state is an active set A of linearly
!> independent rows, their multipliers lambda_A >= 0 and the Cholesky factor L L^T = G_A of
!> the Gram matrix of the active rows only (G_ij = b_i . b_j). The primal point is
!> u = v - Bm_A^T lambda_A with Bm_A u = d_A. A sweep forms u and the slacks s = d - Bm u
!> (two matrix-vector products, O(m n)) and lists the violated rows as candidates. The most
!> violated candidate p (largest -s_p / |b_p|) is added by the dual step of Goldfarb and
!> Idnani (Math. Prog. 27, 1983): with r = G_A^{-1} G_Ap and zeta = G_pp - G_pA r (the
!> squared distance of b_p to the span of the active rows), increasing lambda_p by t moves
!> lambda_A by -t r, u by -t z (z = b_p - Bm_A^T r) and raises s_p by t zeta; the step is the
!> smaller of the full step (s_p = 0, p joins A: one new row of L) and the partial step at
!> which an active multiplier reaches 0 (that row leaves A: a Givens downdate of L). The
!> other candidates' slacks are carried along (s_c += t b_c . z, O(k n) per step), so the
!> next candidate is added without a sweep; a new sweep is made when no candidate is
!> violated, and the solve ends at a sweep that finds no violated row. Only the Gram entries
!> G_pA of an entering row are formed, through a `gram_source_t` when the caller has them
!> cheaply, else as dot products of rows. The work per step is O(m n) per sweep plus
!> O(k n + k^2) per added or dropped row, never O(m^2).
!>
!> Warm start. The rows with lambda > 0 on entry are factored (numerically dependent ones
!> skipped), the equality-constrained problem on them is solved, and rows with negative
!> multipliers are dropped until all are >= 0: a dual-feasible start for the iteration above.
!>
!> Certificate. The returned (u, lambda) are accepted (stats%certified) only when they satisfy
!> the KKT conditions to the stated tolerance tau_i = KKT_FACTOR eps (|b_i|_2 |u|_2 + |d_i|):
!>   u = v - Bm^T lambda (formed so), lambda >= 0, s_i >= -tau_i for all i, |s_i| <= tau_i
!>   where lambda_i > 0.
!> Active residuals above tau (ill-conditioned G_A) get up to two steps of iterative
!> refinement. For any such point, |u - u*|_2^2 <= tau . (lambda + lambda*) with u* the exact
!> projection and lambda* its multipliers (see the tests). When the iteration meets a violated
!> row that depends on the active ones with no multiplier to release (a Farkas-type
!> certificate that {Bm u <= d} is empty), or hits its cap or the caller's bound on the active
!> set (max_active: a Gram of nearly as many rows as unknowns cannot be certified), or the
!> certificate fails, the result is not certified and the caller falls back to the Lawson-Hanson LDP (cr_nnls),
!> which also computes the least-violation point of infeasible problems.
!> Finiteness: the slacks of the first sweep are summed (m additions); a NaN or Inf in Bm or d
!> shows there (stats%nonfinite, not certified) and the caller's fallback names the entry.
!> v and the warm-start lambda must be finite (the caller checks them).
module cr_dual_qp
  use cr_kinds, only: wp
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite, ieee_value, ieee_quiet_nan
  use cr_lapack, only: la_gemv
  implicit none
  private
  public :: gram_source_t, dual_qp_t, dual_qp_stats_t, KKT_FACTOR

  !> tolerance factor of the KKT certificate (tau_i, see the module header)
  real(wp), parameter :: KKT_FACTOR = 256.0_wp
  !> a row whose squared distance to the span of the active rows is below ZTOL |b_p|^2 is
  !> treated as dependent on them (relative pivot of the Cholesky factor below 1e-5)
  real(wp), parameter :: ZTOL = 1.0e-10_wp

  !> Source of Gram entries b_p . b_j of the constraint rows (when the caller can form them
  !> more cheaply than an n-term dot product).
  type, abstract :: gram_source_t
  contains
    procedure(gram_entries_i), deferred :: gram_entries
    procedure :: gram_diag
  end type gram_source_t

  abstract interface
    !> g(j) = b_p . b_idx(j) for the rows of the last assembled problem [size(idx)].
    subroutine gram_entries_i(this, p, idx, g)
      import :: gram_source_t, wp
      class(gram_source_t), intent(in) :: this
      integer, intent(in) :: p, idx(:)
      real(wp), intent(out) :: g(:)
    end subroutine gram_entries_i
  end interface

  !> Outcome of one solve.
  type :: dual_qp_stats_t
    !> .true. when (u, lambda) satisfy the KKT certificate
    logical :: certified = .false.
    !> .true. when a violated row was found dependent on the active ones with no multiplier
    !> to release: {Bm u <= d} is (numerically) empty
    logical :: infeasible = .false.
    !> .true. when the iteration cap stopped the solve
    logical :: capped = .false.
    !> .true. when the active set would exceed max_active rows (left to the caller's
    !> fallback: a Gram of nearly as many rows as unknowns squares a large condition number)
    logical :: overfull = .false.
    !> .true. when the data hold a NaN or Inf (seen in the slacks of the first sweep)
    logical :: nonfinite = .false.
    !> rows added, rows dropped, outer sweeps (products with Bm), refinement steps
    integer :: adds = 0, drops = 0, sweeps = 0, refinements = 0
    !> size of the final active set
    integer :: n_active = 0
    !> max_i (Bm u - d)_i^+ of the returned u (NaN when the data hold a NaN or Inf)
    real(wp) :: max_violation = 0
  end type dual_qp_stats_t

  !> Solver state and work space (grown on demand); keep one per trajectory.
  type :: dual_qp_t
    integer :: mcap = -1, ncap = -1, kcap = -1
    !> active rows in factor order [kcap], their multipliers [kcap]
    integer, allocatable :: act(:)
    real(wp), allocatable :: lam(:)
    !> lower Cholesky factor of G_A [kcap, kcap]
    real(wp), allocatable :: lf(:,:)
    !> work vectors [kcap]
    real(wp), allocatable :: gp(:), y(:), r(:), x(:)
    !> slacks, squared row norms, row norms, tolerances [mcap]; membership [mcap]
    real(wp), allocatable :: s(:), nrm2(:), nrm(:), tau(:)
    logical, allocatable :: in_a(:)
    !> candidates (violated rows of the last sweep) and their tracked slacks [mcap]
    integer, allocatable :: cand(:)
    real(wp), allocatable :: sc(:)
    !> step direction in the primal space [ncap]
    real(wp), allocatable :: zdir(:)
  contains
    procedure :: solve
    procedure, private :: reserve
  end type dual_qp_t

  !> The state of one solve shared by its parts: sizes, active-set size and cap, iterations.
  type :: dqp_run_t
    !> rows, unknowns, active rows, largest active set, iterations and their cap
    integer :: m = 0, n = 0, k = 0, kmax = 0, it = 0, itmax = 0
    !> machine epsilon, |u| of the last sweep
    real(wp) :: eps = 0, unorm = 0
  end type dqp_run_t

contains

  !> x . y with eight partial sums (the compiler keeps the order of a plain sum, which makes
  !> a length-150 dot product latency-bound).
  pure real(wp) function dot8(x, y) result(t)
    real(wp), contiguous, intent(in) :: x(:), y(:)
    real(wp) :: acc(8)
    integer :: i, n8
    n8 = size(x) - mod(size(x), 8)
    acc = 0
    do i = 1, n8, 8
      acc = acc + x(i:i + 7) * y(i:i + 7)
    end do
    t = sum(acc)
    do i = n8 + 1, size(x)
      t = t + x(i) * y(i)
    end do
  end function dot8

  !> g(i) = |b_i|^2 for the m rows [m] (default: one gram_entries call per row).
  subroutine gram_diag(this, g)
    class(gram_source_t), intent(in) :: this
    real(wp), intent(out) :: g(:)
    integer :: i
    real(wp) :: gi(1)
    do i = 1, size(g)
      call this%gram_entries(i, [i], gi)
      g(i) = gi(1)
    end do
  end subroutine gram_diag

  subroutine reserve(this, m, n)
    class(dual_qp_t), intent(inout) :: this
    integer, intent(in) :: m, n
    integer :: kc
    if (m > this%mcap) then
      if (allocated(this%s)) deallocate(this%s, this%nrm2, this%nrm, this%tau, this%in_a, this%cand, this%sc)
      allocate(this%s(m), this%nrm2(m), this%nrm(m), this%tau(m), this%in_a(m), this%cand(m), this%sc(m))
      this%mcap = m
    end if
    if (n > this%ncap) then
      if (allocated(this%zdir)) deallocate(this%zdir)
      allocate(this%zdir(n))
      this%ncap = n
    end if
    kc = max(1, min(m, n))
    if (kc > this%kcap) then
      if (allocated(this%act)) deallocate(this%act, this%lam, this%lf, this%gp, this%y, this%r, this%x)
      allocate(this%act(kc), this%lam(kc), this%lf(kc, kc), this%gp(kc), this%y(kc), this%r(kc), this%x(kc))
      this%kcap = kc
    end if
  end subroutine reserve

  !> Solve min 1/2 |u - v|^2 s.t. Bm u <= d. On entry lambda > 0 marks the warm-start guess
  !> of the active set (ignored when warm = .false.); on return lambda holds the multipliers
  !> (zero off the active set) and u the projection, both valid only when
  !> stats%certified (otherwise they are the last iterate: a dual-feasible point and a good
  !> warm start for a fallback solver). max_iter caps adds + drops (default 4 m + 20).
  subroutine solve(this, bt, d, v, u, lambda, stats, warm, gsrc, max_iter, max_active)
    class(dual_qp_t), intent(inout) :: this
    !> constraint rows as columns: Bm^T [n, m]
    real(wp), contiguous, intent(in) :: bt(:,:)
    !> right-hand side [m], point to project [n]
    real(wp), intent(in) :: d(:)
    real(wp), contiguous, intent(in) :: v(:)
    !> projection [n]
    real(wp), contiguous, intent(out) :: u(:)
    !> multipliers [m] (warm-start guess on entry)
    real(wp), intent(inout) :: lambda(:)
    type(dual_qp_stats_t), intent(out) :: stats
    logical, intent(in), optional :: warm
    !> Gram entries of the rows (default: dot products of the columns of bt)
    class(gram_source_t), intent(in), optional :: gsrc
    integer, intent(in), optional :: max_iter
    !> largest active set handled (default min(m, n))
    integer, intent(in), optional :: max_active
    type(dqp_run_t) :: rs
    integer :: i, m
    logical :: use_warm

    m = size(bt, 2)
    rs%m = m; rs%n = size(bt, 1)
    rs%eps = epsilon(1.0_wp)
    use_warm = .true.
    if (present(warm)) use_warm = warm
    rs%itmax = 4 * m + 20
    if (present(max_iter)) rs%itmax = max_iter
    if (m == 0) then
      u = v
      stats%certified = .true.
      return
    end if
    call this%reserve(m, rs%n)
    rs%kmax = this%kcap
    if (present(max_active)) rs%kmax = max(0, min(rs%kmax, max_active))
    ! squared row norms (the Gram diagonal)
    if (present(gsrc)) then
      call gsrc%gram_diag(this%nrm2(1:m))
    else
      do i = 1, m
        this%nrm2(i) = dot8(bt(:, i), bt(:, i))
      end do
    end if
    this%nrm(1:m) = sqrt(this%nrm2(1:m))
    this%in_a(1:m) = .false.
    rs%k = 0
    rs%it = 0

    ! ---- warm start: factor the guessed rows, solve the equality problem, drop lambda < 0
    if (use_warm .and. present(max_active)) stats%overfull = count(lambda > 0) > rs%kmax
    if (use_warm .and. .not. stats%overfull) call warm_start(this, rs, bt, d, v, lambda, gsrc)
    call gi_iterate(this, rs, bt, d, v, u, stats, gsrc)
    call certify(this, rs, bt, d, v, u, stats)
    call return_iterate(this, rs, bt, d, v, u, lambda, stats)
  end subroutine solve

  !> Factor the rows guessed by lambda > 0, solve the equality problem on them and drop the
  !> rows with a negative multiplier until none is left.
  subroutine warm_start(this, rs, bt, d, v, lambda, gsrc)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(inout) :: rs
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: d(:)
    real(wp), contiguous, intent(in) :: v(:)
    real(wp), intent(in) :: lambda(:)
    class(gram_source_t), intent(in), optional :: gsrc
    integer :: i, j
    real(wp) :: zeta
    do i = 1, rs%m
      if (lambda(i) > 0 .and. this%nrm2(i) > 0 .and. rs%k < rs%kmax) then
        call entering(this, rs, bt, i, zeta, gsrc)
        if (zeta > ZTOL * this%nrm2(i)) call append(this, rs, i, zeta)
      end if
    end do
    do
      if (rs%k == 0) exit
      ! G_A lambda_A = Bm_A v - d_A
      do j = 1, rs%k
        this%y(j) = dot8(bt(:, this%act(j)), v) - d(this%act(j))
      end do
      call chol_solve(this%lf, this%y(1:rs%k), this%lam(1:rs%k))
      if (all(this%lam(1:rs%k) >= 0)) exit
      do j = rs%k, 1, -1
        if (this%lam(j) < 0) call drop(this, rs, j)
      end do
    end do
  end subroutine warm_start

  !> Goldfarb-Idnani iteration: sweep for the violated inactive rows (candidates), take the
  !> most violated one by its tracked slack into the active set (gi_pivot), sweep again when
  !> no candidate is left violated; stops when a sweep finds none or a flag of stats is set.
  subroutine gi_iterate(this, rs, bt, d, v, u, stats, gsrc)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(inout) :: rs
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: d(:)
    real(wp), contiguous, intent(in) :: v(:)
    real(wp), contiguous, intent(inout) :: u(:)
    type(dual_qp_stats_t), intent(inout) :: stats
    class(gram_source_t), intent(in), optional :: gsrc
    integer :: i, p, nc, c, pc
    real(wp) :: best
    logical :: need_sweep, track, stop
    need_sweep = .true.
    nc = 0
    outer: do
      if (stats%overfull) exit outer
      if (need_sweep) then
        call sweep(this, rs, bt, d, v, u, stats, nc, stop)
        if (stop .or. nc == 0) exit outer
        need_sweep = .false.
      end if
      ! most violated candidate (scaled by its norm) by its tracked slack
      p = 0; pc = 0
      best = 0
      do c = 1, nc
        i = this%cand(c)
        if (this%in_a(i)) cycle
        if (-this%sc(c) > this%tau(i) .and. -this%sc(c) > best * this%nrm(i)) then
          best = -this%sc(c) / this%nrm(i); p = i; pc = c
        end if
      end do
      if (p == 0) then
        need_sweep = .true.
        cycle outer
      end if
      track = .false.
      do c = 1, nc
        if (c /= pc .and. .not. this%in_a(this%cand(c))) track = .true.
      end do
      call gi_pivot(this, rs, bt, p, pc, nc, track, stats, stop, gsrc)
      if (stop) exit outer
    end do outer
  end subroutine gi_iterate

  !> A sweep: u, slacks and tolerances of the current iterate (primal) and the candidates, the
  !> violated inactive rows [nc] with their slacks; stop when the data are not finite (first
  !> sweep) or a violated row is zero (infeasible).
  subroutine sweep(this, rs, bt, d, v, u, stats, nc, stop)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(inout) :: rs
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: d(:)
    real(wp), contiguous, intent(in) :: v(:)
    real(wp), contiguous, intent(inout) :: u(:)
    type(dual_qp_stats_t), intent(inout) :: stats
    integer, intent(out) :: nc
    logical, intent(out) :: stop
    integer :: i
    stop = .true.
    nc = 0
    call primal(this, rs, bt, d, v, u)
    stats%sweeps = stats%sweeps + 1
    if (stats%sweeps == 1) then
      if (.not. ieee_is_finite(sum(this%s(1:rs%m)))) then
        stats%nonfinite = .true.
        return
      end if
    end if
    ! candidates: the violated inactive rows
    do i = 1, rs%m
      if (this%in_a(i)) cycle
      if (-this%s(i) > this%tau(i)) then
        if (this%nrm2(i) == 0) then
          stats%infeasible = .true.
          return
        end if
        nc = nc + 1
        this%cand(nc) = i
        this%sc(nc) = this%s(i)
      end if
    end do
    stop = .false.
  end subroutine sweep

  !> Take row p (candidate pc of nc) into the active set: partial steps that drop the active
  !> rows whose multiplier reaches zero, until p is added (with the other candidates' slacks
  !> tracked when track); stop on the cap, an infeasible or an overfull active set.
  subroutine gi_pivot(this, rs, bt, p, pc, nc, track, stats, stop, gsrc)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(inout) :: rs
    real(wp), contiguous, intent(in) :: bt(:,:)
    integer, intent(in) :: p, pc, nc
    logical, intent(inout) :: track
    type(dual_qp_stats_t), intent(inout) :: stats
    logical, intent(out) :: stop
    class(gram_source_t), intent(in), optional :: gsrc
    integer :: i, j, jmin, c, k, n
    real(wp) :: t1, t2, t, zeta, viol, lp
    logical :: dependent
    n = rs%n
    stop = .true.
    viol = -this%sc(pc)
    lp = 0
    do
      if (rs%it >= rs%itmax) then
        stats%capped = .true.
        return
      end if
      rs%it = rs%it + 1
      call entering(this, rs, bt, p, zeta, gsrc)
      k = rs%k
      dependent = .not. zeta > ZTOL * this%nrm2(p) .or. k >= this%kcap
      t2 = huge(1.0_wp)
      if (.not. dependent) t2 = viol / zeta
      ! r = G_A^{-1} G_Ap: back substitution on y = L^{-1} G_Ap
      call back_solve(this%lf, this%y(1:k), this%r(1:k))
      t1 = huge(1.0_wp)
      jmin = 0
      do j = 1, k
        if (this%r(j) > 0) then
          if (this%lam(j) / this%r(j) < t1) then
            t1 = this%lam(j) / this%r(j); jmin = j
          end if
        end if
      end do
      if (jmin == 0 .and. dependent) then
        stats%infeasible = .true.
        return
      end if
      t = min(t1, t2)
      if (track) then
        ! the other candidates' slacks move by t b_c . z, z = b_p - Bm_A^T r (O(k n + nc n)
        ! instead of a sweep)
        this%zdir(1:n) = bt(:, p)
        do j = 1, k
          this%zdir(1:n) = this%zdir(1:n) - this%r(j) * bt(:, this%act(j))
        end do
        do c = 1, nc
          i = this%cand(c)
          if (c == pc .or. this%in_a(i)) cycle
          this%sc(c) = this%sc(c) + t * dot8(bt(:, i), this%zdir(1:n))
        end do
      end if
      this%lam(1:k) = this%lam(1:k) - t * this%r(1:k)
      lp = lp + t
      if (t2 <= t1) then
        if (k >= rs%kmax) then
          stats%overfull = .true.
          return
        end if
        call append(this, rs, p, zeta)
        this%lam(rs%k) = lp
        ! an active row has s = 0; should it leave A later, its slack is tracked from 0
        this%sc(pc) = 0
        stats%adds = stats%adds + 1
        stop = .false.
        return
      end if
      viol = viol - t * zeta
      this%lam(jmin) = 0
      call drop(this, rs, jmin)
      ! the dropped row may be a candidate, tracked from now on
      track = nc > 1
      stats%drops = stats%drops + 1
    end do
  end subroutine gi_pivot

  !> The KKT certificate of the iterate (with up to two refinement steps on the active rows),
  !> unless the iteration stopped on a flag.
  subroutine certify(this, rs, bt, d, v, u, stats)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(inout) :: rs
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: d(:)
    real(wp), contiguous, intent(in) :: v(:)
    real(wp), contiguous, intent(inout) :: u(:)
    type(dual_qp_stats_t), intent(inout) :: stats
    integer :: i, j, ref, k
    logical :: ok
    if (stats%infeasible .or. stats%capped .or. stats%nonfinite .or. stats%overfull) return
    k = rs%k
    do ref = 0, 2
      ok = all(this%lam(1:k) >= 0)
      do j = 1, k
        ok = ok .and. abs(this%s(this%act(j))) <= this%tau(this%act(j))
      end do
      if (ok .or. ref == 2) exit
      ! G_A delta = -s_A, lambda_A += delta
      do j = 1, k
        this%y(j) = -this%s(this%act(j))
      end do
      call chol_solve(this%lf, this%y(1:k), this%r(1:k))
      this%lam(1:k) = this%lam(1:k) + this%r(1:k)
      stats%refinements = stats%refinements + 1
      call primal(this, rs, bt, d, v, u)
    end do
    do i = 1, rs%m
      if (.not. this%in_a(i)) ok = ok .and. this%s(i) >= -this%tau(i)
    end do
    stats%certified = ok
  end subroutine certify

  !> lambda, u and the statistics of the returned iterate.
  subroutine return_iterate(this, rs, bt, d, v, u, lambda, stats)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(in) :: rs
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: d(:)
    real(wp), contiguous, intent(in) :: v(:)
    real(wp), contiguous, intent(inout) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(dual_qp_stats_t), intent(inout) :: stats
    integer :: i, j, k, m
    logical :: clamped
    k = rs%k; m = rs%m
    ! u of the last sweep is v - Bm_A^T lambda_A unless the iteration stopped between sweeps
    ! or a multiplier is clamped at 0
    lambda = 0
    clamped = .false.
    do j = 1, k
      clamped = clamped .or. this%lam(j) < 0
      lambda(this%act(j)) = max(this%lam(j), 0.0_wp)
    end do
    ! the slacks are those of the returned u only after a certified solve: otherwise (an early
    ! exit, possibly before any sweep, or a clamped multiplier) u and its slacks are recomputed
    if (clamped .or. .not. stats%certified) then
      u = v
      do j = 1, k
        u = u - lambda(this%act(j)) * bt(:, this%act(j))
      end do
      this%s(1:m) = d
      call la_gemv('T', -1.0_wp, bt, u, 1.0_wp, this%s(1:m))
    end if
    stats%n_active = k
    if (stats%nonfinite .or. .not. ieee_is_finite(sum(this%s(1:m)))) then
      stats%nonfinite = .true.
      stats%max_violation = ieee_value(1.0_wp, ieee_quiet_nan)
    else
      stats%max_violation = 0
      do i = 1, m
        stats%max_violation = max(stats%max_violation, -this%s(i))
      end do
    end if
  end subroutine return_iterate

  !> u = v - Bm_A^T lambda_A, s = d - Bm u, tau (see the module header).
  subroutine primal(this, rs, bt, d, v, u)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(inout) :: rs
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: d(:)
    real(wp), contiguous, intent(in) :: v(:)
    real(wp), contiguous, intent(inout) :: u(:)
    integer :: jj, m
    m = rs%m
    u = v
    do jj = 1, rs%k
      u = u - this%lam(jj) * bt(:, this%act(jj))
    end do
    this%s(1:m) = d
    call la_gemv('T', -1.0_wp, bt, u, 1.0_wp, this%s(1:m))
    rs%unorm = sqrt(dot8(u, u))
    this%tau(1:m) = KKT_FACTOR * rs%eps * (this%nrm(1:m) * rs%unorm + abs(d))
  end subroutine primal

  !> gp = G_{pA}, y = L^{-1} gp, zeta = G_pp - |y|^2.
  subroutine entering(this, rs, bt, pp, zz, gsrc)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(in) :: rs
    real(wp), contiguous, intent(in) :: bt(:,:)
    integer, intent(in) :: pp
    real(wp), intent(out) :: zz
    class(gram_source_t), intent(in), optional :: gsrc
    integer :: jj, k
    k = rs%k
    if (k > 0) then
      if (present(gsrc)) then
        call gsrc%gram_entries(pp, this%act(1:k), this%gp(1:k))
      else
        do jj = 1, k
          this%gp(jj) = dot8(bt(:, pp), bt(:, this%act(jj)))
        end do
      end if
      call forward_solve(this%lf, this%gp(1:k), this%y(1:k))
    end if
    zz = this%nrm2(pp) - sum(this%y(1:k)**2)
  end subroutine entering

  !> Append row pp to A (its factor row is y, its pivot sqrt(zz)).
  subroutine append(this, rs, pp, zz)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(inout) :: rs
    integer, intent(in) :: pp
    real(wp), intent(in) :: zz
    integer :: k
    rs%k = rs%k + 1
    k = rs%k
    this%lf(k, 1:k - 1) = this%y(1:k - 1)
    this%lf(k, k) = sqrt(zz)
    this%act(k) = pp
    this%lam(k) = 0
    this%in_a(pp) = .true.
  end subroutine append

  !> Remove the row at factor position jj: shift, then a rank-one update of the trailing
  !> block by the removed column (Givens), O(k^2).
  subroutine drop(this, rs, jj)
    class(dual_qp_t), intent(inout) :: this
    type(dqp_run_t), intent(inout) :: rs
    integer, intent(in) :: jj
    integer :: c, i2, nx, k
    real(wp) :: a, xi, rr, cg, sg
    k = rs%k
    this%in_a(this%act(jj)) = .false.
    nx = k - jj
    this%x(1:nx) = this%lf(jj + 1:k, jj)
    do c = 1, jj - 1
      this%lf(jj:k - 1, c) = this%lf(jj + 1:k, c)
    end do
    do c = jj + 1, k
      this%lf(c - 1:k - 1, c - 1) = this%lf(c:k, c)
    end do
    this%act(jj:k - 1) = this%act(jj + 1:k)
    this%lam(jj:k - 1) = this%lam(jj + 1:k)
    k = k - 1
    rs%k = k
    do i2 = jj, k
      a = this%lf(i2, i2)
      xi = this%x(i2 - jj + 1)
      rr = hypot(a, xi)
      cg = rr / a; sg = xi / a
      this%lf(i2, i2) = rr
      this%lf(i2 + 1:k, i2) = (this%lf(i2 + 1:k, i2) + sg * this%x(i2 - jj + 2:nx)) / cg
      this%x(i2 - jj + 2:nx) = cg * this%x(i2 - jj + 2:nx) - sg * this%lf(i2 + 1:k, i2)
    end do
  end subroutine drop

  !> y = L^{-1} g (first size(g) rows of the factor lf)
  subroutine forward_solve(lf, g, yy)
    real(wp), intent(in) :: lf(:,:)
    real(wp), intent(in) :: g(:)
    real(wp), intent(out) :: yy(:)
    integer :: jj, kk
    kk = size(g)
    yy = g
    do jj = 1, kk
      yy(jj) = yy(jj) / lf(jj, jj)
      yy(jj + 1:kk) = yy(jj + 1:kk) - lf(jj + 1:kk, jj) * yy(jj)
    end do
  end subroutine forward_solve

  !> z = L^{-T} yy
  subroutine back_solve(lf, yy, z)
    real(wp), intent(in) :: lf(:,:)
    real(wp), intent(in) :: yy(:)
    real(wp), intent(out) :: z(:)
    integer :: jj, kk
    kk = size(yy)
    do jj = kk, 1, -1
      z(jj) = (yy(jj) - dot_product(lf(jj + 1:kk, jj), z(jj + 1:kk))) / lf(jj, jj)
    end do
  end subroutine back_solve

  !> z = G_A^{-1} g
  subroutine chol_solve(lf, g, z)
    real(wp), intent(in) :: lf(:,:)
    real(wp), intent(in) :: g(:)
    real(wp), intent(out) :: z(:)
    real(wp) :: w(size(g))
    call forward_solve(lf, g, w)
    call back_solve(lf, w, z)
  end subroutine chol_solve
end module cr_dual_qp
