!> What every reader of an inter-stage product checks (the readers in src/products and the
!> hyper-reduction methods' stored data in src/hyper): the schema name and version
!> at the root, and the contents it reads (shapes against the attributes, indices in range,
!> finite values). Each check returns an input error (code 2) whose message names the file, the
!> dataset and the problem, e.g. "'db.h5': dataset 'contacts/ia': index 0 at position 3 outside
!> 1..40".
module cr_product_check
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_h5file, only: h5file_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: check_schema, need_finite, need_range, need_size, need_dims, need_attr_range, product_error

  !> Is every entry finite? (generic over rank 1 and 2)
  interface need_finite
    module procedure finite1, finite2
  end interface need_finite

contains

  !> Input error "'<path>': <what>" (code 2).
  subroutine product_error(path, what, error)
    character(len=*), intent(in) :: path, what
    type(error_t), allocatable, intent(out) :: error
    call set_error(error, "'" // path // "': " // what, EXIT_BAD_INPUT)
  end subroutine product_error

  !> Root attributes `schema` (must equal `schema`) and `schema_version` (must be one of
  !> `versions`); `what` names the product in messages ("snapshot database", "ROM file", ...).
  subroutine check_schema(h5, path, schema, versions, what, version, error)
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path, schema, what
    integer, intent(in) :: versions(:)
    integer, intent(out) :: version
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: got, list
    integer :: k
    version = 0
    call h5%read_attr("/", "schema", got, error)
    if (allocated(error)) then
      call product_error(path, "is not a " // what // " (no schema attribute)", error); return
    end if
    if (got /= schema) then
      call product_error(path, "is not a " // what // " (schema '" // got // "', expected '" // schema // "')", error)
      return
    end if
    call h5%read_attr("/", "schema_version", version, error)
    if (allocated(error)) then
      call product_error(path, what // " without a schema_version attribute", error); return
    end if
    if (any(versions == version)) return
    list = ""
    do k = 1, size(versions)
      if (k > 1) list = list // ", "
      list = list // str(versions(k))
    end do
    call product_error(path, what // " schema version " // str(version) // " is not supported (supported: " // &
      list // ")", error)
  end subroutine check_schema

  subroutine finite1(path, name, x, error)
    character(len=*), intent(in) :: path, name
    real(wp), intent(in) :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: i
    do i = 1, size(x)
      if (.not. ieee_is_finite(x(i))) then
        call product_error(path, "dataset '" // name // "': non-finite value at entry " // str(i), error); return
      end if
    end do
  end subroutine finite1

  subroutine finite2(path, name, x, error)
    character(len=*), intent(in) :: path, name
    real(wp), intent(in) :: x(:,:)
    type(error_t), allocatable, intent(out) :: error
    integer :: i, j
    do j = 1, size(x, 2)
      do i = 1, size(x, 1)
        if (.not. ieee_is_finite(x(i, j))) then
          call product_error(path, "dataset '" // name // "': non-finite value at (" // str(i) // ", " // str(j) // &
            ")", error); return
        end if
      end do
    end do
  end subroutine finite2

  !> Every entry of the integer dataset `name` lies in lo..hi.
  subroutine need_range(path, name, x, lo, hi, error)
    character(len=*), intent(in) :: path, name
    integer, intent(in) :: x(:), lo, hi
    type(error_t), allocatable, intent(out) :: error
    integer :: i
    do i = 1, size(x)
      if (x(i) < lo .or. x(i) > hi) then
        call product_error(path, "dataset '" // name // "': index " // str(x(i)) // " at position " // str(i) // &
          " outside " // str(lo) // ".." // str(hi), error); return
      end if
    end do
  end subroutine need_range

  !> The dataset `name` has n entries (as the attribute or dataset `by` says).
  subroutine need_size(path, name, got, n, by, error)
    character(len=*), intent(in) :: path, name, by
    integer, intent(in) :: got, n
    type(error_t), allocatable, intent(out) :: error
    if (got == n) return
    call product_error(path, "dataset '" // name // "' has " // str(got) // " entries, but " // by // " says " // &
      str(n), error)
  end subroutine need_size

  !> Dimensions of dataset `name` in the open file equal `expect` (read before allocating).
  subroutine need_dims(h5, path, name, expect, by, error)
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path, name, by
    integer(i8), intent(in) :: expect(:)
    type(error_t), allocatable, intent(out) :: error
    integer(i8), allocatable :: d(:)
    character(len=:), allocatable :: a, b
    integer :: k
    call h5%get_dims(name, d, error)
    if (allocated(error)) then
      call product_error(path, "dataset '" // name // "' missing or unreadable", error); return
    end if
    if (size(d) == size(expect)) then
      if (all(d == expect)) return
    end if
    a = ""; b = ""
    do k = 1, size(d)
      if (k > 1) a = a // " x "
      a = a // str(d(k))
    end do
    do k = 1, size(expect)
      if (k > 1) b = b // " x "
      b = b // str(expect(k))
    end do
    call product_error(path, "dataset '" // name // "' has dims " // a // ", but " // by // " gives " // b, error)
  end subroutine need_dims

  !> An integer attribute lies in lo..hi.
  subroutine need_attr_range(path, name, x, lo, hi, error)
    character(len=*), intent(in) :: path, name
    integer, intent(in) :: x, lo, hi
    type(error_t), allocatable, intent(out) :: error
    if (x >= lo .and. x <= hi) return
    call product_error(path, "attribute '" // name // "' = " // str(x) // " outside " // str(lo) // ".." // str(hi), error)
  end subroutine need_attr_range
end module cr_product_check
