!> Hyper-reduction methods through their factory (cr_hyper_factory) and the reduced desired
!> velocity of 'eq_deim' (cr_hyper_eq): the factory refuses unknown names with one line; with
!> every dof selected the DEIM of the desired velocity reproduces V^T v(q) to round-off; with
!> fewer it reads only the selected agents and its error obeys the (oversampled) DEIM bound
!>   |vhat - V^T v| <= |V|_2 |(U_P)^+|_2 |(I - U U^T) v|
!> (Chaturantabut and Sorensen 2010; Peherstorfer, Drmac and Gugercin 2020 for P larger than
!> the m DEIM indices: here both dofs of each of their agents) at a configuration
!> outside the training set. Snapshots are the desired velocities of random configurations in
!> the default hall (generated identically on every rank, distributed by column blocks).
program test_hyper_methods
  use mpi_f08, only: MPI_Init, MPI_Finalize, MPI_COMM_WORLD
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_assert, only: check, test_summary
  use cr_random, only: rng_t
  use cr_distribution, only: block_range
  use cr_lapack, only: la_geqrf, la_orgqr, la_gesvd
  use cr_config, only: scene_cfg_t, obstacles_cfg_t, desired_cfg_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_eim, only: eim_build
  use cr_hyper_terms, only: hyper_terms_t
  use cr_hyper_method, only: hyper_method_t, hyper_slot_t
  use cr_hyper_factory, only: HYPER_NAMES, new_hyper, stored_hypers
  use cr_hyper_eq, only: hyper_eq_t, ops_eq_t
  use cr_reduced_base, only: eval_ctx_t, reduced_ops_t
  use cr_rom_file, only: rom_pair_t
  use cr_reduced_ops, only: make_reduced_ops
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  integer :: ierr

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call test_factory()
  call test_deim_desired()
  call env%free()
  call test_summary(env%rank)
  call MPI_Finalize(ierr)

