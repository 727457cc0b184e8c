!> Levelled logger: only the root rank prints; stages are timed; long loops report progress.
module cr_logger
  use, intrinsic :: iso_fortran_env, only: output_unit, error_unit
  use cr_kinds, only: wp
  implicit none
  private
  public :: logger_t, LOG_ERROR, LOG_WARN, LOG_INFO, LOG_DEBUG

  integer, parameter :: LOG_ERROR = 0, LOG_WARN = 1, LOG_INFO = 2, LOG_DEBUG = 3

  !> Logger state: verbosity, whether this rank prints, stage and progress timers.
  type :: logger_t
    integer :: level = LOG_INFO
    logical :: active = .true.
    character(len=:), allocatable :: stage_name
    integer(8) :: stage_t0 = 0
    integer(8) :: prog_t0 = 0, prog_last = 0
    real(wp) :: progress_interval = 2.0_wp
  contains
    procedure :: init
    procedure :: error, warn, info, debug
    procedure :: stage_begin, stage_end
    procedure :: progress_start, progress
  end type logger_t

contains

  !> Initialise: `active` is true on the printing rank only.
  subroutine init(this, active, level)
    class(logger_t), intent(inout) :: this
    logical, intent(in) :: active
    integer, intent(in), optional :: level
    this%active = active
    if (present(level)) this%level = level
  end subroutine init

  subroutine emit(this, lvl, tag, msg)
    class(logger_t), intent(in) :: this
    integer, intent(in) :: lvl
    character(len=*), intent(in) :: tag, msg
    if (.not. this%active .or. lvl > this%level) return
    if (lvl <= LOG_WARN) then
      write(error_unit, '(a)') tag // msg
      flush(error_unit)
    else
      write(output_unit, '(a)') tag // msg
      flush(output_unit)
    end if
  end subroutine emit

  subroutine error(this, msg)
    class(logger_t), intent(in) :: this
    character(len=*), intent(in) :: msg
    call emit(this, LOG_ERROR, "error: ", msg)
  end subroutine error

  subroutine warn(this, msg)
    class(logger_t), intent(in) :: this
    character(len=*), intent(in) :: msg
    call emit(this, LOG_WARN, "warning: ", msg)
  end subroutine warn

  subroutine info(this, msg)
    class(logger_t), intent(in) :: this
    character(len=*), intent(in) :: msg
    call emit(this, LOG_INFO, "", msg)
  end subroutine info

  subroutine debug(this, msg)
    class(logger_t), intent(in) :: this
    character(len=*), intent(in) :: msg
    call emit(this, LOG_DEBUG, "debug: ", msg)
  end subroutine debug

  !> Open a timed stage.
  subroutine stage_begin(this, name)
    class(logger_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    this%stage_name = name
    call system_clock(this%stage_t0)
    call this%info("== " // name)
  end subroutine stage_begin

  !> Close the current stage, printing its wall time.
  subroutine stage_end(this)
    class(logger_t), intent(inout) :: this
    character(len=32) :: buf
    write(buf, '(f0.3)') elapsed(this%stage_t0)
    if (allocated(this%stage_name)) call this%info("== " // this%stage_name // " done in " // trim(buf) // " s")
  end subroutine stage_end

  !> Start a progress counter for a loop.
  subroutine progress_start(this)
    class(logger_t), intent(inout) :: this
    call system_clock(this%prog_t0)
    this%prog_last = this%prog_t0
  end subroutine progress_start

  !> Report "label k of n, elapsed, ETA" at most every `progress_interval` seconds (and at k = n).
  subroutine progress(this, label, k, n)
    class(logger_t), intent(inout) :: this
    character(len=*), intent(in) :: label
    integer, intent(in) :: k, n
    integer(8) :: now, rate
    real(wp) :: el, eta, since
    character(len=160) :: buf
    call system_clock(now, rate)
    since = real(now - this%prog_last, wp) / real(rate, wp)
    if (since < this%progress_interval .and. k < n) return
    this%prog_last = now
    el = elapsed(this%prog_t0)
    eta = 0.0_wp
    if (k > 0) eta = el * real(n - k, wp) / real(k, wp)
    write(buf, '(a, 1x, i0, " of ", i0, ", elapsed ", f0.1, " s, ETA ", f0.1, " s")') label, k, n, el, eta
    call this%info("   " // trim(buf))
  end subroutine progress

  real(wp) function elapsed(t0)
    integer(8), intent(in) :: t0
    integer(8) :: now, rate
    call system_clock(now, rate)
    elapsed = real(now - t0, wp) / real(rate, wp)
  end function elapsed
end module cr_logger
