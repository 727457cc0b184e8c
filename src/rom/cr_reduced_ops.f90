!> Assembly of the reduced problem of one time step, the paper's
!>   min |alpha - vhat|^2  s.t.  bhat alpha <= dhat,
!> vhat = V^T v(q), bhat = W^T B(q) V, dhat = W^T d(q), by one of the variants
!>   'none'   exact projection: every agent's desired velocity, every row of the cone's support;
!>   'eim'    empirical interpolation: the m_k interpolation entries of each term; the contact
!>            normals of every support row are reconstructed from the s2 modes and
!>            renormalised to unit length (a row whose interpolated normal is shorter than
!>            1/2 has lost its direction and is evaluated exactly), then the rows are
!>            assembled as in the exact variant: O(p2 (m_b + Nb)) per step (README
!>            "Diverged reduced trajectories" says why the raw interpolated rows diverge);
!>   'eq'     empirical quadrature: weighted sums over the m_k quadrature entries;
!>   'online' (contacts = 'online') the rows of B V of the contacts near in the reduced
!>            positions at this step (cell-list search, as the full-order model), each
!>            enforced on its own; vhat exact.
!> Each variant lists the agents whose positions it reads (`agents`); the stepper rebuilds
!> only those positions from the reduced coefficients.
module cr_reduced_ops
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_desired, only: desired_t
  use cr_contact_eval, only: eval_contact
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  use cr_rom_file, only: rom_pair_t
  use cr_hyper_terms, only: contact_row_image
  use cr_lapack, only: la_gemv
  use cr_eim, only: eim_t, eim_interp_matrix
  use cr_dual_qp, only: gram_source_t
  use cr_kinds, only: i8
  implicit none
  private
  public :: eval_ctx_t, reduced_ops_t, make_reduced_ops, HYPER_NAMES, eim_exact_rows

  character(len=8), parameter :: HYPER_NAMES(3) = [character(len=8) :: 'none', 'eim', 'eq']

  !> What the terms depend on besides the positions: the sample's scene, desired-velocity
  !> model and speeds, the agent radius and the time step.
  type :: eval_ctx_t
    type(scene_t) :: scene
    type(desired_t) :: desired
    real(wp), allocatable :: speeds(:)
    real(wp) :: radius = 0, h = 0
  end type eval_ctx_t

  !> A way of assembling (vhat, bhat, dhat); also the source of the Gram entries of the
  !> assembled rows for the dual active-set solver (when has_gram).
  type, abstract, extends(gram_source_t) :: reduced_ops_t
    integer :: nb = 0, r = 0
    !> agents whose positions `assemble` reads
    integer, allocatable :: agents(:)
    !> number of interpolation / quadrature entries of s1, s2, s3 (0 for exact)
    integer :: m(3) = 0
    !> velocity basis [n_dof, nb] and its transpose [nb, n_dof] (contiguous rows of V)
    real(wp), allocatable :: v(:,:), vt(:,:)
    !> .true. when the rows are the R cone vectors (multipliers comparable across steps)
    logical :: fixed_rows = .true.
    !> identity of each assembled row when the rows change from step to step ('online':
    !> the contact key, agent pair or agent-obstacle pair) [rows]
    integer(i8), allocatable :: keys(:)
    !> the cone by support rows (CSR): row l has cone entries wk(wp0(l)+1 : wp0(l+1)) with
    !> values wv (one entry per row for gIS cones)
    integer, allocatable :: wp0(:), wk(:)
    real(wp), allocatable :: wv(:)
    !> Gram matrix of the reduced rows without touching the basis: row k of bhat is z_k V with
    !> a sparse z_k (at most zmax entries, recorded by `assemble`), so bhat bhat^T =
    !> Z (V V^T) Z^T costs zmax^2 flops per entry instead of Nb (has_gram: cone variants with
    !> zmax <= 16, Nb >= 4 zmax^2 and n_dof <= 4000; online contacts (zmax = 4) when
    !> Nb >= 16 and n_dof <= 4000)
    logical :: has_gram = .false.
    integer :: zmax = 0
    real(wp), allocatable :: pmat(:,:), zval(:,:)
    integer, allocatable :: zn(:), zdof(:,:)
  contains
    procedure(assemble_i), deferred :: assemble
    procedure :: gram => ops_gram
    procedure :: gram_entries => ops_gram_entries
    procedure :: gram_diag => ops_gram_diag
    procedure, private :: z_add
  end type reduced_ops_t

  abstract interface
    !> Reduced terms at positions q [n_dof] (valid at least for this%agents):
    !> vhat [nb], bt = bhat^T [nb, rows] (the rows as contiguous columns), dhat [rows]
    !> (rows = R, or the near contacts for 'online').
    subroutine assemble_i(this, ctx, q, vhat, bt, dhat)
      import :: reduced_ops_t, eval_ctx_t, wp
      class(reduced_ops_t), intent(inout) :: this
      type(eval_ctx_t), intent(in) :: ctx
      real(wp), intent(in) :: q(:)
      real(wp), intent(out) :: vhat(:)
      real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    end subroutine assemble_i
  end interface

  !> Exact projection over the cone's support rows.
  type, extends(reduced_ops_t) :: ops_exact_t
    integer, allocatable :: ia(:), ib(:), ob(:)
    !> cone on the support rows [p3, R]
    real(wp), allocatable :: w(:,:)
    real(wp), allocatable :: vfull(:)
  contains
    procedure :: assemble => exact_assemble
  end type ops_exact_t

  !> Near contacts of the reduced positions, each row enforced.
  type, extends(reduced_ops_t) :: ops_online_t
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    real(wp) :: cutoff_factor = 1.5_wp
    real(wp), allocatable :: vfull(:)
  contains
    procedure :: assemble => online_assemble
  end type ops_online_t

  !> Empirical interpolation.
  type, extends(reduced_ops_t) :: ops_eim_t
    integer, allocatable :: idx1(:), idx2(:), idx3(:)
    real(wp), allocatable :: minv1(:,:), minv2(:,:), minv3(:,:)
    !> reduced images of the modes: a1 [nb, m1], a3 [R, m3]; s2 modes u2 [p2, m2]
    real(wp), allocatable :: a1(:,:), a3(:,:), u2(:,:)
    integer, allocatable :: ia(:), ib(:), ob(:), s2_row(:), s2_dof(:)
    real(wp), allocatable :: s2_sgn(:)
    !> s2 entries of each support row (CSR: row l has r2e(r2p(l)+1 : r2p(l+1)))
    integer, allocatable :: r2p(:), r2e(:)
    !> rows evaluated exactly because their interpolated normal was shorter than 1/2
    integer :: n_exact_rows = 0
  contains
    procedure :: assemble => eim_assemble
  end type ops_eim_t

  !> Empirical quadrature.
  type, extends(reduced_ops_t) :: ops_eq_t
    integer, allocatable :: idx1(:), idx2(:), idx3(:)
    real(wp), allocatable :: w1(:), w2(:), w3(:)
    integer, allocatable :: ia(:), ib(:), ob(:)
    !> cone on the support rows [p3, R]
    real(wp), allocatable :: w(:,:)
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
  contains
    procedure :: assemble => eq_assemble
  end type ops_eq_t

