!> Accuracy figures of a reduced trajectory (the paper's section 4) and the failure modes we
!> measure rather than hide: overlaps between agents (contacts outside the enforced set)
!> and agents that never leave (locking).
module cr_rom_metrics
  use cr_kinds, only: wp
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  implicit none
  private
  public :: position_errors, projection_error, max_overlap, agents_not_left

contains

  !> Relative position error per step err(nu) = |q - qr| / |q| (nu = 0..N_T) and the
  !> paper's time-integrated E_mu = sqrt(sum_nu h |q - qr|^2) / sqrt(sum_nu h |q|^2) over
  !> nu = 1..N_T (uniform h cancels). q, qr [n_dof, N_T + 1].
  subroutine position_errors(q, qr, err, e_mu)
    real(wp), intent(in) :: q(:,:), qr(:,:)
    real(wp), intent(out) :: err(:), e_mu
    real(wp) :: num, den, d2, n2
    integer :: nu
    num = 0; den = 0
    do nu = 1, size(q, 2)
      d2 = sum((q(:, nu) - qr(:, nu))**2)
      n2 = sum(q(:, nu)**2)
      err(nu) = sqrt(d2) / max(sqrt(n2), tiny(1.0_wp))
      if (nu > 1) then
        num = num + d2; den = den + n2
      end if
    end do
    e_mu = sqrt(num) / max(sqrt(den), tiny(1.0_wp))
  end subroutine position_errors

  !> Best-approximation error of the velocities u [n_dof, N_T] in the orthonormal basis
  !> v [n_dof, nb]: sqrt(sum |u - V V^T u|^2) / sqrt(sum |u|^2) (0 when u = 0).
  real(wp) function projection_error(u, v) result(e)
    real(wp), intent(in) :: u(:,:), v(:,:)
    real(wp) :: num, den
    integer :: nu
    num = 0; den = 0
    do nu = 1, size(u, 2)
      num = num + sum((u(:, nu) - matmul(v, matmul(u(:, nu), v)))**2)
      den = den + sum(u(:, nu)**2)
    end do
    e = 0
    if (den > 0) e = sqrt(num / den)
  end function projection_error

  !> Deepest overlap (largest -gap, agent-agent or agent-obstacle) over the configurations
  !> q [n_dof, n_conf]; 0 when nothing overlaps.
  real(wp) function max_overlap(scene, radius, q) result(o)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:,:)
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    integer :: nu, l
    o = 0
    call cs%init(size(q, 1) / 2, 1.0_wp, 4 * size(q, 1))
    do nu = 1, size(q, 2)
      call build_contacts(scene, q(:, nu), radius, 1.0e-12_wp * radius, cells, cs)
      do l = 1, cs%n
        o = max(o, -cs%gap(l))
      end do
    end do
  end function max_overlap

  !> Agents that have not left the hall at configuration q [n_dof].
  integer function agents_not_left(scene, radius, q) result(n)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:)
    integer :: i
    n = 0
    do i = 1, size(q) / 2
      if (q(2*i) <= scene%y_out(radius)) n = n + 1
    end do
  end function agents_not_left
end module cr_rom_metrics
