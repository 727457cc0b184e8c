!> Parallel cr_h5file: collective column blocks of a [7, ncols] dataset with an uneven split
!> (the last rank has no columns when np > 1), rank-0 whole writes, appends, commit; read back
!> by every rank and compared exactly. Run at 1, 2 and 4 ranks.
!> Also: write_ranges with round-robin columns (many disjoint ranges per rank), and cr_digest:
!> the ranks' partial digests add up to the digest of the whole dataset; one changed bit or
!> two swapped columns change it.
program test_h5file_mpi
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_assert, only: check, test_summary
  use cr_fsys, only: file_exists
  use cr_h5file, only: h5file_t, cr_h5_real, cr_h5_int
  use cr_digest, only: digest_t, digest_of, digest_add, digest_allreduce, digest_hex
  implicit none
  integer, parameter :: n_rows = 7
  type(env_t) :: env
  type(h5file_t) :: f
  type(error_t), allocatable :: error
  integer :: ierr, r, i, j, ncols, nloc, off, peer, poff, pn, nv
  integer, allocatable :: counts(:), iblk(:,:), iall(:,:), steps(:), rg(:,:)
  integer, parameter :: n_cyc = 11
  type(digest_t) :: dpart, dwhole
  real(wp), allocatable :: cyc(:,:), cycall(:,:), tmp(:,:)
  real(wp), allocatable :: a(:,:), whole(:,:), mine(:,:), theirs(:,:), v(:)
  character(len=32) :: fname
  character(len=:), allocatable :: s
  integer :: ie(0), ione(1)
  real(wp) :: re(n_rows, 0)

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call check(.not. allocated(error), "env init")

  ! uneven split: rank r owns r+1 columns, the last rank none (np > 1)
  allocate(counts(0:env%size-1))
  counts = [(r + 1, r = 0, env%size - 1)]
  if (env%size > 1) counts(env%size - 1) = 0
  if (env%size == 1) counts(0) = 5
  ncols = sum(counts)
  nloc = counts(env%rank)
  off = sum(counts(0:env%rank-1))
  allocate(a(n_rows, ncols))
  do j = 1, ncols
    do i = 1, n_rows
      a(i, j) = real(i, wp) / 7.0_wp + 100.0_wp * j
    end do
  end do
  write(fname, '("mpi_np", i0, ".h5")') env%size

  call f%create(trim(fname), error, env)
  call check(.not. allocated(error), "parallel create")
  call f%create_dataset("basis/phi", [n_rows, ncols], cr_h5_real, error)
  call check(.not. allocated(error), "create_dataset")
  mine = a(:, off+1:off+nloc)
  call f%write_block("basis/phi", mine, off, error)
  call check(.not. allocated(error), "write_block (collective, maybe zero columns)")
  call f%create_dataset("basis/owner", [2, ncols], cr_h5_int, error)
  allocate(iblk(2, nloc))
  iblk(1, :) = env%rank
  iblk(2, :) = [(off + j, j = 1, nloc)]
  call f%write_block("basis/owner", iblk, off, error)
  call check(.not. allocated(error), "integer write_block")
  ! whole-dataset write: rank 0's data is written, the others' ignored
  call f%write("meta/rank0", [real(env%rank, wp), 1.5_wp], error)
  call check(.not. allocated(error), "whole write in parallel")
  call f%write("config", "&output path='x' /", error)
  call f%write_attr("/", "n_ranks_written", env%size, error)
  call check(.not. allocated(error), "attribute in parallel")
  ! empty datasets (a study without contacts): zero-sized blocks on every rank
  call f%create_dataset("empty/idx", [0], cr_h5_int, error)
  if (.not. allocated(error)) call f%create_dataset("empty/val", [n_rows, 0], cr_h5_real, error)
  if (.not. allocated(error)) call f%write_block("empty/idx", ie, 0, error)
  if (.not. allocated(error)) call f%write_block("empty/val", re, 0, error)
  call check(.not. allocated(error), "write_block on empty datasets")
  call f%create_extendible("traj/step", [integer ::], cr_h5_int, error)
  do j = 1, 3
    call f%append("traj/step", 10 * j + env%rank, error)
  end do
  call check(.not. allocated(error), "append in parallel")
  ! a bad offset on one rank is reported on every rank (no hang)
  call f%write_block("basis/phi", mine, merge(ncols, off, env%rank == 0), error)
  if (nloc > 0 .or. env%size > 1) call check(allocated(error), "bad block fails on all ranks")
  ! round-robin columns: rank r owns columns r+1, r+1+P, ... (one range each, plus an empty one)
  call f%create_dataset("cyc/phi", [n_rows, n_cyc], cr_h5_real, error)
  nv = 0
  do j = env%rank + 1, n_cyc, env%size
    nv = nv + 1
  end do
  allocate(cyc(n_rows, nv), rg(2, nv + 1))
  rg(:, 1) = [0, 0]
  nv = 0
  dpart = digest_t()
  do j = env%rank + 1, n_cyc, env%size
    nv = nv + 1
    cyc(:, nv) = [(real(i * j, wp) / 3.0_wp - 1.0_wp, i = 1, n_rows)]
    rg(:, nv + 1) = [j - 1, 1]
    dpart = digest_add(dpart, digest_of(cyc(:, nv:nv), int(j - 1, i8) * n_rows))
  end do
  call f%write_ranges("cyc/phi", cyc, rg, error)
  call check(.not. allocated(error), "write_ranges (round-robin columns)")
  call digest_allreduce(env, dpart)
  call f%commit(error)
  call check(.not. allocated(error), "parallel commit")
  call check(file_exists(trim(fname)) .and. .not. file_exists(trim(fname) // ".partial"), &
    "renamed on every rank's view")

  ! read back: whole dataset on every rank, and a neighbour's block collectively
  call f%open(trim(fname), error, env)
  call check(.not. allocated(error), "parallel open")
  call f%read("basis/phi", whole, error)
  call check(.not. allocated(error), "read whole")
  call check(all(shape(whole) == [n_rows, ncols]), "whole shape")
  call check(all(whole == a), "whole dataset equals the global matrix exactly")
  peer = mod(env%rank + 1, env%size)
  pn = counts(peer)
  poff = sum(counts(0:peer-1))
  allocate(theirs(n_rows, pn))
  call f%read_block("basis/phi", theirs, poff, error)
  call check(.not. allocated(error), "read_block")
  call check(all(theirs == a(:, poff+1:poff+pn)), "neighbour block exact")
  call f%read_block("empty/idx", ie, 0, error)
  if (.not. allocated(error)) call f%read_block("empty/val", re, 0, error)
  call check(.not. allocated(error), "read_block on empty datasets")
  call f%read_block("empty/idx", ione, 0, error)
  call check(allocated(error), "read_block of one entry from an empty dataset fails on every rank")
  call f%read("basis/owner", iall, error)
  do r = 0, env%size - 1
    do j = sum(counts(0:r-1)) + 1, sum(counts(0:r))
      call check(iall(1, j) == r .and. iall(2, j) == j, "integer blocks: owner and column")
    end do
  end do
  call f%read("meta/rank0", v, error)
  call check(all(v == [0.0_wp, 1.5_wp]), "whole write came from rank 0")
  call f%read("config", s, error); call check(s == "&output path='x' /", "string")
  call f%read_attr("/", "n_ranks_written", nv, error); call check(nv == env%size, "attr")
  call f%read("traj/step", steps, error)
  call check(all(steps == [10, 20, 30]), "appends came from rank 0")
  call f%read("cyc/phi", cycall, error)
  call check(.not. allocated(error), "read cyc")
  do j = 1, n_cyc
    call check(all(cycall(:, j) == [(real(i * j, wp) / 3.0_wp - 1.0_wp, i = 1, n_rows)]), &
      "write_ranges: every column where it belongs")
  end do
  dwhole = digest_of(cycall, 0_i8)
  call check(digest_hex(dpart) == digest_hex(dwhole), "digest: the ranks' parts add up to the whole")
  tmp = cycall
  tmp(3, 5) = nearest(tmp(3, 5), 1.0_wp)
  call check(digest_hex(digest_of(tmp, 0_i8)) /= digest_hex(dwhole), "digest: one changed bit is seen")
  tmp = cycall
  tmp(:, 2) = cycall(:, 7); tmp(:, 7) = cycall(:, 2)
  call check(digest_hex(digest_of(tmp, 0_i8)) /= digest_hex(dwhole), "digest: swapped columns are seen")
  call f%close(error)
  call check(.not. allocated(error), "parallel close")

  call env%free()
  call test_summary(env%rank)
  call MPI_Finalize(ierr)
end program test_h5file_mpi
