!> POD benchmark: time and accuracy of tsqr, method of snapshots, ScaLAPACK and randomized
!> SVD (Gaussian, SRFT) on a synthetic snapshot matrix with a slowly decaying spectrum.
!>
!> Usage: crowd_podbench [n_dof n_snap] ...   (default: 300 10000 20000 2000)
!> S = U diag(1/i) V^T with U [n_dof, r], V [n_snap, r] Gaussian / sqrt(rows) (nearly
!> orthonormal), r = min(n_dof, n_snap); columns distributed in balanced blocks. The
!> reference spectrum and optimal errors are those of pod_tsqr. Prints a Markdown table.
!> Start and end through cr_program (MPI, one `error:` line, exit 2 for bad arguments).
program crowd_podbench
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t, set_error, prefix_error
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_random, only: rng_t
  use cr_lapack, only: la_gemm
  use cr_distribution, only: block_range
  use cr_pod, only: pod_result_t, pod_tsqr, pod_snapshots, pod_rsvd, pod_scalapack, sketch_gaussian
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(error_t), allocatable :: error
  integer :: ncase, c, code
  integer, allocatable :: sizes(:)

  call program_start("crowd_podbench", env, log, cli, error, own_arguments=.true.)
  if (.not. allocated(error)) call read_sizes(sizes, error)
  if (.not. allocated(error)) then
    ncase = size(sizes) / 2
    if (env%is_root()) then
      write(*, '(a, i0, a)') "ranks: ", env%size, "; times in s (max over ranks); err = ||S - Phi Phi^T S||_F / ||S||_F"
      write(*, '(a)') ""
      write(*, '(a)') "| n_dof | n_snap | method | N | time | err | optimal err | max rel. err sigma_1..N |"
      write(*, '(a)') "|---:|---:|---|---:|---:|---:|---:|---:|"
    end if
    do c = 1, ncase
      call run_case(sizes(2 * c - 1), sizes(2 * c), error)
      if (allocated(error)) then
        call prefix_error(error, "crowd_podbench"); exit
      end if
    end do
  end if
  code = program_finish(env, log, error)
  if (code /= 0) stop code, quiet=.true.

