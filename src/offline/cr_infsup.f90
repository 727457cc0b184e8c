!> Reduced inf-sup constant of a pair (velocity basis V, multiplier cone Psi) at one
!> configuration q (the paper's eq. red_infsup_const):
!>
!>   gamma = inf_{beta >= 0, beta /= 0} sup_{u in span V} (Psi beta)^T B(q) u / (|u| |Psi beta|)
!>         = inf_{beta >= 0} sqrt( beta^T M beta / beta^T G beta ),
!>   M = Bh Bh^T, Bh = Psi^T B(q) V [R, N] (V orthonormal), G = Psi^T Psi.
!>
!> How the cone-constrained infimum is computed: it is a non-convex problem (a Pareto /
!> complementarity eigenvalue problem), so gamma is bracketed, gamma_low <= gamma <= gamma_up:
!> - gamma_low = sqrt(smallest generalised eigenvalue of (M, G)) (the infimum over all beta);
!>   it is exact when the minimising eigenvector has one sign.
!> - gamma_up: the convex problem min |Bh^T beta|^2 over the simplex (beta >= 0, sum = 1)
!>   is solved exactly (NNLS with the sum constraint as a heavily weighted row); if its value
!>   is zero, gamma = 0 exactly (a non-negative multiplier in the kernel of Bh^T: the
!>   instability the paper observes). From that point, projected-gradient steps on the
!>   Rayleigh quotient over beta >= 0 lower the bound; any feasible beta gives an upper bound.
!> The result reports both bounds and whether they coincide.
module cr_infsup
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_contact_eval, only: eval_contact
  use cr_sparse_cone, only: sparse_cone_t
  use cr_nnls, only: nnls_solve, nnls_stats_t
  use cr_lapack, only: la_syevd
  implicit none
  private
  public :: infsup_t, reduced_infsup

  !> Bracket of the reduced inf-sup constant.
  type :: infsup_t
    real(wp) :: low = 0, up = 0
    !> gamma_low = gamma_up to 1e-10 (relative), or gamma_up = 0
    logical :: exact = .false.
  end type infsup_t


contains

  !> gamma for basis v [n_dof, N] (orthonormal columns), cone psi, at configuration q.
  subroutine reduced_infsup(scene, radius, h, dict_ia, dict_ib, dict_ob, cone, v, q, gam, error)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h
    integer, intent(in) :: dict_ia(:), dict_ib(:), dict_ob(:)
    type(sparse_cone_t), intent(in) :: cone
    real(wp), intent(in) :: v(:,:), q(:)
    type(infsup_t), intent(out) :: gam
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: bh(:,:), m(:,:), g(:,:), l(:,:), c(:,:), w(:), a(:,:), b(:), beta(:)
    real(wp), allocatable :: grad(:), trial(:)
    type(nnls_stats_t) :: st
    real(wp) :: gap, gv(2), wgt, f, ft, step, vmin, vmax
    integer :: r, n, p, ll, ia, ib, i, j, it
    r = cone%r; n = size(v, 2)
    if (r == 0 .or. n == 0) then
      gam = infsup_t(0.0_wp, 0.0_wp, .true.); return
    end if
    ! Bh(r, :) = sum_l psi_{r,l} B_l(q) V,  B_l V = -h (g . (V_ia - V_ib))
    allocate(bh(r, n)); bh = 0
    do i = 1, r
      do p = cone%ptr(i) + 1, cone%ptr(i + 1)
        ll = cone%idx(p)
        ia = dict_ia(ll); ib = dict_ib(ll)
        call eval_contact(scene, q, radius, ia, ib, dict_ob(ll), gap, gv)
        wgt = -h * cone%val(p)
        bh(i, :) = bh(i, :) + wgt * (gv(1) * v(2*ia-1, :) + gv(2) * v(2*ia, :))
        if (ib > 0) bh(i, :) = bh(i, :) - wgt * (gv(1) * v(2*ib-1, :) + gv(2) * v(2*ib, :))
      end do
    end do
    m = matmul(bh, transpose(bh))
    ! G = Psi^T Psi (sparse columns), its Cholesky factor L (G is positive definite for
    ! independent cone vectors; a tiny shift guards against dependent ones)
    allocate(g(r, r)); g = 0
    do i = 1, r
      do j = 1, r
        g(i, j) = sparse_dot(i, j)
      end do
    end do
    allocate(l(r, r)); l = 0
    do j = 1, r
      l(j, j) = g(j, j) + 1.0e-14_wp * maxval([(g(i, i), i = 1, r)]) - sum(l(j, 1:j-1)**2)
      l(j, j) = sqrt(max(l(j, j), tiny(1.0_wp)))
      do i = j + 1, r
        l(i, j) = (g(i, j) - dot_product(l(i, 1:j-1), l(j, 1:j-1))) / l(j, j)
      end do
    end do
    ! C = L^{-1} M L^{-T}: eigenvalues of C = generalised eigenvalues of (M, G)
    c = m
    do j = 1, r            ! C <- L^{-1} C
      call lsolve(c(:, j))
    end do
    c = transpose(c)
    do j = 1, r            ! C <- (L^{-1} C^T)^T = L^{-1} M L^{-T}
      call lsolve(c(:, j))
    end do
    c = 0.5_wp * (c + transpose(c))
    allocate(w(r))
    call la_syevd(c, w, error)
    if (allocated(error)) then
      error%message = "infsup: " // error%message // " (R = " // str(r) // ")"; return
    end if
    gam%low = sqrt(max(w(1), 0.0_wp))
    ! eigenvector in beta coordinates: beta = L^{-T} y; one sign -> exact
    beta = c(:, 1)
    call ltsolve(beta)
    vmin = minval(beta); vmax = maxval(beta)
    if (vmin >= -1.0e-12_wp * maxval(abs(beta)) .or. vmax <= 1.0e-12_wp * maxval(abs(beta))) then
      gam%up = gam%low; gam%exact = .true.; return
    end if
    ! upper bound: min |Bh^T beta|^2 on the simplex, by NNLS with a weighted sum row
    allocate(a(n + 1, r), b(n + 1))
    wgt = 1.0e4_wp * max(maxval(abs(bh)), tiny(1.0_wp))
    a(1:n, :) = transpose(bh); a(n + 1, :) = wgt
    b = 0; b(n + 1) = wgt
    deallocate(beta); allocate(beta(r))
    call nnls_solve(a, b, beta, st, error)
    if (allocated(error)) return
    if (sum(beta) > 0) beta = beta / sum(beta)
    f = quotient(beta)
    gam%up = sqrt(max(f, 0.0_wp))
    if (norm2(matmul(beta, bh)) <= 1.0e-13_wp * max(maxval(abs(bh)), tiny(1.0_wp))) then
      gam%up = 0; gam%low = 0; gam%exact = .true.; return
    end if
    ! projected gradient on the Rayleigh quotient over beta >= 0
    allocate(grad(r), trial(r))
    step = 1.0_wp / max(maxval(abs(m)), tiny(1.0_wp))
    do it = 1, 500
      grad = 2 * (matmul(m, beta) - f * matmul(g, beta)) / max(dot_product(beta, matmul(g, beta)), tiny(1.0_wp))
      trial = max(beta - step * grad, 0.0_wp)
      if (.not. (sum(trial) > 0)) then
        step = step / 2; cycle
      end if
      trial = trial / sum(trial)
      ft = quotient(trial)
      if (ft < f) then
        beta = trial
        if (f - ft <= 1.0e-14_wp * f) then
          f = ft; exit
        end if
        f = ft; step = step * 1.5_wp
      else
        step = step / 2
        if (step < 1.0e-30_wp) exit
      end if
    end do
    gam%up = sqrt(max(f, 0.0_wp))
    gam%exact = gam%up - gam%low <= 1.0e-10_wp * max(gam%up, tiny(1.0_wp))

  contains

    real(wp) function sparse_dot(i1, i2)
      integer, intent(in) :: i1, i2
      integer :: p1, p2
      sparse_dot = 0
      do p1 = cone%ptr(i1) + 1, cone%ptr(i1 + 1)
        do p2 = cone%ptr(i2) + 1, cone%ptr(i2 + 1)
          if (cone%idx(p1) == cone%idx(p2)) sparse_dot = sparse_dot + cone%val(p1) * cone%val(p2)
        end do
      end do
    end function sparse_dot

    subroutine lsolve(x)     ! x <- L^{-1} x
      real(wp), intent(inout) :: x(:)
      integer :: k
      do k = 1, size(x)
        x(k) = (x(k) - dot_product(l(k, 1:k-1), x(1:k-1))) / l(k, k)
      end do
    end subroutine lsolve

    subroutine ltsolve(x)    ! x <- L^{-T} x
      real(wp), intent(inout) :: x(:)
      integer :: k
      do k = size(x), 1, -1
        x(k) = (x(k) - dot_product(l(k+1:, k), x(k+1:))) / l(k, k)
      end do
    end subroutine ltsolve

    real(wp) function quotient(bt)
      real(wp), intent(in) :: bt(:)
      quotient = dot_product(bt, matmul(m, bt)) / max(dot_product(bt, matmul(g, bt)), tiny(1.0_wp))
    end function quotient
  end subroutine reduced_infsup
end module cr_infsup
