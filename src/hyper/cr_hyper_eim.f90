!> Hyper-reduction 'eim': empirical interpolation of the entries of each term (POD + DEIM of
!> the candidate snapshots, cr_eim). Stored per pair in group `eim` with one subgroup per term
!> (`eim/s1`, `eim/s2`, `eim/s3`: attributes p, m [, note]; datasets basis [p, m], indices [m],
!> err [m], sigma). Online, s1 and s3 are interpolated from their m_k entries; the contact
!> normals of every support row are reconstructed from the s2 modes and renormalised to unit
!> length (a row whose interpolated normal is shorter than 1/2 has lost its direction and is
!> evaluated exactly), then the rows are assembled as in the exact variant: O(p2 (m_b + Nb))
!> per step (docs/model.md#eim-rows-with-unit-normals says why the raw interpolated rows
!> diverge).
module cr_hyper_eim
  use cr_kinds, only: wp
  use cr_error, only: error_t, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_h5file, only: h5file_t
  use cr_eim, only: eim_t, eim_build, eim_interp_matrix
  use cr_hyper_terms, only: hyper_terms_t
  use cr_hyper_method, only: hyper_method_t, hyper_train_t, choose_points, default_points, max_points, &
    s1_eim, write_term_attrs, read_term_attrs, TERM_NAMES
  use cr_reduced_base, only: reduced_ops_t, eval_ctx_t, ensure, agent_desired, mark_agents
  use cr_contact_eval, only: eval_contact
  use cr_product_check, only: need_finite, need_range, need_size, product_error
  implicit none
  private
  public :: hyper_eim_t, ops_eim_t, write_eim_group, read_eim_group

  !> The stored EIM of s1, s2, s3.
  type, extends(hyper_method_t) :: hyper_eim_t
    type(eim_t) :: eim(3)
  contains
    procedure, nopass :: storage => eim_storage
    procedure :: build_data => eim_method_build
    procedure :: write => eim_method_write
    procedure :: read => eim_method_read
    procedure :: summary => eim_summary
    procedure :: make_ops => eim_make_ops
  end type hyper_eim_t

  !> Empirical interpolation.
  type, extends(reduced_ops_t) :: ops_eim_t
    integer, allocatable :: idx1(:), idx2(:), idx3(:)
    real(wp), allocatable :: minv1(:,:), minv2(:,:), minv3(:,:)
    !> reduced images of the modes: a1 [nb, m1], a3 [R, m3]; s2 modes u2 [p2, m2]
    real(wp), allocatable :: a1(:,:), a3(:,:), u2(:,:)
    integer, allocatable :: s2_row(:), s2_dof(:)
    real(wp), allocatable :: s2_sgn(:)
    !> s2 entries of each support row (CSR: row l has r2e(r2p(l)+1 : r2p(l+1)))
    integer, allocatable :: r2p(:), r2e(:)
    !> rows evaluated exactly because their interpolated normal was shorter than 1/2
    integer :: n_exact_rows = 0
  contains
    procedure :: assemble => eim_assemble
  end type ops_eim_t

