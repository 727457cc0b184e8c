!> The quantities of interest (cr_qoi) on trajectories with a closed-form answer, in a hall with
!> two exits (top: x in 0.8..1.2; right: y in 0.3..0.7) and a pillar: agent i moves straight at
!> a constant velocity that puts it beyond its exit's "has left" line exactly from frame f(i)
!> (half a step after the line, no rounding question), so the per-exit curves are
!> count(f <= c), the evacuation times the k-th smallest f times h, and a stream of m agents per
!> frame has the steady flow m / h exactly. Censoring: agents that stay give the horizon and
!> censored = true. Trust: agents whose path jumps across a wall or the pillar are counted, the
!> ones that walk out through the openings are not.
program test_qoi
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: scene_cfg_t
  use cr_obstacles, only: obstacles_cfg_t
  use cr_scene, only: scene_t
  use cr_qoi, only: qoi_t, compute_qoi, evacuation_time, steady_flow, mobility_ratio, QOI_PCT
  implicit none
  real(wp), parameter :: h = 0.05_wp, radius = 0.04_wp, d = 0.01_wp
  integer, parameter :: nt = 60
  type(scene_t) :: scene, scene1
  type(scene_cfg_t) :: sc
  type(obstacles_cfg_t) :: oc
  type(error_t), allocatable :: error

  sc%hall_length = 2.0_wp; sc%hall_width = 1.0_wp; sc%l_exit = 0.4_wp; sc%wall_thickness = 0.1_wp
  call scene1%init(sc, oc, error)
  call check(.not. allocated(error), "scene with one exit")
  sc%l_exit2 = 0.4_wp
  oc%n_disks = 1; oc%disk_x(1) = 0.5_wp; oc%disk_y(1) = 0.5_wp; oc%disk_r(1) = 0.1_wp
  call scene%init(sc, oc, error)
  call check(.not. allocated(error), "scene with two exits and a pillar")
  call test_exit_rule()
  call test_streams()
  call test_censoring()
  call test_through()
  call test_bad_input()
  call test_summary()

