!> The checked collectives and messages of env_t (the block used by the library modules):
!> broadcasts, in-place reductions, reduction to rank 0, gathers, all-to-all
!> exchanges and point-to-point messages give exact results (integers, or reals that are
!> small integers) at any number of ranks, return no error, and an unknown reduction is an
!> error. Run at 1, 2 and 3 ranks.
program test_env_checked
  use mpi_f08, only: MPI_Init, MPI_Finalize, MPI_COMM_WORLD
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_assert, only: check, test_summary
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  integer :: ierr, p, n, r, last, i
  integer :: iv(3), ia(2)
  integer(i8) :: lv(2)
  real(wp) :: rv(2, 2), x
  real(wp), allocatable :: mine(:), gath(:), sendbuf(:), recvbuf(:), gr(:), empty(:)
  character(len=:), allocatable :: text
  integer, allocatable :: counts(:), displs(:), got(:), sc(:), rc(:), sd(:), rd(:)

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call check(.not. allocated(error), "env%init")
  p = env%size; r = env%rank; last = p - 1

  ! broadcast from the last rank: integers, 64-bit integers, a 2D real array
  iv = -1; lv = -1; rv = -1
  if (r == last) then
    iv = [1, 2, 3]; lv = [huge(1_i8), -5_i8]; rv = reshape([1.5_wp, 2.5_wp, 3.5_wp, 4.5_wp], [2, 2])
  end if
  call env%bcast(iv, error, root=last); call check(.not. allocated(error), "bcast int: no error")
  call env%bcast(lv, error, root=last); call check(.not. allocated(error), "bcast i8: no error")
  call env%bcast(rv, error, root=last); call check(.not. allocated(error), "bcast real: no error")
  call check(all(iv == [1, 2, 3]), "bcast int: values")
  call check(all(lv == [huge(1_i8), -5_i8]), "bcast i8: values")
  call check(all(rv == reshape([1.5_wp, 2.5_wp, 3.5_wp, 4.5_wp], [2, 2])), "bcast real 2D: values")
  ! a scalar
  n = merge(42, 0, r == 0)
  call env%bcast(n, error)
  call check(n == 42 .and. .not. allocated(error), "bcast of a scalar from rank 0 (the default root)")
  ! a deferred-length string takes the root's length (the others' may be longer, or unallocated)
  if (r == last) then
    text = "from the last rank"
  else if (mod(r, 2) == 0) then
    text = "a longer text on an even rank that is not the root"
  end if
  call env%bcast(text, error, root=last)
  call check(.not. allocated(error), "bcast string: no error")
  call check(text == "from the last rank" .and. len(text) == 18, "bcast string: text and length")
  if (r == 0) text = ""
  call env%bcast(text, error)
  call check(.not. allocated(error) .and. len(text) == 0, "bcast of an empty string")

  ! in-place reductions
  ia = [r + 1, -(r + 1)]
  call env%allreduce(ia, 'sum', error)
  call check(.not. allocated(error) .and. all(ia == [p * (p + 1) / 2, -p * (p + 1) / 2]), "allreduce int sum")
  ia = [r, -r]
  call env%allreduce(ia, 'max', error)
  call check(.not. allocated(error) .and. all(ia == [last, 0]), "allreduce int max")
  lv = [int(r, i8) + 2_i8**40, 1_i8]
  call env%allreduce(lv, 'sum', error)
  call check(.not. allocated(error) .and. all(lv == [int(p, i8) * 2_i8**40 + int(p * (p - 1) / 2, i8), int(p, i8)]), &
    "allreduce i8 sum")
  x = real(r + 1, wp)
  call env%allreduce(x, 'min', error)
  call check(.not. allocated(error) .and. x == 1.0_wp, "allreduce real min (scalar)")
  rv = real(r, wp)
  call env%allreduce(rv, 'max', error)
  call check(.not. allocated(error) .and. all(rv == real(last, wp)), "allreduce real max (2D)")
  call env%allreduce(x, 'product', error)
  call check(allocated(error), "an unknown reduction is an error")
  if (allocated(error)) call check(index(error%message, "unknown reduction 'product'") > 0, &
    "the error names the reduction")

  ! reduction to rank 0
  rv = real(r + 1, wp)
  call env%reduce_sum_root(rv, error)
  call check(.not. allocated(error), "reduce_sum_root: no error")
  if (r == 0) call check(all(rv == real(p * (p + 1) / 2, wp)), "reduce_sum_root: sum on rank 0")

  ! allgather of one integer per rank
  call env%allgather(10 * r, got, error)
  call check(.not. allocated(error) .and. size(got) == p, "allgather int: size")
  call check(all(got == [(10 * i, i = 0, last)]), "allgather int: values in rank order")
  call env%allgather(0.5_wp * r, gr, error)
  call check(.not. allocated(error) .and. size(gr) == p, "allgather real: size")
  call check(all(gr == [(0.5_wp * i, i = 0, last)]), "allgather real: values in rank order")

  ! gatherv / allgatherv: rank q sends q + 1 values equal to q
  allocate(counts(p), displs(p))
  counts = [(i + 1, i = 0, last)]
  displs(1) = 0
  do i = 2, p
    displs(i) = displs(i - 1) + counts(i - 1)
  end do
  mine = [(real(r, wp), i = 1, r + 1)]
  allocate(gath(sum(counts))); gath = -1
  call env%gatherv(mine, gath, counts, displs, 0, error)
  call check(.not. allocated(error), "gatherv: no error")
  if (r == 0) call check(all_blocks(gath), "gatherv: blocks on rank 0")
  gath = -1
  call env%allgatherv(mine, gath, counts, displs, error)
  call check(.not. allocated(error) .and. all_blocks(gath), "allgatherv: blocks on every rank")

  ! all-to-all: rank r sends (q + 1) values 100 r + q to rank q
  allocate(sc(p), rc(p), sd(p), rd(p))
  sc = [(i + 1, i = 0, last)]
  call env%alltoall(sc, rc, error)
  call check(.not. allocated(error) .and. all(rc == r + 1), "alltoall: counts")
  sd(1) = 0; rd(1) = 0
  do i = 2, p
    sd(i) = sd(i - 1) + sc(i - 1); rd(i) = rd(i - 1) + rc(i - 1)
  end do
  allocate(sendbuf(sum(sc)), recvbuf(sum(rc)))
  do i = 1, p
    sendbuf(sd(i) + 1:sd(i) + sc(i)) = real(100 * r + (i - 1), wp)
  end do
  recvbuf = -1
  call env%alltoallv(sendbuf, sc, sd, recvbuf, rc, rd, error)
  call check(.not. allocated(error), "alltoallv: no error")
  do i = 1, p
    call check(all(recvbuf(rd(i) + 1:rd(i) + rc(i)) == real(100 * (i - 1) + r, wp)), "alltoallv: block from each rank")
  end do

  ! point-to-point: a ring, even ranks send first
  if (p > 1) then
    iv = [r, r, r]; rv = real(r, wp)
    if (mod(r, 2) == 0) then
      call ring_send(); call ring_recv()
    else
      call ring_recv(); call ring_send()
    end if
    call check(all(iv == modulo(r - 1, p)), "recv int from the previous rank")
    call check(all(rv == real(modulo(r - 1, p), wp)), "recv real 2D from the previous rank")
  end if

  ! a zero-size assumed-shape array handed on (gfortran 12 gives such a copied dummy the extent -1)
  allocate(empty(0))
  call hand_on(empty)

  call env%sync(error)
  call check(.not. allocated(error), "sync")
  call test_summary(r)
  call env%free()
  call MPI_Finalize(ierr)