contains

  function eim_storage() result(g)
    character(len=:), allocatable :: g
    g = "eim"
  end function eim_storage

  !> EIM of the entries of the three terms, at most m_factor times (2 nb, R, 2 R) modes.
  subroutine eim_method_build(this, env, train, error)
    class(hyper_eim_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(hyper_train_t), intent(in) :: train
    type(error_t), allocatable, intent(out) :: error
    integer :: k, m_max
    do k = 1, 3
      this%eim(k)%p = train%terms%p(k)
      if (train%terms%p(k) == 0) cycle
      m_max = max_points(train, k, train%terms%p(k))
      select case (k)
      case (1)
        call s1_eim(env, train, m_max, this%eim(k), error)
      case (2)
        call eim_build(env, train%s2, m_max, this%eim(k), error)
      case (3)
        call eim_build(env, train%s3, m_max, this%eim(k), error)
      end select
      if (allocated(error)) then
        call prefix_error(error, "EIM of " // TERM_NAMES(k)); return
      end if
    end do
  end subroutine eim_method_build

  subroutine eim_method_write(this, h5, g, error)
    class(hyper_eim_t), intent(in) :: this
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: g
    type(error_t), allocatable, intent(out) :: error
    integer :: k
    call h5%make_group(g // "/eim", error); if (allocated(error)) return
    do k = 1, 3
      call write_eim_group(h5, g // "/eim/" // TERM_NAMES(k), this%eim(k), error); if (allocated(error)) return
    end do
  end subroutine eim_method_write

  subroutine eim_method_read(this, h5, path, g, terms, error)
    class(hyper_eim_t), intent(inout) :: this
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path, g
    type(hyper_terms_t), intent(in) :: terms
    type(error_t), allocatable, intent(out) :: error
    integer :: k
    do k = 1, 3
      call read_eim_group(h5, path, g // "/eim/" // TERM_NAMES(k), terms%p(k), this%eim(k), error)
      if (allocated(error)) return
    end do
  end subroutine eim_method_read

  function eim_summary(this) result(line)
    class(hyper_eim_t), intent(in) :: this
    character(len=:), allocatable :: line
    integer :: k
    line = "EIM m ="
    do k = 1, 3
      line = line // " " // str(this%eim(k)%m)
    end do
  end function eim_summary

  !> Write one EIM (attributes p, m [, note]; basis, indices, err when m > 0; sigma) as group t.
  subroutine write_eim_group(h5, t, e, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: t
    type(eim_t), intent(in) :: e
    type(error_t), allocatable, intent(out) :: error
    call write_term_attrs(h5, t, e%p, e%m, e%note, error); if (allocated(error)) return
    if (e%m > 0) then
      call h5%write(t // "/basis", e%basis(:, 1:e%m), error); if (allocated(error)) return
      call h5%write(t // "/indices", e%idx(1:e%m), error); if (allocated(error)) return
      call h5%write(t // "/err", e%err(1:e%m), error); if (allocated(error)) return
    end if
    if (allocated(e%sigma)) then
      call h5%write(t // "/sigma", e%sigma, error); if (allocated(error)) return
    end if
  end subroutine write_eim_group

  !> Read and validate group t written by write_eim_group; p = the term's candidates.
  subroutine read_eim_group(h5, path, t, p, e, error)
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path, t
    integer, intent(in) :: p
    type(eim_t), intent(out) :: e
    type(error_t), allocatable, intent(out) :: error
    call read_term_attrs(h5, path, t, p, e%p, e%m, e%note, error); if (allocated(error)) return
    if (e%m > 0) then
      call h5%read(t // "/basis", e%basis, error); if (allocated(error)) return
      call h5%read(t // "/indices", e%idx, error); if (allocated(error)) return
      call h5%read(t // "/err", e%err, error); if (allocated(error)) return
      if (size(e%basis, 1) /= e%p .or. size(e%basis, 2) /= e%m) then
        call product_error(path, "dataset '" // t // "/basis' has " // str(size(e%basis, 1)) // " x " // &
          str(size(e%basis, 2)) // " entries, but p and m say " // str(e%p) // " x " // str(e%m), error); return
      end if
      call need_size(path, t // "/indices", size(e%idx), e%m, "attribute m", error); if (allocated(error)) return
      call need_range(path, t // "/indices", e%idx, 1, e%p, error); if (allocated(error)) return
      call need_finite(path, t // "/basis", e%basis, error); if (allocated(error)) return
    end if
    if (h5%exists(t // "/sigma")) then
      call h5%read(t // "/sigma", e%sigma, error); if (allocated(error)) return
    end if
  end subroutine read_eim_group

  subroutine eim_make_ops(this, name, v, terms, n, r, m_req, where, ops, error)
    class(hyper_eim_t), intent(in) :: this
    character(len=*), intent(in) :: name, where
    real(wp), intent(in) :: v(:,:)
    type(hyper_terms_t), intent(in) :: terms
    integer, intent(in) :: n, r, m_req(3)
    class(reduced_ops_t), allocatable, intent(out) :: ops
    type(error_t), allocatable, intent(out) :: error
    integer :: m(3), k, nb
    logical, allocatable :: need(:)
    nb = size(v, 2)
    call choose_points('EIM', where, n, r, m_req, default_points(nb, r), [(this%eim(k)%m, k = 1, 3)], &
      [(terms%p(k), k = 1, 3)], m, error)
    if (allocated(error)) return
    allocate(ops_eim_t :: ops)
    select type (ops)
    type is (ops_eim_t)
      call ops%init_base(v, terms%w, terms%ia, terms%ib, terms%ob, m)
      ops%s2_row = terms%s2_row; ops%s2_dof = terms%s2_dof; ops%s2_sgn = terms%s2_sgn
      call eim_setup(ops, this%eim, v, terms, m, error)
      if (allocated(error)) return
      ! every support row's agents: a row whose interpolated normal lost its direction is
      ! evaluated exactly
      allocate(need(size(v, 1) / 2))
      need = .false.
      call mark_agents(need, ops%idx1, [(k, k = 1, size(ops%ia))], ops%idx3, ops%ia, ops%ib)
      ops%agents = pack([(k, k = 1, size(need))], need)
    end select
  end subroutine eim_make_ops

  !> EIM: indices, interpolation inverses and reduced images of the modes.
  subroutine eim_setup(ops, eim, v, terms, m, error)
    type(ops_eim_t), intent(inout) :: ops
    type(eim_t), intent(in) :: eim(3)
    real(wp), intent(in) :: v(:,:)
    type(hyper_terms_t), intent(in) :: terms
    integer, intent(in) :: m(3)
    type(error_t), allocatable, intent(out) :: error
    type(eim_t) :: e
    integer :: j, i
    do j = 1, 3
      e%p = eim(j)%p
      e%m = m(j)
      if (m(j) > 0) then
        e%basis = eim(j)%basis(:, 1:m(j))
        e%idx = eim(j)%idx(1:m(j))
      else
        allocate(e%basis(e%p, 0), e%idx(0))
      end if
      select case (j)
      case (1)
        ops%idx1 = e%idx
        if (m(j) > 0) then
          call eim_interp_matrix(e, m(j), ops%minv1, error); if (allocated(error)) return
        end if
        ops%a1 = matmul(transpose(v), e%basis)
      case (2)
        ops%idx2 = e%idx
        if (m(j) > 0) then
          call eim_interp_matrix(e, m(j), ops%minv2, error); if (allocated(error)) return
        end if
        ops%u2 = e%basis
        ! entries of each support row
        allocate(ops%r2p(size(terms%ia) + 1), ops%r2e(e%p))
        ops%r2p = 0
        do i = 1, e%p
          ops%r2p(terms%s2_row(i) + 1) = ops%r2p(terms%s2_row(i) + 1) + 1
        end do
        do i = 1, size(terms%ia)
          ops%r2p(i + 1) = ops%r2p(i + 1) + ops%r2p(i)
        end do
        block
          integer, allocatable :: fill(:)
          fill = ops%r2p(1:size(terms%ia))
          do i = 1, e%p
            fill(terms%s2_row(i)) = fill(terms%s2_row(i)) + 1
            ops%r2e(fill(terms%s2_row(i))) = i
          end do
        end block
      case (3)
        ops%idx3 = e%idx
        if (m(j) > 0) then
          call eim_interp_matrix(e, m(j), ops%minv3, error); if (allocated(error)) return
        end if
        ops%a3 = matmul(transpose(terms%w), e%basis)
      end select
      deallocate(e%basis, e%idx)
    end do
  end subroutine eim_setup

  subroutine eim_assemble(this, ctx, q, vhat, bt, dhat)
    class(ops_eim_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    real(wp) :: s(max(this%m(1), this%m(2), this%m(3), 1)), va(2), gap, g(2), c(max(this%m(2), 1))
    real(wp) :: st(size(this%s2_row)), gs(2), cnt(2), nrm
    integer :: j, i, l, p, e, comp
    call ensure(bt, dhat, this%nb, this%r)
    ! s1 at the interpolation dofs
    do j = 1, this%m(1)
      i = this%idx1(j)
      va = agent_desired(ctx, q, (i + 1) / 2)
      s(j) = va(2 - mod(i, 2))
    end do
    if (this%m(1) > 0) then
      vhat = matmul(this%a1, matmul(this%minv1, s(1:this%m(1))))
    else
      vhat = 0
    end if
    ! s2 at the interpolation entries
    do j = 1, this%m(2)
      i = this%idx2(j); l = this%s2_row(i)
      call eval_contact(ctx%scene, q, ctx%radius, this%ia(l), this%ib(l), this%ob(l), gap, g)
      s(j) = this%s2_sgn(i) * ctx%h * g(2 - mod(this%s2_dof(i), 2))
    end do
    bt = 0
    if (this%m(2) > 0) then
      c(1:this%m(2)) = matmul(this%minv2, s(1:this%m(2)))
      st = matmul(this%u2(:, 1:this%m(2)), c(1:this%m(2)))
      ! each support row: interpolated normal (mean over its slots of entry / (sign h)),
      ! renormalised; exact when shorter than 1/2 (its error is then > 1/2 anyway)
      do l = 1, size(this%ia)
        gs = 0; cnt = 0
        do p = this%r2p(l) + 1, this%r2p(l + 1)
          e = this%r2e(p)
          comp = 2 - mod(this%s2_dof(e), 2)
          gs(comp) = gs(comp) + st(e) / (this%s2_sgn(e) * ctx%h)
          cnt(comp) = cnt(comp) + 1
        end do
        gs = gs / max(cnt, 1.0_wp)
        nrm = norm2(gs)
        if (nrm >= 0.5_wp) then
          g = gs / nrm
        else
          call eval_contact(ctx%scene, q, ctx%radius, this%ia(l), this%ib(l), this%ob(l), gap, g)
          this%n_exact_rows = this%n_exact_rows + 1
        end if
        call this%add_support_row(l, g, ctx%h, bt)
      end do
    else
      bt = 0
    end if
    ! s3 at the interpolation rows
    do j = 1, this%m(3)
      l = this%idx3(j)
      call eval_contact(ctx%scene, q, ctx%radius, this%ia(l), this%ib(l), this%ob(l), gap, g)
      s(j) = gap
    end do
    if (this%m(3) > 0) then
      dhat = matmul(this%a3, matmul(this%minv3, s(1:this%m(3))))
    else
      dhat = 0
    end if
  end subroutine eim_assemble
end module cr_hyper_eim
