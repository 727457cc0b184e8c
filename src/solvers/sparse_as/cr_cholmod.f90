!> Fortran side of the CHOLMOD shim (cr_cholmod_shim.c beside it): a sparse symmetric matrix
!> M [n, n], its fill-reducing analysis, and a simplicial LDL' factor of the "active" matrix
!> (M on the active rows, identity elsewhere) that is modified by row additions and deletions
!> (cholmod_rowadd; several rows deleted by one cholmod_updown) instead of being rebuilt.
!> Indices here are 1-based; every CHOLMOD status is checked by the shim and returned as an
!> error_t naming the call.
module cr_cholmod
  use, intrinsic :: iso_c_binding, only: c_ptr, c_null_ptr, c_int, c_double, c_char, c_long, &
    c_associated, c_loc
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  implicit none
  private
  public :: chol_t

  !> A CHOLMOD factor of an active submatrix, with row add/delete.
  type :: chol_t
    type(c_ptr), private :: h = c_null_ptr
    !> dimension of M
    integer :: n = 0
    !> number of numeric factorisations and of row modifications since init
    integer :: n_factor = 0, n_modify = 0
    !> row modifications since the last numeric factorisation
    integer :: n_since = 0
    !> from this dimension on, the Schur pivot test visits only the elimination-tree reach of
    !> the new row in the current factor (below, a scan of the active positions from its first
    !> one is cheaper)
    integer :: reach_min = 2048
    !> from this dimension on, a numeric factorisation starts from the packed identity and
    !> its columns grow as they fill (as cholmod_factorize does); below, each column gets the
    !> analysed count plus room at once (no column moves, more memory)
    integer :: pack_min = 16384
    !> the caller's rows and their slots in the analysed matrix: the caller numbers its rows
    !> 1..nrow, the factor knows M [n, n] on slots; map(i) is row i's slot, 0 when the row has
    !> none (such a row can never be active: identity, refused by factor and rowadd). After
    !> analyze the map is the identity (nrow = n); set_rows changes it (reused analysis).
    integer :: nrow = 0
    integer, allocatable :: map(:)
    !> slot-space work arrays [n]
    real(wp), allocatable, private :: xs(:)
    integer(c_int), allocatable, private :: as(:)
  contains
    procedure :: init => chol_init
    procedure :: free => chol_free
    procedure :: analyze => chol_analyze
    procedure :: factor => chol_factor
    procedure :: pivots => chol_pivots
    procedure :: rowadd => chol_rowadd
    procedure :: rowdel => chol_rowdel
    procedure :: solve => chol_solve
    procedure :: unit_solve => chol_unit_solve
    procedure :: factor_nnz => chol_factor_nnz
    procedure :: row_entries => chol_row_entries
    procedure :: min_pivot => chol_min_pivot
    procedure :: schur => chol_schur
    procedure :: symbolic_nnz => chol_symbolic_nnz
    procedure :: perm => chol_perm
    procedure :: n_schur_scan => chol_n_schur_scan
    procedure :: n_bounded => chol_n_bounded
    procedure :: set_rows => chol_set_rows
    procedure :: set_analysed_values => chol_set_analysed_values
    procedure :: add_slot => chol_add_slot
    procedure :: tail_free => chol_tail_free
  end type chol_t

  interface
    integer(c_int) function c_new(hp) bind(C, name='cr_chol_new')
      import :: c_ptr, c_int
      type(c_ptr), intent(out) :: hp
    end function c_new
    subroutine c_free(hp) bind(C, name='cr_chol_free')
      import :: c_ptr
      type(c_ptr), intent(inout) :: hp
    end subroutine c_free
    subroutine c_message(h, buf, len) bind(C, name='cr_chol_message')
      import :: c_ptr, c_char, c_int
      type(c_ptr), value :: h
      character(kind=c_char), intent(out) :: buf(*)
      integer(c_int), value :: len
    end subroutine c_message
    integer(c_int) function c_analyze(h, n, colptr, rowind, val, perm, inset, ntail) bind(C, name='cr_chol_analyze')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      integer(c_int), value :: n
      integer(c_int), intent(in) :: colptr(*), rowind(*)
      real(c_double), intent(in) :: val(*)
      type(c_ptr), value :: perm
      integer(c_int), intent(in) :: inset(*)
      integer(c_int), value :: ntail
    end function c_analyze
    integer(c_int) function c_analyze_perm(h, n, colptr, rowind, val, perm, inset, ntail) bind(C, name='cr_chol_analyze')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      integer(c_int), value :: n
      integer(c_int), intent(in) :: colptr(*), rowind(*)
      real(c_double), intent(in) :: val(*)
      integer(c_int), intent(in) :: perm(*)
      integer(c_int), intent(in) :: inset(*)
      integer(c_int), value :: ntail
    end function c_analyze_perm
    integer(c_int) function c_add_slot(h, s, nz, rows, val, row) bind(C, name='cr_chol_add_slot')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      integer(c_int), value :: s, nz
      integer(c_int), intent(in) :: rows(*)
      real(c_double), intent(in) :: val(*)
      integer(c_int), value :: row
    end function c_add_slot
    integer(c_int) function c_tail_free(h) bind(C, name='cr_chol_tail_free')
      import :: c_ptr, c_int
      type(c_ptr), value :: h
    end function c_tail_free
    integer(c_int) function c_factor(h, active, pack_min) bind(C, name='cr_chol_factor')
      import :: c_ptr, c_int
      type(c_ptr), value :: h
      integer(c_int), intent(in) :: active(*)
      integer(c_int), value :: pack_min
    end function c_factor
    integer(c_int) function c_pivots(h, d) bind(C, name='cr_chol_pivots')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      real(c_double), intent(out) :: d(*)
    end function c_pivots
    integer(c_int) function c_rowadd(h, t, nz, idx, val, pivot) bind(C, name='cr_chol_rowadd')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      integer(c_int), value :: t, nz
      integer(c_int), intent(in) :: idx(*)
      real(c_double), intent(in) :: val(*)
      real(c_double), intent(out) :: pivot
    end function c_rowadd
    integer(c_int) function c_rowdel(h, nt, t) bind(C, name='cr_chol_rowdel')
      import :: c_ptr, c_int
      type(c_ptr), value :: h
      integer(c_int), value :: nt
      integer(c_int), intent(in) :: t(*)
    end function c_rowdel
    integer(c_int) function c_unit_solve(h, s, x, xss) bind(C, name='cr_chol_unit_solve')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      integer(c_int), value :: s
      real(c_double), intent(out) :: x(*), xss
    end function c_unit_solve
    integer(c_int) function c_solve(h, b, x) bind(C, name='cr_chol_solve')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      real(c_double), intent(in) :: b(*)
      real(c_double), intent(out) :: x(*)
    end function c_solve
    integer(c_int) function c_schur(h, t, nz, idx, val, reach_min, s, x) bind(C, name='cr_chol_schur')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      integer(c_int), value :: t, nz
      integer(c_int), intent(in) :: idx(*)
      real(c_double), intent(in) :: val(*)
      integer(c_int), value :: reach_min
      real(c_double), intent(out) :: s
      type(c_ptr), value :: x
    end function c_schur
    real(c_double) function c_symbolic_nnz(h) bind(C, name='cr_chol_symbolic_nnz')
      import :: c_ptr, c_double
      type(c_ptr), value :: h
    end function c_symbolic_nnz
    integer(c_int) function c_perm(h, perm) bind(C, name='cr_chol_perm')
      import :: c_ptr, c_int
      type(c_ptr), value :: h
      integer(c_int), intent(out) :: perm(*)
    end function c_perm
    real(c_double) function c_min_pivot(h) bind(C, name='cr_chol_min_pivot')
      import :: c_ptr, c_double
      type(c_ptr), value :: h
    end function c_min_pivot
    integer(c_long) function c_n_schur_scan(h) bind(C, name='cr_chol_n_schur_scan')
      import :: c_ptr, c_long
      type(c_ptr), value :: h
    end function c_n_schur_scan
    integer(c_long) function c_n_bounded(h) bind(C, name='cr_chol_n_bounded')
      import :: c_ptr, c_long
      type(c_ptr), value :: h
    end function c_n_bounded
    integer(c_int) function c_set_rows(h, nrow, map) bind(C, name='cr_chol_set_rows')
      import :: c_ptr, c_int
      type(c_ptr), value :: h
      integer(c_int), value :: nrow
      integer(c_int), intent(in) :: map(*)
    end function c_set_rows
    integer(c_int) function c_set_analysed_values(h, nz, val) bind(C, name='cr_chol_set_analysed_values')
      import :: c_ptr, c_int, c_double
      type(c_ptr), value :: h
      integer(c_int), value :: nz
      real(c_double), intent(in) :: val(*)
    end function c_set_analysed_values
    integer(c_long) function c_factor_nnz(h) bind(C, name='cr_chol_factor_nnz')
      import :: c_ptr, c_long
      type(c_ptr), value :: h
    end function c_factor_nnz
    integer(c_long) function c_row_entries(h, t) bind(C, name='cr_chol_row_entries')
      import :: c_ptr, c_long, c_int
      type(c_ptr), value :: h
      integer(c_int), value :: t
    end function c_row_entries
  end interface

