!> Dynamic assignment of tasks (samples) to ranks: a shared counter in an MPI one-sided window
!> held by rank 0. Each rank takes the next ticket with MPI_Fetch_and_op (passive target, no
!> idle master: rank 0 computes too), so ranks that draw cheap samples simply take more.
!> A second counter records completed tasks, for global progress reports.
!>
!> On one node Open MPI uses shared memory for the window (no progress thread needed); across
!> nodes the fetch may wait until rank 0 enters MPI (it does after each of its samples).
module cr_scheduler
  use, intrinsic :: iso_c_binding, only: c_ptr, c_f_pointer
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_env, only: env_t
  implicit none
  private
  public :: scheduler_t, collective_latency

  !> Shared ticket counter over n_tasks tasks.
  type :: scheduler_t
    type(MPI_Win) :: win = MPI_WIN_NULL
    type(MPI_Comm) :: comm = MPI_COMM_NULL
    integer(i8), pointer :: counters(:) => null()
    integer :: n_tasks = 0
    !> this rank's counter operations and the wall time spent in them (s)
    integer :: n_calls = 0
    real(wp) :: t_calls = 0
  contains
    procedure :: init
    procedure :: next
    procedure :: mark_done
    procedure :: n_done
    procedure :: free
  end type scheduler_t

contains

  !> Collective: create the window (counters on rank 0 set to zero).
  subroutine init(this, env, n_tasks, error)
    class(scheduler_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    integer, intent(in) :: n_tasks
    type(error_t), allocatable, intent(out) :: error
    integer(kind=MPI_ADDRESS_KIND) :: bytes
    type(c_ptr) :: base
    integer :: ierr
    this%n_tasks = n_tasks
    this%comm = env%comm
    bytes = 0
    if (env%rank == 0) bytes = 16
    call MPI_Win_allocate(bytes, 8, MPI_INFO_NULL, env%comm, base, this%win, ierr)
    if (ierr /= MPI_SUCCESS) then
      call set_error(error, "scheduler: MPI_Win_allocate failed"); return
    end if
    if (env%rank == 0) then
      call c_f_pointer(base, this%counters, [2])
      call MPI_Win_lock(MPI_LOCK_EXCLUSIVE, 0, 0, this%win, ierr)
      this%counters = 0
      call MPI_Win_unlock(0, this%win, ierr)
    end if
    call MPI_Barrier(env%comm, ierr)
  end subroutine init

  !> Atomically add `inc` to counter `slot` (0: tickets, 1: done) and return the old value.
  integer(i8) function fetch_add(this, slot, inc) result(old)
    type(scheduler_t), intent(inout) :: this
    integer, intent(in) :: slot
    integer(i8), intent(in) :: inc
    integer(i8) :: one(1), res(1)
    integer :: ierr
    real(wp) :: t0
    t0 = MPI_Wtime()
    one = inc
    res = 0
    call MPI_Win_lock(MPI_LOCK_SHARED, 0, 0, this%win, ierr)
    if (inc == 0) then
      call MPI_Fetch_and_op(one, res, MPI_INTEGER8, 0, int(slot, MPI_ADDRESS_KIND), MPI_NO_OP, this%win, ierr)
    else
      call MPI_Fetch_and_op(one, res, MPI_INTEGER8, 0, int(slot, MPI_ADDRESS_KIND), MPI_SUM, this%win, ierr)
    end if
    call MPI_Win_unlock(0, this%win, ierr)
    old = res(1)
    this%n_calls = this%n_calls + 1
    this%t_calls = this%t_calls + (MPI_Wtime() - t0)
  end function fetch_add

  !> The next task (1..n_tasks) for this rank, or 0 when every task has been taken.
  integer function next(this)
    class(scheduler_t), intent(inout) :: this
    integer(i8) :: t
    t = fetch_add(this, 0, 1_i8) + 1
    next = 0
    if (t <= this%n_tasks) next = int(t)
  end function next

  !> Record one completed task; returns the global number completed so far.
  integer function mark_done(this) result(n)
    class(scheduler_t), intent(inout) :: this
    n = int(fetch_add(this, 1, 1_i8) + 1)
  end function mark_done

  !> Global number of completed tasks.
  integer function n_done(this)
    class(scheduler_t), intent(inout) :: this
    n_done = int(fetch_add(this, 1, 0_i8))
  end function n_done

  !> Collective: free the window.
  subroutine free(this)
    class(scheduler_t), intent(inout) :: this
    integer :: ierr
    if (this%win /= MPI_WIN_NULL) call MPI_Win_free(this%win, ierr)
    this%win = MPI_WIN_NULL
    this%counters => null()
  end subroutine free

  !> Collective: mean wall time of a one-integer MPI_Allreduce over `reps` repetitions (s): the
  !> latency of one collective (an input of the stage's scaling model).
  function collective_latency(env, reps) result(t)
    type(env_t), intent(in) :: env
    integer, intent(in) :: reps
    real(wp) :: t
    integer :: k, ierr, one
    real(wp) :: t0
    call MPI_Barrier(env%comm, ierr)
    t0 = MPI_Wtime()
    do k = 1, reps
      one = 1
      call MPI_Allreduce(MPI_IN_PLACE, one, 1, MPI_INTEGER, MPI_SUM, env%comm, ierr)
    end do
    t = (MPI_Wtime() - t0) / max(reps, 1)
    call MPI_Bcast(t, 1, MPI_DOUBLE_PRECISION, 0, env%comm, ierr)
  end function collective_latency
end module cr_scheduler
