!> NNLS benchmark: time per call of nnls_solve on the problems of a file written by
!> scripts/bench/bench_nnls.py (which times SciPy's NNLS on the same problems and compares).
!>
!> Usage: crowd_nnlsbench <problems.bin> [min_seconds]
!> File (stream, little-endian): int32 n_problems, then per problem int32 m, int32 n,
!> float64 A [m, n] (column-major), float64 b [m]. For each problem the solve is repeated
!> (one reusable work space, as the online model calls it) until min_seconds (default 0.2)
!> have passed; prints one line per problem: index, m, n, microseconds per call, residual
!> |A x - b|, converged (1/0), n_passive.
program crowd_nnlsbench
  use, intrinsic :: iso_fortran_env, only: int32, int64, real64, error_unit
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_nnls, only: nnls_solve, nnls_stats_t, nnls_work_t
  use cr_exit_codes, only: EXIT_FAILURE, EXIT_BAD_INPUT
  implicit none
  character(len=4096) :: path, arg
  integer :: u, ios, p, reps, i
  integer(int32) :: nprob, m, n
  real(wp), allocatable :: a(:,:), b(:), x(:)
  real(wp) :: min_seconds, t
  integer(int64) :: c0, c1, rate
  type(nnls_stats_t) :: st
  type(nnls_work_t) :: work
  type(error_t), allocatable :: error
  character(len=256) :: msg

  if (command_argument_count() < 1) then
    write(error_unit, '(a)') "usage: crowd_nnlsbench <problems.bin> [min_seconds]"
    error stop EXIT_BAD_INPUT
  end if
  call get_command_argument(1, path)
  min_seconds = 0.2_wp
  if (command_argument_count() >= 2) then
    call get_command_argument(2, arg)
    read(arg, *, iostat=ios) min_seconds
    if (ios /= 0 .or. .not. min_seconds > 0) then
      write(error_unit, '(a)') "error: crowd_nnlsbench: min_seconds must be a positive number, got '" // &
        trim(arg) // "'"
      error stop EXIT_BAD_INPUT
    end if
  end if
  open(newunit=u, file=trim(path), access='stream', form='unformatted', status='old', action='read', &
    iostat=ios, iomsg=msg)
  if (ios /= 0) then
    write(error_unit, '(a)') "error: crowd_nnlsbench: " // trim(path) // ": " // trim(msg)
    error stop EXIT_BAD_INPUT
  end if
  read(u, iostat=ios) nprob
  if (ios /= 0 .or. nprob < 0) call bad("cannot read the number of problems")
  call system_clock(count_rate=rate)
  do p = 1, nprob
    read(u, iostat=ios) m, n
    if (ios /= 0 .or. m < 0 .or. n < 0) call bad("cannot read the sizes of problem " // itoa(p))
    allocate(a(m, n), b(m), x(n))
    read(u, iostat=ios) a, b
    if (ios /= 0) call bad("cannot read the data of problem " // itoa(p))
    call nnls_solve(a, b, x, st, error, work=work)
    if (allocated(error)) then
      write(error_unit, '(a)') "error: crowd_nnlsbench: problem " // itoa(p) // ": " // error%message
      error stop EXIT_FAILURE
    end if
    reps = 0
    call system_clock(c0)
    do
      do i = 1, 10
        call nnls_solve(a, b, x, st, error, work=work)
      end do
      reps = reps + 10
      call system_clock(c1)
      t = real(c1 - c0, wp) / real(rate, wp)
      if (t >= min_seconds) exit
    end do
    write(*, '(i0, 1x, i0, 1x, i0, 1x, es12.5, 1x, es24.16, 1x, i0, 1x, i0)') p, m, n, 1.0e6_wp * t / reps, &
      st%residual, merge(1, 0, st%converged), st%n_passive
    deallocate(a, b, x)
  end do
  close(u)

contains

  function itoa(k) result(s)
    integer, intent(in) :: k
    character(len=:), allocatable :: s
    character(len=16) :: buf
    write(buf, '(i0)') k
    s = trim(buf)
  end function itoa

  subroutine bad(what)
    character(len=*), intent(in) :: what
    write(error_unit, '(a)') "error: crowd_nnlsbench: " // trim(path) // ": " // what
    error stop EXIT_BAD_INPUT
  end subroutine bad
end program crowd_nnlsbench
