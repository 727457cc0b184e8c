!> Geodesic distance to a target set in a 2D box with convex obstacles, and the desired
!> direction of the agents (steepest descent of that distance).
!>
!> The eikonal equation |grad T| = 1 is solved on a uniform node grid by the fast sweeping
!> method (Godunov upwind update on the axis and diagonal stencils, Gauss-Seidel with 4 axis-aligned and 4 diagonal orderings per cycle, repeated until
!> the largest change in a cycle is below a tolerance). A node is blocked when its distance to
!> some obstacle is < clearance; blocked nodes and the outside of the box are impassable.
!>
!> Initialisation: every unblocked node within `init_radius` (>= sqrt(2) dx, default 0.1 times
!> the smaller box side) of a target set, whose straight segment to the closest target point
!> keeps at least `clearance` from every obstacle (exact line-of-sight test), gets the exact
!> Euclidean distance to that set (0 on it) and is frozen. A dx-independent radius removes the
!> O(dx log(1/dx)) error of first-order schemes at point-like sources (target endpoints), so the
!> error away from obstacles is O(dx). Nodes near a target that are not in sight are swept.
!>
!> Accuracy (tests/unit/test_distance_field.f90): without obstacles the nodal error is about 0.4 dx
!> and halves with dx; next to curved obstacles the blocked-node staircase dominates (about
!> 3 dx at dx = 0.01 just behind a disk, converging like dx^0.6); a cut-cell boundary would fix it.
!>
!> Cost: memory 9 bytes per node (T in real(wp), one byte of state). Building: blocking costs
!> O(sum over obstacles of the nodes in its bounding box (inflated by clearance) x cost of one
!> distance), then each sweeping cycle costs O(n_nodes); the number of cycles depends on how
!> often the characteristics turn around obstacles (a few for simple rooms), not on dx.
!> Queries (`value`, `direction`) are O(1): at most the 16 nodes around the point are read.
module cr_distance_field
  use, intrinsic :: iso_fortran_env, only: int8
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_shapes, only: obstacle_t, obstacle_distance, obstacle_bbox, segment_obstacle_distance
  use cr_exit_codes, only: EXIT_FAILURE, EXIT_BAD_INPUT
  implicit none
  private
  public :: distance_field_t, NODE_FREE, NODE_TARGET, NODE_BLOCKED

  !> node state: free node, updated by the sweeps
  integer(int8), parameter :: NODE_FREE = 0_int8
  !> node state: initialised from the exact distance to a target, frozen
  integer(int8), parameter :: NODE_TARGET = 1_int8
  !> node state: closer than `clearance` to an obstacle, impassable (T = huge)
  integer(int8), parameter :: NODE_BLOCKED = 2_int8

  !> value of T at blocked and unreachable nodes
  real(wp), parameter :: t_inf = huge(1.0_wp)
  !> maximum number of sweeping cycles (8 sweeps each)
  integer, parameter :: max_cycles = 2000

  !> Geodesic distance field on the node grid x_ij = lo + ((i-1) dx, (j-1) dx).
  type :: distance_field_t
    !> lower-left node of the grid
    real(wp) :: lo(2) = 0.0_wp
    !> grid spacing (both directions)
    real(wp) :: dx = 0.0_wp
    !> number of nodes per direction; the grid covers [lo, lo + (n-1) dx] which contains [lo, hi]
    integer :: n(2) = 0
    !> geodesic distance at the nodes, t_inf where blocked or unreachable: [n(1), n(2)]
    real(wp), allocatable :: t(:,:)
    !> node state (NODE_FREE, NODE_TARGET, NODE_BLOCKED): [n(1), n(2)]
    integer(int8), allocatable :: state(:,:)
    !> number of sweeping cycles used by init
    integer :: n_cycles = 0
  contains
    !> build the field (blocking, target initialisation, fast sweeping)
    procedure :: init
    !> release the arrays
    procedure :: free
    !> interpolated geodesic distance at a point (huge if unreachable)
    procedure :: value
    !> unit descent direction -grad T at a point
    procedure :: direction
    !> position of node (i, j)
    procedure :: node_position
    !> .true. if node (i, j) is unblocked and reachable
    procedure :: node_valid
  end type distance_field_t

