!> Working precision and integer kinds used throughout crowdrom.
module cr_kinds
  use, intrinsic :: iso_fortran_env, only: real64, int32, int64
  implicit none
  private
  public :: wp, i4, i8

  !> working real kind (double precision)
  integer, parameter :: wp = real64
  !> default and long integer kinds
  integer, parameter :: i4 = int32, i8 = int64
end module cr_kinds