contains

  !> The cases (n_dof, n_snap) of the command line [2 n_cases] (default 300 10000 20000 2000);
  !> a bad command line is an input error (code 2).
  subroutine read_sizes(sizes, error)
    integer, allocatable, intent(out) :: sizes(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: nargs, c, ios, length
    character(len=:), allocatable :: arg
    nargs = command_argument_count()
    if (nargs == 0) then
      sizes = [300, 10000, 20000, 2000]; return
    end if
    if (mod(nargs, 2) /= 0) then
      call set_error(error, "crowd_podbench: the arguments are pairs 'n_dof n_snap' (got " // &
        trim(count_text(nargs)) // " arguments)", EXIT_BAD_INPUT); return
    end if
    allocate(sizes(nargs))
    do c = 1, nargs
      call get_command_argument(c, length=length)
      if (allocated(arg)) deallocate(arg)
      allocate(character(len=length) :: arg)
      call get_command_argument(c, arg)
      read(arg, *, iostat=ios) sizes(c)
      if (ios /= 0) then
        call set_error(error, "crowd_podbench: argument " // trim(count_text(c)) // " '" // arg // &
          "' is not a whole number (usage: crowd_podbench [n_dof n_snap] ...)", EXIT_BAD_INPUT); return
      else if (sizes(c) < 1 .or. sizes(c) > 10000000) then
        call set_error(error, "crowd_podbench: argument " // trim(count_text(c)) // " = " // arg // &
          " must be in 1..10000000", EXIT_BAD_INPUT); return
      end if
    end do
    do c = 1, nargs / 2
      if (int(sizes(2 * c - 1), 8) * sizes(2 * c) > 2000000000_8) then
        call set_error(error, "crowd_podbench: case " // trim(count_text(c)) // ": n_dof * n_snap exceeds 2e9 " // &
          "entries (the snapshot matrix would not fit)", EXIT_BAD_INPUT); return
      end if
    end do
  end subroutine read_sizes

  !> Decimal text of an integer.
  function count_text(i) result(s)
    integer, intent(in) :: i
    character(len=12) :: s
    write(s, '(i0)') i
  end function count_text

  subroutine run_case(n_dof, n_snap, error)
    integer, intent(in) :: n_dof, n_snap
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: s(:, :), u(:, :), v(:, :)
    type(pod_result_t) :: ref, res
    integer :: off, n_r, r, i, j, in, k
    integer, parameter :: nlist(3) = [10, 50, 100]
    real(wp) :: t0, t, total
    type(rng_t) :: rng
    character(len=16) :: methods(3) = [character(len=16) :: "tsqr", "snapshots", "scalapack"]
    call block_range(n_snap, env%size, env%rank, off, n_r)
    r = min(n_dof, n_snap)
    allocate(u(n_dof, r), v(n_r, r), s(n_dof, n_r))
    do j = 1, r
      call rng%seed(99, j)
      do i = 1, n_dof
        u(i, j) = rng%normal() / sqrt(real(n_dof, wp)) / real(j, wp)
      end do
    end do
    call sketch_gaussian(98, off, v)
    v = v / sqrt(real(n_snap, wp))
    call la_gemm('N', 'T', 1.0_wp, u, v, 0.0_wp, s, error)
    if (allocated(error)) return
    deallocate(u, v)
    total = sum(s**2)
    call env%allreduce(total, 'sum', error)
    if (allocated(error)) return
    total = sqrt(total)

    do k = 1, 3
      call env%sync(error)
      if (allocated(error)) return
      t0 = env%wtime()
      select case (k)
      case (1); call pod_tsqr(env, s, res, error, n_modes=100)
      case (2); call pod_snapshots(env, s, res, error, n_modes=100)
      case (3); call pod_scalapack(env, s, res, error, n_modes=100)
      end select
      t = env%wtime() - t0
      if (allocated(error)) return
      call env%allreduce(t, 'max', error)
      if (allocated(error)) return
      if (k == 1) ref = res
      do in = 1, 3
        call report(n_dof, n_snap, trim(methods(k)), nlist(in), t, s, res, ref, total, error)
        if (allocated(error)) return
      end do
    end do
    do k = 1, 2
      do in = 1, 3
        call env%sync(error)
        if (allocated(error)) return
        t0 = env%wtime()
        call pod_rsvd(env, s, nlist(in), 10, 1, trim(merge("gaussian", "srft    ", k == 1)), 7, res, error)
        t = env%wtime() - t0
        if (allocated(error)) return
        call env%allreduce(t, 'max', error)
        if (allocated(error)) return
        call report(n_dof, n_snap, "rsvd-" // trim(merge("gaussian", "srft    ", k == 1)) // " p=10 q=1", &
          & nlist(in), t, s, res, ref, total, error)
        if (allocated(error)) return
      end do
    end do
  end subroutine run_case

  !> One table row: error of the first n modes of res against the optimum from ref.
  subroutine report(n_dof, n_snap, method, n, t, s, res, ref, total, error)
    integer, intent(in) :: n_dof, n_snap, n
    character(len=*), intent(in) :: method
    real(wp), intent(in) :: t, total
    real(wp), contiguous, intent(in) :: s(:, :)
    type(pod_result_t), intent(in) :: res, ref
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: e, eopt, esig
    integer :: nn
    nn = min(n, res%n_modes)
    call proj_err(s, res%phi(:, 1:nn), e, error)
    if (allocated(error)) return
    call proj_err(s, ref%phi(:, 1:min(n, ref%n_modes)), eopt, error)
    if (allocated(error)) return
    esig = maxval(abs(res%sigma(1:nn) - ref%sigma(1:nn)) / ref%sigma(1:nn))
    if (env%is_root()) write(*, '("| ", i0, " | ", i0, " | ", a, " | ", i0, " | ", f8.3, " | ", es10.3, " | ", &
      & es10.3, " | ", es9.2, " |")') n_dof, n_snap, method, nn, t, e / total, eopt / total, esig
  end subroutine report

  !> e = ||S - Phi Phi^T S||_F over all ranks.
  subroutine proj_err(s, phi, e, error)
    real(wp), contiguous, intent(in) :: s(:, :), phi(:, :)
    real(wp), intent(out) :: e
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: c(:, :), rres(:, :)
    allocate(c(size(phi, 2), size(s, 2)))
    rres = s
    e = 0
    call la_gemm('T', 'N', 1.0_wp, phi, s, 0.0_wp, c, error)
    if (allocated(error)) return
    call la_gemm('N', 'N', -1.0_wp, phi, c, 1.0_wp, rres, error)
    if (allocated(error)) return
    e = sum(rres**2)
    call env%allreduce(e, 'sum', error)
    e = sqrt(e)
  end subroutine proj_err

end program crowd_podbench
