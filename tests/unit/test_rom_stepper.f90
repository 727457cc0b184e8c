!> The reduced time stepping on hand-made reduced problems (no ROM file): an infeasible
!> reduced problem at every step (reduced positions that already overlap) returns the
!> least-violation coefficients, is counted and never produces NaN; the reduced Uzawa
!> iteration cap is counted; a feasible problem gives the exact projection; positions are
!> rebuilt as q0 + h V sum alpha; rows that change order from step to step (online contacts)
!> keep their multipliers by identity, so the dual solver's warm start survives; a local
!> correction that even the full projection cannot solve is counted per step, not an error.
module test_rom_stepper_ops
  use cr_kinds, only: wp
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t
  implicit none
  private
  public :: const_ops_t, perm_ops_t

  !> Returns the same (vhat, bhat, dhat) at every step.
  type, extends(reduced_ops_t) :: const_ops_t
    real(wp), allocatable :: vh(:), bh(:,:), dh(:)
  contains
    procedure :: assemble
  end type const_ops_t

  !> The same rows in a different order (and with one extra far row every other step) at
  !> every step, with their identities in keys (as online contacts).
  type, extends(const_ops_t) :: perm_ops_t
    integer :: calls = 0
  contains
    procedure :: assemble => perm_assemble
  end type perm_ops_t

