!> Unit tests of the model layer: neighbour search against brute force (one cutoff, per-agent
!> margins, the check for rows left out), gap gradients
!> against finite differences, the aiming rule, the random generator, sorting.
program test_model
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: scene_cfg_t, obstacles_cfg_t, desired_cfg_t
  use cr_scene, only: scene_t
  use cr_neighbours, only: cell_list_t, build_contacts, rows_missing, grid_size, cell_index
  use cr_contact_set, only: contact_set_t, contact_key
  use cr_desired, only: desired_t
  use cr_random, only: rng_t
  use cr_sort, only: argsort_i8, bsearch_i8, lower_bound, near_max_index
  use cr_shapes, only: obstacle_distance
  implicit none
  type(scene_t) :: scene
  type(scene_cfg_t) :: sc
  type(obstacles_cfg_t) :: oc
  type(error_t), allocatable :: error

  oc%n_disks = 1; oc%disk_x(1) = 0.65_wp; oc%disk_y(1) = 0.5_wp; oc%disk_r(1) = 0.1_wp
  call scene%init(sc, oc, error)
  call check(.not. allocated(error), "scene builds")
  call check(scene%n_walls == 5 .and. scene%n_interior() == 1, "5 walls + 1 disk")
  call test_neighbours()
  call test_margins()
  call test_far_positions()
  call test_gap_gradient()
  call test_aiming()
  call test_random()
  call test_sort()
  call test_summary()

