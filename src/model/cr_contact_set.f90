!> The linearised contact constraints of one time step: rows of B = -h G and d = D.
!>
!> Velocities and positions are flat arrays [2*n_agents] ordered (x1, y1, x2, y2, ...).
!> Row l of the constraint B u <= d reads  D_l + h G_l . u >= 0, where G_l has the unit
!> normal g(:,l) in the slots of agent ia(l) and -g(:,l) in the slots of agent ib(l)
!> (ib = 0 for an agent-obstacle contact, whose obstacle index is ob(l)).
!> Every row has a stable identity key(l) (agent pair or agent-obstacle pair) used to match
!> multipliers across steps.
module cr_contact_set
  use cr_kinds, only: wp, i8
  implicit none
  private
  public :: contact_set_t, contact_key, kkt_residuals, velocity_scale

  !> Contact rows of one step.
  type :: contact_set_t
    !> number of agents (velocity has 2*n_agents entries)
    integer :: n_agents = 0
    !> number of rows in use
    integer :: n = 0
    !> time step h (B = -h G)
    real(wp) :: h = 0.0_wp
    !> first agent of each row [n]
    integer, allocatable :: ia(:)
    !> second agent of each row, 0 for agent-obstacle rows [n]
    integer, allocatable :: ib(:)
    !> obstacle index of each row, 0 for agent-agent rows [n]
    integer, allocatable :: ob(:)
    !> unit gradient of the gap with respect to q_ia [2, n]
    real(wp), allocatable :: g(:,:)
    !> gap D_l(q) (= d) [n]
    real(wp), allocatable :: gap(:)
  contains
    procedure :: init
    procedure :: free
    procedure :: clear
    procedure :: add
    procedure :: reserve
    procedure :: key
    procedure :: keys_of
    procedure :: apply_b
    procedure :: apply_bt
    procedure :: lipschitz_bound
  end type contact_set_t

