!> Exact projection by a dual active-set method whose linear algebra is a sparse LDL'
!> factorisation (SuiteSparse CHOLMOD, through cr_cholmod) of the Gram matrix of the active rows,
!> modified (cholmod_rowadd; the rows leaving together deleted by one multiple-rank update)
!> rather than rebuilt when the active set changes:
!>
!>   min |u - v|^2  s.t.  B u <= d   <=>   min_{lambda >= 0} f = 1/2 |B^T lambda|^2 - lambda^T (B v - d),
!>   u = v - B^T lambda,  grad f = d - B u (the slacks).
!>
!> Rows are normalised to unit norm (same problem, lambda rescaled on exit). M = B B^T over all
!> candidate rows is assembled once per solve (linear in rows: each row meets the rows of its
!> two agents) and analysed once (AMD) on the rows that can become active (W: warm-start rows
!> and rows with a small slack at u = v; a violated row outside W takes one of the empty tail
!> slots ordered last in every analysis, or, when none is left, enlarges W and M is analysed
!> again, counted in n_reanalyse); the factor holds M on the passive set P and the identity
!> elsewhere. Row deletions hand CHOLMOD the row's pattern (its row subtree in the elimination
!> tree of the analysed matrix) instead of letting it scan the factor.
!> - Analysis reused across solves (reuse_analysis): the analysed matrix is indexed by slots
!>   named by the rows' contact identities; M's pattern between two rows depends only on their
!>   identities (they share an agent), so while every row that may become active (warm-start
!>   rows, rows violated at u = v) has a slot, later solves refactorise on the same analysis
!>   with new values (rows without a slot stay out; a violated one enlarges W as above).
!> - Exact warm start: multipliers on entry that already meet the KKT test are returned with no
!>   analysis and no factorisation (the FOM's re-solves after a cutoff enlargement).
!> - Warm start: P = {rows with lambda > 0 on entry} (the FOM matches rows across steps by their
!>   contact identity), factorised once; lambda then moves from the warm multipliers towards
!>   the minimiser on P by the step back below (warm_search; rows leave only where f still
!>   falls with them at zero), or, without warm_search, every row with a non-positive
!>   minimiser leaves.
!> - Outer iteration (block Lawson-Hanson): the violated rows V whose slack is below add_frac
!>   times the most negative one enter at once (few: row additions of the factor; many: one
!>   numeric refactorisation); after the first dependent block every violated row enters. Then
!>   the step-back loop moves lambda towards the minimiser z on P until z > 0: by a projected
!>   search along max(0, lambda + t (z - lambda)), t in [0, 1] (past every breakpoint where f
!>   still falls; the rows frozen at zero leave P together), or, without proj_search, to the
!>   first breakpoint. f falls strictly at every outer iteration (at the start lambda minimises
!>   f on P, so grad f is zero on P and negative on V, and the directional derivative towards
!>   z is negative), so no face repeats and the method is finite. A row the search brings from
!>   lambda > 0 to zero but violated at the new point stays in P at zero (keep_violated: it
!>   would enter again at once; the step back still ends at a minimiser on P with z > 0).
!> - Minimiser after one change of P without a full solve: when one row t enters, z on P + t
!>   follows from lambda (the minimiser on P) and alpha = M_P^{-1} M(P, t), the backward half of
!>   a solve after the Schur test's forward half: z_t = -slack_t / (M(t,t) - M(P,t)' alpha),
!>   z_P = lambda_P - z_t alpha; when one row k leaves in a projected search, z on P - k is
!>   z - (z_k / (M_P^{-1})_kk) M_P^{-1} e_k, whose forward half visits one elimination-tree
!>   path only. Other changes take a solve on P.
!> - Linearly dependent rows (jammed crowds): an entering row whose new pivot D(t,t) is below
!>   dep_tol is taken out again; if every violated row is dependent, the most violated enters by
!>   exchange (b_t = B_P^T alpha: lambda_P -= tau alpha, lambda_t = tau, the row reaching zero
!>   leaves; u does not move). No alpha > 0: the constraints are infeasible (Farkas).
!> - At convergence iterative refinement on P (at most 3 steps, while the slacks on P shrink and
!>   exceed the violation threshold thr = max(1e-3 tol, 256 eps) times the velocity scale),
!>   and the test repeated.
!> - Safe path: a CHOLMOD failure, an infeasible or capped solve, or a KKT residual above tol
!>   after a fresh refactorisation hands the problem to the dense cluster solver of cr_active_set
!>   (counted in stats%n_fallback and noted, never silent).
!> - Connected clusters of the contact graph with at most settings%dense_rows rows go to the dense
!>   kernel of cr_active_set (faster there: no analysis, no library-call overhead); the others
!>   together to the sparse path.
!> - After settings%refresh_every row modifications the factor is rebuilt; with check_drift the
!>   backward error of a solve with the updated factor is measured first (stats%factor_drift).
module cr_sparse_as
  use cr_kinds, only: wp, i8
  use cr_sort, only: lower_bound
  use cr_grow, only: igrow => grow_int, rgrow => grow_real, lgrow => grow_logical, grow_kept_int, &
    grow_kept_real
  use cr_error, only: error_t, prefix_error
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t, velocity_scale
  use cr_cholmod, only: chol_t
  use cr_active_set, only: active_set_solver_t
  use cr_projection, only: projection_solver_t, solve_stats_t, finish_stats, check_sizes, add_note
  implicit none
  private
  public :: sparse_as_solver_t, pivot_lower_bound

  !> relative pivot (rows of unit norm) below which an entering row counts as dependent
  real(wp), parameter :: dep_tol = 1.0e-10_wp

  !> Sparse dual active-set projection with CHOLMOD factor updates.
  type, extends(projection_solver_t) :: sparse_as_solver_t
    type(chol_t) :: chol
    !> dense solver: tiny problems and the safe path
    type(active_set_solver_t) :: dense
    !> clusters of the contact graph: union-find parents [n_agents], rows per cluster root
    integer, allocatable :: parent(:), crows(:)
    !> the rows of small clusters (dense kernel) and of large ones (sparse path)
    type(contact_set_t) :: cs_small, cs_large
    integer, allocatable :: map_small(:), map_large(:)
    real(wp), allocatable :: u_small(:), u_large(:), l_small(:), l_large(:)
    logical :: dense_ready = .false.
    !> compare updated and fresh factors at every refresh (tests; costs one extra solve)
    logical :: check_drift = .false.
    !> more violated rows than max(bulk_min, k / bulk_div) enter by refactorisation
    integer :: bulk_min = 24, bulk_div = 4
    !> at most this many primal-dual active-set sweeps before the monotone loop
    integer :: pdas_max = 30
    !> the sweeps are used on problems with at least this many rows; off by default (measured:
    !> the monotone loop alone takes 2.4x fewer instructions on congested1000 and 12% less CPU
    !> time on congested100000, where the sweeps cycle; the sweeps save 14% on congested10000)
    integer :: pdas_rows = huge(1)
    !> step back by a projected search: lambda moves to the minimiser of f along the path
    !> max(0, lambda + t (z - lambda)), t in [0, 1], past as many breakpoints as f keeps
    !> falling (every row reaching zero on the way leaves P at once); otherwise the classical
    !> step to the first breakpoint
    logical :: proj_search = .true.
    !> only violated rows with a slack below add_frac times the most negative one enter at an outer
    !> iteration (0: every violated row), on problems with fewer than add_frac_rows rows. Measured
    !> (docs/benchmarks.md#tuned-parameters-of-sparse_active_set, add_frac): 0.5 takes 12% fewer
    !> instructions on congested150, 19% on congested1000 and halves the CPU time of the crowd1000
    !> scene; on congested10000 and congested100000 (one global threshold holds back the many
    !> separate jams) every violated row entering is 10-20% cheaper
    real(wp) :: add_frac = 0.5_wp
    !> warm start by the step back from the warm multipliers (projected search towards the minimiser
    !> on the warm passive set) instead of dropping every row whose minimiser is not positive, on
    !> problems with fewer than warm_search_rows rows. Measured
    !> (docs/benchmarks.md#tuned-parameters-of-sparse_active_set, warm_search): 22% fewer row
    !> updates on congested150; on congested10000 1.7% more instructions than without
    logical :: warm_search = .true.
    integer :: warm_search_rows = 10000
    !> a row that a projected search brings from lambda > 0 to zero but that is violated at the new
    !> point (its slack, the gradient of f, is below -thr there) stays in P at zero instead of
    !> leaving: it would enter again at the next outer iteration (a deletion, an addition and an
    !> iteration saved). Only in the first keep_searches searches of a step back, and never for a
    !> row that was at zero when the search began, so the step back stays finite. Measured
    !> (docs/benchmarks.md#tuned-parameters-of-sparse_active_set, keep_violated): 2-3% fewer
    !> instructions on congested150 (four seeds), -0.7% on congested1000
    logical :: keep_violated = .true.
    integer :: keep_searches = 4
    !> rows kept in P that way since init
    integer :: n_kept = 0
    integer :: add_frac_rows = 10000
    !> projected searches done and rows they froze (left P) since init
    integer :: n_proj = 0, n_proj_rows = 0
    !> projected search: M d, gradient, breakpoints [m], their order [m]
    real(wp), allocatable :: md(:), gd(:), tbk(:), tl(:)
    integer, allocatable :: ord(:)
    !> projected search: md, gd, tl of row j are set in search number pstamp(j) [m]
    integer, allocatable :: pstamp(:)
    integer :: npsearch = 0
    !> rows: norms, rhs, B v - d, multipliers, slacks, minimiser [m]
    real(wp), allocatable :: rn(:), dd(:), cc(:), lam(:), slack(:), z(:), rhs(:), piv(:)
    !> rows by components (tight loops): normalised coefficients c1, c2 [m], positions ka, kb
    !> [m] of the x velocity of the row's agents in uu (kb of a wall row: the slot 2 n_agents + 1
    !> of uu, kept at zero); the passive set P as a list of rows in increasing order,
    !> alist(1:nact), kept equal to the mask act
    real(wp), allocatable :: c1(:), c2(:)
    integer, allocatable :: ka(:), kb(:), alist(:)
    !> right-hand side of the solves on P: B v - d on P (alist), zero elsewhere [m]
    real(wp), allocatable :: bp(:)
    integer :: nact = 0
    !> coefficients of each agent's rows signed for that agent (+ as ia, - as ib) [2 m]
    real(wp), allocatable :: ae1(:), ae2(:)
    real(wp), allocatable :: w(:)
    !> multipliers on entry (original units), for the safe path [m]
    real(wp), allocatable :: l0(:)
    logical, allocatable :: act(:), refused(:), newact(:)
    integer, allocatable :: viol(:), rem(:)
    !> rows of each agent (CSR) [n_agents + 1], [2 m]
    integer, allocatable :: astart(:), arows(:)
    !> M = B B^T, full symmetric CSC [m + 1], [nnz], position of each diagonal entry [m] (the
    !> upper triangle of column j is fp(j):fd(j)), entries of the upper triangle
    integer, allocatable :: fp(:), fi(:), fd(:)
    real(wp), allocatable :: fv(:)
    integer :: nzu = 0
    !> velocities [2 n_agents + 2] (the last two: the zero slot of wall rows)
    real(wp), allocatable :: uu(:)
    !> solves whose warm start already met the KKT test (no analysis, no factorisation)
    integer :: n_warm_exact = 0
    !> row additions whose pre-test was skipped since init: at an agent of the row the active
    !> rows (none, or one at an angle) leave the pivot provably far above the threshold
    !> (pivot_lower_bound)
    integer :: n_free = 0
    !> rows analysed (the set W that can become active): warm-start rows and rows whose slack
    !> at u = v is below w_margin * (velocity scale); a violated row outside W enlarges W
    !> (re-analysis, counted in n_reanalyse). w_margin < 0: every row is analysed.
    real(wp) :: w_margin = 1.0_wp
    integer :: n_reanalyse = 0
    logical, allocatable :: inw(:)
    !> upper triangle of M restricted to W (and the diagonal) in slot space, as analysed
    !> (reuse_slots puts later values on this pattern) [ns + 1], [nnz]
    integer, allocatable :: wptr(:), wi(:)
    real(wp), allocatable :: wv(:)
    !> reuse the analysis of an earlier solve (reuse_analysis): the analysed matrix is indexed by
    !> slots, one per row analysed, named by the row's contact identity (key). M's pattern between
    !> two rows depends only on their identities (they share an agent), so a later solve whose rows
    !> that can become active all have a slot factorises on the same analysis (rows without one stay
    !> inactive; slots without a row are identity rows). The analysis is redone when a row that may
    !> become active has no slot, or when fewer than reuse_fill of the slots hold a row. A fresh
    !> analysis takes the rows whose slack at u = v is below a_margin (>= w_margin) times the
    !> velocity scale, so that it lasts. The rows that may become active: warm-start rows and rows
    !> whose slack at u = v is below r_margin times the velocity scale (0: the violated ones; a row
    !> violated later without a slot enlarges W as before). Measured on congested150
    !> (docs/benchmarks.md#tuned-parameters-of-sparse_active_set, a_margin): r_margin 0 and a_margin
    !> 2 take the fewest instructions.
    logical :: reuse_analysis = .true.
    real(wp) :: a_margin = 2.0_wp, reuse_fill = 0.5_wp, r_margin = 0.0_wp
    !> tail slots: a fresh analysis appends tail_slots empty slots, ordered after the others.
    !> A violated row without a slot (a contact pair new to the analysis) that must enter takes
    !> the next one (its column joins the analysed pattern, the elimination tree grows by one
    !> node; cholmod_rowadd finds the new row's fill itself): no new ordering and no
    !> refactorisation, where the enlargement of W costs both (n_reanalyse); the slot keeps
    !> its row in the next solves that reuse the analysis. Only when the tail slots run out is
    !> W enlarged as before. Rows given a tail slot since init: n_tail.
    integer :: tail_slots = 16
    integer :: n_tail = 0
    !> analyses done (fresh) and reused since the last free
    integer :: n_analyse = 0, n_reuse = 0
    !> slots of the current analysis: number; their keys in an open-addressing hash table
    !> (linear probing) [0:hmask], with the slot of each entry (0: empty) [0:hmask]
    integer :: ns = 0, hmask = 0
    logical :: keys_ok = .false.
    integer(i8), allocatable :: hkey(:)
    integer, allocatable :: hslot(:)
    !> slot of each row [m] (0: none), row of each slot [ns] (reuse_slots)
    integer, allocatable :: rslot(:), smark(:)
    !> reuse_slots: position in wi of each row of the slot column at hand, and that column [ns]
    integer, allocatable :: spos(:), scol(:)
  contains
    procedure :: solve => sparse_as_solve
    procedure :: free => sparse_as_free
  end type sparse_as_solver_t

contains

  !> Split the contact graph into connected clusters; clusters of at most dense_rows rows go
  !> to the dense kernel (faster there: no analysis, no CHOLMOD call overhead), the others
  !> together to the sparse path (sparse_core).
  subroutine sparse_as_solve(this, cs, v, u, lambda, stats, error)
    class(sparse_as_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    type(solve_stats_t) :: s1
    integer :: m, na, i, j, a, b, ns, nl
    logical :: to_dense
    call check_sizes("sparse_active_set", cs, v, u, lambda, error)
    if (allocated(error)) return
    m = cs%n; na = cs%n_agents
    if (m <= this%settings%dense_rows .or. this%settings%dense_rows == 0) then
      call sparse_core(this, cs, v, u, lambda, stats, error)
      return
    end if
    if (allocated(this%parent)) then
      if (size(this%parent) < na) deallocate(this%parent, this%crows)
    end if
    if (.not. allocated(this%parent)) allocate(this%parent(max(na, 16)), this%crows(max(na, 16)))
    do i = 1, na
      this%parent(i) = i
    end do
    do j = 1, m
      if (cs%ib(j) > 0) then
        a = find(cs%ia(j)); b = find(cs%ib(j))
        if (a /= b) this%parent(max(a, b)) = min(a, b)
      end if
    end do
    ! every agent points at its cluster's root from here on (find(x) = parent(x))
    do i = 1, na
      this%parent(i) = find(i)
    end do
    this%crows(1:na) = 0
    do j = 1, m
      a = this%parent(cs%ia(j))
      this%crows(a) = this%crows(a) + 1
    end do
    ns = 0
    do j = 1, m
      if (this%crows(this%parent(cs%ia(j))) <= this%settings%dense_rows) ns = ns + 1
    end do
    if (ns == 0 .or. ns == m) then
      ! one kind only: no copies
      call sparse_core(this, cs, v, u, lambda, stats, error)
      return
    end if
    nl = m - ns
    call this%cs_small%init(na, cs%h, ns); call this%cs_large%init(na, cs%h, nl)
    if (allocated(this%map_small)) deallocate(this%map_small, this%map_large, this%l_small, &
      this%l_large, this%u_small, this%u_large)
    allocate(this%map_small(ns), this%map_large(nl), this%l_small(ns), this%l_large(nl), &
      this%u_small(2 * na), this%u_large(2 * na))
    ns = 0; nl = 0
    do j = 1, m
      to_dense = this%crows(this%parent(cs%ia(j))) <= this%settings%dense_rows
      if (to_dense) then
        call this%cs_small%add(cs%ia(j), cs%ib(j), cs%ob(j), cs%g(:, j), cs%gap(j))
        ns = ns + 1; this%map_small(ns) = j; this%l_small(ns) = lambda(j)
      else
        call this%cs_large%add(cs%ia(j), cs%ib(j), cs%ob(j), cs%g(:, j), cs%gap(j))
        nl = nl + 1; this%map_large(nl) = j; this%l_large(nl) = lambda(j)
      end if
    end do
    ! sparse path on the large clusters (its own dense fallback when needed)
    call sparse_core(this, this%cs_large, v, this%u_large, this%l_large, stats, error)
    if (allocated(error)) return
    ! dense kernel on the small clusters
    if (.not. this%dense_ready) then
      call this%dense%init(this%settings, error)
      if (allocated(error)) return
      this%dense_ready = .true.
    end if
    call this%dense%solve(this%cs_small, v, this%u_small, this%l_small, s1, error)
    if (allocated(error)) then
      call prefix_error(error, "sparse_active_set: small clusters"); return
    end if
    stats%iterations = stats%iterations + s1%iterations
    stats%converged = stats%converged .and. s1%converged
    if (allocated(s1%note)) then
      if (len(s1%note) > 0) call add_note(stats, "small clusters: " // s1%note)
    end if
    ! the two sets of clusters share no agent: each solver leaves the other's agents at v
    u = this%u_large
    do i = 1, na
      if (this%crows(this%parent(i)) > 0 .and. this%crows(this%parent(i)) <= this%settings%dense_rows) &
        u(2*i - 1:2*i) = this%u_small(2*i - 1:2*i)
    end do
    lambda(this%map_small) = this%l_small
    lambda(this%map_large) = this%l_large
    call finish_stats(cs, v, u, lambda, this%settings%tol, stats)

  contains

    integer function find(x) result(r)
      integer, intent(in) :: x
      r = x
      do while (this%parent(r) /= r)
        this%parent(r) = this%parent(this%parent(r))
        r = this%parent(r)
      end do
    end function find

  end subroutine sparse_as_solve

  subroutine sparse_core(this, cs, v, u, lambda, stats, error)
    class(sparse_as_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer :: m, na, j, it, itmax, nv, k, nmod0, nfac0, t
    !> rows the last projected search kept in P at zero (keep_violated)
    integer :: nkept
    real(wp) :: sv, thr, tolv, wmarg
    logical :: ok, bad, exch, done
    character(len=:), allocatable :: why

    call check_sizes("sparse_active_set", cs, v, u, lambda, error)
    if (allocated(error)) return
    m = cs%n; na = cs%n_agents
    stats%note = ""
    stats%converged = .true.
    if (.not. this%settings%warm_start) lambda(1:m) = 0.0_wp
    if (m <= this%settings%dense_rows) then
      call dense_path(.false.)
      return
    end if
    call prepare()
    if (all(this%cc(1:m) <= thr)) then
      u = v
      lambda(1:m) = 0.0_wp
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      return
    end if
    if (warm_is_optimal()) return
    call assemble()
    nfac0 = this%chol%n_factor; nmod0 = this%chol%n_modify
    call order_and_analyze(.false.)
    if (allocated(error)) then
      call fallback(error%message); return
    end if
    why = ""
    call run(why)
    call conclude(done)
    if (.not. done) return
    if (.not. (stats%kkt <= this%settings%tol)) then
      ! the updated factor may have drifted: restart from here (run refactorises the rows with
      ! lam > 0 afresh); the first run's outcome, and its note, are superseded
      stats%note = ""
      ! (the first run may have left anything off P in lam, NaN included: run starts from it)
      where (.not. (this%lam(1:m) > 0.0_wp)) this%lam(1:m) = 0.0_wp
      call run(why)
      call conclude(done)
      if (.not. done) return
      if (.not. (stats%kkt <= this%settings%tol)) call fallback("KKT residual " // str(stats%kkt, "es9.2") // &
        " > tol after a fresh refactorisation")
    end if

  contains

    !> The warm start already solves the problem when its scaled KKT residual (the same test as
    !> every other exit) is at most tol: then no analysis, no factorisation. This is the case of
    !> the FOM's re-solves after a cutoff enlargement (the previous solution, on a superset of
    !> rows that stays feasible) and of steps where nothing moved. (u, lambda) are returned
    !> as they are (no iteration, stats%iterations = 0).
    logical function warm_is_optimal() result(ok)
      ok = .false.
      if (.not. this%settings%warm_start) return
      ! u of the warm multipliers: the rows with lam > 0 as the list of P (P itself is empty)
      this%nact = 0
      do j = 1, m
        if (this%lam(j) > 0.0_wp) then
          this%nact = this%nact + 1; this%alist(this%nact) = j
        end if
      end do
      if (this%nact == 0) return
      call velocities()
      this%nact = 0
      ! cheap screen first (new time steps fail it at once): a violated row
      if (first_violated(m, this%ka, this%kb, this%c1, this%c2, this%dd, this%uu, thr) > 0) return
      u = this%uu(1:2 * na)
      do j = 1, m
        lambda(j) = max(lambda(j), 0.0_wp)
      end do
      stats%converged = .false.
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      ok = stats%kkt <= this%settings%tol
      stats%converged = .true.
      if (ok) then
        this%n_warm_exact = this%n_warm_exact + 1
      else
        ! not optimal: back to the input state (finish_stats is recomputed at the end)
        lambda(1:m) = this%l0(1:m)
        stats%primal = 0; stats%dual = 0; stats%compl = 0; stats%stat = 0; stats%kkt = 0
        stats%note = ""
      end if
    end function warm_is_optimal

    !> The dense cluster solver on the whole problem; as safe path, counted and noted.
    subroutine dense_path(as_fallback)
      logical, intent(in) :: as_fallback
      type(solve_stats_t) :: ds
      if (.not. this%dense_ready) then
        call this%dense%init(this%settings, error)
        if (allocated(error)) return
        this%dense_ready = .true.
      end if
      call this%dense%solve(cs, v, u, lambda, ds, error)
      if (allocated(error)) then
        call prefix_error(error, "sparse_active_set: dense path"); return
      end if
      stats%iterations = stats%iterations + ds%iterations
      stats%converged = ds%converged
      if (as_fallback) stats%n_fallback = stats%n_fallback + 1
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      if (allocated(ds%note)) then
        if (len(ds%note) > 0) call add_note(stats, ds%note)
      end if
    end subroutine dense_path

    !> Factorise the active rows, leaving out (multiplier zero) the rows whose pivot shows them
    !> dependent on the others, up to four factorisations; bad: the fourth still had such a
    !> row (it is left out too and the factor is rebuilt without it).
    subroutine factor_independent(bad)
      logical, intent(out) :: bad
      integer :: tr, jj
      bad = .false.
      do tr = 1, 4
        call this%chol%factor(this%act(1:m), error); if (allocated(error)) return
        call this%chol%pivots(this%piv(1:m), error); if (allocated(error)) return
        bad = .false.
        do jj = 1, m
          if (this%act(jj) .and. .not. (this%piv(jj) > dep_tol)) then
            this%act(jj) = .false.; this%lam(jj) = 0.0_wp; bad = .true.
          end if
        end do
        if (.not. bad) return
      end do
      call this%chol%factor(this%act(1:m), error)
    end subroutine factor_independent

    !> After a run of the active-set iterations: hand a failed run (error or `why`) to the
    !> fallback (done = .false.), otherwise the factor counts, u, lambda and the KKT statistics.
    subroutine conclude(done)
      logical, intent(out) :: done
      integer :: jj
      done = .false.
      stats%n_factor = this%chol%n_factor - nfac0
      stats%n_modify = this%chol%n_modify - nmod0
      if (allocated(error)) then
        call fallback(error%message); return
      end if
      if (len(why) > 0) then
        call fallback(why); return
      end if
      call velocities()
      do jj = 1, m
        lambda(jj) = this%lam(jj) / this%rn(jj)
      end do
      u = this%uu(1:2 * na)
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      done = .true.
    end subroutine conclude

    subroutine fallback(reason)
      character(len=*), intent(in) :: reason
      character(len=:), allocatable :: r
      r = reason
      if (allocated(error)) deallocate(error)
      ! the sparse run's notes are superseded (the reason says why)
      stats%note = ""
      ! restart the dense path from the warm start the caller gave (the sparse multipliers may
      ! be half-way)
      if (this%settings%warm_start) then
        lambda(1:m) = this%l0(1:m)
      else
        lambda(1:m) = 0.0_wp
      end if
      call dense_path(.true.)
      if (allocated(error)) return
      call add_note(stats, "sparse path failed (" // r // "): dense active-set solution")
    end subroutine fallback

    !> Normalised rows, B v - d, scale, thresholds; work arrays sized.
    subroutine prepare()
      integer :: a, b
      real(wp) :: x1, x2, rinv
      call rgrow(this%rn, m); call rgrow(this%dd, m); call rgrow(this%cc, m)
      call rgrow(this%lam, m); call rgrow(this%slack, m); call rgrow(this%z, m)
      call rgrow(this%rhs, m); call rgrow(this%piv, m); call rgrow(this%w, m)
      call rgrow(this%l0, m)
      call rgrow(this%md, m); call rgrow(this%gd, m); call rgrow(this%tbk, m); call rgrow(this%tl, m)
      call igrow(this%ord, m); call igrow(this%pstamp, m)
      this%pstamp(1:m) = 0; this%npsearch = 0
      this%l0(1:m) = lambda(1:m)
      call lgrow(this%act, m); call lgrow(this%refused, m); call lgrow(this%newact, m)
      call lgrow(this%inw, m)
      call igrow(this%viol, m); call igrow(this%rem, m)
      call rgrow(this%uu, 2 * na + 2)
      call rgrow(this%c1, m); call rgrow(this%c2, m)
      call igrow(this%ka, m); call igrow(this%kb, m); call igrow(this%alist, m)
      call rgrow(this%bp, m)
      this%bp(1:m) = 0.0_wp
      this%nact = 0
      tolv = max(1.0e-3_wp * this%settings%tol, 256.0_wp * epsilon(1.0_wp))
      sv = tiny(1.0_wp) * 1.0e10_wp
      if (size(v) > 0) sv = max(sv, maxval(abs(v)))
      do j = 1, m
        ! the row's norm (h |g| with |g| about 1: no scaling needed) and one division
        x1 = -cs%h * cs%g(1, j); x2 = -cs%h * cs%g(2, j)
        this%rn(j) = sqrt(x1 * x1 + x2 * x2)
        if (cs%ib(j) > 0) this%rn(j) = this%rn(j) * sqrt(2.0_wp)
        rinv = 1.0_wp / this%rn(j)
        x1 = x1 * rinv; x2 = x2 * rinv
        this%c1(j) = x1; this%c2(j) = x2
        this%dd(j) = cs%gap(j) * rinv
        sv = max(sv, -this%dd(j))
        a = cs%ia(j); b = cs%ib(j)
        this%ka(j) = 2 * a - 1
        this%cc(j) = x1 * v(2*a - 1) + x2 * v(2*a)
        if (b > 0) then
          this%kb(j) = 2 * b - 1
          this%cc(j) = this%cc(j) - x1 * v(2*b - 1) - x2 * v(2*b)
        else
          this%kb(j) = 2 * na + 1
        end if
        this%cc(j) = this%cc(j) - this%dd(j)
        this%lam(j) = 0.0_wp
        if (this%settings%warm_start .and. lambda(j) > 0.0_wp) this%lam(j) = lambda(j) * this%rn(j)
        this%act(j) = .false.
        this%refused(j) = .false.
      end do
      thr = tolv * sv
      wmarg = this%w_margin
      do j = 1, m
        this%inw(j) = this%w_margin < 0.0_wp .or. this%lam(j) > 0.0_wp .or. &
          this%cc(j) > -this%w_margin * sv
      end do
    end subroutine prepare

    !> M = B B^T (normalised rows): full CSC (fp, fi, fv), rows sorted in each column, the
    !> diagonal of column j at fd(j) (so its upper triangle is fp(j):fd(j)).
    subroutine assemble()
      integer :: a, nz, p1
      ! each agent's rows (CSR astart, arows), each list closed by a sentinel row huge(1)
      call igrow(this%astart, na + 1)
      this%astart(1:na + 1) = 1
      do j = 1, m
        this%astart(cs%ia(j) + 1) = this%astart(cs%ia(j) + 1) + 1
        if (cs%ib(j) > 0) this%astart(cs%ib(j) + 1) = this%astart(cs%ib(j) + 1) + 1
      end do
      this%astart(1) = 1
      do a = 1, na
        this%astart(a + 1) = this%astart(a + 1) + this%astart(a)
      end do
      call igrow(this%arows, this%astart(na + 1))
      call rgrow(this%ae1, this%astart(na + 1)); call rgrow(this%ae2, this%astart(na + 1))
      ! fill pointers live in fp (size na + 1 at least); each agent's rows with their
      ! coefficients signed for the agent, so that M(j, l) = sum over shared agents of the
      ! products of signed coefficients
      call igrow(this%fp, max(m, na) + 1)
      this%fp(1:na) = this%astart(1:na)
      do j = 1, m
        a = cs%ia(j); p1 = this%fp(a); this%fp(a) = p1 + 1
        this%arows(p1) = j; this%ae1(p1) = this%c1(j); this%ae2(p1) = this%c2(j)
        a = cs%ib(j)
        if (a > 0) then
          p1 = this%fp(a); this%fp(a) = p1 + 1
          this%arows(p1) = j; this%ae1(p1) = -this%c1(j); this%ae2(p1) = -this%c2(j)
        end if
      end do
      do a = 1, na
        this%arows(this%astart(a + 1) - 1) = huge(1)
      end do
      ! upper bound of the entries: sum over rows of the rows of their agents
      nz = 0
      do j = 1, m
        nz = nz + this%astart(cs%ia(j) + 1) - this%astart(cs%ia(j)) - 1
        if (cs%ib(j) > 0) nz = nz + this%astart(cs%ib(j) + 1) - this%astart(cs%ib(j)) - 1
      end do
      call igrow(this%fi, nz); call rgrow(this%fv, nz)
      call igrow(this%fd, m)
      call assemble_columns(m, cs%ia, cs%ib, this%c1, this%c2, this%astart, this%arows, &
        this%ae1, this%ae2, this%fp, this%fi, this%fv, this%fd, nz, this%nzu)
      this%fp(m + 1) = nz + 1
    end subroutine assemble

    !> Analyse M restricted to the rows of W (AMD ordering), in slot space: slot k is the k-th row
    !> of W, the other rows have no slot (they never enter the factor). Without fresh and with
    !> reuse_analysis, the previous analysis is kept when every row that may become active has a
    !> slot in it (reuse_slots); a fresh analysis widens W to the a_margin rows first (unless fresh:
    !> the enlargement of a solve, which sets W itself). Reusing the previous call's ordering by
    !> contact identity with a fresh symbolic analysis (CHOLMOD_GIVEN) was measured and is not
    !> cheaper: the symbolic analysis costs about as much as AMD on these graphs.
    subroutine order_and_analyze(fresh)
      logical, intent(in) :: fresh
      integer :: jj, q, nzw, k
      if (.not. fresh .and. this%reuse_analysis) then
        if (reuse_slots()) return
        if (allocated(error)) return
      end if
      if (.not. fresh .and. this%a_margin > this%w_margin .and. this%w_margin >= 0.0_wp) then
        do jj = 1, m
          if (this%cc(jj) > -this%a_margin * sv) this%inw(jj) = .true.
        end do
      end if
      call igrow(this%rslot, m)
      k = 0
      do jj = 1, m
        this%rslot(jj) = 0
        if (this%inw(jj)) then
          k = k + 1; this%rslot(jj) = k
        end if
      end do
      ! and the tail slots k + 1 .. ns (empty columns)
      this%ns = k + max(this%tail_slots, 0)
      ! no reuse of this analysis until it is complete
      this%keys_ok = .false.
      ! slot numbers grow with the row number: sorted columns stay sorted
      call igrow(this%wptr, this%ns + 1); call igrow(this%wi, max(this%nzu, 1))
      call rgrow(this%wv, max(this%nzu, 1))
      nzw = 0
      do jj = 1, m
        if (.not. this%inw(jj)) cycle
        this%wptr(this%rslot(jj)) = nzw + 1
        do q = this%fp(jj), this%fd(jj)
          if (this%inw(this%fi(q))) then
            nzw = nzw + 1
            this%wi(nzw) = this%rslot(this%fi(q)); this%wv(nzw) = this%fv(q)
          end if
        end do
      end do
      this%wptr(k + 1:this%ns + 1) = nzw + 1
      call this%chol%analyze(this%ns, this%wptr, this%wi, this%wv, error, ntail=this%ns - k)
      if (allocated(error)) return
      call this%chol%set_rows(this%rslot(1:m), error)
      if (allocated(error)) return
      this%n_analyse = this%n_analyse + 1
      ! the slots' identities in a hash table (at most half full), for the next solves
      q = 16
      do while (q < 2 * this%ns)
        q = 2 * q
      end do
      if (allocated(this%hkey)) then
        if (size(this%hkey) < q) deallocate(this%hkey, this%hslot)
      end if
      if (.not. allocated(this%hkey)) allocate(this%hkey(0:q - 1), this%hslot(0:q - 1))
      this%hmask = q - 1
      this%hslot(0:q - 1) = 0
      this%keys_ok = .true.
      do jj = 1, m
        if (this%inw(jj)) call slot_insert(cs%key(jj), this%rslot(jj))
      end do
    end subroutine order_and_analyze

    !> Name slot k by contact identity key in the slot table (two rows with one identity: no
    !> reuse of this analysis, never expected of a contact set).
    subroutine slot_insert(key, k)
      integer(i8), intent(in) :: key
      integer, intent(in) :: k
      integer :: q
      q = key_hash(key, this%hmask)
      do while (this%hslot(q) /= 0)
        if (this%hkey(q) == key) this%keys_ok = .false.
        q = iand(q + 1, this%hmask)
      end do
      this%hkey(q) = key; this%hslot(q) = k
    end subroutine slot_insert

    !> The previous analysis serves this solve when every row that may become active (warm start,
    !> slack at u = v below r_margin velocity scales) has a slot (found by its contact identity), no
    !> two rows share one, and at least reuse_fill of the slots hold a row. Then W becomes every row
    !> with a slot, M is handed over in slot space (same pattern as analysed or a part of it) and ok
    !> is true.
    logical function reuse_slots() result(ok)
      integer :: jj, k, nzs, nin, nneed
      ok = .false.
      if (.not. this%keys_ok .or. this%ns == 0) return
      call igrow(this%rslot, m); call igrow(this%smark, this%ns)
      this%smark(1:this%ns) = 0
      nin = 0; nneed = 0
      do jj = 1, m
        k = find_slot(cs%key(jj))
        if (k > 0) then
          if (this%smark(k) /= 0) return
          this%smark(k) = jj; nin = nin + 1
        else if (this%lam(jj) > 0.0_wp .or. this%cc(jj) > -this%r_margin * sv) then
          ! may become active without a slot: a tail slot below, while they last
          nneed = nneed + 1
          if (nneed > this%chol%tail_free()) return
          this%rem(nneed) = jj
        end if
        this%rslot(jj) = k
      end do
      if (real(nin, wp) < this%reuse_fill * real(this%ns - this%chol%tail_free(), wp)) return
      ! the values of M on the analysed pattern (slot_values; M is assembled exactly
      ! symmetric, so the values are those of the row-space upper triangle); an entry outside
      ! the pattern (never expected: the same slots keep the same neighbours) means no reuse
      nzs = this%wptr(this%ns + 1) - 1
      call igrow(this%spos, this%ns); call igrow(this%scol, this%ns)
      call slot_values(m, this%ns, this%rslot, this%fp, this%fi, this%fv, this%wptr, this%wi, &
        this%wv, this%spos, this%scol, ok)
      if (.not. ok) then
        this%keys_ok = .false.; return
      end if
      call this%chol%set_analysed_values(this%wv(1:nzs), error)
      if (allocated(error)) then
        ! the analysis does not match (never expected): analyse afresh
        deallocate(error); this%keys_ok = .false.; return
      end if
      call this%chol%set_rows(this%rslot(1:m), error)
      if (allocated(error)) return
      do jj = 1, m
        this%inw(jj) = this%rslot(jj) > 0
      end do
      do k = 1, nneed
        call tail_slot(this%rem(k)); if (allocated(error)) return
      end do
      this%n_reuse = this%n_reuse + 1
      ok = .true.
    end function reuse_slots

    !> Slot of the analysis named by contact identity key (0: none).
    integer function find_slot(key) result(k)
      integer(i8), intent(in) :: key
      integer :: q
      q = key_hash(key, this%hmask)
      k = 0
      do while (this%hslot(q) /= 0)
        if (this%hkey(q) == key) then
          k = this%hslot(q); return
        end if
        q = iand(q + 1, this%hmask)
      end do
    end function find_slot

    !> Rows viol(1:n) must be able to enter: those outside W take tail slots while enough are
    !> left (tail_slot: the analysis grows, the factor stays); otherwise W takes them and every
    !> row whose current slack is below the margin, M is analysed again and P refactorised. The
    !> margin doubles at each enlargement of a solve, so that a solve re-analyses a few times
    !> at most (W soon holds every row).
    subroutine enlarge_w(n)
      integer, intent(in) :: n
      integer :: q
      if (all(this%inw(this%viol(1:n)))) return
      if (count(.not. this%inw(this%viol(1:n))) <= this%chol%tail_free()) then
        ! tail slots for the rows without one: the analysis grows, the factor stays
        do q = 1, n
          if (.not. this%inw(this%viol(q))) then
            call tail_slot(this%viol(q)); if (allocated(error)) return
          end if
        end do
        return
      end if
      this%inw(this%viol(1:n)) = .true.
      wmarg = 2.0_wp * wmarg
      call slacks()
      do q = 1, m
        if (this%slack(q) < wmarg * sv) this%inw(q) = .true.
      end do
      this%n_reanalyse = this%n_reanalyse + 1
      call order_and_analyze(.true.); if (allocated(error)) return
      call this%chol%factor(this%act(1:m), error)
    end subroutine enlarge_w

    !> Give row jr (no slot) the next tail slot: its column of the slot-space upper triangle
    !> (the rows of its agents that have a slot, then its diagonal) joins the analysed
    !> pattern (wptr, wi: the next solves put their values there) and the analysis in the shim;
    !> its identity joins the slot table.
    subroutine tail_slot(jr)
      integer, intent(in) :: jr
      integer :: q, e, st, cnt, kk, p
      real(wp) :: x
      st = this%ns - this%chol%tail_free() + 1
      e = this%wptr(st)
      q = e - 1 + this%fp(jr + 1) - this%fp(jr)
      if (size(this%wi) < q) call grow_kept_int(this%wi, 2 * q, e - 1)
      if (size(this%wv) < q) call grow_kept_real(this%wv, 2 * q, e - 1)
      cnt = 0
      do q = this%fp(jr), this%fp(jr + 1) - 1
        kk = this%fi(q)
        if (kk == jr .or. this%rslot(kk) == 0) cycle
        ! by increasing slot (insertion: a few entries)
        kk = this%rslot(kk); x = this%fv(q)
        p = e + cnt
        do while (p > e)
          if (this%wi(p - 1) < kk) exit
          this%wi(p) = this%wi(p - 1); this%wv(p) = this%wv(p - 1)
          p = p - 1
        end do
        this%wi(p) = kk; this%wv(p) = x
        cnt = cnt + 1
      end do
      cnt = cnt + 1
      this%wi(e + cnt - 1) = st; this%wv(e + cnt - 1) = this%fv(this%fd(jr))
      call this%chol%add_slot(st, this%wi(e:e + cnt - 1), this%wv(e:e + cnt - 1), jr, error)
      if (allocated(error)) return
      this%wptr(st + 1:this%ns + 1) = e + cnt
      this%rslot(jr) = st; this%inw(jr) = .true.
      call slot_insert(cs%key(jr), st)
      this%n_tail = this%n_tail + 1
    end subroutine tail_slot

    !> The active-set iteration from this%lam (warm start) on the current analysis. why is set
    !> (non-empty) when the safe path must take over.
    subroutine run(why)
      character(len=:), allocatable, intent(inout) :: why
      integer :: q, pmin, nadd, ntry, n_ref, nrem, nv_all, i1
      real(wp) :: frac
      !> z already holds the minimiser on P (one row entered)
      logical :: zset
      integer, parameter :: n_refine = 3
      real(wp) :: pivot, tau, xmax, r, r_ref
      !> some row may be refused (refused(1:m) not all false)
      logical :: any_ref
      why = ""
      any_ref = .true.
      it = 0
      itmax = min(this%settings%max_iter, 10 * m + 100)
      ! ---- warm start: factor the guessed passive set, drop dependent rows, then rows whose
      ! minimiser is not positive
      do j = 1, m
        this%act(j) = this%lam(j) > 0.0_wp
      end do
      call list_from_mask()
      k = this%nact
      if (k > 0 .and. this%warm_search .and. m < this%warm_search_rows) then
        ! from the warm multipliers (feasible, positive on P) by the step back: rows leave P
        ! only where f still falls with them at zero (monotone from here on)
        call factor_independent(bad); if (allocated(error)) return
        call list_prune()
        call step_back(.false., .false.); if (allocated(error)) return
        if (len(why) > 0) return
      else if (k > 0) then
        call factor_independent(bad); if (allocated(error)) return
        call list_prune()
        call drop_nonpositive(); if (allocated(error)) return
      else
        this%lam(1:m) = 0.0_wp
        call this%chol%factor(this%act(1:m), error); if (allocated(error)) return
      end if
      this%refused(1:m) = .false.; any_ref = .false.

      ! ---- primal-dual active-set sweeps (semismooth Newton on the dual): all violated rows
      ! enter and all rows with a non-positive minimiser leave at once. Not monotone, so at
      ! most pdas_max sweeps; a dependent pivot ends them. The block Lawson-Hanson loop below
      ! then finishes from lambda = z > 0 on P (usually with nothing left to do).
      sweeps: do ntry = 1, merge(this%pdas_max, 0, m >= this%pdas_rows)
        ! lambda = z on P (signs unrestricted), then the slacks it gives
        call list_from_mask()
        call solve_p(); if (allocated(error)) return
        call lam_from_z()
        call slacks()
        nv = 0; nrem = 0
        do j = 1, m
          if (this%act(j)) then
            if (this%z(j) <= 0.0_wp) then
              nrem = nrem + 1; this%rem(nrem) = j
            end if
          else if (this%slack(j) < -thr) then
            nv = nv + 1; this%viol(nv) = j
          end if
        end do
        if (nv == 0 .and. nrem == 0) exit sweeps
        if (nv > 0) then
          call enlarge_w(nv); if (allocated(error)) return
        end if
        it = it + 1
        stats%iterations = stats%iterations + 1
        k = this%nact
        this%newact(1:m) = this%act(1:m)
        this%newact(this%viol(1:nv)) = .true.
        this%newact(this%rem(1:nrem)) = .false.
        if (nv + nrem > max(this%bulk_min, k / this%bulk_div)) then
          call this%chol%factor(this%newact(1:m), error); if (allocated(error)) return
          call this%chol%pivots(this%piv(1:m), error); if (allocated(error)) return
          ! rows with a dependent pivot stay out (sweeps are heuristic; the monotone loop
          ! below settles them); refactorise without them
          do q = 1, 3
            bad = .false.
            do j = 1, m
              if (this%newact(j) .and. .not. (this%piv(j) > dep_tol)) then
                this%newact(j) = .false.; bad = .true.
              end if
            end do
            if (.not. bad) exit
            call this%chol%factor(this%newact(1:m), error); if (allocated(error)) return
            call this%chol%pivots(this%piv(1:m), error); if (allocated(error)) return
          end do
          if (bad) then
            call this%chol%factor(this%act(1:m), error); if (allocated(error)) return
            exit sweeps
          end if
          this%act(1:m) = this%newact(1:m)
        else
          if (nrem > 0) then
            call this%chol%rowdel(this%rem(1:nrem), error); if (allocated(error)) return
          end if
          this%act(this%rem(1:nrem)) = .false.
          bad = .false.
          do q = 1, nv
            ! with the pivot pre-test: a row dependent on the ones added before it is never
            ! added (CHOLMOD's next update would divide by its zero pivot)
            t = this%viol(q)
            call add_row(t, pivot); if (allocated(error)) return
            if (.not. this%act(t)) then
              bad = .true.
              exit
            end if
          end do
          ! an addition also lowers the later pivots (and a bad one spoils the factor)
          if (.not. bad) bad = .not. (this%chol%min_pivot() > dep_tol)
          if (bad) then
            ! refactorise the current set, leaving out the rows with a dependent pivot
            call factor_independent(bad); if (allocated(error)) return
            if (bad) exit sweeps
          end if
        end if
      end do sweeps
      ! back to the invariant of the monotone loop: lambda = z > 0 on P (the warm start above
      ! already ends there: only the sweeps leave it)
      if (m >= this%pdas_rows .and. this%pdas_max > 0) then
        call list_from_mask()
        call drop_nonpositive(); if (allocated(error)) return
      end if

      ! ---- main loop (block Lawson-Hanson)
      frac = merge(this%add_frac, 0.0_wp, m < this%add_frac_rows)
      n_ref = 0; r_ref = huge(1.0_wp)
      outer: do
        if (this%chol%n_since >= this%settings%refresh_every) then
          call refresh(); if (allocated(error)) return
        end if
        call velocities()
        call slacks_violated(m, this%ka, this%kb, this%c1, this%c2, this%dd, this%uu, thr, &
          this%act, this%refused, this%slack, nv, this%viol)
        if (nv == 0 .and. any_ref) then
          ! rows refused as dependent but still violated: exchange them in
          do j = 1, m
            if (this%slack(j) < -thr) then
              if (this%refused(j) .and. .not. this%act(j)) then
                nv = nv + 1; this%viol(nv) = j
              end if
            end if
          end do
        end if
        nv_all = nv
        if (nv > 0 .and. frac > 0.0_wp) then
          ! only the rows violated by at least add_frac times the largest violation enter
          r = 0.0_wp
          do q = 1, nv
            r = min(r, this%slack(this%viol(q)))
          end do
          nadd = 0
          do q = 1, nv
            if (this%slack(this%viol(q)) <= frac * r) then
              nadd = nadd + 1; this%viol(nadd) = this%viol(q)
            end if
          end do
          nv = nadd
        end if
        if (nv > 0) then
          call enlarge_w(nv); if (allocated(error)) return
        end if
        exch = nv > 0 .and. all(this%refused(this%viol(1:nv)))
        if (nv == 0) then
          k = this%nact
          if (k == 0) exit outer
          ! iterative refinement on P (at most n_refine steps while the slacks on P shrink and
          ! exceed thr: 1e-3 of the tolerance; polishing them to round-off, 1e-2 thr, took 1.3
          ! solves per step on congested150 for KKT residuals up to 5x smaller, all 140x below tol)
          r = 0.0_wp
          do q = 1, k
            r = max(r, abs(this%slack(this%alist(q))))
          end do
          if (n_ref >= n_refine .or. r <= thr .or. r >= 0.5_wp * r_ref) exit outer
          n_ref = n_ref + 1; r_ref = r
          this%rhs(1:m) = 0.0_wp
          do q = 1, k
            j = this%alist(q); this%rhs(j) = this%slack(j)
          end do
          call this%chol%solve(this%rhs(1:m), this%z(1:m), error); if (allocated(error)) return
          ok = .true.
          do q = 1, k
            j = this%alist(q)
            if (.not. (this%lam(j) - this%z(j) > 0.0_wp)) ok = .false.
          end do
          if (.not. ok) exit outer
          do q = 1, k
            j = this%alist(q); this%lam(j) = this%lam(j) - this%z(j)
          end do
          cycle outer
        end if
        n_ref = 0; r_ref = huge(1.0_wp)
        if (it >= itmax) then
          why = "iteration cap " // str(itmax) // " reached"
          return
        end if
        it = it + 1
        stats%iterations = stats%iterations + 1
        k = this%nact
        nadd = 0
        zset = .false.
        if (exch) then
          continue
        else if (nv > max(this%bulk_min, k / this%bulk_div)) then
          ! many entering rows: one refactorisation of P + V
          this%newact(1:m) = this%act(1:m)
          this%newact(this%viol(1:nv)) = .true.
          call this%chol%factor(this%newact(1:m), error); if (allocated(error)) return
          call this%chol%pivots(this%piv(1:m), error); if (allocated(error)) return
          bad = .false.
          do j = 1, m
            if (this%newact(j) .and. .not. (this%piv(j) > dep_tol)) bad = .true.
          end do
          if (bad) then
            ! dependent rows among them: back to P, and add one at a time below
            call this%chol%factor(this%act(1:m), error); if (allocated(error)) return
          else
            this%act(1:m) = this%newact(1:m)
            call list_from_mask()
            nadd = nv
          end if
        end if
        if (nadd == 0 .and. .not. exch) then
          ! the rows that entered join the list of P together after the loop (rem: scratch)
          do q = 1, nv
            t = this%viol(q)
            if (nv == 1) then
              ! one row enters: the minimiser on P + t from lambda (the minimiser on P) and
              ! alpha = M_P^{-1} M(P, t) (the backward half of a solve after the test's
              ! forward half): z_t = -slack_t / pivot, z_P = lambda_P - z_t alpha
              call add_row(t, pivot, alpha=.true., schur=r); if (allocated(error)) return
              if (this%act(t)) then
                tau = -this%slack(t) / r
                do j = 1, this%nact
                  i1 = this%alist(j); this%z(i1) = this%lam(i1) - tau * this%w(i1)
                end do
                this%z(t) = tau
                zset = .true.
              end if
            else
              call add_row(t, pivot); if (allocated(error)) return
            end if
            if (this%act(t)) then
              nadd = nadd + 1; this%rem(nadd) = t
            else
              this%refused(t) = .true.; any_ref = .true.
            end if
          end do
          call list_merge(nadd, this%rem)
        end if
        if (nadd == 0 .and. .not. exch .and. nv < nv_all) then
          ! the most violated rows are dependent on P: from here on every violated row enters
          ! (the classical rule; a dependent block is where degenerate exchanges could cycle)
          frac = 0.0_wp
          cycle outer
        end if
        if (nadd == 0) then
          ! every violated row is dependent on P: exchange the most violated one
          frac = 0.0_wp
          t = this%viol(1)
          do q = 2, nv
            if (this%slack(this%viol(q)) < this%slack(t)) t = this%viol(q)
          end do
          this%refused(t) = .false.
          ! alpha = M_P^{-1} B_P b_t (this%w, left by add_row)
          call add_row(t, pivot, precheck=.true., alpha=.true.); if (allocated(error)) return
          if (this%act(t)) then
            call list_insert(t)
            call step_back(.false., .false.); if (allocated(error)) return
            if (len(why) > 0) return
            cycle outer
          end if
          xmax = 0.0_wp
          do q = 1, this%nact
            xmax = max(xmax, abs(this%w(this%alist(q))))
          end do
          tau = huge(1.0_wp); pmin = 0
          do q = 1, this%nact
            j = this%alist(q)
            if (this%w(j) > 1.0e-12_wp * xmax) then
              r = this%lam(j) / this%w(j)
              if (r < tau) then
                tau = r; pmin = j
              end if
            end if
          end do
          if (pmin == 0) then
            why = "constraints infeasible (Farkas certificate)"
            return
          end if
          do q = 1, this%nact
            j = this%alist(q); this%lam(j) = max(0.0_wp, this%lam(j) - tau * this%w(j))
          end do
          this%lam(pmin) = 0.0_wp
          call this%chol%rowdel([pmin], error); if (allocated(error)) return
          this%act(pmin) = .false.
          call list_delete(pmin)
          call add_row(t, pivot, 1.0e3_wp * epsilon(1.0_wp), precheck=.true.)
          if (allocated(error)) return
          if (this%act(t)) then
            call list_insert(t)
            this%lam(t) = tau
          else
            this%refused(t) = .true.; any_ref = .true.
            this%lam(t) = 0.0_wp
          end if
          call nonpositive_on_p(this%lam)
          if (nv > 0) then
            call remove_rows(nv); if (allocated(error)) return
          end if
          call step_back(.false., .false.); if (allocated(error)) return
        else
          if (any_ref) this%refused(1:m) = .false.
          any_ref = .false.
          ! lambda has not moved since the slacks above (entering rows have lambda = 0)
          call step_back(.true., zset); if (allocated(error)) return
        end if
        if (len(why) > 0) return
      end do outer
    end subroutine run

    !> Move lambda towards the minimiser z on P until z > 0 (rows reaching zero leave P, except
    !> the violated ones kept by keep_violated in the first keep_searches searches).
    !> fresh: uu and the slacks are those of lambda on entry (no need to compute them again).
    subroutine step_back(fresh, have_z)
      logical, intent(in) :: fresh
      !> z already holds the minimiser on P
      logical, intent(in) :: have_z
      real(wp) :: alpha, r, lmax
      integer :: jj, q, nsearch, i1
      logical :: have_u, zok
      have_u = fresh
      nsearch = 0
      zok = have_z
      do
        if (.not. zok) then
          call solve_p(); if (allocated(error)) return
        end if
        zok = .false.
        alpha = 1.0_wp
        do q = 1, this%nact
          jj = this%alist(q)
          if (this%z(jj) <= 0.0_wp) then
            ! a row at zero (lambda = 0, e.g. entered with z = 0) blocks at once: alpha = 0
            r = 0.0_wp
            if (this%lam(jj) > 0.0_wp) r = this%lam(jj) / (this%lam(jj) - this%z(jj))
            alpha = min(alpha, r)
          end if
        end do
        if (alpha >= 1.0_wp) then
          call copy_on_list(this%nact, this%alist, this%z, this%lam)
          return
        end if
        if (it >= itmax) then
          why = "iteration cap " // str(itmax) // " reached"
          return
        end if
        it = it + 1
        stats%iterations = stats%iterations + 1
        if (this%proj_search) then
          call projected_step(have_u, this%keep_violated .and. nsearch < this%keep_searches)
          if (allocated(error)) return
          nsearch = nsearch + 1
          have_u = .false.
          ! only kept rows reached zero: solve again on P (they are in it, at zero)
          if (nv == 0 .and. nkept > 0) cycle
          if (nv == 1 .and. nkept == 0) then
            ! one row leaves: the minimiser on P without it from the one on P by a column
            ! of the inverse, z - (z_k / (M_P^{-1})_kk) M_P^{-1} e_k (half a solve less)
            jj = this%viol(1)
            call this%chol%unit_solve(jj, this%rhs(1:m), r, error); if (allocated(error)) return
            r = this%z(jj) / r
            do q = 1, this%nact
              i1 = this%alist(q); this%z(i1) = this%z(i1) - r * this%rhs(i1)
            end do
            this%z(jj) = 0.0_wp
            zok = .true.
          end if
          if (nv > 0) then
            call remove_rows(nv); if (allocated(error)) return
            cycle
          end if
        end if
        lmax = 0.0_wp
        do q = 1, this%nact
          jj = this%alist(q)
          this%lam(jj) = this%lam(jj) + alpha * (this%z(jj) - this%lam(jj))
          lmax = max(lmax, this%lam(jj))
        end do
        nv = 0
        do q = 1, this%nact
          jj = this%alist(q)
          if (this%z(jj) <= 0.0_wp .and. this%lam(jj) <= 64.0_wp * epsilon(1.0_wp) * lmax) then
            this%lam(jj) = 0.0_wp
            nv = nv + 1; this%viol(nv) = jj
          end if
        end do
        if (nv == 0) then
          ! round-off: take out the row that defined alpha
          do q = 1, this%nact
            jj = this%alist(q)
            if (this%z(jj) <= 0.0_wp) then
              if (this%lam(jj) <= 0.0_wp .or. nv == 0) then
                if (nv == 0) then
                  nv = 1; this%viol(1) = jj
                else if (this%lam(jj) < this%lam(this%viol(1))) then
                  this%viol(1) = jj
                end if
              end if
            end if
          end do
          this%lam(this%viol(1)) = 0.0_wp
        end if
        call remove_rows(nv); if (allocated(error)) return
      end do
    end subroutine step_back

    !> Projected search from lambda (feasible, zero off P) towards the minimiser z on P (some
    !> z_j <= 0): f along the path lambda(t) = max(0, lambda + t d), d = z - lambda, t in [0, 1],
    !> is a convex piecewise quadratic whose pieces end where a row reaches zero (breakpoints
    !> t_j = lambda_j / (lambda_j - z_j), sorted). Walk the pieces while f still falls; at each
    !> breakpoint the row is frozen at zero (d_j = 0; M d and the slope are updated from column
    !> j of M). lambda becomes lambda(t*), the frozen rows are returned in viol(1:nv) (they
    !> leave P). f(lambda(t*)) <= f at the first breakpoint (the classical step), so the
    !> method stays monotone and finite. nv = 0 (round-off: no descent) leaves lambda as is.
    !> have_u: this%slack already holds the slacks at lambda. keep: frozen rows that had
    !> lambda > 0 when the search began and are violated at lambda(t*) (slack = gradient there
    !> below -thr) stay in P at zero (nkept of them; the next solve on P includes them, and a
    !> row at zero with z <= 0 then leaves at once, never kept again).
    subroutine projected_step(have_u, keep)
      logical, intent(in) :: have_u, keep
      integer :: jj, q, nb, kb, p1, p2, l, i, ps
      real(wp) :: sl, qq, ta, tn, ts, dj, lmax, r
      ! d = z - lambda on P (in this%w); the gradient g = M lambda - c on P is the slack of the
      ! rows at u(lambda), and M d = M_P z - M_P lambda = -g on P (z solves M_P z = c_P)
      if (.not. have_u) then
        call velocities()
        do q = 1, this%nact
          jj = this%alist(q)
          this%slack(jj) = slack_of(jj, this%ka, this%kb, this%c1, this%c2, this%dd, this%uu)
        end do
      end if
      nkept = 0
      ! gd = slack, md = -slack, tl = 0 on P, set when a row is first met in the walk (ps)
      this%npsearch = this%npsearch + 1
      ps = this%npsearch
      call search_start(this%nact, this%alist, this%z, this%lam, this%slack, this%w, this%ord, &
        this%tbk, sl, nb)
      qq = -sl
      ta = 0.0_wp; kb = 0; ts = 0.0_wp
      do
        tn = 1.0_wp
        if (kb < nb) then
          ! next breakpoint: the smallest left (selection: the walk usually stops after a few)
          p2 = kb + 1
          do p1 = kb + 2, nb
            if (this%tbk(this%ord(p1)) < this%tbk(this%ord(p2))) p2 = p1
          end do
          l = this%ord(p2); this%ord(p2) = this%ord(kb + 1); this%ord(kb + 1) = l
          tn = min(1.0_wp, this%tbk(l))
        end if
        if (.not. (sl < 0.0_wp)) then
          ts = ta; exit
        end if
        if (qq > 0.0_wp) then
          if (ta - sl / qq <= tn) then
            ts = ta - sl / qq; exit
          end if
        end if
        if (kb >= nb .or. tn >= 1.0_wp) then
          ts = tn; exit
        end if
        ! move to the breakpoint, freeze its row: the slope there with d, then without d_l;
        ! the gradient of a row is brought up to date (gd + (t - tl) M d) only when its M d
        ! changes, so that a breakpoint costs one column of M
        sl = sl + (tn - ta) * qq
        kb = kb + 1
        l = this%ord(kb)
        if (this%pstamp(l) /= ps) then
          this%gd(l) = this%slack(l); this%md(l) = -this%slack(l); this%tl(l) = 0.0_wp
          this%pstamp(l) = ps
        end if
        dj = this%w(l)
        sl = sl - dj * (this%gd(l) + (tn - this%tl(l)) * this%md(l))
        ! q' = (d - dj e_l)' M (d - dj e_l) = q - 2 dj (M d)_l + dj^2 M_ll, then M d -= dj M(:, l)
        qq = qq - 2.0_wp * dj * this%md(l)
        do q = this%fp(l), this%fp(l + 1) - 1
          i = this%fi(q)
          if (i == l) qq = qq + dj * dj * this%fv(q)
          if (this%act(i)) then
            if (this%pstamp(i) /= ps) then
              this%gd(i) = this%slack(i); this%md(i) = -this%slack(i); this%tl(i) = 0.0_wp
              this%pstamp(i) = ps
            end if
            this%gd(i) = this%gd(i) + (tn - this%tl(i)) * this%md(i)
            this%tl(i) = tn
            this%md(i) = this%md(i) - dj * this%fv(q)
          end if
        end do
        this%w(l) = 0.0_wp
        ta = tn
      end do
      nv = 0
      if (kb == 0) return
      ! lambda(t*): frozen rows (and rows that reach zero at t* by round-off) leave
      call move_on_list(this%nact, this%alist, this%lam, this%w, ts, lmax)
      do q = 1, kb
        this%lam(this%ord(q)) = 0.0_wp
      end do
      this%n_proj = this%n_proj + 1
      do q = 1, this%nact
        jj = this%alist(q)
        if (this%z(jj) <= 0.0_wp .and. this%lam(jj) <= 64.0_wp * epsilon(1.0_wp) * lmax) then
          this%lam(jj) = 0.0_wp
          nv = nv + 1; this%viol(nv) = jj
        end if
      end do
      if (keep) then
        ! the gradient of a frozen row at t* (gd + (t* - tl) M d; a row the walk did not meet:
        ! slack + t* (-slack)); tbk > 0: lambda was positive at the start
        p1 = 0
        do q = 1, nv
          jj = this%viol(q)
          if (this%pstamp(jj) == ps) then
            r = this%gd(jj) + (ts - this%tl(jj)) * this%md(jj)
          else
            r = this%slack(jj) * (1.0_wp - ts)
          end if
          if (r < -thr .and. this%tbk(jj) > 0.0_wp) then
            nkept = nkept + 1
          else
            p1 = p1 + 1; this%viol(p1) = jj
          end if
        end do
        nv = p1
        this%n_kept = this%n_kept + nkept
      end if
      this%n_proj_rows = this%n_proj_rows + nv
    end subroutine projected_step

    !> Take rows viol(1:n) out of P (row deletions, or one refactorisation when many).
    subroutine remove_rows(n)
      integer, intent(in) :: n
      integer :: q
      if (n > max(this%bulk_min, this%nact / this%bulk_div)) then
        this%act(this%viol(1:n)) = .false.
        call list_prune()
        call this%chol%factor(this%act(1:m), error)
      else
        call this%chol%rowdel(this%viol(1:n), error); if (allocated(error)) return
        do q = 1, n
          this%act(this%viol(q)) = .false.
          if (n <= 4) call list_delete(this%viol(q))
        end do
        if (n > 4) call list_prune()
      end if
      this%lam(this%viol(1:n)) = 0.0_wp
    end subroutine remove_rows

    !> The minimiser z on P; rows with z <= 0 leave P until none is left, then lambda = z on P
    !> (zero elsewhere).
    subroutine drop_nonpositive()
      do
        call solve_p(); if (allocated(error)) return
        call nonpositive_on_p(this%z)
        if (nv == 0) exit
        call remove_rows(nv); if (allocated(error)) return
      end do
      call lam_from_z()
    end subroutine drop_nonpositive

    !> The rows of P (in list order) where x <= 0: viol(1:nv).
    subroutine nonpositive_on_p(x)
      real(wp), intent(in) :: x(:)
      integer :: q, jj
      nv = 0
      do q = 1, this%nact
        jj = this%alist(q)
        if (x(jj) <= 0.0_wp) then
          nv = nv + 1; this%viol(nv) = jj
        end if
      end do
    end subroutine nonpositive_on_p

    !> lambda = z on P, zero elsewhere.
    subroutine lam_from_z()
      integer :: q, jj
      this%lam(1:m) = 0.0_wp
      do q = 1, this%nact
        jj = this%alist(q); this%lam(jj) = this%z(jj)
      end do
    end subroutine lam_from_z

    !> The list of P (alist, nact) and the right-hand side bp from the mask act.
    subroutine list_from_mask()
      integer :: jj
      this%nact = 0
      do jj = 1, m
        if (this%act(jj)) then
          this%nact = this%nact + 1; this%alist(this%nact) = jj
          this%bp(jj) = this%cc(jj)
        else
          this%bp(jj) = 0.0_wp
        end if
      end do
    end subroutine list_from_mask

    !> Rows whose mask went off (removals, dependent rows) leave the list of P.
    subroutine list_prune()
      integer :: q, n, jj
      n = 0
      do q = 1, this%nact
        jj = this%alist(q)
        if (this%act(jj)) then
          n = n + 1; this%alist(n) = jj
        else
          this%bp(jj) = 0.0_wp
        end if
      end do
      this%nact = n
    end subroutine list_prune

    !> Rows rows(1:n) entered P (masks on): into the list, in order (a few one by one, more
    !> by one merge from the back when rows is increasing).
    subroutine list_merge(n, rows)
      integer, intent(in) :: n, rows(:)
      integer :: q, i, k
      logical :: one_by_one
      one_by_one = n <= 8
      do q = 2, n
        if (rows(q) <= rows(q - 1)) one_by_one = .true.
      end do
      if (one_by_one) then
        do k = 1, n
          call list_insert(rows(k))
        end do
        return
      end if
      i = this%nact; k = n
      do q = this%nact + n, 1, -1
        if (k == 0) exit
        if (i > 0) then
          if (this%alist(i) > rows(k)) then
            this%alist(q) = this%alist(i); i = i - 1
            cycle
          end if
        end if
        this%alist(q) = rows(k); this%bp(rows(k)) = this%cc(rows(k)); k = k - 1
      end do
      this%nact = this%nact + n
    end subroutine list_merge

    !> Row tt left P (mask off): out of the list.
    subroutine list_delete(tt)
      integer, intent(in) :: tt
      integer :: lo, n
      this%bp(tt) = 0.0_wp
      n = this%nact
      lo = lower_bound(this%alist(1:n), tt)
      if (lo > n) return
      if (this%alist(lo) /= tt) return
      this%alist(lo:n - 1) = this%alist(lo + 1:n)
      this%nact = n - 1
    end subroutine list_delete

    !> Row tt entered P (mask on): into the list, in order.
    subroutine list_insert(tt)
      integer, intent(in) :: tt
      integer :: lo, n
      this%bp(tt) = this%cc(tt)
      ! the first position whose row exceeds tt (binary search), then shift the tail
      n = this%nact
      lo = lower_bound(this%alist(1:n), tt)
      if (lo <= n) this%alist(lo + 1:n + 1) = this%alist(lo:n)
      this%alist(lo) = tt
      this%nact = n + 1
    end subroutine list_insert

    !> Row tt enters the factor unless dependent on P: pivot = 1 - w^T M_P^{-1} w (w = M(P, tt),
    !> alpha = M_P^{-1} w left in this%w) is checked before the addition (a near-zero pivot would
    !> spoil the rank-one downdate of the trailing factor); pivot is then the factor's new D(tt,tt).
    subroutine add_row(tt, pivot, min_pivot, precheck, alpha, schur)
      integer, intent(in) :: tt
      real(wp), intent(out) :: pivot
      !> with alpha: the Schur complement M(tt,tt) - M(P,tt)^T alpha the test found
      real(wp), intent(out), optional :: schur
      !> relative pivot below which tt counts as dependent (default dep_tol)
      real(wp), intent(in), optional :: min_pivot
      !> test the pivot by a solve before the addition (default; leaves alpha in this%w);
      !> otherwise the row is added and, when its pivot or a later one became too small, the
      !> factor is rebuilt without it (cheaper when rows are rarely dependent)
      logical, intent(in), optional :: precheck
      !> present: compute alpha = M_P^{-1} M(P, tt) into this%w by a full solve (the
      !> exchange step needs it); otherwise the test is one sparse forward solve
      logical, intent(in), optional :: alpha
      integer :: q1, q2, q
      real(wp) :: s, dtt, pmin_rel
      logical :: pre
      pre = .true.
      if (present(precheck)) pre = precheck
      pmin_rel = dep_tol
      if (present(min_pivot)) pmin_rel = min_pivot
      q1 = this%fp(tt); q2 = this%fp(tt + 1) - 1
      dtt = 0.0_wp
      do q = q1, q2
        if (this%fi(q) == tt) dtt = this%fv(q)
      end do
      if (pre) then
        if (present(alpha)) then
          ! alpha = M_P^{-1} M(P, tt) in this%w on P: the test's forward solve, then the
          ! backward one
          call this%chol%schur(tt, this%fi(q1:q2), this%fv(q1:q2), s, error, this%w(1:m))
          if (allocated(error)) return
        else if (pivot_lower_bound(tt, this%fp, this%fi, this%act, cs%ia, cs%ib, this%c1, &
                                   this%c2) > 1.0e3_wp * pmin_rel * dtt) then
          ! at an agent of tt the active rows leave part of b_t outside the span of B_P:
          ! the pivot is at least that part's norm^2, far above the threshold (no test)
          this%n_free = this%n_free + 1
          s = 0.0_wp
        else
          call this%chol%schur(tt, this%fi(q1:q2), this%fv(q1:q2), s, error)
          if (allocated(error)) return
        end if
        pivot = dtt - s
        if (present(schur)) schur = pivot
        if (.not. (pivot > pmin_rel * dtt)) return
      end if
      call this%chol%rowadd(tt, this%fi(q1:q2), this%fv(q1:q2), pivot, error)
      if (allocated(error)) return
      this%act(tt) = .true.
      ! the addition also lowers the later pivots: if any became tiny, tt depends on P
      if (.not. pre) pivot = min(pivot, this%chol%min_pivot())
      if (.not. (pivot > pmin_rel * dtt)) then
        ! dependent row: the rank-2 update of the trailing factor is unreliable, rebuild
        this%act(tt) = .false.
        call this%chol%factor(this%act(1:m), error)
      end if
    end subroutine add_row

    !> z = (B_P B_P^T)^{-1} (B v - d)_P (zero off P).
    subroutine solve_p()
      call this%chol%solve(this%bp(1:m), this%z(1:m), error)
    end subroutine solve_p

    !> Refactorise P afresh. With check_drift, first measure the backward error of a solve with
    !> the updated factor, |M_P z - c_P|_inf / (|M_P|_inf |z|_inf + |c_P|_inf) (about eps for a
    !> fresh factor, whatever the conditioning of M_P), into stats%factor_drift.
    subroutine refresh()
      real(wp) :: r, rmax, mnorm, rs, zmax, cmax
      integer :: jj, q
      if (this%check_drift) then
        call solve_p(); if (allocated(error)) return
        rmax = 0.0_wp; mnorm = 0.0_wp; zmax = 0.0_wp; cmax = 0.0_wp
        do jj = 1, m
          if (.not. this%act(jj)) cycle
          r = -this%cc(jj); rs = 0.0_wp
          do q = this%fp(jj), this%fp(jj + 1) - 1
            if (this%act(this%fi(q))) then
              r = r + this%fv(q) * this%z(this%fi(q))
              rs = rs + abs(this%fv(q))
            end if
          end do
          rmax = max(rmax, abs(r)); mnorm = max(mnorm, rs)
          zmax = max(zmax, abs(this%z(jj))); cmax = max(cmax, abs(this%cc(jj)))
        end do
        if (mnorm * zmax + cmax > 0.0_wp) &
          stats%factor_drift = max(stats%factor_drift, rmax / (mnorm * zmax + cmax))
      end if
      call this%chol%factor(this%act(1:m), error)
    end subroutine refresh

    !> uu = v - B_P^T lambda_P, slack = d - B uu (normalised rows).
    subroutine slacks()
      call velocities()
      call all_slacks(m, this%ka, this%kb, this%c1, this%c2, this%dd, this%uu, this%slack)
    end subroutine slacks

    !> uu = v - B_P^T lambda_P (normalised rows).
    subroutine velocities()
      call active_velocities(this%nact, this%alist, this%ka, this%kb, this%c1, this%c2, &
        this%lam, 2 * na, v, this%uu)
    end subroutine velocities

  end subroutine sparse_core

  !> A lower bound of the pivot row tt would get against the active rows (its Schur
  !> complement, the squared distance of b_t to the span of B_P; rows by their coefficients
  !> c1, c2 on the velocity of their first agent ia and -c1, -c2 on that of their second ib,
  !> 0 for a wall), from the active rows at each of tt's agents only: the distance is at least
  !> that of b_t's part on the agent's velocity (norm^2 n2 = c1^2 + c2^2) to the span of the
  !> active rows' parts there, which is n2 with no such row, n2 sin^2(angle) with one, and
  !> unknown (0) with two or more. Column tt of M (fi(fp(tt):fp(tt + 1) - 1)) must list every
  !> row sharing an agent with tt. Public for its test.
  pure real(wp) function pivot_lower_bound(tt, fp, fi, act, ia, ib, c1, c2) result(bnd)
    integer, intent(in) :: tt, fp(*), fi(*), ia(*), ib(*)
    logical, intent(in) :: act(*)
    real(wp), intent(in) :: c1(*), c2(*)
    integer :: ag(2), nr(2), l, p, k, na_t
    real(wp) :: n2, cr(2), nl2(2)
    ag(1) = ia(tt); ag(2) = ib(tt)
    na_t = merge(2, 1, ag(2) > 0)
    nr = 0; cr = 0.0_wp; nl2 = 1.0_wp
    do p = fp(tt), fp(tt + 1) - 1
      l = fi(p)
      if (l == tt .or. .not. act(l)) cycle
      do k = 1, na_t
        if (ia(l) == ag(k) .or. ib(l) == ag(k)) then
          nr(k) = nr(k) + 1
          ! (c1, c2) x (c1_l, c2_l): the sine of the angle times both norms
          cr(k) = c1(tt) * c2(l) - c2(tt) * c1(l)
          nl2(k) = c1(l)**2 + c2(l)**2
        end if
      end do
    end do
    n2 = c1(tt)**2 + c2(tt)**2
    bnd = 0.0_wp
    do k = 1, na_t
      if (nr(k) == 0) then
        bnd = max(bnd, n2)
      else if (nr(k) == 1) then
        bnd = max(bnd, cr(k)**2 / nl2(k))
      end if
    end do
  end function pivot_lower_bound

  !> projected_step's start: d = z - lambda on the list of P (into w), the slope
  !> sl = slack' d, and the rows with z <= 0 (ord(1:nb)) with their breakpoints tbk.
  pure subroutine search_start(nact, alist, z, lam, slack, w, ord, tbk, sl, nb)
    integer, intent(in) :: nact, alist(nact)
    real(wp), intent(in) :: z(*), lam(*), slack(*)
    real(wp), intent(inout) :: w(*), tbk(*)
    integer, intent(inout) :: ord(*)
    real(wp), intent(out) :: sl
    integer, intent(out) :: nb
    integer :: q, jj
    sl = 0.0_wp; nb = 0
    do q = 1, nact
      jj = alist(q)
      w(jj) = z(jj) - lam(jj)
      sl = sl + slack(jj) * w(jj)
      if (z(jj) <= 0.0_wp) then
        nb = nb + 1; ord(nb) = jj
        if (lam(jj) > 0.0_wp) then
          tbk(jj) = lam(jj) / (lam(jj) - z(jj))
        else
          tbk(jj) = 0.0_wp
        end if
      end if
    end do
  end subroutine search_start

  !> lam = max(0, lam + t w) on the list of P; lmax its largest value there.
  pure subroutine move_on_list(nact, alist, lam, w, t, lmax)
    integer, intent(in) :: nact, alist(nact)
    real(wp), intent(inout) :: lam(*)
    real(wp), intent(in) :: w(*), t
    real(wp), intent(out) :: lmax
    integer :: q, jj
    lmax = 0.0_wp
    do q = 1, nact
      jj = alist(q)
      lam(jj) = max(0.0_wp, lam(jj) + t * w(jj))
      lmax = max(lmax, lam(jj))
    end do
  end subroutine move_on_list

  !> dst = src on the list of P.
  pure subroutine copy_on_list(nact, alist, src, dst)
    integer, intent(in) :: nact, alist(nact)
    real(wp), intent(in) :: src(*)
    real(wp), intent(inout) :: dst(*)
    integer :: q
    do q = 1, nact
      dst(alist(q)) = src(alist(q))
    end do
  end subroutine copy_on_list

  !> reuse_slots: the values of M on the analysed pattern (wptr, wi: upper triangle in slot
  !> space, rows increasing in each column): slot column b = rslot(jj) takes the entries of
  !> the whole column jj of M whose row has a slot a <= b, each found through the positions
  !> of column b's rows scattered first (spos, scol [ns]: work). ok is false when an entry
  !> lies outside the pattern.
  pure subroutine slot_values(m, ns, rslot, fp, fi, fv, wptr, wi, wv, spos, scol, ok)
    integer, intent(in) :: m, ns, rslot(m), fp(m + 1), fi(*), wptr(ns + 1), wi(*)
    real(wp), intent(in) :: fv(*)
    real(wp), intent(inout) :: wv(*)
    integer, intent(inout) :: spos(ns), scol(ns)
    logical, intent(out) :: ok
    integer :: jj, a, b, p, q
    ok = .false.
    wv(1:wptr(ns + 1) - 1) = 0.0_wp
    scol = 0
    do jj = 1, m
      b = rslot(jj)
      if (b == 0) cycle
      do p = wptr(b), wptr(b + 1) - 1
        spos(wi(p)) = p; scol(wi(p)) = b
      end do
      do q = fp(jj), fp(jj + 1) - 1
        a = rslot(fi(q))
        if (a == 0 .or. a > b) cycle
        if (scol(a) /= b) return
        wv(spos(a)) = fv(q)
      end do
    end do
    ok = .true.
  end subroutine slot_values

  !> Columns of M = B B^T (sparse_core's assemble): column j (signed + for its first agent a,
  !> - for its second b) is the rows of a (a wall row), or the merge of the rows of a and of b
  !> (each list sorted by row and closed by the sentinel huge(1)), a row met in both (the
  !> same pair twice) summed: sorted columns without marks or sorting. fd(j): position of
  !> the diagonal; nz: entries; nzu: entries of the upper triangle. (Explicit-shape arrays:
  !> in the solver's own arrays the compiler reloaded every descriptor after each store.)
  pure subroutine assemble_columns(m, ia, ib, c1, c2, astart, arows, ae1, ae2, fp, fi, fv, fd, nz, nzu)
    integer, intent(in) :: m, ia(m), ib(m), astart(*), arows(*)
    real(wp), intent(in) :: c1(m), c2(m), ae1(*), ae2(*)
    integer, intent(inout) :: fp(*), fi(*), fd(m)
    real(wp), intent(inout) :: fv(*)
    integer, intent(out) :: nz, nzu
    integer :: j, a, b, l, p1, p2, e1, r1, r2
    real(wp) :: x1, x2
    nz = 0; nzu = 0
    do j = 1, m
      fp(j) = nz + 1
      a = ia(j); b = ib(j)
      x1 = c1(j); x2 = c2(j)
      p1 = astart(a)
      if (b == 0) then
        e1 = astart(a + 1) - 2
        do p1 = p1, e1
          l = arows(p1)
          nz = nz + 1
          fi(nz) = l; fv(nz) = x1 * ae1(p1) + x2 * ae2(p1)
          if (l == j) fd(j) = nz
        end do
      else
        p2 = astart(b)
        r1 = arows(p1); r2 = arows(p2)
        do
          nz = nz + 1
          if (r1 < r2) then
            fi(nz) = r1; fv(nz) = x1 * ae1(p1) + x2 * ae2(p1)
            p1 = p1 + 1; r1 = arows(p1)
          else if (r2 < r1) then
            fi(nz) = r2; fv(nz) = -(x1 * ae1(p2) + x2 * ae2(p2))
            p2 = p2 + 1; r2 = arows(p2)
          else if (r1 == huge(1)) then
            nz = nz - 1; exit
          else
            fi(nz) = r1
            fv(nz) = (x1 * ae1(p1) + x2 * ae2(p1)) - (x1 * ae1(p2) + x2 * ae2(p2))
            if (r1 == j) fd(j) = nz
            p1 = p1 + 1; r1 = arows(p1)
            p2 = p2 + 1; r2 = arows(p2)
          end if
        end do
      end if
      nzu = nzu + fd(j) - fp(j) + 1
    end do
  end subroutine assemble_columns

  !> uu = v - sum over the rows j of P (list alist(1:nact), in increasing order) of lam_j b_j
  !> (normalised rows by components c1, c2, velocity positions ka, kb of their agents: see
  !> sparse_as_solver_t); uu [n + 2], v [n], uu(n + 1:n + 2) (wall rows' second agent) zero.
  pure subroutine active_velocities(nact, alist, ka, kb, c1, c2, lam, n, v, uu)
    integer, intent(in) :: nact, n
    integer, intent(in) :: alist(*), ka(*), kb(*)
    real(wp), intent(in) :: c1(*), c2(*), lam(*), v(n)
    real(wp), intent(inout) :: uu(n + 2)
    integer :: q, j, a, b
    real(wp) :: t1, t2
    uu(1:n) = v
    do q = 1, nact
      j = alist(q)
      t1 = lam(j) * c1(j); t2 = lam(j) * c2(j)
      a = ka(j); b = kb(j)
      uu(a) = uu(a) - t1; uu(a + 1) = uu(a + 1) - t2
      uu(b) = uu(b) + t1; uu(b + 1) = uu(b + 1) + t2
    end do
    ! the wall rows' slot took their updates: zero again (only ever read as zero)
    uu(n + 1:n + 2) = 0.0_wp
  end subroutine active_velocities

  !> slack_j = d_j - b_j . uu for every row [m] (as active_velocities).
  pure subroutine all_slacks(m, ka, kb, c1, c2, dd, uu, slack)
    integer, intent(in) :: m
    integer, intent(in) :: ka(m), kb(m)
    real(wp), intent(in) :: c1(m), c2(m), dd(m), uu(*)
    real(wp), intent(inout) :: slack(m)
    integer :: j
    do j = 1, m
      slack(j) = slack_of(j, ka, kb, c1, c2, dd, uu)
    end do
  end subroutine all_slacks

  !> slack_j = d_j - b_j . uu for every row [m] (as all_slacks), and the rows violated
  !> (slack_j < -thr) outside P (act) and not refused, in increasing order: viol(1:nv).
  pure subroutine slacks_violated(m, ka, kb, c1, c2, dd, uu, thr, act, refused, slack, nv, viol)
    integer, intent(in) :: m
    integer, intent(in) :: ka(m), kb(m)
    real(wp), intent(in) :: c1(m), c2(m), dd(m), uu(*), thr
    logical, intent(in) :: act(m), refused(m)
    real(wp), intent(inout) :: slack(m)
    integer, intent(out) :: nv
    integer, intent(inout) :: viol(*)
    integer :: j
    real(wp) :: r
    nv = 0
    do j = 1, m
      r = slack_of(j, ka, kb, c1, c2, dd, uu)
      slack(j) = r
      if (r < -thr) then
        if (.not. (act(j) .or. refused(j))) then
          nv = nv + 1; viol(nv) = j
        end if
      end if
    end do
  end subroutine slacks_violated

  !> The first row j with slack_j < -thr (as all_slacks), 0 if none.
  pure integer function first_violated(m, ka, kb, c1, c2, dd, uu, thr) result(jv)
    integer, intent(in) :: m
    integer, intent(in) :: ka(m), kb(m)
    real(wp), intent(in) :: c1(m), c2(m), dd(m), uu(*), thr
    integer :: j
    jv = 0
    do j = 1, m
      if (slack_of(j, ka, kb, c1, c2, dd, uu) < -thr) then
        jv = j; return
      end if
    end do
  end function first_violated

  !> slack_j = d_j - b_j . uu of row j (normalised rows by components c1, c2, velocity
  !> positions ka, kb of the row's agents; a wall row's kb is uu's zero slot): the one formula
  !> of the slack kernels.
  pure real(wp) function slack_of(j, ka, kb, c1, c2, dd, uu) result(r)
    integer, intent(in) :: j, ka(*), kb(*)
    real(wp), intent(in) :: c1(*), c2(*), dd(*), uu(*)
    r = c1(j) * uu(ka(j)) + c2(j) * uu(ka(j) + 1)
    r = r - c1(j) * uu(kb(j)) - c2(j) * uu(kb(j) + 1)
    r = dd(j) - r
  end function slack_of

  !> Position of a contact identity (agent pair or agent-obstacle pair: two 31-bit halves) in
  !> a hash table of mask + 1 (a power of two) entries; no integer overflow.
  pure integer function key_hash(key, mask) result(q)
    integer(i8), intent(in) :: key
    integer, intent(in) :: mask
    integer(i8) :: hi, lo, h
    hi = ishft(key, -32); lo = iand(key, 4294967295_i8)
    h = ieor(lo * 1000003_i8, hi * 2750159_i8)
    h = ieor(h, ishft(h, -17))
    q = int(iand(h, int(mask, i8)))
  end function key_hash

  subroutine sparse_as_free(this)
    class(sparse_as_solver_t), intent(inout) :: this
    call this%chol%free()
    this%keys_ok = .false.; this%ns = 0
    this%n_analyse = 0; this%n_reuse = 0; this%n_tail = 0
    if (this%dense_ready) call this%dense%free()
    this%dense_ready = .false.
  end subroutine sparse_as_free
end module cr_sparse_as