contains

  subroutine perm_assemble(this, ctx, q, vhat, bt, dhat)
    class(perm_ops_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    integer, allocatable :: order(:)
    integer :: m, l, shift
    integer(8) :: far
    this%calls = this%calls + 1
    m = size(this%dh)
    shift = mod(7 * this%calls, m)
    order = [(1 + mod(l - 1 + shift, m), l = 1, m)]
    if (mod(this%calls, 2) == 0) order = [order, 0]
    if (allocated(bt)) deallocate(bt, dhat)
    allocate(bt(size(this%bh, 2), size(order)), dhat(size(order)))
    this%keys = [(int(order(l), 8) * 1000_8, l = 1, size(order))]
    far = 999_8
    do l = 1, size(order)
      if (order(l) == 0) then
        bt(:, l) = 1.0_wp
        dhat(l) = 1.0e3_wp
        this%keys(l) = far
      else
        bt(:, l) = this%bh(order(l), :)
        dhat(l) = this%dh(order(l))
      end if
    end do
    vhat = this%vh
    if (size(q) < 0 .or. ctx%h < 0) vhat = 0
  end subroutine perm_assemble

  subroutine assemble(this, ctx, q, vhat, bt, dhat)
    class(const_ops_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    vhat = this%vh
    bt = transpose(this%bh)
    dhat = this%dh
    if (size(q) < 0 .or. ctx%h < 0) vhat = 0
  end subroutine assemble
end module test_rom_stepper_ops

program test_rom_stepper
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_reduced_ops, only: eval_ctx_t
  use cr_rom_stepper, only: rom_solver_cfg_t, rom_traj_t, run_trajectory, reduced_positions
  use test_rom_stepper_ops, only: const_ops_t, perm_ops_t
  use cr_config, only: scene_cfg_t, obstacles_cfg_t, desired_cfg_t
  use cr_rom_file, only: rom_pair_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_reduced_ops, only: reduced_ops_t, make_reduced_ops, eim_exact_rows
  use cr_hyper_eim, only: hyper_eim_t
  use cr_random, only: rng_t
  use cr_lapack, only: la_geqrf, la_orgqr
  use cr_rom_guard, only: rom_guard_t
  use cr_projection, only: projection_settings_t
  use cr_local_correction, only: local_correction_t
  implicit none
  type(const_ops_t) :: ops
  type(eval_ctx_t) :: ctx
  type(rom_solver_cfg_t) :: scfg
  type(rom_traj_t) :: traj
  type(error_t), allocatable :: error
  real(wp), allocatable :: q(:,:)
  real(wp) :: q0(4)

  q0 = [0.1_wp, 0.2_wp, 0.3_wp, 0.4_wp]
  ctx%h = 0.5_wp
  ops%nb = 1; ops%r = 2
  ops%v = reshape([1.0_wp, 0.0_wp, 0.0_wp, 0.0_wp], [4, 1])
  ops%agents = [1, 2]
  ops%m = 0

  ! infeasible at every step: alpha <= -1 and -alpha <= -1; least violation alpha = 0
  ops%vh = [0.5_wp]
  ops%bh = reshape([1.0_wp, -1.0_wp], [2, 1])
  ops%dh = [-1.0_wp, -1.0_wp]
  call run_trajectory(ops, ctx, q0, 5, scfg, traj, error)
  call check(.not. allocated(error), "infeasible: no error")
  call check(traj%n_infeasible == 5, "infeasible: every step counted")
  call check(all(abs(traj%alpha) <= 1.0e-10_wp), "infeasible: least-violation coefficients (alpha = 0)")
  call check(all(traj%beta == traj%beta) .and. all(abs(traj%beta) < huge(1.0_wp)), "infeasible: finite multipliers")

  ! feasible: alpha <= 0.2 and -alpha <= 1: projection of 0.5 is 0.2, multiplier 0.3
  ops%dh = [0.2_wp, 1.0_wp]
  call run_trajectory(ops, ctx, q0, 3, scfg, traj, error)
  call check(.not. allocated(error), "feasible: no error")
  call check(traj%n_infeasible == 0 .and. traj%n_capped == 0, "feasible: nothing counted")
  call check_close(traj%alpha(1, 3), 0.2_wp, 1.0e-14_wp, "feasible: exact projection")
  call check_close(traj%beta(1, 3), 0.3_wp, 1.0e-14_wp, "feasible: multiplier")
  call check(traj%beta(2, 3) == 0.0_wp, "feasible: inactive multiplier zero")
  q = reduced_positions(q0, ops%v, traj%alpha, ctx%h)
  call check_close(q(1, 4), 0.1_wp + 0.5_wp * 0.6_wp, 1.0e-14_wp, "positions: q0 + h V sum alpha")
  call check(all(q(2:, 4) == q0(2:)), "positions: untouched dofs")

  ! the paper's Uzawa with a cap of 2 iterations cannot converge: counted as capped
  scfg%name = 'uzawa'
  scfg%uzawa_max_iter = 2
  scfg%uzawa_rho_factor = 1.0e-3_wp
  call run_trajectory(ops, ctx, q0, 4, scfg, traj, error)
  call check(traj%n_capped == 4, "uzawa: capped steps counted")
  call check(all(abs(traj%alpha) < huge(1.0_wp)), "uzawa capped: finite")
  ! converged Uzawa agrees with the exact solution
  scfg%uzawa_max_iter = 100000
  scfg%uzawa_rho_factor = 0.2_wp
  scfg%uzawa_eps = 1.0e-14_wp
  call run_trajectory(ops, ctx, q0, 2, scfg, traj, error)
  call check(traj%n_capped == 0, "uzawa: converged")
  call check_close(traj%alpha(1, 2), 0.2_wp, 1.0e-10_wp, "uzawa: same projection")
  call check_gram()
  call check_guard()
  call check_identities()
  call check_unsolved_correction()
  call test_summary()

contains

  !> Local correction of every step (&sweep correction = 'local') where no velocity can remove
  !> the overlaps: agent 1 is a disk of radius 0.55 in a hall 1 m wide, overlapping the bottom
  !> and the top wall. Every step is counted in corr_unsolved, none is an error, the carried
  !> positions stay finite.
  subroutine check_unsolved_correction()
    type(local_correction_t) :: corr
    type(eval_ctx_t) :: c2
    real(wp) :: q1(4)
    call c2%scene%init(scene_cfg_t(), obstacles_cfg_t(), error)
    call check(.not. allocated(error), "unsolved correction: scene")
    c2%h = 0.01_wp
    c2%radius = 0.55_wp
    q1 = [0.3_wp, 0.5_wp, 1.0_wp, 0.5_wp]
    call corr%init(projection_settings_t(), 1.5_wp, error)
    call check(.not. allocated(error), "unsolved correction: init")
    scfg = rom_solver_cfg_t()
    ! the feasible reduced problem of the main program: alpha = 0.2 moves agent 1 along x
    ops%nb = 1; ops%r = 2
    ops%v = reshape([1.0_wp, 0.0_wp, 0.0_wp, 0.0_wp], [4, 1])
    ops%agents = [1, 2]
    ops%vh = [0.5_wp]
    ops%bh = reshape([1.0_wp, -1.0_wp], [2, 1])
    ops%dh = [0.2_wp, 1.0_wp]
    call run_trajectory(ops, c2, q1, 3, scfg, traj, error, corr=corr)
    call check(.not. allocated(error), "unsolved correction: not an error")
    if (allocated(error)) then
      deallocate(error); return
    end if
    call check(traj%corr_unsolved == 3, "unsolved correction: every step counted")
    call check(all(abs(traj%q) < huge(1.0_wp)), "unsolved correction: finite positions")
    call corr%free()
  end subroutine check_unsolved_correction

  !> Rows permuted at every step, matched by identity: after the first step the dual solver's
  !> warm start is the answer (nothing added), and every step gives the same projection as a
  !> cold solve of the unpermuted problem.
  subroutine check_identities()
    type(perm_ops_t) :: pops
    type(const_ops_t) :: cops
    type(rom_solver_cfg_t) :: c1
    type(rom_traj_t) :: t1, t2
    type(rng_t) :: rng
    integer, parameter :: nb = 6, m = 9
    real(wp) :: qz(2 * nb)
    integer :: i, j
    call rng%seed(5, 3)
    allocate(cops%vh(nb), cops%bh(m, nb), cops%dh(m))
    do j = 1, nb
      cops%vh(j) = 3 * rng%normal()
      do i = 1, m
        cops%bh(i, j) = rng%normal()
      end do
    end do
    cops%dh = [(abs(rng%normal()) * 0.1_wp, i = 1, m)]
    cops%nb = nb; cops%r = m; cops%m = 0
    cops%v = reshape([(merge(1.0_wp, 0.0_wp, mod(i - 1, 2 * nb + 1) == 0), i = 1, 2 * nb * nb)], [2 * nb, nb])
    cops%agents = [(i, i = 1, nb)]
    pops%vh = cops%vh; pops%bh = cops%bh; pops%dh = cops%dh
    pops%nb = nb; pops%r = m; pops%m = 0; pops%v = cops%v; pops%agents = cops%agents
    pops%fixed_rows = .false.
    qz = 0
    call run_trajectory(cops, ctx, qz, 6, c1, t1, error)
    call check(.not. allocated(error) .and. t1%n_fallback == 0, "identities: fixed rows solved")
    call check(t1%active_sum > 0, "identities: some rows active")
    call run_trajectory(pops, ctx, qz, 6, c1, t2, error)
    call check(.not. allocated(error) .and. t2%n_fallback == 0, "identities: permuted rows solved")
    call check(t1%dual_adds > 0 .and. t2%dual_adds == t1%dual_adds, &
      "identities: rows added as often as with fixed rows (the warm start is kept)")
    call check(maxval(abs(t2%alpha - t1%alpha)) <= 1.0e-12_wp * maxval(abs(t1%alpha)), &
      "identities: the same projection whatever the order")
  end subroutine check_identities

  !> The cheap Gram of the exact assembly (Z (V V^T) Z^T) equals bhat bhat^T.
  subroutine check_gram()
    integer, parameter :: na = 40, nb = 70, nd = 12
    type(scene_cfg_t) :: sc
    type(obstacles_cfg_t) :: oc
    type(desired_cfg_t) :: dc
    type(eval_ctx_t) :: c2
    type(rom_pair_t) :: pair
    type(sparse_cone_t) :: cone
    class(reduced_ops_t), allocatable :: rops
    type(rng_t) :: rng
    real(wp), allocatable :: a(:,:), tau(:), q(:), vh(:), bh(:,:), dh(:), g(:,:), gd(:)
    integer :: ia(nd), ib(nd), ob(nd), i, j
    call rng%seed(11, 1)
    call c2%scene%init(sc, oc, error)
    call check(.not. allocated(error), "gram: scene")
    allocate(q(2 * na), a(2 * na, nb), tau(nb))
    do i = 1, na
      q(2*i-1) = 0.1_wp + 1.1_wp * rng%uniform()
      q(2*i) = 0.1_wp + 0.8_wp * rng%uniform()
    end do
    do j = 1, nb
      do i = 1, 2 * na
        a(i, j) = rng%normal()
      end do
    end do
    call la_geqrf(a, tau, error)
    call la_orgqr(a, tau, error)
    call check(.not. allocated(error), "gram: orthonormal basis")
    do i = 1, nd
      ia(i) = i; ib(i) = i + 7; ob(i) = 0
    end do
    ib(nd) = 0; ob(nd) = 1
    call cone%from_indices(nd, [3, 1, 12, 7, 5, 9])
    pair%n = nb; pair%r = 6; pair%nb = nb; pair%v = a
    call pair%terms%init(cone, 6, ia, ib, ob, 2 * na, error)
    call check(.not. allocated(error), "gram: candidates")
    call make_reduced_ops('none', 'cone', pair, [0, 0, 0], 1.5_wp, "test", rops, error)
    call check(.not. allocated(error), "gram: ops")
    call check(rops%has_gram, "gram: used when Nb >= 4 zmax^2")
    c2%radius = 0.02_wp; c2%h = 0.05_wp
    c2%speeds = [(1.0_wp, i = 1, na)]
    call c2%desired%init(dc, c2%scene, c2%radius, na, error)
    allocate(vh(nb), g(6, 6))
    call rops%assemble(c2, q, vh, bh, dh)
    call rops%gram(g)
    call check(maxval(abs(g - matmul(transpose(bh), bh))) <= 1.0e-14_wp * maxval(abs(g)), "gram: Z P Z^T = Bh Bh^T")
    ! the entries the dual solver asks for, and the diagonal
    allocate(gd(6))
    do i = 1, 6
      call rops%gram_entries(i, [6, 1, i, 3], gd(1:4))
      call check(maxval(abs(gd(1:4) - g(i, [6, 1, i, 3]))) <= 1.0e-14_wp * maxval(abs(g)), "gram: entries of row")
    end do
    call rops%gram_diag(gd)
    call check(maxval(abs(gd - [(g(i, i), i = 1, 6)])) <= 1.0e-14_wp * maxval(abs(g)), "gram: diagonal")
    call check_eim_rows(pair, c2, q, bh)
  end subroutine check_gram

  !> EIM rows keep unit normals: with every s2 entry interpolated (identity modes) the EIM rows
  !> are the exact rows and none is evaluated exactly; with one mode on a single entry, the
  !> interpolated normals of the other rows vanish (the congested150 failure: such a row
  !> asked for |alpha| ~ 1e14) and are evaluated exactly, so again the exact rows.
  subroutine check_eim_rows(pair0, c2, q, bh_exact)
    type(rom_pair_t), intent(in) :: pair0
    type(eval_ctx_t), intent(in) :: c2
    real(wp), intent(in) :: q(:), bh_exact(:,:)
    type(rom_pair_t) :: pe
    type(hyper_eim_t) :: he
    class(reduced_ops_t), allocatable :: rops
    real(wp), allocatable :: vh(:), bh(:,:), dh(:)
    integer :: p2, p3, i, j
    p2 = pair0%terms%p(2); p3 = pair0%terms%p(3)
    do j = 1, 2
      pe = pair0
      pe%hyper = .true.
      call he%eim(1)%free(); call he%eim(2)%free(); call he%eim(3)%free()
      he%eim(1)%p = pair0%terms%p(1); he%eim(3)%p = p3
      allocate(he%eim(1)%basis(he%eim(1)%p, 0), he%eim(1)%idx(0))
      allocate(he%eim(3)%basis(p3, 0), he%eim(3)%idx(0))
      he%eim(2)%p = p2
      if (j == 1) then
        he%eim(2)%m = p2
        allocate(he%eim(2)%basis(p2, p2))
        he%eim(2)%basis = 0
        do i = 1, p2
          he%eim(2)%basis(i, i) = 1
        end do
        he%eim(2)%idx = [(i, i = 1, p2)]
      else
        he%eim(2)%m = 1
        allocate(he%eim(2)%basis(p2, 1))
        he%eim(2)%basis = 0
        he%eim(2)%basis(1, 1) = 1
        he%eim(2)%idx = [1]
      end if
      ! the pair stores this EIM as its only method
      if (allocated(pe%methods)) deallocate(pe%methods)
      allocate(pe%methods(1))
      allocate(pe%methods(1)%m, source=he)
      call make_reduced_ops('eim', 'cone', pe, [0, he%eim(2)%m, 0], 1.5_wp, "test", rops, error)
      call check(.not. allocated(error), "eim rows: ops")
      if (allocated(error)) return
      allocate(vh(pe%nb))
      call rops%assemble(c2, q, vh, bh, dh)
      call check(maxval(abs(bh - bh_exact)) <= 1.0e-13_wp * maxval(abs(bh_exact)), &
        "eim rows " // merge("all entries", "one mode   ", j == 1) // ": the exact rows")
      if (j == 1) call check(eim_exact_rows(rops) == 0, "eim rows all entries: no exact evaluation")
      if (j == 2) call check(eim_exact_rows(rops) >= p3 - 1, "eim rows one mode: vanishing normals evaluated exactly")
      deallocate(vh)
    end do
  end subroutine check_eim_rows

  !> A reduced row of norm 1e-15 that asks for a negative gap (the EIM failure of congested150,
  !> docs/model.md#eim-rows-with-unit-normals) is feasible only at |alpha| = 1e12: the guard stops
  !> the trajectory at that step and zeroes the coefficients from there; a sane trajectory
  !> is not touched.
  subroutine check_guard()
    type(rom_guard_t) :: guard
    type(scene_cfg_t) :: sc
    type(eval_ctx_t) :: c3
    scfg = rom_solver_cfg_t()
    call c3%scene%init(sc, obstacles_cfg_t(), error)
    c3%h = 0.5_wp
    call guard%init(c3%scene, 1.0_wp, 2.5_wp, 2)
    call check(guard%inside(q0(1:2)) .and. guard%inside(q0(3:4)), "guard: the start is inside")
    ops%r = 1
    ops%vh = [0.5_wp]
    ops%bh = reshape([1.0e-15_wp], [1, 1])
    ops%dh = [-1.0e-3_wp]
    call run_trajectory(ops, c3, q0, 5, scfg, traj, error)
    call check(.not. allocated(error) .and. traj%n_infeasible == 0 .and. abs(traj%alpha(1, 1)) > 1.0e11_wp, &
      "vanishing row: feasible at |alpha| ~ 1e12, nothing flagged without the guard")
    call run_trajectory(ops, c3, q0, 5, scfg, traj, error, guard=guard)
    call check(.not. allocated(error) .and. traj%diverged_step == 1, "guard: diverged at step 1")
    call check(all(traj%alpha == 0), "guard: coefficients zero from the diverged step on")
    ops%bh = reshape([1.0_wp], [1, 1])
    ops%dh = [0.2_wp]
    call run_trajectory(ops, c3, q0, 5, scfg, traj, error, guard=guard)
    call check(.not. allocated(error) .and. traj%diverged_step == 0 .and. abs(traj%alpha(1, 5) - 0.2_wp) <= 1.0e-14_wp, &
      "guard: a sane trajectory runs to the end unchanged")
  end subroutine check_guard
end program test_rom_stepper
