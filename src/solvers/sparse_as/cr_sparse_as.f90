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
!>
!> The parts (src/solvers/sparse_as/): the knobs and their validation (cr_sparse_as_settings),
!> the working state every part receives (cr_sparse_as_state), cluster split
!> (cr_sparse_as_clusters), rows, M and the slack kernels (cr_sparse_as_rows), the list of P
!> (cr_sparse_as_lists), the factor on P (cr_sparse_as_factor, on the CHOLMOD binding
!> cr_cholmod and its C shim), slots and analysis reuse (cr_sparse_as_slots), the step back
!> (cr_sparse_as_search) and the driver loop (cr_sparse_as_loop); this module holds the
!> solver type, the entry, the warm-start test and the safe path.
module cr_sparse_as
  use cr_kinds, only: wp
  use cr_error, only: error_t, prefix_error
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t
  use cr_active_set, only: active_set_solver_t
  use cr_projection, only: projection_solver_t, solve_stats_t, finish_stats, check_sizes, add_note
  use cr_sparse_as_settings, only: sparse_as_settings_t
  use cr_sparse_as_state, only: sparse_as_state_t
  use cr_sparse_as_clusters, only: cluster_split_t
  use cr_sparse_as_rows, only: prepare_rows, assemble_gram, velocities, first_violated
  use cr_sparse_as_factor, only: pivot_lower_bound
  use cr_sparse_as_slots, only: order_and_analyze
  use cr_sparse_as_loop, only: run
  implicit none
  private
  public :: sparse_as_solver_t, sparse_as_settings_t, pivot_lower_bound

  !> Sparse dual active-set projection with CHOLMOD factor updates.
  type, extends(projection_solver_t) :: sparse_as_solver_t
    !> tuning knobs (validated at every solve)
    type(sparse_as_settings_t) :: knobs
    !> factor, rows, analysis, counters since init
    type(sparse_as_state_t) :: state
    !> dense solver: tiny problems, small clusters and the safe path
    type(active_set_solver_t) :: dense
    logical :: dense_ready = .false.
    type(cluster_split_t) :: clusters
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
    integer :: ns, dense_rows
    call this%knobs%validate(error)
    if (allocated(error)) return
    call check_sizes("sparse_active_set", cs, v, u, lambda, error)
    if (allocated(error)) return
    dense_rows = this%settings%dense_rows
    if (cs%n <= dense_rows .or. dense_rows == 0) then
      call sparse_core(this, cs, v, u, lambda, stats, error)
      return
    end if
    call this%clusters%find_clusters(cs, dense_rows, ns)
    if (ns == 0 .or. ns == cs%n) then
      ! one kind only: no copies
      call sparse_core(this, cs, v, u, lambda, stats, error)
      return
    end if
    call this%clusters%split_rows(cs, lambda, dense_rows, ns)
    associate (cl => this%clusters)
      ! sparse path on the large clusters (its own dense fallback when needed)
      call sparse_core(this, cl%cs_large, v, cl%u_large, cl%l_large, stats, error)
      if (allocated(error)) return
      ! dense kernel on the small clusters
      call ensure_dense(this, error); if (allocated(error)) return
      call this%dense%solve(cl%cs_small, v, cl%u_small, cl%l_small, s1, error)
    end associate
    if (allocated(error)) then
      call prefix_error(error, "sparse_active_set: small clusters"); return
    end if
    stats%iterations = stats%iterations + s1%iterations
    stats%converged = stats%converged .and. s1%converged
    if (allocated(s1%note)) then
      if (len(s1%note) > 0) call add_note(stats, "small clusters: " // s1%note)
    end if
    call this%clusters%merge_back(cs%n_agents, dense_rows, u, lambda)
    call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
  end subroutine sparse_as_solve

  !> The sparse path on one contact set: rows, the warm-start test, M, the analysis, the
  !> driver loop (run), then the KKT test; a failure hands the problem to the safe path.
  subroutine sparse_core(this, cs, v, u, lambda, stats, error)
    class(sparse_as_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer :: m
    logical :: done
    character(len=:), allocatable :: reason

    call check_sizes("sparse_active_set", cs, v, u, lambda, error)
    if (allocated(error)) return
    m = cs%n
    stats%note = ""
    stats%converged = .true.
    if (.not. this%settings%warm_start) lambda(1:m) = 0.0_wp
    if (m <= this%settings%dense_rows) then
      call dense_path(this, cs, v, u, lambda, .false., stats, error)
      return
    end if
    associate (st => this%state)
      st%m = m; st%na = cs%n_agents
      call prepare_rows(st, this%knobs, cs, v, lambda, this%settings%tol, this%settings%warm_start)
      if (all(st%cc(1:m) <= st%thr)) then
        u = v
        lambda(1:m) = 0.0_wp
        call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
        return
      end if
      if (warm_is_optimal(this, cs, v, u, lambda, stats)) return
      call assemble_gram(st, cs)
      st%nfac0 = st%chol%n_factor; st%nmod0 = st%chol%n_modify
      call order_and_analyze(st, this%knobs, cs, .false., error)
      if (allocated(error)) then
        reason = error%message
        call fallback(this, cs, v, u, lambda, reason, stats, error); return
      end if
      call run(st, this%knobs, this%settings, cs, v, stats, error)
      call conclude(this, cs, v, u, lambda, stats, done, error)
      if (.not. done) return
      if (.not. (stats%kkt <= this%settings%tol)) then
        ! the updated factor may have drifted: restart from here (run refactorises the rows with
        ! lam > 0 afresh); the first run's outcome, and its note, are superseded
        stats%note = ""
        ! (the first run may have left anything off P in lam, NaN included: run starts from it)
        where (.not. (st%lam(1:m) > 0.0_wp)) st%lam(1:m) = 0.0_wp
        call run(st, this%knobs, this%settings, cs, v, stats, error)
        call conclude(this, cs, v, u, lambda, stats, done, error)
        if (.not. done) return
        if (.not. (stats%kkt <= this%settings%tol)) then
          reason = "KKT residual " // str(stats%kkt, "es9.2") // " > tol after a fresh refactorisation"
          call fallback(this, cs, v, u, lambda, reason, stats, error)
        end if
      end if
    end associate
  end subroutine sparse_core

  !> The warm start already solves the problem when its scaled KKT residual (the same test as
  !> every other exit) is at most tol: then no analysis, no factorisation. This is the case of
  !> the FOM's re-solves after a cutoff enlargement (the previous solution, on a superset of
  !> rows that stays feasible) and of steps where nothing moved. (u, lambda) are returned
  !> as they are (no iteration, stats%iterations = 0).
  logical function warm_is_optimal(this, cs, v, u, lambda, stats) result(ok)
    class(sparse_as_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(inout) :: stats
    integer :: j, m
    ok = .false.
    if (.not. this%settings%warm_start) return
    associate (st => this%state)
      m = st%m
      ! u of the warm multipliers: the rows with lam > 0 as the list of P (P itself is empty)
      st%nact = 0
      do j = 1, m
        if (st%lam(j) > 0.0_wp) then
          st%nact = st%nact + 1; st%alist(st%nact) = j
        end if
      end do
      if (st%nact == 0) return
      call velocities(st, v)
      st%nact = 0
      ! cheap screen first (new time steps fail it at once): a violated row
      if (first_violated(m, st%ka, st%kb, st%c1, st%c2, st%dd, st%uu, st%thr) > 0) return
      u = st%uu(1:2 * st%na)
      do j = 1, m
        lambda(j) = max(lambda(j), 0.0_wp)
      end do
      stats%converged = .false.
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      ok = stats%kkt <= this%settings%tol
      stats%converged = .true.
      if (ok) then
        st%n_warm_exact = st%n_warm_exact + 1
      else
        ! not optimal: back to the input state (finish_stats is recomputed at the end)
        lambda(1:m) = st%l0(1:m)
        stats%primal = 0; stats%dual = 0; stats%compl = 0; stats%stat = 0; stats%kkt = 0
        stats%note = ""
      end if
    end associate
  end function warm_is_optimal

  !> The dense solver, initialised on first use.
  subroutine ensure_dense(this, error)
    class(sparse_as_solver_t), intent(inout) :: this
    type(error_t), allocatable, intent(inout) :: error
    if (this%dense_ready) return
    call this%dense%init(this%settings, error)
    if (allocated(error)) return
    this%dense_ready = .true.
  end subroutine ensure_dense

  !> The dense cluster solver on the whole problem; as safe path, counted and noted.
  subroutine dense_path(this, cs, v, u, lambda, as_fallback, stats, error)
    class(sparse_as_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    logical, intent(in) :: as_fallback
    type(solve_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(inout) :: error
    type(solve_stats_t) :: ds
    call ensure_dense(this, error); if (allocated(error)) return
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

  !> After a run of the active-set iterations: hand a failed run (error or st%why) to the
  !> fallback (done = .false.), otherwise the factor counts, u, lambda and the KKT statistics.
  subroutine conclude(this, cs, v, u, lambda, stats, done, error)
    class(sparse_as_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(inout) :: stats
    logical, intent(out) :: done
    type(error_t), allocatable, intent(inout) :: error
    character(len=:), allocatable :: reason
    integer :: jj
    done = .false.
    associate (st => this%state)
      stats%n_factor = st%chol%n_factor - st%nfac0
      stats%n_modify = st%chol%n_modify - st%nmod0
      if (allocated(error)) then
        reason = error%message
        call fallback(this, cs, v, u, lambda, reason, stats, error); return
      end if
      if (len(st%why) > 0) then
        reason = st%why
        call fallback(this, cs, v, u, lambda, reason, stats, error); return
      end if
      call velocities(st, v)
      do jj = 1, st%m
        lambda(jj) = st%lam(jj) / st%rn(jj)
      end do
      u = st%uu(1:2 * st%na)
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      done = .true.
    end associate
  end subroutine conclude

  !> The safe path: the dense solver from the caller's warm start, noted with the reason.
  subroutine fallback(this, cs, v, u, lambda, reason, stats, error)
    class(sparse_as_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    character(len=*), intent(in) :: reason
    type(solve_stats_t), intent(inout) :: stats
    type(error_t), allocatable, intent(inout) :: error
    integer :: m
    m = this%state%m
    if (allocated(error)) deallocate(error)
    ! the sparse run's notes are superseded (the reason says why)
    stats%note = ""
    ! restart the dense path from the warm start the caller gave (the sparse multipliers may
    ! be half-way)
    if (this%settings%warm_start) then
      lambda(1:m) = this%state%l0(1:m)
    else
      lambda(1:m) = 0.0_wp
    end if
    call dense_path(this, cs, v, u, lambda, .true., stats, error)
    if (allocated(error)) return
    call add_note(stats, "sparse path failed (" // reason // "): dense active-set solution")
  end subroutine fallback

  subroutine sparse_as_free(this)
    class(sparse_as_solver_t), intent(inout) :: this
    call this%state%free()
    if (this%dense_ready) call this%dense%free()
    this%dense_ready = .false.
  end subroutine sparse_as_free
end module cr_sparse_as
