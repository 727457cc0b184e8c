!> Time stepping of the reduced model for one parameter (the paper's section 3.2):
!>   q^(nu-1) = q^0 + h V sum_{k < nu} alpha^k          (only the agents the assembly reads)
!>   (alpha^nu, beta^nu) = reduced projection at q^(nu-1)
!> solved by the reduced solver named in rom_solver_cfg_t (built by make_reduced_solver of
!> cr_reduced_solver: 'dual' (default), 'nnls', 'uzawa'). Infeasible reduced problems (the
!> reduced positions already overlap) return the least-violation solution and are counted;
!> so are solves that reach their iteration cap. With rows that change from step to step
!> (online contacts) the multipliers are carried over by contact identity (ops%keys).
!>
!> With a local exact correction (argument `corr`, &sweep correction = 'local'), each step
!> continues from the corrected positions, carried in full:
!>   u_r = V alpha^nu,  u = u_r + delta = corr%correct(q^(nu-1), u_r),  q^nu = q^(nu-1) + h u,
!> the next reduced step is assembled at q^nu, and alpha^nu stays the reduced solve's answer
!> (the correction delta is not projected back onto the basis: a projection would lose the
!> part of delta outside span(V), and with it the guarantee of no overlap). The positions of
!> every step are then returned in traj%q (reduced_positions(alpha) no longer gives them).
!>
!> With the density-dependent desired speed (ctx%density%on, &desired speed_model = 'weidmann')
!> each step first rebuilds every agent's position (an agent's density reads its neighbours,
!> which the assembly's agents do not list; one product with V, O(n_dof Nb)), then evaluates
!> the local density of the agents the assembly reads only (ops%agents: the agents of its
!> sampled points; the kernel over their neighbours found in a grid of every agent,
!> density_speed_t%scale_speeds_of) and hands the assembly their speeds scaled by the diagram:
!> the hyper-reduction evaluates the desired velocity of its agents at their density-dependent
!> speed, as with every agent's density (to the order of the kernel sums).
module cr_rom_stepper
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, prefix_error
  use cr_strings, only: str
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t
  use cr_rom_guard, only: rom_guard_t
  use cr_key_map, only: key_map_t
  use cr_lapack, only: la_gemv
  use cr_local_correction, only: local_correction_t, local_stats_t
  use cr_reduced_solver, only: rom_solver_cfg_t, reduced_tally_t, reduced_solver_t, make_reduced_solver
  implicit none
  private
  public :: rom_solver_cfg_t, rom_traj_t, run_trajectory, reduced_positions

  !> One reduced trajectory (the solver's figures, summed over the steps, in reduced_tally_t).
  type, extends(reduced_tally_t) :: rom_traj_t
    !> coefficients [nb, n_steps] and multipliers [R, n_steps] (no multipliers for 'online')
    real(wp), allocatable :: alpha(:,:), beta(:,:)
    !> largest number of constraint rows
    integer :: max_rows = 0
    !> wall time of the stepping (seconds), and its parts: reduced positions, assembly,
    !> solve (the rest is bookkeeping)
    real(wp) :: time = 0, time_positions = 0, time_assemble = 0, time_solve = 0
    !> first step whose positions the divergence guard refused (0: none); the stepping
    !> stopped there and alpha(:, diverged_step:) = 0 (positions frozen at step - 1)
    integer :: diverged_step = 0
    !> with a local correction only: the corrected positions [n_dof, n_steps + 1] (column 1:
    !> q0; frozen after a diverged step), agents corrected at each step [n_steps], steps with
    !> a conflict, and the wall time of the corrections (included in `time`) [s]
    real(wp), allocatable :: q(:,:)
    integer, allocatable :: n_corrected(:)
    integer :: conflict_steps = 0
    !> agents of the violated rows (before neighbours), summed over the steps
    integer :: n_conflict_agents = 0
    !> steps whose correction even the projection with every agent free could not solve to
    !> the tolerance (the solver's best iterate was used: reported, not an error)
    integer :: corr_unsolved = 0
    real(wp) :: time_correct = 0
  end type rom_traj_t

  !> The state of a trajectory between its steps.
  type :: stepper_state_t
    !> the dofs the assembly reads [2 * size(ops%agents)], their rows of V [., nb] and of q0
    integer, allocatable :: dofs(:)
    real(wp), allocatable :: vsub(:,:), q0sub(:), qsub(:)
    !> positions [n_dof], sum of the coefficients so far [nb], this step's desired and
    !> returned coefficients [nb]
    real(wp), allocatable :: q(:), acc(:), vhat(:), alpha(:)
    !> this step's assembly: rows as columns [nb, R], right-hand side [R]; multipliers [R]
    real(wp), allocatable :: bt(:,:), dhat(:), lam(:)
    !> with a correction: reduced and corrected velocities [n_dof], every agent
    real(wp), allocatable :: ur(:), uc(:)
    integer, allocatable :: all_agents(:)
    !> positive multipliers of the previous step's rows by identity (warm start)
    type(key_map_t) :: prev
    class(reduced_solver_t), allocatable :: solver
    !> with the density-dependent desired speed: ctx with the step's speeds, and the desired
    !> velocities at the given speeds (the look-ahead's directions) [n_dof], set at the dofs
    !> the assembly reads from vsel [2, size(ops%agents)]
    type(eval_ctx_t) :: dctx
    real(wp), allocatable :: vdes(:), vsel(:,:)
    !> positions carried in full (with a correction)
    logical :: carry = .false.
  end type stepper_state_t

contains

  !> Run n_steps reduced steps from q0 [n_dof]. With `guard`, every step is checked (cr_rom_guard)
  !> and the stepping stops at the first diverged step (traj%diverged_step). With `corr`
  !> (initialised), every step is corrected locally and the positions are carried in full
  !> (module header). An unknown solver name is an error.
  subroutine run_trajectory(ops, ctx, q0, n_steps, scfg, traj, error, guard, corr)
    class(reduced_ops_t), intent(inout) :: ops
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q0(:)
    integer, intent(in) :: n_steps
    type(rom_solver_cfg_t), intent(in) :: scfg
    type(rom_traj_t), intent(out) :: traj
    type(error_t), allocatable, intent(out) :: error
    type(rom_guard_t), intent(in), optional :: guard
    type(local_correction_t), intent(inout), optional :: corr
    type(stepper_state_t) :: st
    integer :: nu
    integer(8) :: c0, c1, rate, t0, t1, t2, t3, t4
    logical :: finite
    call make_reduced_solver(scfg, st%solver, error)
    if (allocated(error)) return
    call start_trajectory(ops, q0, n_steps, present(corr), st, traj)
    if (st%carry) then
      ! each trajectory's correction starts cold (reproducible whatever ran before)
      call corr%reset()
    end if
    if (ctx%density%on) then
      st%dctx = ctx
      allocate(st%vdes(size(q0)), st%vsel(2, size(ops%agents)))
      st%vdes = 0
    end if
    call system_clock(c0, rate)
    do nu = 1, n_steps
      call system_clock(t0)
      call step_positions(ctx, ops, q0, st)
      call system_clock(t1)
      if (present(guard) .and. nu > 1) then
        ! the positions the previous step produced (those the assembly reads; every agent
        ! when carried)
        if (st%carry) then
          finite = guard%agents_ok(st%q, st%all_agents)
        else
          finite = guard%agents_ok(st%q, ops%agents)
        end if
        if (.not. finite) then
          traj%diverged_step = nu - 1; exit
        end if
      end if
      call step_assemble(ops, ctx, st)
      call system_clock(t2)
      call solve_step(ops, ctx, st, traj, error)
      if (allocated(error)) then
        call prefix_error(error, "reduced step " // str(nu)); return
      end if
      call system_clock(t3)
      traj%time_positions = traj%time_positions + real(t1 - t0, wp) / real(rate, wp)
      traj%time_assemble = traj%time_assemble + real(t2 - t1, wp) / real(rate, wp)
      traj%time_solve = traj%time_solve + real(t3 - t2, wp) / real(rate, wp)
      traj%alpha(:, nu) = st%alpha
      if (size(traj%beta, 1) == size(st%lam)) traj%beta(:, nu) = st%lam
      st%acc = st%acc + st%alpha
      if (present(guard)) then
        if (.not. guard%coeffs_ok(st%alpha, st%acc, ctx%h)) then
          traj%diverged_step = nu; exit
        end if
      end if
      if (st%carry) then
        call correct_step(ops, ctx, corr, nu, st, traj, error)
        if (allocated(error)) return
        call system_clock(t4)
        traj%time_correct = traj%time_correct + real(t4 - t3, wp) / real(rate, wp)
      end if
    end do
    if (traj%diverged_step > 0) call freeze_after(traj, n_steps, st%carry)
    call system_clock(c1)
    traj%time = real(c1 - c0, wp) / real(rate, wp)
  end subroutine run_trajectory

  !> The dofs the assembly reads and their rows of V, the trajectory's arrays, and with a
  !> correction (carry) the positions of every step from q0.
  subroutine start_trajectory(ops, q0, n_steps, carry, st, traj)
    class(reduced_ops_t), intent(in) :: ops
    real(wp), intent(in) :: q0(:)
    integer, intent(in) :: n_steps
    logical, intent(in) :: carry
    type(stepper_state_t), intent(inout) :: st
    type(rom_traj_t), intent(inout) :: traj
    integer :: j, nb
    nb = ops%nb
    ! the dofs the assembly reads, and their rows of V (contiguous)
    allocate(st%dofs(2 * size(ops%agents)))
    do j = 1, size(ops%agents)
      st%dofs(2*j-1:2*j) = [2 * ops%agents(j) - 1, 2 * ops%agents(j)]
    end do
    st%vsub = ops%v(st%dofs, :)
    st%q0sub = q0(st%dofs)
    allocate(st%qsub(size(st%dofs)))
    allocate(traj%alpha(nb, n_steps), traj%beta(merge(ops%r, 0, ops%fixed_rows), n_steps))
    traj%alpha = 0; traj%beta = 0
    allocate(st%acc(nb), st%vhat(nb), st%alpha(nb))
    st%acc = 0
    st%q = q0
    st%carry = carry
    if (carry) then
      allocate(traj%q(size(q0), n_steps + 1), traj%n_corrected(n_steps), st%ur(size(q0)), st%uc(size(q0)))
      traj%q(:, 1) = q0
      traj%n_corrected = 0
      st%all_agents = [(j, j = 1, size(q0) / 2)]
    end if
  end subroutine start_trajectory

  !> Positions at the start of the step, where needed: q0 + h V acc on the dofs the assembly
  !> reads (carried in full with a correction: nothing to do).
  subroutine step_positions(ctx, ops, q0, st)
    type(eval_ctx_t), intent(in) :: ctx
    class(reduced_ops_t), intent(in) :: ops
    real(wp), intent(in) :: q0(:)
    type(stepper_state_t), intent(inout) :: st
    if (st%carry) return
    if (ctx%density%on) then
      ! every agent (the density of an agent reads its neighbours)
      st%q = q0
      call la_gemv('N', ctx%h, ops%v, st%acc, 1.0_wp, st%q)
      return
    end if
    st%qsub = st%q0sub
    call la_gemv('N', ctx%h, st%vsub, st%acc, 1.0_wp, st%qsub)
    st%q(st%dofs) = st%qsub
  end subroutine step_positions

  !> The step's reduced assembly at st%q; with the density-dependent desired speed, at the
  !> speeds the diagram gives the local density there of each agent the assembly reads.
  subroutine step_assemble(ops, ctx, st)
    class(reduced_ops_t), intent(inout) :: ops
    type(eval_ctx_t), intent(in) :: ctx
    type(stepper_state_t), intent(inout) :: st
    if (ctx%density%on) then
      ! the desired velocities of the assembly's agents (their directions for the look-ahead)
      call ctx%desired%evaluate_at(st%q, ctx%speeds, ops%agents, st%vsel)
      st%vdes(st%dofs) = reshape(st%vsel, [size(st%dofs)])
      call st%dctx%density%scale_speeds_of(st%q, st%vdes, ops%agents, ctx%speeds, st%dctx%speeds)
      call ops%assemble(st%dctx, st%q, st%vhat, st%bt, st%dhat)
    else
      call ops%assemble(ctx, st%q, st%vhat, st%bt, st%dhat)
    end if
  end subroutine step_assemble

  !> The reduced solve of the assembled step: multipliers sized to the rows and warm started
  !> by contact identity (online contacts), the solver's step, the positive multipliers kept
  !> for the next step.
  subroutine solve_step(ops, ctx, st, traj, error)
    class(reduced_ops_t), intent(in) :: ops
    type(eval_ctx_t), intent(in) :: ctx
    type(stepper_state_t), intent(inout) :: st
    type(rom_traj_t), intent(inout) :: traj
    type(error_t), allocatable, intent(out) :: error
    traj%max_rows = max(traj%max_rows, size(st%dhat))
    if (allocated(st%lam)) then
      if (size(st%lam) /= size(st%dhat)) deallocate(st%lam)
    end if
    if (.not. allocated(st%lam)) then
      allocate(st%lam(size(st%dhat))); st%lam = 0
    end if
    if (.not. ops%fixed_rows .and. allocated(ops%keys)) &
      call match_rows(ops%keys(1:size(st%dhat)), st%lam, st%prev)
    call st%solver%step(ops, ctx%h, st%bt, st%dhat, st%vhat, st%alpha, st%lam, traj%reduced_tally_t, error)
    if (allocated(error)) return
    if (.not. ops%fixed_rows .and. allocated(ops%keys)) &
      call st%prev%fill(ops%keys(1:size(st%dhat)), st%lam, keep=st%lam > 0)
  end subroutine solve_step

  !> The local correction of step nu: u = V alpha + delta, q <- q + h u.
  subroutine correct_step(ops, ctx, corr, nu, st, traj, error)
    class(reduced_ops_t), intent(in) :: ops
    type(eval_ctx_t), intent(in) :: ctx
    type(local_correction_t), intent(inout) :: corr
    integer, intent(in) :: nu
    type(stepper_state_t), intent(inout) :: st
    type(rom_traj_t), intent(inout) :: traj
    type(error_t), allocatable, intent(out) :: error
    type(local_stats_t) :: lst
    call la_gemv('N', 1.0_wp, ops%v, st%alpha, 0.0_wp, st%ur)
    call corr%correct(ctx%scene, ctx%radius, st%q, st%ur, ctx%h, st%uc, lst, error)
    if (allocated(error)) then
      call prefix_error(error, "local correction after reduced step " // str(nu)); return
    end if
    st%q = st%q + ctx%h * st%uc
    traj%q(:, nu + 1) = st%q
    traj%n_corrected(nu) = lst%n_corrected
    if (lst%n_violated > 0) traj%conflict_steps = traj%conflict_steps + 1
    if (.not. lst%converged) traj%corr_unsolved = traj%corr_unsolved + 1
    traj%n_conflict_agents = traj%n_conflict_agents + lst%n_seeds
  end subroutine correct_step

  !> After a diverged step: coefficients and multipliers from that step on are zero and the
  !> corrected positions frozen.
  subroutine freeze_after(traj, n_steps, carry)
    type(rom_traj_t), intent(inout) :: traj
    integer, intent(in) :: n_steps
    logical, intent(in) :: carry
    integer :: j
    traj%alpha(:, traj%diverged_step:) = 0
    traj%beta(:, traj%diverged_step:) = 0
    if (carry) then
      do j = traj%diverged_step + 1, n_steps + 1
        traj%q(:, j) = traj%q(:, traj%diverged_step)
      end do
      traj%n_corrected(traj%diverged_step:) = 0
    end if
  end subroutine freeze_after

  !> Multipliers of the current rows (identities keys [rows]) from the previous step's
  !> positive ones (prev); lam is (re)allocated [rows].
  subroutine match_rows(keys, lam, prev)
    integer(i8), intent(in) :: keys(:)
    real(wp), allocatable, intent(inout) :: lam(:)
    type(key_map_t), intent(in) :: prev
    if (allocated(lam)) then
      if (size(lam) /= size(keys)) deallocate(lam)
    end if
    if (.not. allocated(lam)) allocate(lam(size(keys)))
    call prev%lookup(keys, lam, 0.0_wp)
  end subroutine match_rows

  !> Reduced positions of every step: q(:, nu + 1) = q0 + h V sum_{k <= nu} alpha^k,
  !> nu = 0..n_steps [n_dof, n_steps + 1].
  function reduced_positions(q0, v, alpha, h) result(q)
    real(wp), intent(in) :: q0(:), v(:,:), alpha(:,:), h
    real(wp), allocatable :: q(:,:)
    real(wp), allocatable :: acc(:)
    integer :: nu
    allocate(q(size(q0), size(alpha, 2) + 1))
    acc = [(0.0_wp, nu = 1, size(alpha, 1))]
    q(:, 1) = q0
    do nu = 1, size(alpha, 2)
      acc = acc + alpha(:, nu)
      q(:, nu + 1) = q0 + h * matmul(v, acc)
    end do
  end function reduced_positions
end module cr_rom_stepper
