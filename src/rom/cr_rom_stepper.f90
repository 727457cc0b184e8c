!> Time stepping of the reduced model for one parameter (the paper's section 3.2):
!>   q^(nu-1) = q^0 + h V sum_{k < nu} alpha^k          (only the agents the assembly reads)
!>   (alpha^nu, beta^nu) = reduced projection at q^(nu-1)
!> solved exactly by
!>  'dual' (default) the warm-started dual active-set solver on the Gram of the active rows
!>         (cr_dual_qp), whose answer is accepted only with its KKT certificate; otherwise
!>         (infeasible problem, cap, failed certificate) the step falls back to the
!>         Lawson-Hanson LDP below, warm started from the dual iterate, and is counted;
!>  'nnls' the Lawson-Hanson least-distance solver (cr_nnls) warm-started from the previous
!>         step's multipliers;
!> or by the paper's Uzawa iteration for comparison. Infeasible reduced problems (the
!> reduced positions already overlap) return the least-violation solution and are counted;
!> so are solves that reach their iteration cap. With rows that change from step to step
!> (online contacts) the multipliers are carried over by contact identity (ops%keys).
!> The data of each step are checked for NaN / Inf once: a sum over vhat and dhat here, and
!> the dual solver sums the slacks of its first sweep (which carry any NaN / Inf of bhat); a
!> non-finite sum sends the step to ldp_solve, which names the offending entry.
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
!> which the assembly's agents do not list; O(n_dof Nb)), evaluates every agent's local density
!> there as the full-order model does (cell list and kernel, O(n_agents)) and hands the assembly
!> the speeds scaled by the diagram (density_speed_t%scale_speeds): every hyper-reduction
!> evaluates the desired velocity of the agents it reads at their density-dependent speed.
module cr_rom_stepper
  use cr_kinds, only: wp, i8
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_error, only: error_t, prefix_error
  use cr_strings, only: str
  use cr_nnls, only: ldp_solve, ldp_stats_t, nnls_work_t
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t
  use cr_rom_guard, only: rom_guard_t
  use cr_dual_qp, only: dual_qp_t, dual_qp_stats_t
  use cr_key_map, only: key_map_t
  use cr_lapack, only: la_gemv
  use cr_local_correction, only: local_correction_t, local_stats_t
  implicit none
  private
  public :: rom_solver_cfg_t, rom_traj_t, run_trajectory, reduced_positions

  !> Reduced solver settings.
  type :: rom_solver_cfg_t
    !> 'dual', 'nnls' or 'uzawa'
    character(len=8) :: name = 'dual'
    !> NNLS iteration cap (0: the solver's default 3 n + 50)
    integer :: nnls_max_iter = 0
    real(wp) :: uzawa_rho_factor = 0.2_wp
    real(wp) :: uzawa_eps = 1.0e-12_wp
    integer :: uzawa_max_iter = 1000000
  end type rom_solver_cfg_t

  !> One reduced trajectory.
  type :: rom_traj_t
    !> coefficients [nb, n_steps] and multipliers [R, n_steps] (no multipliers for 'online')
    real(wp), allocatable :: alpha(:,:), beta(:,:)
    !> steps with an infeasible reduced problem / a solve stopped by its cap
    integer :: n_infeasible = 0, n_capped = 0
    !> 'dual': steps answered by the Lawson-Hanson fallback (infeasible ones included),
    !> rows added and dropped by the dual iteration, sum of the final active-set sizes
    integer :: n_fallback = 0, dual_adds = 0, dual_drops = 0, active_sum = 0
    !> why the dual solver handed over: found infeasible, capped or more than 3/4 Nb active
    !> rows, certificate failed
    integer :: dual_why(3) = 0
    !> total solver iterations, largest number of constraint rows
    integer :: iterations = 0, max_rows = 0
    !> largest violation of the reduced constraints by the returned coefficients
    real(wp) :: max_violation = 0
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

contains

  !> Run n_steps reduced steps from q0 [n_dof]. With `guard`, every step is checked (cr_rom_guard)
  !> and the stepping stops at the first diverged step (traj%diverged_step). With `corr`
  !> (initialised), every step is corrected locally and the positions are carried in full
  !> (module header).
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
    real(wp), allocatable :: q(:), acc(:), vhat(:), alpha(:), bt(:,:), bhat(:,:), dhat(:), lam(:), gram(:,:)
    real(wp), allocatable :: ur(:), uc(:)
    integer, allocatable :: all_agents(:)
    type(local_stats_t) :: lst
    real(wp), allocatable :: vsub(:,:), qsub(:), q0sub(:), lam0(:)
    integer, allocatable :: dofs(:)
    !> positive multipliers of the previous step's rows by identity (warm start)
    type(key_map_t) :: prev
    type(nnls_work_t) :: work
    type(ldp_stats_t) :: st
    type(dual_qp_t) :: dqp
    type(dual_qp_stats_t) :: dst
    !> with the density-dependent desired speed: ctx with the step's speeds, and the desired
    !> velocities at the given speeds (the look-ahead's directions) [n_dof]
    type(eval_ctx_t) :: dctx
    real(wp), allocatable :: vdes(:)
    integer :: nu, j, nb, its
    integer(8) :: c0, c1, rate, t0, t1, t2, t3, t4
    logical :: capped, finite, carry
    nb = ops%nb
    ! the dofs the assembly reads, and their rows of V (contiguous)
    allocate(dofs(2 * size(ops%agents)))
    do j = 1, size(ops%agents)
      dofs(2*j-1:2*j) = [2 * ops%agents(j) - 1, 2 * ops%agents(j)]
    end do
    vsub = ops%v(dofs, :)
    q0sub = q0(dofs)
    allocate(qsub(size(dofs)))
    allocate(traj%alpha(nb, n_steps), traj%beta(merge(ops%r, 0, ops%fixed_rows), n_steps))
    traj%alpha = 0; traj%beta = 0
    allocate(acc(nb), vhat(nb), alpha(nb))
    acc = 0
    q = q0
    carry = present(corr)
    if (carry) then
      allocate(traj%q(size(q0), n_steps + 1), traj%n_corrected(n_steps), ur(size(q0)), uc(size(q0)))
      traj%q(:, 1) = q0
      traj%n_corrected = 0
      all_agents = [(j, j = 1, size(q0) / 2)]
      ! each trajectory's correction starts cold (reproducible whatever ran before)
      call corr%reset()
    end if
    if (ctx%density%on) then
      dctx = ctx
      allocate(vdes(size(q0)))
    end if
    call system_clock(c0, rate)
    do nu = 1, n_steps
      call system_clock(t0)
      ! positions at the start of the step, where needed: q0 + h V acc on those dofs (carried
      ! in full with a correction)
      if (ctx%density%on .and. .not. carry) then
        ! every agent (the density of an agent reads its neighbours)
        q = q0
        call la_gemv('N', ctx%h, ops%v, acc, 1.0_wp, q)
      else if (.not. carry) then
        qsub = q0sub
        call la_gemv('N', ctx%h, vsub, acc, 1.0_wp, qsub)
        q(dofs) = qsub
      end if
      call system_clock(t1)
      if (present(guard) .and. nu > 1) then
        ! the positions the previous step produced (those the assembly reads; every agent
        ! when carried)
        if (carry) then
          finite = guard%agents_ok(q, all_agents)
        else
          finite = guard%agents_ok(q, ops%agents)
        end if
        if (.not. finite) then
          traj%diverged_step = nu - 1; exit
        end if
      end if
      if (ctx%density%on) then
        call ctx%desired%evaluate(q, ctx%speeds, vdes)
        call dctx%density%scale_speeds(q, vdes, ctx%speeds, dctx%speeds)
        call ops%assemble(dctx, q, vhat, bt, dhat)
      else
        call ops%assemble(ctx, q, vhat, bt, dhat)
      end if
      call system_clock(t2)
      traj%max_rows = max(traj%max_rows, size(dhat))
      if (allocated(lam)) then
        if (size(lam) /= size(dhat)) deallocate(lam)
      end if
      if (.not. allocated(lam)) then
        allocate(lam(size(dhat))); lam = 0
      end if
      if (.not. ops%fixed_rows .and. allocated(ops%keys)) call match_rows(ops%keys(1:size(dhat)), lam, prev)
      if (scfg%name /= 'dual') bhat = transpose(bt)
      if (scfg%name == 'uzawa') then
        lam = 0
        call reduced_uzawa(bhat, dhat, vhat, ctx%h, alpha, lam, scfg, its, capped)
        traj%iterations = traj%iterations + its
        if (capped) traj%n_capped = traj%n_capped + 1
        if (size(dhat) > 0) traj%max_violation = max(traj%max_violation, maxval(matmul(bhat, alpha) - dhat))
      else if (scfg%name == 'dual') then
        finite = ieee_is_finite(sum(vhat) + sum(dhat))
        ! no flag of the previous step's solve may speak for this one (a step with non-finite
        ! data is not solved)
        dst = dual_qp_stats_t()
        if (finite) then
          lam0 = lam
          ! at most 3/4 Nb active rows: beyond, their Gram is too ill-conditioned to certify
          ! (the locked regime of online contacts) and the QR-based NNLS takes the step
          if (ops%has_gram) then
            call dqp%solve(bt, dhat, vhat, alpha, lam, dst, warm=.true., gsrc=ops, max_active=(3 * nb) / 4)
          else
            call dqp%solve(bt, dhat, vhat, alpha, lam, dst, warm=.true., max_active=(3 * nb) / 4)
          end if
          traj%iterations = traj%iterations + dst%adds + dst%drops
          traj%dual_adds = traj%dual_adds + dst%adds
          traj%dual_drops = traj%dual_drops + dst%drops
          traj%active_sum = traj%active_sum + dst%n_active
        end if
        if (dst%infeasible) traj%dual_why(1) = traj%dual_why(1) + 1
        if (dst%capped .or. dst%overfull) traj%dual_why(2) = traj%dual_why(2) + 1
        if (.not. (dst%certified .or. dst%infeasible .or. dst%capped .or. dst%overfull)) &
          traj%dual_why(3) = traj%dual_why(3) + 1
        if (dst%certified) then
          traj%max_violation = max(traj%max_violation, dst%max_violation)
        else
          traj%n_fallback = traj%n_fallback + 1
          ! stopped early: the previous step's active set is the better guess
          if (dst%overfull .or. dst%capped) lam = lam0
          call ldp_fallback()
          if (allocated(error)) return
        end if
      else
        if (ops%has_gram .and. ops%fixed_rows) then
          if (.not. allocated(gram)) allocate(gram(ops%r, ops%r))
          call ops%gram(gram)
          if (scfg%nnls_max_iter > 0) then
            call ldp_solve(bhat, dhat, vhat, alpha, lam, st, error, warm=.true., max_iter=scfg%nnls_max_iter, &
              work=work, gram=gram)
          else
            call ldp_solve(bhat, dhat, vhat, alpha, lam, st, error, warm=.true., work=work, gram=gram)
          end if
        else if (scfg%nnls_max_iter > 0) then
          call ldp_solve(bhat, dhat, vhat, alpha, lam, st, error, warm=.true., max_iter=scfg%nnls_max_iter, work=work)
        else
          call ldp_solve(bhat, dhat, vhat, alpha, lam, st, error, warm=.true., work=work)
        end if
        if (allocated(error)) then
          call prefix_error(error, "reduced step " // str(nu)); return
        end if
        traj%iterations = traj%iterations + st%nnls%iterations
        if (st%infeasible) traj%n_infeasible = traj%n_infeasible + 1
        if (.not. st%nnls%converged) traj%n_capped = traj%n_capped + 1
        if (.not. st%infeasible) traj%max_violation = max(traj%max_violation, st%max_violation)
      end if
      if (.not. ops%fixed_rows .and. allocated(ops%keys)) call prev%fill(ops%keys(1:size(dhat)), lam, keep=lam > 0)
      call system_clock(t3)
      traj%time_positions = traj%time_positions + real(t1 - t0, wp) / real(rate, wp)
      traj%time_assemble = traj%time_assemble + real(t2 - t1, wp) / real(rate, wp)
      traj%time_solve = traj%time_solve + real(t3 - t2, wp) / real(rate, wp)
      traj%alpha(:, nu) = alpha
      if (size(traj%beta, 1) == size(lam)) traj%beta(:, nu) = lam
      acc = acc + alpha
      if (present(guard)) then
        if (.not. guard%coeffs_ok(alpha, acc, ctx%h)) then
          traj%diverged_step = nu; exit
        end if
      end if
      if (carry) then
        ! u = V alpha + delta, q <- q + h u (the correction's time counts in the step's)
        call la_gemv('N', 1.0_wp, ops%v, alpha, 0.0_wp, ur)
        call corr%correct(ctx%scene, ctx%radius, q, ur, ctx%h, uc, lst, error)
        if (allocated(error)) then
          call prefix_error(error, "local correction after reduced step " // str(nu)); return
        end if
        q = q + ctx%h * uc
        traj%q(:, nu + 1) = q
        traj%n_corrected(nu) = lst%n_corrected
        if (lst%n_violated > 0) traj%conflict_steps = traj%conflict_steps + 1
        if (.not. lst%converged) traj%corr_unsolved = traj%corr_unsolved + 1
        traj%n_conflict_agents = traj%n_conflict_agents + lst%n_seeds
        call system_clock(t4)
        traj%time_correct = traj%time_correct + real(t4 - t3, wp) / real(rate, wp)
      end if
    end do
    if (traj%diverged_step > 0) then
      traj%alpha(:, traj%diverged_step:) = 0
      traj%beta(:, traj%diverged_step:) = 0
      if (carry) then
        do j = traj%diverged_step + 1, n_steps + 1
          traj%q(:, j) = traj%q(:, traj%diverged_step)
        end do
        traj%n_corrected(traj%diverged_step:) = 0
      end if
    end if
    call system_clock(c1)
    traj%time = real(c1 - c0, wp) / real(rate, wp)

  contains

    !> The certified Lawson-Hanson LDP, warm started from lam (> 0 marks the guess).
    subroutine ldp_fallback()
      bhat = transpose(bt)
      if (scfg%nnls_max_iter > 0) then
        call ldp_solve(bhat, dhat, vhat, alpha, lam, st, error, warm=.true., max_iter=scfg%nnls_max_iter, work=work)
      else
        call ldp_solve(bhat, dhat, vhat, alpha, lam, st, error, warm=.true., work=work)
      end if
      if (allocated(error)) then
        call prefix_error(error, "reduced step " // str(nu)); return
      end if
      traj%iterations = traj%iterations + st%nnls%iterations
      if (st%infeasible) traj%n_infeasible = traj%n_infeasible + 1
      if (.not. st%nnls%converged) traj%n_capped = traj%n_capped + 1
      if (.not. st%infeasible) traj%max_violation = max(traj%max_violation, st%max_violation)
    end subroutine ldp_fallback
  end subroutine run_trajectory

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
