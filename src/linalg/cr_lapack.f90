!> Thin checked wrappers over LAPACK, BLAS and ScaLAPACK.
!>
!> Explicit interfaces for every external routine (gfortran rejects one external routine
!> called with scalar and array actuals), assumed-shape contiguous arrays, workspace
!> queries (lwork = -1), sizes checked before the call, and every `info` translated into a
!> message naming the routine and the sizes. The SVD routines run with floating-point
!> halting paused: LAPACK's ieeeck divides by zero on purpose.
module cr_lapack
  use, intrinsic :: ieee_arithmetic, only: ieee_get_halting_mode, ieee_set_halting_mode, &
    & ieee_usual, ieee_set_flag, ieee_all
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  implicit none
  private
  public :: la_geqrf, la_orgqr, la_gesvd, la_syevd, la_gemm, la_pdgesvd
  public :: lapack_info_message, pause_fpe_halting, restore_fpe_halting
  public :: la_syrk, la_gemv

  interface
    subroutine dgeqrf(m, n, a, lda, tau, work, lwork, info)
      import :: wp
      integer, intent(in) :: m, n, lda, lwork
      real(wp), intent(inout) :: a(lda, *)
      real(wp), intent(out) :: tau(*), work(*)
      integer, intent(out) :: info
    end subroutine dgeqrf
    subroutine dorgqr(m, n, k, a, lda, tau, work, lwork, info)
      import :: wp
      integer, intent(in) :: m, n, k, lda, lwork
      real(wp), intent(inout) :: a(lda, *)
      real(wp), intent(in) :: tau(*)
      real(wp), intent(out) :: work(*)
      integer, intent(out) :: info
    end subroutine dorgqr
    subroutine dgesvd(jobu, jobvt, m, n, a, lda, s, u, ldu, vt, ldvt, work, lwork, info)
      import :: wp
      character, intent(in) :: jobu, jobvt
      integer, intent(in) :: m, n, lda, ldu, ldvt, lwork
      real(wp), intent(inout) :: a(lda, *)
      real(wp), intent(out) :: s(*), u(ldu, *), vt(ldvt, *), work(*)
      integer, intent(out) :: info
    end subroutine dgesvd
    subroutine dgesdd(jobz, m, n, a, lda, s, u, ldu, vt, ldvt, work, lwork, iwork, info)
      import :: wp
      character, intent(in) :: jobz
      integer, intent(in) :: m, n, lda, ldu, ldvt, lwork
      real(wp), intent(inout) :: a(lda, *)
      real(wp), intent(out) :: s(*), u(ldu, *), vt(ldvt, *), work(*)
      integer, intent(out) :: iwork(*), info
    end subroutine dgesdd
    subroutine dsyevd(jobz, uplo, n, a, lda, w, work, lwork, iwork, liwork, info)
      import :: wp
      character, intent(in) :: jobz, uplo
      integer, intent(in) :: n, lda, lwork, liwork
      real(wp), intent(inout) :: a(lda, *)
      real(wp), intent(out) :: w(*), work(*)
      integer, intent(out) :: iwork(*), info
    end subroutine dsyevd
    subroutine dgemm(transa, transb, m, n, k, alpha, a, lda, b, ldb, beta, c, ldc)
      import :: wp
      character, intent(in) :: transa, transb
      integer, intent(in) :: m, n, k, lda, ldb, ldc
      real(wp), intent(in) :: alpha, beta, a(lda, *), b(ldb, *)
      real(wp), intent(inout) :: c(ldc, *)
    end subroutine dgemm
    subroutine dsyrk(uplo, trans, n, k, alpha, a, lda, beta, c, ldc)
      import :: wp
      character, intent(in) :: uplo, trans
      integer, intent(in) :: n, k, lda, ldc
      real(wp), intent(in) :: alpha, beta, a(lda, *)
      real(wp), intent(inout) :: c(ldc, *)
    end subroutine dsyrk
    subroutine pdgesvd(jobu, jobvt, m, n, a, ia, ja, desca, s, u, iu, ju, descu, &
        & vt, ivt, jvt, descvt, work, lwork, info)
      import :: wp
      character, intent(in) :: jobu, jobvt
      integer, intent(in) :: m, n, ia, ja, iu, ju, ivt, jvt, lwork
      integer, intent(in) :: desca(9), descu(9), descvt(9)
      real(wp), intent(inout) :: a(*)
      real(wp), intent(out) :: s(*), u(*), vt(*), work(*)
      integer, intent(out) :: info
    end subroutine pdgesvd
  end interface

