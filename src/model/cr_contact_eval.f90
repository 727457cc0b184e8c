!> Contact rows of a *given* list of contacts (e.g. the global contact dictionary of a
!> snapshot database, or the contacts selected for a reduced model) at positions q:
!> gap D_l(q) and unit normal g_l(q), as rows of a contact_set_t (B = -h G, d = D).
!> No neighbour search: the list decides which rows exist.
module cr_contact_eval
  use cr_kinds, only: wp
  use cr_contact_set, only: contact_set_t
  use cr_scene, only: scene_t
  use cr_shapes, only: obstacle_distance
  implicit none
  private
  public :: eval_contacts, eval_contact

contains

  !> Gap and unit normal of contact (ia, ib, ob) at q [2*n_agents].
  pure subroutine eval_contact(scene, q, radius, ia, ib, ob, gap, g)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:)
    real(wp), intent(in) :: radius
    integer, intent(in) :: ia, ib, ob
    real(wp), intent(out) :: gap, g(2)
    real(wp) :: d(2), dist
    if (ib > 0) then
      d = q(2*ia-1:2*ia) - q(2*ib-1:2*ib)
      dist = norm2(d)
      if (dist > 0) then
        g = d / dist
      else
        g = [1.0_wp, 0.0_wp]
      end if
      gap = dist - 2 * radius
    else
      call obstacle_distance(scene%obstacles(ob), q(2*ia-1:2*ia), dist, g)
      gap = dist - radius
    end if
  end subroutine eval_contact

  !> Fill cs (cleared) with the rows of contacts (ia(k), ib(k), ob(k)), k = 1..size(ia), at q.
  subroutine eval_contacts(scene, q, radius, h, ia, ib, ob, cs)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:)
    real(wp), intent(in) :: radius, h
    integer, intent(in) :: ia(:), ib(:), ob(:)
    type(contact_set_t), intent(inout) :: cs
    real(wp) :: gap, g(2)
    integer :: k
    if (.not. allocated(cs%ia)) call cs%init(size(q) / 2, h, size(ia))
    cs%n_agents = size(q) / 2
    cs%h = h
    call cs%clear()
    do k = 1, size(ia)
      call eval_contact(scene, q, radius, ia(k), ib(k), ob(k), gap, g)
      call cs%add(ia(k), ib(k), ob(k), g, gap)
    end do
  end subroutine eval_contacts
end module cr_contact_eval
