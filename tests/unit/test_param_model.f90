!> cr_param_model: the one parameter-to-model mapping. The component names written to the files
!> rebuild the same mapping; apply sets l_exit and the speeds; scene_of moves the exit; unknown
!> components are refused. The heterogeneous population (speed_mean, speed_spread and its seed
!> component): the per-agent draw is reproducible from mu alone, has the moments of the uniform
!> distribution on (mean - spread, mean + spread) within sampling error, and the study's bad
!> bounds and a bad mu are refused with a message naming the group and variable; crowd_predict's
!> sampling rule draws its seed component as an integer, as the study's sampling does.
program test_param_model
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: config_t
  use cr_scene, only: scene_t
  use cr_desired, only: desired_t
  use cr_param_model, only: param_model_t, SPEED_SEED_MAX
  use cr_study_config, only: study_cfg_t, check_study
  use cr_sampling, only: param_space_t, sample_set_t, generate_samples
  use cr_predict_config, only: predict_cfg_t
  use cr_query_list, only: query_list_t, load_queries
  implicit none
  type(param_model_t) :: a, b
  type(config_t) :: cfg
  type(scene_t) :: sc
  type(desired_t) :: des
  type(error_t), allocatable :: error
  real(wp), allocatable :: sp(:)
  real(wp) :: mu(5)

  call a%init_model([character(len=8) :: 'l_exit', 'speeds'], 4)
  call check(a%n_expanded == 5 .and. a%component_names() == "l_exit,speed_1,speed_2,speed_3,speed_4", &
    "expansion and component names")
  call b%init_from_components(a%component_names(), 4, error)
  call check(.not. allocated(error), "components read back")
  call check(b%n_params == 2 .and. all(b%first == a%first) .and. all(b%width == a%width) .and. &
    all(b%names == a%names), "the same mapping from the stored names")
  call b%init_from_components("l_exit,speed", 4, error)
  call check(.not. allocated(error) .and. b%n_expanded == 2, "l_exit and one common speed")
  call b%init_from_components("l_exit,width", 4, error)
  call check(allocated(error), "unknown component refused")
  if (allocated(error)) call check(index(error%message, "'width'") > 0, "message names the component")
  call b%init_from_components("speed_1,speed_2", 4, error)
  call check(allocated(error), "components for another number of agents refused")

  mu = [0.2_wp, 1.0_wp, 2.0_wp, 3.0_wp, 4.0_wp]
  call a%sample_model(mu, cfg, [9.0_wp, 9.0_wp, 9.0_wp, 9.0_wp], 0.05_wp, sc, sp, des, error)
  call check(.not. allocated(error), "sample model built")
  call check(all(sp == mu(2:5)), "speeds of the sample")
  call check_close(sc%x_hi - sc%x_lo, 0.2_wp, 1.0e-14_wp, "exit width of the sample")
  call a%scene_of(mu, cfg, sc, error)
  call check(.not. allocated(error), "scene_of")
  call check_close(sc%l_exit, 0.2_wp, 0.0_wp, "scene_of applies l_exit")
  call check_heterogeneous()
  call check_bad_spread()
  call test_summary()

