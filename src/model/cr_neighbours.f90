!> Candidate contacts of one step: agent pairs found with a uniform cell list, and
!> agent-obstacle pairs filtered by bounding boxes, each kept when its gap <= cutoff.
!>
!> Cost O(n_agents + n_cells + n_agents * n_obstacles_near): the cell grid covers the
!> bounding box of the agents with cells of side >= 2 r + cutoff, and is coarsened so that
!> it never has more than 4 n_agents + 64 cells.
!>
!> Any finite coordinates are accepted (a reduced trajectory that has diverged may put agents
!> at 1e300 m): the grid size and every cell index are computed and clamped in real
!> arithmetic on half-coordinates (so that hi - lo cannot overflow even for +-huge) before
!> any conversion to integer. Non-finite coordinates cannot overflow either: such an agent
!> is put in cell 1 and its gaps are NaN, which the callers' finiteness checks report.
module cr_neighbours
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_contact_set, only: contact_set_t
  use cr_shapes, only: obstacle_distance
  use cr_scene, only: scene_t
  implicit none
  private
  public :: cell_list_t, build_contacts, bin_agents, rows_missing, grid_size, cell_index, pair_contact

  !> Linked-cell structure (reused across steps to avoid reallocation).
  type :: cell_list_t
    integer :: nx = 0, ny = 0
    real(wp) :: x0 = 0, y0 = 0, side = 1
    integer, allocatable :: head(:), next(:)
    !> cell of each agent (1-based, as head) [n_agents]
    integer, allocatable :: cell(:)
    !> cells that meet an obstacle's bounding box grown by radius + cutoff [nx*ny]
    logical, allocatable :: near(:)
  end type cell_list_t

