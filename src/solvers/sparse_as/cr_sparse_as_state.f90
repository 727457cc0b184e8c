!> The working state of the sparse dual active-set projection: the factor, the normalised rows,
!> the Gram matrix M = B B^T, the passive set P (mask and list), the analysed slots, the
!> scalars of the solve at hand and the counters since init. Every part of sparse_active_set
!> (cr_sparse_as_*) receives it as an argument.
module cr_sparse_as_state
  use cr_kinds, only: wp, i8
  use cr_cholmod, only: chol_t
  implicit none
  private
  public :: sparse_as_state_t

  type :: sparse_as_state_t
    type(chol_t) :: chol
    ! ---- the solve at hand
    !> rows, agents; iterations of this run and their cap; rows in viol of the last step;
    !> rows the last projected search kept in P at zero (keep_violated); factorisations and
    !> row modifications of the factor when the solve began
    integer :: m = 0, na = 0, it = 0, itmax = 0, nv = 0, nkept = 0, nfac0 = 0, nmod0 = 0
    !> velocity scale, violation threshold thr = max(1e-3 tol, 256 eps) sv, margin of W
    real(wp) :: sv = 0.0_wp, thr = 0.0_wp, wmarg = 0.0_wp
    !> why the safe path must take over (empty: it need not)
    character(len=:), allocatable :: why
    ! ---- counters since init
    !> rows kept in P by keep_violated; projected searches done and rows they froze (left P)
    integer :: n_kept = 0, n_proj = 0, n_proj_rows = 0
    !> solves whose warm start already met the KKT test (no analysis, no factorisation)
    integer :: n_warm_exact = 0
    !> row additions whose pre-test was skipped: at an agent of the row the active rows (none,
    !> or one at an angle) leave the pivot provably far above the threshold (pivot_lower_bound)
    integer :: n_free = 0
    !> enlargements of W (re-analysis); rows given a tail slot
    integer :: n_reanalyse = 0, n_tail = 0
    !> analyses done (fresh) and reused since the last free
    integer :: n_analyse = 0, n_reuse = 0
    ! ---- rows
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
    !> alpha = M_P^{-1} M(P, t) of an entering row, or d = z - lambda of a search [m]
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
    ! ---- the analysis (cr_sparse_as_slots)
    !> rows of W [m]
    logical, allocatable :: inw(:)
    !> upper triangle of M restricted to W (and the diagonal) in slot space, as analysed
    !> (reuse_slots puts later values on this pattern) [ns + 1], [nnz]
    integer, allocatable :: wptr(:), wi(:)
    real(wp), allocatable :: wv(:)
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
    procedure :: free => state_free
  end type sparse_as_state_t

contains

  !> Release the factor and forget the analysis (the work arrays are kept for reuse).
  subroutine state_free(this)
    class(sparse_as_state_t), intent(inout) :: this
    call this%chol%free()
    this%keys_ok = .false.; this%ns = 0
    this%n_analyse = 0; this%n_reuse = 0; this%n_tail = 0
  end subroutine state_free
end module cr_sparse_as_state
