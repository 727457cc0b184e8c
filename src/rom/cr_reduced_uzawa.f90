!> Reduced solver 'uzawa': the paper's reduced Uzawa iteration, from beta = 0 at every step
!> (for comparison with the exact solvers).
module cr_reduced_uzawa
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_reduced_base, only: reduced_ops_t
  use cr_reduced_solver, only: reduced_solver_t, reduced_tally_t, rom_solver_cfg_t
  implicit none
  private
  public :: reduced_uzawa_t

  !> The paper's Uzawa iteration.
  type, extends(reduced_solver_t) :: reduced_uzawa_t
    !> the rows bhat [R, nb]
    real(wp), allocatable :: bhat(:,:)
  contains
    procedure :: step => uzawa_step
  end type reduced_uzawa_t

contains

  subroutine uzawa_step(this, ops, h, bt, dhat, vhat, alpha, lam, tally, error)
    class(reduced_uzawa_t), intent(inout) :: this
    class(reduced_ops_t), intent(in) :: ops
    real(wp), intent(in) :: h
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: dhat(:)
    real(wp), contiguous, intent(in) :: vhat(:)
    real(wp), contiguous, intent(inout) :: alpha(:)
    real(wp), intent(inout) :: lam(:)
    type(reduced_tally_t), intent(inout) :: tally
    type(error_t), allocatable, intent(out) :: error
    integer :: its
    logical :: capped
    this%bhat = transpose(bt)
    lam = 0
    call reduced_uzawa(this%bhat, dhat, vhat, h, alpha, lam, this%cfg, its, capped)
    tally%iterations = tally%iterations + its
    if (capped) tally%n_capped = tally%n_capped + 1
    if (size(dhat) > 0) tally%max_violation = max(tally%max_violation, maxval(matmul(this%bhat, alpha) - dhat))
  end subroutine uzawa_step

  !> The paper's reduced Uzawa iteration from beta = 0: alpha = vhat - bhat^T beta,
  !> beta = max(0, beta + rho (bhat alpha - dhat)), rho = factor / h^2 as in the full-order
  !> model (bhat = W^T B V with B = -h G); stops when |beta_k - beta_{k-1}| / (|beta_{k-1}| + 1)
  !> <= eps or at the cap.
  subroutine reduced_uzawa(bhat, dhat, vhat, h, alpha, beta, scfg, its, capped)
    real(wp), intent(in) :: bhat(:,:), dhat(:), vhat(:), h
    real(wp), intent(out) :: alpha(:)
    real(wp), intent(inout) :: beta(:)
    type(rom_solver_cfg_t), intent(in) :: scfg
    integer, intent(out) :: its
    logical, intent(out) :: capped
    real(wp), allocatable :: bn(:)
    real(wp) :: rho, nrm
    rho = scfg%uzawa_rho_factor / h**2
    capped = .true.
    allocate(bn(size(beta)))
    do its = 1, scfg%uzawa_max_iter
      alpha = vhat - matmul(beta, bhat)
      bn = max(0.0_wp, beta + rho * (matmul(bhat, alpha) - dhat))
      nrm = norm2(bn - beta) / (norm2(beta) + 1)
      beta = bn
      if (nrm <= scfg%uzawa_eps) then
        capped = .false.
        exit
      end if
    end do
    its = min(its, scfg%uzawa_max_iter)
    alpha = vhat - matmul(beta, bhat)
  end subroutine reduced_uzawa
end module cr_reduced_uzawa
