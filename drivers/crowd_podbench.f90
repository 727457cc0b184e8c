!> POD benchmark: time and accuracy of tsqr, method of snapshots, ScaLAPACK and randomized
!> SVD (Gaussian, SRFT) on a synthetic snapshot matrix with a slowly decaying spectrum.
!>
!> Usage: crowd_podbench [n_dof n_snap] ...   (default: 300 10000 20000 2000)
!> S = U diag(1/i) V^T with U [n_dof, r], V [n_snap, r] Gaussian / sqrt(rows) (nearly
!> orthonormal), r = min(n_dof, n_snap); columns distributed in balanced blocks. The
!> reference spectrum and optimal errors are those of pod_tsqr. Prints a Markdown table.
program crowd_podbench
  use mpi_f08
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t
  use cr_random, only: rng_t
  use cr_lapack, only: la_gemm
  use cr_distribution, only: block_range
  use cr_pod, only: pod_result_t, pod_tsqr, pod_snapshots, pod_rsvd, pod_scalapack, sketch_gaussian
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  integer :: ierr, ncase, c, nargs, ios, length
  integer, allocatable :: sizes(:)
  character(len=:), allocatable :: arg

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  nargs = command_argument_count()
  if (nargs == 1 .or. mod(nargs, 2) /= 0) call refuse("crowd_podbench: the arguments are pairs " // &
    "'n_dof n_snap' (got " // trim(count_text(nargs)) // " arguments)")
  if (nargs >= 2) then
    ncase = nargs / 2
    allocate(sizes(2 * ncase))
    do c = 1, 2 * ncase
      call get_command_argument(c, length=length)
      if (allocated(arg)) deallocate(arg)
      allocate(character(len=length) :: arg)
      call get_command_argument(c, arg)
      read(arg, *, iostat=ios) sizes(c)
      if (ios /= 0) then
        call refuse("crowd_podbench: argument " // trim(count_text(c)) // " '" // arg // &
          "' is not a whole number (usage: crowd_podbench [n_dof n_snap] ...)")
      else if (sizes(c) < 1 .or. sizes(c) > 10000000) then
        call refuse("crowd_podbench: argument " // trim(count_text(c)) // " = " // arg // &
          " must be in 1..10000000")
      end if
    end do
    do c = 1, ncase
      if (int(sizes(2 * c - 1), 8) * sizes(2 * c) > 2000000000_8) call refuse("crowd_podbench: case " // &
        trim(count_text(c)) // ": n_dof * n_snap exceeds 2e9 entries (the snapshot matrix would not fit)")
    end do
  else
    ncase = 2
    sizes = [300, 10000, 20000, 2000]
  end if
  if (env%is_root()) then
    write(*, '(a, i0, a)') "ranks: ", env%size, "; times in s (max over ranks); err = ||S - Phi Phi^T S||_F / ||S||_F"
    write(*, '(a)') ""
    write(*, '(a)') "| n_dof | n_snap | method | N | time | err | optimal err | max rel. err sigma_1..N |"
    write(*, '(a)') "|---:|---:|---|---:|---:|---:|---:|---:|"
  end if
  do c = 1, ncase
    call run_case(sizes(2 * c - 1), sizes(2 * c))
  end do
  call env%free()
  call MPI_Finalize(ierr)

contains

  !> Bad command line: one error line (rank 0), MPI finalised, exit 2.
  subroutine refuse(msg)
    character(len=*), intent(in) :: msg
    if (env%is_root()) write(*, '(a)') "error: " // msg
    call env%free()
    call MPI_Finalize(ierr)
    stop 2, quiet=.true.
  end subroutine refuse

  !> Decimal text of an integer.
  function count_text(i) result(s)
    integer, intent(in) :: i
    character(len=12) :: s
    write(s, '(i0)') i
  end function count_text

  subroutine run_case(n_dof, n_snap)
    integer, intent(in) :: n_dof, n_snap
    real(wp), allocatable :: s(:, :), u(:, :), v(:, :)
    type(pod_result_t) :: ref, res
    integer :: off, n_r, r, i, j, in, k
    integer, parameter :: nlist(3) = [10, 50, 100]
    real(wp) :: t0, t, total
    type(error_t), allocatable :: e2
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
    deallocate(u, v)
    total = sum(s**2)
    call env%allreduce(total, 'sum', error)
    call stop_on(error)
    total = sqrt(total)

    do k = 1, 3
      call env%sync(error)
      call stop_on(error)
      t0 = env%wtime()
      select case (k)
      case (1); call pod_tsqr(env, s, res, error, n_modes=100)
      case (2); call pod_snapshots(env, s, res, error, n_modes=100)
      case (3); call pod_scalapack(env, s, res, error, n_modes=100)
      end select
      t = env%wtime() - t0
      call env%allreduce(t, 'max', e2)
      call stop_on(error)
      call stop_on(e2)
      if (k == 1) ref = res
      do in = 1, 3
        call report(n_dof, n_snap, trim(methods(k)), nlist(in), t, s, res, ref, total)
      end do
    end do
    do k = 1, 2
      do in = 1, 3
        call env%sync(error)
        call stop_on(error)
        t0 = env%wtime()
        call pod_rsvd(env, s, nlist(in), 10, 1, trim(merge("gaussian", "srft    ", k == 1)), 7, res, error)
        t = env%wtime() - t0
        call env%allreduce(t, 'max', e2)
        call stop_on(error)
        call stop_on(e2)
        call report(n_dof, n_snap, "rsvd-" // trim(merge("gaussian", "srft    ", k == 1)) // " p=10 q=1", &
          & nlist(in), t, s, res, ref, total)
      end do
    end do
  end subroutine run_case

  !> One table row: error of the first n modes of res against the optimum from ref.
  subroutine report(n_dof, n_snap, method, n, t, s, res, ref, total)
    integer, intent(in) :: n_dof, n_snap, n
    character(len=*), intent(in) :: method
    real(wp), intent(in) :: t, total
    real(wp), contiguous, intent(in) :: s(:, :)
    type(pod_result_t), intent(in) :: res, ref
    real(wp) :: e, eopt, esig
    integer :: nn
    nn = min(n, res%n_modes)
    e = proj_err(s, res%phi(:, 1:nn))
    eopt = proj_err(s, ref%phi(:, 1:min(n, ref%n_modes)))
    esig = maxval(abs(res%sigma(1:nn) - ref%sigma(1:nn)) / ref%sigma(1:nn))
    if (env%is_root()) write(*, '("| ", i0, " | ", i0, " | ", a, " | ", i0, " | ", f8.3, " | ", es10.3, " | ", &
      & es10.3, " | ", es9.2, " |")') n_dof, n_snap, method, nn, t, e / total, eopt / total, esig
  end subroutine report

  real(wp) function proj_err(s, phi)
    real(wp), contiguous, intent(in) :: s(:, :), phi(:, :)
    real(wp), allocatable :: c(:, :), rres(:, :)
    type(error_t), allocatable :: err
    allocate(c(size(phi, 2), size(s, 2)))
    rres = s
    call la_gemm('T', 'N', 1.0_wp, phi, s, 0.0_wp, c, err)
    call la_gemm('N', 'N', -1.0_wp, phi, c, 1.0_wp, rres, err)
    proj_err = sum(rres**2)
    call env%allreduce(proj_err, 'sum', err)
    call stop_on(err)
    proj_err = sqrt(proj_err)
  end function proj_err

  subroutine stop_on(err)
    type(error_t), allocatable, intent(in) :: err
    integer :: ie
    if (.not. allocated(err)) return
    if (env%is_root()) write(*, '(a)') "error: crowd_podbench: " // err%message
    call MPI_Finalize(ie)
    error stop 1
  end subroutine stop_on
end program crowd_podbench
