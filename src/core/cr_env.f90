!> Parallel environment: wraps a duplicate of the communicator it is given.
!>
!> Library code never names MPI_COMM_WORLD; drivers create an env_t on it and tests may
!> create one on any sub-communicator. Collective helpers check every MPI status.
module cr_env
  use, intrinsic :: iso_c_binding, only: c_ptr, c_f_pointer
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  implicit none
  private
  public :: env_t, agree_error_on
  ! ---- snap2 additions (snapshot stage): collectives, shared counter, MPI-IO block file ----
  public :: shared_counter_t, par_file_t
  ! ---- end snap2 additions ----

  !> MPI environment: private duplicate communicator, rank, size.
  type :: env_t
    type(MPI_Comm) :: comm = MPI_COMM_NULL
    integer :: rank = 0
    integer :: size = 1
  contains
    procedure :: init
    procedure :: free
    procedure :: is_root
    procedure :: barrier
    procedure :: any_true
    procedure :: sum_real, sum_real_array, sum_int, max_real, min_real, max_int
    procedure :: bcast_string
    procedure :: agree_error
    procedure, nopass :: wtime
    ! ---- snap2 additions (snapshot stage) ----
    procedure :: bcast_i4_0, bcast_i4_1, bcast_i8_1, bcast_r8_1
    generic :: bcast => bcast_i4_0, bcast_i4_1, bcast_i8_1, bcast_r8_1
    procedure :: allgather_i4, allgather_r8
    generic :: allgather => allgather_i4, allgather_r8
    procedure :: allgatherv_i4, allgatherv_i8
    generic :: allgatherv => allgatherv_i4, allgatherv_i8
    procedure :: reduce_i4_1, reduce_i8_1, reduce_r8_1
    generic :: allreduce => reduce_i4_1, reduce_i8_1, reduce_r8_1
    procedure :: collective_latency
    procedure :: library_version
    procedure :: gather_text
    ! ---- end snap2 additions ----
  end type env_t

  ! ---- snap2 additions (snapshot stage) ----
  !> A set of 64-bit counters held by rank 0 in an MPI one-sided window; any rank adds to one
  !> atomically (passive target: rank 0 need not take part).
  type :: shared_counter_t
    type(MPI_Win) :: win = MPI_WIN_NULL
    integer(i8), pointer :: slots(:) => null()
    !> this rank's operations and the wall time spent in them (s)
    integer :: n_calls = 0
    real(wp) :: t_calls = 0
  contains
    procedure :: init => counter_init
    procedure :: fetch_add => counter_fetch_add
    procedure :: free => counter_free
  end type shared_counter_t

  !> A file opened for writing with MPI-IO by every rank of an environment; each rank writes
  !> its own byte blocks at explicit offsets (independent writes: no rank waits for another).
  type :: par_file_t
    type(MPI_File) :: fh = MPI_FILE_NULL
    character(len=:), allocatable :: path
    type(MPI_Comm) :: comm = MPI_COMM_NULL
  contains
    procedure :: open => pfile_open
    procedure :: write_at => pfile_write_at
    procedure :: close => pfile_close
  end type par_file_t
  ! ---- end snap2 additions ----

