!> Hyper-reduction 'eq' (and its variant 'eq_deim'): empirical quadrature of the projected terms
!> (cr_eq: NNOMP / signed OMP on Gramians summed over all ranks).
!>
!> Stored per pair in group `eq`: one subgroup per term (`eq/s1`, `eq/s2`, `eq/s3`: attributes
!> p, m [, note]; datasets indices [m], weights [m, m] (column k: the weights after k
!> selections), err [m]) and `eq/v_deim`, a DEIM of the desired velocity s1 = v(q) (POD + DEIM
!> of the same snapshots, layout of an EIM group, cr_hyper_eim). Files written before
!> `v_deim` existed are read as they are; 'eq_deim' then refuses them.
!>
!> Online, 'eq' sums the m_k weighted quadrature entries of each term. Its desired-velocity
!> term needs every dof (docs/model.md#reduced-desired-velocity-eq_deim):
!> Pi1 = V^T v = sum_j v_j V(j,:) is exact for a quadrature only if it integrates every
!> function j -> v_j V(j, i), and these span R^n_dof as soon as Nb >= 2 and the snapshots
!> v vary, so the only exact rule is all dofs with weight 1. 'eq_deim' replaces that term by
!> the DEIM of v with its m_v leading modes U: the agents A of the first m_v DEIM dofs give
!> both components each (one evaluation per agent), P = their 2 |A| >= m_v dofs, and
!> vhat = V^T U (U_P)^+ v_P (least squares, "gappy POD" / oversampled DEIM; = the DEIM
!> interpolant when P = I), which reads the desired velocity (hence the positions) of the
!> agents A only. Error bound: |v - U (U_P)^+ v_P| <= |(U_P)^+|_2 |(I - U U^T) v|.
module cr_hyper_eq
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_h5file, only: h5file_t
  use cr_eim, only: eim_t
  use cr_eq, only: eq_t, eq_gramian, eq_build
  use cr_hyper_terms, only: hyper_terms_t
  use cr_hyper_method, only: hyper_method_t, hyper_train_t, choose_points, default_points, max_points, &
    s1_eim, write_term_attrs, read_term_attrs, TERM_NAMES
  use cr_hyper_eim, only: write_eim_group, read_eim_group
  use cr_reduced_base, only: reduced_ops_t, eval_ctx_t, gram_setup, add_row, add_pair, ensure, &
    agent_desired, mark_agents, unique_map
  use cr_contact_eval, only: eval_contact
  use cr_lapack, only: la_gemv, la_gesvd
  use cr_product_check, only: need_finite, need_range, need_size, product_error
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: hyper_eq_t, ops_eq_t

  !> The stored EQ of s1, s2, s3 and the DEIM of s1.
  type, extends(hyper_method_t) :: hyper_eq_t
    type(eq_t) :: eq(3)
    !> DEIM of the desired velocity (p = 0 when the file has none)
    type(eim_t) :: vdeim
  contains
    procedure, nopass :: storage => eq_storage
    procedure :: build_data => eq_method_build
    procedure :: write => eq_method_write
    procedure :: read => eq_method_read
    procedure :: summary => eq_summary
    procedure :: make_ops => eq_make_ops
  end type hyper_eq_t

  !> Empirical quadrature.
  type, extends(reduced_ops_t) :: ops_eq_t
    integer, allocatable :: idx1(:), idx2(:), idx3(:)
    real(wp), allocatable :: w1(:), w2(:), w3(:)
    !> each point's contact row / agent evaluated once per step: distinct rows of the s2 and
    !> s3 points and their positions, distinct agents of the s1 points and their positions
    integer, allocatable :: urows(:), pos2(:), pos3(:), uagents(:), pos1(:)
    real(wp), allocatable :: ugap(:), ug(:,:), udes(:,:)
    !> work vector [n_dof]
    real(wp), allocatable :: xs(:)
    !> reduced images of the unit directions of each s2 point's contact row: x and y parts of
    !> (V^T rows of agent b) - (V^T rows of agent a) [nb, 2, m2] (b = 0: minus agent a's)
    real(wp), allocatable :: dvt(:,:,:)
    !> columns of bt written at this step [R]
    logical, allocatable :: written(:)
    !> 'eq_deim': vhat = a1m s1 with s1 the desired velocity at the dofs idx1 (both dofs of
    !> each agent of the m_v DEIM dofs) and a1m = V^T U (U_P)^+ [nb, size(idx1)]
    logical :: deim_v = .false.
    real(wp), allocatable :: a1m(:,:), s1v(:)
  contains
    procedure :: assemble => eq_assemble
  end type ops_eq_t

contains

  function eq_storage() result(g)
    character(len=:), allocatable :: g
    g = "eq"
  end function eq_storage

  !> EQ of the three projected terms (s2: candidates are the support rows) and DEIM of s1,
  !> at most m_factor times (2 nb, R, 2 R) points; EQ tolerance eq_tol.
  subroutine eq_method_build(this, env, train, error)
    class(hyper_eq_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(hyper_train_t), intent(in) :: train
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: kmat(:,:), h(:,:)
    integer :: k, nb, m_max
    nb = size(train%v, 2)
    do k = 1, 3
      this%eq(k)%p = train%terms%p(merge(1, 3, k == 1))
      if (train%terms%p(k) == 0) cycle
      call train%terms%kernel(k, train%v, kmat)
      select case (k)
      case (1)
        call eq_gramian(env, train%s1, kmat, h, error)
      case (2)
        call row_gramian(h, error)
      case (3)
        call eq_gramian(env, train%s3, kmat, h, error)
      end select
      if (allocated(error)) then
        call prefix_error(error, "EQ Gramian of " // TERM_NAMES(k)); return
      end if
      m_max = max_points(train, k, size(h, 1))
      call eq_build(h, k /= 2, m_max, train%eq_tol, this%eq(k), error)
      if (allocated(error)) then
        call prefix_error(error, "EQ of " // TERM_NAMES(k)); return
      end if
    end do
    ! the DEIM of the desired velocity ('eq_deim')
    if (train%terms%p(1) > 0) then
      m_max = max_points(train, 1, train%terms%p(1))
      call s1_eim(env, train, m_max, this%vdeim, error)
      if (allocated(error)) then
        call prefix_error(error, "DEIM of the desired velocity"); return
      end if
    end if

  contains

    !> H2 = (sum over all ranks' configurations of Y Y^T) o (W W^T), Y = row images [p3, Nb].
    subroutine row_gramian(h, error)
      real(wp), allocatable, intent(out) :: h(:,:)
      type(error_t), allocatable, intent(out) :: error
      real(wp), allocatable :: y(:,:), yy(:)
      integer :: p3, c
      p3 = train%terms%p(3)
      allocate(y(p3, nb), yy(p3 * p3))
      yy = 0
      h = reshape(yy, [p3, p3])
      do c = 1, size(train%q, 2)
        call train%terms%row_images(train%scenes(train%scene_of(c)), train%q(:, c), train%radius, train%dt, &
          train%v, y)
        h = h + matmul(y, transpose(y))
      end do
      yy = reshape(h, [p3 * p3])
      call env%allreduce(yy, 'sum', error)
      if (allocated(error)) return
      h = reshape(yy, [p3, p3]) * kmat
      if (any(.not. abs(h) <= huge(1.0_wp))) call set_error(error, "the row Gramian is not finite")
    end subroutine row_gramian
  end subroutine eq_method_build

  subroutine eq_method_write(this, h5, g, error)
    class(hyper_eq_t), intent(in) :: this
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: g
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: t
    integer :: k
    call h5%make_group(g // "/eq", error); if (allocated(error)) return
    do k = 1, 3
      t = g // "/eq/" // TERM_NAMES(k)
      associate (e => this%eq(k))
        call write_term_attrs(h5, t, e%p, e%m, e%note, error); if (allocated(error)) return
        if (e%m > 0) then
          call h5%write(t // "/indices", e%idx(1:e%m), error); if (allocated(error)) return
          call h5%write(t // "/weights", e%w, error); if (allocated(error)) return
          call h5%write(t // "/err", e%err(1:e%m), error); if (allocated(error)) return
        end if
      end associate
    end do
    if (this%vdeim%p > 0) call write_eim_group(h5, g // "/eq/v_deim", this%vdeim, error)
  end subroutine eq_method_write

  subroutine eq_method_read(this, h5, path, g, terms, error)
    class(hyper_eq_t), intent(inout) :: this
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path, g
    type(hyper_terms_t), intent(in) :: terms
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: t
    integer :: j
    do j = 1, 3
      t = g // "/eq/" // TERM_NAMES(j)
      associate (e => this%eq(j))
        call read_term_attrs(h5, path, t, terms%p(merge(1, 3, j == 1)), e%p, e%m, e%note, error)
        if (allocated(error)) return
        if (e%m > 0) then
          call h5%read(t // "/indices", e%idx, error); if (allocated(error)) return
          call h5%read(t // "/weights", e%w, error); if (allocated(error)) return
          call h5%read(t // "/err", e%err, error); if (allocated(error)) return
          call need_size(path, t // "/indices", size(e%idx), e%m, "attribute m", error); if (allocated(error)) return
          call need_range(path, t // "/indices", e%idx, 1, e%p, error); if (allocated(error)) return
          if (size(e%w, 1) /= e%m .or. size(e%w, 2) /= e%m) then
            call product_error(path, "dataset '" // t // "/weights' has " // str(size(e%w, 1)) // " x " // &
              str(size(e%w, 2)) // " entries, but m says " // str(e%m) // " x " // str(e%m), error); return
          end if
          call need_finite(path, t // "/weights", e%w, error); if (allocated(error)) return
        end if
      end associate
    end do
    if (h5%exists(g // "/eq/v_deim")) then
      call read_eim_group(h5, path, g // "/eq/v_deim", terms%p(1), this%vdeim, error)
    end if
  end subroutine eq_method_read

  function eq_summary(this) result(line)
    class(hyper_eq_t), intent(in) :: this
    character(len=:), allocatable :: line
    integer :: k
    line = "EQ m ="
    do k = 1, 3
      line = line // " " // str(this%eq(k)%m)
      if (this%eq(k)%m > 0) line = line // " (err " // str(this%eq(k)%err(this%eq(k)%m)) // ")"
    end do
    line = line // ", DEIM of v m = " // str(this%vdeim%m)
    if (this%vdeim%m > 0) line = line // " (err " // str(this%vdeim%err(this%vdeim%m)) // ")"
  end function eq_summary

  !> 'eq', or 'eq_deim' (m_v = DEIM points of the desired velocity; default EQ_DEIM_M_V_DEFAULT
  !> times nb, capped by what is stored).
  subroutine eq_make_ops(this, name, v, terms, n, r, m_req, where, ops, error)
    class(hyper_eq_t), intent(in) :: this
    character(len=*), intent(in) :: name, where
    real(wp), intent(in) :: v(:,:)
    type(hyper_terms_t), intent(in) :: terms
    integer, intent(in) :: n, r, m_req(3)
    class(reduced_ops_t), allocatable, intent(out) :: ops
    type(error_t), allocatable, intent(out) :: error
    integer :: m(3), k, nb, n_agents
    logical :: deim_v
    logical, allocatable :: need(:)
    integer, allocatable :: agents(:), pos(:)
    real(wp), allocatable :: pinv(:,:)
    nb = size(v, 2)
    n_agents = size(v, 1) / 2
    deim_v = name == 'eq_deim'
    if (deim_v) then
      if (this%vdeim%p == 0) then
        call set_error(error, where // ": hyper = 'eq_deim' needs the DEIM of the desired velocity (group " // &
          "'eq/v_deim'), which this ROM file does not store for (N, R) = (" // str(n) // ", " // str(r) // &
          "); rerun crowd_offline", EXIT_BAD_INPUT); return
      end if
      call choose_points('EQ', where, n, r, m_req, [nb, r, 2 * r], [this%vdeim%m, this%eq(2)%m, this%eq(3)%m], &
        [terms%p(1), terms%p(3), terms%p(3)], m, error)
    else
      call choose_points('EQ', where, n, r, m_req, default_points(nb, r), [(this%eq(k)%m, k = 1, 3)], &
        [terms%p(1), terms%p(3), terms%p(3)], m, error)
    end if
    if (allocated(error)) return
    allocate(ops_eq_t :: ops)
    select type (ops)
    type is (ops_eq_t)
      call ops%init_base(v, terms%w, terms%ia, terms%ib, terms%ob, m)
      ops%deim_v = deim_v
      if (deim_v) then
        ! the agents of the first m_v DEIM dofs, both components of each (an agent's desired
        ! velocity is one evaluation): least squares on these 2 |A| >= m_v rows
        call unique_map((first(this%vdeim%idx, m(1)) + 1) / 2, agents, pos)
        ops%idx1 = [(2 * agents(k) - 1, 2 * agents(k), k = 1, size(agents))]
        allocate(ops%w1(0), ops%s1v(size(ops%idx1)))
        if (m(1) > 0) then
          call pinv_rows(this%vdeim%basis(ops%idx1, 1:m(1)), pinv, error)
          if (allocated(error)) then
            call prefix_error(error, where // ": DEIM of the desired velocity"); return
          end if
          ops%a1m = matmul(matmul(ops%vt, this%vdeim%basis(:, 1:m(1))), pinv)
        else
          allocate(ops%a1m(nb, 0))
        end if
      else
        ops%idx1 = first(this%eq(1)%idx, m(1)); ops%w1 = weights(1, m(1))
      end if
      ops%idx2 = first(this%eq(2)%idx, m(2)); ops%w2 = weights(2, m(2))
      ops%idx3 = first(this%eq(3)%idx, m(3)); ops%w3 = weights(3, m(3))
      allocate(need(n_agents))
      need = .false.
      call mark_agents(need, ops%idx1, ops%idx2, ops%idx3, ops%ia, ops%ib)
      ops%agents = pack([(k, k = 1, n_agents)], need)
      call gram_setup(ops, v, terms%w)
      call unique_map([ops%idx2, ops%idx3], ops%urows, ops%pos2, ops%pos3, size(ops%idx2))
      call unique_map((ops%idx1 + 1) / 2, ops%uagents, ops%pos1)
      allocate(ops%ugap(size(ops%urows)), ops%ug(2, size(ops%urows)), ops%udes(2, size(ops%uagents)))
      allocate(ops%xs(size(v, 1)), ops%dvt(nb, 2, m(2)), ops%written(r))
      ops%dvt = 0
      do k = 1, m(2)
        associate (l => ops%idx2(k))
          call add_row(ops%dvt(:, 1, k), ops%vt, 1.0_wp, ops%ia(l), ops%ib(l), [1.0_wp, 0.0_wp])
          call add_row(ops%dvt(:, 2, k), ops%vt, 1.0_wp, ops%ia(l), ops%ib(l), [0.0_wp, 1.0_wp])
        end associate
      end do
    end select

  contains

    !> The first mj selected points; empty when mj = 0 (idx is then not read: a term with no
    !> point, e.g. R = 0, has no indices in the ROM file and idx stays unallocated)
    function first(idx, mj) result(sel)
      integer, allocatable, intent(in) :: idx(:)
      integer, intent(in) :: mj
      integer, allocatable :: sel(:)
      if (mj == 0) then
        allocate(sel(0))
      else
        sel = idx(1:mj)
      end if
    end function first

    function weights(j, mj) result(w)
      integer, intent(in) :: j, mj
      real(wp), allocatable :: w(:)
      if (mj == 0) then
        allocate(w(0))
      else
        w = this%eq(j)%w(1:mj, mj)
      end if
    end function weights
  end subroutine eq_make_ops

  !> Pseudo-inverse of u [k, m] with k >= m by its SVD: pinv [m, k]; refuses (code 2) a u whose
  !> condition number exceeds 1e12 (the interpolation would amplify rounding beyond use).
  subroutine pinv_rows(u, pinv, error)
    real(wp), intent(in) :: u(:,:)
    real(wp), allocatable, intent(out) :: pinv(:,:)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: a(:,:), s(:), uu(:,:), vt(:,:)
    integer :: j, m
    m = size(u, 2)
    a = u
    allocate(s(m), uu(size(u, 1), m), vt(m, m))
    call la_gesvd(a, s, error, uu, vt)
    if (allocated(error)) return
    if (.not. s(m) > 1.0e-12_wp * s(1)) then
      call set_error(error, "the interpolation rows are singular (condition number " // str(s(1) / s(m)) // ")", EXIT_BAD_INPUT)
      return
    end if
    do j = 1, m
      uu(:, j) = uu(:, j) / s(j)
    end do
    pinv = matmul(transpose(vt), transpose(uu))
  end subroutine pinv_rows

  subroutine eq_assemble(this, ctx, q, vhat, bt, dhat)
    class(ops_eq_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    real(wp) :: g(2), c
    integer :: j, i, l, k, a, b, p, u
    call ensure(bt, dhat, this%nb, this%r)
    dhat = 0
    ! each column of bt is written by its first point and accumulated by the next ones (a gIS
    ! cone has one point per column): no clearing pass over bt
    this%written = .false.
    if (this%has_gram) this%zn = 0
    ! each agent and contact row once
    do u = 1, size(this%uagents)
      this%udes(:, u) = agent_desired(ctx, q, this%uagents(u))
    end do
    do u = 1, size(this%urows)
      l = this%urows(u)
      call eval_contact(ctx%scene, q, ctx%radius, this%ia(l), this%ib(l), this%ob(l), this%ugap(u), this%ug(:, u))
    end do
    ! vhat: 'eq_deim' interpolates v from its DEIM dofs, vhat = V^T U (U_I)^{-1} v_I; 'eq' takes
    ! V^T x with x the weighted desired velocity at the points: one product with V^T when the
    ! points cover a good part of the dofs, else one column per point
    if (this%deim_v) then
      do j = 1, size(this%idx1)
        i = this%idx1(j)
        this%s1v(j) = this%udes(2 - mod(i, 2), this%pos1(j))
      end do
      call la_gemv('N', 1.0_wp, this%a1m, this%s1v, 0.0_wp, vhat)
    else if (8 * this%m(1) >= size(this%vt, 2)) then
      this%xs = 0
      do j = 1, this%m(1)
        i = this%idx1(j)
        this%xs(i) = this%xs(i) + this%w1(j) * this%udes(2 - mod(i, 2), this%pos1(j))
      end do
      call la_gemv('N', 1.0_wp, this%vt, this%xs, 0.0_wp, vhat)
    else
      vhat = 0
      do j = 1, this%m(1)
        i = this%idx1(j)
        vhat = vhat + (this%w1(j) * this%udes(2 - mod(i, 2), this%pos1(j))) * this%vt(:, i)
      end do
    end if
    do j = 1, this%m(2)
      l = this%idx2(j); a = this%ia(l); b = this%ib(l)
      g = this%ug(:, this%pos2(j))
      do p = this%wp0(l) + 1, this%wp0(l + 1)
        k = this%wk(p)
        c = this%w2(j) * this%wv(p)
        call add_pair(bt(:, k), (c * ctx%h) * g(1), this%dvt(:, 1, j), (c * ctx%h) * g(2), this%dvt(:, 2, j), &
          this%written(k))
        this%written(k) = .true.
        if (this%has_gram) call this%z_add(k, c, a, b, g, ctx%h)
      end do
    end do
    do k = 1, this%r
      if (.not. this%written(k)) bt(:, k) = 0
    end do
    do j = 1, this%m(3)
      l = this%idx3(j)
      do p = this%wp0(l) + 1, this%wp0(l + 1)
        dhat(this%wk(p)) = dhat(this%wk(p)) + (this%w3(j) * this%ugap(this%pos3(j))) * this%wv(p)
      end do
    end do
  end subroutine eq_assemble
end module cr_hyper_eq
