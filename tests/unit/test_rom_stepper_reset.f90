!> The reduced stepper judges every step by its own dual solver flags: run_trajectory resets
!> the dual_qp statistics before each step, and a step with non-finite data is not solved by
!> the dual solver, so no flag of the step before may speak for it. Two trajectories of two
!> steps each, whose second step has a NaN in vhat:
!>  - the first step exits overfull (an active row beyond max_active = 3/4 Nb = 0 with Nb = 1):
!>    the NaN step must count as "certificate failed" (dual_why(3)), not as a second
!>    "capped or overfull" (dual_why(2)), and must go to the Lawson-Hanson fallback, which
!>    refuses the NaN with an error naming step 2;
!>  - the first step is certified (no active row): the NaN step must not be accepted on the
!>    stale certificate, it must go to the fallback and end in the same error.
!> An unknown solver name is refused before any step is assembled.
module test_rom_stepper_reset_ops
  use cr_kinds, only: wp
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t
  implicit none
  private
  public :: two_step_ops_t

  !> Step k returns (vh(k), bh, dh): one unknown, one row alpha <= dh.
  type, extends(reduced_ops_t) :: two_step_ops_t
    real(wp), allocatable :: vh(:), bh(:,:), dh(:)
    integer :: calls = 0
  contains
    procedure :: assemble
  end type two_step_ops_t

contains

  subroutine assemble(this, ctx, q, vhat, bt, dhat)
    class(two_step_ops_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    this%calls = this%calls + 1
    vhat = this%vh(min(this%calls, size(this%vh)))
    bt = transpose(this%bh)
    dhat = this%dh
    if (size(q) < 0 .or. ctx%h < 0) vhat = 0
  end subroutine assemble
end module test_rom_stepper_reset_ops

program test_rom_stepper_reset
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_assert, only: check, test_summary
  use cr_reduced_ops, only: eval_ctx_t
  use cr_rom_stepper, only: rom_solver_cfg_t, rom_traj_t, run_trajectory
  use test_rom_stepper_reset_ops, only: two_step_ops_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  type(two_step_ops_t) :: ops
  type(eval_ctx_t) :: ctx
  type(rom_solver_cfg_t) :: scfg
  type(rom_traj_t) :: traj
  type(error_t), allocatable :: error
  real(wp) :: q0(4), nan

  nan = ieee_value(1.0_wp, ieee_quiet_nan)
  q0 = [0.1_wp, 0.2_wp, 0.3_wp, 0.4_wp]
  ctx%h = 0.5_wp
  ops%nb = 1; ops%r = 1
  ops%v = reshape([1.0_wp, 0.0_wp, 0.0_wp, 0.0_wp], [4, 1])
  ops%agents = [1, 2]
  ops%m = 0
  ops%bh = reshape([1.0_wp], [1, 1])
  ops%dh = [0.2_wp]
  scfg%name = 'dual'

  ! control: one step with the row active (projection of 0.5 onto alpha <= 0.2) exits
  ! overfull and is answered by the fallback
  ops%vh = [0.5_wp]; ops%calls = 0
  call run_trajectory(ops, ctx, q0, 1, scfg, traj, error)
  call check(.not. allocated(error), "overfull step alone: no error")
  call check(all(traj%dual_why == [0, 1, 0]), "overfull step alone: counted as capped or overfull, got " // &
    why(traj%dual_why))
  call check(traj%n_fallback == 1, "overfull step alone: answered by the fallback")
  call check(abs(traj%alpha(1, 1) - 0.2_wp) <= 1.0e-14_wp, "overfull step alone: the projection 0.2")

  ! overfull, then non-finite data
  ops%vh = [0.5_wp, nan]; ops%calls = 0
  call run_trajectory(ops, ctx, q0, 2, scfg, traj, error)
  call check(ops%calls == 2, "overfull then NaN: both steps assembled")
  call check(allocated(error), "overfull then NaN: the fallback refuses the NaN (error)")
  if (allocated(error)) call check(index(error%message, "reduced step 2") > 0 .and. &
    index(error%message, "not finite") > 0, "overfull then NaN: the error names step 2 and the non-finite entry: " // &
    error%message)
  call check(all(traj%dual_why == [0, 1, 1]), "overfull then NaN: step 1 overfull, step 2 by its own flags " // &
    "(certificate failed), got " // why(traj%dual_why))
  call check(traj%n_fallback == 2, "overfull then NaN: both steps sent to the fallback, got " // str(traj%n_fallback))
  call check(abs(traj%alpha(1, 1) - 0.2_wp) <= 1.0e-14_wp, "overfull then NaN: step 1 kept its answer")

  ! certified (no active row: 0.1 <= 0.2), then non-finite data
  ops%vh = [0.1_wp, nan]; ops%calls = 0
  call run_trajectory(ops, ctx, q0, 2, scfg, traj, error)
  call check(ops%calls == 2, "certified then NaN: both steps assembled")
  call check(allocated(error), "certified then NaN: the NaN step is not accepted on the first step's certificate")
  if (allocated(error)) call check(index(error%message, "reduced step 2") > 0, &
    "certified then NaN: the error names step 2: " // error%message)
  call check(all(traj%dual_why == [0, 0, 1]), "certified then NaN: only step 2 uncertified, got " // why(traj%dual_why))
  call check(traj%n_fallback == 1, "certified then NaN: step 2 sent to the fallback, got " // str(traj%n_fallback))
  call check(traj%alpha(1, 1) == 0.1_wp, "certified then NaN: step 1 kept its answer")

  ! an unknown solver name is refused (bad input) before any step is assembled
  scfg%name = 'lbfgs'
  ops%vh = [0.1_wp]; ops%calls = 0
  call run_trajectory(ops, ctx, q0, 1, scfg, traj, error)
  call check(allocated(error), "unknown solver: refused")
  if (allocated(error)) call check(index(error%message, "'lbfgs'") > 0 .and. error%code == EXIT_BAD_INPUT, &
    "unknown solver: code 2 and the name in the message: " // error%message)
  call check(ops%calls == 0, "unknown solver: no step assembled")

  call test_summary(0)

contains

  function why(w) result(s)
    integer, intent(in) :: w(3)
    character(len=:), allocatable :: s
    s = "[" // str(w(1)) // ", " // str(w(2)) // ", " // str(w(3)) // "]"
  end function why
end program test_rom_stepper_reset
