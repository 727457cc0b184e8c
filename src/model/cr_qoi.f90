!> Quantities of interest (QoI) of a trajectory, and the one place that defines them (docs/queries.md,
!> "Quantities of interest"). Every program (crowd_fom, crowd_snapshots, the reduced sweep, the
!> prediction) and every script reads them as computed here.
!>
!> From positions q [n_dof, n_steps + 1] (agent i at q(2i-1:2i, :), frame c at time c h), the
!> scene, the agent radius r and the step h:
!>  * exits: 1 = the top-wall exit, 2 = the right-wall exit when the scene has one. Agent i is
!>    out through exit e from the first frame at which it is beyond that exit's "has left" line
!>    (scene%exit_of) and stays counted out after it (an agent that steps back is not counted
!>    twice nor removed).
!>  * curve(c, e): agents out through exit e at frame c, c = 0..n_steps; curve_total(c) their sum.
!>  * t_evac(j) = t50, t90, t100 [s] (QOI_PCT): the first frame time c h at which at least
!>    ceiling(p n_agents / 100) agents are out; where not reached within the horizon, the horizon
!>    n_steps h with censored(j) = .true.
!>  * flow_rate(e) [1/s]: least-squares slope of curve(:, e) against time over the frames from
!>    the first at which it reaches QOI_FLOW_LO % of its final count to the first at which it
!>    reaches QOI_FLOW_HI % of it (both ceilings, as above); flow(e) = flow_rate(e) / width(e)
!>    [1/(m s)]. Fewer than 3 frames in that window, or no agent out: 0 with flow_defined = false.
!>  * trust indicators: the deepest agent-agent and agent-obstacle overlaps over all frames [m];
!>    n_through, agents whose centre path (straight between consecutive frames) meets a wall or
!>    an interior obstacle (the walls enclose the hall except at the openings, so this also
!>    counts an agent that left the hall other than through an exit); displacement
!>    |q(:, n_steps) - q(:, 0)| [m], whose ratio to the exact model's is the mobility.
module cr_qoi
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_shapes, only: segment_obstacle_distance
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  implicit none
  private
  public :: qoi_t, qoi_acc_t, compute_qoi, QOI_PCT, QOI_FLOW_LO, QOI_FLOW_HI
  public :: evacuation_time, steady_flow, max_overlaps, mobility_ratio, qoi_pack_size, pack_qoi, unpack_qoi

  !> evacuation fractions [%] of t_evac: t50, t90, t100
  integer, parameter :: QOI_PCT(3) = [50, 90, 100]
  !> window of the steady flow [% of the exit's final count]
  integer, parameter :: QOI_FLOW_LO = 10, QOI_FLOW_HI = 80

  !> The QoIs of one trajectory (see the module header).
  type :: qoi_t
    integer :: n_agents = 0, n_steps = 0, n_exits = 0
    !> time step [s]
    real(wp) :: h = 0
    !> agents out through each exit [0:n_steps, n_exits] and through any exit [0:n_steps]
    integer, allocatable :: curve(:,:), curve_total(:)
    !> t50, t90, t100 [s] (the horizon where censored)
    real(wp) :: t_evac(3) = 0
    logical :: censored(3) = .true.
    !> per exit [n_exits]: width [m], steady flow [1/s], specific flow [1/(m s)], defined
    real(wp), allocatable :: width(:), flow_rate(:), flow(:)
    logical, allocatable :: flow_defined(:)
    !> deepest agent-agent and agent-obstacle overlaps [m] (0: none)
    real(wp) :: overlap_aa = 0, overlap_aw = 0
    !> agents whose path met a wall or an obstacle
    integer :: n_through = 0
    !> |q(:, n_steps) - q(:, 0)| [m]
    real(wp) :: displacement = 0
  contains
    procedure :: free
  end type qoi_t

  !> Accumulates the QoIs of a trajectory frame by frame (init, add per frame, finish), so a
  !> program that does not keep its trajectory (crowd_fom) computes exactly what compute_qoi does.
  type :: qoi_acc_t
    integer :: n_agents = 0, n_frames = 0
    !> per agent: first frame out (-1: not out) and the exit [n_agents]
    integer, allocatable :: first(:), via(:)
    !> per agent: its path met an obstacle [n_agents]
    logical, allocatable :: hit(:)
    !> first and latest frame [2 n_agents]
    real(wp), allocatable :: q0(:), prev(:)
    real(wp) :: overlap_aa = 0, overlap_aw = 0
    type(cell_list_t), private :: cells
    type(contact_set_t), private :: cs
  contains
    procedure :: init => acc_init
    procedure :: add => acc_add
    procedure :: finish => acc_finish
  end type qoi_acc_t

contains

  !> Every QoI of the trajectory q [n_dof, n_steps + 1] (time step h, agent radius radius).
  subroutine compute_qoi(scene, radius, h, q, qoi, error)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h, q(:,:)
    type(qoi_t), intent(out) :: qoi
    type(error_t), allocatable, intent(out) :: error
    type(qoi_acc_t) :: acc
    integer :: c
    if (mod(size(q, 1), 2) /= 0) then
      call set_error(error, "qoi: trajectory of " // str(size(q, 1)) // " rows: expected 2 per agent"); return
    end if
    call acc%init(size(q, 1) / 2)
    do c = 1, size(q, 2)
      call acc%add(scene, radius, q(:, c))
    end do
    call acc%finish(scene, radius, h, qoi, error)
  end subroutine compute_qoi

  !> Start a trajectory of n_agents agents.
  subroutine acc_init(this, n_agents)
    class(qoi_acc_t), intent(inout) :: this
    integer, intent(in) :: n_agents
    this%n_agents = n_agents; this%n_frames = 0
    if (allocated(this%first)) deallocate(this%first, this%via, this%hit)
    allocate(this%first(n_agents), this%via(n_agents), this%hit(n_agents))
    this%first = -1; this%via = 0; this%hit = .false.
    this%overlap_aa = 0; this%overlap_aw = 0
    if (allocated(this%q0)) deallocate(this%q0)
    if (allocated(this%prev)) deallocate(this%prev)
    call this%cs%init(n_agents, 1.0_wp, 8 * n_agents)
  end subroutine acc_init

  !> Add the next frame q [2 n_agents]: who is out through which exit (scene%exit_of), the
  !> overlaps, the paths from the previous frame through obstacles.
  subroutine acc_add(this, scene, radius, q)
    class(qoi_acc_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:)
    integer :: i, e
    do i = 1, this%n_agents
      if (this%first(i) >= 0) cycle
      e = scene%exit_of(q(2*i-1:2*i), radius)
      if (e > 0) then
        this%first(i) = this%n_frames; this%via(i) = e
      end if
    end do
    call frame_overlaps(scene, radius, q, this%cells, this%cs, this%overlap_aa, this%overlap_aw)
    if (this%n_frames == 0) then
      this%q0 = q
    else
      call mark_through(scene, this%prev, q, this%hit)
    end if
    this%prev = q
    this%n_frames = this%n_frames + 1
  end subroutine acc_add

  !> The QoIs of the frames added (at least one; time step h).
  subroutine acc_finish(this, scene, radius, h, qoi, error)
    class(qoi_acc_t), intent(in) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h
    type(qoi_t), intent(out) :: qoi
    type(error_t), allocatable, intent(out) :: error
    integer :: j, e, i, nt
    if (this%n_frames < 1 .or. .not. (h > 0) .or. .not. (radius > 0)) then
      call set_error(error, "qoi: " // str(this%n_frames) // " frames with h = " // str(h) // ", radius = " // &
        str(radius) // ": expected at least one frame, h > 0, radius > 0"); return
    end if
    nt = this%n_frames - 1
    qoi%n_agents = this%n_agents; qoi%n_steps = nt; qoi%n_exits = scene%n_exits(); qoi%h = h
    allocate(qoi%curve(0:nt, qoi%n_exits), qoi%curve_total(0:nt))
    qoi%curve = 0
    do i = 1, this%n_agents
      if (this%first(i) >= 0) qoi%curve(this%first(i), this%via(i)) = qoi%curve(this%first(i), this%via(i)) + 1
    end do
    do j = 1, nt
      qoi%curve(j, :) = qoi%curve(j, :) + qoi%curve(j - 1, :)
    end do
    qoi%curve_total = sum(qoi%curve, dim=2)
    do j = 1, size(QOI_PCT)
      call evacuation_time(qoi%curve_total, qoi%n_agents, QOI_PCT(j), h, qoi%t_evac(j), qoi%censored(j))
    end do
    allocate(qoi%width(qoi%n_exits), qoi%flow_rate(qoi%n_exits), qoi%flow(qoi%n_exits), qoi%flow_defined(qoi%n_exits))
    do e = 1, qoi%n_exits
      qoi%width(e) = scene%exit_width(e)
      call steady_flow(qoi%curve(:, e), h, qoi%flow_rate(e), qoi%flow_defined(e))
      qoi%flow(e) = 0
      if (qoi%flow_defined(e)) qoi%flow(e) = qoi%flow_rate(e) / qoi%width(e)
    end do
    qoi%overlap_aa = this%overlap_aa; qoi%overlap_aw = this%overlap_aw
    qoi%n_through = count(this%hit)
    qoi%displacement = norm2(this%prev - this%q0)
  end subroutine acc_finish

  !> Release the arrays.
  subroutine free(this)
    class(qoi_t), intent(inout) :: this
    if (allocated(this%curve)) deallocate(this%curve)
    if (allocated(this%curve_total)) deallocate(this%curve_total)
    if (allocated(this%width)) deallocate(this%width)
    if (allocated(this%flow_rate)) deallocate(this%flow_rate)
    if (allocated(this%flow)) deallocate(this%flow)
    if (allocated(this%flow_defined)) deallocate(this%flow_defined)
    this%n_agents = 0; this%n_steps = 0; this%n_exits = 0
  end subroutine free

  !> First time t = c h at which curve(c) (c = 0..size - 1) reaches pct % of n_agents (at least
  !> ceiling(pct n_agents / 100) agents out); not reached: the horizon (size - 1) h, censored.
  pure subroutine evacuation_time(curve, n_agents, pct, h, t, censored)
    integer, intent(in) :: curve(0:), n_agents, pct
    real(wp), intent(in) :: h
    real(wp), intent(out) :: t
    logical, intent(out) :: censored
    integer :: c, k
    k = (pct * n_agents + 99) / 100
    censored = .false.
    do c = 0, size(curve) - 1
      if (curve(c) >= k) then
        t = c * h; return
      end if
    end do
    t = (size(curve) - 1) * h
    censored = .true.
  end subroutine evacuation_time

  !> Steady flow [1/s] of the cumulative count cum(c) (c = 0..size - 1, time c h): least-squares
  !> slope between the first frames at which it reaches QOI_FLOW_LO % and QOI_FLOW_HI % of its
  !> final count; 0 and defined = false with no agent out or fewer than 3 frames in the window.
  pure subroutine steady_flow(cum, h, rate, defined)
    integer, intent(in) :: cum(0:)
    real(wp), intent(in) :: h
    real(wp), intent(out) :: rate
    logical, intent(out) :: defined
    integer :: f, c1, c2, c
    real(wp) :: cm, ym, sxy, sxx
    rate = 0
    defined = .false.
    f = cum(size(cum) - 1)
    if (f <= 0) return
    c1 = first_at_least(cum, (QOI_FLOW_LO * f + 99) / 100)
    c2 = first_at_least(cum, (QOI_FLOW_HI * f + 99) / 100)
    if (c2 - c1 + 1 < 3) return
    cm = 0.5_wp * (c1 + c2)
    ym = real(sum(cum(c1:c2)), wp) / (c2 - c1 + 1)
    sxy = 0; sxx = 0
    do c = c1, c2
      sxy = sxy + (c - cm) * (cum(c) - ym)
      sxx = sxx + (c - cm)**2
    end do
    rate = sxy / sxx / h
    defined = .true.
  end subroutine steady_flow

  !> First index c of cum(0:) with cum(c) >= k (size - 1 when none: the callers ask for at most
  !> the last value).
  pure integer function first_at_least(cum, k) result(c)
    integer, intent(in) :: cum(0:), k
    do c = 0, size(cum) - 1
      if (cum(c) >= k) return
    end do
    c = size(cum) - 1
  end function first_at_least

  !> Deepest agent-agent (o_aa) and agent-obstacle (o_aw: walls and interior obstacles)
  !> overlaps over the configurations q [n_dof, n_conf]; 0 when nothing overlaps.
  subroutine max_overlaps(scene, radius, q, o_aa, o_aw)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:,:)
    real(wp), intent(out) :: o_aa, o_aw
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    integer :: nu
    o_aa = 0; o_aw = 0
    call cs%init(size(q, 1) / 2, 1.0_wp, 4 * size(q, 1))
    do nu = 1, size(q, 2)
      call frame_overlaps(scene, radius, q(:, nu), cells, cs, o_aa, o_aw)
    end do
  end subroutine max_overlaps

  !> Raise o_aa, o_aw to the deepest agent-agent and agent-obstacle overlaps of the
  !> configuration q [n_dof] (cells, cs: work space).
  subroutine frame_overlaps(scene, radius, q, cells, cs, o_aa, o_aw)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:)
    type(cell_list_t), intent(inout) :: cells
    type(contact_set_t), intent(inout) :: cs
    real(wp), intent(inout) :: o_aa, o_aw
    integer :: l
    call build_contacts(scene, q, radius, 1.0e-12_wp * radius, cells, cs)
    do l = 1, cs%n
      if (cs%ib(l) > 0) then
        o_aa = max(o_aa, -cs%gap(l))
      else
        o_aw = max(o_aw, -cs%gap(l))
      end if
    end do
  end subroutine frame_overlaps

  !> Mark the agents whose centre path from a to b [2 n_agents] meets a wall or an interior
  !> obstacle (bounding boxes first, then the exact distance).
  subroutine mark_through(scene, a, b, hit)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: a(:), b(:)
    logical, intent(inout) :: hit(:)
    real(wp) :: p(2), r(2)
    integer :: i, k
    do i = 1, size(hit)
      if (hit(i)) cycle
      p = a(2*i-1:2*i); r = b(2*i-1:2*i)
      do k = 1, scene%n_obstacles()
        if (any(max(p, r) < scene%lo(:, k)) .or. any(min(p, r) > scene%hi(:, k))) cycle
        if (segment_obstacle_distance(scene%obstacles(k), p, r) <= 0) then
          hit(i) = .true.; exit
        end if
      end do
    end do
  end subroutine mark_through

  !> Length of pack_qoi's buffer for n_steps steps and n_exits exits.
  pure integer function qoi_pack_size(n_steps, n_exits) result(n)
    integer, intent(in) :: n_steps, n_exits
    n = (n_steps + 1) * n_exits + 6 + 4 * n_exits + 4
  end function qoi_pack_size

  !> The QoIs as reals (integers exactly), e.g. to sum them over ranks: buf [qoi_pack_size].
  pure subroutine pack_qoi(qoi, buf)
    type(qoi_t), intent(in) :: qoi
    real(wp), intent(out) :: buf(:)
    integer :: m, ne
    ne = qoi%n_exits
    m = (qoi%n_steps + 1) * ne
    buf(1:m) = reshape(real(qoi%curve, wp), [m])
    buf(m + 1:m + 3) = qoi%t_evac
    buf(m + 4:m + 6) = merge(1, 0, qoi%censored)
    m = m + 6
    buf(m + 1:m + ne) = qoi%width; m = m + ne
    buf(m + 1:m + ne) = qoi%flow_rate; m = m + ne
    buf(m + 1:m + ne) = qoi%flow; m = m + ne
    buf(m + 1:m + ne) = merge(1, 0, qoi%flow_defined); m = m + ne
    buf(m + 1:m + 4) = [qoi%overlap_aa, qoi%overlap_aw, real(qoi%n_through, wp), qoi%displacement]
  end subroutine pack_qoi

  !> The QoIs of n_agents agents, n_steps steps, n_exits exits and time step h from pack_qoi's buf.
  subroutine unpack_qoi(buf, n_agents, n_steps, n_exits, h, qoi)
    real(wp), intent(in) :: buf(:), h
    integer, intent(in) :: n_agents, n_steps, n_exits
    type(qoi_t), intent(out) :: qoi
    integer :: m, ne
    ne = n_exits
    qoi%n_agents = n_agents; qoi%n_steps = n_steps; qoi%n_exits = ne; qoi%h = h
    m = (n_steps + 1) * ne
    allocate(qoi%curve(0:n_steps, ne), qoi%curve_total(0:n_steps))
    qoi%curve = reshape(nint(buf(1:m)), [n_steps + 1, ne])
    qoi%curve_total = sum(qoi%curve, dim=2)
    qoi%t_evac = buf(m + 1:m + 3)
    qoi%censored = buf(m + 4:m + 6) > 0.5_wp
    m = m + 6
    qoi%width = buf(m + 1:m + ne); m = m + ne
    qoi%flow_rate = buf(m + 1:m + ne); m = m + ne
    qoi%flow = buf(m + 1:m + ne); m = m + ne
    qoi%flow_defined = buf(m + 1:m + ne) > 0.5_wp; m = m + ne
    qoi%overlap_aa = buf(m + 1); qoi%overlap_aw = buf(m + 2); qoi%n_through = nint(buf(m + 3))
    qoi%displacement = buf(m + 4)
  end subroutine unpack_qoi

  !> Mobility of a trajectory against a reference: the ratio of their displacements
  !> (qoi_t%displacement); -1 when the reference does not move.
  pure real(wp) function mobility_ratio(displacement, displacement_ref) result(m)
    real(wp), intent(in) :: displacement, displacement_ref
    m = -1
    if (displacement_ref > 0) m = displacement / displacement_ref
  end function mobility_ratio
end module cr_qoi
