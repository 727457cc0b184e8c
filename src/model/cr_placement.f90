!> Initial positions of the agents: random placement followed by overlap removal (the
!> paper's procedure, without an O(N^2) rejection loop), or positions read from a file.
!>
!> Overlap removal: repeat  q <- q + delta  with  delta = argmin |delta|^2  subject to
!> D_l(q) + G_l(q) . delta >= 0  for every pair/obstacle contact with gap <= a small cutoff,
!> solved exactly by the active-set projection (h = 1, zero desired velocity). Gaps are
!> convex functions of q, so every linearised row that holds also holds for the true gap;
!> a few iterations remove all overlaps. Failure to do so is reported, never ignored.
module cr_placement
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_config, only: agents_cfg_t
  use cr_scene, only: scene_t
  use cr_random, only: rng_t
  use cr_h5file, only: h5file_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  use cr_projection, only: projection_solver_t, projection_settings_t, solve_stats_t, &
    make_projection_solver
  implicit none
  private
  public :: place_agents, read_positions_text, read_positions_h5, check_feasible

contains

  !> Initial positions q [2*n_agents] from &agents (random + overlap removal, or file).
  subroutine place_agents(cfg, scene, q, iterations, error)
    type(agents_cfg_t), intent(in) :: cfg
    type(scene_t), intent(in) :: scene
    real(wp), allocatable, intent(out) :: q(:)
    integer, intent(out) :: iterations
    type(error_t), allocatable, intent(out) :: error
    type(rng_t) :: rng
    real(wp) :: reg(4)
    integer :: i
    iterations = 0
    if (cfg%init == 'file') then
      if (is_hdf5_name(trim(cfg%init_file))) then
        call read_positions_h5(trim(cfg%init_file), cfg%n_agents, q, error)
      else
        call read_positions_text(trim(cfg%init_file), cfg%n_agents, q, error)
      end if
      if (allocated(error)) return
      call check_feasible(scene, q, cfg%radius, "&agents: init_file '" // trim(cfg%init_file) // "'", error)
      return
    end if
    reg = cfg%region
    if (all(reg == 0)) reg = [0.0_wp, 0.0_wp, scene%length, scene%width]
    allocate(q(2 * cfg%n_agents))
    call rng%seed(cfg%seed)
    do i = 1, cfg%n_agents
      q(2*i-1) = reg(1) + cfg%radius + rng%uniform() * (reg(3) - reg(1) - 2 * cfg%radius)
      q(2*i) = reg(2) + cfg%radius + rng%uniform() * (reg(4) - reg(2) - 2 * cfg%radius)
    end do
    call separate(scene, q, cfg%radius, cfg%placement_max_iter, iterations, error)
  end subroutine place_agents

  !> Overlap removal by repeated exact projections (see module doc).
  subroutine separate(scene, q, radius, max_iter, iterations, error)
    type(scene_t), intent(in) :: scene
    real(wp), intent(inout) :: q(:)
    real(wp), intent(in) :: radius
    integer, intent(in) :: max_iter
    integer, intent(out) :: iterations
    type(error_t), allocatable, intent(out) :: error
    type(contact_set_t) :: cs
    type(cell_list_t) :: cells
    type(projection_settings_t) :: settings
    class(projection_solver_t), allocatable :: solver
    type(solve_stats_t) :: stats
    real(wp), allocatable :: v(:), delta(:), lambda(:)
    real(wp) :: margin, worst
    integer :: na, it
    na = size(q) / 2
    ! an iterative sparse solver: any N; exactness is not needed since the loop checks the
    ! true gaps and repeats
    settings%name = 'apgd'
    settings%tol = 1.0e-9_wp
    settings%max_iter = 20000
    call make_projection_solver(settings, solver, error)
    if (allocated(error)) return
    call cs%init(na, 1.0_wp, 8 * na)
    allocate(v(2 * na), delta(2 * na))
    v = 0.0_wp
    margin = 1.0e-9_wp * radius
    worst = 0.0_wp
    iterations = 0
    do it = 1, max_iter
      call build_contacts(scene, q, radius, 0.05_wp * radius, cells, cs)
      worst = 0.0_wp
      if (cs%n > 0) worst = minval(cs%gap(1:cs%n))
      if (worst >= 0.0_wp) exit
      iterations = it
      cs%gap(1:cs%n) = cs%gap(1:cs%n) - margin
      if (allocated(lambda)) deallocate(lambda)
      allocate(lambda(cs%n))
      lambda = 0.0_wp
      call solver%solve(cs, v, delta, lambda, stats, error)
      if (allocated(error)) return
      q = q + delta
    end do
    if (worst < 0.0_wp) then
      call set_error(error, "&agents: cannot make the initial configuration feasible: " // str(na) // &
        " agents of radius " // str(radius) // " still overlap by " // str(-worst) // " after " // &
        str(max_iter) // " projection iterations (placement_max_iter); use fewer agents or a larger region", 2)
    end if
  end subroutine separate

  !> Read n lines "x y" from a plain text file into q [2n].
  subroutine read_positions_text(path, n, q, error)
    character(len=*), intent(in) :: path
    integer, intent(in) :: n
    real(wp), allocatable, intent(out) :: q(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: u, ios, k
    character(len=256) :: msg
    allocate(q(2 * n))
    open(newunit=u, file=path, status='old', action='read', iostat=ios, iomsg=msg)
    if (ios /= 0) then
      call set_error(error, "&agents: init_file: cannot open '" // path // "' (" // trim(msg) // ")", 2)
      return
    end if
    do k = 1, n
      read(u, *, iostat=ios, iomsg=msg) q(2*k-1), q(2*k)
      if (ios /= 0) then
        call set_error(error, "&agents: init_file: '" // path // "' line " // str(k) // &
          ": expected two numbers 'x y' per agent for n_agents = " // str(n) // " (" // trim(msg) // ")", 2)
        close(u); return
      end if
    end do
    close(u)
    if (any(q /= q) .or. any(abs(q) > huge(1.0_wp) / 4)) &
      call set_error(error, "&agents: init_file: '" // path // "' has a non-finite value", 2)
  end subroutine read_positions_text

  logical function is_hdf5_name(path)
    character(len=*), intent(in) :: path
    integer :: n
    n = len(path)
    is_hdf5_name = .false.
    if (n > 3) is_hdf5_name = path(n-2:n) == '.h5'
    if (n > 5) is_hdf5_name = is_hdf5_name .or. path(n-4:n) == '.hdf5'
  end function is_hdf5_name

  !> Read q [2n] from an HDF5 file: dataset 'positions' [2n] (x1, y1, x2, ...) or, in a
  !> crowdrom full-order output, 'agents/initial_positions'.
  subroutine read_positions_h5(path, n, q, error)
    character(len=*), intent(in) :: path
    integer, intent(in) :: n
    real(wp), allocatable, intent(out) :: q(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: name
    call h5%open(path, error)
    if (allocated(error)) then
      error%message = "&agents: init_file: " // error%message; error%code = 2; return
    end if
    if (h5%exists("positions")) then
      name = "positions"
    else if (h5%exists("agents/initial_positions")) then
      name = "agents/initial_positions"
    else
      call set_error(error, "&agents: init_file: '" // path // &
        "' has neither a dataset 'positions' nor 'agents/initial_positions'", 2)
      call h5%close(e2); return
    end if
    call h5%read(name, q, error)
    call h5%close(e2)
    if (allocated(error)) then
      error%message = "&agents: init_file: " // error%message; error%code = 2; return
    end if
    if (size(q) /= 2 * n) then
      call set_error(error, "&agents: init_file: '" // path // "' dataset '" // name // "' has " // &
        str(size(q)) // " values, expected 2 * n_agents = " // str(2 * n), 2); return
    end if
    if (any(q /= q) .or. any(abs(q) > huge(1.0_wp) / 4)) &
      call set_error(error, "&agents: init_file: '" // path // "' has a non-finite value", 2)
  end subroutine read_positions_h5

  !> Error if two agents coincide or overlap, or an agent overlaps an obstacle, at q.
  subroutine check_feasible(scene, q, radius, where, error)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:)
    real(wp), intent(in) :: radius
    character(len=*), intent(in) :: where
    type(error_t), allocatable, intent(out) :: error
    type(contact_set_t) :: cs
    type(cell_list_t) :: cells
    integer :: l
    real(wp) :: tol
    tol = 1.0e-9_wp * radius
    call cs%init(size(q) / 2, 1.0_wp)
    call build_contacts(scene, q, radius, 0.0_wp, cells, cs)
    do l = 1, cs%n
      if (cs%ib(l) > 0) then
        if (cs%gap(l) <= -2 * radius + tol) then
          call set_error(error, where // ": agents " // str(cs%ia(l)) // " and " // str(cs%ib(l)) // &
            " are at the same position", 2); return
        else if (cs%gap(l) < -tol) then
          call set_error(error, where // ": agents " // str(cs%ia(l)) // " and " // str(cs%ib(l)) // &
            " overlap by " // str(-cs%gap(l)), 2); return
        end if
      else if (cs%gap(l) < -tol) then
        call set_error(error, where // ": agent " // str(cs%ia(l)) // " starts inside obstacle '" // &
          scene%obstacles(cs%ob(l))%label // "' (gap " // str(cs%gap(l)) // ")", 2); return
      end if
    end do
  end subroutine check_feasible
end module cr_placement
