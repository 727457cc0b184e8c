!> Divergence guard of a reduced trajectory: a reduced model can produce coefficients that
!> send agents kilometres away (an EIM-interpolated constraint that is nearly zero but asks
!> for a negative gap, docs/model.md#eim-rows-with-unit-normals), or non-finite values. The
!> guard decides, once per step and cheaply, whether the trajectory is still physical; the
!> stepper stops at the first step that is not, and the sweep reports the sample as diverged.
!>
!> The sane region is the hall's outer box [-t, L + t] x [-t, H + t] (walls of thickness t)
!> inflated by margin = D + 2 c_max T, D the diagonal of that box, c_max the largest agent
!> speed and T = h n_steps the horizon: a full-order agent stays in the hall or walks out
!> of the exit at speed <= c_max, and the reduced velocity is at most twice as fast
!> (|alpha| <= 2 |vhat| <= 2 |v| when the constraints admit 0), so no agent of a sane
!> trajectory can leave it. A step is diverged when
!>   (1) a coefficient alpha or a position the step computed is not finite, or
!>   (2) a position the step computed (the agents the assembly reads) is outside the region, or
!>   (3) h |sum alpha|_2 > sqrt(n_agents) * diam(region): as V has orthonormal columns,
!>       |q - q0|_2 = h |sum alpha|_2, so some agent then moved farther than the region's
!>       diameter from a start inside it (this covers the agents the assembly does not read
!>       at O(nb) cost).
!> `first_outside` applies (1)-(2) to whole stored trajectories, agent by agent, so that the
!> step at which the first agent leaves is exact even when the assembly reads few agents.
module cr_rom_guard
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_scene, only: scene_t
  implicit none
  private
  public :: rom_guard_t

  !> The sane region and the coefficient bound of one sample.
  type :: rom_guard_t
    !> region [x_min, x_max] x [y_min, y_max]
    real(wp) :: lo(2) = 0, hi(2) = 0
    !> bound of h |sum alpha|_2 (criterion 3)
    real(wp) :: acc_bound = huge(1.0_wp)
    logical :: active = .false.
  contains
    procedure :: init => guard_init
    procedure :: coeffs_ok => guard_coeffs_ok
    procedure :: agents_ok => guard_agents_ok
    procedure :: inside => guard_inside
    procedure :: first_outside => guard_first_outside
  end type rom_guard_t

contains

  !> Region of a sample: scene, largest speed c_max, horizon t_end = h n_steps, n_agents.
  subroutine guard_init(this, scene, c_max, t_end, n_agents)
    class(rom_guard_t), intent(out) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: c_max, t_end
    integer, intent(in) :: n_agents
    real(wp) :: diag, margin
    this%lo = [-scene%wall, -scene%wall]
    this%hi = [scene%length + scene%wall, scene%width + scene%wall]
    diag = norm2(this%hi - this%lo)
    margin = diag + 2 * abs(c_max) * abs(t_end)
    this%lo = this%lo - margin
    this%hi = this%hi + margin
    this%acc_bound = sqrt(real(max(n_agents, 1), wp)) * norm2(this%hi - this%lo)
    this%active = .true.
  end subroutine guard_init

  !> Position p [2] inside the region (false for non-finite p).
  pure logical function guard_inside(this, p) result(ok)
    class(rom_guard_t), intent(in) :: this
    real(wp), intent(in) :: p(2)
    ok = all(ieee_is_finite(p))   ! first: an ordered comparison with NaN would trap
    if (ok) ok = all(p >= this%lo) .and. all(p <= this%hi)
  end function guard_inside

  !> Coefficients of one step: alpha [nb] finite and the running sum acc [nb] within the
  !> bound (criterion 3) for the step h. Cost O(nb).
  pure logical function guard_coeffs_ok(this, alpha, acc, h) result(ok)
    class(rom_guard_t), intent(in) :: this
    real(wp), intent(in) :: alpha(:), acc(:), h
    ok = .true.
    if (.not. this%active) return
    ok = all(ieee_is_finite(alpha)) .and. all(ieee_is_finite(acc))
    if (ok) ok = h * norm2(acc) <= this%acc_bound
  end function guard_coeffs_ok

  !> Positions q [n_dof], valid for `agents` (those the assembly reads), all inside the
  !> region. Cost O(size(agents)).
  pure logical function guard_agents_ok(this, q, agents) result(ok)
    class(rom_guard_t), intent(in) :: this
    real(wp), intent(in) :: q(:)
    integer, intent(in) :: agents(:)
    integer :: j, a
    ok = .true.
    if (.not. this%active) return
    do j = 1, size(agents)
      a = agents(j)
      if (.not. this%inside(q(2*a-1:2*a))) then
        ok = .false.; return
      end if
    end do
  end function guard_agents_ok

  !> First column nu of q [n_dof, n_conf] with a non-finite position or an agent outside
  !> the region (0 when none).
  pure integer function guard_first_outside(this, q) result(nu_bad)
    class(rom_guard_t), intent(in) :: this
    real(wp), intent(in) :: q(:,:)
    integer :: nu, i
    nu_bad = 0
    if (.not. this%active) return
    do nu = 1, size(q, 2)
      do i = 1, size(q, 1) / 2
        if (.not. this%inside(q(2*i-1:2*i, nu))) then
          nu_bad = nu; return
        end if
      end do
    end do
  end function guard_first_outside
end module cr_rom_guard
