!> Reduced solver 'dual': the warm-started dual active-set solver on the Gram of the active rows
!> (cr_dual_qp), whose answer is accepted only with its KKT certificate; otherwise (infeasible
!> problem, cap, more than 3/4 Nb active rows, failed certificate, non-finite data) the step
!> goes to the Lawson-Hanson LDP (ldp_step of cr_reduced_nnls), warm started from the dual
!> iterate, and is counted. The data of each step are checked for NaN / Inf once: a sum over
!> vhat and dhat here, and the dual solver sums the slacks of its first sweep (which carry any
!> NaN / Inf of bhat); a non-finite sum sends the step to the LDP, which names the offending
!> entry.
module cr_reduced_dual
  use cr_kinds, only: wp
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_error, only: error_t
  use cr_nnls, only: nnls_work_t
  use cr_dual_qp, only: dual_qp_t, dual_qp_stats_t
  use cr_reduced_base, only: reduced_ops_t
  use cr_reduced_solver, only: reduced_solver_t, reduced_tally_t
  use cr_reduced_nnls, only: ldp_step
  implicit none
  private
  public :: reduced_dual_t

  !> Certified dual active set with the LDP as fallback.
  type, extends(reduced_solver_t) :: reduced_dual_t
    type(dual_qp_t) :: dqp
    !> work space of the fallback, kept from step to step
    type(nnls_work_t) :: work
    !> the rows bhat [R, nb] (fallback only), the multipliers on entry [R]
    real(wp), allocatable :: bhat(:,:), lam0(:)
  contains
    procedure :: step => dual_step
  end type reduced_dual_t

contains

  subroutine dual_step(this, ops, h, bt, dhat, vhat, alpha, lam, tally, error)
    class(reduced_dual_t), intent(inout) :: this
    class(reduced_ops_t), intent(in) :: ops
    real(wp), intent(in) :: h
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: dhat(:)
    real(wp), contiguous, intent(in) :: vhat(:)
    real(wp), contiguous, intent(inout) :: alpha(:)
    real(wp), intent(inout) :: lam(:)
    type(reduced_tally_t), intent(inout) :: tally
    type(error_t), allocatable, intent(out) :: error
    type(dual_qp_stats_t) :: dst
    logical :: finite
    integer :: nb
    nb = ops%nb
    finite = ieee_is_finite(sum(vhat) + sum(dhat))
    ! no flag of the previous step's solve may speak for this one (a step with non-finite
    ! data is not solved)
    dst = dual_qp_stats_t()
    if (finite) then
      this%lam0 = lam
      ! at most 3/4 Nb active rows: beyond, their Gram is too ill-conditioned to certify
      ! (the locked regime of online contacts) and the QR-based NNLS takes the step
      if (ops%has_gram) then
        call this%dqp%solve(bt, dhat, vhat, alpha, lam, dst, warm=.true., gsrc=ops, max_active=(3 * nb) / 4)
      else
        call this%dqp%solve(bt, dhat, vhat, alpha, lam, dst, warm=.true., max_active=(3 * nb) / 4)
      end if
      tally%iterations = tally%iterations + dst%adds + dst%drops
      tally%dual_adds = tally%dual_adds + dst%adds
      tally%dual_drops = tally%dual_drops + dst%drops
      tally%active_sum = tally%active_sum + dst%n_active
    end if
    if (dst%infeasible) tally%dual_why(1) = tally%dual_why(1) + 1
    if (dst%capped .or. dst%overfull) tally%dual_why(2) = tally%dual_why(2) + 1
    if (.not. (dst%certified .or. dst%infeasible .or. dst%capped .or. dst%overfull)) &
      tally%dual_why(3) = tally%dual_why(3) + 1
    if (dst%certified) then
      tally%max_violation = max(tally%max_violation, dst%max_violation)
    else
      tally%n_fallback = tally%n_fallback + 1
      ! stopped early: the previous step's active set is the better guess
      if (dst%overfull .or. dst%capped) lam = this%lam0
      ! the certified Lawson-Hanson LDP, warm started from lam (> 0 marks the guess)
      this%bhat = transpose(bt)
      call ldp_step(this%cfg, this%bhat, dhat, vhat, alpha, lam, this%work, tally, error)
    end if
  end subroutine dual_step
end module cr_reduced_dual
