!> File-system helpers (POSIX rename/remove through the C library) for atomic output.
module cr_fsys
  use, intrinsic :: iso_c_binding, only: c_int, c_char, c_null_char
  implicit none
  private
  public :: rename_file, remove_file, file_exists, make_dir, remove_dir, file_size

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
  end interface

contains

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
end module cr_fsys