contains

  !> Fill `cs` (cleared first) with every agent pair and agent-obstacle pair whose gap is
  !> <= cutoff, at positions q [2*n_agents]. Agents with active(i) = .false. are skipped.
  !> With margin [n_agents] (cutoff >= 2 maxval(margin)), a pair (a, b) is kept when its gap
  !> is <= margin(a) + margin(b) and an agent-obstacle pair when it is <= 2 margin(a) instead.
  subroutine build_contacts(scene, q, radius, cutoff, cells, cs, active, margin)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:)
    real(wp), intent(in) :: radius, cutoff
    type(cell_list_t), intent(inout) :: cells
    type(contact_set_t), intent(inout) :: cs
    logical, intent(in), optional :: active(:)
    real(wp), intent(in), optional :: margin(:)
    integer :: na, i, j, cx, cy, ix, iy, c, k
    real(wp) :: dx, dy, dist, gap, reach, g(2), nrm(2), mi
    !> obstacle bounding boxes grown by radius + cutoff [2, n_obstacles]
    real(wp) :: olo(2, scene%n_obstacles()), ohi(2, scene%n_obstacles())
    logical :: use_i, per_agent
    na = size(q) / 2
    per_agent = present(margin)
    call cs%clear()
    if (na == 0) return
    if (.not. allocated(cs%ia)) call cs%reserve(16)
    call bin_agents(q, 2 * radius + cutoff, cells, active)
    if (allocated(cells%near)) then
      if (size(cells%near) < size(cells%head)) deallocate(cells%near)
    end if
    if (.not. allocated(cells%near)) allocate(cells%near(size(cells%head)))
    ! -- agent pairs
    reach = 2 * radius + cutoff
    do i = 1, na
      use_i = .true.
      if (present(active)) use_i = active(i)
      if (.not. use_i) cycle
      cx = mod(cells%cell(i) - 1, cells%nx)
      cy = (cells%cell(i) - 1) / cells%nx
      mi = cutoff
      if (per_agent) mi = margin(i)
      do iy = max(cy - 1, 0), min(cy + 1, cells%ny - 1)
        do ix = max(cx - 1, 0), min(cx + 1, cells%nx - 1)
          j = cells%head(iy * cells%nx + ix + 1)
          do while (j > 0)
            if (j > i) then
              dx = q(2*i-1) - q(2*j-1); dy = q(2*i) - q(2*j)
              if (abs(dx) <= reach .and. abs(dy) <= reach) then
                call pair_contact(dx, dy, radius, g, gap)
                if (per_agent) then
                  if (gap <= mi + margin(j)) call append(i, j, 0, g, gap)
                else
                  if (gap <= cutoff) call append(i, j, 0, g, gap)
                end if
              end if
            end if
            j = cells%next(j)
          end do
        end do
      end do
    end do
    ! -- agent-obstacle pairs: only agents in a cell that meets a grown obstacle box (cell_index
    ! is monotone, so an agent inside a box lies in one of the cells from the cell of the box's
    ! low corner to that of its high corner; agents with a non-finite coordinate test them all)
    cells%near(1:cells%nx * cells%ny) = .false.
    do k = 1, size(olo, 2)
      olo(:, k) = scene%lo(:, k) - radius - cutoff
      ohi(:, k) = scene%hi(:, k) + radius + cutoff
      call mark_box(olo(:, k), ohi(:, k))
    end do
    do i = 1, na
      if (present(active)) then
        if (.not. active(i)) cycle
      end if
      if (ieee_is_finite(q(2*i-1)) .and. ieee_is_finite(q(2*i))) then
        if (.not. cells%near(cells%cell(i))) cycle
      end if
      mi = cutoff
      if (per_agent) mi = 2 * margin(i)
      do k = 1, size(olo, 2)
        if (q(2*i-1) < olo(1, k) .or. q(2*i-1) > ohi(1, k)) cycle
        if (q(2*i) < olo(2, k) .or. q(2*i) > ohi(2, k)) cycle
        call obstacle_distance(scene%obstacles(k), q(2*i-1:2*i), dist, nrm)
        gap = dist - radius
        if (gap <= mi) call append(i, 0, k, nrm, gap)
      end do
    end do

  contains

    !> Mark the cells from the cell of blo to that of bhi (every cell on a side where a corner
    !> has no finite cell coordinate).
    subroutine mark_box(blo, bhi)
      real(wp), intent(in) :: blo(2), bhi(2)
      integer :: x0, x1, y0, y1, yy
      x0 = corner_cell(blo(1), cells%x0, cells%nx, 0)
      x1 = corner_cell(bhi(1), cells%x0, cells%nx, cells%nx - 1)
      y0 = corner_cell(blo(2), cells%y0, cells%ny, 0)
      y1 = corner_cell(bhi(2), cells%y0, cells%ny, cells%ny - 1)
      do yy = y0, y1
        cells%near(yy * cells%nx + x0 + 1:yy * cells%nx + x1 + 1) = .true.
      end do
    end subroutine mark_box

    !> cell_index of a box corner x, or `fallback` when its cell coordinate is not finite
    pure integer function corner_cell(x, x0, n, fallback) result(c)
      real(wp), intent(in) :: x, x0
      integer, intent(in) :: n, fallback
      real(wp) :: t
      t = (0.5_wp * x - 0.5_wp * x0) / (0.5_wp * cells%side)
      if (ieee_is_finite(t)) then
        c = cell_index(x, x0, cells%side, n)
      else
        c = fallback
      end if
    end function corner_cell

    !> cs%add without the call (the call cost 22% of build_contacts on congested150, callgrind):
    !> room is made (doubling) only when the rows are full
    subroutine append(a, b, o, gg, dd)
      integer, intent(in) :: a, b, o
      real(wp), intent(in) :: gg(2), dd
      integer :: m
      if (cs%n >= size(cs%ia)) call cs%reserve(2 * size(cs%ia))
      m = cs%n + 1
      cs%n = m
      cs%ia(m) = a; cs%ib(m) = b; cs%ob(m) = o
      cs%g(1, m) = gg(1); cs%g(2, m) = gg(2)
      cs%gap(m) = dd
    end subroutine append

  end subroutine build_contacts

  !> The agents at positions q [2*n_agents] (those with active(i), all without it) in a grid of
  !> cells of side >= side0 over the bounding box of the finite positions, at most
  !> 4 n_agents + 64 cells (module header): cells%head, next and cell (kept, grown as needed).
  subroutine bin_agents(q, side0, cells, active)
    real(wp), intent(in) :: q(:), side0
    type(cell_list_t), intent(inout) :: cells
    logical, intent(in), optional :: active(:)
    real(wp) :: lo(2), hi(2)
    integer :: na, i, c
    na = size(q) / 2
    lo = [huge(1.0_wp), huge(1.0_wp)]; hi = -lo
    do i = 1, na
      if (.not. all(ieee_is_finite(q(2*i-1:2*i)))) cycle
      lo = min(lo, q(2*i-1:2*i)); hi = max(hi, q(2*i-1:2*i))
    end do
    if (lo(1) > hi(1)) then   ! no finite agent
      lo = 0; hi = 0
    end if
    call grid_size(0.5_wp * hi - 0.5_wp * lo, side0, real(4 * na + 64, wp), cells%side, cells%nx, cells%ny)
    cells%x0 = lo(1); cells%y0 = lo(2)
    if (allocated(cells%head)) then
      if (size(cells%head) < cells%nx * cells%ny) deallocate(cells%head)
    end if
    if (.not. allocated(cells%head)) allocate(cells%head(cells%nx * cells%ny))
    if (allocated(cells%next)) then
      if (size(cells%next) < na) deallocate(cells%next)
    end if
    if (.not. allocated(cells%next)) allocate(cells%next(na))
    if (allocated(cells%cell)) then
      if (size(cells%cell) < na) deallocate(cells%cell)
    end if
    if (.not. allocated(cells%cell)) allocate(cells%cell(na))
    cells%head(1:cells%nx * cells%ny) = 0
    do i = na, 1, -1
      if (present(active)) then
        if (.not. active(i)) cycle
      end if
      c = cell_index(q(2*i), cells%y0, cells%side, cells%ny) * cells%nx + &
        cell_index(q(2*i-1), cells%x0, cells%side, cells%nx) + 1
      cells%cell(i) = c
      cells%next(i) = cells%head(c)
      cells%head(c) = i
    end do
  end subroutine bin_agents

  !> Whether a pair the contact set built by build_contacts(..., margin) left out could be
  !> needed: an agent pair (a, b) with gap <= need(a) + need(b) but > margin(a) + margin(b),
  !> or an agent-obstacle pair with gap <= need(a) but > 2 margin(a). need [n_agents] bounds
  !> how far each agent can close a gap in the step (h |u_a|). Only agents with need > margin
  !> can be in such a pair; their neighbours are searched in `cells` as built by that call
  !> (same positions q), over as many cells as the reach needs.
  logical function rows_missing(scene, q, radius, cells, margin, need) result(miss)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:), radius, margin(:), need(:)
    type(cell_list_t), intent(in) :: cells
    integer :: na, i, j, k, cx, cy, ix, iy, w
    real(wp) :: nmax, ext, reach, dx, dy, g(2), gap, dist, nrm(2)
    miss = .false.
    na = size(q) / 2
    if (na == 0) return
    nmax = maxval(need(1:na))
    ext = (cells%nx + cells%ny) * cells%side
    do i = 1, na
      if (.not. (need(i) > margin(i))) cycle
      ! agent pairs: every agent whose centre is within the reach, in the cells around i's
      ! (each need capped at the grid's extent, beyond which no neighbour lies: a huge need,
      ! as of a diverged velocity, overflows neither the reach nor the cell count)
      reach = 2 * radius + min(need(i), ext) + min(nmax, ext)
      w = 1
      if (reach > cells%side) w = int(min(real(max(cells%nx, cells%ny), wp), reach / cells%side + 1))
      cx = mod(cells%cell(i) - 1, cells%nx)
      cy = (cells%cell(i) - 1) / cells%nx
      do iy = max(cy - w, 0), min(cy + w, cells%ny - 1)
        do ix = max(cx - w, 0), min(cx + w, cells%nx - 1)
          j = cells%head(iy * cells%nx + ix + 1)
          do while (j > 0)
            if (j /= i) then
              dx = q(2*i-1) - q(2*j-1); dy = q(2*i) - q(2*j)
              if (abs(dx) <= reach .and. abs(dy) <= reach) then
                call pair_contact(dx, dy, radius, g, gap)
                if (gap <= min(need(i), ext) + min(need(j), ext) .and. gap > margin(i) + margin(j)) then
                  miss = .true.; return
                end if
              end if
            end if
            j = cells%next(j)
          end do
        end do
      end do
      ! agent-obstacle pairs
      if (.not. (need(i) > 2 * margin(i))) cycle
      do k = 1, scene%n_obstacles()
        if (q(2*i-1) < scene%lo(1, k) - radius - need(i) .or. q(2*i-1) > scene%hi(1, k) + radius + need(i)) cycle
        if (q(2*i) < scene%lo(2, k) - radius - need(i) .or. q(2*i) > scene%hi(2, k) + radius + need(i)) cycle
        call obstacle_distance(scene%obstacles(k), q(2*i-1:2*i), dist, nrm)
        gap = dist - radius
        if (gap <= need(i) .and. gap > 2 * margin(i)) then
          miss = .true.; return
        end if
      end do
    end do
  end function rows_missing

  !> The contact of two disks of radius `radius` whose centres differ by (dx, dy) = q_i - q_j:
  !> unit normal g (from j towards i; any unit normal for coincident centres) and gap.
  pure subroutine pair_contact(dx, dy, radius, g, gap)
    real(wp), intent(in) :: dx, dy, radius
    real(wp), intent(out) :: g(2), gap
    real(wp) :: dist
    dist = sqrt(dx * dx + dy * dy)
    if (dist > 0) then
      g = [dx, dy] / dist
    else
      g = [1.0_wp, 0.0_wp]   ! coincident centres: any unit normal
    end if
    gap = dist - 2 * radius
  end subroutine pair_contact

  !> Cell side >= side0 and grid nx x ny (nx ny <= max_cells) covering a box of half-extent
  !> half_ext [2] (finite, >= 0). Real arithmetic throughout; nx, ny <= max_cells.
  pure subroutine grid_size(half_ext, side0, max_cells, side, nx, ny)
    real(wp), intent(in) :: half_ext(2), side0, max_cells
    real(wp), intent(out) :: side
    integer, intent(out) :: nx, ny
    real(wp) :: hs, rx, ry
    ! half side; jump close to the final size at once (the grid of a huge box is coarse), then
    ! coarsen by factors 1.5 until the count fits
    hs = max(0.5_wp * side0, maxval(half_ext) / max_cells, sqrt(half_ext(1)) * sqrt(half_ext(2)) / sqrt(max_cells))
    do
      rx = real(floor(half_ext(1) / hs), wp) + 1
      ry = real(floor(half_ext(2) / hs), wp) + 1
      if (rx * ry <= max_cells) exit
      hs = hs * 1.5_wp
    end do
    side = 2 * hs
    nx = int(rx); ny = int(ry)
  end subroutine grid_size

  !> 0-based cell index of coordinate x on a grid of n cells of the given side from x0,
  !> clamped to 0..n-1 in real arithmetic (no integer overflow for any x; NaN gives 0).
  pure integer function cell_index(x, x0, side, n) result(c)
    real(wp), intent(in) :: x, x0, side
    integer, intent(in) :: n
    real(wp) :: t
    t = (0.5_wp * x - 0.5_wp * x0) / (0.5_wp * side)
    if (.not. ieee_is_finite(t)) t = 0   ! NaN coordinate (or Inf): cell 0
    t = min(max(t, 0.0_wp), real(n - 1, wp))
    c = int(t)
  end function cell_index
end module cr_neighbours