contains

  !> Message for a nonzero LAPACK `info`: illegal argument (info < 0) or routine-specific
  !> failure (info > 0); `sizes` describes the problem, e.g. "m = 3, n = 4".
  pure function lapack_info_message(routine, info, sizes) result(msg)
    character(len=*), intent(in) :: routine, sizes
    integer, intent(in) :: info
    character(len=:), allocatable :: msg
    if (info < 0) then
      msg = routine // ": argument " // str(-info) // " had an illegal value (" // sizes // ")"
    else
      select case (routine)
      case ("dgesvd", "pdgesvd")
        msg = routine // ": " // str(info) // " superdiagonals of the bidiagonal form did not " // &
          & "converge to zero (" // sizes // ")"
      case ("dsyevd")
        msg = routine // ": the eigenvalue algorithm failed to converge (info = " // str(info) // &
          & ", " // sizes // ")"
      case default
        msg = routine // ": failed with info = " // str(info) // " (" // sizes // ")"
      end select
    end if
  end function lapack_info_message

  !> Switch off halting on overflow, division by zero and invalid (saved in `saved`).
  subroutine pause_fpe_halting(saved)
    logical, intent(out) :: saved(size(ieee_usual))
    call ieee_get_halting_mode(ieee_usual, saved)
    call ieee_set_halting_mode(ieee_usual, .false.)
  end subroutine pause_fpe_halting

  !> Clear the exception flags raised meanwhile and restore the halting modes.
  subroutine restore_fpe_halting(saved)
    logical, intent(in) :: saved(size(ieee_usual))
    call ieee_set_flag(ieee_all, .false.)
    call ieee_set_halting_mode(ieee_usual, saved)
  end subroutine restore_fpe_halting

  !> Householder QR in place: a [m, n] -> R in the upper triangle and reflectors below;
  !> tau [min(m, n)].
  subroutine la_geqrf(a, tau, error)
    real(wp), contiguous, intent(inout) :: a(:, :)
    real(wp), contiguous, intent(out) :: tau(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: m, n, info, lwork
    real(wp) :: wq(1)
    real(wp), allocatable :: work(:)
    m = size(a, 1); n = size(a, 2)
    if (size(tau) /= min(m, n)) then
      call set_error(error, "dgeqrf: tau has " // str(size(tau)) // " entries, expected min(m, n) = " // &
        & str(min(m, n)) // " (m = " // str(m) // ", n = " // str(n) // ")")
      return
    end if
    if (m == 0 .or. n == 0) return
    call dgeqrf(m, n, a, m, tau, wq, -1, info)
    lwork = max(1, n, int(wq(1)))
    allocate(work(lwork))
    call dgeqrf(m, n, a, m, tau, work, lwork, info)
    if (info /= 0) call set_error(error, lapack_info_message("dgeqrf", info, &
      & "m = " // str(m) // ", n = " // str(n)))
  end subroutine la_geqrf

  !> Form the m x n matrix Q with orthonormal columns from the first size(tau) reflectors
  !> stored in a [m, n] (n <= m) by la_geqrf.
  subroutine la_orgqr(a, tau, error)
    real(wp), contiguous, intent(inout) :: a(:, :)
    real(wp), contiguous, intent(in) :: tau(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: m, n, k, info, lwork
    real(wp) :: wq(1)
    real(wp), allocatable :: work(:)
    m = size(a, 1); n = size(a, 2); k = size(tau)
    if (n > m .or. k > n) then
      call set_error(error, "dorgqr: need k <= n <= m, got m = " // str(m) // ", n = " // str(n) // &
        & ", k = " // str(k))
      return
    end if
    if (n == 0) return
    call dorgqr(m, n, k, a, m, tau, wq, -1, info)
    lwork = max(1, n, int(wq(1)))
    allocate(work(lwork))
    call dorgqr(m, n, k, a, m, tau, work, lwork, info)
    if (info /= 0) call set_error(error, lapack_info_message("dorgqr", info, &
      & "m = " // str(m) // ", n = " // str(n) // ", k = " // str(k)))
  end subroutine la_orgqr

  !> Thin SVD a = U diag(s) VT of a [m, n] (destroyed); s [min(m, n)] descending;
  !> optional u [m, min(m, n)] and vt [min(m, n), n]. With vectors: LAPACK's divide and
  !> conquer dgesdd (the same backward-stable bidiagonalisation; dgesvd's QR iteration spends
  !> its time in reference dbdsqr's rotations: TSQR POD of 2 000 x 8 400, 20.1 -> 2.9 s),
  !> computing both U and VT (a temporary for the one not asked for); if dgesdd does not
  !> converge (info > 0, rare), dgesvd on a copy of a kept for it. Values only: dgesvd.
  subroutine la_gesvd(a, s, error, u, vt)
    real(wp), contiguous, intent(inout) :: a(:, :)
    real(wp), contiguous, intent(out) :: s(:)
    type(error_t), allocatable, intent(out) :: error
    real(wp), contiguous, intent(out), optional, target :: u(:, :), vt(:, :)
    integer :: m, n, k, info, lwork, ldu, ldvt
    character :: jobu, jobvt
    real(wp) :: wq(1)
    real(wp), target :: dummy(1, 1)
    real(wp), pointer :: pu(:, :), pvt(:, :)
    real(wp), allocatable :: work(:), a0(:, :)
    logical :: saved(size(ieee_usual))
    character(len=:), allocatable :: sizes
    m = size(a, 1); n = size(a, 2); k = min(m, n)
    sizes = "m = " // str(m) // ", n = " // str(n)
    if (size(s) /= k) then
      call set_error(error, "dgesvd: s has " // str(size(s)) // " entries, expected min(m, n) = " // &
        & str(k) // " (" // sizes // ")")
      return
    end if
    jobu = 'N'; jobvt = 'N'; pu => dummy; pvt => dummy; ldu = 1; ldvt = 1
    if (present(u)) then
      if (size(u, 1) /= m .or. size(u, 2) /= k) then
        call set_error(error, "dgesvd: u is " // str(size(u, 1)) // " x " // str(size(u, 2)) // &
          & ", expected " // str(m) // " x " // str(k) // " (" // sizes // ")")
        return
      end if
      jobu = 'S'; pu => u; ldu = max(1, m)
    end if
    if (present(vt)) then
      if (size(vt, 1) /= k .or. size(vt, 2) /= n) then
        call set_error(error, "dgesvd: vt is " // str(size(vt, 1)) // " x " // str(size(vt, 2)) // &
          & ", expected " // str(k) // " x " // str(n) // " (" // sizes // ")")
        return
      end if
      jobvt = 'S'; pvt => vt; ldvt = max(1, k)
    end if
    if (k == 0) return
    if (present(u) .or. present(vt)) then
      call divide_and_conquer(info)
      if (info <= 0) then
        if (info /= 0) call set_error(error, lapack_info_message("dgesdd", info, sizes))
        return
      end if
      ! dgesdd did not converge: the QR iteration on the kept copy
      a = a0
    end if
    call pause_fpe_halting(saved)
    call dgesvd(jobu, jobvt, m, n, a, m, s, pu, ldu, pvt, ldvt, wq, -1, info)
    lwork = max(1, 5 * k + max(m, n), int(wq(1)))
    allocate(work(lwork))
    call dgesvd(jobu, jobvt, m, n, a, m, s, pu, ldu, pvt, ldvt, work, lwork, info)
    call restore_fpe_halting(saved)
    if (info /= 0) call set_error(error, lapack_info_message("dgesvd", info, sizes))

  contains

    !> dgesdd('S') into u / vt (or temporaries); a copy of a is kept in a0 for the fallback.
    subroutine divide_and_conquer(inf)
      integer, intent(out) :: inf
      real(wp), allocatable, target :: tu(:, :), tvt(:, :)
      real(wp), allocatable :: wk(:)
      real(wp), pointer :: du(:, :), dvt(:, :)
      integer, allocatable :: iwork(:)
      real(wp) :: q(1)
      a0 = a
      if (present(u)) then
        du => u
      else
        allocate(tu(m, k)); du => tu
      end if
      if (present(vt)) then
        dvt => vt
      else
        allocate(tvt(k, n)); dvt => tvt
      end if
      allocate(iwork(8 * k))
      call pause_fpe_halting(saved)
      call dgesdd('S', m, n, a, m, s, du, m, dvt, k, q, -1, iwork, inf)
      if (inf == 0) then
        allocate(wk(max(1, nint(q(1)))))
        call dgesdd('S', m, n, a, m, s, du, m, dvt, k, wk, size(wk), iwork, inf)
      end if
      call restore_fpe_halting(saved)
    end subroutine divide_and_conquer
  end subroutine la_gesvd

  !> Symmetric eigen-decomposition (divide and conquer): a [n, n] (lower triangle used)
  !> is overwritten by the orthonormal eigenvectors, w [n] ascending eigenvalues.
  subroutine la_syevd(a, w, error)
    real(wp), contiguous, intent(inout) :: a(:, :)
    real(wp), contiguous, intent(out) :: w(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: n, info, lwork, liwork, iwq(1)
    real(wp) :: wq(1)
    real(wp), allocatable :: work(:)
    integer, allocatable :: iwork(:)
    logical :: saved(size(ieee_usual))
    n = size(a, 1)
    if (size(a, 2) /= n .or. size(w) /= n) then
      call set_error(error, "dsyevd: a is " // str(size(a, 1)) // " x " // str(size(a, 2)) // &
        & " and w has " // str(size(w)) // " entries; expected n x n and n")
      return
    end if
    if (n == 0) return
    call pause_fpe_halting(saved)
    call dsyevd('V', 'L', n, a, n, w, wq, -1, iwq, -1, info)
    lwork = max(1 + 6 * n + 2 * n * n, int(wq(1)))
    liwork = max(3 + 5 * n, iwq(1))
    allocate(work(lwork), iwork(liwork))
    call dsyevd('V', 'L', n, a, n, w, work, lwork, iwork, liwork, info)
    call restore_fpe_halting(saved)
    if (info /= 0) call set_error(error, lapack_info_message("dsyevd", info, "n = " // str(n)))
  end subroutine la_syevd

  !> y = alpha op(a) x + beta y with op = 'N' or 'T' (a hot kernel: the caller passes
  !> consistent sizes, x [size(op(a), 2)], y [size(op(a), 1)]; nothing is checked).
  subroutine la_gemv(trans, alpha, a, x, beta, y)
    character, intent(in) :: trans
    real(wp), intent(in) :: alpha, beta
    ! not `contiguous`: a contiguous actual is passed as is, another one is packed
    real(wp), intent(in) :: a(:, :), x(:)
    real(wp), intent(inout) :: y(:)
    if (size(a, 1) == 0 .or. size(a, 2) == 0) then
      if (beta == 0.0_wp) then
        y = 0.0_wp
      else
        y = beta * y
      end if
      return
    end if
    call dgemv(trans, size(a, 1), size(a, 2), alpha, a, size(a, 1), x, 1, beta, y, 1)
  end subroutine la_gemv

  !> c = alpha op(a) op(b) + beta c with op = 'N' or 'T'; shapes checked.
  subroutine la_gemm(transa, transb, alpha, a, b, beta, c, error)
    character, intent(in) :: transa, transb
    real(wp), intent(in) :: alpha, beta
    real(wp), contiguous, intent(in) :: a(:, :), b(:, :)
    real(wp), contiguous, intent(inout) :: c(:, :)
    type(error_t), allocatable, intent(out) :: error
    integer :: m, n, k, kb
    if (transa == 'T') then
      m = size(a, 2); k = size(a, 1)
    else
      m = size(a, 1); k = size(a, 2)
    end if
    if (transb == 'T') then
      n = size(b, 1); kb = size(b, 2)
    else
      n = size(b, 2); kb = size(b, 1)
    end if
    if (kb /= k .or. size(c, 1) /= m .or. size(c, 2) /= n) then
      call set_error(error, "dgemm: op(a) is " // str(m) // " x " // str(k) // ", op(b) is " // &
        & str(kb) // " x " // str(n) // ", c is " // str(size(c, 1)) // " x " // str(size(c, 2)))
      return
    end if
    if (m == 0 .or. n == 0) return
    if (k == 0) then
      if (beta == 0.0_wp) then
        c = 0.0_wp
      else
        c = beta * c
      end if
      return
    end if
    call dgemm(transa, transb, m, n, k, alpha, a, size(a, 1), b, size(b, 1), beta, c, size(c, 1))
  end subroutine la_gemm

  !> ScaLAPACK SVD of the distributed m x n matrix a (descriptor desca, destroyed):
  !> s [min(m, n)] on every process, left singular vectors in u (descriptor descu,
  !> m x min(m, n)); right singular vectors are not computed.
  !> info = min(m, n) + 1: the processes' singular values differ. pdgesvd computes them with
  !> dbdsqr on every process, with that process's rows of U (1-cyclic over all P processes);
  !> when m < P some processes own no row and dbdsqr takes dqds instead of QR there, which
  !> rounds differently (for m = 1 even gives a wrong value). Callers keep m >= P (cr_pod).
  subroutine la_pdgesvd(m, n, a, desca, s, u, descu, error)
    integer, intent(in) :: m, n, desca(9), descu(9)
    real(wp), contiguous, intent(inout) :: a(:)
    real(wp), contiguous, intent(out) :: s(:), u(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: info, lwork, descvt(9)
    real(wp) :: wq(1), vt(1)
    real(wp), allocatable :: work(:)
    logical :: saved(size(ieee_usual))
    character(len=:), allocatable :: sizes
    sizes = "m = " // str(m) // ", n = " // str(n)
    if (size(s) /= min(m, n)) then
      call set_error(error, "pdgesvd: s has " // str(size(s)) // " entries, expected " // &
        & str(min(m, n)) // " (" // sizes // ")")
      return
    end if
    if (min(m, n) == 0) return
    descvt = descu
    call pause_fpe_halting(saved)
    call pdgesvd('V', 'N', m, n, a, 1, 1, desca, s, u, 1, 1, descu, vt, 1, 1, descvt, wq, -1, info)
    if (info == 0) then
      lwork = max(1, int(wq(1)))
      allocate(work(lwork))
      call pdgesvd('V', 'N', m, n, a, 1, 1, desca, s, u, 1, 1, descu, vt, 1, 1, descvt, work, &
        & lwork, info)
    end if
    call restore_fpe_halting(saved)
    if (info /= 0) then
      if (info == min(m, n) + 1) then
        call set_error(error, "pdgesvd: the singular values differ between processes (info = min(m, n) + 1: " // &
          & "heterogeneous arithmetic, or fewer rows than processes; " // sizes // ")")
      else
        call set_error(error, lapack_info_message("pdgesvd", info, sizes))
      end if
    end if
  end subroutine la_pdgesvd

  !> Symmetric rank-k update c = alpha a a^T + beta c (trans = 'N', a [n, k]) or
  !> c = alpha a^T a + beta c (trans = 'T', a [k, n]); c [n, n], only the `uplo` ('U' or 'L')
  !> triangle is referenced and updated. Half the flops of la_gemm for a Gram matrix.
  subroutine la_syrk(uplo, trans, alpha, a, beta, c, error)
    character, intent(in) :: uplo, trans
    real(wp), intent(in) :: alpha, beta
    real(wp), contiguous, intent(in) :: a(:, :)
    real(wp), contiguous, intent(inout) :: c(:, :)
    type(error_t), allocatable, intent(out) :: error
    integer :: n, k
    if (trans == 'T') then
      n = size(a, 2); k = size(a, 1)
    else
      n = size(a, 1); k = size(a, 2)
    end if
    if ((uplo /= 'U' .and. uplo /= 'L') .or. (trans /= 'N' .and. trans /= 'T')) then
      call set_error(error, "dsyrk: uplo = '" // uplo // "' and trans = '" // trans // &
        & "'; expected 'U'/'L' and 'N'/'T'")
      return
    end if
    if (size(c, 1) /= n .or. size(c, 2) /= n) then
      call set_error(error, "dsyrk: op(a) is " // str(n) // " x " // str(k) // ", c is " // &
        & str(size(c, 1)) // " x " // str(size(c, 2)) // ", expected " // str(n) // " x " // str(n))
      return
    end if
    if (n == 0) return
    call dsyrk(uplo, trans, n, k, alpha, a, max(1, size(a, 1)), beta, c, n)
  end subroutine la_syrk
end module cr_lapack
