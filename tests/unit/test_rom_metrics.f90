!> The accuracy measures of the reduced-model sweep on a synthetic study with a known answer:
!> agents in a column under the exit walk straight out at a constant speed, so the step at
!> which each one is out, hence the evacuation times of 50 % and 90 % of the crowd, are known
!> in closed form; a "reduced" trajectory walking at a fraction s of the speed has the
!> displacement error |1 - s| and mobility s exactly. Row aggregation: diverged samples are
!> excluded, a fraction that only one model reaches is counted, never averaged. Overlaps are
!> split agent-agent / agent-wall on a hand-made configuration. The divergence guard stops
!> a reduced problem whose feasible set lies kilometres away at the step it happens.
program test_rom_metrics
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_positive_inf
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: scene_cfg_t, obstacles_cfg_t
  use cr_scene, only: scene_t
  use cr_rom_metrics, only: sample_measures_t, row_measures_t, measure_sample, aggregate_measures, &
    evacuation_time, EVAC_PCT
  use cr_qoi, only: max_overlaps
  use cr_rom_guard, only: rom_guard_t
  implicit none
  integer, parameter :: na = 10, nt = 150
  real(wp), parameter :: h = 0.01_wp, radius = 0.04_wp
  type(scene_t) :: scene
  type(scene_cfg_t) :: sc
  type(error_t), allocatable :: error
  real(wp) :: y0(na), yout
  integer :: i0

  sc%hall_length = 2.0_wp; sc%hall_width = 1.0_wp; sc%l_exit = 0.4_wp; sc%wall_thickness = 0.1_wp
  call scene%init(sc, obstacles_cfg_t(), error)
  call check(.not. allocated(error), "scene")
  yout = scene%y_out(radius)
  call check_close(yout, 1.14_wp, 1.0e-15_wp, "y_out = H + wall + r")
  ! start heights 0.3 of a step (at speed 1) away from any crossing: no rounding question
  do i0 = 1, na
    y0(i0) = 0.103_wp + 0.09_wp * (i0 - 1)
  end do
  call test_times()
  call test_overlaps()
  call test_guard()
  call test_summary()

