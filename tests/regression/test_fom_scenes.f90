!> Regression: whole runs of the reference scenes with a brute-force overlap check after
!> every step (all pairs, all obstacles: independent of the neighbour search), and the
!> check that agents reach the exit. Argument: the inputs/ directory.
program test_fom_scenes
  use mpi_f08
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_assert, only: check, test_summary
  use cr_strings, only: str
  use cr_config, only: config_t, read_config
  use cr_config_check, only: check_config
  use cr_fom, only: fom_t, step_record_t
  use cr_shapes, only: obstacle_distance
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  character(len=512) :: dir
  integer :: ierr
  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call get_command_argument(1, dir)
  call run_scene(trim(dir) // "/hall20.nml", until_empty=.true., max_steps=200, all_leave=.true.)
  call run_scene(trim(dir) // "/tiny.nml", until_empty=.true., max_steps=400, all_leave=.true.)
  call run_scene(trim(dir) // "/congested150.nml", until_empty=.false., max_steps=50, all_leave=.false.)
  call env%free()
  call MPI_Finalize(ierr)
  call test_summary()

contains

  subroutine run_scene(path, until_empty, max_steps, all_leave)
    character(len=*), intent(in) :: path
    logical, intent(in) :: until_empty, all_leave
    integer, intent(in) :: max_steps
    type(config_t) :: cfg
    type(fom_t) :: fom
    type(step_record_t) :: rec
    type(error_t), allocatable :: err
    integer :: k, n_fail, n0, n_prev, bad_changes, sum_changes
    real(wp) :: worst, kkt
    call read_config(path, env, cfg, err)
    call check(.not. allocated(err), path // ": reads")
    if (allocated(err)) then
      print '(a)', err%message; return
    end if
    call check_config(cfg, err)
    call check(.not. allocated(err), path // ": valid")
    cfg%time%until_empty = until_empty
    cfg%time%max_steps = max_steps
    call fom%init(cfg, err)
    call check(.not. allocated(err), path // ": init")
    if (allocated(err)) then
      print '(a)', err%message; return
    end if
    worst = brute_min_gap(fom)
    call check(worst >= -1.0e-10_wp * fom%radius, path // ": initial configuration feasible")
    n0 = fom%n_inside()
    n_fail = 0; kkt = 0
    n_prev = 0; bad_changes = 0; sum_changes = 0
    do k = 1, max_steps
      if (until_empty .and. fom%n_inside() == 0) exit
      call fom%advance(rec, err)
      if (allocated(err)) then
        call check(.false., path // ": step " // str(k) // ": " // err%message); return
      end if
      ! active-set changes: every active row is one on the first step (no warm start); later
      ! at most the rows active now plus the rows active before (the warm start's)
      if (k == 1 .and. rec%n_changes /= rec%n_active) bad_changes = bad_changes + 1
      if (rec%n_changes < 0 .or. rec%n_changes > rec%n_active + n_prev) bad_changes = bad_changes + 1
      n_prev = rec%n_active; sum_changes = sum_changes + rec%n_changes
      if (.not. rec%converged) n_fail = n_fail + 1
      kkt = max(kkt, rec%kkt)
      worst = min(worst, brute_min_gap(fom))
    end do
    print '(a)', path // ": " // str(fom%step) // " steps, " // str(fom%n_agents - fom%n_inside()) // " of " // &
      str(fom%n_agents) // " left, deepest overlap " // str(-min(worst, 0.0_wp)) // ", max KKT " // str(kkt)
    call check(worst >= -1.0e-10_wp * fom%radius, path // ": no overlap deeper than round-off (min gap " // &
      str(worst) // ")")
    call check(n_fail == 0, path // ": every step converged")
    call check(bad_changes == 0 .and. sum_changes > 0, path // ": active-set changes counted (" // &
      str(sum_changes) // ")")
    call check(kkt <= 1.0e-9_wp, path // ": KKT residual <= 1e-9")
    if (all_leave) then
      call check(fom%n_inside() == 0, path // ": every agent leaves (" // str(fom%n_inside()) // " remain)")
    else
      call check(fom%n_inside() < n0, path // ": agents reach the exit")
    end if
  end subroutine run_scene

  !> Smallest true gap over all agent pairs and all agent-obstacle pairs (O(N^2)).
  real(wp) function brute_min_gap(fom) result(g)
    type(fom_t), intent(in) :: fom
    integer :: i, j, k
    real(wp) :: d, nrm(2)
    g = huge(1.0_wp)
    do i = 1, fom%n_agents
      do j = i + 1, fom%n_agents
        g = min(g, norm2(fom%q(2*i-1:2*i) - fom%q(2*j-1:2*j)) - 2 * fom%radius)
      end do
      do k = 1, fom%scene%n_obstacles()
        call obstacle_distance(fom%scene%obstacles(k), fom%q(2*i-1:2*i), d, nrm)
        g = min(g, d - fom%radius)
      end do
    end do
  end function brute_min_gap
end program test_fom_scenes
