!> Tiny JSON object writer for run summaries (flat or nested objects, pretty-printed).
!>
!> Usage:
!>   type(json_writer_t) :: js
!>   call js%add("n_agents", 40); call js%add("speedup", 12.5_wp)
!>   call js%begin_object("timings"); call js%add("fom", 1.2_wp); call js%end_object()
!>   call js%write_file("summary.json", error)
!> Keys and strings are escaped; non-finite reals are written as null. The file is written to
!> `path.partial` and renamed, so a reader never sees a half-written summary.
module cr_json
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_fsys, only: rename_file, write_whole_file, remove_file
  implicit none
  private
  public :: json_writer_t, json_escape

  integer, parameter :: max_depth = 32

  !> Accumulates one JSON object; `add` keys in order, nest with begin_object/end_object.
  type :: json_writer_t
    private
    character(len=:), allocatable :: buf
    integer :: depth = 0
    !> no member written yet at this level
    logical :: first(0:max_depth) = .true.
    !> begin_object beyond max_depth or end_object without begin_object
    logical :: misuse = .false.
  contains
    procedure :: reset
    procedure, private :: add_string, add_int, add_int8, add_real, add_logical, add_real_array, &
      add_int_array
    generic :: add => add_string, add_int, add_int8, add_real, add_logical, add_real_array, &
      add_int_array
    procedure :: begin_object
    procedure :: end_object
    procedure :: to_string
    procedure :: write_file
  end type json_writer_t

contains

  !> JSON string literal of s (with quotes), escaping quotes, backslashes and control characters.
  pure function json_escape(s) result(t)
    character(len=*), intent(in) :: s
    character(len=:), allocatable :: t
    character(len=*), parameter :: hex = "0123456789abcdef"
    integer :: k, c
    t = '"'
    do k = 1, len(s)
      c = iachar(s(k:k))
      select case (c)
      case (34)
        t = t // '\"'
      case (92)
        t = t // '\\'
      case (10)
        t = t // '\n'
      case (13)
        t = t // '\r'
      case (9)
        t = t // '\t'
      case (0:8, 11:12, 14:31)
        t = t // '\u00' // hex(c/16+1:c/16+1) // hex(mod(c, 16)+1:mod(c, 16)+1)
      case default
        t = t // s(k:k)
      end select
    end do
    t = t // '"'
  end function json_escape

  pure function real_text(x) result(s)
    real(wp), intent(in) :: x
    character(len=:), allocatable :: s
    character(len=40) :: b
    if (.not. ieee_is_finite(x)) then
      s = "null"
    else
      write(b, '(es25.16e3)') x
      s = trim(adjustl(b))
    end if
  end function real_text

  pure function int_text(i) result(s)
    integer(i8), intent(in) :: i
    character(len=:), allocatable :: s
    character(len=24) :: b
    write(b, '(i0)') i
    s = trim(b)
  end function int_text

  !> Clear the writer.
  subroutine reset(this)
    class(json_writer_t), intent(inout) :: this
    if (allocated(this%buf)) deallocate(this%buf)
    this%depth = 0
    this%first = .true.
    this%misuse = .false.
  end subroutine reset

  !> Start a member: separator, newline, indentation and the key.
  subroutine member(this, key)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key
    if (.not. allocated(this%buf)) this%buf = "{"
    if (.not. this%first(this%depth)) this%buf = this%buf // ","
    this%first(this%depth) = .false.
    this%buf = this%buf // new_line('a') // repeat("  ", this%depth + 1) // json_escape(key) &
      // ": "
  end subroutine member

  subroutine add_string(this, key, value)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key, value
    call member(this, key)
    this%buf = this%buf // json_escape(value)
  end subroutine add_string

  subroutine add_int(this, key, value)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key
    integer, intent(in) :: value
    call member(this, key)
    this%buf = this%buf // int_text(int(value, i8))
  end subroutine add_int

  subroutine add_int8(this, key, value)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key
    integer(i8), intent(in) :: value
    call member(this, key)
    this%buf = this%buf // int_text(value)
  end subroutine add_int8

  subroutine add_real(this, key, value)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key
    real(wp), intent(in) :: value
    call member(this, key)
    this%buf = this%buf // real_text(value)
  end subroutine add_real

  subroutine add_logical(this, key, value)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key
    logical, intent(in) :: value
    call member(this, key)
    if (value) then
      this%buf = this%buf // "true"
    else
      this%buf = this%buf // "false"
    end if
  end subroutine add_logical

  subroutine add_real_array(this, key, value)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key
    real(wp), intent(in) :: value(:)
    integer :: k
    call member(this, key)
    this%buf = this%buf // "["
    do k = 1, size(value)
      if (k > 1) this%buf = this%buf // ", "
      this%buf = this%buf // real_text(value(k))
    end do
    this%buf = this%buf // "]"
  end subroutine add_real_array

  subroutine add_int_array(this, key, value)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key
    integer, intent(in) :: value(:)
    integer :: k
    call member(this, key)
    this%buf = this%buf // "["
    do k = 1, size(value)
      if (k > 1) this%buf = this%buf // ", "
      this%buf = this%buf // int_text(int(value(k), i8))
    end do
    this%buf = this%buf // "]"
  end subroutine add_int_array

  !> Open a nested object under `key`; close it with end_object.
  subroutine begin_object(this, key)
    class(json_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: key
    if (this%depth >= max_depth) then
      this%misuse = .true.; return
    end if
    call member(this, key)
    this%buf = this%buf // "{"
    this%depth = this%depth + 1
    this%first(this%depth) = .true.
  end subroutine begin_object

  !> Close the innermost open object.
  subroutine end_object(this)
    class(json_writer_t), intent(inout) :: this
    if (this%depth <= 0) then
      this%misuse = .true.; return
    end if
    if (.not. this%first(this%depth)) then
      this%buf = this%buf // new_line('a') // repeat("  ", this%depth)
    end if
    this%buf = this%buf // "}"
    this%depth = this%depth - 1
  end subroutine end_object

  !> The complete document (root object closed), ending with a newline.
  function to_string(this) result(s)
    class(json_writer_t), intent(in) :: this
    character(len=:), allocatable :: s
    if (.not. allocated(this%buf)) then
      s = "{}" // new_line('a')
    else
      s = this%buf // new_line('a') // "}" // new_line('a')
    end if
  end function to_string

  !> Write the document to path.partial and rename it to path. Fails if objects are unbalanced.
  subroutine write_file(this, path, error)
    class(json_writer_t), intent(in) :: this
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: msg
    integer :: status
    if (this%depth /= 0 .or. this%misuse) then
      call set_error(error, "json: write '" // path // "': unbalanced begin_object/end_object")
      return
    end if
    call write_whole_file(path // ".partial", this%to_string(), msg)
    if (len(msg) > 0) then
      call set_error(error, "json: " // msg); return
    end if
    if (rename_file(path // ".partial", path) /= 0) then
      call set_error(error, "json: rename '" // path // ".partial' -> '" // path // "' failed")
      ! no temporary left behind
      status = remove_file(path // ".partial")
    end if
  end subroutine write_file
end module cr_json
