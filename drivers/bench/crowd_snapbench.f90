!> Micro-benchmark of the snapshot stage's machine inputs (for scripts/bench/snapshot_model.py; not a
!> test): at the ranks it is started on, measures
!>  * the shared counter: mean wall time of one fetch-and-add when every rank takes a ticket
!>    after each 0.5..1.5 x `work` s of computation (env's shared_counter_t, as the scheduler);
!>  * the cost of one collective for ranks arriving from computation: each of `reps` rounds,
!>    every rank computes for a drawn 0.5..1.5 x `work` seconds, then all meet in an
!>    MPI_Allreduce; cost = (wall - computing time) / reps, mean over ranks (on shared cores
!>    this is the scheduler's wake-up delay, not the network latency);
!>  * the block-write bandwidth of the database writer's path: every rank writes `mb` MB in
!>    blocks of `block` bytes at disjoint offsets of one file with cr_fsys's block_file_t (each
!>    rank its own POSIX pwrite); per-rank bandwidth = bytes / time, aggregate = all bytes /
!>    slowest;
!>  * the heavier collective calls of the stage for ranks arriving from computation (as the
!>    collective above): a counter window created, and freed (each timed from the end of the
!>    computation; mean over `reps_h` rounds and over ranks).
!>
!> Usage: mpirun -np P crowd_snapbench [FILE] [mb] [block] ; prints one JSON line (rank 0).
program crowd_snapbench
  use cr_kinds, only: wp, i8
  use cr_env, only: env_t, shared_counter_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_fsys, only: block_file_t
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_random, only: rng_t
  use cr_exit_codes, only: EXIT_BAD_INPUT, EXIT_STOPPED
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(error_t), allocatable :: error
  type(shared_counter_t) :: counter
  type(block_file_t) :: pf
  type(rng_t) :: rng
  character(len=256) :: arg
  character(len=:), allocatable :: path
  integer :: k, reps, u, nblk, ios, j, code
  logical :: existed, created
  integer, parameter :: reps_h = 10
  integer(i8) :: t, bytes, block
  real(wp) :: t0, t_counter, t_coll, spent, work, x, y, t_write, wmax, mb, t_win(2)
  real(wp), allocatable :: buf(:), r(:)

  ! MPI, the environment and the logger as in every driver; the arguments are its own
  call program_start("crowd_snapbench", env, log, cli, error, own_arguments=.true.)
  path = "snapbench.tmp"; mb = 20; block = 65536
  if (command_argument_count() >= 1) then
    call get_command_argument(1, arg); path = trim(arg)
  end if
  if (command_argument_count() >= 2 .and. .not. allocated(error)) then
    call get_command_argument(2, arg); read(arg, *, iostat=ios) mb
    if (ios /= 0 .or. .not. (mb > 0)) call set_error(error, "crowd_snapbench: argument 2 (mb) must be a " // &
      "positive number of megabytes, got '" // trim(arg) // "'", EXIT_BAD_INPUT)
  end if
  if (command_argument_count() >= 3 .and. .not. allocated(error)) then
    call get_command_argument(3, arg); read(arg, *, iostat=ios) block
    if (ios /= 0 .or. block < 8 .or. mod(block, 8_i8) /= 0) call set_error(error, "crowd_snapbench: " // &
      "argument 3 (block) must be a positive multiple of 8 bytes, got '" // trim(arg) // "'", EXIT_BAD_INPUT)
  end if
  ! the scratch file is created and deleted here: an existing file is never overwritten
  if (.not. allocated(error)) then
    inquire(file=path, exist=existed)
    if (existed) call set_error(error, "crowd_snapbench: scratch file '" // path // &
      "' exists already (refusing to overwrite it; give another path as argument 1)", EXIT_BAD_INPUT)
  end if
  created = .false.
  ! shared counter: 50 tickets per rank, each after 0.5..1.5 x `work` s of computation (as in
  ! the sample loop: rank 0, which holds the counters, is computing too)
  reps = 30; work = 2.0e-3_wp; spent = 0
  call rng%seed(1234, stream=env%rank)
  if (.not. allocated(error)) call counter%init(env, 2, error)
  if (.not. allocated(error)) call env%sync(error)
  if (.not. allocated(error)) then
    do k = 1, 50
      x = env%wtime()
      y = work * (0.5_wp + rng%uniform())
      do while (env%wtime() - x < y)
      end do
      t = counter%fetch_add(1, 1_i8, error)
      if (allocated(error)) exit
    end do
    t_counter = counter%t_calls / max(counter%n_calls, 1)
    call counter%free()
  end if
  ! collectives after computation
  if (.not. allocated(error)) call env%sync(error)
  if (.not. allocated(error)) then
    t0 = env%wtime()
    do k = 1, reps
      x = env%wtime()
      y = work * (0.5_wp + rng%uniform())
      do while (env%wtime() - x < y)
      end do
      spent = spent + (env%wtime() - x)
      r = [1.0_wp]
      call env%allreduce(r, 'sum', error)
      if (allocated(error)) exit
    end do
    t_coll = ((env%wtime() - t0) - spent) / reps
    if (.not. allocated(error)) call env%allreduce(t_coll, 'sum', error)
    t_coll = t_coll / env%size
  end if
  ! block writes
  if (.not. allocated(error)) then
    bytes = int(mb * 1.0e6_wp, i8)
    nblk = int(max(bytes / block, 1_i8))
    allocate(buf(block / 8)); buf = real(env%rank, wp)
    if (env%is_root()) then
      open(newunit=u, file=path, status='new', action='write', iostat=ios)
      if (ios == 0) then
        close(u); created = .true.
      else
        call set_error(error, "crowd_snapbench: cannot create scratch file '" // path // "'", EXIT_STOPPED)
      end if
    end if
    call env%agree_error(error)
    if (.not. allocated(error)) call env%sync(error)
    if (.not. allocated(error)) call pf%open(path, error)
    t0 = env%wtime()
    do k = 1, nblk
      if (allocated(error)) exit
      call pf%write_at((int(k - 1, i8) * env%size + env%rank) * block, buf, block, error)
    end do
    t_write = env%wtime() - t0
    if (.not. allocated(error)) call pf%close(error)
    wmax = t_write
    if (.not. allocated(error)) call env%allreduce(wmax, 'max', error)
    if (.not. allocated(error)) call env%allreduce(t_write, 'sum', error)
    t_write = t_write / env%size
  end if
  ! the heavier collective calls of the stage, for ranks arriving from computation: a counter
  ! window created and freed (MPI_Win_allocate, MPI_Win_free)
  if (.not. allocated(error)) call env%sync(error)
  if (.not. allocated(error)) then
    ! (creation and release timed apart, each after computation: the stage creates the window
    ! in its setup and frees it at the end of the loop)
    t_win = 0
    do k = 1, reps_h
      do j = 1, 2
        x = env%wtime()
        y = work * (0.5_wp + rng%uniform())
        do while (env%wtime() - x < y)
        end do
        t0 = env%wtime()
        if (j == 1) then
          call counter%init(env, 1, error)
        else
          call counter%free()
        end if
        t_win(j) = t_win(j) + (env%wtime() - t0)
        if (allocated(error)) exit
      end do
      if (allocated(error)) exit
    end do
    t_win = t_win / reps_h
    if (.not. allocated(error)) call env%allreduce(t_win, 'sum', error)
    t_win = t_win / env%size
  end if
  if (env%is_root() .and. created) then
    open(newunit=u, file=path, status='old', iostat=ios); if (ios == 0) close(u, status='delete')
  end if
  if (.not. allocated(error) .and. env%is_root()) then
    print '(a)', '{"ranks": ' // str(env%size) // ', "counter_latency": ' // str(t_counter) // &
      ', "collective_cost": ' // str(t_coll) // ', "write_block_bytes": ' // str(block) // &
      ', "write_bytes_per_rank": ' // str(real(nblk, wp) * block) // &
      ', "write_bandwidth_per_rank": ' // str(real(nblk, wp) * block / max(t_write, 1.0e-9_wp)) // &
      ', "write_bandwidth_aggregate": ' // str(real(nblk, wp) * block * env%size / max(wmax, 1.0e-9_wp)) // &
      ', "window_create_cost": ' // str(t_win(1)) // ', "window_free_cost": ' // str(t_win(2)) // '}'
  end if
  code = program_finish(env, log, error)
  if (code /= 0) stop code, quiet=.true.
end program crowd_snapbench
