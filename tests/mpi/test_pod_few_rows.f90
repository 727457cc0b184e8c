!> pod_scalapack with fewer rows than ranks (n_dof < P, e.g. a study of one agent at 4 ranks):
!> pdgesvd computes the singular values on every process with that process's rows of U, and
!> the processes that own none use dqds instead of QR, so it reported info = min(m, n) + 1
!> ("values differ between processes") for rank-1 and full-rank S alike (and for one row gave
!> a value 17% off on some processes). Such an S now gets the serial SVD of S gathered on rank
!> 0 (method "scalapack-serial"); S with n_dof >= P still goes through pdgesvd. Both must
!> agree with the TSQR POD (sigma, rank, modes with their signs) at 1, 2 and 4 ranks.
program test_pod_few_rows
  use mpi_f08, only: MPI_Init, MPI_Finalize, MPI_COMM_WORLD
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_strings, only: str
  use cr_assert, only: check, check_close, test_summary
  use cr_pod, only: pod_result_t, pod_tsqr, pod_scalapack
  use cr_test_columns, only: local_cols, make_s
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  integer :: ierr
  real(wp), parameter :: eps = epsilon(1.0_wp)

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call check(.not. allocated(error), "env%init")
  call test_few_rows()
  call env%free()
  call MPI_Finalize(ierr)
  call test_summary(env%rank)

contains

  !> m = 1..5 rows (at 4 ranks: 1..3 fewer than the ranks, 4 and 5 not), n = 2, 3, 5
  !> snapshots, rank 1..min(m, n, 3) with sigma 3, 1, 0.3 (gaps >= 0.7); the reported case is
  !> the rank-1 3 x 2.
  subroutine test_few_rows()
    real(wp), parameter :: sig_all(3) = [3.0_wp, 1.0_wp, 0.3_wp]
    integer, parameter :: ns(3) = [2, 3, 5]
    real(wp), allocatable :: s(:, :), u(:, :)
    type(pod_result_t) :: sc, ts
    type(error_t), allocatable :: e
    character(len=:), allocatable :: name
    real(wp) :: tol_s, tol_v
    integer :: m, k, n, r
    do m = 1, 5
      do k = 1, size(ns)
        n = ns(k)
        do r = 1, min(m, n, 3)
          name = str(m) // " x " // str(n) // " rank " // str(r) // " at " // str(env%size) // " ranks"
          call make_s(m, n, sig_all(1:r), 10 * m + n, s, u)
          call pod_scalapack(env, local_cols(env, s), sc, e)
          call check(.not. allocated(e), "scalapack " // name // ": runs")
          if (allocated(e)) then
            if (env%rank == 0) print "(a)", "  " // e%message
            cycle
          end if
          if (m < env%size) then
            call check(sc%method == "scalapack-serial", name // ": fewer rows than ranks, serial SVD")
          else
            call check(sc%method == "scalapack", name // ": pdgesvd")
          end if
          call pod_tsqr(env, local_cols(env, s), ts, e)
          call check(.not. allocated(e), "tsqr " // name // ": runs")
          if (allocated(e)) cycle
          ! both backward stable: singular values to c max(m, n) eps sigma_1 (c = 100 as in
          ! test_pod), modes to that over the gap (>= 0.7)
          tol_s = 100 * max(m, n) * eps * sig_all(1)
          tol_v = tol_s / 0.7_wp
          call check(sc%rank == r .and. ts%rank == r, name // ": rank " // str(r) // " (scalapack " // &
            str(sc%rank) // ", tsqr " // str(ts%rank) // ")")
          call check(size(sc%sigma_all) == size(ts%sigma_all), name // ": as many singular values")
          if (size(sc%sigma_all) == size(ts%sigma_all)) &
            call check_close(maxval(abs(sc%sigma_all - ts%sigma_all)), 0.0_wp, tol_s, name // ": sigma = tsqr")
          call check_close(maxval(abs(sc%sigma_all(1:r) - sig_all(1:r))), 0.0_wp, tol_s, name // ": sigma = exact")
          if (sc%n_modes == ts%n_modes) then
            call check_close(maxval(abs(sc%phi - ts%phi)), 0.0_wp, tol_v, name // ": modes = tsqr (same signs)")
          else
            call check(.false., name // ": as many modes")
          end if
        end do
      end do
    end do
  end subroutine test_few_rows
end program test_pod_few_rows