contains

  !> The per-agent speeds of (mean, spread, seed): reproducible, uniform moments, seed-dependent.
  subroutine check_heterogeneous()
    integer, parameter :: n = 20000
    type(param_model_t) :: h, h2
    type(config_t) :: c
    real(wp), allocatable :: s1(:), s2(:)
    real(wp) :: mean, var, m, sp
    real(wp), allocatable :: mu(:)
    type(error_t), allocatable :: err
    call h%init_model([character(len=12) :: 'l_exit', 'speed_mean', 'speed_spread'], n)
    call check(h%n_expanded == 4 .and. h%component_names() == "l_exit,speed_mean,speed_spread,speed_seed", &
      "heterogeneous population: components (the spread brings its seed)")
    call h2%init_from_components(h%component_names(), n, err)
    call check(.not. allocated(err), "heterogeneous components read back")
    call h2%init_from_components("speed_mean,speed_seed,speed_spread", n, err)
    call check(allocated(err), "a seed component not after its spread refused")
    call h2%init_from_components("l_exit,speed_mean", n, err)
    call check(allocated(err), "speed_mean without speed_spread refused")
    call h2%init_from_components(h%component_names(), n, err)
    m = 1.2_wp; sp = 0.3_wp
    mu = [0.3_wp, m, sp, 4321.0_wp]
    allocate(s1(n), s2(n))
    s1 = 9; s2 = 7
    call h%apply(mu, c, s1)
    call h2%apply(mu, c, s2)
    call check(all(s1 == s2), "the same speeds from the same mu (rebuilt mapping, other reference speeds)")
    call check(minval(s1) > m - sp .and. maxval(s1) < m + sp, "every speed within (mean - spread, mean + spread)")
    mean = sum(s1) / n
    var = sum((s1 - mean)**2) / (n - 1)
    ! sampling errors: sd(mean) = spread / sqrt(3 n); sd(var) = spread^2 sqrt(4 / (45 n)) (uniform: mu4 = s^4 / 5)
    call check_close(mean, m, 4 * sp / sqrt(3.0_wp * n), "sample mean = speed_mean within 4 standard errors")
    call check_close(var, sp**2 / 3, 4 * sp**2 * sqrt(4.0_wp / (45.0_wp * n)), &
      "sample variance = spread^2 / 3 within 4 standard errors")
    call check(count(s1 < m) > n / 2 - 4 * sqrt(real(n, wp)) / 2 .and. count(s1 < m) < n / 2 + 4 * sqrt(real(n, wp)) / 2, &
      "half the speeds below the mean within 4 standard errors")
    mu(4) = 4322
    call h%apply(mu, c, s2)
    call check(count(s1 == s2) == 0, "another seed gives other speeds")
    mu(3) = 0
    call h%apply(mu, c, s2)
    call check(all(s2 == m), "spread 0: every agent at the mean")
  end subroutine check_heterogeneous

  !> Bad bounds of the study and bad (mean, spread, seed) values are refused by name.
  subroutine check_bad_spread()
    type(study_cfg_t) :: st
    type(config_t) :: c
    type(param_space_t) :: sp
    type(sample_set_t) :: tr, va
    type(error_t), allocatable :: err
    st%n_params = 2
    st%param_name(1:2) = [character(len=16) :: 'speed_mean', 'speed_spread']
    st%param_min(1:2) = [1.0_wp, 0.0_wp]; st%param_max(1:2) = [1.4_wp, 0.3_wp]
    st%n_train = 5; st%n_valid = 2; st%seed = 11
    call check_study(st, c, err)
    call check(.not. allocated(err), "a good heterogeneous box is accepted")
    call sp%init(st, 6)
    call generate_samples(st, sp, tr, va, err)
    call check(.not. allocated(err), "samples of the heterogeneous box")
    call check(all(tr%mu(3, :) == aint(tr%mu(3, :))) .and. all(tr%mu(3, :) >= 0) .and. &
      all(tr%mu(3, :) <= SPEED_SEED_MAX) .and. tr%mu(3, 1) /= tr%mu(3, 2), "the sampling draws integer seeds")
    call check(all(tr%mu(1, :) >= 1.0_wp .and. tr%mu(1, :) <= 1.4_wp .and. tr%mu(2, :) >= 0 .and. &
      tr%mu(2, :) <= 0.3_wp) .and. all(va%mu(3, :) == aint(va%mu(3, :))), "the drawn samples lie in the box")
    call refused(st, 2, -0.1_wp, 0.3_wp, "&study: param_min(2) = -1.0", "speed_spread range must be >= 0")
    call refused(st, 1, 0.0_wp, 1.4_wp, "&study: param_min(1) = 0", "speed_mean range must be > 0")
    call refused(st, 2, 0.0_wp, 1.5_wp, "&study: param_max(2) = 1.5", "must not exceed param_min(1)")
    st%param_name(2) = 'speed'
    call check_study(st, c, err)
    call check(allocated(err), "speed_mean without speed_spread refused")
    if (allocated(err)) call check(index(err%message, "'speed_mean' and 'speed_spread' go together") > 0, &
      "message: they go together")
    call bad_mu(sp, c, [0.0_wp, 0.0_wp, 3.0_wp], "speed_mean = 0")
    call bad_mu(sp, c, [1.0_wp, -0.1_wp, 3.0_wp], "speed_spread = -1.0")
    call bad_mu(sp, c, [1.0_wp, 1.5_wp, 3.0_wp], "must not exceed speed_mean")
    call bad_mu(sp, c, [1.0_wp, 0.1_wp, 3.5_wp], "speed_seed = 3.5")
    call bad_mu(sp, c, [1.0_wp, 0.1_wp, -1.0_wp], "speed_seed = -1")
    call check_sampled_queries(sp)
  end subroutine check_bad_spread

  !> crowd_predict's sampling rule draws the population's seed as the study does (an integer in
  !> 0..SPEED_SEED_MAX), also when a distribution is given for speed_spread; the list passes the
  !> checks of every query.
  subroutine check_sampled_queries(sp)
    type(param_space_t), intent(in) :: sp
    type(predict_cfg_t) :: pc
    type(config_t) :: c
    type(query_list_t) :: list
    type(error_t), allocatable :: err
    integer :: pass
    c%agents%n_agents = 6
    pc%n_queries = 40; pc%seed = 5
    do pass = 1, 2
      if (pass == 2) then
        pc%dist_param(1) = 'speed_spread'; pc%dist(1) = 'uniform'; pc%dist_a(1) = 0.05_wp; pc%dist_b(1) = 0.2_wp
      end if
      call load_queries(pc, sp, c, "&predict", list, err)
      call check(.not. allocated(err), "sampled queries of the heterogeneous box accepted")
      if (allocated(err)) then
        print '(a)', "  " // err%message
        return
      end if
      call check(list%n == 40 .and. all(list%mu(3, :) == aint(list%mu(3, :))) .and. all(list%mu(3, :) >= 0) .and. &
        all(list%mu(3, :) <= SPEED_SEED_MAX) .and. count(list%mu(3, :) /= list%mu(3, 1)) > 30, &
        "sampled seeds are distinct integers in 0..SPEED_SEED_MAX")
    end do
    call check(all(list%mu(2, :) >= 0.05_wp .and. list%mu(2, :) <= 0.2_wp) .and. &
      all(list%mu(1, :) >= 1.0_wp .and. list%mu(1, :) <= 1.4_wp), "the given distribution of speed_spread")
  end subroutine check_sampled_queries

  subroutine refused(st0, k, lo, hi, name, msg)
    type(study_cfg_t), intent(in) :: st0
    integer, intent(in) :: k
    real(wp), intent(in) :: lo, hi
    character(len=*), intent(in) :: name, msg
    type(study_cfg_t) :: st
    type(config_t) :: c
    type(error_t), allocatable :: err
    st = st0
    st%param_min(k) = lo; st%param_max(k) = hi
    call check_study(st, c, err)
    call check(allocated(err), "refused: " // msg)
    if (allocated(err)) call check(index(err%message, name) > 0 .and. index(err%message, msg) > 0, &
      "message names the variable: " // name)
  end subroutine refused

  subroutine bad_mu(sp, c, mu, msg)
    type(param_space_t), intent(in) :: sp
    type(config_t), intent(in) :: c
    real(wp), intent(in) :: mu(:)
    character(len=*), intent(in) :: msg
    type(error_t), allocatable :: err
    call sp%check_values(mu, c, "mu", err)
    call check(allocated(err), "bad mu refused: " // msg)
    if (allocated(err)) call check(index(err%message, "mu") == 1 .and. index(err%message, msg) > 0, &
      "message: " // msg)
  end subroutine bad_mu
end program test_param_model