contains

  !> Build the field on the box [lo, hi] with spacing dx.
  !> obstacles: convex obstacles (impassable where distance < clearance);
  !> clearance: typically agent radius - 1.5 dx, so that every node of the cell containing a
  !> feasible agent centre is unblocked (may be <= 0);
  !> targets: target sets (e.g. exit segments of zero thickness), at least one;
  !> init_radius: radius of the exact initialisation around the targets (see module doc).
  subroutine init(this, lo, hi, dx, obstacles, clearance, targets, error, init_radius)
    class(distance_field_t), intent(inout) :: this
    real(wp), intent(in) :: lo(2), hi(2), dx
    type(obstacle_t), intent(in) :: obstacles(:)
    real(wp), intent(in) :: clearance
    type(obstacle_t), intent(in) :: targets(:)
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(in), optional :: init_radius
    real(wp) :: nreal(2), band, tol, change, d, nrm(2), p(2)
    integer :: k, i, j, m, ilo(2), ihi(2), n_target_nodes
    logical :: visible
    character(len=*), parameter :: ctx = "distance_field%init: "

    call this%free()
    if (.not. (all(ieee_is_finite(lo)) .and. all(ieee_is_finite(hi)) .and. ieee_is_finite(dx) &
        .and. ieee_is_finite(clearance))) then
      call set_error(error, ctx // "lo, hi, dx and clearance must be finite", EXIT_BAD_INPUT)
      return
    end if
    if (dx <= 0.0_wp) then
      call set_error(error, ctx // "dx must be > 0, got " // str(dx), EXIT_BAD_INPUT)
      return
    end if
    if (.not. all(hi > lo)) then
      call set_error(error, ctx // "need lo < hi, got lo = (" // str(lo(1)) // ", " // str(lo(2)) &
          // ") hi = (" // str(hi(1)) // ", " // str(hi(2)) // ")", EXIT_BAD_INPUT)
      return
    end if
    if (size(targets) == 0) then
      call set_error(error, ctx // "no target set given", EXIT_BAD_INPUT)
      return
    end if
    do k = 1, size(obstacles)
      if (obstacles(k)%kind == 0) then
        call set_error(error, ctx // "obstacle " // str(k) // " was not built", EXIT_BAD_INPUT)
        return
      end if
    end do
    do k = 1, size(targets)
      if (targets(k)%kind == 0) then
        call set_error(error, ctx // "target " // str(k) // " was not built", EXIT_BAD_INPUT)
        return
      end if
    end do
    nreal = (hi - lo) / dx
    if (any(nreal > 1.0e5_wp) .or. product(nreal + 1.0_wp) > 2.0e8_wp) then
      call set_error(error, ctx // "grid too large: " // str(nreal(1), "es10.3") // " x " &
          // str(nreal(2), "es10.3") // " cells for dx = " // str(dx), EXIT_BAD_INPUT)
      return
    end if
    this%lo = lo
    this%dx = dx
    ! smallest node count covering [lo, hi] (tolerant to round-off in (hi - lo) / dx)
    this%n = max(2, ceiling(nreal * (1.0_wp - 1.0e-12_wp)) + 1)
    allocate(this%t(this%n(1), this%n(2)), source=t_inf)
    allocate(this%state(this%n(1), this%n(2)), source=NODE_FREE)

    ! blocked nodes: only the nodes in each obstacle's bounding box inflated by the clearance
    do k = 1, size(obstacles)
      call node_range(this, obstacles(k), max(clearance, 0.0_wp), ilo, ihi)
      do j = ilo(2), ihi(2)
        do i = ilo(1), ihi(1)
          if (this%state(i, j) == NODE_BLOCKED) cycle
          call obstacle_distance(obstacles(k), this%node_position(i, j), d, nrm)
          if (d < clearance) this%state(i, j) = NODE_BLOCKED
        end do
      end do
    end do

    ! target nodes: exact Euclidean distance within init_radius, where the target is in sight
    band = 0.1_wp * minval(hi - lo)
    if (present(init_radius)) band = init_radius
    if (.not. ieee_is_finite(band)) band = 2.0_wp * maxval(real(this%n, wp) * dx)
    band = max(band, sqrt(2.0_wp) * dx)
    n_target_nodes = 0
    do k = 1, size(targets)
      call node_range(this, targets(k), band, ilo, ihi)
      do j = ilo(2), ihi(2)
        do i = ilo(1), ihi(1)
          if (this%state(i, j) == NODE_BLOCKED) cycle
          p = this%node_position(i, j)
          call obstacle_distance(targets(k), p, d, nrm)
          if (d > band) cycle
          if (d > 0.0_wp) then
            ! line of sight from the node to its closest target point p - d * nrm
            visible = .true.
            do m = 1, size(obstacles)
              associate (sd => segment_obstacle_distance(obstacles(m), p, p - d * nrm))
                visible = .not. (sd < clearance .or. sd <= 0.0_wp)
              end associate
              if (.not. visible) exit
            end do
            if (.not. visible) cycle
          end if
          if (this%state(i, j) /= NODE_TARGET) n_target_nodes = n_target_nodes + 1
          this%state(i, j) = NODE_TARGET
          this%t(i, j) = min(this%t(i, j), max(d, 0.0_wp))
        end do
      end do
    end do
    if (n_target_nodes == 0) then
      call set_error(error, ctx // "no unblocked grid node in sight within " // str(band) &
          // " of any target (targets outside the grid or inside obstacles?)", EXIT_BAD_INPUT)
      return
    end if

    ! fast sweeping: 4 orderings per cycle until the largest decrease is below tol
    tol = 1.0e-10_wp * dx
    do k = 1, max_cycles
      change = 0.0_wp
      do m = 1, 8
        ! orderings: 4 axis-aligned, then 4 along the diagonals; (di, dj) = (+,+), (-,+), (-,-), (+,-)
        call sweep(this%t, this%state, dx, m > 4, merge(1, -1, modulo(m - 1, 4) == 0 .or. modulo(m - 1, 4) == 3), &
            merge(1, -1, modulo(m - 1, 4) <= 1), change)
      end do
      this%n_cycles = k
      if (change <= tol) return
    end do
    call set_error(error, ctx // "fast sweeping did not converge in " // str(max_cycles) &
        // " cycles (last change " // str(change) // ")", EXIT_FAILURE)
  end subroutine init

  !> Node index range [ilo, ihi] covering the bounding box of obst inflated by margin (may be empty).
  pure subroutine node_range(this, obst, margin, ilo, ihi)
    class(distance_field_t), intent(in) :: this
    type(obstacle_t), intent(in) :: obst
    real(wp), intent(in) :: margin
    integer, intent(out) :: ilo(2), ihi(2)
    real(wp) :: blo(2), bhi(2), xl(2), xh(2)
    call obstacle_bbox(obst, blo, bhi)
    ! clamp in real arithmetic before converting, so far-away boxes cannot overflow integers
    xl = min(max((blo - margin - this%lo) / this%dx, -1.0_wp), real(this%n, wp) + 1.0_wp)
    xh = min(max((bhi + margin - this%lo) / this%dx, -1.0_wp), real(this%n, wp) + 1.0_wp)
    ilo = max(1, floor(xl) + 1)
    ihi = min(this%n, ceiling(xh) + 1)
  end subroutine node_range

  !> One Gauss-Seidel sweep over all nodes. Axis orderings (rotated = .false.): j from j0 to j1
  !> step dj (outer), i from i0 to i1 step di (inner). Rotated orderings (rotated = .true.):
  !> anti-diagonals u = i + j in order dj (outer, +1 or -1), i in order di along each (inner);
  !> they serve the diagonal stencil as the axis orderings serve the axis stencil.
  !> change: running maximum of the decreases of T.
  pure subroutine sweep(t, state, h, rotated, di, dj, change)
    real(wp), intent(inout) :: t(:,:)
    integer(int8), intent(in) :: state(:,:)
    real(wp), intent(in) :: h
    logical, intent(in) :: rotated
    integer, intent(in) :: di, dj
    real(wp), intent(inout) :: change
    integer :: i, j, u, n1, n2, ia, ib, ja, jb, ua, ub
    n1 = size(t, 1)
    n2 = size(t, 2)
    if (.not. rotated) then
      call order(1, n1, di, ia, ib)
      call order(1, n2, dj, ja, jb)
      do j = ja, jb, dj
        do i = ia, ib, di
          if (state(i, j) == NODE_FREE) call relax(t, state, h, i, j, change)
        end do
      end do
    else
      call order(2, n1 + n2, dj, ua, ub)
      do u = ua, ub, dj
        call order(max(1, u - n2), min(n1, u - 1), di, ia, ib)
        do i = ia, ib, di
          j = u - i
          if (state(i, j) == NODE_FREE) call relax(t, state, h, i, j, change)
        end do
      end do
    end if
  contains
    pure subroutine order(first, last, step, from, to)
      integer, intent(in) :: first, last, step
      integer, intent(out) :: from, to
      if (step > 0) then
        from = first
        to = last
      else
        from = last
        to = first
      end if
    end subroutine order
  end subroutine sweep

  !> Update of free node (i, j): the smaller of the Godunov upwind solutions on the axis stencil
  !> (spacing h) and on the diagonal stencil (spacing sqrt(2) h), both exact for plane fronts;
  !> the diagonal one keeps first-order accuracy along the staircase of blocked nodes. A
  !> diagonal neighbour is used only if one of the two axis nodes between them is unblocked
  !> (no leak through one-node-thick walls). change: running maximum of the decreases of T.
  pure subroutine relax(t, state, h, i, j, change)
    real(wp), intent(inout) :: t(:,:)
    integer(int8), intent(in) :: state(:,:)
    real(wp), intent(in) :: h
    integer, intent(in) :: i, j
    real(wp), intent(inout) :: change
    integer :: n1, n2
    real(wp) :: a, b, tn
    n1 = size(t, 1)
    n2 = size(t, 2)
    ! axis stencil
    a = t_inf
    if (i > 1) a = t(i - 1, j)
    if (i < n1) a = min(a, t(i + 1, j))
    b = t_inf
    if (j > 1) b = t(i, j - 1)
    if (j < n2) b = min(b, t(i, j + 1))
    tn = godunov(a, b, h)
    ! diagonal stencil: directions (1,1) and (1,-1)
    a = t_inf
    if (i > 1 .and. j > 1) then
      if (state(i - 1, j) /= NODE_BLOCKED .or. state(i, j - 1) /= NODE_BLOCKED) a = t(i - 1, j - 1)
    end if
    if (i < n1 .and. j < n2) then
      if (state(i + 1, j) /= NODE_BLOCKED .or. state(i, j + 1) /= NODE_BLOCKED) a = min(a, t(i + 1, j + 1))
    end if
    b = t_inf
    if (i > 1 .and. j < n2) then
      if (state(i - 1, j) /= NODE_BLOCKED .or. state(i, j + 1) /= NODE_BLOCKED) b = t(i - 1, j + 1)
    end if
    if (i < n1 .and. j > 1) then
      if (state(i + 1, j) /= NODE_BLOCKED .or. state(i, j - 1) /= NODE_BLOCKED) b = min(b, t(i + 1, j - 1))
    end if
    tn = min(tn, godunov(a, b, sqrt(2.0_wp) * h))
    if (tn < t(i, j)) then
      change = max(change, t(i, j) - tn)
      t(i, j) = tn
    end if
  end subroutine relax

  !> Godunov upwind solution of (T - a)_+^2 + (T - b)_+^2 = h^2 (t_inf if a = b = t_inf).
  elemental function godunov(a, b, h) result(tn)
    real(wp), intent(in) :: a, b, h
    real(wp) :: tn
    if (min(a, b) >= t_inf) then
      tn = t_inf
    else if (abs(a - b) >= h) then
      tn = min(a, b) + h
    else
      tn = 0.5_wp * (a + b + sqrt(2.0_wp * h * h - (a - b)**2))
    end if
  end function godunov

  !> Release the arrays.
  subroutine free(this)
    class(distance_field_t), intent(inout) :: this
    if (allocated(this%t)) deallocate(this%t)
    if (allocated(this%state)) deallocate(this%state)
    this%n = 0
    this%n_cycles = 0
  end subroutine free

  !> Position of node (i, j).
  pure function node_position(this, i, j) result(p)
    class(distance_field_t), intent(in) :: this
    integer, intent(in) :: i, j
    real(wp) :: p(2)
    p = this%lo + this%dx * real([i - 1, j - 1], wp)
  end function node_position

  !> .true. if node (i, j) exists, is unblocked and has a finite distance.
  pure logical function node_valid(this, i, j)
    class(distance_field_t), intent(in) :: this
    integer, intent(in) :: i, j
    node_valid = .false.
    if (i < 1 .or. j < 1 .or. i > this%n(1) .or. j > this%n(2)) return
    node_valid = this%state(i, j) /= NODE_BLOCKED .and. this%t(i, j) < t_inf
  end function node_valid

  !> Local model of T around p: value and gradient.
  !> If the 4 nodes of the cell containing p are valid: bilinear interpolant and its gradient.
  !> Otherwise: weighted least-squares plane through the valid nodes of the 4 x 4 nodes around
  !> the cell. has_grad = .false. when no plane can be fitted (val is then the smallest
  !> "T(node) + |node - p|" over valid nodes, or huge if there is none, or p is off the grid).
  pure subroutine local_model(this, p, val, grad, has_grad)
    class(distance_field_t), intent(in) :: this
    real(wp), intent(in) :: p(2)
    real(wp), intent(out) :: val, grad(2)
    logical, intent(out) :: has_grad
    real(wp), parameter :: eps_edge = 1.0e-9_wp
    real(wp) :: x(2), s, u, t11, t21, t12, t22, xi, eta, w, m(3, 3), r(3), det, sol(3), dn
    integer :: i, j, ii, jj, nvalid

    val = t_inf
    grad = 0.0_wp
    has_grad = .false.
    if (.not. allocated(this%t)) return
    x = (p - this%lo) / this%dx
    if (.not. all(ieee_is_finite(x))) return
    if (any(x < -eps_edge) .or. any(x > real(this%n - 1, wp) + eps_edge)) return
    i = min(max(floor(x(1)), 0), this%n(1) - 2) + 1
    j = min(max(floor(x(2)), 0), this%n(2) - 2) + 1
    s = min(max(x(1) - real(i - 1, wp), 0.0_wp), 1.0_wp)
    u = min(max(x(2) - real(j - 1, wp), 0.0_wp), 1.0_wp)

    if (this%node_valid(i, j) .and. this%node_valid(i + 1, j) .and. &
        this%node_valid(i, j + 1) .and. this%node_valid(i + 1, j + 1)) then
      t11 = this%t(i, j)
      t21 = this%t(i + 1, j)
      t12 = this%t(i, j + 1)
      t22 = this%t(i + 1, j + 1)
      val = (1.0_wp - s) * (1.0_wp - u) * t11 + s * (1.0_wp - u) * t21 &
          + (1.0_wp - s) * u * t12 + s * u * t22
      grad(1) = ((1.0_wp - u) * (t21 - t11) + u * (t22 - t12)) / this%dx
      grad(2) = ((1.0_wp - s) * (t12 - t11) + s * (t22 - t21)) / this%dx
      has_grad = .true.
      return
    end if

    ! fallback: weighted least-squares plane T ~ c + g . (x_node - p) over valid nodes nearby
    m = 0.0_wp
    r = 0.0_wp
    nvalid = 0
    do jj = j - 1, j + 2
      do ii = i - 1, i + 2
        if (.not. this%node_valid(ii, jj)) cycle
        nvalid = nvalid + 1
        xi = real(ii - 1, wp) - x(1)
        eta = real(jj - 1, wp) - x(2)
        dn = sqrt(xi * xi + eta * eta)
        val = min(val, this%t(ii, jj) + dn * this%dx)
        w = 1.0_wp / (1.0_wp + dn * dn)
        m(:, 1) = m(:, 1) + w * [1.0_wp, xi, eta]
        m(:, 2) = m(:, 2) + w * xi * [1.0_wp, xi, eta]
        m(:, 3) = m(:, 3) + w * eta * [1.0_wp, xi, eta]
        r = r + w * this%t(ii, jj) * [1.0_wp, xi, eta]
      end do
    end do
    if (nvalid < 3) return
    det = det3(m)
    ! nodes are on a unit lattice, so a non-degenerate fit has det of order 1 or more
    if (abs(det) <= 1.0e-8_wp * max(1.0_wp, m(1, 1))**3) return
    sol(1) = det3(reshape([r, m(:, 2), m(:, 3)], [3, 3])) / det
    sol(2) = det3(reshape([m(:, 1), r, m(:, 3)], [3, 3])) / det
    sol(3) = det3(reshape([m(:, 1), m(:, 2), r], [3, 3])) / det
    val = sol(1)
    grad = sol(2:3) / this%dx
    has_grad = .true.
  end subroutine local_model

  !> Determinant of a 3 x 3 matrix.
  pure function det3(a) result(d)
    real(wp), intent(in) :: a(3, 3)
    real(wp) :: d
    d = a(1, 1) * (a(2, 2) * a(3, 3) - a(3, 2) * a(2, 3)) &
      - a(1, 2) * (a(2, 1) * a(3, 3) - a(3, 1) * a(2, 3)) &
      + a(1, 3) * (a(2, 1) * a(3, 2) - a(3, 1) * a(2, 2))
  end function det3

  !> Interpolated geodesic distance at p: bilinear where the cell's 4 nodes are valid, a local
  !> least-squares plane otherwise; huge(1.0_wp) if p is unreachable or off the grid. O(1).
  pure function value(this, p) result(val)
    class(distance_field_t), intent(in) :: this
    real(wp), intent(in) :: p(2)
    real(wp) :: val
    real(wp) :: grad(2)
    logical :: has_grad
    call local_model(this, p, val, grad, has_grad)
  end function value

  !> Desired direction at p: dir = -grad T / |grad T| from the local model of T (bilinear
  !> interpolant, or least-squares plane near blocked nodes). ok = .false. (and dir = 0) if p
  !> is off the grid, no valid node is near, or the gradient vanishes. O(1).
  pure subroutine direction(this, p, dir, ok)
    class(distance_field_t), intent(in) :: this
    real(wp), intent(in) :: p(2)
    real(wp), intent(out) :: dir(2)
    logical, intent(out) :: ok
    real(wp) :: val, grad(2), g
    call local_model(this, p, val, grad, ok)
    dir = 0.0_wp
    if (.not. ok) return
    g = norm2(grad)
    ok = g > 1.0e-8_wp
    if (ok) dir = -grad / g
  end subroutine direction
end module cr_distance_field
