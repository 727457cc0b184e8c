!> The text of a namelist input file, read once on rank 0 and broadcast, then parsed
!> group by group from an internal file on every rank.
!>
!> Unknown group names (a misspelt `&agent` for `&agents`) are rejected, so that a group
!> is never silently ignored.
module cr_namelist_text
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_env, only: env_t
  use cr_strings, only: to_lower, str
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: namelist_text_t, MAX_LINE
  !> shared by every group reader: the read status, the echo of values (exact round trip)
  public :: nml_status, echo_real, echo_reals, echo_logical

  integer, parameter :: MAX_LINE = 1024

  !> Lines of one namelist file.
  type :: namelist_text_t
    !> path of the file (for messages)
    character(len=:), allocatable :: path
    !> the whole file as one string with newline separators
    character(len=:), allocatable :: text
    !> the file as records for internal-file namelist reads [n_lines]
    character(len=MAX_LINE), allocatable :: lines(:)
  contains
    procedure :: load
    procedure :: set_text
    procedure :: has_group
    procedure :: check_groups
    procedure :: require_groups
  end type namelist_text_t

contains

  !> Rank 0 reads `path`; the text is broadcast to every rank of `env`.
  subroutine load(this, path, env, error)
    class(namelist_text_t), intent(inout) :: this
    character(len=*), intent(in) :: path
    type(env_t), intent(in) :: env
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: status
    integer :: unit, ios, n_line
    character(len=MAX_LINE) :: line
    character(len=256) :: msg
    this%path = path
    n_line = 0
    status = ""
    this%text = ""
    if (env%is_root()) then
      open(newunit=unit, file=path, status='old', action='read', iostat=ios, iomsg=msg)
      if (ios /= 0) then
        status = path // ": cannot open input file (" // trim(msg) // ")"
      else
        do
          read(unit, '(a)', iostat=ios) line
          if (ios /= 0) exit
          n_line = n_line + 1
          if (has_binary(line)) then
            status = path // ": not a namelist file (binary data on line " // str(n_line) // &
              "): no namelist group can be read from it"
            exit
          end if
          if (len_trim(line) >= MAX_LINE - 1) then
            status = path // ": a line is longer than " // "1000 characters"
            exit
          end if
          this%text = this%text // trim(line) // new_line('a')
        end do
        close(unit)
      end if
    end if
    call env%bcast(status, error)
    if (allocated(error)) return
    if (len(status) > 0) then
      call set_error(error, status, EXIT_BAD_INPUT); return
    end if
    call env%bcast(this%text, error)
    if (allocated(error)) return
    call this%set_text(path, this%text)
  end subroutine load

  !> Take the namelist text from a string (e.g. the effective configuration stored in an
  !> HDF5 attribute); `path` names its origin in messages.
  subroutine set_text(this, path, text)
    class(namelist_text_t), intent(inout) :: this
    character(len=*), intent(in) :: path, text
    integer :: k, n, nl, i0
    character(len=:), allocatable :: copy
    copy = text
    if (len(copy) > 0) then
      if (copy(len(copy):len(copy)) /= new_line('a')) copy = copy // new_line('a')
    end if
    this%path = path
    this%text = copy
    nl = 0
    do k = 1, len(copy)
      if (copy(k:k) == new_line('a')) nl = nl + 1
    end do
    if (allocated(this%lines)) deallocate(this%lines)
    allocate(this%lines(max(nl, 1)))
    this%lines = ""
    n = 0; i0 = 1
    do k = 1, len(copy)
      if (copy(k:k) == new_line('a')) then
        n = n + 1
        this%lines(n) = copy(i0:k-1)
        i0 = k + 1
      end if
    end do
  end subroutine set_text

  !> True if the file contains the group `&name` (case-insensitive, outside comments).
  logical function has_group(this, name)
    class(namelist_text_t), intent(in) :: this
    character(len=*), intent(in) :: name
    character(len=:), allocatable :: groups(:)
    integer :: k
    call list_groups(this, groups)
    has_group = .false.
    do k = 1, size(groups)
      if (trim(groups(k)) == to_lower(name)) has_group = .true.
    end do
  end function has_group

  !> Error if the file has a group not in `known` or the same group twice.
  subroutine check_groups(this, known, error)
    class(namelist_text_t), intent(in) :: this
    character(len=*), intent(in) :: known(:)
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: groups(:)
    character(len=:), allocatable :: list
    integer :: k, j, bare
    logical :: found
    call list_groups(this, groups, bare)
    if (bare > 0) then
      call set_error(error, this%path // ": line " // str(bare) // ": '&' without a group name (a group " // &
        "starts with &name, e.g. &scene)", EXIT_BAD_INPUT)
      return
    end if
    do k = 1, size(groups)
      found = .false.
      do j = 1, size(known)
        if (trim(groups(k)) == to_lower(trim(known(j)))) found = .true.
      end do
      if (.not. found) then
        list = ""
        do j = 1, size(known)
          list = list // " &" // trim(known(j))
        end do
        call set_error(error, this%path // ": unknown namelist group &" // trim(groups(k)) // &
          " (known groups:" // list // ")", EXIT_BAD_INPUT)
        return
      end if
      do j = 1, k - 1
        if (groups(j) == groups(k)) then
          call set_error(error, this%path // ": namelist group &" // trim(groups(k)) // &
            " appears twice", EXIT_BAD_INPUT)
          return
        end if
      end do
    end do
  end subroutine check_groups

  !> Error unless the file holds every group in `needed` (the groups without which `program`
  !> has nothing to run: defaults are only for variables left out of a group that is present).
  !> The message names the file, the missing groups, what the program reads and, for a file
  !> with none of them, what the file holds (nothing: empty or not a namelist; or the groups
  !> of another program). Groups not in `known` are refused first (check_groups), unless the
  !> file holds none of the needed groups (then that is the better message).
  subroutine require_groups(this, program, needed, known, error)
    class(namelist_text_t), intent(in) :: this
    !> program name for the message, e.g. 'crowd_fom'
    character(len=*), intent(in) :: program
    !> groups the program cannot run without (lower case, no '&')
    character(len=*), intent(in) :: needed(:)
    !> every group a crowdrom input may hold
    character(len=*), intent(in) :: known(:)
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: groups(:), holds
    character(len=64) :: missing(size(needed))
    integer :: k, n_missing
    call list_groups(this, groups)
    n_missing = 0
    do k = 1, size(needed)
      if (.not. any(groups == to_lower(trim(needed(k))))) then
        n_missing = n_missing + 1
        missing(n_missing) = to_lower(trim(needed(k)))
      end if
    end do
    if (n_missing < size(needed)) then
      call this%check_groups(known, error)
      if (allocated(error)) return
    end if
    if (n_missing == 0) return
    holds = ""
    if (size(groups) == 0) then
      holds = "; the file holds no namelist group: it is empty or not a namelist file"
    else if (n_missing == size(needed)) then
      holds = "; the file holds only " // group_list(groups) // ": is it the input of another program?"
    end if
    if (n_missing == 1) then
      call set_error(error, this%path // ": namelist group " // group_list(missing(1:1)) // " is missing (" // &
        program // " needs " // group_list(needed) // holds // ")", EXIT_BAD_INPUT)
    else
      call set_error(error, this%path // ": namelist groups " // group_list(missing(1:n_missing)) // &
        " are missing (" // program // " needs " // group_list(needed) // holds // ")", EXIT_BAD_INPUT)
    end if
  end subroutine require_groups

  !> "&a, &b, &c" from a list of group names.
  pure function group_list(names) result(s)
    character(len=*), intent(in) :: names(:)
    character(len=:), allocatable :: s
    integer :: k
    s = ""
    do k = 1, size(names)
      if (k > 1) s = s // ", "
      s = s // "&" // trim(names(k))
    end do
  end function group_list

  !> True if the line holds control characters other than tab, carriage return and form feed
  !> (a binary file read as text).
  pure logical function has_binary(line)
    character(len=*), intent(in) :: line
    integer :: i, c
    has_binary = .false.
    do i = 1, len(line)
      c = iachar(line(i:i))
      if (c < 32 .and. c /= 9 .and. c /= 12 .and. c /= 13) then
        has_binary = .true.; return
      end if
      if (c == 127) then
        has_binary = .true.; return
      end if
    end do
  end function has_binary

  !> Names (lower case) of the groups opened with '&' at the start of a token; `bare`: the
  !> line of the first '&' followed by no name (0: none).
  subroutine list_groups(this, groups, bare)
    type(namelist_text_t), intent(in) :: this
    character(len=:), allocatable, intent(out) :: groups(:)
    integer, intent(out), optional :: bare
    character(len=64) :: found(200)
    integer :: n, k, i, j
    character(len=MAX_LINE) :: line
    logical :: in_str
    character :: q
    n = 0
    if (present(bare)) bare = 0
    do k = 1, size(this%lines)
      line = this%lines(k)
      in_str = .false.; q = ' '
      i = 1
      do while (i <= len_trim(line))
        if (in_str) then
          if (line(i:i) == q) in_str = .false.
        else if (line(i:i) == '"' .or. line(i:i) == "'") then
          in_str = .true.; q = line(i:i)
        else if (line(i:i) == '!') then
          exit
        else if (line(i:i) == '&') then
          j = i + 1
          do while (j <= len_trim(line))
            if (index('abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_', line(j:j)) == 0) exit
            j = j + 1
          end do
          if (j == i + 1 .and. present(bare)) then
            if (bare == 0) bare = k
          end if
          if (j > i + 1 .and. n < size(found)) then
            n = n + 1
            found(n) = to_lower(line(i+1:j-1))
          end if
          i = j - 1
        end if
        i = i + 1
      end do
    end do
    allocate(character(len=64) :: groups(n))
    groups = found(1:n)
  end subroutine list_groups
  !> Error of a namelist read of `group` (iostat ios, iomsg msg) naming the file, the group and
  !> what the compiler says (e.g. the variable); an absent group keeps its defaults.
  subroutine nml_status(t, group, ios, msg, error)
    type(namelist_text_t), intent(in) :: t
    character(len=*), intent(in) :: group
    integer, intent(in) :: ios
    character(len=*), intent(in) :: msg
    type(error_t), allocatable, intent(out) :: error
    if (ios == 0) return
    if (is_iostat_end(ios) .and. .not. t%has_group(group)) return
    call set_error(error, t%path // ": namelist group &" // group // ": " // trim(msg), EXIT_BAD_INPUT)
  end subroutine nml_status

  !> A real as the echo of a configuration writes it (es23.16: reads back exactly).
  function echo_real(x) result(t)
    real(wp), intent(in) :: x
    character(len=:), allocatable :: t
    t = str(x, "es23.16")
  end function echo_real

  !> Reals separated by ", ".
  function echo_reals(x) result(t)
    real(wp), intent(in) :: x(:)
    character(len=:), allocatable :: t
    integer :: m
    t = ""
    do m = 1, size(x)
      if (m > 1) t = t // ", "
      t = t // echo_real(x(m))
    end do
  end function echo_reals

  !> ".true. " or ".false." (the width the echoes have always had).
  function echo_logical(l) result(t)
    logical, intent(in) :: l
    character(len=:), allocatable :: t
    t = merge(".true. ", ".false.", l)
  end function echo_logical
end module cr_namelist_text