contains

  !> The per-exit rule and is_out agree; a point beyond both lines counts for the top exit.
  subroutine test_exit_rule()
    call check(scene%n_exits() == 2 .and. scene1%n_exits() == 1, "number of exits")
    call check(scene%exit_of([1.0_wp, 1.15_wp], radius) == 1 .and. scene%exit_of([2.15_wp, 0.5_wp], radius) == 2 .and. &
      scene%exit_of([2.15_wp, 1.15_wp], radius) == 1 .and. scene%exit_of([1.0_wp, 1.13_wp], radius) == 0 .and. &
      scene%exit_of([2.13_wp, 0.5_wp], radius) == 0, "exit_of: top line y = 1.14, right line x = 2.14")
    call check(scene1%exit_of([2.15_wp, 0.5_wp], radius) == 0 .and. .not. scene1%is_out([2.15_wp, 0.5_wp], radius), &
      "without a second exit, right of the right wall is not out")
    call check(scene%is_out([1.0_wp, 1.15_wp], radius) .and. scene%is_out([2.15_wp, 0.5_wp], radius) .and. &
      .not. scene%is_out([1.0_wp, 1.13_wp], radius), "is_out = exit_of > 0")
    call check_close(scene%exit_width(1), 0.4_wp, 0.0_wp, "width of exit 1")
    call check_close(scene%exit_width(2), 0.4_wp, 0.0_wp, "width of exit 2")
  end subroutine test_exit_rule

  !> Agent moving along direction e (1: up through the top opening at x; 2: right through the
  !> right opening at y) beyond the line from frame f: positions [2, nt + 1].
  function mover(e, f, s) result(p)
    integer, intent(in) :: e, f
    real(wp), intent(in) :: s
    real(wp) :: p(2, nt + 1), line
    integer :: c
    line = merge(scene%y_out(radius), scene%length + scene%wall + radius, e == 1)
    do c = 0, nt
      if (e == 1) then
        p(:, c + 1) = [s, line + (c - f + 0.5_wp) * d]
      else
        p(:, c + 1) = [line + (c - f + 0.5_wp) * d, s]
      end if
    end do
  end function mover

  !> k-th smallest entry of f (k >= 1), huge when k > size(f).
  integer function kth(f, k)
    integer, intent(in) :: f(:), k
    integer :: g(size(f)), i, j, t
    g = f
    do i = 2, size(g)
      t = g(i); j = i - 1
      do while (j >= 1)
        if (g(j) <= t) exit
        g(j + 1) = g(j); j = j - 1
      end do
      g(j + 1) = t
    end do
    kth = huge(1)
    if (k <= size(g)) kth = g(k)
  end function kth

  !> 40 agents out through the top exit, 2 per frame at frames 11..30; 20 through the right
  !> exit, 1 per frame at frames 21..40: curves, times and flows in closed form.
  subroutine test_streams()
    integer, parameter :: n1 = 40, n2 = 20, na = n1 + n2
    real(wp) :: q(2 * na, nt + 1), disp2
    integer :: f(na), ex(na), i, c, j, k
    type(qoi_t) :: qoi
    logical :: ok
    do i = 1, n1
      f(i) = 11 + (i - 1) / 2; ex(i) = 1
      q(2*i-1:2*i, :) = mover(1, f(i), 0.85_wp + 0.3_wp * (i - 1) / (n1 - 1))
    end do
    do i = 1, n2
      f(n1 + i) = 20 + i; ex(n1 + i) = 2
      q(2*(n1+i)-1:2*(n1+i), :) = mover(2, f(n1 + i), 0.35_wp + 0.3_wp * (i - 1) / (n2 - 1))
    end do
    call compute_qoi(scene, radius, h, q, qoi, error)
    call check(.not. allocated(error), "compute_qoi")
    call check(qoi%n_agents == na .and. qoi%n_steps == nt .and. qoi%n_exits == 2, "sizes")
    ok = .true.
    do c = 0, nt
      ok = ok .and. qoi%curve(c, 1) == count(f <= c .and. ex == 1) .and. qoi%curve(c, 2) == count(f <= c .and. ex == 2) &
        .and. qoi%curve_total(c) == count(f <= c)
    end do
    call check(ok, "per-exit curves = count(f <= c) per exit, total = their sum")
    do j = 1, 3
      k = (QOI_PCT(j) * na + 99) / 100
      call check(qoi%t_evac(j) == kth(f, k) * h .and. .not. qoi%censored(j), "t" // trim(pct_name(j)) // " = k-th f times h")
    end do
    call check(qoi%t_evac(3) == 40 * h, "t100 = 40 h (the last right-exit agent)")
    ! exit 1: cum = 2 (c - 10) on 11..30; window 10 % (4 agents: frame 12) .. 80 % (32: frame 26)
    call check(all(qoi%flow_defined), "both flows defined")
    call check_close(qoi%flow_rate(1), 2 / h, 1.0e-12_wp, "flow rate of exit 1 = 2 agents per frame")
    call check_close(qoi%flow(1), 2 / h / 0.4_wp, 1.0e-12_wp, "specific flow of exit 1 = rate / width")
    call check_close(qoi%flow_rate(2), 1 / h, 1.0e-12_wp, "flow rate of exit 2 = 1 agent per frame")
    call check(qoi%n_through == 0, "agents walking out through the openings did not pass through a wall")
    disp2 = 0
    do i = 1, na
      disp2 = disp2 + (nt * d)**2
    end do
    call check_close(qoi%displacement, sqrt(disp2), 1.0e-12_wp, "displacement = |q(N) - q(0)|")
    call check_close(mobility_ratio(qoi%displacement, 2 * qoi%displacement), 0.5_wp, 0.0_wp, "mobility = ratio")
    call check(mobility_ratio(1.0_wp, 0.0_wp) == -1, "mobility against a reference that does not move: -1")
    call check(qoi%overlap_aw == 0, "no agent-obstacle overlap")
  end subroutine test_streams

  pure function pct_name(j) result(s)
    integer, intent(in) :: j
    character(len=3) :: s
    write(s, '(i0)') QOI_PCT(j)
  end function pct_name

  !> 10 agents, 6 out (frames 5..10), 4 stay: t50 reached, t90 and t100 censored at the horizon;
  !> an agent that steps back in after leaving stays counted out; flows undefined with one agent.
  subroutine test_censoring()
    integer, parameter :: na = 10
    real(wp) :: q(2 * na, nt + 1), rate
    integer :: i
    type(qoi_t) :: qoi
    logical :: def
    do i = 1, 6
      q(2*i-1:2*i, :) = mover(1, 4 + i, 0.85_wp + 0.05_wp * i)
    end do
    do i = 7, na
      q(2*i-1, :) = 0.2_wp * (i - 6); q(2*i, :) = 0.2_wp
    end do
    ! agent 1 steps back below the line from frame 20 on
    q(2, 21:) = scene%y_out(radius) - 0.01_wp
    call compute_qoi(scene, radius, h, q, qoi, error)
    call check(.not. allocated(error), "compute_qoi")
    call check(qoi%t_evac(1) == 9 * h .and. .not. qoi%censored(1), "t50: the 5th agent out at frame 9")
    call check(qoi%t_evac(2) == nt * h .and. qoi%censored(2) .and. qoi%t_evac(3) == nt * h .and. qoi%censored(3), &
      "t90, t100 not reached: the horizon, censored")
    call check(qoi%curve_total(nt) == 6 .and. qoi%curve(nt, 2) == 0, "an agent that steps back stays counted out")
    call check(.not. qoi%flow_defined(2) .and. qoi%flow(2) == 0 .and. qoi%flow_rate(2) == 0, &
      "no agent through exit 2: flow undefined, stored 0")
    call steady_flow([0, 0, 1, 1, 1], h, rate, def)
    call check(.not. def .and. rate == 0, "one agent: a window of one frame, undefined")
    call steady_flow([0, 1, 2, 2], h, rate, def)
    call check(.not. def, "window of 2 frames: undefined")
    call steady_flow([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10], h, rate, def)
    call check(def .and. abs(rate - 1 / h) < 1.0e-12_wp / h, "window 1..8 of a unit ramp: 1 per frame")
    call evacuation_time([0, 0, 0], 0, 100, h, rate, def)
    call check(rate == 0 .and. .not. def, "no agent: every fraction reached at t = 0")
  end subroutine test_censoring

  !> Agent 1 jumps across the left barrier wall (from inside the hall to above the line in one
  !> frame: counted out through exit 1 and through a wall), agent 2 across the bottom wall,
  !> agent 3 across the pillar, agent 4 walks out through the top opening, agent 5 walks next to
  !> the pillar (touching nothing): 3 through.
  subroutine test_through()
    real(wp) :: q(10, nt + 1)
    type(qoi_t) :: qoi
    integer :: c
    q(:, 1) = [0.3_wp, 0.9_wp, 1.5_wp, 0.05_wp, 0.3_wp, 0.5_wp, 0.9_wp, 0.905_wp, 0.3_wp, 0.3_wp]
    do c = 2, nt + 1
      q(:, c) = q(:, c - 1)
    end do
    q(1:2, 31:) = spread([0.3_wp, 1.3_wp], 2, nt - 29)
    q(3:4, 11:) = spread([1.5_wp, -0.3_wp], 2, nt - 9)
    q(5:6, 41:) = spread([0.7_wp, 0.5_wp], 2, nt - 39)
    do c = 0, nt
      q(8, c + 1) = 0.905_wp + c * 0.01_wp
      q(9, c + 1) = 0.3_wp + c * 0.005_wp
    end do
    call compute_qoi(scene, radius, h, q, qoi, error)
    call check(.not. allocated(error), "compute_qoi")
    call check(qoi%n_through == 3, "3 agents passed through a wall or the pillar")
    call check(qoi%curve(23, 1) == 0 .and. qoi%curve(24, 1) == 1 .and. qoi%curve(29, 1) == 1 .and. qoi%curve(30, 1) == 2, &
      "the walker counts out through exit 1 from frame 24, the wall-jumper from frame 30")
  end subroutine test_through

  !> Shapes the definitions do not cover are refused.
  subroutine test_bad_input()
    type(qoi_t) :: qoi
    real(wp) :: q(3, 2), q0(2, 0)
    q = 0
    call compute_qoi(scene, radius, h, q, qoi, error)
    call check(allocated(error), "odd number of rows refused")
    call compute_qoi(scene, radius, h, q0, qoi, error)
    call check(allocated(error), "no frame refused")
    call compute_qoi(scene, radius, 0.0_wp, q(1:2, :), qoi, error)
    call check(allocated(error), "h = 0 refused")
  end subroutine test_bad_input
end program test_qoi
