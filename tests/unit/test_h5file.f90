!> Serial round trips of cr_h5file: every dataset type, attributes, extendible appends, blocks,
!> atomic commit/abort, and the error messages of the bad paths.
program test_h5file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_fsys, only: file_exists, remove_file
  use cr_h5file, only: h5file_t, cr_h5_real, cr_h5_int, cr_h5_int64
  implicit none
  type(h5file_t) :: f
  type(error_t), allocatable :: error
  real(wp) :: r0, r0b
  real(wp), allocatable :: r1(:), r2(:,:), r3(:,:,:), r1b(:), r2b(:,:), r3b(:,:,:), blk(:,:)
  integer :: i0, i0b, k, status
  integer, allocatable :: i1(:), i2(:,:), i1b(:), i2b(:,:), empty(:)
  integer(i8), allocatable :: l1(:), l1b(:), dims(:)
  character(len=:), allocatable :: s, sb
  real(wp), allocatable :: stream(:,:), col(:)
  integer, allocatable :: ia(:)
  integer(i8), allocatable :: offs(:)

  status = remove_file("rt.h5"); status = remove_file("rt.h5.partial")
  status = remove_file("ab.h5"); status = remove_file("ab.h5.partial")
  status = remove_file("inplace.h5")

  ! ---- reference data (values that do not survive a float conversion bit-for-bit if mangled)
  r0 = acos(-1.0_wp)
  r1 = [(1.0_wp / real(k, wp), k = 1, 7)]
  allocate(r2(4, 3), r3(2, 3, 4))
  r2 = reshape([(sqrt(real(k, wp)) * 1e-3_wp, k = 1, 12)], [4, 3])
  r3 = reshape([(real(k, wp)**3 - 1.0e10_wp, k = 1, 24)], [2, 3, 4])
  r3(1, 1, 1) = -huge(1.0_wp); r3(2, 1, 1) = tiny(1.0_wp)
  i0 = -123456789
  i1 = [(k * 7 - 30, k = 1, 9)]
  i2 = reshape([(k * (-1)**k, k = 1, 10)], [5, 2])
  l1 = [huge(1_i8), -huge(1_i8), 0_i8, 2_i8**40 + 3]
  allocate(empty(0))
  s = 'config: &scene n = 3 / "quoted" \ back' // new_line('a') // 'line 2  '

  ! ---- write a temporary file
  call f%create("rt.h5", error)
  call check(.not. allocated(error), "create")
  call check(file_exists("rt.h5.partial") .and. .not. file_exists("rt.h5"), &
    "create writes only the .partial temporary")
  call f%write("scalars/r0", r0, error); call check(.not. allocated(error), "write real0")
  call f%write("scalars/i0", i0, error); call check(.not. allocated(error), "write int0")
  call f%write("r1", r1, error); call check(.not. allocated(error), "write real1")
  call f%write("traj/positions", r2, error); call check(.not. allocated(error), "write real2")
  call f%write("r3", r3, error); call check(.not. allocated(error), "write real3")
  call f%write("i1", i1, error); call check(.not. allocated(error), "write int1")
  call f%write("i2", i2, error); call check(.not. allocated(error), "write int2")
  call f%write("l1", l1, error); call check(.not. allocated(error), "write int64")
  call f%write("empty", empty, error); call check(.not. allocated(error), "write empty int1")
  call f%write("config", s, error); call check(.not. allocated(error), "write string")
  ! overwrite with the same shape (reuse) and a different shape (replace)
  call f%write("i1", i1, error); call check(.not. allocated(error), "rewrite same shape")
  call f%write("r1", [r1, 9.0_wp], error); call check(.not. allocated(error), "rewrite new shape")
  call f%write("r1", r1, error); call check(.not. allocated(error), "rewrite back")

  call f%make_group("a/b/c", error); call check(.not. allocated(error), "nested group")
  call f%make_group("a/b", error); call check(.not. allocated(error), "existing group is fine")
  call check(f%exists("a/b/c") .and. f%exists("/a/b") .and. f%exists("traj/positions"), "exists")
  call check(.not. f%exists("a/x/c") .and. .not. f%exists("nope"), "not exists")

  call f%write_attr("/", "schema", "crowdrom-test", error); call check(.not. allocated(error), "attr str")
  call f%write_attr("", "schema_version", 1, error); call check(.not. allocated(error), "attr int")
  call f%write_attr("/", "dt", 0.05_wp, error); call check(.not. allocated(error), "attr real")
  call f%write_attr("traj/positions", "domain", [-1.0_wp, 0.5_wp, 3.25_wp], error)
  call check(.not. allocated(error), "attr real array on a dataset")
  call f%write_attr("a/b", "counts", [3, 4], error); call check(.not. allocated(error), "attr int array")
  call f%write_attr("/", "schema_version", 2, error); call check(.not. allocated(error), "attr replace")
  call f%write_attr("nope", "x", 1, error)
  call check(allocated(error), "attr on missing object fails")

  ! ---- extendible datasets: 5 steps of a [6, *] stream, 1D contact stream, scalar streams
  call f%create_extendible("traj/stream", [6], cr_h5_real, error)
  call check(.not. allocated(error), "create_extendible real [6,*]")
  call f%create_extendible("traj/contacts/ia", [integer ::], cr_h5_int, error)
  call check(.not. allocated(error), "create_extendible int 1D")
  call f%create_extendible("traj/contacts/offset", [integer ::], cr_h5_int64, error)
  call check(.not. allocated(error), "create_extendible int64 1D")
  call f%create_extendible("traj/time", [integer ::], cr_h5_real, error, chunk=2)
  call check(.not. allocated(error), "create_extendible with chunk")
  allocate(stream(6, 5))
  call f%append("traj/contacts/offset", 0_i8, error)
  do k = 1, 5
    stream(:, k) = [(real(100 * k + i0b, wp) / 3.0_wp, i0b = 1, 6)]
    col = stream(:, k)
    call f%append("traj/stream", col, error); call check(.not. allocated(error), "append column")
    call f%append("traj/time", 0.1_wp * k, error); call check(.not. allocated(error), "append scalar")
    ia = [(k * 10 + i0b, i0b = 1, mod(k, 3))]      ! 1, 2, 0, 1, 2 contacts
    call f%append("traj/contacts/ia", ia, error); call check(.not. allocated(error), "append block")
    call f%append("traj/contacts/offset", int(k, i8), error)
  end do
  call f%append("traj/stream", [1.0_wp, 2.0_wp], error)
  call check(allocated(error), "append with wrong row shape fails")
  if (allocated(error)) call check(index(error%message, "traj/stream") > 0, "append message names dataset")
  call f%append("r1", 1.0_wp, error)
  call check(allocated(error), "append to a fixed dataset fails")

  ! ---- serial hyperslab blocks
  call f%create_dataset("basis", [7, 5], cr_h5_real, error)
  call check(.not. allocated(error), "create_dataset")
  allocate(blk(7, 5))
  blk = reshape([(real(k, wp) * 0.25_wp, k = 1, 35)], [7, 5])
  call f%write_block("basis", blk(:, 1:2), 0, error); call check(.not. allocated(error), "write_block 1")
  call f%write_block("basis", blk(:, 3:5), 2, error); call check(.not. allocated(error), "write_block 2")
  call f%write_block("basis", blk(:, 4:5), 4, error)
  call check(allocated(error), "write_block out of bounds fails")

  call f%commit(error)
  call check(.not. allocated(error), "commit")
  call check(file_exists("rt.h5") .and. .not. file_exists("rt.h5.partial"), "commit renames")

  ! ---- read back and compare exactly
  call f%open("rt.h5", error)
  call check(.not. allocated(error), "open")
  call f%read("scalars/r0", r0b, error); call check(r0b == r0, "read real0")
  call f%read("scalars/i0", i0b, error); call check(i0b == i0, "read int0")
  call f%read("r1", r1b, error); call check(all(r1b == r1) .and. size(r1b) == 7, "read real1")
  call f%read("traj/positions", r2b, error); call check(all(shape(r2b) == [4, 3]), "real2 shape")
  call check(all(r2b == r2), "read real2")
  call f%read("r3", r3b, error); call check(all(shape(r3b) == [2, 3, 4]) .and. all(r3b == r3), "read real3")
  call f%read("i1", i1b, error); call check(all(i1b == i1), "read int1")
  call f%read("i2", i2b, error); call check(all(shape(i2b) == [5, 2]) .and. all(i2b == i2), "read int2")
  call f%read("l1", l1b, error); call check(all(l1b == l1), "read int64")
  call f%read("empty", i1b, error); call check(.not. allocated(error) .and. size(i1b) == 0, "read empty")
  call f%read("config", sb, error); call check(sb == s, "read string exactly (trailing blanks kept)")
  call f%get_dims("traj/positions", dims, error)
  call check(all(dims == [4_i8, 3_i8]), "get_dims Fortran order")
  call f%get_dims("scalars/r0", dims, error); call check(size(dims) == 0, "get_dims scalar")

  call f%read_attr("/", "schema", sb, error); call check(sb == "crowdrom-test", "read attr string")
  call f%read_attr("/", "schema_version", i0b, error); call check(i0b == 2, "read attr int (replaced)")
  call f%read_attr("", "dt", r0b, error); call check(r0b == 0.05_wp, "read attr real")
  call f%read_attr("traj/positions", "domain", r1b, error)
  call check(all(r1b == [-1.0_wp, 0.5_wp, 3.25_wp]), "read attr real array")
  call f%read_attr("a/b", "counts", i1b, error); call check(all(i1b == [3, 4]), "read attr int array")
  call f%read_attr("/", "missing_attr", i0b, error)
  call check(allocated(error), "missing attribute fails")
  if (allocated(error)) call check(index(error%message, "missing_attr") > 0, "attr message names it")

  call f%read("traj/stream", r2b, error)
  call check(all(shape(r2b) == [6, 5]) .and. all(r2b == stream), "extendible: 5 appended columns")
  call f%read("traj/time", r1b, error)
  call check(all(r1b == [(0.1_wp * k, k = 1, 5)]), "extendible scalar stream")
  call f%read("traj/contacts/ia", i1b, error)
  call check(all(i1b == [11, 21, 22, 41, 51, 52]), "extendible 1D blocks incl. empty step")
  call f%read("traj/contacts/offset", offs, error)
  call check(all(offs == [0_i8, 1_i8, 2_i8, 3_i8, 4_i8, 5_i8]), "extendible int64 stream")

  call f%read("basis", r2b, error); call check(all(r2b == blk), "blocks read whole")
  r2b = 0
  deallocate(r2b); allocate(r2b(7, 3))
  call f%read_block("basis", r2b, 1, error)
  call check(.not. allocated(error) .and. all(r2b == blk(:, 2:4)), "read_block columns 2..4")

  ! bad paths: missing dataset, wrong rank, wrong class, write on read-only
  call f%read("traj/nothing", r2b, error)
  call check(allocated(error), "missing dataset fails")
  if (allocated(error)) then
    call check(index(error%message, "traj/nothing") > 0 .and. index(error%message, "rt.h5") > 0, &
      "missing dataset message names dataset and file: " // error%message)
  end if
  call f%read("r3", r2b, error)
  call check(allocated(error), "wrong rank fails")
  if (allocated(error)) call check(index(error%message, "rank") > 0, "rank message")
  call f%read("i1", r1b, error)
  call check(allocated(error), "integer dataset read as real fails")
  call f%write("x", 1.0_wp, error)
  call check(allocated(error), "write on read-only file fails")
  call f%close(error); call check(.not. allocated(error), "close")
  call check(.not. f%is_open(), "closed")

  call f%open("does_not_exist.h5", error)
  call check(allocated(error), "open missing file fails")
  if (allocated(error)) call check(index(error%message, "does_not_exist.h5") > 0, &
    "open message names the file")

  ! ---- abort: an existing final file survives an aborted second write
  call f%create("rt.h5", error)
  call f%write("scalars/r0", -1.0_wp, error)
  call f%abort()
  call check(.not. file_exists("rt.h5.partial"), "abort deletes the temporary")
  call f%open("rt.h5", error)
  call check(.not. allocated(error), "old file still opens after abort")
  call f%read("scalars/r0", r0b, error); call check(r0b == r0, "old content intact after abort")
  call f%close(error)
  call f%create("ab.h5", error)
  call f%abort()
  call check(.not. file_exists("ab.h5") .and. .not. file_exists("ab.h5.partial"), &
    "abort leaves no file at all")

  ! ---- a create that fails leaves another writer's temporary alone (removing it would
  ! lose the first writer's work at its commit): the same output created twice,
  ! the second refused by HDF5 (the temporary is open), the first still commits
  block
    type(h5file_t) :: g
    call f%create("two.h5", error)
    call f%write("scalars/r0", 7.0_wp, error)
    call g%create("two.h5", error)
    call check(allocated(error), "a second create of an open temporary is refused")
    if (allocated(error)) deallocate(error)
    call check(file_exists("two.h5.partial"), "the refused create leaves the first writer's temporary")
    call f%commit(error)
    call check(.not. allocated(error) .and. file_exists("two.h5"), "the first writer still commits")
    if (allocated(error)) deallocate(error)
    call f%open("two.h5", error)
    call f%read("scalars/r0", r0b, error)
    call check(.not. allocated(error) .and. r0b == 7.0_wp, "the first writer's content is intact")
    call f%close(error)
    call check(remove_file("two.h5") == 0, "cleanup two.h5")
  end block

  ! ---- commit replaces an existing final file
  call f%create("rt.h5", error)
  call f%write("scalars/r0", 2.5_wp, error)
  call check(file_exists("rt.h5"), "old final file kept until commit")
  call f%commit(error)
  call f%open("rt.h5", error)
  call f%read("scalars/r0", r0b, error); call check(r0b == 2.5_wp, "commit replaced the old file")
  call check(.not. f%exists("r3"), "replaced file holds only new content")
  call f%close(error)

  ! ---- in place (resumable): visible at once, reopen read-write and append
  call f%create("inplace.h5", error, in_place=.true.)
  call check(file_exists("inplace.h5") .and. .not. file_exists("inplace.h5.partial"), "in_place")
  call f%create_extendible("done", [integer ::], cr_h5_int, error)
  call f%append("done", 1, error)
  call f%commit(error); call check(.not. allocated(error), "commit in place")
  call f%open("inplace.h5", error, readwrite=.true.)
  call f%append("done", 2, error); call check(.not. allocated(error), "append after reopen")
  call f%close(error)
  call f%open("inplace.h5", error)
  call f%read("done", i1b, error); call check(all(i1b == [1, 2]), "resumed stream")
  call f%close(error)

  call test_summary()
end program test_h5file