contains

  !> Every registered name is served; an unknown one is refused with one line (code 2), also
  !> through make_reduced_ops with its prefix; the stored groups are eim and eq.
  subroutine test_factory()
    class(hyper_method_t), allocatable :: m
    type(hyper_slot_t), allocatable :: slots(:)
    type(rom_pair_t) :: pair
    class(reduced_ops_t), allocatable :: ops
    type(sparse_cone_t) :: cone
    integer :: k
    do k = 1, size(HYPER_NAMES)
      call new_hyper(HYPER_NAMES(k), m, error)
      call check(.not. allocated(error) .and. allocated(m), "factory: serves '" // trim(HYPER_NAMES(k)) // "'")
      if (allocated(m)) deallocate(m)
    end do
    call new_hyper('deim', m, error)
    call check(allocated(error), "factory: refuses 'deim'")
    if (.not. allocated(error)) return
    call check(error%code == EXIT_BAD_INPUT, "factory: input error (code 2)")
    call check(error%message == "unknown hyper-reduction 'deim' (known: none, eim, eq, eq_deim)", &
      "factory: the one-line message (got: " // error%message // ")")
    call check(index(error%message, new_line('a')) == 0, "factory: one line")
    call stored_hypers(slots)
    call check(size(slots) == 2, "factory: two stored methods")
    if (size(slots) == 2) call check(slots(1)%m%storage() == "eim" .and. slots(2)%m%storage() == "eq", &
      "factory: stored groups eim, eq")
    pair%n = 1; pair%r = 0; pair%nb = 1
    allocate(pair%v(4, 1))
    pair%v = 0.5_wp
    call cone%from_indices(1, [integer ::])
    call pair%terms%init(cone, 0, [1], [2], [0], 4, error)
    call make_reduced_ops('EQ', 'cone', pair, [0, 0, 0], 1.5_wp, "in.nml: &sweep", ops, error)
    call check(allocated(error), "factory: make_reduced_ops refuses 'EQ'")
    if (allocated(error)) call check(error%code == EXIT_BAD_INPUT .and. &
      error%message == "in.nml: &sweep: unknown hyper-reduction " // &
      "'EQ' (known: none, eim, eq, eq_deim)", "factory: make_reduced_ops message (got: " // error%message // ")")
    ! a pair without stored data serves 'none' and refuses 'eq_deim'
    call make_reduced_ops('eq_deim', 'cone', pair, [0, 0, 0], 1.5_wp, "t", ops, error)
    call check(allocated(error), "factory: 'eq_deim' needs stored data")
    call make_reduced_ops('none', 'cone', pair, [0, 0, 0], 1.5_wp, "t", ops, error)
    call check(.not. allocated(error), "factory: 'none' needs nothing stored")
  end subroutine test_factory

  !> DEIM of the desired velocity: exact with every dof, bounded error with fewer.
  subroutine test_deim_desired()
    integer, parameter :: na = 24, nd = 2 * na, nb = 16, n_snap = 240, m_small = 14
    type(scene_cfg_t) :: sc
    type(obstacles_cfg_t) :: oc
    type(desired_cfg_t) :: dc
    type(eval_ctx_t) :: ctx
    type(sparse_cone_t) :: cone
    type(hyper_terms_t) :: terms
    type(hyper_eq_t) :: he
    class(hyper_method_t), allocatable :: hm
    class(reduced_ops_t), allocatable :: ops
    type(rng_t) :: rng
    real(wp), allocatable :: s(:,:), v(:,:), tau(:), q(:), vd(:), vh(:), ref(:), bt(:,:), dh(:), sv(:), res(:), &
      work(:,:), u(:,:)
    integer, allocatable :: rows(:)
    logical, allocatable :: used(:)
    integer :: j0, j1, c, i, k, m
    real(wp) :: cond, bound, err
    call ctx%scene%init(sc, oc, error)
    call check(.not. allocated(error), "deim: scene")
    ctx%radius = 0.02_wp; ctx%h = 0.05_wp
    ctx%speeds = [(1.0_wp + 0.01_wp * i, i = 1, na)]
    call ctx%desired%init(dc, ctx%scene, ctx%radius, na, error)
    call check(.not. allocated(error), "deim: desired velocity")
    if (allocated(error)) return
    ! training snapshots: this rank's block of the random configurations
    call block_range(n_snap, env%size, env%rank, j0, j1)
    j1 = j0 + j1; j0 = j0 + 1
    allocate(s(nd, j1 - j0 + 1), vd(nd))
    do c = j0, j1
      q = random_q(c)
      call ctx%desired%evaluate(q, ctx%speeds, vd)
      s(:, c - j0 + 1) = vd
    end do
    ! an orthonormal basis V [nd, nb]
    call rng%seed(5, 1)
    allocate(v(nd, nb), tau(nb))
    do k = 1, nb
      do i = 1, nd
        v(i, k) = rng%normal()
      end do
    end do
    call la_geqrf(v, tau, error)
    call la_orgqr(v, tau, error)
    call check(.not. allocated(error), "deim: orthonormal basis")
    ! no contact terms (R = 0): vhat alone
    call cone%from_indices(1, [integer ::])
    call terms%init(cone, 0, [1], [2], [0], nd, error)
    call check(.not. allocated(error), "deim: candidates")
    do k = 1, 3
      he%eq(k)%p = terms%p(merge(1, 3, k == 1)); he%eq(k)%m = 0
      allocate(he%eq(k)%idx(0), he%eq(k)%w(0, 0), he%eq(k)%err(0))
    end do
    call eim_build(env, s, nd, he%vdeim, error)
    call check(.not. allocated(error), "deim: build")
    if (allocated(error)) return
    call check(he%vdeim%m == nd, "deim: the snapshots have full rank " // str(nd) // " (got " // str(he%vdeim%m) // ")")
    ! a configuration outside the training set and its exact reduced desired velocity
    q = random_q(n_snap + 7)
    call ctx%desired%evaluate(q, ctx%speeds, vd)
    ref = matmul(transpose(v), vd)
    allocate(vh(nb))
    do m = he%vdeim%m, m_small, m_small - he%vdeim%m
      call he%make_ops('eq_deim', v, terms, nb, 0, [m, 0, 0], "test", ops, error)
      call check(.not. allocated(error), "deim: ops with m = " // str(m))
      if (allocated(error)) return
      call ops%assemble(ctx, q, vh, bt, dh)
      err = norm2(vh - ref)
      ! the rows used: both dofs of every agent of the first m DEIM dofs
      allocate(used(na))
      used = .false.
      used((he%vdeim%idx(1:m) + 1) / 2) = .true.
      rows = [(merge([2 * i - 1, 2 * i], [0, 0], used(i)), i = 1, na)]
      rows = pack(rows, rows > 0)
      call check(size(ops%agents) == count(used) .and. all(used(ops%agents)), "deim m = " // str(m) // &
        ": reads exactly the DEIM agents")
      u = he%vdeim%basis(:, 1:m)
      work = u(rows, :)
      allocate(sv(m))
      call la_gesvd(work, sv, error)
      call check(.not. allocated(error), "deim: singular values of U_P")
      cond = sv(1) / sv(m)
      if (m == nd) then
        ! every dof: U square orthogonal, the interpolation is the identity up to rounding
        call check(size(ops%agents) == na, "deim all dofs: every agent read")
        call check(err <= 100 * nd * epsilon(1.0_wp) * cond * norm2(vd), "deim all dofs: V^T v to round-off (err " // &
          str(err) // ", cond " // str(cond) // ")")
      else
        ! fewer: only the selected agents, and the bound |V|_2 |(U_P)^+|_2 |(I - U U^T) v| (|V|_2 = 1)
        call check(size(ops%agents) < na, "deim m = " // str(m) // ": reads " // str(size(ops%agents)) // " of " // &
          str(na) // " agents")
        res = vd - matmul(u, matmul(transpose(u), vd))
        bound = norm2(res) / sv(m)
        call check(err <= bound * (1 + 1.0e-8_wp) + 100 * nd * epsilon(1.0_wp) * cond * norm2(vd), &
          "deim m = " // str(m) // ": error " // str(err) // " within the bound " // str(bound))
        call check(err > 0, "deim m = " // str(m) // ": a true reduction (not exact)")
      end if
      deallocate(used, sv)
    end do
    ! terms without points, as the ROM file reader leaves them (m = 0: no indices stored, idx
    ! never allocated in the method the factory made); make_ops once took the section idx(1:0)
    ! of the unallocated array, a read of its undefined bounds that only valgrind sees
    ! (scripts/dev/memcheck.sh runs this program at 1 rank)
    call new_hyper('eq', hm, error)
    call check(.not. allocated(error), "eq without points: method")
    if (allocated(error)) return
    select type (hm)
    type is (hyper_eq_t)
      do k = 1, 3
        hm%eq(k)%p = terms%p(merge(1, 3, k == 1)); hm%eq(k)%m = 0
      end do
    end select
    call hm%make_ops('eq', v, terms, nb, 0, [0, 0, 0], "test", ops, error)
    call check(.not. allocated(error), "eq without points: ops")
    if (allocated(error)) return
    select type (ops)
    type is (ops_eq_t)
      call check(size(ops%idx1) == 0 .and. size(ops%idx2) == 0 .and. size(ops%idx3) == 0 .and. &
        size(ops%agents) == 0, "eq without points: no point, no agent read")
    class default
      call check(.false., "eq without points: ops of type ops_eq_t")
    end select
    call ops%assemble(ctx, q, vh, bt, dh)
    call check(all(vh == 0) .and. size(dh) == 0, "eq without points: vhat = 0, no row")
  end subroutine test_deim_desired

  !> Configuration number c: 24 agents uniform in [0.1, 1.2] x [0.1, 0.9] of the default 1.3 x 1
  !> hall (stream c).
  function random_q(c) result(q)
    integer, intent(in) :: c
    real(wp), allocatable :: q(:)
    type(rng_t) :: rng
    integer :: i, na
    na = 24
    allocate(q(2 * na))
    call rng%seed(17, c)
    do i = 1, na
      q(2*i-1) = 0.1_wp + 1.1_wp * rng%uniform()
      q(2*i) = 0.1_wp + 0.8_wp * rng%uniform()
    end do
  end function random_q
end program test_hyper_methods
