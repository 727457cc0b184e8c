!> LAPACK wrappers: results on small known problems and the translation of size errors and
!> `info` codes into messages.
program test_lapack
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_lapack, only: la_geqrf, la_orgqr, la_gesvd, la_syevd, la_gemm, lapack_info_message
  use cr_assert, only: check, check_close, test_summary
  implicit none
  type(error_t), allocatable :: e
  real(wp) :: a(4, 3), q(4, 3), r(3, 3), tau(3), s(3), u(4, 3), vt(3, 3), c(3, 3), w(3)
  real(wp) :: bad_tau(2), bad_u(3, 3), cc(2, 2)
  integer :: j
  ! Tolerances from the backward stability of Householder QR, the SVD and the symmetric
  ! eigensolver (Higham, Accuracy and Stability, Thms 19.4 and 19.13; LAPACK Users' Guide 4.9
  ! and 4.7): errors <= p(m, n) eps ||A|| with p a modest function of the sizes, here
  ! p = c m n with c = 4 (m = 4, n = 3: 48 eps). Not what one CPU gave: the AVX-512 kernels
  ! give |Q^T Q - I| = 4 eps where other kernels give 1 eps (docs/testing.md).
  real(wp), parameter :: P_MN = 4.0_wp * 4.0_wp * 3.0_wp * epsilon(1.0_wp)
  real(wp) :: anorm

  a = reshape([1.0_wp, 2.0_wp, 3.0_wp, 4.0_wp, 2.0_wp, 1.0_wp, 0.0_wp, 5.0_wp, &
    & -1.0_wp, 0.5_wp, 2.0_wp, 1.0_wp], [4, 3])
  anorm = norm2(a)   ! ||A||_F >= ||A||_2

  ! QR reproduces A, Q orthonormal
  q = a
  call la_geqrf(q, tau, e)
  call check(.not. allocated(e), "geqrf runs")
  r = 0.0_wp
  do j = 1, 3
    r(1:j, j) = q(1:j, j)
  end do
  call la_orgqr(q, tau, e)
  call check(.not. allocated(e), "orgqr runs")
  call check_close(maxval(abs(matmul(q, r) - a)), 0.0_wp, P_MN * anorm, "QR = A")
  ! computed Q = exactly orthogonal + dQ, |dQ(:, j)| <= p eps: |Q^T Q - I| <= 2 p eps
  call check_close(maxval(abs(matmul(transpose(q), q) - identity(3))), 0.0_wp, 2.0_wp * P_MN, "Q^T Q = I")

  ! SVD reproduces A
  q = a
  call la_gesvd(q, s, e, u=u, vt=vt)
  call check(.not. allocated(e), "gesvd runs")
  do j = 1, 3
    u(:, j) = s(j) * u(:, j)
  end do
  call check_close(maxval(abs(matmul(u, vt) - a)), 0.0_wp, P_MN * anorm, "U S VT = A")
  call check(s(1) >= s(2) .and. s(2) >= s(3), "singular values descending")

  ! symmetric eigen-decomposition of A^T A: eigenvalues = s^2 ascending
  c = matmul(transpose(a), a)
  call la_syevd(c, w, e)
  call check(.not. allocated(e), "syevd runs")
  ! |dlambda| <= p eps ||A^T A||_2 (dsyevd) and |d(s^2)| <= 2 s p eps ||A||_2 (dgesvd): 3 p eps ||A||^2
  call check_close(maxval(abs(w - s(3:1:-1)**2)), 0.0_wp, 3.0_wp * P_MN * anorm**2, "eig(A^T A) = s^2")

  ! size errors are reported with the sizes, nothing is called
  q = a
  call la_geqrf(q, bad_tau, e)
  call check(allocated(e), "geqrf: short tau is an error")
  if (allocated(e)) call check(index(e%message, "dgeqrf: tau has 2 entries, expected min(m, n) = 3 (m = 4, n = 3)") > 0, &
    & "geqrf: message names the sizes")
  call la_gesvd(q, s, e, u=bad_u)
  call check(allocated(e), "gesvd: wrong u is an error")
  if (allocated(e)) call check(index(e%message, "u is 3 x 3, expected 4 x 3") > 0, "gesvd: message names the shapes")
  call la_gemm('N', 'N', 1.0_wp, a, a, 0.0_wp, cc, e)
  call check(allocated(e), "gemm: mismatch is an error")
  if (allocated(e)) call check(index(e%message, "op(a) is 4 x 3, op(b) is 4 x 3") > 0, "gemm: message names the shapes")
  call la_orgqr(q(1:2, :), tau, e)
  call check(allocated(e), "orgqr: n > m is an error")
  call la_syevd(a(1:3, 1:2), w, e)
  call check(allocated(e), "syevd: non-square is an error")

  ! the SVD with vectors (divide and conquer) on sizes above dgesdd's small-matrix switch (25),
  ! tall and wide, u only, vt only, both: U S VT = A, orthonormal factors, and the same values
  ! as the values-only call, all within the backward-error bound p eps ||A|| (p = 4 m n)
  call svd_shapes(60, 40)
  call svd_shapes(40, 60)

  ! info translation
  call check(lapack_info_message("dgeqrf", -7, "m = 4, n = 3") == &
    & "dgeqrf: argument 7 had an illegal value (m = 4, n = 3)", "info < 0: illegal argument")
  call check(index(lapack_info_message("dgesvd", 2, "m = 4, n = 3"), "2 superdiagonals") > 0, &
    & "dgesvd info > 0: convergence failure")
  call check(index(lapack_info_message("dsyevd", 5, "n = 3"), "failed to converge (info = 5, n = 3)") > 0, &
    & "dsyevd info > 0")
  call test_summary()
