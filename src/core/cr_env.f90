!> Parallel environment: wraps a duplicate of the communicator it is given.
!>
!> Library code never names MPI_COMM_WORLD; drivers create an env_t on it and tests may
!> create one on any sub-communicator. Collective helpers check every MPI status.
!>
!> MPI errors are returned, not fatal: the duplicate communicator and every window created
!> here have the error handler MPI_ERRORS_RETURN, so a failing call gives its status to
!> check_mpi, which returns an error_t with code EXIT_MPI naming the call. A rank holding
!> such an error does not take part in the error agreement (see agree_error_on); its driver
!> ends the job by MPI_Abort (cr_program). Communicators derived from env%comm inherit the
!> handler (HDF5's MPI-IO driver sets MPI_ERRORS_RETURN on its own duplicate anyway, and checks
!> the statuses); BLACS, which does not check them, gets an env of its own with
!> MPI_ERRORS_ARE_FATAL (init's errors_fatal, cr_distribution).
module cr_env
  use, intrinsic :: iso_c_binding, only: c_ptr, c_f_pointer
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_exit_codes, only: EXIT_MPI
  use cr_strings, only: str
  implicit none
  private
  public :: env_t, agree_error_on, mpi_failed
  public :: shared_counter_t, pending_bcast_t

  !> An MPI call of this rank has failed (set by check_mpi; see mpi_failed).
  logical, save :: failed_here = .false.

  !> MPI environment: private duplicate communicator, rank, size.
  type :: env_t
    type(MPI_Comm) :: comm = MPI_COMM_NULL
    integer :: rank = 0
    integer :: size = 1
  contains
    procedure :: init
    procedure :: free
    procedure :: is_root
    procedure :: agree_error
    procedure, nopass :: wtime
    ! ---- checked collectives and messages for the library modules (linalg, offline, hyper,
    ! io): every MPI status is checked and a failure returned as an error naming the call,
    ! the sizes and MPI's own message. Arrays of any rank (contiguous; a section is copied).
    !> broadcast from rank `root` (default 0); a deferred-length string takes the root's length
    procedure :: bcast_int, bcast_i8, bcast_real, bcast_text
    generic :: bcast => bcast_int, bcast_i8, bcast_real, bcast_text
    !> in-place reduction over all ranks, op 'sum', 'min' or 'max'
    procedure :: allreduce_int, allreduce_i8, allreduce_real
    generic :: allreduce => allreduce_int, allreduce_i8, allreduce_real
    !> in-place sum on rank 0 only
    procedure :: reduce_sum_root
    !> distributed values: the lowest global index within a relative sqrt(eps) of the maximum
    procedure :: allreduce_near_maxloc
    !> one value from every rank, in rank order
    procedure :: allgather_int, allgather_real
    generic :: allgather => allgather_int, allgather_real
    !> counts and displacements of a variable-size gather: every rank's n, in rank order
    procedure :: block_counts
    !> variable-size gathers and exchanges (counts, displacements in elements)
    procedure :: allgatherv_int, allgatherv_i8, allgatherv_real
    generic :: allgatherv => allgatherv_int, allgatherv_i8, allgatherv_real
    procedure :: gatherv_real, alltoallv_real
    generic :: gatherv => gatherv_real
    generic :: alltoallv => alltoallv_real
    !> every rank's text concatenated in rank order
    procedure :: gather_text
    !> one integer to and from every rank
    procedure :: alltoall_int
    generic :: alltoall => alltoall_int
    !> point-to-point messages
    procedure :: send_int, send_real, recv_int, recv_real
    generic :: send => send_int, send_real
    generic :: recv => recv_int, recv_real
    !> barrier with its status checked
    procedure :: sync
    !> mean time of a small allreduce (s); the MPI library's version line
    procedure :: collective_latency, library_version
    ! ---- end of the checked collectives
  end type env_t

  !> A set of 64-bit counters held by rank 0 in an MPI one-sided window; any rank adds to one
  !> atomically (passive target: rank 0 need not take part).
  type :: shared_counter_t
    type(MPI_Win) :: win = MPI_WIN_NULL
    integer(i8), pointer :: slots(:) => null()
    !> number of counters (known on every rank: fetch_add refuses a slot outside 1..n_slots,
    !> which MPI would not: an out-of-range displacement is not an error there)
    integer :: n_slots = 0
    !> this rank's operations and the wall time spent in them (s)
    integer :: n_calls = 0
    real(wp) :: t_calls = 0
    !> this rank's access epoch (MPI_Win_lock_all) is open: opened by the first fetch_add, closed by free
    logical :: epoch = .false.
  contains
    procedure :: init => counter_init
    procedure :: fetch_add => counter_fetch_add
    procedure :: free => counter_free
  end type shared_counter_t

  !> A broadcast of 64-bit integers from rank 0 in progress (MPI_Ibcast): every rank sets `x`
  !> (the same size; rank 0 its data), calls start, and may go on working; `x` holds rank 0's
  !> data once test has said done or wait has returned. Must not be copied while in progress.
  type :: pending_bcast_t
    integer(i8), allocatable :: x(:)
    type(MPI_Request), private :: req = MPI_REQUEST_NULL
    !> started and not yet completed on this rank
    logical :: active = .false.
  contains
    procedure :: start => pending_start
    procedure :: test => pending_test
    procedure :: wait => pending_wait
  end type pending_bcast_t


contains

  !> Duplicate `comm`, make MPI errors on the duplicate returned (MPI_ERRORS_RETURN) and
  !> record rank/size. (A failure of MPI_Comm_dup itself is handled by `comm`'s own handler.)
  !> With errors_fatal = .true. (default .false.) the duplicate gets MPI_ERRORS_ARE_FATAL
  !> instead: for a communicator handed to a library that does not check MPI statuses (BLACS,
  !> see cr_distribution), where a returned error would pass unseen.
  subroutine init(this, comm, error, errors_fatal)
    class(env_t), intent(inout) :: this
    type(MPI_Comm), intent(in) :: comm
    type(error_t), allocatable, intent(out) :: error
    logical, intent(in), optional :: errors_fatal
    integer :: ierr
    logical :: fatal
    fatal = .false.
    if (present(errors_fatal)) fatal = errors_fatal
    call MPI_Comm_dup(comm, this%comm, ierr)
    call check_mpi(ierr, "MPI_Comm_dup", error)
    if (allocated(error)) return
    if (fatal) then
      call MPI_Comm_set_errhandler(this%comm, MPI_ERRORS_ARE_FATAL, ierr)
      call check_mpi(ierr, "MPI_Comm_set_errhandler (MPI_ERRORS_ARE_FATAL)", error)
    else
      call MPI_Comm_set_errhandler(this%comm, MPI_ERRORS_RETURN, ierr)
      call check_mpi(ierr, "MPI_Comm_set_errhandler (MPI_ERRORS_RETURN)", error)
    end if
    if (allocated(error)) return
    call MPI_Comm_rank(this%comm, this%rank, ierr)
    call check_mpi(ierr, "MPI_Comm_rank", error)
    if (allocated(error)) return
    call MPI_Comm_size(this%comm, this%size, ierr)
    call check_mpi(ierr, "MPI_Comm_size", error)
  end subroutine init

  !> Release the duplicated communicator. Like every `free` of the code, it cannot fail for the
  !> caller: a failing MPI_Comm_free (the handle is not used again) leaves nothing to recover.
  subroutine free(this)
    class(env_t), intent(inout) :: this
    integer :: ierr
    ! (no MPI call after a failed one on this rank: see mpi_failed)
    if (this%comm /= MPI_COMM_NULL .and. .not. failed_here) call MPI_Comm_free(this%comm, ierr)
    this%comm = MPI_COMM_NULL
  end subroutine free

  !> True on rank 0.
  pure logical function is_root(this)
    class(env_t), intent(in) :: this
    is_root = this%rank == 0
  end function is_root

  !> Collective error agreement: if any rank of the environment holds an error, every rank
  !> returns the error of the lowest failing rank (message and code broadcast from it). When
  !> only some ranks failed, the message starts with "rank R of P: " so that the one line that
  !> rank 0 prints says where it happened. Collective: every rank must call it.
  !>
  !> Except after a failed MPI call: a rank on which any MPI call has failed (mpi_failed; its
  !> error has code EXIT_MPI, or another one if a caller replaced it) returns its error at
  !> once, unchanged, without any MPI call. Its call may have failed inside a collective that other
  !> ranks are still waiting in, and a further collective could then be matched wrongly or never
  !> complete. That rank goes straight to its driver's end (program_finish), whose MPI_Abort
  !> also ends the ranks waiting in this agreement or elsewhere. If a call of the agreement
  !> itself fails, the rank's error becomes such an MPI failure too (code EXIT_MPI).
  subroutine agree_error(this, error)
    class(env_t), intent(in) :: this
    type(error_t), allocatable, intent(inout) :: error
    call agree_error_on(this%comm, error)
  end subroutine agree_error

  !> agree_error on a plain communicator (for handles that keep their own, e.g. HDF5 files).
  subroutine agree_error_on(comm, error)
    type(MPI_Comm), intent(in) :: comm
    type(error_t), allocatable, intent(inout) :: error
    integer :: who, n_failed, rank, nranks, ierr, meta(2)
    character(len=:), allocatable :: msg
    ! a failed MPI call here cannot be agreed on: the rank keeps its own message, or this one,
    ! with the code of an MPI failure
    type(error_t), allocatable :: mpi_error
    if (comm == MPI_COMM_NULL) return
    ! no collective after a failed MPI call (see agree_error and mpi_failed)
    if (failed_here) return
    call MPI_Comm_size(comm, nranks, ierr)
    call check_mpi(ierr, "MPI_Comm_size (error agreement)", mpi_error)
    if (failed()) return
    if (nranks == 1) return
    call MPI_Comm_rank(comm, rank, ierr)
    call check_mpi(ierr, "MPI_Comm_rank (error agreement)", mpi_error)
    if (failed()) return
    who = huge(1)
    if (allocated(error)) who = rank
    call MPI_Allreduce(MPI_IN_PLACE, who, 1, MPI_INTEGER, MPI_MIN, comm, ierr)
    call check_mpi(ierr, "MPI_Allreduce (error agreement: failing rank)", mpi_error)
    if (failed()) return
    if (who == huge(1)) return
    n_failed = merge(1, 0, allocated(error))
    call MPI_Allreduce(MPI_IN_PLACE, n_failed, 1, MPI_INTEGER, MPI_SUM, comm, ierr)
    call check_mpi(ierr, "MPI_Allreduce (error agreement: number of failing ranks)", mpi_error)
    if (failed()) return
    meta = 0
    if (rank == who) then
      msg = error%message
      meta = [len(msg), error%code]
    end if
    call MPI_Bcast(meta, 2, MPI_INTEGER, who, comm, ierr)
    call check_mpi(ierr, "MPI_Bcast (error agreement: message length)", mpi_error)
    if (failed()) return
    if (rank /= who) allocate(character(len=meta(1)) :: msg)
    if (meta(1) > 0) call MPI_Bcast(msg, meta(1), MPI_CHARACTER, who, comm, ierr)
    call check_mpi(ierr, "MPI_Bcast (error agreement: message)", mpi_error)
    if (failed()) return
    if (n_failed < nranks) msg = "rank " // str(who) // " of " // str(nranks) // ": " // msg
    if (allocated(error)) deallocate(error)
    call set_error(error, msg, meta(2))
  contains
    !> The agreement's own MPI call failed: this rank's error (its own message, then the failed
    !> call) becomes an MPI failure, which ends the job (see agree_error).
    logical function failed()
      failed = allocated(mpi_error)
      if (.not. failed) return
      if (allocated(error)) then
        error%message = error%message // "; then " // mpi_error%message
        error%code = EXIT_MPI
      else
        call move_alloc(mpi_error, error)
      end if
    end function failed
  end subroutine agree_error_on


  !> Wall-clock time in seconds.
  real(wp) function wtime()
    wtime = MPI_Wtime()
  end function wtime

  ! ==================================================================================
  ! Checked collectives and messages for the library modules (one block, see the type).
  ! ==================================================================================

  !> Number of elements of an assumed-rank dummy from its shape. gfortran 12 reports the extent
  !> -1 for a zero-size assumed-shape actual copied into a contiguous assumed-rank dummy, so the
  !> extents are clamped at 0 (size() would be wrong too).
  pure integer function n_of(shp)
    integer, intent(in) :: shp(:)
    n_of = product(max(shp, 0))
  end function n_of

  !> Turn a non-zero MPI status into an error "env: <what> failed: <MPI's message>" with code
  !> EXIT_MPI (statuses other than MPI_SUCCESS reach it because of MPI_ERRORS_RETURN, see init).
  subroutine check_mpi(ierr, what, error)
    integer, intent(in) :: ierr
    character(len=*), intent(in) :: what
    type(error_t), allocatable, intent(inout) :: error
    character(len=MPI_MAX_ERROR_STRING) :: msg
    integer :: n, ierr2
    if (ierr == MPI_SUCCESS) return
    failed_here = .true.
    if (allocated(error)) return
    msg = ''
    call MPI_Error_string(ierr, msg, n, ierr2)
    if (ierr2 /= MPI_SUCCESS) msg = 'MPI error code ' // str(ierr)
    call set_error(error, "env: " // what // " failed: " // trim(msg), EXIT_MPI)
  end subroutine check_mpi

  !> True once an MPI call of this rank has failed (any env_t, any communicator or window).
  !> From then on this rank makes no blocking MPI call on its way to the driver's end, where
  !> MPI_Abort ends the job (cr_program): the failed call may have been a collective that the
  !> other ranks still wait in, so a clean-up collective here (a barrier, freeing a window or
  !> a communicator, closing a parallel HDF5 file) could wait for ever. sync, free,
  !> counter_free and agree_error skip their MPI calls, and cr_h5file leaves parallel files
  !> open.
  logical function mpi_failed()
    mpi_failed = failed_here
  end function mpi_failed

  !> The MPI operation of 'sum', 'min' or 'max'.
  subroutine reduction_op(op, mop, error)
    character(len=*), intent(in) :: op
    type(MPI_Op), intent(out) :: mop
    type(error_t), allocatable, intent(out) :: error
    select case (op)
    case ('sum'); mop = MPI_SUM
    case ('min'); mop = MPI_MIN
    case ('max'); mop = MPI_MAX
    case default
      mop = MPI_OP_NULL
      call set_error(error, "env: unknown reduction '" // op // "' (known: sum, min, max)")
    end select
  end subroutine reduction_op

  subroutine bcast_int(this, x, error, root)
    class(env_t), intent(in) :: this
    integer, contiguous, intent(inout) :: x(..)
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: root
    integer :: ierr, r
    r = 0
    if (present(root)) r = root
    call MPI_Bcast(x, n_of(shape(x)), MPI_INTEGER, r, this%comm, ierr)
    call check_mpi(ierr, "MPI_Bcast of " // str(n_of(shape(x))) // " integer(s) from rank " // str(r), error)
  end subroutine bcast_int

  subroutine bcast_i8(this, x, error, root)
    class(env_t), intent(in) :: this
    integer(i8), contiguous, intent(inout) :: x(..)
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: root
    integer :: ierr, r
    r = 0
    if (present(root)) r = root
    call MPI_Bcast(x, n_of(shape(x)), MPI_INTEGER8, r, this%comm, ierr)
    call check_mpi(ierr, "MPI_Bcast of " // str(n_of(shape(x))) // " 64-bit integer(s) from rank " // str(r), error)
  end subroutine bcast_i8

  subroutine bcast_real(this, x, error, root)
    class(env_t), intent(in) :: this
    real(wp), contiguous, intent(inout) :: x(..)
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: root
    integer :: ierr, r
    r = 0
    if (present(root)) r = root
    call MPI_Bcast(x, n_of(shape(x)), MPI_DOUBLE_PRECISION, r, this%comm, ierr)
    call check_mpi(ierr, "MPI_Bcast of " // str(n_of(shape(x))) // " real(s) from rank " // str(r), error)
  end subroutine bcast_real

  subroutine bcast_text(this, s, error, root)
    class(env_t), intent(in) :: this
    character(len=:), allocatable, intent(inout) :: s
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: root
    integer :: ierr, r, n
    r = 0
    if (present(root)) r = root
    if (this%rank == r .and. .not. allocated(s)) s = ""
    n = 0
    if (this%rank == r) n = len(s)
    call MPI_Bcast(n, 1, MPI_INTEGER, r, this%comm, ierr)
    call check_mpi(ierr, "MPI_Bcast of a string's length from rank " // str(r), error)
    if (allocated(error)) return
    if (this%rank /= r) then
      if (allocated(s)) deallocate(s)
      allocate(character(len=n) :: s)
    end if
    if (n == 0) return
    call MPI_Bcast(s, n, MPI_CHARACTER, r, this%comm, ierr)
    call check_mpi(ierr, "MPI_Bcast of " // str(n) // " character(s) from rank " // str(r), error)
  end subroutine bcast_text

  subroutine allreduce_int(this, x, op, error)
    class(env_t), intent(in) :: this
    integer, contiguous, intent(inout) :: x(..)
    character(len=*), intent(in) :: op
    type(error_t), allocatable, intent(out) :: error
    type(MPI_Op) :: mop
    integer :: ierr
    call reduction_op(op, mop, error); if (allocated(error)) return
    call MPI_Allreduce(MPI_IN_PLACE, x, n_of(shape(x)), MPI_INTEGER, mop, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allreduce (" // op // ") of " // str(n_of(shape(x))) // " integer(s)", error)
  end subroutine allreduce_int

  subroutine allreduce_i8(this, x, op, error)
    class(env_t), intent(in) :: this
    integer(i8), contiguous, intent(inout) :: x(..)
    character(len=*), intent(in) :: op
    type(error_t), allocatable, intent(out) :: error
    type(MPI_Op) :: mop
    integer :: ierr
    call reduction_op(op, mop, error); if (allocated(error)) return
    call MPI_Allreduce(MPI_IN_PLACE, x, n_of(shape(x)), MPI_INTEGER8, mop, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allreduce (" // op // ") of " // str(n_of(shape(x))) // " 64-bit integer(s)", error)
  end subroutine allreduce_i8

  subroutine allreduce_real(this, x, op, error)
    class(env_t), intent(in) :: this
    real(wp), contiguous, intent(inout) :: x(..)
    character(len=*), intent(in) :: op
    type(error_t), allocatable, intent(out) :: error
    type(MPI_Op) :: mop
    integer :: ierr
    call reduction_op(op, mop, error); if (allocated(error)) return
    call MPI_Allreduce(MPI_IN_PLACE, x, n_of(shape(x)), MPI_DOUBLE_PRECISION, mop, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allreduce (" // op // ") of " // str(n_of(shape(x))) // " real(s)", error)
  end subroutine allreduce_real

  !> x summed over the ranks, on rank 0 (other ranks' x is left as it was or undefined).
  subroutine reduce_sum_root(this, x, error)
    class(env_t), intent(in) :: this
    real(wp), contiguous, intent(inout) :: x(..)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    if (this%rank == 0) then
      call MPI_Reduce(MPI_IN_PLACE, x, n_of(shape(x)), MPI_DOUBLE_PRECISION, MPI_SUM, 0, this%comm, ierr)
    else
      call MPI_Reduce(x, x, n_of(shape(x)), MPI_DOUBLE_PRECISION, MPI_SUM, 0, this%comm, ierr)
    end if
    call check_mpi(ierr, "MPI_Reduce (sum to rank 0) of " // str(n_of(shape(x))) // " real(s)", error)
  end subroutine reduce_sum_root

  !> The rule of cr_sort::near_max_index applied to all ranks' values as one array: x [n_local]
  !> are this rank's values, x(k) has the global index offset + k (the ranks hold disjoint
  !> index sets; a rank may hold none), mask [n_local] (optional) selects the entries taking
  !> part. On return, on every rank, gidx is the lowest global index whose value is within a
  !> relative sqrt(eps) of the largest selected value over all ranks, and val its value; gidx = 0
  !> and val = -huge when no rank selects an entry (or every selected value is NaN). The
  !> threshold is taken from the global maximum, not from each rank's own, so the choice is the
  !> same at any number of ranks and any split of the indices. Two reductions: the maximum,
  !> then MPI_MINLOC on (global index, value) over each rank's first candidate.
  subroutine allreduce_near_maxloc(this, x, offset, val, gidx, error, mask)
    class(env_t), intent(in) :: this
    real(wp), intent(in) :: x(:)
    integer(i8), intent(in) :: offset
    real(wp), intent(out) :: val
    integer(i8), intent(out) :: gidx
    type(error_t), allocatable, intent(out) :: error
    logical, intent(in), optional :: mask(:)
    !> global indices must stay below 2^53 to be carried exactly by a double
    real(wp), parameter :: exact_max = 2.0_wp**53
    real(wp) :: tol, thr, red(2), pair(2), res(2)
    integer :: k, ierr
    val = -huge(1.0_wp); gidx = 0
    tol = sqrt(epsilon(1.0_wp))
    ! red = [largest selected value, a bad argument on this rank]: reduced together, so a bad
    ! argument on one rank is an error on every rank (nobody is left in a collective)
    red = [-huge(1.0_wp), 0.0_wp]
    if (present(mask)) then
      if (size(mask) /= size(x)) red(2) = 1
    end if
    if (offset < 0 .or. real(offset, wp) + real(size(x), wp) >= exact_max) red(2) = 1
    if (red(2) == 0) then
      do k = 1, size(x)
        if (selected(k)) then
          if (x(k) > red(1)) red(1) = x(k)
        end if
      end do
    end if
    call MPI_Allreduce(MPI_IN_PLACE, red, 2, MPI_DOUBLE_PRECISION, MPI_MAX, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allreduce (max) of the near maxloc", error)
    if (allocated(error)) return
    if (red(2) /= 0) then
      call set_error(error, "near maxloc: a rank passed a mask whose size differs from its values' or global " // &
        "indices outside 1..2^53 (this rank: " // str(size(x)) // " values from offset " // str(offset) // ")")
      return
    end if
    ! threshold of cr_sort::near_max_index (-huge when big - tol |big| would overflow)
    thr = -huge(1.0_wp)
    if (red(1) >= -huge(1.0_wp) / (1 + tol)) thr = red(1) - tol * abs(red(1))
    ! this rank's first candidate: [global index, value]; none: [2^53, -huge]
    pair = [exact_max, -huge(1.0_wp)]
    do k = 1, size(x)
      if (.not. selected(k)) cycle
      if (x(k) >= thr) then
        pair = [real(offset + k, wp), x(k)]
        exit
      end if
    end do
    call MPI_Allreduce(pair, res, 1, MPI_2DOUBLE_PRECISION, MPI_MINLOC, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allreduce (minloc) of the near maxloc", error)
    if (allocated(error)) return
    if (res(1) < exact_max) then
      gidx = nint(res(1), i8); val = res(2)
    end if

  contains

    logical function selected(kk)
      integer, intent(in) :: kk
      selected = .true.
      if (present(mask)) selected = mask(kk)
    end function selected
  end subroutine allreduce_near_maxloc

  !> all(p) = x of rank p - 1 [this%size], on every rank.
  subroutine allgather_real(this, x, all, error)
    class(env_t), intent(in) :: this
    real(wp), intent(in) :: x
    real(wp), allocatable, intent(out) :: all(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    allocate(all(this%size))
    call MPI_Allgather(x, 1, MPI_DOUBLE_PRECISION, all, 1, MPI_DOUBLE_PRECISION, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allgather of one real per rank", error)
  end subroutine allgather_real

  !> all(p) = x of rank p - 1 [this%size], on every rank.
  subroutine allgather_int(this, x, all, error)
    class(env_t), intent(in) :: this
    integer, intent(in) :: x
    integer, allocatable, intent(out) :: all(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    allocate(all(this%size))
    call MPI_Allgather(x, 1, MPI_INTEGER, all, 1, MPI_INTEGER, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allgather of one integer per rank", error)
  end subroutine allgather_int

  !> Gather x of every rank into all on rank `root`: rank p's block at all(displs(p)+1:)
  !> (counts, displs [this%size], significant on root only).
  subroutine gatherv_real(this, x, all, counts, displs, root, error)
    class(env_t), intent(in) :: this
    real(wp), contiguous, intent(in) :: x(..)
    real(wp), contiguous, intent(inout) :: all(..)
    integer, intent(in) :: counts(:), displs(:)
    integer, intent(in) :: root
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Gatherv(x, n_of(shape(x)), MPI_DOUBLE_PRECISION, all, counts, displs, MPI_DOUBLE_PRECISION, root, &
      this%comm, ierr)
    call check_mpi(ierr, "MPI_Gatherv of " // str(n_of(shape(x))) // " real(s) to rank " // str(root), error)
  end subroutine gatherv_real

  !> counts(p) = n of rank p - 1 and displs(p) = sum(counts(1:p-1)) [this%size] on every rank:
  !> the layout of a gather of blocks of n elements (error if the total exceeds 32-bit counts).
  subroutine block_counts(this, n, counts, displs, error)
    class(env_t), intent(in) :: this
    integer, intent(in) :: n
    integer, allocatable, intent(out) :: counts(:), displs(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: p
    call this%allgather(n, counts, error)
    if (allocated(error)) return
    allocate(displs(this%size))
    displs(1) = 0
    do p = 2, this%size
      displs(p) = displs(p - 1) + counts(p - 1)
    end do
    if (sum(int(counts, i8)) > huge(1)) call set_error(error, "env: a gather of " // &
      str(sum(int(counts, i8))) // " elements exceeds the 32-bit MPI counts")
  end subroutine block_counts

  !> Gather x of every rank into all on every rank: rank p's block at all(displs(p)+1:)
  !> (counts, displs [this%size], e.g. from block_counts).
  subroutine allgatherv_int(this, x, all, counts, displs, error)
    class(env_t), intent(in) :: this
    integer, contiguous, intent(in) :: x(..)
    integer, contiguous, intent(inout) :: all(..)
    integer, intent(in) :: counts(:), displs(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Allgatherv(x, n_of(shape(x)), MPI_INTEGER, all, counts, displs, MPI_INTEGER, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allgatherv of " // str(sum(int(counts, i8))) // " integer(s)", error)
  end subroutine allgatherv_int

  subroutine allgatherv_i8(this, x, all, counts, displs, error)
    class(env_t), intent(in) :: this
    integer(i8), contiguous, intent(in) :: x(..)
    integer(i8), contiguous, intent(inout) :: all(..)
    integer, intent(in) :: counts(:), displs(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Allgatherv(x, n_of(shape(x)), MPI_INTEGER8, all, counts, displs, MPI_INTEGER8, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allgatherv of " // str(sum(int(counts, i8))) // " 64-bit integer(s)", error)
  end subroutine allgatherv_i8

  subroutine allgatherv_real(this, x, all, counts, displs, error)
    class(env_t), intent(in) :: this
    real(wp), contiguous, intent(in) :: x(..)
    real(wp), contiguous, intent(inout) :: all(..)
    integer, intent(in) :: counts(:), displs(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Allgatherv(x, n_of(shape(x)), MPI_DOUBLE_PRECISION, all, counts, displs, MPI_DOUBLE_PRECISION, &
      this%comm, ierr)
    call check_mpi(ierr, "MPI_Allgatherv of " // str(sum(int(counts, i8))) // " real(s)", error)
  end subroutine allgatherv_real

  !> Exchange blocks of reals between all ranks (counts, displacements [this%size]).
  subroutine alltoallv_real(this, sendbuf, scount, sdispl, recvbuf, rcount, rdispl, error)
    class(env_t), intent(in) :: this
    real(wp), contiguous, intent(in) :: sendbuf(..)
    integer, intent(in) :: scount(:), sdispl(:)
    real(wp), contiguous, intent(inout) :: recvbuf(..)
    integer, intent(in) :: rcount(:), rdispl(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Alltoallv(sendbuf, scount, sdispl, MPI_DOUBLE_PRECISION, recvbuf, rcount, rdispl, &
      MPI_DOUBLE_PRECISION, this%comm, ierr)
    call check_mpi(ierr, "MPI_Alltoallv of " // str(sum(scount)) // " real(s)", error)
  end subroutine alltoallv_real

  !> recv(p) = send(this%rank + 1) of rank p - 1 [this%size].
  subroutine alltoall_int(this, send, recv, error)
    class(env_t), intent(in) :: this
    integer, intent(in) :: send(:)
    integer, intent(out) :: recv(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Alltoall(send, 1, MPI_INTEGER, recv, 1, MPI_INTEGER, this%comm, ierr)
    call check_mpi(ierr, "MPI_Alltoall of one integer per rank", error)
  end subroutine alltoall_int

  subroutine send_int(this, x, dest, tag, error)
    class(env_t), intent(in) :: this
    integer, contiguous, intent(in) :: x(..)
    integer, intent(in) :: dest, tag
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Send(x, n_of(shape(x)), MPI_INTEGER, dest, tag, this%comm, ierr)
    call check_mpi(ierr, "MPI_Send of " // str(n_of(shape(x))) // " integer(s) to rank " // str(dest), error)
  end subroutine send_int

  subroutine send_real(this, x, dest, tag, error)
    class(env_t), intent(in) :: this
    real(wp), contiguous, intent(in) :: x(..)
    integer, intent(in) :: dest, tag
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Send(x, n_of(shape(x)), MPI_DOUBLE_PRECISION, dest, tag, this%comm, ierr)
    call check_mpi(ierr, "MPI_Send of " // str(n_of(shape(x))) // " real(s) to rank " // str(dest), error)
  end subroutine send_real

  subroutine recv_int(this, x, source, tag, error)
    class(env_t), intent(in) :: this
    integer, contiguous, intent(inout) :: x(..)
    integer, intent(in) :: source, tag
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Recv(x, n_of(shape(x)), MPI_INTEGER, source, tag, this%comm, MPI_STATUS_IGNORE, ierr)
    call check_mpi(ierr, "MPI_Recv of " // str(n_of(shape(x))) // " integer(s) from rank " // str(source), error)
  end subroutine recv_int

  subroutine recv_real(this, x, source, tag, error)
    class(env_t), intent(in) :: this
    real(wp), contiguous, intent(inout) :: x(..)
    integer, intent(in) :: source, tag
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Recv(x, n_of(shape(x)), MPI_DOUBLE_PRECISION, source, tag, this%comm, MPI_STATUS_IGNORE, ierr)
    call check_mpi(ierr, "MPI_Recv of " // str(n_of(shape(x))) // " real(s) from rank " // str(source), error)
  end subroutine recv_real

  !> Barrier (every rank waits for all).
  subroutine sync(this, error)
    class(env_t), intent(in) :: this
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    if (failed_here) then
      ! (see mpi_failed)
      call set_error(error, "env: MPI_Barrier skipped after a failed MPI call on this rank", EXIT_MPI)
      return
    end if
    call MPI_Barrier(this%comm, ierr)
    call check_mpi(ierr, "MPI_Barrier", error)
  end subroutine sync
  ! ---- end of the checked collectives

  ! ==================================================================================
  ! Measures, text gathers and shared counters (snapshot stage).
  ! ==================================================================================

  !> Mean wall time of a one-integer MPI_Allreduce over `reps` repetitions (s), rank 0's value
  !> on every rank.
  function collective_latency(this, reps, error) result(t)
    class(env_t), intent(in) :: this
    integer, intent(in) :: reps
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: t, tt(1)
    integer :: k, ierr, one
    real(wp) :: t0
    t = 0
    call MPI_Barrier(this%comm, ierr)
    call check_mpi(ierr, "MPI_Barrier", error)
    if (allocated(error)) return
    t0 = MPI_Wtime()
    do k = 1, reps
      one = 1
      call MPI_Allreduce(MPI_IN_PLACE, one, 1, MPI_INTEGER, MPI_SUM, this%comm, ierr)
      call check_mpi(ierr, "MPI_Allreduce of 1 integer", error)
      if (allocated(error)) return
    end do
    tt = (MPI_Wtime() - t0) / max(reps, 1)
    call this%bcast(tt, error)
    t = tt(1)
  end function collective_latency

  !> Concatenation of every rank's text in rank order (every rank receives it).
  subroutine gather_text(this, s, all, error)
    class(env_t), intent(in) :: this
    character(len=*), intent(in) :: s
    character(len=:), allocatable, intent(out) :: all
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: cnt(:), displs(:)
    integer :: ierr
    call this%block_counts(len(s), cnt, displs, error)
    if (allocated(error)) return
    allocate(character(len=sum(cnt)) :: all)
    call MPI_Allgatherv(s, len(s), MPI_CHARACTER, all, cnt, displs, MPI_CHARACTER, this%comm, ierr)
    call check_mpi(ierr, "MPI_Allgatherv of " // str(sum(cnt)) // " characters", error)
  end subroutine gather_text

  !> First line of the MPI library's version string (not collective).
  function library_version(this) result(s)
    class(env_t), intent(in) :: this
    character(len=:), allocatable :: s
    character(len=MPI_MAX_LIBRARY_VERSION_STRING) :: v
    integer :: n, ierr
    call MPI_Get_library_version(v, n, ierr)
    s = "unknown"
    if (ierr /= MPI_SUCCESS .or. this%size < 1) return
    s = trim(v(1:min(n, len(v))))
    if (index(s, new_line('a')) > 0) s = s(1:index(s, new_line('a')) - 1)
  end function library_version

  !> Create the window of n_slots counters on rank 0, all zero. With barrier = .false. (default
  !> .true.) the ranks do not wait for rank 0 to have zeroed them (nor agree on an error): the
  !> caller must then make every rank receive a message from rank 0, sent after this call,
  !> before any rank's first fetch_add (and must agree on errors itself).
  subroutine counter_init(this, env, n_slots, error, barrier)
    class(shared_counter_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    integer, intent(in) :: n_slots
    type(error_t), allocatable, intent(out) :: error
    logical, intent(in), optional :: barrier
    integer(kind=MPI_ADDRESS_KIND) :: bytes
    type(c_ptr) :: base
    integer :: ierr
    bytes = 0
    if (env%rank == 0) bytes = 8 * n_slots
    call MPI_Win_allocate(bytes, 8, MPI_INFO_NULL, env%comm, base, this%win, ierr)
    call check_mpi(ierr, "MPI_Win_allocate of " // str(n_slots) // " counters", error)
    if (allocated(error)) return
    this%n_slots = n_slots
    ! a window's default handler is MPI_ERRORS_ARE_FATAL (it is not inherited from env%comm)
    call MPI_Win_set_errhandler(this%win, MPI_ERRORS_RETURN, ierr)
    call check_mpi(ierr, "MPI_Win_set_errhandler (MPI_ERRORS_RETURN, shared counter)", error)
    if (allocated(error)) return
    if (env%rank == 0) then
      call c_f_pointer(base, this%slots, [n_slots])
      call MPI_Win_lock(MPI_LOCK_EXCLUSIVE, 0, 0, this%win, ierr)
      call check_mpi(ierr, "MPI_Win_lock (counter init)", error)
      if (allocated(error)) return
      this%slots = 0
      call MPI_Win_unlock(0, this%win, ierr)
      call check_mpi(ierr, "MPI_Win_unlock (counter init)", error)
    end if
    ! the agreement is also the barrier: no rank takes a ticket before rank 0 has zeroed them
    if (present(barrier)) then
      if (.not. barrier) return
    end if
    call env%agree_error(error)
  end subroutine counter_init

  !> Atomically add inc to counter `slot` (1-based) and return its old value (not collective).
  function counter_fetch_add(this, slot, inc, error) result(old)
    class(shared_counter_t), intent(inout) :: this
    integer, intent(in) :: slot
    integer(i8), intent(in) :: inc
    type(error_t), allocatable, intent(out) :: error
    integer(i8) :: old
    integer(i8) :: one(1), res(1)
    integer :: ierr
    real(wp) :: t0
    t0 = MPI_Wtime()
    one = inc
    res = 0
    old = -1
    if (this%win == MPI_WIN_NULL) then
      call set_error(error, "env: shared counter used before init (slot " // str(slot) // ")"); return
    end if
    if (slot < 1 .or. slot > this%n_slots) then
      call set_error(error, "env: shared counter slot " // str(slot) // " outside 1.." // str(this%n_slots))
      return
    end if
    ! one passive-target epoch for all of this rank's operations (no lock and unlock each time)
    if (.not. this%epoch) then
      call MPI_Win_lock_all(0, this%win, ierr)
      call check_mpi(ierr, "MPI_Win_lock_all (shared counter)", error)
      if (allocated(error)) return
      this%epoch = .true.
    end if
    if (inc == 0) then
      call MPI_Fetch_and_op(one, res, MPI_INTEGER8, 0, int(slot - 1, MPI_ADDRESS_KIND), MPI_NO_OP, this%win, ierr)
    else
      call MPI_Fetch_and_op(one, res, MPI_INTEGER8, 0, int(slot - 1, MPI_ADDRESS_KIND), MPI_SUM, this%win, ierr)
    end if
    call check_mpi(ierr, "MPI_Fetch_and_op (shared counter " // str(slot) // ")", error)
    if (allocated(error)) return
    call MPI_Win_flush(0, this%win, ierr)
    call check_mpi(ierr, "MPI_Win_flush (shared counter)", error)
    if (allocated(error)) return
    old = res(1)
    this%n_calls = this%n_calls + 1
    this%t_calls = this%t_calls + (MPI_Wtime() - t0)
  end function counter_fetch_add

  !> Free the window (collective over the environment it was created on). Like env%free it
  !> cannot fail for the caller: the two statuses are deliberately not turned into an error.
  !> The window is not used again, so a failed MPI_Win_unlock_all or MPI_Win_free (returned,
  !> not fatal: MPI_ERRORS_RETURN) leaves nothing to recover; MPI_Win_free is called whatever
  !> the unlock returned, since it is collective and the other ranks wait for this one in it.
  subroutine counter_free(this)
    class(shared_counter_t), intent(inout) :: this
    integer :: ierr_unlock, ierr_free
    ! no MPI call after a failed one on this rank (see mpi_failed)
    if (this%epoch .and. .not. failed_here) call MPI_Win_unlock_all(this%win, ierr_unlock)
    this%epoch = .false.
    if (this%win /= MPI_WIN_NULL .and. .not. failed_here) call MPI_Win_free(this%win, ierr_free)
    this%win = MPI_WIN_NULL
    this%slots => null()
    this%n_slots = 0
  end subroutine counter_free

  !> Start the broadcast of `this%x` from rank 0 over env (collective, nonblocking).
  subroutine pending_start(this, env, error)
    class(pending_bcast_t), intent(inout), target :: this
    type(env_t), intent(in) :: env
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    if (.not. allocated(this%x)) allocate(this%x(0))
    call MPI_Ibcast(this%x, size(this%x), MPI_INTEGER8, 0, env%comm, this%req, ierr)
    call check_mpi(ierr, "MPI_Ibcast of " // str(size(this%x)) // " 64-bit integer(s) from rank 0", error)
    this%active = .not. allocated(error)
  end subroutine pending_start

  !> done = the broadcast has completed on this rank (x holds rank 0's data); not collective.
  subroutine pending_test(this, done, error)
    class(pending_bcast_t), intent(inout), target :: this
    logical, intent(out) :: done
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    done = .not. this%active
    if (done) return
    call MPI_Test(this%req, done, MPI_STATUS_IGNORE, ierr)
    call check_mpi(ierr, "MPI_Test (broadcast from rank 0)", error)
    if (allocated(error)) then
      done = .false.; return
    end if
    if (done) then
      this%active = .false.
      if (MPI_ASYNC_PROTECTS_NONBLOCKING .eqv. .false.) call MPI_F_sync_reg(this%x)
    end if
  end subroutine pending_test

  !> Wait until the broadcast has completed on this rank; not collective.
  subroutine pending_wait(this, error)
    class(pending_bcast_t), intent(inout), target :: this
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    if (.not. this%active) return
    call MPI_Wait(this%req, MPI_STATUS_IGNORE, ierr)
    this%active = .false.
    call check_mpi(ierr, "MPI_Wait (broadcast from rank 0)", error)
    if (MPI_ASYNC_PROTECTS_NONBLOCKING .eqv. .false.) call MPI_F_sync_reg(this%x)
  end subroutine pending_wait

end module cr_env