contains

  !> Duplicate `comm` and record rank/size.
  subroutine init(this, comm, error)
    class(env_t), intent(inout) :: this
    type(MPI_Comm), intent(in) :: comm
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    call MPI_Comm_dup(comm, this%comm, ierr)
    if (ierr /= MPI_SUCCESS) then
      call set_error(error, "env: MPI_Comm_dup failed"); return
    end if
    call MPI_Comm_rank(this%comm, this%rank, ierr)
    call MPI_Comm_size(this%comm, this%size, ierr)
  end subroutine init

  !> Release the duplicated communicator.
  subroutine free(this)
    class(env_t), intent(inout) :: this
    integer :: ierr
    if (this%comm /= MPI_COMM_NULL) call MPI_Comm_free(this%comm, ierr)
    this%comm = MPI_COMM_NULL
  end subroutine free

  !> True on rank 0.
  pure logical function is_root(this)
    class(env_t), intent(in) :: this
    is_root = this%rank == 0
  end function is_root

  subroutine barrier(this)
    class(env_t), intent(in) :: this
    integer :: ierr
    call MPI_Barrier(this%comm, ierr)
  end subroutine barrier

  !> Logical OR over ranks (used to make failures collective).
  logical function any_true(this, flag)
    class(env_t), intent(in) :: this
    logical, intent(in) :: flag
    integer :: ierr
    call MPI_Allreduce(flag, any_true, 1, MPI_LOGICAL, MPI_LOR, this%comm, ierr)
  end function any_true

  real(wp) function sum_real(this, x)
    class(env_t), intent(in) :: this
    real(wp), intent(in) :: x
    integer :: ierr
    call MPI_Allreduce(x, sum_real, 1, MPI_DOUBLE_PRECISION, MPI_SUM, this%comm, ierr)
  end function sum_real

  !> In-place sum over ranks of a real array (all ranks receive the result).
  subroutine sum_real_array(this, x)
    class(env_t), intent(in) :: this
    real(wp), intent(inout) :: x(:)
    integer :: ierr
    if (this%size == 1 .or. size(x) == 0) return
    call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_DOUBLE_PRECISION, MPI_SUM, this%comm, ierr)
  end subroutine sum_real_array

  integer(i8) function sum_int(this, i)
    class(env_t), intent(in) :: this
    integer(i8), intent(in) :: i
    integer :: ierr
    call MPI_Allreduce(i, sum_int, 1, MPI_INTEGER8, MPI_SUM, this%comm, ierr)
  end function sum_int

  real(wp) function max_real(this, x)
    class(env_t), intent(in) :: this
    real(wp), intent(in) :: x
    integer :: ierr
    call MPI_Allreduce(x, max_real, 1, MPI_DOUBLE_PRECISION, MPI_MAX, this%comm, ierr)
  end function max_real

  real(wp) function min_real(this, x)
    class(env_t), intent(in) :: this
    real(wp), intent(in) :: x
    integer :: ierr
    call MPI_Allreduce(x, min_real, 1, MPI_DOUBLE_PRECISION, MPI_MIN, this%comm, ierr)
  end function min_real

  integer function max_int(this, i)
    class(env_t), intent(in) :: this
    integer, intent(in) :: i
    integer :: ierr
    call MPI_Allreduce(i, max_int, 1, MPI_INTEGER, MPI_MAX, this%comm, ierr)
  end function max_int

  !> Broadcast a deferred-length string from rank 0 to all ranks.
  subroutine bcast_string(this, s)
    class(env_t), intent(in) :: this
    character(len=:), allocatable, intent(inout) :: s
    integer :: n, ierr
    n = 0
    if (this%rank == 0) n = len(s)
    call MPI_Bcast(n, 1, MPI_INTEGER, 0, this%comm, ierr)
    if (this%rank /= 0) then
      if (allocated(s)) deallocate(s)
      allocate(character(len=n) :: s)
    end if
    if (n > 0) call MPI_Bcast(s, n, MPI_CHARACTER, 0, this%comm, ierr)
  end subroutine bcast_string

  !> Collective error agreement: if any rank of the environment holds an error, every rank
  !> returns the error of the lowest failing rank (message and code broadcast from it). When
  !> only some ranks failed, the message starts with "rank R of P: " so that the one line that
  !> rank 0 prints says where it happened. Collective: every rank must call it.
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
    if (comm == MPI_COMM_NULL) return
    call MPI_Comm_size(comm, nranks, ierr)
    if (nranks == 1) return
    call MPI_Comm_rank(comm, rank, ierr)
    who = huge(1)
    if (allocated(error)) who = rank
    call MPI_Allreduce(MPI_IN_PLACE, who, 1, MPI_INTEGER, MPI_MIN, comm, ierr)
    if (who == huge(1)) return
    n_failed = merge(1, 0, allocated(error))
    call MPI_Allreduce(MPI_IN_PLACE, n_failed, 1, MPI_INTEGER, MPI_SUM, comm, ierr)
    meta = 0
    if (rank == who) then
      msg = error%message
      meta = [len(msg), error%code]
    end if
    call MPI_Bcast(meta, 2, MPI_INTEGER, who, comm, ierr)
    if (rank /= who) allocate(character(len=meta(1)) :: msg)
    if (meta(1) > 0) call MPI_Bcast(msg, meta(1), MPI_CHARACTER, who, comm, ierr)
    if (n_failed < nranks) msg = "rank " // str(who) // " of " // str(nranks) // ": " // msg
    if (allocated(error)) deallocate(error)
    call set_error(error, msg, meta(2))
  end subroutine agree_error_on

  ! ---- snap2 additions (snapshot stage): every MPI status checked; on failure `error` says
  ! ---- which operation failed with which sizes. Collective unless said otherwise.

  !> Error "env: <op> failed (<MPI error string>)" if ierr is not MPI_SUCCESS.
  subroutine mpi_check(ierr, op, error)
    integer, intent(in) :: ierr
    character(len=*), intent(in) :: op
    type(error_t), allocatable, intent(inout) :: error
    character(len=MPI_MAX_ERROR_STRING) :: msg
    integer :: n, ie
    if (ierr == MPI_SUCCESS .or. allocated(error)) return
    msg = ''
    call MPI_Error_string(ierr, msg, n, ie)
    call set_error(error, "env: " // op // " failed (" // trim(msg) // ")")
  end subroutine mpi_check

  !> Broadcast x from rank `root` (default 0).
  subroutine bcast_i4_0(this, x, error, root)
    class(env_t), intent(in) :: this
    integer, intent(inout) :: x
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: root
    integer :: ierr
    call MPI_Bcast(x, 1, MPI_INTEGER, root_of(root), this%comm, ierr)
    call mpi_check(ierr, "MPI_Bcast of 1 integer", error)
  end subroutine bcast_i4_0

  subroutine bcast_i4_1(this, x, error, root)
    class(env_t), intent(in) :: this
    integer, intent(inout) :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: root
    integer :: ierr
    if (size(x) == 0) return
    call MPI_Bcast(x, size(x), MPI_INTEGER, root_of(root), this%comm, ierr)
    call mpi_check(ierr, "MPI_Bcast of " // str(size(x)) // " integers", error)
  end subroutine bcast_i4_1

  subroutine bcast_i8_1(this, x, error, root)
    class(env_t), intent(in) :: this
    integer(i8), intent(inout) :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: root
    integer :: ierr
    if (size(x) == 0) return
    call MPI_Bcast(x, size(x), MPI_INTEGER8, root_of(root), this%comm, ierr)
    call mpi_check(ierr, "MPI_Bcast of " // str(size(x)) // " 64-bit integers", error)
  end subroutine bcast_i8_1

  subroutine bcast_r8_1(this, x, error, root)
    class(env_t), intent(in) :: this
    real(wp), intent(inout) :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: root
    integer :: ierr
    if (size(x) == 0) return
    call MPI_Bcast(x, size(x), MPI_DOUBLE_PRECISION, root_of(root), this%comm, ierr)
    call mpi_check(ierr, "MPI_Bcast of " // str(size(x)) // " reals", error)
  end subroutine bcast_r8_1

  pure integer function root_of(root)
    integer, intent(in), optional :: root
    root_of = 0
    if (present(root)) root_of = root
  end function root_of

  !> Every rank's x, in rank order [size].
  subroutine allgather_i4(this, x, all, error)
    class(env_t), intent(in) :: this
    integer, intent(in) :: x
    integer, allocatable, intent(out) :: all(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    allocate(all(this%size))
    call MPI_Allgather(x, 1, MPI_INTEGER, all, 1, MPI_INTEGER, this%comm, ierr)
    call mpi_check(ierr, "MPI_Allgather of 1 integer", error)
  end subroutine allgather_i4

  subroutine allgather_r8(this, x, all, error)
    class(env_t), intent(in) :: this
    real(wp), intent(in) :: x
    real(wp), allocatable, intent(out) :: all(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    allocate(all(this%size))
    call MPI_Allgather(x, 1, MPI_DOUBLE_PRECISION, all, 1, MPI_DOUBLE_PRECISION, this%comm, ierr)
    call mpi_check(ierr, "MPI_Allgather of 1 real", error)
  end subroutine allgather_r8

  !> Concatenation of every rank's x in rank order [sum of sizes]; counts(r) = size on rank r-1.
  subroutine allgatherv_i4(this, x, all, error, counts)
    class(env_t), intent(in) :: this
    integer, intent(in) :: x(:)
    integer, allocatable, intent(out) :: all(:)
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable, intent(out), optional :: counts(:)
    integer, allocatable :: cnt(:), displs(:)
    integer :: ierr
    call gather_counts(this, size(x), cnt, displs, error)
    if (allocated(error)) return
    allocate(all(sum(cnt)))
    call MPI_Allgatherv(x, size(x), MPI_INTEGER, all, cnt, displs, MPI_INTEGER, this%comm, ierr)
    call mpi_check(ierr, "MPI_Allgatherv of " // str(sum(cnt)) // " integers", error)
    if (present(counts)) call move_alloc(cnt, counts)
  end subroutine allgatherv_i4

  subroutine allgatherv_i8(this, x, all, error, counts)
    class(env_t), intent(in) :: this
    integer(i8), intent(in) :: x(:)
    integer(i8), allocatable, intent(out) :: all(:)
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable, intent(out), optional :: counts(:)
    integer, allocatable :: cnt(:), displs(:)
    integer :: ierr
    call gather_counts(this, size(x), cnt, displs, error)
    if (allocated(error)) return
    allocate(all(sum(cnt)))
    call MPI_Allgatherv(x, size(x), MPI_INTEGER8, all, cnt, displs, MPI_INTEGER8, this%comm, ierr)
    call mpi_check(ierr, "MPI_Allgatherv of " // str(sum(cnt)) // " 64-bit integers", error)
    if (present(counts)) call move_alloc(cnt, counts)
  end subroutine allgatherv_i8

  subroutine gather_counts(this, n, cnt, displs, error)
    class(env_t), intent(in) :: this
    integer, intent(in) :: n
    integer, allocatable, intent(out) :: cnt(:), displs(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: r
    call this%allgather(n, cnt, error)
    if (allocated(error)) return
    allocate(displs(this%size))
    displs(1) = 0
    do r = 2, this%size
      displs(r) = displs(r - 1) + cnt(r - 1)
    end do
    if (sum(int(cnt, i8)) > huge(1)) call set_error(error, "env: MPI_Allgatherv of " // &
      str(sum(int(cnt, i8))) // " entries exceeds the 32-bit counts")
  end subroutine gather_counts

  !> In-place reduction of x over the ranks; op = 'sum', 'max' or 'min'.
  subroutine reduce_i4_1(this, x, op, error)
    class(env_t), intent(in) :: this
    integer, intent(inout) :: x(:)
    character(len=*), intent(in) :: op
    type(error_t), allocatable, intent(out) :: error
    type(MPI_Op) :: o
    integer :: ierr
    call op_of(op, o, error)
    if (allocated(error) .or. size(x) == 0) return
    call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_INTEGER, o, this%comm, ierr)
    call mpi_check(ierr, "MPI_Allreduce (" // op // ") of " // str(size(x)) // " integers", error)
  end subroutine reduce_i4_1

  subroutine reduce_i8_1(this, x, op, error)
    class(env_t), intent(in) :: this
    integer(i8), intent(inout) :: x(:)
    character(len=*), intent(in) :: op
    type(error_t), allocatable, intent(out) :: error
    type(MPI_Op) :: o
    integer :: ierr
    call op_of(op, o, error)
    if (allocated(error) .or. size(x) == 0) return
    call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_INTEGER8, o, this%comm, ierr)
    call mpi_check(ierr, "MPI_Allreduce (" // op // ") of " // str(size(x)) // " 64-bit integers", error)
  end subroutine reduce_i8_1

  subroutine reduce_r8_1(this, x, op, error)
    class(env_t), intent(in) :: this
    real(wp), intent(inout) :: x(:)
    character(len=*), intent(in) :: op
    type(error_t), allocatable, intent(out) :: error
    type(MPI_Op) :: o
    integer :: ierr
    call op_of(op, o, error)
    if (allocated(error) .or. size(x) == 0) return
    call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_DOUBLE_PRECISION, o, this%comm, ierr)
    call mpi_check(ierr, "MPI_Allreduce (" // op // ") of " // str(size(x)) // " reals", error)
  end subroutine reduce_r8_1

  subroutine op_of(op, o, error)
    character(len=*), intent(in) :: op
    type(MPI_Op), intent(out) :: o
    type(error_t), allocatable, intent(out) :: error
    select case (op)
    case ('sum'); o = MPI_SUM
    case ('max'); o = MPI_MAX
    case ('min'); o = MPI_MIN
    case default
      o = MPI_OP_NULL
      call set_error(error, "env: unknown reduction '" // op // "' (sum, max, min)")
    end select
  end subroutine op_of

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
    call mpi_check(ierr, "MPI_Barrier", error)
    if (allocated(error)) return
    t0 = MPI_Wtime()
    do k = 1, reps
      one = 1
      call MPI_Allreduce(MPI_IN_PLACE, one, 1, MPI_INTEGER, MPI_SUM, this%comm, ierr)
      call mpi_check(ierr, "MPI_Allreduce of 1 integer", error)
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
    call gather_counts(this, len(s), cnt, displs, error)
    if (allocated(error)) return
    allocate(character(len=sum(cnt)) :: all)
    call MPI_Allgatherv(s, len(s), MPI_CHARACTER, all, cnt, displs, MPI_CHARACTER, this%comm, ierr)
    call mpi_check(ierr, "MPI_Allgatherv of " // str(sum(cnt)) // " characters", error)
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

  !> Create the window of n_slots counters on rank 0, all zero.
  subroutine counter_init(this, env, n_slots, error)
    class(shared_counter_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    integer, intent(in) :: n_slots
    type(error_t), allocatable, intent(out) :: error
    integer(kind=MPI_ADDRESS_KIND) :: bytes
    type(c_ptr) :: base
    integer :: ierr
    bytes = 0
    if (env%rank == 0) bytes = 8 * n_slots
    call MPI_Win_allocate(bytes, 8, MPI_INFO_NULL, env%comm, base, this%win, ierr)
    call mpi_check(ierr, "MPI_Win_allocate of " // str(n_slots) // " counters", error)
    if (allocated(error)) return
    if (env%rank == 0) then
      call c_f_pointer(base, this%slots, [n_slots])
      call MPI_Win_lock(MPI_LOCK_EXCLUSIVE, 0, 0, this%win, ierr)
      call mpi_check(ierr, "MPI_Win_lock (counter init)", error)
      if (allocated(error)) return
      this%slots = 0
      call MPI_Win_unlock(0, this%win, ierr)
      call mpi_check(ierr, "MPI_Win_unlock (counter init)", error)
    end if
    ! the agreement is also the barrier: no rank takes a ticket before rank 0 has zeroed them
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
    call MPI_Win_lock(MPI_LOCK_SHARED, 0, 0, this%win, ierr)
    call mpi_check(ierr, "MPI_Win_lock (shared counter)", error)
    if (allocated(error)) return
    if (inc == 0) then
      call MPI_Fetch_and_op(one, res, MPI_INTEGER8, 0, int(slot - 1, MPI_ADDRESS_KIND), MPI_NO_OP, this%win, ierr)
    else
      call MPI_Fetch_and_op(one, res, MPI_INTEGER8, 0, int(slot - 1, MPI_ADDRESS_KIND), MPI_SUM, this%win, ierr)
    end if
    call mpi_check(ierr, "MPI_Fetch_and_op (shared counter " // str(slot) // ")", error)
    call MPI_Win_unlock(0, this%win, ierr)
    call mpi_check(ierr, "MPI_Win_unlock (shared counter)", error)
    if (allocated(error)) return
    old = res(1)
    this%n_calls = this%n_calls + 1
    this%t_calls = this%t_calls + (MPI_Wtime() - t0)
  end function counter_fetch_add

  !> Free the window (collective over the environment it was created on).
  subroutine counter_free(this)
    class(shared_counter_t), intent(inout) :: this
    integer :: ierr
    if (this%win /= MPI_WIN_NULL) call MPI_Win_free(this%win, ierr)
    this%win = MPI_WIN_NULL
    this%slots => null()
  end subroutine counter_free

  !> Open an existing file for writing on every rank of env (MPI-IO).
  subroutine pfile_open(this, env, path, error)
    class(par_file_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    this%path = path
    this%comm = env%comm
    call MPI_File_open(env%comm, path, MPI_MODE_WRONLY, MPI_INFO_NULL, this%fh, ierr)
    call mpi_check(ierr, "MPI_File_open of '" // path // "' for writing", error)
  end subroutine pfile_open

  !> Write nbytes bytes of buf at byte offset `offset` of the file (independent: not
  !> collective; blocks of different ranks must not overlap).
  subroutine pfile_write_at(this, offset, buf, nbytes, error)
    class(par_file_t), intent(inout) :: this
    integer(i8), intent(in) :: offset, nbytes
    type(*), intent(in), contiguous :: buf(..)
    type(error_t), allocatable, intent(out) :: error
    type(MPI_Status) :: st
    integer :: ierr, got
    if (nbytes <= 0) return
    if (nbytes > huge(1)) then
      call set_error(error, "env: write of " // str(nbytes) // " bytes to '" // this%path // &
        "' exceeds one MPI count"); return
    end if
    call MPI_File_write_at(this%fh, int(offset, MPI_OFFSET_KIND), buf, int(nbytes), MPI_BYTE, st, ierr)
    call mpi_check(ierr, "MPI_File_write_at of " // str(nbytes) // " bytes at offset " // str(offset) // &
      " of '" // this%path // "'", error)
    if (allocated(error)) return
    call MPI_Get_count(st, MPI_BYTE, got, ierr)
    if (ierr == MPI_SUCCESS .and. got /= nbytes) call set_error(error, "env: MPI_File_write_at wrote " // &
      str(got) // " of " // str(nbytes) // " bytes at offset " // str(offset) // " of '" // this%path // &
      "' (disk full?)")
  end subroutine pfile_write_at

  !> Close the file (collective); the data are visible to any later open.
  subroutine pfile_close(this, error)
    class(par_file_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    integer :: ierr
    if (this%fh == MPI_FILE_NULL) return
    call MPI_File_close(this%fh, ierr)
    call mpi_check(ierr, "MPI_File_close of '" // this%path // "'", error)
    this%fh = MPI_FILE_NULL
  end subroutine pfile_close
  ! ---- end snap2 additions ----

  !> Wall-clock time in seconds.
  real(wp) function wtime()
    wtime = MPI_Wtime()
  end function wtime
end module cr_env
