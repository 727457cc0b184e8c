!> The files a program reads and writes, checked before any work: every output must be
!> creatable (its directory exists and is writable, it is not a directory) and must not be
!> one of the inputs or another output. Paths are compared resolved (absolute, symbolic
!> links, `.` and `..` removed), so `./x.h5`, `dir/../x.h5` and a link to x.h5 are x.h5; a hard
!> link is caught by its inode.
module cr_paths
  use cr_error, only: error_t, problems_t
  use cr_fsys, only: real_path, is_directory, dir_writable, dir_of, file_exists, clear_errno, errno_text, &
    same_file
  implicit none
  private
  public :: io_paths_t, resolved_output

  !> One named file: `what` says where it comes from (e.g. "&output file", "--summary").
  type :: path_entry_t
    character(len=:), allocatable :: what
    character(len=:), allocatable :: path
  end type path_entry_t

  !> The inputs and outputs of one run.
  type :: io_paths_t
    type(path_entry_t), allocatable :: inputs(:)
    type(path_entry_t), allocatable :: outputs(:)
  contains
    procedure :: input => add_input
    procedure :: output => add_output
    procedure :: check
  end type io_paths_t

contains

  !> Record a file the run reads (ignored when `path` is blank).
  subroutine add_input(this, what, path)
    class(io_paths_t), intent(inout) :: this
    character(len=*), intent(in) :: what, path
    if (len_trim(path) == 0) return
    call append(this%inputs, what, trim(path))
  end subroutine add_input

  !> Record a file the run writes (ignored when `path` is blank).
  subroutine add_output(this, what, path)
    class(io_paths_t), intent(inout) :: this
    character(len=*), intent(in) :: what, path
    if (len_trim(path) == 0) return
    call append(this%outputs, what, trim(path))
  end subroutine add_output

  subroutine append(list, what, path)
    type(path_entry_t), allocatable, intent(inout) :: list(:)
    character(len=*), intent(in) :: what, path
    type(path_entry_t), allocatable :: tmp(:)
    integer :: n
    if (.not. allocated(list)) allocate(list(0))
    n = size(list)
    allocate(tmp(n + 1))
    tmp(1:n) = list
    tmp(n + 1)%what = what
    tmp(n + 1)%path = path
    call move_alloc(tmp, list)
  end subroutine append

  !> Resolved absolute path an output will have ("" if its directory cannot be resolved).
  function resolved_output(path) result(r)
    character(len=*), intent(in) :: path
    character(len=:), allocatable :: r, d
    integer :: k
    r = ""
    if (file_exists(path) .or. is_directory(path)) then
      r = real_path(path); return
    end if
    d = real_path(dir_of(path))
    if (len(d) == 0) return
    k = index(path, "/", back=.true.)
    if (d == "/") then
      r = "/" // path(k+1:)
    else
      r = d // "/" // path(k+1:)
    end if
  end function resolved_output

  !> Every problem with the outputs, in one input error (code 2): an output that is an input
  !> or another output, a directory, or in a directory that is missing or not writable.
  subroutine check(this, prefix, error)
    class(io_paths_t), intent(in) :: this
    !> start of the message (e.g. the input file's name), may be empty
    character(len=*), intent(in) :: prefix
    type(error_t), allocatable, intent(out) :: error
    type(problems_t) :: probs
    character(len=:), allocatable :: r, ri, d, why
    character(len=4096), allocatable :: res_out(:)
    integer :: k, j
    if (.not. allocated(this%outputs)) return
    allocate(res_out(size(this%outputs)))
    res_out = ""
    do k = 1, size(this%outputs)
      associate (o => this%outputs(k))
        d = dir_of(o%path)
        if (is_directory(o%path)) then
          call probs%need(.false., o%what // " '" // o%path // "' is a directory")
          cycle
        end if
        if (.not. is_directory(d)) then
          call probs%need(.false., o%what // " '" // o%path // "': the directory '" // d // "' does not exist")
          cycle
        end if
        call clear_errno()
        if (.not. dir_writable(d)) then
          why = errno_text()
          if (len(why) == 0) why = "not writable"
          call probs%need(.false., o%what // " '" // o%path // "': cannot write in the directory '" // d // &
            "' (" // why // ")")
          cycle
        end if
        r = resolved_output(o%path)
        if (len(r) == 0) cycle
        res_out(k) = r
        if (allocated(this%inputs)) then
          do j = 1, size(this%inputs)
            if (.not. (file_exists(this%inputs(j)%path))) cycle
            ri = real_path(this%inputs(j)%path)
            if (len(ri) == 0) cycle
            call probs%need(ri /= r .and. ri /= r // ".partial" .and. .not. same_file(o%path, this%inputs(j)%path), &
              o%what // " '" // o%path // &
              "' is the input " // this%inputs(j)%what // " '" // this%inputs(j)%path // &
              "' (both are " // ri // "): refusing to overwrite an input")
          end do
        end if
        do j = 1, k - 1
          if (len_trim(res_out(j)) == 0) cycle
          call probs%need(trim(res_out(j)) /= r, o%what // " '" // o%path // "' and " // &
            this%outputs(j)%what // " '" // this%outputs(j)%path // "' are the same file (" // r // ")")
          ! every output is written to <name>.partial first: one output may not be the other's
          call probs%need(trim(res_out(j)) /= r // ".partial" .and. trim(res_out(j)) // ".partial" /= r, &
            o%what // " '" // o%path // "' and " // this%outputs(j)%what // " '" // &
            this%outputs(j)%path // "' clash: one is the other's temporary (<name>.partial)")
        end do
      end associate
    end do
    call probs%to_error(prefix, error)
  end subroutine check
end module cr_paths