contains

  !> The cell list finds exactly the brute-force set of rows with gap <= cutoff.
  subroutine test_neighbours()
    type(rng_t) :: rng
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    real(wp), allocatable :: q(:)
    integer(i8), allocatable :: brute(:)
    real(wp) :: cutoff, dist, nrm(2), r
    integer :: na, i, j, k, nb, trial
    r = 0.03_wp
    do trial = 1, 4
      na = 40 * trial
      call rng%seed(trial)
      allocate(q(2 * na))
      do i = 1, na
        q(2*i-1) = -0.1_wp + 1.5_wp * rng%uniform()
        q(2*i) = -0.1_wp + 1.4_wp * rng%uniform()
      end do
      cutoff = 0.02_wp * trial
      call cs%init(na, 0.1_wp)
      call build_contacts(scene, q, r, cutoff, cells, cs)
      allocate(brute(na * na + na * scene%n_obstacles()))
      nb = 0
      do i = 1, na
        do j = i + 1, na
          if (norm2(q(2*i-1:2*i) - q(2*j-1:2*j)) - 2 * r <= cutoff) then
            nb = nb + 1; brute(nb) = contact_key(i, j, 0)
          end if
        end do
        do k = 1, scene%n_obstacles()
          call obstacle_distance(scene%obstacles(k), q(2*i-1:2*i), dist, nrm)
          if (dist - r <= cutoff) then
            nb = nb + 1; brute(nb) = contact_key(i, 0, k)
          end if
        end do
      end do
      call check(same_rows(cs, brute(1:nb)), "cell list equals brute force (trial " // char(48 + trial) // ")")
      deallocate(q, brute)
    end do
  end subroutine test_neighbours

  !> Per-agent margins: the cell list keeps exactly the brute-force rows (pairs with gap <=
  !> m_a + m_b, agent-obstacle pairs with gap <= 2 m_a); rows_missing is true exactly when
  !> brute force finds a row left out that a need vector reaches (pairs: gap <= n_a + n_b,
  !> obstacles: gap <= n_a), including needs far beyond the cell side.
  subroutine test_margins()
    type(rng_t) :: rng
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    real(wp), allocatable :: q(:), mg(:), nd(:)
    integer(i8), allocatable :: brute(:)
    real(wp) :: dist, nrm(2), r, gap, scale
    integer :: na, i, j, k, nb, trial, nmiss, nagree
    logical :: miss, want
    character(len=2) :: tag
    r = 0.03_wp
    nmiss = 0; nagree = 0
    do trial = 1, 24
      write(tag, '(i2.2)') trial
      na = 10 + 5 * mod(trial, 8)
      call rng%seed(100 + trial)
      allocate(q(2 * na), mg(na), nd(na))
      do i = 1, na
        q(2*i-1) = -0.1_wp + 1.3_wp * rng%uniform()
        q(2*i) = -0.1_wp + 1.2_wp * rng%uniform()
        mg(i) = 0.03_wp * rng%uniform()
      end do
      if (mod(trial, 3) == 0) mg(1) = 0.0_wp
      call cs%init(na, 0.1_wp)
      call build_contacts(scene, q, r, 2 * maxval(mg), cells, cs, margin=mg)
      allocate(brute(na * na + na * scene%n_obstacles()))
      nb = 0
      do i = 1, na
        do j = i + 1, na
          if (norm2(q(2*i-1:2*i) - q(2*j-1:2*j)) - 2 * r <= mg(i) + mg(j)) then
            nb = nb + 1; brute(nb) = contact_key(i, j, 0)
          end if
        end do
        do k = 1, scene%n_obstacles()
          call obstacle_distance(scene%obstacles(k), q(2*i-1:2*i), dist, nrm)
          if (dist - r <= 2 * mg(i)) then
            nb = nb + 1; brute(nb) = contact_key(i, 0, k)
          end if
        end do
      end do
      call check(same_rows(cs, brute(1:nb)), "margins: cell list equals brute force (trial " // tag // ")")
      ! needs: most agents within their margin, a few beyond (up to 20 cell sides)
      scale = merge(0.5_wp, 0.05_wp, mod(trial, 4) == 0)
      do i = 1, na
        nd(i) = mg(i) * rng%uniform()
        if (rng%uniform() < 0.15_wp) nd(i) = mg(i) + scale * rng%uniform()
      end do
      want = .false.
      do i = 1, na
        do j = 1, na
          if (j == i) cycle
          gap = norm2(q(2*i-1:2*i) - q(2*j-1:2*j)) - 2 * r
          if (gap <= nd(i) + nd(j) .and. gap > mg(i) + mg(j)) want = .true.
        end do
        do k = 1, scene%n_obstacles()
          call obstacle_distance(scene%obstacles(k), q(2*i-1:2*i), dist, nrm)
          gap = dist - r
          if (gap <= nd(i) .and. gap > 2 * mg(i)) want = .true.
        end do
      end do
      miss = rows_missing(scene, q, r, cells, mg, nd)
      call check(miss .eqv. want, "rows_missing equals brute force (trial " // tag // ")")
      if (want) nmiss = nmiss + 1
      if (miss .eqv. want) nagree = nagree + 1
      ! needs within the margins: nothing can be missing
      call check(.not. rows_missing(scene, q, r, cells, mg, min(nd, mg)), &
        "rows_missing false when every need is within its margin (trial " // tag // ")")
      deallocate(q, mg, nd, brute)
    end do
    ! a pair several cells apart reached by two fast agents (the search must widen beyond the
    ! neighbouring cells): gap 0.24 between the agents, walls and disk at gaps >= 0.22
    allocate(q(4), mg(2), nd(2))
    q = [0.25_wp, 0.35_wp, 0.25_wp, 0.65_wp]
    mg = [0.001_wp, 0.001_wp]
    call cs%init(2, 0.1_wp)
    call build_contacts(scene, q, r, 2 * maxval(mg), cells, cs, margin=mg)
    call check(cs%n == 0 .and. 0.3_wp > 3 * cells%side, "margins: pair many cells apart, no row kept")
    nd = [0.13_wp, 0.13_wp]
    call check(rows_missing(scene, q, r, cells, mg, nd), "rows_missing finds a pair several cells away")
    nd = [0.11_wp, 0.11_wp]
    call check(.not. rows_missing(scene, q, r, cells, mg, nd), "rows_missing false when the needs fall short")
    nd = [huge(1.0_wp), 0.0_wp]
    call check(rows_missing(scene, q, r, cells, mg, nd), "rows_missing with a huge need (no overflow)")
    nd = [huge(1.0_wp), huge(1.0_wp)]
    call check(rows_missing(scene, q, r, cells, mg, nd), "rows_missing with two huge needs (no overflow)")
    deallocate(q, mg, nd)
    ! the trials above must exercise both answers
    call check(nmiss >= 3 .and. nmiss <= 21, "rows_missing trials include rows missing and none missing")
  end subroutine test_margins

  !> The rows of cs are exactly the contact identities `want` (any order).
  logical function same_rows(cs, want) result(same)
    type(contact_set_t), intent(in) :: cs
    integer(i8), intent(in) :: want(:)
    integer(i8) :: found(cs%n), w(size(want))
    integer :: idx(max(cs%n, size(want))), k
    same = cs%n == size(want)
    if (.not. same) return
    do k = 1, cs%n
      found(k) = cs%key(k)
    end do
    call argsort_i8(found, idx(1:cs%n)); found = found(idx(1:cs%n))
    call argsort_i8(want, idx(1:size(want))); w = want(idx(1:size(want)))
    same = all(found == w)
  end function same_rows

  !> Positions far outside the hall (a diverged reduced trajectory: 1e9 m, 1e300 m, +-huge)
  !> neither overflow the cell indices nor lose the near pairs: the cell list still equals
  !> brute force, the grid stays within its cell budget, and every cell index is in range.
  subroutine test_far_positions()
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    real(wp), parameter :: far(4) = [1.0e9_wp, 1.0e300_wp, huge(1.0_wp), -huge(1.0_wp)]
    real(wp) :: q(12), r, side
    integer :: k, nx, ny, na
    logical :: pair12, pair34, others
    character(len=32) :: tag
    r = 0.03_wp
    na = 6
    do k = 1, size(far)
      write(tag, '(es10.2)') far(k)
      ! agents 1, 2 touching in the hall; 3, 4 touching far away; 5 far on x; 6 far on y
      q = [0.3_wp, 0.4_wp, 0.35_wp, 0.4_wp, far(k), 0.2_wp, far(k), 0.25_wp, far(k), far(k), 0.5_wp, -far(k)]
      if (abs(far(k)) > 1.0e20_wp) q(7) = far(k) * (1 - 1.0e-16_wp)   ! at 1e300 m, 5 cm is below round-off
      call cs%init(na, 0.1_wp)
      call build_contacts(scene, q, r, 0.01_wp, cells, cs)
      call check(cells%nx >= 1 .and. cells%ny >= 1 .and. real(cells%nx, wp) * cells%ny <= 4 * na + 64, &
        "far positions " // trim(tag) // ": grid within its cell budget")
      pair12 = any(cs%ia(1:cs%n) == 1 .and. cs%ib(1:cs%n) == 2)
      pair34 = any(cs%ia(1:cs%n) == 3 .and. cs%ib(1:cs%n) == 4)
      others = any(cs%ia(1:cs%n) >= 5 .or. (cs%ib(1:cs%n) >= 5))
      call check(pair12 .and. .not. others, "far positions " // trim(tag) // ": near pair in the hall found, " // &
        "far agents without contacts")
      if (abs(far(k)) < 1.0e20_wp) call check(pair34, "far positions " // trim(tag) // ": far touching pair found")
    end do
    ! the grid helpers on extreme boxes
    call grid_size([0.5_wp * huge(1.0_wp), 0.5_wp * huge(1.0_wp)], 0.1_wp, 100.0_wp, side, nx, ny)
    call check(nx >= 1 .and. ny >= 1 .and. nx * ny <= 100 .and. side > 0, "grid over [-huge, huge]^2: " // &
      "at most 100 cells")
    call check(cell_index(huge(1.0_wp), -huge(1.0_wp), side, nx) == nx - 1 .and. &
      cell_index(-huge(1.0_wp), -huge(1.0_wp), side, nx) == 0, "cell index of +-huge in range")
    call check(cell_index(1.0e300_wp, 0.0_wp, 0.1_wp, 7) == 6 .and. cell_index(-1.0e300_wp, 0.0_wp, 0.1_wp, 7) == 0, &
      "cell index of +-1e300 clamped")
  end subroutine test_far_positions

  !> The pair normal is the gradient of the gap (central differences).
  subroutine test_gap_gradient()
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    real(wp) :: q(4), qp(4), qm(4), e, fd(4), gfull(4)
    integer :: c
    q = [0.3_wp, 0.4_wp, 0.37_wp, 0.45_wp]
    call cs%init(2, 1.0_wp)
    call build_contacts(scene, q, 0.03_wp, 0.1_wp, cells, cs)
    call check(cs%n >= 1, "pair found")
    if (cs%n < 1) return
    gfull = [cs%g(:, 1), -cs%g(:, 1)]
    e = 1.0e-6_wp
    do c = 1, 4
      qp = q; qm = q
      qp(c) = qp(c) + e; qm(c) = qm(c) - e
      fd(c) = (gap(qp) - gap(qm)) / (2 * e)
    end do
    call check(maxval(abs(fd - gfull)) < 1.0e-8_wp, "pair gap gradient = finite differences")
  end subroutine test_gap_gradient

  real(wp) function gap(q)
    real(wp), intent(in) :: q(4)
    gap = norm2(q(1:2) - q(3:4)) - 0.06_wp
  end function gap

  !> Agents aim at the exit opening narrowed by the radius.
  subroutine test_aiming()
    type(desired_t) :: des
    type(desired_cfg_t) :: dc
    type(scene_t) :: hall
    real(wp) :: dir(2), r, p(2)
    type(error_t), allocatable :: err
    call hall%init(sc, obstacles_cfg_t(), err)
    r = 0.05_wp
    call des%init(dc, hall, r, 1, err)
    call check(.not. allocated(err) .and. .not. des%use_field, "analytic field without interior obstacles")
    ! far left below the barrier wall: aim at (x_lo + r, H)
    p = [0.1_wp, 0.5_wp]
    call des%direction(p, dir)
    call check(maxval(abs(dir - ([hall%x_lo + r, hall%width] - p) / norm2([hall%x_lo + r, hall%width] - p))) &
      < 1e-12_wp, "aims at the narrowed opening, not the door corner")
    p = [0.65_wp, 0.97_wp]
    call des%direction(p, dir)
    call check(maxval(abs(dir - [0.0_wp, 1.0_wp])) < 1e-12_wp, "walks straight out in the doorway")
    p = [0.9_wp, 1.5_wp]
    call des%direction(p, dir)
    call check(dir(2) > 0 .and. dir(1) > 0, "keeps walking away past the exit")
    call check_close(norm2(dir), 1.0_wp, 1e-14_wp, "unit direction")
    ! with the interior disk, the exact geodesic is used (auto) and the direction is unit and finite
    call des%init(dc, scene, r, 1, err)
    call check(.not. allocated(err) .and. des%use_exact .and. .not. des%use_field, &
      "exact geodesic with an interior obstacle (auto)")
    p = [0.65_wp, 0.3_wp]   ! behind the disk: must go around it
    call des%direction(p, dir)
    call check(abs(dir(1)) > 0.2_wp, "goes around the obstacle (not straight through)")
    call check_close(norm2(dir), 1.0_wp, 1e-12_wp, "unit direction from the exact geodesic")
    ! the grid field when forced
    dc%field = 'grid'
    call des%init(dc, scene, r, 1, err)
    call check(.not. allocated(err) .and. des%use_field .and. .not. des%use_exact, "grid field when forced")
    call des%direction(p, dir)
    call check(abs(dir(1)) > 0.2_wp, "goes around the obstacle (grid)")
    call check_close(norm2(dir), 1.0_wp, 1e-12_wp, "unit direction from the field")
  end subroutine test_aiming

  subroutine test_random()
    type(rng_t) :: a, b
    real(wp) :: x(1000), y(1000), m
    call a%seed(7); call b%seed(7)
    call a%uniform_array(x); call b%uniform_array(y)
    call check(all(x == y), "same seed, same stream")
    call check(all(x > 0 .and. x < 1), "uniform in (0,1)")
    m = sum(x) / size(x)
    call check(abs(m - 0.5_wp) < 0.05_wp, "mean near 1/2")
    call b%seed(7, stream=1); call b%uniform_array(y)
    call check(any(x /= y), "streams differ")
  end subroutine test_random

  subroutine test_sort()
    integer(i8) :: k(6) = [5_i8, 3_i8, 9_i8, 1_i8, 3_i8, 7_i8]
    integer :: idx(6)
    call argsort_i8(k, idx)
    call check(all(k(idx(1:5)) <= k(idx(2:6))), "argsort ascending")
    call check(idx(2) == 2 .and. idx(3) == 5, "argsort stable")
    call check(bsearch_i8(k(idx), 7_i8) == 5 .and. bsearch_i8(k(idx), 4_i8) == 0, "binary search")
    ! first position >= key: inside, on a repeated value, before the first, past the last, empty
    call check(lower_bound([1, 3, 3, 8], 4) == 4, "lower_bound between values")
    call check(lower_bound([1, 3, 3, 8], 3) == 2, "lower_bound on a repeated value")
    call check(lower_bound([1, 3, 3, 8], 0) == 1, "lower_bound before the first")
    call check(lower_bound([1, 3, 3, 8], 9) == 5, "lower_bound past the last")
    call check(lower_bound([integer ::], 5) == 1, "lower_bound of an empty array")
    ! near_max_index: entries a few eps apart tie (lowest index), a real difference does not
    call check(near_max_index([0.5_wp, 1.0_wp - 4 * epsilon(1.0_wp), 1.0_wp]) == 2, &
      "near_max_index: a tie to rounding goes to the lowest index")
    call check(near_max_index([0.5_wp, 1.0_wp - 1.0e-6_wp, 1.0_wp]) == 3, &
      "near_max_index: a difference far above sqrt(eps) is not a tie")
    call check(near_max_index([3.0_wp, 1.0_wp, 1.0_wp], mask=[.false., .true., .true.]) == 2, &
      "near_max_index: masked entries are not candidates")
    call check(near_max_index([-2.0_wp, -1.0_wp - epsilon(1.0_wp), -1.0_wp]) == 2, &
      "near_max_index: negative values, relative to |max|")
    call check(near_max_index([real(wp) ::]) == 0, "near_max_index of an empty array")
    call check(near_max_index([1.0_wp], mask=[.false.]) == 0, "near_max_index with nothing selected")
  end subroutine test_sort
end program test_model