contains

  logical function all_blocks(a)
    real(wp), intent(in) :: a(:)
    integer :: q
    all_blocks = .true.
    do q = 1, p
      all_blocks = all_blocks .and. all(a(displs(q) + 1:displs(q) + counts(q)) == real(q - 1, wp))
    end do
  end function all_blocks

  subroutine hand_on(a)
    real(wp), intent(inout) :: a(:)
    call env%allreduce(a, 'sum', error)
    call check(.not. allocated(error), "allreduce of a zero-size assumed-shape array")
    call env%bcast(a, error)
    call check(.not. allocated(error), "bcast of a zero-size assumed-shape array")
  end subroutine hand_on

  subroutine ring_send()
    integer :: tmp(3)
    real(wp) :: tr(2, 2)
    tmp = r; tr = real(r, wp)
    call env%send(tmp, modulo(r + 1, p), 7, error); call check(.not. allocated(error), "send int")
    call env%send(tr, modulo(r + 1, p), 8, error); call check(.not. allocated(error), "send real")
  end subroutine ring_send

  subroutine ring_recv()
    call env%recv(iv, modulo(r - 1, p), 7, error); call check(.not. allocated(error), "recv int")
    call env%recv(rv, modulo(r - 1, p), 8, error); call check(.not. allocated(error), "recv real")
  end subroutine ring_recv
end program test_env_checked
