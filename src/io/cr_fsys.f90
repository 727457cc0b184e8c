!> File-system helpers (POSIX rename/remove through the C library) for atomic output, and the
!> block file `block_file_t` (POSIX pwrite of byte blocks at explicit offsets).
module cr_fsys
  use, intrinsic :: iso_c_binding, only: c_int, c_char, c_null_char, c_ptr, c_long, c_f_pointer, &
    c_associated, c_size_t, c_loc, c_intptr_t, c_null_ptr
  use cr_kinds, only: i8
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  implicit none
  private
  public :: rename_file, remove_file, file_exists, make_dir, remove_dir, file_size, truncate_file, &
    clear_errno, errno_text, io_fault_text, discard_fd, reserve_space, errno_name, truncate_to, &
    real_path, is_directory, dir_writable, dir_of, write_whole_file, same_file, block_file_t

  !> An existing file opened by one process for writing byte blocks at explicit offsets (POSIX
  !> open, pwrite, close: unbuffered, nothing collective). Several processes (e.g. the MPI ranks
  !> writing their samples into the snapshot database) may each open the same file and write
  !> disjoint blocks; a block is on the file when write_at returns, and visible to any later open.
  type :: block_file_t
    integer(c_int) :: fd = -1
    character(len=:), allocatable :: path
  contains
    procedure :: open => bf_open
    procedure :: write_at => bf_write_at
    procedure :: close => bf_close
  end type block_file_t

  interface
    integer(c_int) function c_rename(old, new) bind(c, name="rename")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: old(*), new(*)
    end function c_rename
    integer(c_int) function c_remove(path) bind(c, name="remove")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: path(*)
    end function c_remove
    integer(c_int) function c_mkdir(path, mode) bind(c, name="mkdir")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: path(*)
      integer(c_int), value :: mode
    end function c_mkdir
    integer(c_int) function c_rmdir(path) bind(c, name="rmdir")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: path(*)
    end function c_rmdir
    integer(c_int) function c_truncate(path, length) bind(c, name="truncate")
      import :: c_int, c_char, c_long
      character(kind=c_char), intent(in) :: path(*)
      integer(c_long), value :: length
    end function c_truncate
    type(c_ptr) function c_errno_location() bind(c, name="__errno_location")
      import :: c_ptr
    end function c_errno_location
    type(c_ptr) function c_strerror(errnum) bind(c, name="strerror")
      import :: c_ptr, c_int
      integer(c_int), value :: errnum
    end function c_strerror
    integer(c_size_t) function c_strlen(s) bind(c, name="strlen")
      import :: c_ptr, c_size_t
      type(c_ptr), value :: s
    end function c_strlen
    type(c_ptr) function c_realpath(path, resolved) bind(c, name="realpath")
      import :: c_ptr, c_char
      character(kind=c_char), intent(in) :: path(*)
      character(kind=c_char), intent(out) :: resolved(*)
    end function c_realpath
    integer(c_int) function c_access(path, mode) bind(c, name="access")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: path(*)
      integer(c_int), value :: mode
    end function c_access
    integer(c_int) function c_open(path, flags) bind(c, name="open")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: path(*)
      integer(c_int), value :: flags
    end function c_open
    integer(c_int) function c_fallocate(fd, mode, offset, length) bind(c, name="fallocate")
      import :: c_int, c_long
      integer(c_int), value :: fd, mode
      integer(c_long), value :: offset, length
    end function c_fallocate
    integer(c_int) function c_stat(path, buf) bind(c, name="stat")
      import :: c_int, c_char, c_long
      character(kind=c_char), intent(in) :: path(*)
      integer(c_long), intent(out) :: buf(*)
    end function c_stat
    integer(c_int) function c_memfd_create(name, flags) bind(c, name="memfd_create")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: name(*)
      integer(c_int), value :: flags
    end function c_memfd_create
    integer(c_int) function c_dup2(old, new) bind(c, name="dup2")
      import :: c_int
      integer(c_int), value :: old, new
    end function c_dup2
    integer(c_int) function c_close(fd) bind(c, name="close")
      import :: c_int
      integer(c_int), value :: fd
    end function c_close
    integer(c_long) function c_pwrite(fd, buf, n, offset) bind(c, name="pwrite")
      import :: c_int, c_long, c_size_t, c_ptr
      integer(c_int), value :: fd
      type(c_ptr), value :: buf
      integer(c_size_t), value :: n
      integer(c_long), value :: offset
    end function c_pwrite
  end interface

