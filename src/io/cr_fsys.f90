!> File-system helpers (POSIX rename/remove through the C library) for atomic output.
module cr_fsys
  use, intrinsic :: iso_c_binding, only: c_int, c_char, c_null_char
  implicit none
  private
  public :: rename_file, remove_file, file_exists

  interface
    integer(c_int) function c_rename(old, new) bind(c, name="rename")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: old(*), new(*)
    end function c_rename
    integer(c_int) function c_remove(path) bind(c, name="remove")
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: path(*)
    end function c_remove
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
end module cr_fsys
