!> Reduced solver 'nnls': the Lawson-Hanson least-distance solver of cr_nnls, warm started from
!> the previous step's multipliers (with the Gram of the rows from the assembly when the rows
!> are fixed and it has them). ldp_step is also the certified fallback of 'dual'.
module cr_reduced_nnls
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_nnls, only: ldp_solve, ldp_stats_t, nnls_work_t
  use cr_reduced_base, only: reduced_ops_t
  use cr_reduced_solver, only: reduced_solver_t, reduced_tally_t, rom_solver_cfg_t
  implicit none
  private
  public :: reduced_nnls_t, ldp_step

  !> Lawson-Hanson LDP on every step.
  type, extends(reduced_solver_t) :: reduced_nnls_t
    !> NNLS work space, kept from step to step
    type(nnls_work_t) :: work
    !> the rows bhat [R, nb] and their Gram [R, R] (fixed rows with ops%has_gram)
    real(wp), allocatable :: bhat(:,:), gram(:,:)
  contains
    procedure :: step => nnls_step
  end type reduced_nnls_t

contains

  subroutine nnls_step(this, ops, h, bt, dhat, vhat, alpha, lam, tally, error)
    class(reduced_nnls_t), intent(inout) :: this
    class(reduced_ops_t), intent(in) :: ops
    real(wp), intent(in) :: h
    real(wp), contiguous, intent(in) :: bt(:,:)
    real(wp), intent(in) :: dhat(:)
    real(wp), contiguous, intent(in) :: vhat(:)
    real(wp), contiguous, intent(inout) :: alpha(:)
    real(wp), intent(inout) :: lam(:)
    type(reduced_tally_t), intent(inout) :: tally
    type(error_t), allocatable, intent(out) :: error
    this%bhat = transpose(bt)
    if (ops%has_gram .and. ops%fixed_rows) then
      if (.not. allocated(this%gram)) allocate(this%gram(ops%r, ops%r))
      call ops%gram(this%gram)
      call ldp_step(this%cfg, this%bhat, dhat, vhat, alpha, lam, this%work, tally, error, this%gram)
    else
      call ldp_step(this%cfg, this%bhat, dhat, vhat, alpha, lam, this%work, tally, error)
    end if
  end subroutine nnls_step

  !> The warm-started LDP (lam > 0 marks the guess) with the cap cfg%nnls_max_iter (0: the
  !> solver's default), its figures added to tally.
  subroutine ldp_step(cfg, bhat, dhat, vhat, alpha, lam, work, tally, error, gram)
    type(rom_solver_cfg_t), intent(in) :: cfg
    !> rows [R, nb], right-hand side [R], desired coefficients [nb]
    real(wp), intent(in) :: bhat(:,:), dhat(:), vhat(:)
    !> coefficients [nb]
    real(wp), intent(out) :: alpha(:)
    !> multipliers [R]
    real(wp), intent(inout) :: lam(:)
    type(nnls_work_t), intent(inout) :: work
    type(reduced_tally_t), intent(inout) :: tally
    type(error_t), allocatable, intent(out) :: error
    !> bhat bhat^T [R, R]
    real(wp), intent(in), optional :: gram(:,:)
    type(ldp_stats_t) :: st
    if (cfg%nnls_max_iter > 0) then
      call ldp_solve(bhat, dhat, vhat, alpha, lam, st, error, warm=.true., max_iter=cfg%nnls_max_iter, &
        work=work, gram=gram)
    else
      call ldp_solve(bhat, dhat, vhat, alpha, lam, st, error, warm=.true., work=work, gram=gram)
    end if
    if (allocated(error)) return
    tally%iterations = tally%iterations + st%nnls%iterations
    if (st%infeasible) tally%n_infeasible = tally%n_infeasible + 1
    if (.not. st%nnls%converged) tally%n_capped = tally%n_capped + 1
    if (.not. st%infeasible) tally%max_violation = max(tally%max_violation, st%max_violation)
  end subroutine ldp_step
end module cr_reduced_nnls