contains

  !> Reserve disk blocks for the first `nbytes` of an existing file without changing its size
  !> (fallocate with FALLOC_FL_KEEP_SIZE), so that later writes in that range cannot fail
  !> for want of space. 0 on success, else the errno (28: no space; 95: not supported by the
  !> file system, the caller then goes on without a reservation).
  integer function reserve_space(path, nbytes) result(status)
    character(len=*), intent(in) :: path
    integer(8), intent(in) :: nbytes
    integer(c_int) :: fd, e
    integer(c_int), pointer :: err
    call c_f_pointer(c_errno_location(), err)
    fd = c_open(path // c_null_char, 1_c_int)
    if (fd < 0) then
      status = int(err); return
    end if
    err = 0
    status = 0
    if (c_fallocate(fd, 1_c_int, 0_c_long, int(max(nbytes, 1_8), c_long)) /= 0) status = int(err)
    e = c_close(fd)
  end function reserve_space

  !> Write `text` as the whole content of `path` (replaced), and make sure it is on disk: the
  !> space is reserved first (a full disk is an error here, not a silently empty file: the
  !> Fortran runtime does not report a failed flush at close), and the size is checked after
  !> closing. `message` is "" on success, else why it failed.
  subroutine write_whole_file(path, text, message)
    character(len=*), intent(in) :: path, text
    character(len=:), allocatable, intent(out) :: message
    integer :: u, ios, status
    character(len=256) :: msg
    message = ""
    open(newunit=u, file=path, status="replace", action="write", access="stream", form="unformatted", &
      iostat=ios, iomsg=msg)
    if (ios /= 0) then
      message = "cannot create '" // path // "' (" // trim(msg) // ")"; return
    end if
    status = reserve_space(path, int(len(text), 8))
    if (status == 28 .or. status == 122 .or. status == 27) then
      close(u, status="delete")
      message = "cannot write '" // path // "': " // errno_name(status); return
    end if
    write(u, iostat=ios, iomsg=msg) text
    if (ios == 0) then
      close(u, iostat=ios, iomsg=msg)
    else
      close(u, status="delete")
    end if
    if (ios /= 0) then
      message = "cannot write '" // path // "' (" // trim(msg) // ")"; status = remove_file(path); return
    end if
    if (file_size(path) /= len(text)) then
      message = "cannot write '" // path // "': only " // itoa8(file_size(path)) // " of " // &
        itoa8(int(len(text), 8)) // " bytes reached the disk"
      status = remove_file(path)
    end if
  contains
    function itoa8(i) result(s)
      integer(8), intent(in) :: i
      character(len=:), allocatable :: s
      character(len=24) :: b
      write(b, '(i0)') i
      s = trim(b)
    end function itoa8
  end subroutine write_whole_file

  !> True if both paths exist and are the same file (same device and inode: also through a
  !> hard link). Linux (x86_64, aarch64): st_dev and st_ino are the first two 8-byte fields
  !> of struct stat.
  logical function same_file(a, b)
    character(len=*), intent(in) :: a, b
    integer(c_long) :: sa(32), sb(32)
    same_file = .false.
    sa = 0; sb = 0
    if (c_stat(a // c_null_char, sa) /= 0) return
    if (c_stat(b // c_null_char, sb) /= 0) return
    same_file = sa(1) == sb(1) .and. sa(2) == sb(2)
  end function same_file

  !> Truncate (or extend with a hole) a file to `n` bytes; 0 on success.
  integer function truncate_to(path, n) result(status)
    character(len=*), intent(in) :: path
    integer(8), intent(in) :: n
    status = -1
    if (n < 0) return
    status = int(c_truncate(path // c_null_char, int(n, c_long)))
  end function truncate_to

  !> strerror text of an errno value.
  function errno_name(code) result(s)
    integer, intent(in) :: code
    character(len=:), allocatable :: s
    integer(c_int), pointer :: e
    integer(c_int) :: saved
    call c_f_pointer(c_errno_location(), e)
    saved = e
    e = int(code, c_int)
    s = errno_text()
    e = saved
  end function errno_name

  !> Point the open file descriptor `fd` at an anonymous in-memory file, so that whatever is
  !> still written through it (a library flushing its caches while closing a file that is
  !> being abandoned, e.g. on a full disk) succeeds and is thrown away. 0 on success.
  integer function discard_fd(fd) result(status)
    integer(c_int), intent(in) :: fd
    integer(c_int) :: mfd
    status = -1
    if (fd < 0) return
    mfd = c_memfd_create("crowdrom-discarded-output" // c_null_char, 0_c_int)
    if (mfd < 0) return
    if (c_dup2(mfd, fd) < 0) then
      status = int(c_close(mfd)); status = -1; return
    end if
    status = int(c_close(mfd))
    status = 0
  end function discard_fd

  !> Truncate a file to zero bytes (frees its blocks); 0 on success.
  integer function truncate_file(path) result(status)
    character(len=*), intent(in) :: path
    status = int(c_truncate(path // c_null_char, 0_c_long))
  end function truncate_file

  !> Set the C errno to 0 (before a call whose failure reason is wanted).
  subroutine clear_errno()
    integer(c_int), pointer :: e
    call c_f_pointer(c_errno_location(), e)
    e = 0
  end subroutine clear_errno

  !> The system's reason for the last failed call (strerror(errno)), "" when errno is 0.
  function errno_text() result(s)
    character(len=:), allocatable :: s
    integer(c_int), pointer :: e
    type(c_ptr) :: p
    character(kind=c_char), pointer :: chars(:)
    integer :: n, k
    call c_f_pointer(c_errno_location(), e)
    s = ""
    if (e == 0) return
    p = c_strerror(e)
    if (.not. c_associated(p)) return
    n = int(c_strlen(p))
    call c_f_pointer(p, chars, [n])
    deallocate(s)
    allocate(character(len=n) :: s)
    do k = 1, n
      s(k:k) = chars(k)
    end do
  end function errno_text

  !> errno_text() when errno holds a storage fault (no space, quota, read-only file system,
  !> permission, I/O error, file too large, is a directory, not a directory), else "". Used
  !> to say why a write failed; other codes may be left over from unrelated calls.
  function io_fault_text() result(s)
    character(len=:), allocatable :: s
    integer(c_int), pointer :: e
    call c_f_pointer(c_errno_location(), e)
    s = ""
    select case (e)
    case (28, 122, 30, 13, 5, 27, 21, 20, 1)
      s = errno_text()
    end select
  end function io_fault_text

  !> Canonical absolute path (symbolic links, '.' and '..' resolved) of an existing file or
  !> directory; "" if it cannot be resolved (missing, or a component is not searchable).
  function real_path(path) result(s)
    character(len=*), intent(in) :: path
    character(len=:), allocatable :: s
    character(kind=c_char) :: buf(4097)
    integer :: n
    s = ""
    if (len(path) == 0) return
    buf = c_null_char
    if (.not. c_associated(c_realpath(path // c_null_char, buf))) return
    n = 0
    do while (n < size(buf))
      if (buf(n + 1) == c_null_char) exit
      n = n + 1
    end do
    deallocate(s)
    allocate(character(len=n) :: s)
    s = transfer(buf(1:n), s)
  end function real_path

  !> True if `path` is an existing directory.
  logical function is_directory(path)
    character(len=*), intent(in) :: path
    inquire(file=path // "/.", exist=is_directory)
  end function is_directory

  !> True if the directory `path` allows creating files (access W_OK and X_OK).
  logical function dir_writable(path)
    character(len=*), intent(in) :: path
    dir_writable = c_access(path // c_null_char, 3_c_int) == 0
  end function dir_writable

  !> Directory part of a path ("." when there is none; "/" for a file in the root).
  function dir_of(path) result(d)
    character(len=*), intent(in) :: path
    character(len=:), allocatable :: d
    integer :: k
    k = index(path, "/", back=.true.)
    if (k == 0) then
      d = "."
    else if (k == 1) then
      d = "/"
    else
      d = path(1:k-1)
    end if
  end function dir_of

  !> Atomically rename old -> new (replacing new if it exists, POSIX rename); 0 on success.
  integer function rename_file(old, new) result(status)
    character(len=*), intent(in) :: old, new
    status = int(c_rename(old // c_null_char, new // c_null_char))
  end function rename_file

  !> Delete a file; 0 on success (non-zero if it did not exist).
  integer function remove_file(path) result(status)
    character(len=*), intent(in) :: path
    status = int(c_remove(path // c_null_char))
  end function remove_file

  !> True if a file of this name exists.
  logical function file_exists(path)
    character(len=*), intent(in) :: path
    inquire(file=path, exist=file_exists)
  end function file_exists

  !> Create a directory (mode 0755); 0 on success or if it already exists as a directory.
  integer function make_dir(path) result(status)
    character(len=*), intent(in) :: path
    logical :: ex
    status = int(c_mkdir(path // c_null_char, int(o'755', c_int)))
    if (status /= 0) then
      inquire(file=path // "/.", exist=ex)
      if (ex) status = 0
    end if
  end function make_dir

  !> Remove an empty directory; 0 on success.
  integer function remove_dir(path) result(status)
    character(len=*), intent(in) :: path
    status = int(c_rmdir(path // c_null_char))
  end function remove_dir

  !> Size of a file in bytes (-1 if it does not exist).
  integer(8) function file_size(path)
    character(len=*), intent(in) :: path
    logical :: ex
    inquire(file=path, exist=ex, size=file_size)
    if (.not. ex) file_size = -1
  end function file_size

  !> Open the existing file `path` for block writes (this process only).
  subroutine bf_open(this, path, error)
    class(block_file_t), intent(inout) :: this
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    integer(c_int), parameter :: O_WRONLY = 1
    this%path = path
    call clear_errno()
    this%fd = c_open(path // c_null_char, O_WRONLY)
    if (this%fd < 0) call set_error(error, "cannot open '" // path // "' for writing: " // errno_text())
  end subroutine bf_open

  !> Write nbytes bytes of buf at byte offset `offset` of the file (blocks written by several
  !> processes must not overlap). A failure (e.g. no space left) is an error naming the sizes
  !> and the system's reason.
  subroutine bf_write_at(this, offset, buf, nbytes, error)
    class(block_file_t), intent(inout) :: this
    integer(i8), intent(in) :: offset, nbytes
    type(*), intent(in), target :: buf(*)
    type(error_t), allocatable, intent(out) :: error
    integer(c_long) :: got
    integer(c_intptr_t) :: base
    integer(c_int), pointer :: e
    integer(i8) :: done
    integer :: tries
    if (nbytes <= 0) return
    if (this%fd < 0) then
      call set_error(error, "write to '" // this%path // "': the file is not open"); return
    end if
    call c_f_pointer(c_errno_location(), e)
    base = transfer(c_loc(buf), base)
    done = 0
    tries = 0
    ! the rest of a short write is written again (a full disk then says so); a write interrupted
    ! before it wrote anything (EINTR) is repeated
    do while (done < nbytes)
      e = 0
      got = c_pwrite(this%fd, transfer(base + int(done, c_intptr_t), c_null_ptr), int(nbytes - done, c_size_t), &
        int(offset + done, c_long))
      if (got < 0 .and. e == 4 .and. tries < 100) then
        tries = tries + 1
        cycle
      end if
      if (got <= 0) then
        if (got == 0 .and. e == 0) then
          call set_error(error, "write of " // str(nbytes) // " bytes at offset " // str(offset) // " of '" // &
            this%path // "' wrote only " // str(done) // " bytes (disk full?)")
        else
          call set_error(error, "write of " // str(nbytes) // " bytes at offset " // str(offset) // " of '" // &
            this%path // "' failed: " // errno_text())
        end if
        return
      end if
      done = done + int(got, i8)
    end do
  end subroutine bf_write_at

  !> Close the file (a failure, e.g. a write the system could only report now, is an error).
  subroutine bf_close(this, error)
    class(block_file_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    if (this%fd < 0) return
    call clear_errno()
    if (c_close(this%fd) /= 0) call set_error(error, "closing '" // this%path // "' failed: " // errno_text())
    this%fd = -1
  end subroutine bf_close
end module cr_fsys
