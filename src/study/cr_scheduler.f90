!> Dynamic assignment of tasks (samples) to ranks: a shared counter in an MPI one-sided window
!> held by rank 0 (env's shared_counter_t). Each rank takes the next ticket with a fetch-and-add
!> (passive target, no idle master: rank 0 computes too), so ranks that draw cheap samples
!> simply take more. One counter operation per task: the ticket number also tells how many
!> tasks have been handed out (progress reports count started tasks).
!>
!> On one node Open MPI uses shared memory for the window (no progress thread needed); across
!> nodes the fetch may wait until rank 0 enters MPI (it does after each of its samples).
module cr_scheduler
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_env, only: env_t, shared_counter_t
  implicit none
  private
  public :: scheduler_t

  !> Shared ticket counter over n_tasks tasks.
  type :: scheduler_t
    type(shared_counter_t) :: counter
    integer :: n_tasks = 0
  contains
    procedure :: init
    procedure :: next
    procedure :: n_calls
    procedure :: t_calls
    procedure :: free
  end type scheduler_t

contains

  !> Collective: create the ticket counter on rank 0, zero. With barrier = .false. (default
  !> .true.) the ranks do not wait for rank 0 to have zeroed it: the caller must have every rank
  !> receive a message from rank 0 sent after init (e.g. a broadcast) before the first `next`.
  subroutine init(this, env, n_tasks, error, barrier)
    class(scheduler_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    integer, intent(in) :: n_tasks
    type(error_t), allocatable, intent(out) :: error
    logical, intent(in), optional :: barrier
    this%n_tasks = n_tasks
    call this%counter%init(env, 1, error, barrier)
  end subroutine init

  !> The next task (1..n_tasks) for this rank, or 0 when every task has been taken.
  integer function next(this, error)
    class(scheduler_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    integer(i8) :: t
    next = 0
    t = this%counter%fetch_add(1, 1_i8, error) + 1
    if (allocated(error)) return
    if (t <= this%n_tasks) next = int(t)
  end function next

  !> This rank's counter operations so far.
  integer function n_calls(this)
    class(scheduler_t), intent(in) :: this
    n_calls = this%counter%n_calls
  end function n_calls

  !> Wall time this rank spent in counter operations (s).
  real(wp) function t_calls(this)
    class(scheduler_t), intent(in) :: this
    t_calls = this%counter%t_calls
  end function t_calls

  !> Collective: free the window.
  subroutine free(this)
    class(scheduler_t), intent(inout) :: this
    call this%counter%free()
  end subroutine free
end module cr_scheduler
