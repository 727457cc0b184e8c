!> The paper's appendix (Hertz contact): greedy cone construction on pressure profiles
!> lambda_{a,p}(r) = p sqrt(1 - r^2/a^2) on |r| <= a selects (a_max, p_max) first, then
!> (a_min, p_max); the non-negative projection coefficients onto cone(psi_1, psi_2) equal
!> the closed forms of Proposition 'lambdas-explicit' with complete elliptic integrals.
program test_hertz
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_assert, only: check, check_close, test_summary
  use cr_cone, only: sparse_columns_t, cone_result_t, mcpg_build, cone_project_gram
  implicit none
  real(wp), parameter :: pi = acos(-1.0_wp)
  real(wp), parameter :: a_lo = 0.5_wp, a_hi = 1.0_wp, p_lo = 1.0_wp, p_hi = 2.0_wp
  integer, parameter :: na = 11, np = 6, m = 20000
  type(env_t) :: env
  type(error_t), allocatable :: error
  integer :: ierr
  real(wp) :: xg(48), wg(48)
  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call gauss_legendre(xg, wg)
  call test_elliptic_j()
  call test_selection()
  call test_coefficients()
  call env%free()
  call MPI_Finalize(ierr)
  call test_summary()

contains

  real(wp) function a_of(i)
    integer, intent(in) :: i
    a_of = a_lo + (a_hi - a_lo) * (i - 1) / real(na - 1, wp)
  end function a_of

  real(wp) function p_of(j)
    integer, intent(in) :: j
    p_of = p_lo + (p_hi - p_lo) * (j - 1) / real(np - 1, wp)
  end function p_of

  !> Gauss-Legendre nodes and weights on [-1, 1] (Newton on P_n).
  subroutine gauss_legendre(x, w)
    real(wp), intent(out) :: x(:), w(:)
    integer :: n, i, k, it
    real(wp) :: z, p0, p1, p2, dp
    n = size(x)
    do i = 1, n
      z = cos(pi * (i - 0.25_wp) / (n + 0.5_wp))
      do it = 1, 100
        p0 = 1; p1 = z
        do k = 2, n
          p2 = ((2 * k - 1) * z * p1 - (k - 1) * p0) / k
          p0 = p1; p1 = p2
        end do
        dp = n * (z * p1 - p0) / (z * z - 1)
        z = z - p1 / dp
        if (abs(p1 / dp) < 1e-16_wp) exit
      end do
      x(i) = z
      w(i) = 2 / ((1 - z * z) * dp * dp)
    end do
  end subroutine gauss_legendre

  !> J(u, v) = <phi_u, phi_v> (u <= v) by quadrature of the smooth form
  !> 2u int_0^{pi/2} cos^2 t sqrt(1 - (u/v)^2 sin^2 t) dt.
  real(wp) function j_quad(u, v)
    real(wp), intent(in) :: u, v
    real(wp) :: t, rho
    integer :: k
    rho = min(u, v) / max(u, v)
    j_quad = 0
    do k = 1, size(xg)
      t = (xg(k) + 1) * pi / 4
      j_quad = j_quad + wg(k) * cos(t)**2 * sqrt(1 - rho**2 * sin(t)**2)
    end do
    j_quad = 2 * min(u, v) * j_quad * pi / 4
  end function j_quad

  !> Complete elliptic integrals K(k), E(k) by the arithmetic-geometric mean.
  subroutine elliptic_ke(k, kk, ee)
    real(wp), intent(in) :: k
    real(wp), intent(out) :: kk, ee
    real(wp) :: a, b, c, s, an, pw
    integer :: it
    a = 1; b = sqrt(1 - k * k); c = k
    s = 0.5_wp * c * c
    pw = 0.5_wp
    do it = 1, 60
      an = (a + b) / 2
      c = (a - b) / 2
      b = sqrt(a * b)
      a = an
      pw = 2 * pw
      s = s + pw * c * c
      if (abs(c) < 1e-17_wp) exit
    end do
    kk = pi / (2 * a)
    ee = kk * (1 - s)
  end subroutine elliptic_ke

  !> Proposition 'J-integral': J(u, v) with complete elliptic integrals, rho = u / v.
  real(wp) function j_elliptic(u, v)
    real(wp), intent(in) :: u, v
    real(wp) :: rho, kk, ee
    rho = min(u, v) / max(u, v)
    if (rho >= 1) then
      j_elliptic = 4 * u / 3; return
    end if
    call elliptic_ke(rho, kk, ee)
    j_elliptic = 2 * min(u, v) / (3 * rho**2) * ((rho**2 - 1) * kk + (rho**2 + 1) * ee)
  end function j_elliptic

  subroutine test_elliptic_j()
    integer :: i
    real(wp) :: worst
    worst = 0
    do i = 1, na
      worst = max(worst, abs(j_quad(a_of(i), a_hi) - j_elliptic(a_of(i), a_hi)))
    end do
    call check(worst < 1e-13_wp, "J by quadrature equals the elliptic-integral form")
    call check_close(j_elliptic(0.7_wp, 0.7_wp), 4 * 0.7_wp / 3, 1e-15_wp, "J(u,u) = 4u/3")
  end subroutine test_elliptic_j

  !> mCPG on the discretised profiles (midpoint rule, sqrt weights) picks the two extremes.
  subroutine test_selection()
    type(sparse_columns_t) :: lam
    type(cone_result_t) :: res
    type(error_t), allocatable :: err
    real(wp) :: dr, r, val
    integer :: i, j, k, col, nnz
    dr = 2 * a_hi / m
    lam%n_rows = m; lam%n_cols = na * np; lam%col_offset = 0
    allocate(lam%ptr(na * np + 1), lam%idx(na * np * m), lam%val(na * np * m))
    lam%ptr(1) = 0; nnz = 0
    do j = 1, np
      do i = 1, na
        col = (j - 1) * na + i
        do k = 1, m
          r = -a_hi + (k - 0.5_wp) * dr
          if (abs(r) < a_of(i)) then
            val = p_of(j) * sqrt(1 - (r / a_of(i))**2) * sqrt(dr)
            nnz = nnz + 1; lam%idx(nnz) = k; lam%val(nnz) = val
          end if
        end do
        lam%ptr(col + 1) = nnz
      end do
    end do
    call mcpg_build(env, lam, 0.0_wp, 2, res, err)
    call check(.not. allocated(err) .and. res%r == 2, "mcpg on Hertz profiles: two steps")
    if (res%r == 2) then
      call check(res%sigma(1) == int((np - 1) * na + na, i8), "first selection: (a_max, p_max)")
      call check(res%sigma(2) == int((np - 1) * na + 1, i8), "second selection: (a_min, p_max)")
    end if
  end subroutine test_selection

  !> NNLS coefficients onto cone(psi_1, psi_2) vs the closed forms, on the whole grid.
  subroutine test_coefficients()
    real(wp) :: g(2, 2), rg(2, 2), c(2), k(2), res2, a, p, aa, bb, cc, xx, yy, l1, l2, worst, eps
    type(error_t), allocatable :: err
    integer :: i, j
    ! psi_1 = p_hi phi_{a_hi}, psi_2 = p_hi phi_{a_lo}; inner products by quadrature
    g(1, 1) = p_hi**2 * j_quad(a_hi, a_hi); g(2, 2) = p_hi**2 * j_quad(a_lo, a_lo)
    g(1, 2) = p_hi**2 * j_quad(a_lo, a_hi); g(2, 1) = g(1, 2)
    eps = 1e-12_wp * maxval([g(1, 1), g(2, 2)])
    rg = 0
    rg(1, 1) = sqrt(g(1, 1) + eps)
    rg(1, 2) = g(1, 2) / rg(1, 1)
    rg(2, 2) = sqrt(g(2, 2) + eps - rg(1, 2)**2)
    ! closed forms (elliptic integrals)
    aa = 4 * a_hi / 3; bb = 4 * a_lo / 3; cc = j_elliptic(a_lo, a_hi)
    worst = 0
    do j = 1, np
      do i = 1, na
        a = a_of(i); p = p_of(j)
        c = [p * p_hi * j_quad(a, a_hi), p * p_hi * j_quad(a_lo, a)]
        call cone_project_gram(rg, g, c, p**2 * 4 * a / 3, k, res2, err)
        xx = j_elliptic(a, a_hi); yy = j_elliptic(a_lo, a)
        l1 = p / p_hi * (bb * xx - cc * yy) / (aa * bb - cc**2)
        l2 = p / p_hi * (aa * yy - cc * xx) / (aa * bb - cc**2)
        worst = max(worst, abs(k(1) - l1), abs(k(2) - l2))
      end do
    end do
    call check(.not. allocated(err), "projections solved")
    call check(worst <= 1e-8_wp, "projection coefficients equal the closed forms to 1e-8")
    print '(a, es10.3)', "largest coefficient difference: ", worst
  end subroutine test_coefficients
end program test_hertz
