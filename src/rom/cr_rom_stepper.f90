!> Time stepping of the reduced model for one parameter (the paper's section 3.2):
!>   q^(nu-1) = q^0 + h V sum_{k < nu} alpha^k          (only the agents the assembly reads)
!>   (alpha^nu, beta^nu) = reduced projection at q^(nu-1)
!> solved exactly by the active-set least-distance solver (warm-started from the previous
!> step's multipliers), or by the paper's Uzawa iteration for comparison. Infeasible reduced
!> problems (the reduced positions already overlap) return the least-violation solution and
!> are counted; so are solves that reach their iteration cap.
module cr_rom_stepper
  use cr_kinds, only: wp
  use cr_error, only: error_t, prefix_error
  use cr_strings, only: str
  use cr_nnls, only: ldp_solve, ldp_stats_t, nnls_work_t
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t
  use cr_rom_guard, only: rom_guard_t
  implicit none
  private
  public :: rom_solver_cfg_t, rom_traj_t, run_trajectory, reduced_positions

  !> Reduced solver settings.
  type :: rom_solver_cfg_t
    character(len=8) :: name = 'nnls'
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
    !> total solver iterations, largest number of constraint rows
    integer :: iterations = 0, max_rows = 0
    !> largest violation of the reduced constraints by the returned coefficients
    real(wp) :: max_violation = 0
    !> wall time of the stepping (seconds)
    real(wp) :: time = 0
    !> first step whose positions the divergence guard refused (0: none); the stepping
    !> stopped there and alpha(:, diverged_step:) = 0 (positions frozen at step - 1)
    integer :: diverged_step = 0
  end type rom_traj_t

contains

  !> Run n_steps reduced steps from q0 [n_dof]. With `guard`, every step is checked (cr_rom_guard)
  !> and the stepping stops at the first diverged step (traj%diverged_step).
  subroutine run_trajectory(ops, ctx, q0, n_steps, scfg, traj, error, guard)
    class(reduced_ops_t), intent(inout) :: ops
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q0(:)
    integer, intent(in) :: n_steps
    type(rom_solver_cfg_t), intent(in) :: scfg
    type(rom_traj_t), intent(out) :: traj
    type(error_t), allocatable, intent(out) :: error
    type(rom_guard_t), intent(in), optional :: guard
    real(wp), allocatable :: q(:), acc(:), vhat(:), alpha(:), bhat(:,:), dhat(:), lam(:), gram(:,:)
    type(nnls_work_t) :: work
    type(ldp_stats_t) :: st
    integer :: nu, j, a, nb, na, its
    integer(8) :: c0, c1, rate
    logical :: all_agents, capped
    nb = ops%nb
    na = size(q0) / 2
    all_agents = size(ops%agents) == na
    allocate(traj%alpha(nb, n_steps), traj%beta(merge(ops%r, 0, ops%fixed_rows), n_steps))
    traj%alpha = 0; traj%beta = 0
    allocate(acc(nb), vhat(nb), alpha(nb))
    acc = 0
    q = q0
    call system_clock(c0, rate)
    do nu = 1, n_steps
      ! positions at the start of the step, where needed
      if (all_agents) then
        q = q0 + ctx%h * matmul(ops%v, acc)
      else
        do j = 1, size(ops%agents)
          a = ops%agents(j)
          q(2*a-1) = q0(2*a-1) + ctx%h * dot_product(ops%v(2*a-1, :), acc)
          q(2*a) = q0(2*a) + ctx%h * dot_product(ops%v(2*a, :), acc)
        end do
      end if
      if (present(guard) .and. nu > 1) then
        ! the positions the previous step produced (those the assembly reads)
        if (.not. guard%agents_ok(q, ops%agents)) then
          traj%diverged_step = nu - 1; exit
        end if
      end if
      call ops%assemble(ctx, q, vhat, bhat, dhat)
      traj%max_rows = max(traj%max_rows, size(dhat))
      if (allocated(lam)) then
        if (size(lam) /= size(dhat)) deallocate(lam)
      end if
      if (.not. allocated(lam)) then
        allocate(lam(size(dhat))); lam = 0
      end if
      if (scfg%name == 'uzawa') then
        lam = 0
        call reduced_uzawa(bhat, dhat, vhat, ctx%h, alpha, lam, scfg, its, capped)
        traj%iterations = traj%iterations + its
        if (capped) traj%n_capped = traj%n_capped + 1
        if (size(dhat) > 0) traj%max_violation = max(traj%max_violation, maxval(matmul(bhat, alpha) - dhat))
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
      traj%alpha(:, nu) = alpha
      if (size(traj%beta, 1) == size(lam)) traj%beta(:, nu) = lam
      acc = acc + alpha
      if (present(guard)) then
        if (.not. guard%coeffs_ok(alpha, acc, ctx%h)) then
          traj%diverged_step = nu; exit
        end if
      end if
    end do
    if (traj%diverged_step > 0) then
      traj%alpha(:, traj%diverged_step:) = 0
      traj%beta(:, traj%diverged_step:) = 0
    end if
    call system_clock(c1)
    traj%time = real(c1 - c0, wp) / real(rate, wp)
  end subroutine run_trajectory

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
