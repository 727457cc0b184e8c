!> POD methods on matrices with known singular values, distributed by column blocks.
!> Run at 1, 2 and 4 ranks; each run also recomputes on a one-rank communicator (rank 0)
!> and checks that the distributed result equals the serial one up to round-off.
program test_pod
  use mpi_f08
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t
  use cr_lapack, only: la_gesvd
  use cr_distribution, only: block_range
  use cr_pod, only: pod_result_t, pod_tsqr, pod_snapshots, pod_rsvd, pod_scalapack
  use cr_test_columns, only: make_s
  use cr_assert, only: check, check_close, check_rel, test_summary
  implicit none
  type(env_t) :: env, env1
  type(MPI_Comm) :: c1
  type(error_t), allocatable :: error
  integer :: ierr, i
  real(wp), parameter :: EPSM = epsilon(1.0_wp)
  !> Orthonormality of computed modes [n_dof, k] from Householder QR / SVD / symmetric
  !> eigensolvers: ||Phi^T Phi - I||_2 <= 2 p(n) eps with p(n) = c n, c = 4 (Higham, Accuracy
  !> and Stability, Thm 19.4; LAPACK Users' Guide 4.7/4.9): ORTH_C * n_dof * eps. Derived, not
  !> measured: the AVX-512 kernels give 17 eps for n_dof = 40 where 1e-14 (45 eps) was asked.
  real(wp), parameter :: ORTH_C = 8.0_wp * EPSM

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call MPI_Comm_split(env%comm, merge(0, 1, env%rank == 0), env%rank, c1, ierr)
  call env1%init(c1, error)

  call test_well_conditioned()
  call test_ill_conditioned()
  call test_rsvd()
  call test_rank_deficient()
  call test_truncation_and_errors()
  call test_sign_rule()

  call env1%free()
  call MPI_Comm_free(c1, ierr)
  call env%free()
  call test_summary(env%rank)
  call MPI_Finalize(ierr)

contains

  !> This rank's columns of s: balanced blocks, or rank 1 empty if `hole`.
  function local_cols(s, hole) result(sl)
    real(wp), intent(in) :: s(:, :)
    logical, intent(in) :: hole
    real(wp), allocatable :: sl(:, :)
    integer :: off, cnt, np, part
    np = env%size
    part = env%rank
    if (hole .and. np > 1) then
      np = env%size - 1
      if (env%rank == 1) then
        allocate(sl(size(s, 1), 0)); return
      end if
      if (env%rank > 1) part = env%rank - 1
    end if
    call block_range(size(s, 2), np, part, off, cnt)
    sl = s(:, off + 1:off + cnt)
  end function local_cols

  !> max_i min(||a_i - b_i||, ||a_i + b_i||): columns equal up to sign.
  real(wp) function mode_diff(a, b)
    real(wp), intent(in) :: a(:, :), b(:, :)
    integer :: j
    mode_diff = 0.0_wp
    if (size(a, 2) /= size(b, 2) .or. size(a, 1) /= size(b, 1)) then
      mode_diff = huge(1.0_wp); return
    end if
    do j = 1, size(a, 2)
      mode_diff = max(mode_diff, min(norm2(a(:, j) - b(:, j)), norm2(a(:, j) + b(:, j))))
    end do
  end function mode_diff

  !> ||Phi^T Phi - I||_2 (spectral norm)
  real(wp) function orth_err(phi)
    real(wp), intent(in) :: phi(:, :)
    real(wp), allocatable :: g(:, :), sv(:)
    type(error_t), allocatable :: err
    integer :: j
    orth_err = 0.0_wp
    if (size(phi, 2) == 0) return
    g = matmul(transpose(phi), phi)
    do j = 1, size(g, 1)
      g(j, j) = g(j, j) - 1.0_wp
    end do
    allocate(sv(size(g, 1)))
    call la_gesvd(g, sv, err)
    orth_err = sv(1)
  end function orth_err

  !> ||S - Phi Phi^T S||_F
  real(wp) function proj_err(s, phi)
    real(wp), intent(in) :: s(:, :), phi(:, :)
    proj_err = norm2(s - matmul(phi, matmul(transpose(phi), s)))
  end function proj_err

  logical function finite(x)
    real(wp), intent(in) :: x(:)
    finite = all(abs(x) <= huge(1.0_wp))
  end function finite

  !> Serial POD of the full s on rank 0 (one-rank communicator).
  subroutine serial(method, s, res)
    character(len=*), intent(in) :: method
    real(wp), contiguous, intent(in) :: s(:, :)
    type(pod_result_t), intent(out) :: res
    type(error_t), allocatable :: err
    select case (method)
    case ("tsqr"); call pod_tsqr(env1, s, res, err)
    case ("snapshots"); call pod_snapshots(env1, s, res, err)
    case ("scalapack"); call pod_scalapack(env1, s, res, err)
    end select
    call check(.not. allocated(err), "serial " // method // " runs")
  end subroutine serial

  subroutine test_well_conditioned()
    integer, parameter :: nd = 40, ns = 103
    real(wp) :: sig(nd), sref(nd), err
    real(wp), allocatable :: s(:, :), u(:, :), a(:, :), vt(:, :), uref(:, :)
    type(pod_result_t) :: t, t1, sn, sc, th
    type(error_t), allocatable :: e
    do i = 1, nd
      sig(i) = 1.0_wp / real(i, wp)
    end do
    call make_s(nd, ns, sig, 11, s, u)
    ! serial LAPACK reference
    a = s
    allocate(uref(nd, nd), vt(nd, ns))
    call la_gesvd(a, sref, e, u=uref)
    call check(.not. allocated(e), "reference dgesvd")

    call pod_tsqr(env, local_cols(s, .false.), t, e)
    call check(.not. allocated(e), "tsqr runs")
    call check(t%n_modes == nd .and. t%rank == nd, "tsqr: full rank 40")
    err = maxval(abs(t%sigma - sig) / sig)
    call check_close(err, 0.0_wp, 1.0e-12_wp, "tsqr: singular values to 1e-12 relative")
    call check_close(orth_err(t%phi), 0.0_wp, ORTH_C * nd, "tsqr: modes orthonormal")
    call check_close(mode_diff(t%phi, uref), 0.0_wp, 1.0e-10_wp, "tsqr: modes = dgesvd reference up to sign")
    call check_close(mode_diff(t%phi, u), 0.0_wp, 1.0e-10_wp, "tsqr: modes = generating U up to sign")
    call check(t%energy > 1.0_wp - 1.0e-12_wp, "tsqr: all energy retained")

    call pod_tsqr(env, local_cols(s, .true.), th, e)
    call check(.not. allocated(e), "tsqr with an empty rank runs")
    call check_close(maxval(abs(th%sigma - t%sigma)), 0.0_wp, 1.0e-14_wp, "tsqr: empty rank, same sigma")
    call check_close(maxval(abs(th%phi - t%phi)), 0.0_wp, 1.0e-12_wp, "tsqr: empty rank, same modes")

    call pod_snapshots(env, local_cols(s, .false.), sn, e)
    call check(.not. allocated(e), "snapshots runs")
    call check_close(maxval(abs(sn%sigma(1:20) - sig(1:20)) / sig(1:20)), 0.0_wp, 1.0e-10_wp, &
      & "snapshots: agrees for well-conditioned data (sigma)")
    call check_close(mode_diff(sn%phi(:, 1:20), t%phi(:, 1:20)), 0.0_wp, 1.0e-8_wp, &
      & "snapshots: agrees for well-conditioned data (modes)")

    call pod_scalapack(env, local_cols(s, .true.), sc, e)
    call check(.not. allocated(e), "scalapack runs")
    call check_close(maxval(abs(sc%sigma - t%sigma) / sig), 0.0_wp, 1.0e-12_wp, "scalapack: sigma = tsqr")
    call check_close(maxval(abs(sc%phi - t%phi)), 0.0_wp, 1.0e-10_wp, "scalapack: modes = tsqr (same signs)")

    if (env%rank == 0) then
      call serial("tsqr", s, t1)
      call check_close(maxval(abs(t1%sigma - t%sigma)), 0.0_wp, 1.0e-14_wp, "tsqr: np = 1 and np = N agree (sigma)")
      call check_close(maxval(abs(t1%phi - t%phi)), 0.0_wp, 1.0e-12_wp, "tsqr: np = 1 and np = N agree (modes)")
      call serial("scalapack", s, t1)
      call check_close(maxval(abs(t1%phi - sc%phi)), 0.0_wp, 1.0e-12_wp, "scalapack: np = 1 and np = N agree")
    end if

    ! wide case: n_snap < n_dof (S^T short and fat), Gram S^T S for snapshots
    call make_s(60, 25, sig(1:20), 12, s, u)
    call pod_tsqr(env, local_cols(s, .false.), t, e)
    call check(.not. allocated(e) .and. t%rank == 20, "wide: tsqr rank 20")
    call check_close(maxval(abs(t%sigma - sig(1:20)) / sig(1:20)), 0.0_wp, 1.0e-12_wp, "wide: tsqr sigma")
    call check_close(mode_diff(t%phi, u), 0.0_wp, 1.0e-10_wp, "wide: tsqr modes")
    call pod_snapshots(env, local_cols(s, .true.), sn, e)
    call check(.not. allocated(e) .and. sn%rank == 20, "wide: snapshots rank 20")
    call check_close(mode_diff(sn%phi, u), 0.0_wp, 1.0e-8_wp, "wide: snapshots modes")
    call pod_scalapack(env, local_cols(s, .false.), sc, e)
    call check(.not. allocated(e) .and. sc%rank == 20, "wide: scalapack rank 20")
    call check_close(maxval(abs(sc%phi - t%phi)), 0.0_wp, 1.0e-10_wp, "wide: scalapack modes = tsqr")
  end subroutine test_well_conditioned

  subroutine test_ill_conditioned()
    integer, parameter :: nd = 30, ns = 90
    real(wp) :: sig(nd)
    real(wp), allocatable :: s(:, :), u(:, :)
    type(pod_result_t) :: t, sn, t1
    type(error_t), allocatable :: e
    do i = 1, nd
      sig(i) = 10.0_wp**(-14.0_wp * real(i - 1, wp) / real(nd - 1, wp))
    end do
    call make_s(nd, ns, sig, 21, s, u)
    call pod_tsqr(env, local_cols(s, .false.), t, e)
    ! numerical rank: sigma_i > max(n_dof, n_snap) eps sigma_1 = 2e-14, so sigma_30 = 1e-14 is out
    call check(.not. allocated(e) .and. t%rank == count(sig > ns * EPSM), &
      & "ill-conditioned (1e14): tsqr keeps every mode above the rank threshold (29)")
    call check_close(orth_err(t%phi), 0.0_wp, ORTH_C * nd, "ill-conditioned: tsqr modes orthonormal")
    ! absolute accuracy eps * sigma_1 (scaled by size); relative 1e-12 where sigma >= 1e-3
    call check_close(maxval(abs(t%sigma_all - sig)), 0.0_wp, 100.0_wp * nd * EPSM, &
      & "ill-conditioned: tsqr sigma to c eps sigma_1")
    call check_close(maxval(abs(t%sigma(1:7) - sig(1:7)) / sig(1:7)), 0.0_wp, 1.0e-12_wp, &
      & "ill-conditioned: tsqr leading sigma to 1e-12 relative")
    call check_close(mode_diff(t%phi(:, 1:10), u(:, 1:10)), 0.0_wp, 1.0e-10_wp, &
      & "ill-conditioned: tsqr leading modes")
    call pod_snapshots(env, local_cols(s, .false.), sn, e)
    ! the Gram matrix squares the condition number: sigma below ~1e-8 are lost
    call check(.not. allocated(e) .and. sn%rank < 20, "ill-conditioned: snapshots loses the small modes")
    call check(abs(sn%sigma_all(25) - sig(25)) > 0.5_wp * sig(25), &
      & "ill-conditioned: snapshots sigma_25 is noise (documented)")
    call check_close(orth_err(sn%phi), 0.0_wp, 1.0e-13_wp, "ill-conditioned: snapshots modes orthonormal")
    if (env%rank == 0) then
      call serial("tsqr", s, t1)
      call check_close(maxval(abs(t1%sigma_all - t%sigma_all)), 0.0_wp, 1.0e-14_wp, &
        & "ill-conditioned: tsqr np = 1 and np = N agree")
    end if
  end subroutine test_ill_conditioned

  subroutine test_rsvd()
    integer, parameter :: nd = 80, ns = 150, k = 10, p = 10
    real(wp) :: sig(nd), tail, bound_g, bound_s, eg, es, e1
    real(wp), allocatable :: s(:, :), u(:, :)
    type(pod_result_t) :: g, sr, g1, gl, t
    type(error_t), allocatable :: e
    character(len=8) :: sk(2) = [character(len=8) :: "gaussian", "srft"]
    integer :: j, q
    do i = 1, nd
      sig(i) = 1.0_wp / real(i, wp)   ! slow decay
    end do
    call make_s(nd, ns, sig, 31, s, u)
    tail = sqrt(sum(sig(k + 1:)**2))
    ! Halko-Martinsson-Tropp: E ||(I - QQ^T) S||_F <= sqrt(1 + k / (p - 1)) tail_k (Gaussian,
    ! Thm 10.5); SRFT: sqrt(1 + 7 n / l) tail_k (Thm 11.2). Truncating B to k modes adds at
    ! most tail_k in quadrature.
    bound_g = sqrt(1.0_wp + real(k, wp) / real(p - 1, wp) + 1.0_wp) * tail
    bound_s = sqrt(1.0_wp + 7.0_wp * real(ns, wp) / real(k + p, wp) + 1.0_wp) * tail
    do j = 1, 2
      do q = 0, 1
        call pod_rsvd(env, local_cols(s, .false.), k, p, q, trim(sk(j)), 7, g, e)
        call check(.not. allocated(e), "rsvd " // trim(sk(j)) // " runs")
        call check(g%n_modes == k, "rsvd: k modes")
        call check_close(orth_err(g%phi), 0.0_wp, 1.0e-13_wp, "rsvd: modes orthonormal")
        eg = proj_err(s, g%phi)
        call check(eg >= tail * (1.0_wp - 1.0e-12_wp), "rsvd: error >= optimal (Eckart-Young)")
        if (j == 1) then
          call check(eg <= bound_g, "rsvd gaussian: error within the HMT bound")
        else
          call check(eg <= bound_s, "rsvd srft: error within the HMT bound")
        end if
        if (env%rank == 0 .and. q == 1) then
          write(*, '(a, a8, a, i0, 3(a, f8.5))') "rsvd ", sk(j), " q=", q, ": ||S - PP^TS||_F / tail_k = ", &
            & eg / tail, "  (bound ", merge(bound_g, bound_s, j == 1) / tail, ")"
        end if
        ! independent of the number of ranks (and of an empty rank)
        call pod_rsvd(env, local_cols(s, .true.), k, p, q, trim(sk(j)), 7, gl, e)
        call check_close(maxval(abs(gl%phi - g%phi)), 0.0_wp, 1.0e-10_wp, "rsvd: empty rank gives the same modes")
        if (env%rank == 0) then
          call pod_rsvd(env1, s, k, p, q, trim(sk(j)), 7, g1, e)
          call check_close(maxval(abs(g1%sigma - g%sigma)), 0.0_wp, 1.0e-13_wp, "rsvd: np = 1 and np = N agree (sigma)")
          call check_close(maxval(abs(g1%phi - g%phi)), 0.0_wp, 1.0e-10_wp, "rsvd: np = 1 and np = N agree (modes)")
        end if
      end do
    end do
    ! power iterations help on a slow spectrum; full oversampling recovers the exact POD
    call pod_rsvd(env, local_cols(s, .false.), k, p, 0, "gaussian", 7, g, e)
    call pod_rsvd(env, local_cols(s, .false.), k, p, 2, "gaussian", 7, sr, e)
    eg = proj_err(s, g%phi); es = proj_err(s, sr%phi)
    call check(es <= eg, "rsvd: q = 2 is no worse than q = 0")
    call check_close(es / tail, 1.0_wp, 0.05_wp, "rsvd: q = 2 within 5% of the optimal error")
    call pod_tsqr(env, local_cols(s, .false.), t, e, n_modes=k)
    call pod_rsvd(env, local_cols(s, .false.), k, nd, 0, "srft", 3, sr, e)
    e1 = mode_diff(sr%phi, t%phi)
    call check_close(e1, 0.0_wp, 1.0e-10_wp, "rsvd: l = n_dof gives the exact modes")
    call pod_rsvd(env, local_cols(s, .false.), k, p, 0, "fourier", 7, g, e)
    call check(allocated(e), "rsvd: unknown sketch is an error")
    if (allocated(e) .and. env%rank == 0) call check(index(e%message, "gaussian, srft") > 0, &
      & "rsvd: message lists the sketches")
  end subroutine test_rsvd

  subroutine test_rank_deficient()
    integer, parameter :: nd = 30
    real(wp), allocatable :: s(:, :), u(:, :), a(:, :), z(:, :)
    type(pod_result_t) :: r(5)
    type(error_t), allocatable :: e
    real(wp) :: sig(5) = [3.0_wp, 2.0_wp, 1.0_wp, 0.5_wp, 0.25_wp]
    integer :: m
    character(len=16) :: names(5) = [character(len=16) :: "tsqr", "snapshots", "scalapack", &
      & "rsvd-gaussian", "rsvd-srft"]
    ! repeated columns: [A A A], rank 5; and zero snapshots in between
    call make_s(nd, 15, sig, 41, a, u)
    allocate(s(nd, 51))
    s = 0.0_wp
    s(:, 1:15) = a; s(:, 19:33) = a; s(:, 37:51) = a
    call run_all(s, .false., r)
    do m = 1, 5
      call check(r(m)%rank == 5 .and. r(m)%n_modes == 5, trim(names(m)) // ": repeated/zero columns: rank 5")
      call check(finite(r(m)%sigma_all) .and. finite(reshape(r(m)%phi, [size(r(m)%phi)])), &
        & trim(names(m)) // ": repeated columns: no NaN")
      call check_close(mode_diff(r(m)%phi, u), 0.0_wp, 1.0e-7_wp, trim(names(m)) // ": repeated columns: modes")
      call check_close(r(m)%energy, 1.0_wp, 1.0e-12_wp, trim(names(m)) // ": repeated columns: energy 1")
    end do
    ! all-zero matrix (and an empty rank): rank 0, no modes, no NaN
    allocate(z(nd, 20))
    z = 0.0_wp
    call run_all(z, .true., r)
    do m = 1, 5
      call check(r(m)%rank == 0 .and. r(m)%n_modes == 0 .and. size(r(m)%phi, 2) == 0, &
        & trim(names(m)) // ": zero matrix: no modes")
      call check(finite(r(m)%sigma_all) .and. r(m)%energy == 0.0_wp, trim(names(m)) // ": zero matrix: no NaN")
    end do
    call pod_tsqr(env, local_cols(z, .false.), r(1), e, eps=0.0_wp)
    call check(.not. allocated(e) .and. r(1)%n_modes == 0, "zero matrix, eps = 0: no modes")
    call pod_tsqr(env, local_cols(z, .false.), r(1), e, eps=1.0_wp)
    call check(.not. allocated(e) .and. r(1)%n_modes == 0, "zero matrix, eps = 1: no modes")
  end subroutine test_rank_deficient

  !> Every method on x (rsvd with k = 8, p = 4, q = 1).
  subroutine run_all(x, hole, r)
    type(pod_result_t), intent(out) :: r(5)
    type(error_t), allocatable :: e
    real(wp), intent(in) :: x(:, :)
    logical, intent(in) :: hole
    call pod_tsqr(env, local_cols(x, hole), r(1), e)
    call check(.not. allocated(e), "tsqr runs")
    call pod_snapshots(env, local_cols(x, hole), r(2), e)
    call check(.not. allocated(e), "snapshots runs")
    call pod_scalapack(env, local_cols(x, hole), r(3), e)
    call check(.not. allocated(e), "scalapack runs")
    call pod_rsvd(env, local_cols(x, hole), 8, 4, 1, "gaussian", 5, r(4), e)
    call check(.not. allocated(e), "rsvd gaussian runs")
    call pod_rsvd(env, local_cols(x, hole), 8, 4, 1, "srft", 5, r(5), e)
    call check(.not. allocated(e), "rsvd srft runs")
  end subroutine run_all

  subroutine test_truncation_and_errors()
    real(wp) :: sig(4) = [4.0_wp, 2.0_wp, 1.0_wp, 1.0_wp]   ! energies 16, 4, 1, 1 of 22
    real(wp), allocatable :: s(:, :), u(:, :)
    type(pod_result_t) :: t
    type(error_t), allocatable :: e
    call make_s(12, 9, sig, 51, s, u)
    call pod_tsqr(env, local_cols(s, .false.), t, e, eps=0.0_wp)
    call check(t%n_modes == 4, "eps = 0: all modes up to the rank (4)")
    call pod_tsqr(env, local_cols(s, .false.), t, e, eps=1.0_wp)
    call check(t%n_modes == 0, "eps = 1: no mode needed")
    call pod_tsqr(env, local_cols(s, .false.), t, e, eps=0.1_wp)
    call check(t%n_modes == 2, "eps = 0.1: 2 modes (residual 2/22)")
    call check_rel(t%energy, 20.0_wp / 22.0_wp, 1.0e-12_wp, "eps = 0.1: energy 20/22")
    call pod_tsqr(env, local_cols(s, .false.), t, e, eps=0.05_wp)
    call check(t%n_modes == 3, "eps = 0.05: 3 modes (residual 1/22)")
    call pod_scalapack(env, local_cols(s, .false.), t, e, eps=0.05_wp)
    call check(t%n_modes == 3, "scalapack eps = 0.05: 3 modes")
    call pod_snapshots(env, local_cols(s, .false.), t, e, n_modes=2)
    call check(t%n_modes == 2, "snapshots n_modes = 2")
    call pod_tsqr(env, local_cols(s, .false.), t, e, n_modes=7)
    call check(t%n_modes == 4, "n_modes = 7 capped at the rank (4)")
    call pod_tsqr(env, local_cols(s, .false.), t, e, eps=1.5_wp)
    call check(allocated(e), "eps = 1.5 is an error")
    if (allocated(e)) call check(index(e%message, "not in [0, 1]") > 0, "eps error message")
    call pod_rsvd(env, local_cols(s, .false.), 0, 2, 0, "gaussian", 1, t, e)
    call check(allocated(e), "rsvd k = 0 is an error")
  end subroutine test_truncation_and_errors
  !> Sign rule with near-ties: an S whose leading mode's two largest entries differ in magnitude by a
  !> relative 1e-12 (far below sqrt(eps), i.e. a tie to the rule; a mirror-symmetric scene gives
  !> such pairs, unequal by a few eps in a CPU-dependent order): the lower index is positive for
  !> every method, whichever entry LAPACK returns larger. A relative 1e-6 difference is genuine:
  !> the larger entry is positive.
  subroutine test_sign_rule()
    real(wp) :: s(3, 2), d
    type(pod_result_t) :: t
    type(error_t), allocatable :: e
    integer :: m, k
    character(len=9), parameter :: names(3) = [character(len=9) :: "tsqr", "snapshots", "scalapack"]
    do k = 1, 2
      d = merge(1.0e-12_wp, 1.0e-6_wp, k == 1)
      ! orthogonal columns: the modes are the normalised columns, sigma = 3 |s1| and 0.1 |s2|
      ! (full rank: pdgesvd reports a rank-1 3 x 2 S at 4 ranks as heterogeneous, info = n + 1)
      s(:, 1) = 3.0_wp * [1.0_wp, -(1.0_wp + d), 0.3_wp]
      s(:, 2) = 0.1_wp * [1.0_wp + d, 1.0_wp, 0.0_wp]
      do m = 1, 3
        select case (m)
        case (1); call pod_tsqr(env, local_cols(s, .false.), t, e)
        case (2); call pod_snapshots(env, local_cols(s, .false.), t, e)
        case (3); call pod_scalapack(env, local_cols(s, .false.), t, e)
        end select
        if (allocated(e) .and. env%rank == 0) print "(a)", "sign rule: " // e%message
        call check(.not. allocated(e), "sign rule: " // trim(names(m)) // " runs")
        if (allocated(e)) cycle
        call check(t%n_modes == 2, "sign rule: " // trim(names(m)) // " rank 2")
        if (t%n_modes /= 2) cycle
        if (k == 1) then
          call check(t%phi(1, 1) > 0.0_wp, "sign rule: " // trim(names(m)) // " near-tie -> lowest index positive")
        else
          call check(t%phi(2, 1) > 0.0_wp, "sign rule: " // trim(names(m)) // " 1e-6 apart -> largest positive")
        end if
      end do
    end do
  end subroutine test_sign_rule

end program test_pod
