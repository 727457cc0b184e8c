!> Command-line handling shared by the drivers: `program input.nml [--summary FILE] [--help]`.
module cr_cli
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: cli_t, parse_cli

  !> Parsed command line.
  type :: cli_t
    character(len=:), allocatable :: input
    character(len=:), allocatable :: summary
    logical :: help = .false.
    !> --stop-after K (crowd_snapshots testing hook): stop after K samples; -1 when not given
    integer :: stop_after = -1
    !> --quarantine-bad-pieces (crowd_snapshots): move bad pieces aside and recompute them
    logical :: quarantine = .false.
    !> --batch-seconds S (crowd_snapshots): time slice of one piece; < 0 when not given
    real(wp) :: batch_seconds = -1
  end type cli_t

contains

  !> Parse the command line; unknown options and a missing input are errors.
  subroutine parse_cli(program_name, cli, error, allow_stop_after)
    character(len=*), intent(in) :: program_name
    type(cli_t), intent(out) :: cli
    type(error_t), allocatable, intent(out) :: error
    !> accept the crowd_snapshots options `--stop-after K`, `--quarantine-bad-pieces` and
    !> `--batch-seconds S` (default .false.: they are unknown options)
    logical, intent(in), optional :: allow_stop_after
    integer :: k, n, length, ios
    logical :: stop_ok
    character(len=:), allocatable :: arg
    stop_ok = .false.
    if (present(allow_stop_after)) stop_ok = allow_stop_after
    n = command_argument_count()
    cli%summary = ""
    k = 0
    do while (k < n)
      k = k + 1
      call get_command_argument(k, length=length)
      allocate(character(len=length) :: arg)
      call get_command_argument(k, arg)
      select case (arg)
      case ('-h', '--help')
        cli%help = .true.
      case ('--summary')
        if (k == n) then
          call set_error(error, program_name // ": --summary needs a file name", EXIT_BAD_INPUT); return
        end if
        k = k + 1
        call get_command_argument(k, length=length)
        deallocate(arg); allocate(character(len=length) :: arg)
        call get_command_argument(k, arg)
        cli%summary = arg
      case ('--stop-after')
        if (.not. stop_ok) then
          call set_error(error, program_name // ": unknown option '" // arg // "' (see --help)", EXIT_BAD_INPUT); return
        end if
        if (k == n) then
          call set_error(error, program_name // ": --stop-after needs a number of samples", EXIT_BAD_INPUT); return
        end if
        k = k + 1
        call get_command_argument(k, length=length)
        deallocate(arg); allocate(character(len=length) :: arg)
        call get_command_argument(k, arg)
        read(arg, *, iostat=ios) cli%stop_after
        if (ios /= 0 .or. cli%stop_after < 0) then
          call set_error(error, program_name // ": --stop-after '" // arg // "' is not a number >= 0", EXIT_BAD_INPUT); return
        end if
      case ('--quarantine-bad-pieces')
        if (.not. stop_ok) then
          call set_error(error, program_name // ": unknown option '" // arg // "' (see --help)", EXIT_BAD_INPUT); return
        end if
        cli%quarantine = .true.
      case ('--batch-seconds')
        if (.not. stop_ok) then
          call set_error(error, program_name // ": unknown option '" // arg // "' (see --help)", EXIT_BAD_INPUT); return
        end if
        if (k == n) then
          call set_error(error, program_name // ": --batch-seconds needs a time in seconds", EXIT_BAD_INPUT); return
        end if
        k = k + 1
        call get_command_argument(k, length=length)
        deallocate(arg); allocate(character(len=length) :: arg)
        call get_command_argument(k, arg)
        read(arg, *, iostat=ios) cli%batch_seconds
        if (ios /= 0 .or. .not. (cli%batch_seconds >= 0 .and. cli%batch_seconds <= 1.0e6_wp)) then
          call set_error(error, program_name // ": --batch-seconds '" // arg // "' is not a time in [0, 1e6] s", EXIT_BAD_INPUT)
          return
        end if
      case default
        if (arg(1:1) == '-') then
          call set_error(error, program_name // ": unknown option '" // arg // "' (see --help)", EXIT_BAD_INPUT); return
        end if
        if (allocated(cli%input)) then
          call set_error(error, program_name // ": more than one input file given ('" // cli%input // &
            "' and '" // arg // "')", EXIT_BAD_INPUT); return
        end if
        cli%input = arg
      end select
      deallocate(arg)
    end do
    if (.not. cli%help .and. .not. allocated(cli%input)) &
      call set_error(error, program_name // ": no input file given (usage: " // program_name // &
        " input.nml [--summary FILE]; see --help)", EXIT_BAD_INPUT)
  end subroutine parse_cli
end module cr_cli
