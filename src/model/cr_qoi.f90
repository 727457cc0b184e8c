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
  public :: qoi_t, compute_qoi, QOI_PCT, QOI_FLOW_LO, QOI_FLOW_HI
  public :: exit_curves, evacuation_time, steady_flow, max_overlaps, agents_through_obstacles, mobility_ratio

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

contains

  !> Every QoI of the trajectory q [n_dof, n_steps + 1] (time step h, agent radius radius).
  subroutine compute_qoi(scene, radius, h, q, qoi, error)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h, q(:,:)
    type(qoi_t), intent(out) :: qoi
    type(error_t), allocatable, intent(out) :: error
    integer :: j, e, nt
    if (mod(size(q, 1), 2) /= 0 .or. size(q, 2) < 1 .or. .not. (h > 0) .or. .not. (radius > 0)) then
      call set_error(error, "qoi: trajectory [" // str(size(q, 1)) // ", " // str(size(q, 2)) // "] with h = " // &
        str(h) // ", radius = " // str(radius) // ": expected an even number of rows, at least one frame, h > 0, " // &
        "radius > 0"); return
    end if
    nt = size(q, 2) - 1
    qoi%n_agents = size(q, 1) / 2; qoi%n_steps = nt; qoi%n_exits = scene%n_exits(); qoi%h = h
    call exit_curves(scene, radius, q, qoi%curve)
    allocate(qoi%curve_total(0:nt))
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
    call max_overlaps(scene, radius, q, qoi%overlap_aa, qoi%overlap_aw)
    qoi%n_through = agents_through_obstacles(scene, q)
    qoi%displacement = norm2(q(:, nt + 1) - q(:, 1))
  end subroutine compute_qoi

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

  !> Per-exit evacuation curves of the configurations q [n_dof, n_conf]: curve(c, e) agents out
  !> through exit e at configuration c [0:n_conf - 1, scene%n_exits()] (each agent counted from
  !> the first configuration at which scene%exit_of says it is beyond an exit's line, through
  !> that exit).
  subroutine exit_curves(scene, radius, q, curve)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:,:)
    integer, allocatable, intent(out) :: curve(:,:)
    logical :: out(size(q, 1) / 2)
    integer :: i, c, e
    allocate(curve(0:size(q, 2) - 1, scene%n_exits()))
    curve = 0
    out = .false.
    do c = 0, size(q, 2) - 1
      if (c > 0) curve(c, :) = curve(c - 1, :)
      do i = 1, size(out)
        if (out(i)) cycle
        e = scene%exit_of(q(2*i-1:2*i, c + 1), radius)
        if (e > 0) then
          out(i) = .true.
          curve(c, e) = curve(c, e) + 1
        end if
      end do
    end do
  end subroutine exit_curves

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
    integer :: nu, l
    o_aa = 0; o_aw = 0
    call cs%init(size(q, 1) / 2, 1.0_wp, 4 * size(q, 1))
    do nu = 1, size(q, 2)
      call build_contacts(scene, q(:, nu), radius, 1.0e-12_wp * radius, cells, cs)
      do l = 1, cs%n
        if (cs%ib(l) > 0) then
          o_aa = max(o_aa, -cs%gap(l))
        else
          o_aw = max(o_aw, -cs%gap(l))
        end if
      end do
    end do
  end subroutine max_overlaps

  !> Agents of q [n_dof, n_conf] whose centre path, straight between consecutive configurations,
  !> meets a wall or an interior obstacle (bounding boxes first, then the exact distance).
  integer function agents_through_obstacles(scene, q) result(n)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:,:)
    logical :: hit(size(q, 1) / 2)
    real(wp) :: a(2), b(2)
    integer :: i, c, k
    hit = .false.
    do c = 2, size(q, 2)
      do i = 1, size(hit)
        if (hit(i)) cycle
        a = q(2*i-1:2*i, c - 1); b = q(2*i-1:2*i, c)
        do k = 1, scene%n_obstacles()
          if (any(max(a, b) < scene%lo(:, k)) .or. any(min(a, b) > scene%hi(:, k))) cycle
          if (segment_obstacle_distance(scene%obstacles(k), a, b) <= 0) then
            hit(i) = .true.; exit
          end if
        end do
      end do
    end do
    n = count(hit)
  end function agents_through_obstacles

  !> Mobility of a trajectory against a reference: the ratio of their displacements
  !> (qoi_t%displacement); -1 when the reference does not move.
  pure real(wp) function mobility_ratio(displacement, displacement_ref) result(m)
    real(wp), intent(in) :: displacement, displacement_ref
    m = -1
    if (displacement_ref > 0) m = displacement / displacement_ref
  end function mobility_ratio
end module cr_qoi