contains

  !> Start CHOLMOD (idempotent).
  subroutine chol_init(this, error)
    class(chol_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    if (c_associated(this%h)) return
    if (c_new(this%h) /= 0) call set_error(error, "cholmod: cholmod_start failed (out of memory?)")
  end subroutine chol_init

  subroutine chol_free(this)
    class(chol_t), intent(inout) :: this
    if (c_associated(this%h)) call c_free(this%h)
    this%h = c_null_ptr
    this%n = 0
  end subroutine chol_free

  !> Error with the shim's message.
  subroutine shim_error(this, what, code, error)
    type(chol_t), intent(in) :: this
    character(len=*), intent(in) :: what
    integer(c_int), intent(in) :: code
    type(error_t), allocatable, intent(out) :: error
    character(kind=c_char) :: buf(256)
    character(len=256) :: msg
    integer :: i
    call c_message(this%h, buf, 256_c_int)
    do i = 1, 256
      msg(i:i) = buf(i)
    end do
    call set_error(error, "cholmod " // what // ": " // trim(msg) // " (code " // str(int(code)) // ")")
  end subroutine shim_error

  !> Set M (upper triangle, compressed columns, 1-based, rows sorted within each column) and
  !> analyse it; perm [n] (1-based) is the ordering to use, AMD when absent. inset [n]: the
  !> rows that may become active (all when absent); M must hold every entry between two of
  !> them; factor and rowadd refuse the other rows (an error, never a wrong factor).
  !> ntail (default 0): the last ntail slots are tail slots (empty columns, ordered last; with
  !> perm absent, AMD orders the others), handed out later by add_slot.
  subroutine chol_analyze(this, n, colptr, rowind, val, error, perm, inset, ntail)
    class(chol_t), intent(inout) :: this
    integer, intent(in) :: n
    !> column starts [n + 1], row indices and values [colptr(n+1) - 1]
    integer, intent(in) :: colptr(:), rowind(:)
    real(wp), intent(in) :: val(:)
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: perm(:)
    logical, intent(in), optional :: inset(:)
    integer, intent(in), optional :: ntail
    integer(c_int) :: rc, nt
    integer(c_int), allocatable :: ins(:)
    integer :: nz, i
    nt = 0_c_int
    if (present(ntail)) nt = int(ntail, c_int)
    call this%init(error)
    if (allocated(error)) return
    nz = colptr(n + 1) - 1
    allocate(ins(max(n, 1)))
    ins = 1_c_int
    if (present(inset)) ins(1:n) = merge(1_c_int, 0_c_int, inset(1:n))
    if (present(perm)) then
      rc = c_analyze_perm(this%h, int(n, c_int), int(colptr(1:n + 1) - 1, c_int), &
        int(rowind(1:max(nz, 1)) - 1, c_int), val, int(perm(1:max(n, 1)) - 1, c_int), ins, nt)
    else
      rc = c_analyze(this%h, int(n, c_int), int(colptr(1:n + 1) - 1, c_int), &
        int(rowind(1:max(nz, 1)) - 1, c_int), val, c_null_ptr, ins, nt)
    end if
    if (rc /= 0) then
      ! the shim keeps no analysis after a failure: neither does this side
      this%n = 0; this%nrow = 0
      call shim_error(this, "analyze", rc, error); return
    end if
    this%n = n
    this%nrow = n
    if (allocated(this%map)) then
      if (size(this%map) < n) deallocate(this%map)
    end if
    if (.not. allocated(this%map)) allocate(this%map(max(n, 16)))
    this%map(1:n) = [(i, i = 1, n)]
    if (allocated(this%xs)) then
      if (size(this%xs) < n) deallocate(this%xs, this%as)
    end if
    if (.not. allocated(this%xs)) allocate(this%xs(max(n, 16)), this%as(max(n, 16)))
  end subroutine chol_analyze

  !> The caller's rows from now on: map [nrow], map(i) the slot of row i in the analysed
  !> matrix or 0 (no slot: never active). Slots must be distinct; the factor must be rebuilt
  !> (factor) before it is used again.
  subroutine chol_set_rows(this, map, error)
    class(chol_t), intent(inout) :: this
    integer, intent(in) :: map(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: nr, i
    integer(c_int) :: rc
    nr = size(map)
    if (.not. c_associated(this%h) .or. this%n == 0) then
      call set_error(error, "cholmod set_rows: no analysis"); return
    end if
    if (any(map < 0 .or. map > this%n)) then
      call set_error(error, "cholmod set_rows: a slot outside 0.." // str(this%n)); return
    end if
    this%as(1:this%n) = 0_c_int
    do i = 1, nr
      if (map(i) == 0) cycle
      if (this%as(map(i)) /= 0) then
        call set_error(error, "cholmod set_rows: rows " // str(int(this%as(map(i)))) // " and " // str(i) // &
          " share slot " // str(map(i))); return
      end if
      this%as(map(i)) = int(i, c_int)
    end do
    if (allocated(this%map)) then
      if (size(this%map) < nr) deallocate(this%map)
    end if
    if (.not. allocated(this%map)) allocate(this%map(max(nr, 16)))
    this%map(1:nr) = map
    this%nrow = nr
    rc = c_set_rows(this%h, int(nr, c_int), int(map - 1, c_int))
    if (rc /= 0) call shim_error(this, "set_rows", rc, error)
  end subroutine chol_set_rows

  !> New values of M on the stored analysis, given on the analysed pattern itself: val [nnz]
  !> in the order of the entries handed to analyze (zero for an entry absent now). The
  !> current factor no longer counts (no solve or update on it); the next factor call
  !> refactorises it in place.
  subroutine chol_set_analysed_values(this, val, error)
    class(chol_t), intent(inout) :: this
    real(wp), intent(in) :: val(:)
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc
    if (.not. c_associated(this%h) .or. this%n == 0) then
      call set_error(error, "cholmod set_analysed_values: no analysis to reuse"); return
    end if
    rc = c_set_analysed_values(this%h, int(size(val), c_int), val)
    if (rc /= 0) call shim_error(this, "set_analysed_values", rc, error)
  end subroutine chol_set_analysed_values

  !> Give tail slot s (the next free one) to row `row` (1-based; a row without a slot): rows
  !> (slots, increasing, all below s, then s) and val are its column of the upper triangle of
  !> M. The analysis grows by that column (no new ordering, no factorisation); the row is an
  !> identity row of the factor until rowadd.
  subroutine chol_add_slot(this, s, rows, val, row, error)
    class(chol_t), intent(inout) :: this
    integer, intent(in) :: s, row
    integer, intent(in) :: rows(:)
    real(wp), intent(in) :: val(:)
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc
    if (.not. c_associated(this%h) .or. this%n == 0) then
      call set_error(error, "cholmod add_slot: no analysis"); return
    end if
    if (row < 1 .or. row > this%nrow .or. size(rows) /= size(val)) then
      call set_error(error, "cholmod add_slot: row " // str(row) // " outside 1.." // str(this%nrow) // &
        " or sizes differ"); return
    end if
    if (this%map(row) /= 0) then
      call set_error(error, "cholmod add_slot: row " // str(row) // " already has slot " // str(this%map(row))); return
    end if
    rc = c_add_slot(this%h, int(s - 1, c_int), int(size(rows), c_int), int(rows - 1, c_int), val, &
      int(row - 1, c_int))
    if (rc /= 0) then
      call shim_error(this, "add_slot", rc, error); return
    end if
    this%map(row) = s
  end subroutine chol_add_slot

  !> Tail slots not yet handed out (0 without an analysis).
  integer function chol_tail_free(this) result(k)
    class(chol_t), intent(in) :: this
    k = 0
    if (c_associated(this%h)) k = int(c_tail_free(this%h))
  end function chol_tail_free

  !> Numeric factorisation of M on the rows with active(i) [nrow], identity elsewhere.
  subroutine chol_factor(this, active, error)
    class(chol_t), intent(inout) :: this
    logical, intent(in) :: active(:)
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc
    integer :: i, k
    this%as(1:this%n) = 0_c_int
    do i = 1, this%nrow
      if (.not. active(i)) cycle
      k = this%map(i)
      if (k == 0) then
        call set_error(error, "cholmod factor: row " // str(i) // " is active but outside the analysed set")
        return
      end if
      this%as(k) = 1_c_int
    end do
    rc = c_factor(this%h, this%as, int(this%pack_min, c_int))
    if (rc /= 0) then
      call shim_error(this, "factor", rc, error); return
    end if
    this%n_factor = this%n_factor + 1
    this%n_since = 0
  end subroutine chol_factor

  !> Pivots D(i,i) of the current factor (1 on inactive rows) [nrow].
  subroutine chol_pivots(this, d, error)
    class(chol_t), intent(inout) :: this
    real(wp), intent(out) :: d(:)
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc
    integer :: i
    rc = c_pivots(this%h, this%xs)
    if (rc /= 0) then
      call shim_error(this, "pivots", rc, error); return
    end if
    do i = 1, this%nrow
      d(i) = 1.0_wp
      if (this%map(i) > 0) d(i) = this%xs(this%map(i))
    end do
  end subroutine chol_pivots

  !> Make row t active: idx, val [nz] are its entries in M (entries on inactive rows other
  !> than t are ignored). pivot: the new D(t,t).
  subroutine chol_rowadd(this, t, idx, val, pivot, error)
    class(chol_t), intent(inout) :: this
    integer, intent(in) :: t
    integer, intent(in) :: idx(:)
    real(wp), intent(in) :: val(:)
    real(wp), intent(out) :: pivot
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc
    integer(c_int) :: ic(size(idx))
    real(wp) :: vc(size(idx))
    integer :: nz
    if (this%map(t) == 0) then
      call set_error(error, "cholmod rowadd: row " // str(t) // " is outside the analysed set"); return
    end if
    call to_slots(this, idx, val, ic, vc, nz)
    rc = c_rowadd(this%h, int(this%map(t) - 1, c_int), int(nz, c_int), ic, vc, pivot)
    if (rc /= 0) then
      call shim_error(this, "rowadd", rc, error); return
    end if
    this%n_modify = this%n_modify + 1
    this%n_since = this%n_since + 1
  end subroutine chol_rowadd

  !> Make rows t(:) inactive (identity rows), in one update of the factor.
  subroutine chol_rowdel(this, t, error)
    class(chol_t), intent(inout) :: this
    integer, intent(in) :: t(:)
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc, ts(size(t))
    integer :: q
    do q = 1, size(t)
      if (this%map(t(q)) == 0) then
        call set_error(error, "cholmod rowdel: row " // str(t(q)) // " has no slot (never active)"); return
      end if
      ts(q) = int(this%map(t(q)) - 1, c_int)
    end do
    rc = c_rowdel(this%h, int(size(t), c_int), ts)
    if (rc /= 0) then
      call shim_error(this, "rowdel", rc, error); return
    end if
    this%n_modify = this%n_modify + size(t)
    this%n_since = this%n_since + size(t)
  end subroutine chol_rowdel

  !> The entries (idx, val) of a row of M in the caller's numbering as 0-based slots (ic, vc
  !> [nz]): rows without a slot are inactive, so their entries are dropped (as every inactive
  !> row's).
  subroutine to_slots(this, idx, val, ic, vc, nz)
    type(chol_t), intent(in) :: this
    integer, intent(in) :: idx(:)
    real(wp), intent(in) :: val(:)
    integer(c_int), intent(out) :: ic(:)
    real(wp), intent(out) :: vc(:)
    integer, intent(out) :: nz
    integer :: q
    nz = 0
    do q = 1, size(idx)
      if (this%map(idx(q)) == 0) cycle
      nz = nz + 1; ic(nz) = int(this%map(idx(q)) - 1, c_int); vc(nz) = val(q)
    end do
  end subroutine to_slots

  !> x = A^{-1} b with the current factor [nrow] (identity on rows without a slot).
  subroutine chol_solve(this, b, x, error)
    class(chol_t), intent(inout) :: this
    real(wp), intent(in) :: b(:)
    real(wp), intent(out) :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc
    rc = c_solve(this%h, b, x)
    if (rc /= 0) call shim_error(this, "solve", rc, error)
  end subroutine chol_solve

  !> x = A^{-1} e_t (the column of the inverse of the active matrix at the active row t; set on
  !> the active rows only) and xtt = x(t): a forward solve along one path of the elimination
  !> tree and a full backward solve.
  subroutine chol_unit_solve(this, t, x, xtt, error)
    class(chol_t), intent(inout) :: this
    integer, intent(in) :: t
    real(wp), intent(out) :: x(:), xtt
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc
    if (this%map(t) == 0) then
      call set_error(error, "cholmod unit_solve: row " // str(t) // " has no slot (never active)"); return
    end if
    rc = c_unit_solve(this%h, int(this%map(t) - 1, c_int), x, xtt)
    if (rc /= 0) call shim_error(this, "unit_solve", rc, error)
  end subroutine chol_unit_solve

  !> s = w^T A_P^{-1} w for w = M(P, t) given by its entries idx, val [nz] (entries off the
  !> active rows and t itself are ignored): row t's pivot would be M(t,t) - s.
  subroutine chol_schur(this, t, idx, val, s, error, x)
    class(chol_t), intent(inout) :: this
    integer, intent(in) :: t
    integer, intent(in) :: idx(:)
    real(wp), intent(in) :: val(:)
    real(wp), intent(out) :: s
    type(error_t), allocatable, intent(out) :: error
    !> present: also x = A^{-1} w (the backward half of the solve after the test's forward
    !> half), set on the active rows only
    real(wp), intent(out), optional, target, contiguous :: x(:)
    integer(c_int) :: rc
    integer(c_int) :: ic(size(idx))
    real(wp) :: vc(size(idx))
    integer :: nz
    type(c_ptr) :: xp
    if (this%map(t) == 0) then
      call set_error(error, "cholmod schur: row " // str(t) // " is outside the analysed set"); return
    end if
    call to_slots(this, idx, val, ic, vc, nz)
    xp = c_null_ptr
    if (present(x)) then
      if (size(x) > 0) xp = c_loc(x(1))
    end if
    rc = c_schur(this%h, int(this%map(t) - 1, c_int), int(nz, c_int), ic, vc, &
      int(this%reach_min, c_int), s, xp)
    if (rc /= 0) call shim_error(this, "schur", rc, error)
  end subroutine chol_schur

  !> Predicted entries of the factor of the whole M (analysis).
  real(wp) function chol_symbolic_nnz(this) result(s)
    class(chol_t), intent(in) :: this
    s = real(c_symbolic_nnz(this%h), wp)
  end function chol_symbolic_nnz

  !> The ordering in use, 1-based: perm(k) is the row at position k [n].
  subroutine chol_perm(this, perm, error)
    class(chol_t), intent(inout) :: this
    integer, intent(out) :: perm(:)
    type(error_t), allocatable, intent(out) :: error
    integer(c_int) :: rc
    integer(c_int), allocatable :: p(:)
    allocate(p(max(this%n, 1)))
    rc = c_perm(this%h, p)
    if (rc /= 0) then
      call shim_error(this, "perm", rc, error); return
    end if
    perm(1:this%n) = int(p(1:this%n)) + 1
  end subroutine chol_perm

  !> Smallest pivot D(i,i) over the active rows (NaN-safe: a NaN pivot is returned as is).
  real(wp) function chol_min_pivot(this) result(d)
    class(chol_t), intent(in) :: this
    d = real(c_min_pivot(this%h), wp)
  end function chol_min_pivot

  !> Schur pivot tests through the elimination-tree reach (n >= reach_min) whose reach missed
  !> a fill of the factor (never expected; then done by the scan) since init.
  integer function chol_n_schur_scan(this) result(k)
    class(chol_t), intent(in) :: this
    k = 0
    if (c_associated(this%h)) k = int(c_n_schur_scan(this%h))
  end function chol_n_schur_scan

  !> Factorisations redone with the pivots bounded (an exact zero pivot, a row dependent on the
  !> earlier ones: CHOLMOD would have set every later pivot to zero) since init.
  integer function chol_n_bounded(this) result(k)
    class(chol_t), intent(in) :: this
    k = 0
    if (c_associated(this%h)) k = int(c_n_bounded(this%h))
  end function chol_n_bounded

  !> Stored entries of the current factor.
  integer function chol_factor_nnz(this) result(nnz)
    class(chol_t), intent(in) :: this
    nnz = int(c_factor_nnz(this%h))
  end function chol_factor_nnz

  !> Stored off-diagonal entries of the current factor in the row of caller row t (0 for a
  !> row without a slot or without a factor): a deleted row has none (tests).
  integer function chol_row_entries(this, t) result(k)
    class(chol_t), intent(in) :: this
    integer, intent(in) :: t
    k = 0
    if (.not. c_associated(this%h)) return
    if (t < 1 .or. t > size(this%map)) return
    if (this%map(t) == 0) return
    k = int(c_row_entries(this%h, int(this%map(t) - 1, c_int)))
  end function chol_row_entries
end module cr_cholmod