contains
  subroutine svd_shapes(m, n)
    integer, intent(in) :: m, n
    real(wp), allocatable :: a0(:, :), x(:, :), uu(:, :), vv(:, :), u1(:, :), v1(:, :), sv(:), s0(:)
    real(wp) :: p, nrm
    integer :: k, i, jj
    character(len=16) :: tag
    k = min(m, n)
    write(tag, '(i0, " x ", i0)') m, n
    allocate(a0(m, n))
    ! a fixed, well-spread test matrix (no random stream: the same on every machine)
    do jj = 1, n
      do i = 1, m
        a0(i, jj) = sin(real(i * jj, wp) + 0.3_wp * i) + merge(2.0_wp, 0.0_wp, i == jj)
      end do
    end do
    nrm = norm2(a0)
    p = 4.0_wp * m * n * epsilon(1.0_wp)
    allocate(sv(k), s0(k), uu(m, k), vv(k, n), u1(m, k), v1(k, n))
    x = a0
    call la_gesvd(x, s0, e)
    call check(.not. allocated(e), "gesvd values only runs (" // trim(tag) // ")")
    x = a0
    call la_gesvd(x, sv, e, u=uu, vt=vv)
    call check(.not. allocated(e), "gesvd with u and vt runs (" // trim(tag) // ")")
    call check_close(maxval(abs(sv - s0)), 0.0_wp, 2.0_wp * p * nrm, "same values as the values-only call (" // &
      & trim(tag) // ")")
    call check(all(sv(1:k-1) >= sv(2:k)), "values descending (" // trim(tag) // ")")
    call check_close(maxval(abs(matmul(transpose(uu), uu) - identity(k))), 0.0_wp, p, "U^T U = I (" // trim(tag) // ")")
    call check_close(maxval(abs(matmul(vv, transpose(vv)) - identity(k))), 0.0_wp, p, "V^T V = I (" // trim(tag) // ")")
    do jj = 1, k
      u1(:, jj) = sv(jj) * uu(:, jj)
    end do
    call check_close(maxval(abs(matmul(u1, vv) - a0)), 0.0_wp, p * nrm, "U S VT = A (" // trim(tag) // ")")
    ! one factor only: the same factor as with both (the same computation)
    x = a0
    call la_gesvd(x, sv, e, u=u1)
    call check(.not. allocated(e), "gesvd with u only runs (" // trim(tag) // ")")
    call check(all(u1 == uu), "u only = u of the call with both (" // trim(tag) // ")")
    x = a0
    call la_gesvd(x, sv, e, vt=v1)
    call check(.not. allocated(e), "gesvd with vt only runs (" // trim(tag) // ")")
    call check(all(v1 == vv), "vt only = vt of the call with both (" // trim(tag) // ")")
  end subroutine svd_shapes

  pure function identity(n) result(id)
    integer, intent(in) :: n
    real(wp) :: id(n, n)
    integer :: i
    id = 0.0_wp
    do i = 1, n
      id(i, i) = 1.0_wp
    end do
  end function identity
end program test_lapack
