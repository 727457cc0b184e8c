!> One reduced query: the model of a parameter (scene, speeds, desired velocity, divergence
!> guard) and, after cr_rom_stepper's run_trajectory, its positions with every agent checked
!> by the guard. The one stepping path of the reduced model: the sweep (cr_rom_sweep) and the
!> prediction for new parameters (cr_predict_run) both call it, so a parameter gives the same
!> trajectory bit for bit in either.
module cr_rom_query
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_reduced_ops, only: eval_ctx_t
  use cr_rom_guard, only: rom_guard_t
  use cr_rom_stepper, only: rom_traj_t, reduced_positions
  use cr_rom_study, only: rom_study_t
  implicit none
  private
  public :: query_setup, query_positions

contains

  !> The evaluation context and the divergence guard of parameter mu [n_expanded] of study st.
  subroutine query_setup(st, mu, ctx, guard, error)
    type(rom_study_t), intent(in) :: st
    real(wp), intent(in) :: mu(:)
    type(eval_ctx_t), intent(out) :: ctx
    type(rom_guard_t), intent(out) :: guard
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: c_max
    call st%space%sample_model(mu, st%cfg, st%speeds, st%radius, ctx%scene, ctx%speeds, ctx%desired, error)
    if (allocated(error)) return
    ctx%radius = st%radius
    ctx%h = st%dt
    ! the density-dependent desired speed (&desired speed_model = 'weidmann'), at every step
    if (st%cfg%desired%speed_model == 'weidmann') call ctx%density%init(st%cfg%desired, st%n_agents)
    c_max = 0
    if (size(ctx%speeds) > 0) c_max = maxval(abs(ctx%speeds))
    if (ctx%desired%from_file) c_max = max(c_max, sqrt(2.0_wp) * maxval(abs(ctx%desired%fixed)))
    call guard%init(ctx%scene, c_max, st%dt * st%n_steps, st%n_agents)
  end subroutine query_setup

  !> The positions of a reduced trajectory [n_dof, n_steps + 1] (basis v [n_dof, nb]): carried
  !> in full by a corrected stepping, else rebuilt from the coefficients. Every agent is checked
  !> (the stepper checks only the agents its assembly reads): from the first frame the guard
  !> refuses, the trajectory counts as diverged one step earlier and stays frozen there
  !> (traj%diverged_step, alpha, beta and n_corrected updated).
  subroutine query_positions(st, v, guard, traj, qr)
    type(rom_study_t), intent(in) :: st
    real(wp), intent(in) :: v(:,:)
    type(rom_guard_t), intent(in) :: guard
    type(rom_traj_t), intent(inout) :: traj
    real(wp), allocatable, intent(out) :: qr(:,:)
    integer :: kbad, j
    if (allocated(traj%q)) then
      qr = traj%q
    else
      qr = reduced_positions(st%q0, v, traj%alpha, st%dt)
    end if
    kbad = guard%first_outside(qr)
    if (kbad <= 0) return
    if (traj%diverged_step /= 0 .and. kbad - 1 >= traj%diverged_step) return
    traj%diverged_step = kbad - 1
    traj%alpha(:, kbad - 1:) = 0
    traj%beta(:, kbad - 1:) = 0
    if (allocated(traj%q)) then
      do j = kbad, st%n_steps + 1
        qr(:, j) = qr(:, kbad - 1)
      end do
      traj%n_corrected(kbad - 1:) = 0
    else
      qr = reduced_positions(st%q0, v, traj%alpha, st%dt)
    end if
  end subroutine query_positions
end module cr_rom_query
