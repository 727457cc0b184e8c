!> Shared helpers of the solver tests: seeding the Fortran random generator, a random
!> feasible disk scene (jittered lattice) with its contact rows and a desired velocity; for
!> the tests of the projections in a hall (position projection, local correction): agents on
!> a jittered lattice, the smallest true gap of a configuration and the full model's
!> projection with every agent free.
module cr_test_scenes
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_contact_set, only: contact_set_t
  use cr_scene, only: scene_t
  use cr_shapes, only: obstacle_distance
  use cr_neighbours, only: cell_list_t, build_contacts
  use cr_projection, only: projection_settings_t, projection_solver_t, solve_stats_t, &
    make_projection_solver
  implicit none
  private
  public :: seed_random, lattice_scene, hex_scene, hall_lattice, min_true_gap, full_projection

contains

  !> Make random_number reproducible.
  subroutine seed_random(value)
    integer, intent(in) :: value
    integer :: n
    integer, allocatable :: s(:)
    call random_seed(size=n)
    allocate(s(n)); s = value
    call random_seed(put=s)
  end subroutine seed_random

  !> nx x ny disks of radius rad on a jittered lattice (gaps 2e-3 .. 6e-3), every pair with
  !> gap < cutoff as a row (step h), n_obs random obstacle rows with gaps in [0, 5e-3), and a
  !> desired velocity towards the centre plus noise. With near_touch, agents 1 and 2 are
  !> moved to a gap of 1e-7 (if that overlaps nobody).
  subroutine lattice_scene(nx, ny, n_obs, cutoff, rad, h, cs, v, near_touch)
    integer, intent(in) :: nx, ny, n_obs
    real(wp), intent(in) :: cutoff, rad, h
    type(contact_set_t), intent(out) :: cs
    real(wp), allocatable, intent(out) :: v(:)
    logical, intent(in), optional :: near_touch
    real(wp), allocatable :: q(:,:), jit(:,:), nz(:)
    real(wp) :: dx, c(2), dist, gap, ang, r(2), qold(2)
    integer :: na, i, j, k
    na = nx * ny
    dx = 2.0_wp * rad + 0.004_wp
    allocate(q(2, na), jit(2, na), nz(2 * na))
    call random_number(jit)
    do j = 1, ny
      do i = 1, nx
        k = i + (j - 1) * nx
        q(:, k) = [i * dx, j * dx] + 0.002_wp * (jit(:, k) - 0.5_wp)
      end do
    end do
    if (present(near_touch)) then
      if (near_touch .and. na >= 2) then
        qold = q(:, 2)
        q(:, 2) = q(:, 1) + (2.0_wp * rad + 1.0e-7_wp) * (q(:, 2) - q(:, 1)) / norm2(q(:, 2) - q(:, 1))
        do k = 3, na
          if (norm2(q(:, 2) - q(:, k)) < 2.0_wp * rad) q(:, 2) = qold
        end do
      end if
    end if
    call cs%init(na, h, 4 * na)
    do i = 1, na
      do j = i + 1, na
        dist = norm2(q(:, i) - q(:, j))
        gap = dist - 2.0_wp * rad
        if (gap < cutoff) call cs%add(i, j, 0, (q(:, i) - q(:, j)) / dist, gap)
      end do
    end do
    do k = 1, n_obs
      call random_number(r)
      i = 1 + int(r(1) * na)
      ang = 8.0_wp * atan(1.0_wp) * r(2)
      call random_number(gap)
      call cs%add(i, 0, k, [cos(ang), sin(ang)], 0.005_wp * gap)
    end do
    c = sum(q, dim=2) / na
    call random_number(nz)
    allocate(v(2 * na))
    do k = 1, na
      v(2*k - 1:2*k) = -(q(:, k) - c) / max(norm2(q(:, k) - c), 1.0e-3_wp) + (nz(2*k - 1:2*k) - 0.5_wp)
    end do
  end subroutine lattice_scene

  !> nx x ny disks of radius rad in hexagonal packing (touching neighbours, plus jitter) resting
  !> on the wall y = 0 and against the wall x = 0, every pair closer than 1e-3 a row (3 per
  !> agent: many linearly dependent rows), step h; v pushes into the corner, plus noise.
  subroutine hex_scene(nx, ny, jitter, rad, h, cs, v)
    integer, intent(in) :: nx, ny
    real(wp), intent(in) :: jitter, rad, h
    type(contact_set_t), intent(out) :: cs
    real(wp), allocatable, intent(out) :: v(:)
    real(wp), allocatable :: q(:,:), jit(:,:), nz(:)
    real(wp) :: dist
    integer :: na, i, j, k
    na = nx * ny
    allocate(q(2, na), jit(2, na), nz(2 * na))
    call random_number(jit)
    do j = 1, ny
      do i = 1, nx
        k = i + (j - 1) * nx
        q(:, k) = [rad + 2.0_wp * rad * (i - 1) + rad * mod(j - 1, 2), &
          rad + sqrt(3.0_wp) * rad * (j - 1)] + jitter * (jit(:, k) - 0.5_wp)
      end do
    end do
    call cs%init(na, h, 4 * na)
    do i = 1, na
      do j = i + 1, na
        dist = norm2(q(:, i) - q(:, j))
        if (dist - 2.0_wp * rad < 1.0e-3_wp) call cs%add(i, j, 0, (q(:, i) - q(:, j)) / dist, &
          dist - 2.0_wp * rad)
      end do
      if (q(2, i) - rad < 1.0e-3_wp) call cs%add(i, 0, 1, [0.0_wp, 1.0_wp], q(2, i) - rad)
      if (q(1, i) - rad < 1.0e-3_wp) call cs%add(i, 0, 2, [1.0_wp, 0.0_wp], q(1, i) - rad)
    end do
    call random_number(nz)
    allocate(v(2 * na))
    do k = 1, na
      v(2*k - 1:2*k) = [-0.5_wp, -1.0_wp] + 0.6_wp * (nz(2*k - 1:2*k) - 0.5_wp)
    end do
  end subroutine hex_scene

  !> Agents on an nx x ny lattice, spacing dx, the first at (x0, x0), each coordinate jittered
  !> by +-jit/2 (random_number): q [2 nx ny].
  subroutine hall_lattice(nx, ny, x0, dx, jit, q)
    integer, intent(in) :: nx, ny
    real(wp), intent(in) :: x0, dx, jit
    real(wp), allocatable, intent(out) :: q(:)
    real(wp), allocatable :: r(:)
    integer :: i, j, a
    allocate(q(2 * nx * ny), r(2 * nx * ny))
    call random_number(r)
    do j = 1, ny
      do i = 1, nx
        a = i + (j - 1) * nx
        q(2*a-1) = x0 + (i - 1) * dx + jit * (r(2*a-1) - 0.5_wp)
        q(2*a) = x0 + (j - 1) * dx + jit * (r(2*a) - 0.5_wp)
      end do
    end do
  end subroutine hall_lattice

  !> Smallest true gap at positions q [2 n_a] of disks of radius rad in scene: every agent pair
  !> and every agent-obstacle pair (O(n_a^2), for tests).
  real(wp) function min_true_gap(scene, rad, q) result(gmin)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: rad, q(:)
    integer :: i, j, k
    real(wp) :: dist, nrm(2)
    gmin = huge(1.0_wp)
    do i = 1, size(q) / 2
      do j = i + 1, size(q) / 2
        gmin = min(gmin, norm2(q(2*i-1:2*i) - q(2*j-1:2*j)) - 2 * rad)
      end do
      do k = 1, scene%n_obstacles()
        call obstacle_distance(scene%obstacles(k), q(2*i-1:2*i), dist, nrm)
        gmin = min(gmin, dist - rad)
      end do
    end do
  end function min_true_gap

  !> The full model's projection with every agent free, the reference of the local ones:
  !> u [2 n_a] = argmin |u - w|^2 s.t. every row of the step h whose gap at q [2 n_a] is within
  !> cutoff holds (disks of radius rad in scene), by the solver of `settings`; st its
  !> statistics, n_rows the number of rows.
  subroutine full_projection(scene, settings, q, rad, h, cutoff, w, u, st, n_rows, error)
    type(scene_t), intent(in) :: scene
    type(projection_settings_t), intent(in) :: settings
    real(wp), intent(in) :: q(:), rad, h, cutoff, w(:)
    real(wp), intent(out) :: u(:)
    type(solve_stats_t), intent(out) :: st
    integer, intent(out) :: n_rows
    type(error_t), allocatable, intent(out) :: error
    class(projection_solver_t), allocatable :: solver
    type(contact_set_t) :: cs
    type(cell_list_t) :: cells
    real(wp), allocatable :: lambda(:)
    call make_projection_solver(settings, solver, error)
    if (allocated(error)) return
    call cs%init(size(q) / 2, h)
    call build_contacts(scene, q, rad, cutoff, cells, cs)
    n_rows = cs%n
    allocate(lambda(cs%n))
    lambda = 0
    call solver%solve(cs, w, u, lambda, st, error)
    call solver%free()
  end subroutine full_projection
end module cr_test_scenes