contains

  !> Straight walk at speed c: positions [2 na, nt + 1].
  function walk(c) result(q)
    real(wp), intent(in) :: c
    real(wp) :: q(2 * na, nt + 1)
    integer :: nu, i
    do nu = 0, nt
      do i = 1, na
        q(2*i-1, nu + 1) = 1.0_wp
        q(2*i, nu + 1) = y0(i) + c * nu * h
      end do
    end do
  end function walk

  !> Closed form: time at which pct % of the agents (walking at speed c) are out, or -1
  !> when after the horizon. Agent i is out at the first step nu with y0 + c nu h > y_out,
  !> nu = floor((y_out - y0) / (c h)) + 1; the k-th agent out (k = ceil(pct na / 100)) is the
  !> k-th highest.
  real(wp) function t_closed(c, pct) result(t)
    real(wp), intent(in) :: c
    integer, intent(in) :: pct
    integer :: k, nu
    k = ceiling(pct * na / 100.0_wp)
    nu = floor((yout - y0(na - k + 1)) / (c * h)) + 1
    t = -1
    if (nu <= nt) t = nu * h
  end function t_closed

  subroutine test_times()
    type(sample_measures_t) :: ms(4)
    type(row_measures_t) :: agg
    real(wp) :: qf(2 * na, nt + 1), e1, e2, e4
    integer :: j
    character(len=2) :: p
    ! s1: full model at speed 1, reduced at 0.8 (both reach 50 % and 90 %)
    qf = walk(1.0_wp)
    call measure_sample(scene, radius, h, walk(0.8_wp), ms(1), error, q=qf)
    call check(.not. allocated(error), "measure_sample")
    ! s2: reduced at 0.5 (reaches 50 %, not 90 %: agent 2 needs 190 steps)
    call measure_sample(scene, radius, h, walk(0.5_wp), ms(2), error, q=qf)
    call check(.not. allocated(error), "measure_sample")
    ! s3: diverged (excluded whatever its figures)
    call measure_sample(scene, radius, h, walk(3.0_wp), ms(3), error, q=qf)
    call check(.not. allocated(error), "measure_sample")
    ms(3)%diverged = .true.
    ! s4: full model at 0.5 (misses 90 %), reduced at 0.8
    call measure_sample(scene, radius, h, walk(0.8_wp), ms(4), error, q=walk(0.5_wp))
    call check(.not. allocated(error), "measure_sample")
    do j = 1, 2
      write(p, '(i2)') EVAC_PCT(j)
      call check(ms(1)%t_fom(j) == t_closed(1.0_wp, EVAC_PCT(j)) .and. t_closed(1.0_wp, EVAC_PCT(j)) > 0, &
        "t" // p // " full model = closed form")
      call check(ms(1)%t_rom(j) == t_closed(0.8_wp, EVAC_PCT(j)) .and. t_closed(0.8_wp, EVAC_PCT(j)) > 0, &
        "t" // p // " reduced (0.8) = closed form")
    end do
    call check(ms(2)%t_rom(1) == t_closed(0.5_wp, 50) .and. ms(2)%t_rom(1) > 0, "t50 at speed 0.5 = closed form")
    call check(ms(2)%t_rom(2) == -1 .and. t_closed(0.5_wp, 90) == -1, "t90 at speed 0.5: not reached, -1")
    call check(ms(1)%evac_fom(1) == 0 .and. ms(1)%evac_fom(nt + 1) == na .and. &
      all(ms(1)%evac_fom(2:) >= ms(1)%evac_fom(:nt)), "evacuation curve: 0 to all, non-decreasing")
    call check(ms(2)%not_left == count(floor((yout - y0) / (0.5_wp * h)) + 1 > nt) .and. ms(2)%not_left == 4 .and. &
      ms(2)%not_left_fom == 0, "agents not out at the end: reduced (0.5) 4 = closed form, full 0")
    call check_close(ms(1)%e_disp, 0.2_wp, 1.0e-13_wp, "E_disp of the 0.8 walk = 0.2")
    call check_close(ms(2)%e_disp, 0.5_wp, 1.0e-13_wp, "E_disp of the 0.5 walk = 0.5")
    call check_close(ms(1)%mobility, 0.8_wp, 1.0e-13_wp, "mobility of the 0.8 walk = 0.8")
    call check(ms(1)%e_mu > 0 .and. ms(1)%e_mu < ms(1)%e_disp, "E_mu (relative to positions) < E_disp")
    call aggregate_measures(ms, h, agg)
    call check(agg%n_samples == 4 .and. agg%n_diverged == 1, "row: 1 of 4 diverged")
    e1 = abs(t_closed(0.8_wp, 50) - t_closed(1.0_wp, 50)) / t_closed(1.0_wp, 50)
    e2 = abs(t_closed(0.5_wp, 50) - t_closed(1.0_wp, 50)) / t_closed(1.0_wp, 50)
    e4 = abs(t_closed(0.8_wp, 50) - t_closed(0.5_wp, 50)) / t_closed(0.5_wp, 50)
    call check_close(agg%t_err(1), (e1 + e2 + e4) / 3, 1.0e-14_wp, "row t50 error: mean over the 3 kept samples")
    call check(agg%t_n(1) == 3 .and. agg%t_rom_missed(1) == 0 .and. agg%t_fom_missed(1) == 0, "row t50 counts")
    e1 = abs(t_closed(0.8_wp, 90) - t_closed(1.0_wp, 90)) / t_closed(1.0_wp, 90)
    call check_close(agg%t_err(2), e1, 1.0e-14_wp, "row t90 error: only where both reach 90 %")
    call check(agg%t_n(2) == 1 .and. agg%t_rom_missed(2) == 1 .and. agg%t_fom_missed(2) == 1, &
      "row t90 counts: 1 both, 1 reduced misses, 1 full misses")
    call check_close(agg%e_disp, (0.2_wp + 0.5_wp + 0.6_wp) / 3, 1.0e-13_wp, "row E_disp over kept samples")
    call check_close(agg%e_avg, (ms(1)%e_mu + ms(2)%e_mu + ms(4)%e_mu) / 3, 1.0e-15_wp, "row E_avg over kept samples")
    ! every sample diverged: nothing averaged
    ms%diverged = .true.
    call aggregate_measures(ms, h, agg)
    call check(agg%n_diverged == 4 .and. agg%e_avg == -1 .and. agg%e_disp == -1 .and. all(agg%t_err == -1), &
      "row with every sample diverged: no figure")
    call check(evacuation_time([0, 1, 1, 2], 2, 90, 0.5_wp) == 1.5_wp .and. &
      evacuation_time([0, 1, 1, 1], 2, 90, 0.5_wp) == -1, "90 % of 2 agents is both of them")
  end subroutine test_times

  !> Agent 1 overlaps the left wall by 0.01, agents 2 and 3 each other by 0.02, agent 4 is free.
  subroutine test_overlaps()
    real(wp) :: q(8, 2), oaa, oaw
    q(:, 1) = [0.5_wp, 0.5_wp, 1.5_wp, 0.3_wp, 1.56_wp, 0.3_wp, 1.0_wp, 0.7_wp]
    q(:, 2) = q(:, 1)
    q(1, 2) = 0.03_wp
    call max_overlaps(scene, radius, q, oaa, oaw)
    call check_close(oaa, 0.02_wp, 1.0e-14_wp, "agent-agent overlap 0.02")
    call check_close(oaw, 0.01_wp, 1.0e-14_wp, "agent-wall overlap 0.01")
  end subroutine test_overlaps

  !> The guard's region and its per-step tests.
  subroutine test_guard()
    type(rom_guard_t) :: g
    real(wp) :: q(4), qq(4, 3)
    call g%init(scene, 2.0_wp, 1.0_wp, 2)
    call check(g%inside([1.0_wp, 5.0_wp]) .and. .not. g%inside([1.0_wp, 5.0e8_wp]), "guard: 5e8 m is outside")
    call check(.not. g%inside([0.0_wp, ieee_value(1.0_wp, ieee_quiet_nan)]), "guard: NaN is outside")
    q = [0.5_wp, 0.5_wp, 1.0e9_wp, 0.5_wp]
    call check(g%agents_ok(q, [1]) .and. .not. g%agents_ok(q, [1, 2]), "guard: agents read checked")
    call check(g%coeffs_ok([1.0_wp, 2.0_wp], [1.0_wp, 2.0_wp], h), "guard: sane coefficients")
    call check(.not. g%coeffs_ok([1.0e12_wp, 0.0_wp], [1.0e12_wp, 0.0_wp], h), "guard: h |sum alpha| too large")
    call check(.not. g%coeffs_ok([ieee_value(1.0_wp, ieee_positive_inf), 0.0_wp], [1.0_wp, 0.0_wp], h), "guard: Inf coefficient")
    qq(:, 1) = [0.5_wp, 0.5_wp, 1.0_wp, 0.5_wp]
    qq(:, 2) = qq(:, 1)
    qq(:, 3) = [0.5_wp, 0.5_wp, 1.0_wp, -1.0e300_wp]
    call check(g%first_outside(qq) == 3 .and. g%first_outside(qq(:, 1:2)) == 0, "guard: first configuration outside")
  end subroutine test_guard
end program test_rom_metrics
