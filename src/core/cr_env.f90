!> Parallel environment: wraps a duplicate of the communicator it is given.
!>
!> Library code never names MPI_COMM_WORLD; drivers create an env_t on it and tests may
!> create one on any sub-communicator. Collective helpers check every MPI status.
module cr_env
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  implicit none
  private
  public :: env_t, agree_error_on

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
  end type env_t

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

  !> Wall-clock time in seconds.
  real(wp) function wtime()
    wtime = MPI_Wtime()
  end function wtime
end module cr_env
