!> env_t's variable-size gathers of integers (block_counts, allgatherv), text gather, measures,
!> shared counter, nonblocking broadcast from rank 0 (the snapshot stage's MPI goes through
!> them; the other collectives are checked by test_env_checked), and the block file the ranks write the snapshot database with
!> (cr_fsys's block_file_t: every rank opens the same file and writes its own blocks). Run at 1
!> and 2 ranks: every result is checked against what it must be.
program test_env_collectives
  use mpi_f08, only: MPI_Init, MPI_Finalize, MPI_COMM_WORLD
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_env, only: env_t, shared_counter_t, pending_bcast_t
  use cr_fsys, only: block_file_t
  use cr_strings, only: str
  use cr_assert, only: check, test_summary
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  type(shared_counter_t) :: counter
  type(block_file_t) :: pf
  integer :: ierr, p, r, k, u, ios
  integer, allocatable :: ia(:), got(:), counts(:), displs(:)
  integer(i8), allocatable :: la(:), lall(:)
  integer(i8) :: old, tickets(1)
  real(wp) :: t, tt(1)
  character(len=:), allocatable :: text
  character(len=*), parameter :: path = "test_env_collectives.bin"
  integer(i8), allocatable :: back(:)
  type(pending_bcast_t) :: pb
  logical :: done

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call check(.not. allocated(error), "env init")
  p = env%size; r = env%rank

  ! variable-size gathers of integers: rank r contributes r + 1 entries equal to r (the
  ! broadcasts, reductions and gathers of reals are checked by test_env_checked)
  ia = [(r, k = 1, r + 1)]
  call env%block_counts(size(ia), counts, displs, error)
  call check(.not. allocated(error) .and. all(counts == [(k + 1, k = 0, p - 1)]), "block_counts: counts")
  call check(all(displs == [(k * (k + 1) / 2, k = 0, p - 1)]), "block_counts: displacements")
  allocate(got(sum(counts)))
  call env%allgatherv(ia, got, counts, displs, error)
  call check(.not. allocated(error) .and. size(got) == p * (p + 1) / 2, "allgatherv: total size")
  call check(all(got == [((k, u = 1, k + 1), k = 0, p - 1)]), "allgatherv: rank order")
  la = [(int(r, i8) * 10_i8**10, k = 1, 2)]
  call env%block_counts(size(la), counts, displs, error)
  allocate(lall(sum(counts)))
  call env%allgatherv(la, lall, counts, displs, error)
  call check(.not. allocated(error) .and. size(lall) == 2 * p .and. lall(2 * p) == int(p - 1, i8) * 10_i8**10, &
    "allgatherv of 64-bit integers")
  call env%gather_text(repeat(achar(iachar('a') + r), r + 1), text, error)
  call check(len(text) == p * (p + 1) / 2 .and. text(1:1) == 'a', "gather_text: rank order")
  if (p > 1) call check(text(2:3) == 'bb', "gather_text: second rank")

  ! measures: a positive latency, the same on every rank; a version line without a newline
  t = env%collective_latency(5, error)
  call check(.not. allocated(error) .and. t > 0, "collective_latency: positive")
  tt = t
  call env%allreduce(tt, 'max', error)
  call check(tt(1) == t, "collective_latency: rank 0's value on every rank")
  text = env%library_version()
  call check(len(text) > 0 .and. index(text, new_line('a')) == 0, "library_version: one line")

  ! shared counter: every ticket is handed out exactly once
  call counter%init(env, 2, error)
  call check(.not. allocated(error), "counter init")
  deallocate(ia); allocate(ia(0))
  do k = 1, 5
    old = counter%fetch_add(1, 1_i8, error)
    ia = [ia, int(old)]
  end do
  old = counter%fetch_add(2, 7_i8, error)
  call check(.not. allocated(error) .and. counter%n_calls == 6, "counter operations counted")
  call env%block_counts(size(ia), counts, displs, error)
  deallocate(got); allocate(got(sum(counts)))
  call env%allgatherv(ia, got, counts, displs, error)
  call check(size(got) == 5 * p, "5 tickets per rank")
  do k = 0, 5 * p - 1
    call check(count(got == k) == 1, "ticket " // str(k) // " handed out once")
  end do
  call env%sync(error)
  call check(.not. allocated(error), "barrier")
  tickets(1) = counter%fetch_add(2, 0_i8, error)
  call check(tickets(1) == 7_i8 * p, "second counter: sum of the additions")
  ! a slot outside the window is refused (MPI itself would write past the window on rank 0)
  old = counter%fetch_add(3, 1_i8, error)
  call check(allocated(error) .and. old == -1_i8, "counter slot 3 of 2 refused")
  if (allocated(error)) then
    call check(error%message == "env: shared counter slot 3 outside 1..2", "counter slot refusal: " // &
      error%message)
    deallocate(error)
  end if
  old = counter%fetch_add(0, 1_i8, error)
  call check(allocated(error), "counter slot 0 refused")
  if (allocated(error)) deallocate(error)
  call counter%free()
  old = counter%fetch_add(1, 1_i8, error)
  call check(allocated(error), "counter used after free refused")
  if (allocated(error)) deallocate(error)

  ! block file: each rank opens the file and writes its blocks interleaved; rank 0 reads it back
  if (r == 0) then
    open(newunit=u, file=path, status='replace', action='write'); close(u)
  end if
  call env%sync(error)
  call check(.not. allocated(error), "barrier")
  call pf%open(path, error)
  call check(.not. allocated(error), "block file open")
  do k = 0, 2
    la = [int(100 * r + k, i8)]
    call pf%write_at(int(8 * (k * p + r), i8), la, 8_i8, error)
  end do
  call pf%close(error)
  call check(.not. allocated(error), "block file writes and close")
  call env%sync(error)
  call check(.not. allocated(error), "barrier")
  if (r == 0) then
    allocate(back(3 * p))
    open(newunit=u, file=path, access='stream', form='unformatted', status='old', iostat=ios)
    read(u, iostat=ios) back
    close(u, status='delete')
    call check(ios == 0, "file read back")
    do k = 0, 2
      call check(all(back(k * p + 1:(k + 1) * p) == [(int(100 * u + k, i8), u = 0, p - 1)]), &
        "block row " // str(k) // " in place")
    end do
  end if
  call pf%open("no_such_dir/x.bin", error)
  call check(allocated(error), "opening a file in a missing directory fails")
  if (allocated(error)) then
    call check(index(error%message, "'no_such_dir/x.bin'") > 0 .and. &
      index(error%message, "No such file or directory") > 0, "message names the file and the reason")
    deallocate(error)
  end if
  call pf%write_at(0_i8, [1_i8], 8_i8, error)
  call check(allocated(error), "a write to a file that is not open fails")
  if (allocated(error)) deallocate(error)

  ! nonblocking broadcast from rank 0 (pending_bcast_t): every rank gets rank 0's data once
  ! test has said done or wait has returned; a broadcast of nothing completes too
  allocate(pb%x(3))
  pb%x = -1_i8
  if (r == 0) pb%x = [11_i8, 10_i8**12, -7_i8]
  call pb%start(env, error)
  call check(.not. allocated(error) .and. pb%active, "pending broadcast: started")
  done = .false.
  do k = 1, 100000
    call pb%test(done, error)
    if (done .or. allocated(error)) exit
  end do
  if (.not. done .and. .not. allocated(error)) call pb%wait(error)
  call check(.not. allocated(error) .and. .not. pb%active, "pending broadcast: completed")
  call check(all(pb%x == [11_i8, 10_i8**12, -7_i8]), "pending broadcast: rank 0's data on every rank")
  call pb%wait(error)
  call check(.not. allocated(error), "pending broadcast: wait after completion is a no-op")
  deallocate(pb%x)
  call pb%start(env, error)
  call pb%wait(error)
  call check(.not. allocated(error) .and. size(pb%x) == 0 .and. .not. pb%active, "pending broadcast of nothing")

  call test_summary(r)
  call env%free()
  call MPI_Finalize(ierr)
end program test_env_collectives