contains

  !> Prepare an empty set for `n_agents` agents and step `h` with room for `capacity` rows.
  subroutine init(this, n_agents, h, capacity)
    class(contact_set_t), intent(inout) :: this
    integer, intent(in) :: n_agents
    real(wp), intent(in) :: h
    integer, intent(in), optional :: capacity
    integer :: cap
    cap = 16
    if (present(capacity)) cap = max(capacity, 16)
    call this%free()
    this%n_agents = n_agents
    this%h = h
    allocate(this%ia(cap), this%ib(cap), this%ob(cap), this%g(2, cap), this%gap(cap))
    this%n = 0
  end subroutine init

  subroutine free(this)
    class(contact_set_t), intent(inout) :: this
    if (allocated(this%ia)) deallocate(this%ia, this%ib, this%ob, this%g, this%gap)
    this%n = 0
  end subroutine free

  !> Remove all rows, keeping the storage.
  subroutine clear(this)
    class(contact_set_t), intent(inout) :: this
    this%n = 0
  end subroutine clear

  !> Append a row: agents ia, ib (0 for obstacle), obstacle ob (0 for pair), normal g, gap.
  subroutine add(this, ia, ib, ob, g, gap)
    class(contact_set_t), intent(inout) :: this
    integer, intent(in) :: ia, ib, ob
    real(wp), intent(in) :: g(2), gap
    integer :: cap
    if (.not. allocated(this%ia)) call this%init((this%n_agents), (this%h))
    cap = size(this%ia)
    if (this%n == cap) call grow(this, 2 * cap)
    this%n = this%n + 1
    this%ia(this%n) = ia
    this%ib(this%n) = ib
    this%ob(this%n) = ob
    this%g(:, this%n) = g
    this%gap(this%n) = gap
  end subroutine add

  !> Room for at least `cap` rows, keeping the rows in use (storage allocated if needed).
  subroutine reserve(this, cap)
    class(contact_set_t), intent(inout) :: this
    integer, intent(in) :: cap
    if (.not. allocated(this%ia)) then
      call this%init((this%n_agents), (this%h), cap)
    else if (size(this%ia) < cap) then
      call grow(this, cap)
    end if
  end subroutine reserve

  subroutine grow(this, cap)
    type(contact_set_t), intent(inout) :: this
    integer, intent(in) :: cap
    integer, allocatable :: i1(:), i2(:), i3(:)
    real(wp), allocatable :: g(:,:), d(:)
    integer :: n
    n = this%n
    allocate(i1(cap), i2(cap), i3(cap), g(2, cap), d(cap))
    i1(1:n) = this%ia(1:n); i2(1:n) = this%ib(1:n); i3(1:n) = this%ob(1:n)
    g(:, 1:n) = this%g(:, 1:n); d(1:n) = this%gap(1:n)
    call move_alloc(i1, this%ia); call move_alloc(i2, this%ib); call move_alloc(i3, this%ob)
    call move_alloc(g, this%g); call move_alloc(d, this%gap)
  end subroutine grow

  !> Stable identity of row l (see contact_key).
  elemental integer(i8) function key(this, l)
    class(contact_set_t), intent(in) :: this
    integer, intent(in) :: l
    key = contact_key(this%ia(l), this%ib(l), this%ob(l))
  end function key

  !> keys(l) = identity of row l for every row [>= n] (see contact_key).
  pure subroutine keys_of(this, keys)
    class(contact_set_t), intent(in) :: this
    integer(i8), intent(out) :: keys(:)
    integer :: l
    do l = 1, this%n
      keys(l) = contact_key(this%ia(l), this%ib(l), this%ob(l))
    end do
  end subroutine keys_of

  !> Identity of a contact: agent pair (ia < ib) or agent-obstacle pair, as one integer.
  !> Pairs sort before obstacle contacts of the same first agent.
  elemental integer(i8) function contact_key(ia, ib, ob)
    integer, intent(in) :: ia, ib, ob
    if (ib > 0) then
      contact_key = int(min(ia, ib), i8) * 4294967296_i8 + int(max(ia, ib), i8)
    else
      contact_key = int(ia, i8) * 4294967296_i8 + 2147483648_i8 + int(ob, i8)
    end if
  end function contact_key

  !> bu = B u, with B = -h G  (u: [2*n_agents], bu: [n]).
  pure subroutine apply_b(this, u, bu)
    class(contact_set_t), intent(in) :: this
    real(wp), intent(in) :: u(:)
    real(wp), intent(out) :: bu(:)
    integer :: l, a, b
    real(wp) :: s
    do l = 1, this%n
      a = this%ia(l)
      s = this%g(1, l) * u(2*a - 1) + this%g(2, l) * u(2*a)
      b = this%ib(l)
      if (b > 0) s = s - this%g(1, l) * u(2*b - 1) - this%g(2, l) * u(2*b)
      bu(l) = -this%h * s
    end do
  end subroutine apply_b

  !> w = B^T lambda  (lambda: [n], w: [2*n_agents]).
  pure subroutine apply_bt(this, lambda, w)
    class(contact_set_t), intent(in) :: this
    real(wp), intent(in) :: lambda(:)
    real(wp), intent(out) :: w(:)
    integer :: l, a, b
    real(wp) :: s
    w = 0.0_wp
    do l = 1, this%n
      s = -this%h * lambda(l)
      a = this%ia(l)
      w(2*a - 1) = w(2*a - 1) + s * this%g(1, l)
      w(2*a) = w(2*a) + s * this%g(2, l)
      b = this%ib(l)
      if (b > 0) then
        w(2*b - 1) = w(2*b - 1) - s * this%g(1, l)
        w(2*b) = w(2*b) - s * this%g(2, l)
      end if
    end do
  end subroutine apply_bt

  !> Upper bound of ||B B^T||_2 by Gershgorin: row l of |B B^T| sums to at most
  !> h^2 (count(ia) + count(ib)) where count(i) is the number of rows touching agent i.
  pure real(wp) function lipschitz_bound(this) result(lb)
    class(contact_set_t), intent(in) :: this
    integer, allocatable :: cnt(:)
    integer :: l, c
    allocate(cnt(max(this%n_agents, 1)))
    cnt = 0
    do l = 1, this%n
      cnt(this%ia(l)) = cnt(this%ia(l)) + 1
      if (this%ib(l) > 0) cnt(this%ib(l)) = cnt(this%ib(l)) + 1
    end do
    lb = 0.0_wp
    do l = 1, this%n
      c = cnt(this%ia(l))
      if (this%ib(l) > 0) c = c + cnt(this%ib(l))
      lb = max(lb, real(c, wp))
    end do
    lb = lb * this%h**2
  end function lipschitz_bound

  !> Scaled KKT residuals of (u, lambda) for  min |u - v|^2  s.t.  B u <= d.
  !>
  !> With the velocity scale s = max(|v|_inf, max_l (-d_l)^+ / h, sqrt(tiny)) (overlapping rows
  !> force a motion of at least -d_l / h even when v = 0): primal = max_l (Bu - d)_l^+ / (h s);
  !> dual = max_l (-lambda_l)^+ h / s; compl = max_l |lambda_l (Bu - d)_l| / s^2;
  !> stat = |u - v + B^T lambda|_inf / s. All are dimensionless.
  subroutine kkt_residuals(cs, v, u, lambda, primal, dual, compl, stat)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:), u(:), lambda(:)
    real(wp), intent(out) :: primal, dual, compl, stat
    real(wp), allocatable :: r(:), w(:)
    real(wp) :: s
    integer :: l
    s = velocity_scale(cs, v)
    allocate(r(cs%n), w(size(u)))
    call cs%apply_b(u, r)
    primal = 0.0_wp; dual = 0.0_wp; compl = 0.0_wp
    do l = 1, cs%n
      r(l) = r(l) - cs%gap(l)
      primal = max(primal, r(l))
      dual = max(dual, -lambda(l))
      compl = max(compl, abs(lambda(l) * r(l)))
    end do
    primal = primal / (cs%h * s)
    dual = dual * cs%h / s
    compl = compl / s**2
    call cs%apply_bt(lambda(1:cs%n), w)
    stat = 0.0_wp
    if (size(u) > 0) stat = maxval(abs(u - v + w)) / s
  end subroutine kkt_residuals

  !> Velocity scale of a projection problem: max(|v|_inf, max_l (-d_l)^+ / h, sqrt(tiny)).
  !> Overlapping rows (d_l < 0) force a motion of at least -d_l / h even when v = 0. The
  !> floor sqrt(tiny) keeps s**2 a normal number (a crowd at rest, v = 0: residuals 0 / s**2
  !> must be 0, not 0 / 0).
  pure real(wp) function velocity_scale(cs, v) result(s)
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    integer :: l
    s = sqrt(tiny(1.0_wp))
    if (size(v) > 0) s = max(s, maxval(abs(v)))
    do l = 1, cs%n
      s = max(s, -cs%gap(l) / cs%h)
    end do
  end function velocity_scale
end module cr_contact_set
