!> Candidate contacts of one step: agent pairs found with a uniform cell list, and
!> agent-obstacle pairs filtered by bounding boxes, each kept when its gap <= cutoff.
!>
!> Cost O(n_agents + n_cells + n_agents * n_obstacles_near): the cell grid covers the
!> bounding box of the agents with cells of side >= 2 r + cutoff, and is coarsened so that
!> it never has more than 4 n_agents + 64 cells.
module cr_neighbours
  use cr_kinds, only: wp
  use cr_contact_set, only: contact_set_t
  use cr_shapes, only: obstacle_distance
  use cr_scene, only: scene_t
  implicit none
  private
  public :: cell_list_t, build_contacts

  !> Linked-cell structure (reused across steps to avoid reallocation).
  type :: cell_list_t
    integer :: nx = 0, ny = 0
    real(wp) :: x0 = 0, y0 = 0, side = 1
    integer, allocatable :: head(:), next(:)
  end type cell_list_t

contains

  !> Fill `cs` (cleared first) with every agent pair and agent-obstacle pair whose gap is
  !> <= cutoff, at positions q [2*n_agents]. Agents with active(i) = .false. are skipped.
  subroutine build_contacts(scene, q, radius, cutoff, cells, cs, active)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:)
    real(wp), intent(in) :: radius, cutoff
    type(cell_list_t), intent(inout) :: cells
    type(contact_set_t), intent(inout) :: cs
    logical, intent(in), optional :: active(:)
    integer :: na, i, j, cx, cy, ix, iy, c, k
    real(wp) :: lo(2), hi(2), dx, dy, dist, gap, reach, g(2), nrm(2)
    logical :: use_i
    na = size(q) / 2
    call cs%clear()
    if (na == 0) return
    ! -- cell grid over the agents' bounding box
    lo = [huge(1.0_wp), huge(1.0_wp)]; hi = -lo
    do i = 1, na
      lo = min(lo, q(2*i-1:2*i)); hi = max(hi, q(2*i-1:2*i))
    end do
    cells%side = 2 * radius + cutoff
    cells%x0 = lo(1); cells%y0 = lo(2)
    do
      cells%nx = int((hi(1) - lo(1)) / cells%side) + 1
      cells%ny = int((hi(2) - lo(2)) / cells%side) + 1
      if (real(cells%nx, wp) * real(cells%ny, wp) <= real(4 * na + 64, wp)) exit
      cells%side = cells%side * 1.5_wp
    end do
    if (allocated(cells%head)) then
      if (size(cells%head) < cells%nx * cells%ny) deallocate(cells%head)
    end if
    if (.not. allocated(cells%head)) allocate(cells%head(cells%nx * cells%ny))
    if (allocated(cells%next)) then
      if (size(cells%next) < na) deallocate(cells%next)
    end if
    if (.not. allocated(cells%next)) allocate(cells%next(na))
    cells%head(1:cells%nx * cells%ny) = 0
    do i = na, 1, -1
      if (present(active)) then
        if (.not. active(i)) cycle
      end if
      c = cell_of(i)
      cells%next(i) = cells%head(c)
      cells%head(c) = i
    end do
    ! -- agent pairs
    reach = 2 * radius + cutoff
    do i = 1, na
      use_i = .true.
      if (present(active)) use_i = active(i)
      if (.not. use_i) cycle
      cx = min(int((q(2*i-1) - cells%x0) / cells%side), cells%nx - 1)
      cy = min(int((q(2*i) - cells%y0) / cells%side), cells%ny - 1)
      do iy = max(cy - 1, 0), min(cy + 1, cells%ny - 1)
        do ix = max(cx - 1, 0), min(cx + 1, cells%nx - 1)
          j = cells%head(iy * cells%nx + ix + 1)
          do while (j > 0)
            if (j > i) then
              dx = q(2*i-1) - q(2*j-1); dy = q(2*i) - q(2*j)
              if (abs(dx) <= reach .and. abs(dy) <= reach) then
                dist = sqrt(dx * dx + dy * dy)
                if (dist - 2 * radius <= cutoff) then
                  if (dist > 0) then
                    g = [dx, dy] / dist
                  else
                    g = [1.0_wp, 0.0_wp]   ! coincident centres: any unit normal
                  end if
                  call cs%add(i, j, 0, g, dist - 2 * radius)
                end if
              end if
            end if
            j = cells%next(j)
          end do
        end do
      end do
    end do
    ! -- agent-obstacle pairs
    do i = 1, na
      if (present(active)) then
        if (.not. active(i)) cycle
      end if
      do k = 1, scene%n_obstacles()
        if (q(2*i-1) < scene%lo(1, k) - radius - cutoff .or. q(2*i-1) > scene%hi(1, k) + radius + cutoff) cycle
        if (q(2*i) < scene%lo(2, k) - radius - cutoff .or. q(2*i) > scene%hi(2, k) + radius + cutoff) cycle
        call obstacle_distance(scene%obstacles(k), q(2*i-1:2*i), dist, nrm)
        gap = dist - radius
        if (gap <= cutoff) call cs%add(i, 0, k, nrm, gap)
      end do
    end do

  contains

    pure integer function cell_of(a)
      integer, intent(in) :: a
      integer :: ax, ay
      ax = min(int((q(2*a-1) - cells%x0) / cells%side), cells%nx - 1)
      ay = min(int((q(2*a) - cells%y0) / cells%side), cells%ny - 1)
      cell_of = ay * cells%nx + ax + 1
    end function cell_of
  end subroutine build_contacts
end module cr_neighbours