contains

  !> Build the variant `hyper` ('none', 'eim', 'eq') with contacts 'cone' or 'online' for
  !> `pair`; m_req = requested (m_v, m_b, m_d), 0 = default (2 nb, R, 2 R capped by what is
  !> stored). `where` prefixes error messages.
  subroutine make_reduced_ops(hyper, contacts, pair, m_req, cutoff_factor, where, ops, error)
    character(len=*), intent(in) :: hyper, contacts
    type(rom_pair_t), intent(in) :: pair
    integer, intent(in) :: m_req(3)
    real(wp), intent(in) :: cutoff_factor
    character(len=*), intent(in) :: where
    class(reduced_ops_t), allocatable, intent(out) :: ops
    type(error_t), allocatable, intent(out) :: error
    integer :: m(3), k, n_agents
    logical, allocatable :: need(:)
    n_agents = size(pair%v, 1) / 2
    if (contacts == 'online') then
      allocate(ops_online_t :: ops)
    else
      select case (trim(hyper))
      case ('none')
        allocate(ops_exact_t :: ops)
      case ('eim')
        allocate(ops_eim_t :: ops)
      case ('eq')
        allocate(ops_eq_t :: ops)
      case default
        call set_error(error, where // ": unknown hyper-reduction '" // trim(hyper) // "' (known: none, eim, eq)", 2)
        return
      end select
    end if
    ops%nb = pair%nb
    ops%r = pair%r
    ops%v = pair%v
    ops%vt = transpose(pair%v)
    call cone_rows(pair%terms%w, ops%wp0, ops%wk, ops%wv)
    allocate(need(n_agents))
    need = .false.
    select type (ops)
    type is (ops_online_t)
      ops%cutoff_factor = cutoff_factor
      ops%fixed_rows = .false.
      allocate(ops%vfull(2 * n_agents))
      call ops%cs%init(n_agents, 1.0_wp, 8 * n_agents)
      need = .true.
      ! Gram entries of contact rows (4 dofs each) for the dual active-set solver
      ops%zmax = 4
      ops%has_gram = pair%nb >= 16 .and. 2 * n_agents <= 4000
      if (ops%has_gram) ops%pmat = matmul(pair%v, transpose(pair%v))
      allocate(ops%zn(0), ops%zdof(4, 0), ops%zval(4, 0), ops%keys(0))
    type is (ops_exact_t)
      ops%ia = pair%terms%ia; ops%ib = pair%terms%ib; ops%ob = pair%terms%ob
      ops%w = pair%terms%w
      allocate(ops%vfull(2 * n_agents))
      need = .true.
      call gram_setup(ops, pair)
    type is (ops_eim_t)
      call choose_m('EIM', [(pair%eim(k)%m, k = 1, 3)], [(pair%terms%p(k), k = 1, 3)], m, error)
      if (allocated(error)) return
      ops%m = m
      ops%ia = pair%terms%ia; ops%ib = pair%terms%ib; ops%ob = pair%terms%ob
      ops%s2_row = pair%terms%s2_row; ops%s2_dof = pair%terms%s2_dof; ops%s2_sgn = pair%terms%s2_sgn
      call eim_setup(ops, pair, m, error)
      if (allocated(error)) return
      ! every support row's agents: a row whose interpolated normal lost its direction is
      ! evaluated exactly
      call mark(ops%idx1, [(k, k = 1, size(ops%ia))], ops%idx3, ops%ia, ops%ib)
    type is (ops_eq_t)
      call choose_m('EQ', [(pair%eq(k)%m, k = 1, 3)], [pair%terms%p(1), pair%terms%p(3), pair%terms%p(3)], &
        m, error)
      if (allocated(error)) return
      ops%m = m
      ops%ia = pair%terms%ia; ops%ib = pair%terms%ib; ops%ob = pair%terms%ob
      ops%w = pair%terms%w
      ops%idx1 = pair%eq(1)%idx(1:m(1)); ops%w1 = weights(1, m(1))
      ops%idx2 = pair%eq(2)%idx(1:m(2)); ops%w2 = weights(2, m(2))
      ops%idx3 = pair%eq(3)%idx(1:m(3)); ops%w3 = weights(3, m(3))
      call mark(ops%idx1, ops%idx2, ops%idx3, ops%ia, ops%ib)
      call gram_setup(ops, pair)
      call unique_map([ops%idx2, ops%idx3], ops%urows, ops%pos2, ops%pos3, size(ops%idx2))
      call unique_map((ops%idx1 + 1) / 2, ops%uagents, ops%pos1)
      allocate(ops%ugap(size(ops%urows)), ops%ug(2, size(ops%urows)), ops%udes(2, size(ops%uagents)))
      allocate(ops%xs(size(pair%v, 1)), ops%dvt(pair%nb, 2, m(2)), ops%written(pair%r))
      ops%dvt = 0
      do k = 1, m(2)
        associate (l => ops%idx2(k))
          call add_row(ops%dvt(:, 1, k), ops%vt, 1.0_wp, ops%ia(l), ops%ib(l), [1.0_wp, 0.0_wp])
          call add_row(ops%dvt(:, 2, k), ops%vt, 1.0_wp, ops%ia(l), ops%ib(l), [0.0_wp, 1.0_wp])
        end associate
      end do
    end select
    ops%agents = pack([(k, k = 1, n_agents)], need)

  contains

    function weights(j, mj) result(w)
      integer, intent(in) :: j, mj
      real(wp), allocatable :: w(:)
      if (mj == 0) then
        allocate(w(0))
      else
        w = pair%eq(j)%w(1:mj, mj)
      end if
    end function weights

    !> m per term: requested, or the paper's default capped by what is stored.
    subroutine choose_m(what, stored, cand, m, error)
      character(len=*), intent(in) :: what
      !> points stored and candidates of each term
      integer, intent(in) :: stored(3), cand(3)
      integer, intent(out) :: m(3)
      type(error_t), allocatable, intent(out) :: error
      character(len=3), parameter :: names(3) = ['m_v', 'm_b', 'm_d']
      integer :: dflt(3), j
      if (.not. pair%hyper) then
        call set_error(error, where // ": the ROM file stores no hyper-reduction for (N, R) = (" // str(pair%n) // &
          ", " // str(pair%r) // ") (&hyper enabled = .false.); use hyper = 'none'", 2); return
      end if
      dflt = [2 * pair%nb, pair%r, 2 * pair%r]
      do j = 1, 3
        if (m_req(j) > cand(j)) then
          call set_error(error, where // ": " // names(j) // " = " // str(m_req(j)) // " is larger than the " // &
            str(cand(j)) // " " // what // " candidates of term s" // str(j) // " for (N, R) = (" // str(pair%n) // &
            ", " // str(pair%r) // ")", 2); return
        end if
        if (m_req(j) > stored(j)) then
          call set_error(error, where // ": " // names(j) // " = " // str(m_req(j)) // " but the ROM file stores " // &
            str(stored(j)) // " " // what // " points for term s" // str(j) // " of (N, R) = (" // str(pair%n) // &
            ", " // str(pair%r) // ") (raise &hyper m_factor)", 2); return
        end if
        if (m_req(j) > 0) then
          m(j) = m_req(j)
        else
          m(j) = min(dflt(j), stored(j))
        end if
      end do
    end subroutine choose_m

    !> Mark the agents read by the selected dofs i1 and support rows r2, r3.
    subroutine mark(i1, r2, r3, ia, ib)
      integer, intent(in) :: i1(:), r2(:), r3(:), ia(:), ib(:)
      integer :: j
      do j = 1, size(i1)
        need((i1(j) + 1) / 2) = .true.
      end do
      do j = 1, size(r2)
        need(ia(r2(j))) = .true.
        if (ib(r2(j)) > 0) need(ib(r2(j))) = .true.
      end do
      do j = 1, size(r3)
        need(ia(r3(j))) = .true.
        if (ib(r3(j)) > 0) need(ib(r3(j))) = .true.
      end do
    end subroutine mark
  end subroutine make_reduced_ops

  !> Distinct values u of x and the position of each x(j) in u; with n1 given, pos_a covers
  !> x(1:n1) and pos_b x(n1+1:).
  subroutine unique_map(x, u, pos_a, pos_b, n1)
    integer, intent(in) :: x(:)
    integer, allocatable, intent(out) :: u(:), pos_a(:)
    integer, allocatable, intent(out), optional :: pos_b(:)
    integer, intent(in), optional :: n1
    integer, allocatable :: where(:), pos(:)
    integer :: j, n
    allocate(u(size(x)), pos(size(x)), where(maxval([x, 1])))
    where = 0
    n = 0
    do j = 1, size(x)
      if (where(x(j)) == 0) then
        n = n + 1
        u(n) = x(j)
        where(x(j)) = n
      end if
      pos(j) = where(x(j))
    end do
    u = u(1:n)
    if (present(n1)) then
      pos_a = pos(1:n1)
      pos_b = pos(n1 + 1:)
    else
      pos_a = pos
    end if
  end subroutine unique_map

  !> Prepare the cheap Gram matrix of the rows (see reduced_ops_t) when it pays.
  subroutine gram_setup(ops, pair)
    class(reduced_ops_t), intent(inout) :: ops
    type(rom_pair_t), intent(in) :: pair
    integer :: k, n_dof
    n_dof = size(pair%v, 1)
    ops%zmax = 0
    do k = 1, pair%r
      ops%zmax = max(ops%zmax, 4 * count(pair%terms%w(:, k) /= 0))
    end do
    ! worth it when a row's dof-space support is much smaller than the basis
    ops%has_gram = pair%r > 0 .and. ops%zmax <= 16 .and. n_dof <= 4000 .and. pair%nb >= 4 * ops%zmax**2
    if (.not. ops%has_gram) return
    ops%pmat = matmul(pair%v, transpose(pair%v))
    allocate(ops%zn(pair%r), ops%zdof(ops%zmax, pair%r), ops%zval(ops%zmax, pair%r))
    ops%zn = 0
  end subroutine gram_setup

  !> Record z_k += c (the dof-space row of a contact: -h g on agent a, +h g on agent b).
  subroutine z_add(this, k, c, a, b, g, h)
    class(reduced_ops_t), intent(inout) :: this
    integer, intent(in) :: k, a, b
    real(wp), intent(in) :: c, g(2), h
    integer :: n
    n = this%zn(k)
    this%zdof(n + 1:n + 2, k) = [2*a - 1, 2*a]
    this%zval(n + 1:n + 2, k) = -c * h * g
    n = n + 2
    if (b > 0) then
      this%zdof(n + 1:n + 2, k) = [2*b - 1, 2*b]
      this%zval(n + 1:n + 2, k) = c * h * g
      n = n + 2
    end if
    this%zn(k) = n
  end subroutine z_add

  !> g = bhat bhat^T [R, R] from the rows recorded by the last `assemble`.
  subroutine ops_gram(this, g)
    class(reduced_ops_t), intent(in) :: this
    real(wp), intent(out) :: g(:,:)
    integer :: k, kk, i, j
    real(wp) :: t
    do k = 1, this%r
      do kk = k, this%r
        t = 0
        do j = 1, this%zn(kk)
          do i = 1, this%zn(k)
            t = t + this%zval(i, k) * this%zval(j, kk) * this%pmat(this%zdof(i, k), this%zdof(j, kk))
          end do
        end do
        g(k, kk) = t
        g(kk, k) = t
      end do
    end do
  end subroutine ops_gram

  !> g(j) = (row p) . (row idx(j)) of the last assembled bhat, from the recorded sparse
  !> rows: z_p P z_j^T (zmax^2 flops per entry; needs has_gram).
  subroutine ops_gram_entries(this, p, idx, g)
    class(reduced_ops_t), intent(in) :: this
    integer, intent(in) :: p, idx(:)
    real(wp), intent(out) :: g(:)
    integer :: jj
    if (this%zmax == 4) then
      do jj = 1, size(idx)
        g(jj) = zpz4(this, p, idx(jj))
      end do
    else
      do jj = 1, size(idx)
        g(jj) = zpz(this, p, idx(jj))
      end do
    end if
  end subroutine ops_gram_entries

  !> g(k) = |row k|^2 of the last assembled bhat [R or rows].
  subroutine ops_gram_diag(this, g)
    class(reduced_ops_t), intent(in) :: this
    real(wp), intent(out) :: g(:)
    integer :: k
    if (this%zmax == 4) then
      do k = 1, size(g)
        g(k) = zpz4(this, k, k)
      end do
    else
      do k = 1, size(g)
        g(k) = zpz(this, k, k)
      end do
    end if
  end subroutine ops_gram_diag

  !> z_p P z_k^T, general zmax.
  pure real(wp) function zpz(this, p, k) result(t)
    class(reduced_ops_t), intent(in) :: this
    integer, intent(in) :: p, k
    integer :: i, j
    t = 0
    do j = 1, this%zn(k)
      do i = 1, this%zn(p)
        t = t + this%zval(i, p) * this%zval(j, k) * this%pmat(this%zdof(i, p), this%zdof(j, k))
      end do
    end do
  end function zpz

  !> z_p P z_k^T for zmax = 4 (one contact: 2 or 4 entries), unrolled.
  pure real(wp) function zpz4(this, p, k) result(t)
    class(reduced_ops_t), intent(in) :: this
    integer, intent(in) :: p, k
    integer :: j, c, d1, d2, d3, d4
    real(wp) :: z1, z2, z3, z4
    t = 0
    if (this%zn(p) == 0) return
    z1 = this%zval(1, p); z2 = this%zval(2, p)
    d1 = this%zdof(1, p); d2 = this%zdof(2, p)
    if (this%zn(p) == 4) then
      z3 = this%zval(3, p); z4 = this%zval(4, p)
      d3 = this%zdof(3, p); d4 = this%zdof(4, p)
    else
      z3 = 0; z4 = 0; d3 = d1; d4 = d2
    end if
    do j = 1, this%zn(k)
      c = this%zdof(j, k)
      t = t + this%zval(j, k) * (z1 * this%pmat(d1, c) + z2 * this%pmat(d2, c) + z3 * this%pmat(d3, c) + &
        z4 * this%pmat(d4, c))
    end do
  end function zpz4

  !> CSR by rows of the cone on its support rows w [p3, R].
  subroutine cone_rows(w, ptr, k, val)
    real(wp), intent(in) :: w(:,:)
    integer, allocatable, intent(out) :: ptr(:), k(:)
    real(wp), allocatable, intent(out) :: val(:)
    integer :: l, j, n
    allocate(ptr(size(w, 1) + 1), k(count(w /= 0)), val(count(w /= 0)))
    n = 0
    ptr(1) = 0
    do l = 1, size(w, 1)
      do j = 1, size(w, 2)
        if (w(l, j) /= 0) then
          n = n + 1
          k(n) = j; val(n) = w(l, j)
        end if
      end do
      ptr(l + 1) = n
    end do
  end subroutine cone_rows

  !> EIM: indices, interpolation inverses and reduced images of the modes.
  subroutine eim_setup(ops, pair, m, error)
    type(ops_eim_t), intent(inout) :: ops
    type(rom_pair_t), intent(in) :: pair
    integer, intent(in) :: m(3)
    type(error_t), allocatable, intent(out) :: error
    type(eim_t) :: e
    integer :: j, i
    do j = 1, 3
      e%p = pair%eim(j)%p
      e%m = m(j)
      if (m(j) > 0) then
        e%basis = pair%eim(j)%basis(:, 1:m(j))
        e%idx = pair%eim(j)%idx(1:m(j))
      else
        allocate(e%basis(e%p, 0), e%idx(0))
      end if
      select case (j)
      case (1)
        ops%idx1 = e%idx
        if (m(j) > 0) then
          call eim_interp_matrix(e, m(j), ops%minv1, error); if (allocated(error)) return
        end if
        ops%a1 = matmul(transpose(pair%v), e%basis)
      case (2)
        ops%idx2 = e%idx
        if (m(j) > 0) then
          call eim_interp_matrix(e, m(j), ops%minv2, error); if (allocated(error)) return
        end if
        ops%u2 = e%basis
        ! entries of each support row
        allocate(ops%r2p(size(pair%terms%ia) + 1), ops%r2e(e%p))
        ops%r2p = 0
        do i = 1, e%p
          ops%r2p(pair%terms%s2_row(i) + 1) = ops%r2p(pair%terms%s2_row(i) + 1) + 1
        end do
        do i = 1, size(pair%terms%ia)
          ops%r2p(i + 1) = ops%r2p(i + 1) + ops%r2p(i)
        end do
        block
          integer, allocatable :: fill(:)
          fill = ops%r2p(1:size(pair%terms%ia))
          do i = 1, e%p
            fill(pair%terms%s2_row(i)) = fill(pair%terms%s2_row(i)) + 1
            ops%r2e(fill(pair%terms%s2_row(i))) = i
          end do
        end block
      case (3)
        ops%idx3 = e%idx
        if (m(j) > 0) then
          call eim_interp_matrix(e, m(j), ops%minv3, error); if (allocated(error)) return
        end if
        ops%a3 = matmul(transpose(pair%terms%w), e%basis)
      end select
      deallocate(e%basis, e%idx)
    end do
  end subroutine eim_setup

  !> Desired velocity of agent a at q.
  function agent_desired(ctx, q, a) result(va)
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    integer, intent(in) :: a
    real(wp) :: va(2), d(2)
    if (ctx%desired%from_file) then
      va = ctx%desired%fixed(2*a-1:2*a)
      return
    end if
    call ctx%desired%direction(q(2*a-1:2*a), d)
    va = ctx%speeds(a) * d
  end function agent_desired

  subroutine exact_assemble(this, ctx, q, vhat, bt, dhat)
    class(ops_exact_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    real(wp) :: gap, g(2)
    integer :: k, a, b, j, p
    call ctx%desired%evaluate(q, ctx%speeds, this%vfull)
    call la_gemv('N', 1.0_wp, this%vt, this%vfull, 0.0_wp, vhat)
    call ensure(bt, dhat, this%nb, this%r)
    bt = 0; dhat = 0
    if (this%has_gram) this%zn = 0
    do k = 1, size(this%ia)
      a = this%ia(k); b = this%ib(k)
      call eval_contact(ctx%scene, q, ctx%radius, a, b, this%ob(k), gap, g)
      do p = this%wp0(k) + 1, this%wp0(k + 1)
        j = this%wk(p)
        call add_row(bt(:, j), this%vt, this%wv(p) * ctx%h, a, b, g)
        dhat(j) = dhat(j) + this%wv(p) * gap
        if (this%has_gram) call this%z_add(j, this%wv(p), a, b, g, ctx%h)
      end do
    end do
  end subroutine exact_assemble

  !> y += c (-(g . V^T rows of agent a) + (g . V^T rows of agent b)) for vt = V^T [nb, n_dof]:
  !> the reduced image of a contact row scaled by c / h (b = 0: obstacle contact).
  pure subroutine add_row(y, vt, c, a, b, g)
    real(wp), contiguous, intent(inout) :: y(:)
    real(wp), contiguous, intent(in) :: vt(:,:)
    real(wp), intent(in) :: c, g(2)
    integer, intent(in) :: a, b
    real(wp) :: c1, c2
    integer :: i
    c1 = c * g(1); c2 = c * g(2)
    if (b > 0) then
      do i = 1, size(y)
        y(i) = y(i) + c1 * (vt(i, 2*b-1) - vt(i, 2*a-1)) + c2 * (vt(i, 2*b) - vt(i, 2*a))
      end do
    else
      do i = 1, size(y)
        y(i) = y(i) - c1 * vt(i, 2*a-1) - c2 * vt(i, 2*a)
      end do
    end if
  end subroutine add_row

  !> y += c1 x1 + c2 x2 (acc), or y = c1 x1 + c2 x2.
  pure subroutine add_pair(y, c1, x1, c2, x2, acc)
    real(wp), contiguous, intent(inout) :: y(:)
    real(wp), intent(in) :: c1, c2
    real(wp), contiguous, intent(in) :: x1(:), x2(:)
    logical, intent(in) :: acc
    integer :: i
    if (acc) then
      do i = 1, size(y)
        y(i) = y(i) + c1 * x1(i) + c2 * x2(i)
      end do
    else
      do i = 1, size(y)
        y(i) = c1 * x1(i) + c2 * x2(i)
      end do
    end if
  end subroutine add_pair

  subroutine online_assemble(this, ctx, q, vhat, bt, dhat)
    class(ops_online_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    real(wp) :: vmax, cutoff
    integer :: l, a, b, i
    call ctx%desired%evaluate(q, ctx%speeds, this%vfull)
    call la_gemv('N', 1.0_wp, this%vt, this%vfull, 0.0_wp, vhat)
    vmax = 0
    do i = 1, size(ctx%speeds)
      vmax = max(vmax, norm2(this%vfull(2*i-1:2*i)))
    end do
    ! the full-order model's candidate rule (the reduced velocity is not known yet)
    cutoff = max(this%cutoff_factor * 2 * ctx%h * vmax, 1.0e-12_wp * ctx%radius)
    this%cs%h = ctx%h
    call build_contacts(ctx%scene, q, ctx%radius, cutoff, this%cells, this%cs)
    if (allocated(bt)) then
      if (size(bt, 2) /= this%cs%n) deallocate(bt, dhat)
    end if
    if (.not. allocated(bt)) allocate(bt(this%nb, this%cs%n), dhat(this%cs%n))
    if (size(this%keys) < this%cs%n) then
      deallocate(this%keys, this%zn, this%zdof, this%zval)
      allocate(this%keys(2 * this%cs%n), this%zn(2 * this%cs%n), this%zdof(4, 2 * this%cs%n), &
        this%zval(4, 2 * this%cs%n))
    end if
    do l = 1, this%cs%n
      a = this%cs%ia(l); b = this%cs%ib(l)
      bt(:, l) = 0
      call add_row(bt(:, l), this%vt, ctx%h, a, b, this%cs%g(:, l))
      dhat(l) = this%cs%gap(l)
      this%keys(l) = this%cs%key(l)
      if (this%has_gram) then
        this%zn(l) = 0
        call this%z_add(l, 1.0_wp, a, b, this%cs%g(:, l), ctx%h)
      end if
    end do
  end subroutine online_assemble

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
        do p = this%wp0(l) + 1, this%wp0(l + 1)
          call add_row(bt(:, this%wk(p)), this%vt, this%wv(p) * ctx%h, this%ia(l), this%ib(l), g)
        end do
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
    ! vhat = V^T x with x the weighted desired velocity at the points: one product with V^T
    ! when the points cover a good part of the dofs, else one column per point
    if (8 * this%m(1) >= size(this%vt, 2)) then
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

  !> Rows the EIM assembly evaluated exactly since `ops` was made (interpolated normal shorter
  !> than 1/2); 0 for the other variants.
  integer function eim_exact_rows(ops) result(n)
    class(reduced_ops_t), intent(in) :: ops
    n = 0
    select type (ops)
    type is (ops_eim_t)
      n = ops%n_exact_rows
    end select
  end function eim_exact_rows

  !> Allocate bt [nb, r], dhat [r] if needed.
  subroutine ensure(bt, dhat, nb, r)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    integer, intent(in) :: nb, r
    if (allocated(bt)) then
      if (size(bt, 1) == nb .and. size(bt, 2) == r) return
      deallocate(bt, dhat)
    end if
    allocate(bt(nb, r), dhat(r))
  end subroutine ensure
end module cr_reduced_ops
