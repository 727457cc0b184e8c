!> The online half every hyper-reduction method shares: what the reduced terms depend on
!> (`eval_ctx_t`) and the abstract assembly of the reduced problem of one time step
!> (`reduced_ops_t`), the paper's
!>   min |alpha - vhat|^2  s.t.  bhat alpha <= dhat,
!> vhat = V^T v(q), bhat = W^T B(q) V, dhat = W^T d(q); plus the helpers the assemblies share
!> (reduced image of a contact row, cone by rows, Gram entries of the assembled rows for the
!> dual active-set solver). Each method (src/hyper/cr_hyper_*.f90) extends `reduced_ops_t`.
module cr_reduced_base
  use cr_kinds, only: wp, i8
  use cr_scene, only: scene_t
  use cr_desired, only: desired_t
  use cr_density_speed, only: density_speed_t
  use cr_dual_qp, only: gram_source_t
  implicit none
  private
  public :: eval_ctx_t, reduced_ops_t, unique_map, gram_setup, cone_rows, agent_desired, add_row, add_pair, ensure, &
    mark_agents

  !> What the terms depend on besides the positions: the sample's scene, desired-velocity
  !> model and speeds, the agent radius and the time step. With the density-dependent desired
  !> speed (density%on, &desired speed_model = 'weidmann') the stepper hands the assembly a
  !> copy whose speeds are those of the step (cr_rom_stepper).
  type :: eval_ctx_t
    type(scene_t) :: scene
    type(desired_t) :: desired
    real(wp), allocatable :: speeds(:)
    real(wp) :: radius = 0, h = 0
    type(density_speed_t) :: density
  end type eval_ctx_t

  !> A way of assembling (vhat, bhat, dhat); also the source of the Gram entries of the
  !> assembled rows for the dual active-set solver (when has_gram).
  type, abstract, extends(gram_source_t) :: reduced_ops_t
    integer :: nb = 0, r = 0
    !> agents whose positions `assemble` reads
    integer, allocatable :: agents(:)
    !> number of interpolation / quadrature entries of s1, s2, s3 (0 for exact)
    integer :: m(3) = 0
    !> the cone's support rows: agents ia, ib (0: obstacle) and obstacle ob of each [p3]
    integer, allocatable :: ia(:), ib(:), ob(:)
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
    procedure :: z_add
    procedure :: init_base
    procedure :: add_support_row
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

contains

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

  !> The part every assembly shares: basis v [n_dof, nb] and its transpose, R, the cone w
  !> [p3, R] on its support rows by rows, the support rows (agents ia, ib, obstacle ob [p3])
  !> and the points m of s1, s2, s3 (default 0: exact).
  subroutine init_base(this, v, w, ia, ib, ob, m)
    class(reduced_ops_t), intent(inout) :: this
    real(wp), intent(in) :: v(:,:), w(:,:)
    integer, intent(in) :: ia(:), ib(:), ob(:)
    integer, intent(in), optional :: m(3)
    this%nb = size(v, 2)
    this%r = size(w, 2)
    this%v = v
    this%vt = transpose(v)
    call cone_rows(w, this%wp0, this%wk, this%wv)
    this%ia = ia; this%ib = ib; this%ob = ob
    if (present(m)) this%m = m
  end subroutine init_base

  !> Add support row l with unit normal g (agents ia(l), ib(l)) to every cone column it enters:
  !> bt(:, k) += w_lk h V^T g-row; with gap, dhat(k) += w_lk gap, and the Gram entries of the
  !> column are recorded (when has_gram).
  subroutine add_support_row(this, l, g, h, bt, gap, dhat)
    class(reduced_ops_t), intent(inout) :: this
    integer, intent(in) :: l
    real(wp), intent(in) :: g(2), h
    real(wp), contiguous, intent(inout) :: bt(:,:)
    real(wp), intent(in), optional :: gap
    real(wp), intent(inout), optional :: dhat(:)
    integer :: p, k
    do p = this%wp0(l) + 1, this%wp0(l + 1)
      k = this%wk(p)
      call add_row(bt(:, k), this%vt, this%wv(p) * h, this%ia(l), this%ib(l), g)
      if (present(dhat)) dhat(k) = dhat(k) + this%wv(p) * gap
      if (this%has_gram) call this%z_add(k, this%wv(p), this%ia(l), this%ib(l), g, h)
    end do
  end subroutine add_support_row

  !> Prepare the cheap Gram matrix of the rows (see reduced_ops_t) when it pays: v [n_dof, nb]
  !> the basis, w [p3, R] the cone on its support rows.
  subroutine gram_setup(ops, v, w)
    class(reduced_ops_t), intent(inout) :: ops
    real(wp), intent(in) :: v(:,:), w(:,:)
    integer :: k, n_dof, r, nb
    n_dof = size(v, 1); nb = size(v, 2); r = size(w, 2)
    ops%zmax = 0
    do k = 1, r
      ops%zmax = max(ops%zmax, 4 * count(w(:, k) /= 0))
    end do
    ! worth it when a row's dof-space support is much smaller than the basis
    ops%has_gram = r > 0 .and. ops%zmax <= 16 .and. n_dof <= 4000 .and. nb >= 4 * ops%zmax**2
    if (.not. ops%has_gram) return
    ops%pmat = matmul(v, transpose(v))
    allocate(ops%zn(r), ops%zdof(ops%zmax, r), ops%zval(ops%zmax, r))
    ops%zn = 0
  end subroutine gram_setup

  !> Mark in need [n_agents] the agents read by the dofs i1 and the support rows r2, r3 of
  !> agents ia, ib (ib = 0: obstacle).
  subroutine mark_agents(need, i1, r2, r3, ia, ib)
    logical, intent(inout) :: need(:)
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
  end subroutine mark_agents

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
end module cr_reduced_base
