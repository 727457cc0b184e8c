!> The &study namelist group: which parameters of the full-order model vary, over which box,
!> how the training and validation samples are drawn, and where the snapshot database goes.
!>
!>   &study n_params = 2, param_name = 'l_exit', 'speed', param_min = 0.28, 4.5,
!>          param_max = 0.36, 5.5, sampling = 'random', n_train = 200, n_valid = 50, seed = 1,
!>          database = 'results/congested150_snapshots.h5' /
!>
!> Parameter names: 'l_exit' (exit width, m), 'l_exit2' (second exit, right wall, m), 'speed' (one desired speed c shared by every
!> agent, m/s), 'speeds' (each agent's speed c_i drawn independently in [param_min, param_max]:
!> n_agents components), 'speed_mean' and 'speed_spread' (together: each agent's speed drawn
!> uniformly on [mean - spread, mean + spread] from a per-sample seed component, see
!> cr_param_model; mean > 0, spread >= 0 and spread <= mean over the whole box, so that no speed
!> is negative). Bounds are absolute. Reading follows cr_config (defaults, iostat,
!> message naming file and group); check_study collects every problem.
module cr_study_config
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, problems_t
  use cr_strings, only: str, to_lower
  use cr_namelist_text, only: namelist_text_t
  use cr_config, only: config_t, config_echo, MAX_PATH, model_inputs
  use cr_paths, only: io_paths_t
  use cr_sane, only: need_sane, MAX_LENGTH, MAX_SPEED
  use cr_hash, only: hash_text
  use cr_param_model, only: KNOWN_PARAMS, KNOWN_PARAMS_TEXT
  use cr_snapshot_file, only: SNAP_SCHEMA
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: check_study_paths
  public :: study_cfg_t, read_study, check_study, study_echo, study_hash, MAX_PARAMS, KNOWN_PARAMS

  !> most parameters in one study ('speeds' counts as one here)
  integer, parameter :: MAX_PARAMS = 8
  !> the largest training or validation set (samples)
  integer, parameter :: MAX_SAMPLES = 1000000

  !> &study: parameters, sampling, database.
  type :: study_cfg_t
    integer :: n_params = 0
    character(len=16) :: param_name(MAX_PARAMS) = ''
    !> absolute bounds of each parameter (units of the parameter)
    real(wp) :: param_min(MAX_PARAMS) = 0.0_wp
    real(wp) :: param_max(MAX_PARAMS) = 0.0_wp
    !> 'random' (uniform in the box, reproducible from seed) or 'grid' (tensor grid for training)
    character(len=16) :: sampling = 'random'
    !> grid points per parameter (sampling = 'grid'); product must equal n_train
    integer :: grid_n(MAX_PARAMS) = 0
    integer :: n_train = 200
    integer :: n_valid = 50
    integer :: seed = 1
    character(len=MAX_PATH) :: database = 'snapshots.h5'
  end type study_cfg_t

contains

  !> Read &study from the loaded namelist text (the group is required).
  subroutine read_study(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(study_cfg_t), intent(out) :: c
    type(error_t), allocatable, intent(out) :: error
    integer :: n_params, grid_n(MAX_PARAMS), n_train, n_valid, seed
    character(len=16) :: param_name(MAX_PARAMS), sampling
    real(wp) :: param_min(MAX_PARAMS), param_max(MAX_PARAMS)
    character(len=MAX_PATH) :: database
    namelist /study/ n_params, param_name, param_min, param_max, sampling, grid_n, n_train, &
      n_valid, seed, database
    integer :: ios, k
    character(len=512) :: msg
    if (.not. t%has_group('study')) then
      call set_error(error, t%path // ": no namelist group &study (a parameter study needs one)", EXIT_BAD_INPUT)
      return
    end if
    n_params = c%n_params; param_name = c%param_name; param_min = c%param_min
    param_max = c%param_max; sampling = c%sampling; grid_n = c%grid_n; n_train = c%n_train
    n_valid = c%n_valid; seed = c%seed; database = c%database
    msg = ''
    read(t%lines, nml=study, iostat=ios, iomsg=msg)
    if (ios /= 0) then
      call set_error(error, t%path // ": namelist group &study: " // trim(msg), EXIT_BAD_INPUT); return
    end if
    c%n_params = n_params; c%param_min = param_min; c%param_max = param_max
    do k = 1, MAX_PARAMS
      c%param_name(k) = to_lower(adjustl(param_name(k)))
    end do
    c%sampling = to_lower(adjustl(sampling)); c%grid_n = grid_n; c%n_train = n_train
    c%n_valid = n_valid; c%seed = seed; c%database = database
  end subroutine read_study

  !> crowd_snapshots' outputs (&study database, the --summary file) checked against its
  !> inputs and each other, before any work (see cr_paths).
  subroutine check_study_paths(input, summary, cfg, s, error)
    character(len=*), intent(in) :: input, summary
    type(config_t), intent(in) :: cfg
    type(study_cfg_t), intent(in) :: s
    type(error_t), allocatable, intent(out) :: error
    type(io_paths_t) :: paths
    call paths%input("file", input)
    call model_inputs(cfg, paths)
    call paths%output("&study database", s%database)
    call paths%output("--summary", summary)
    call paths%check(input, error)
  end subroutine check_study_paths

  !> Check &study against the model configuration; `error` lists every problem.
  subroutine check_study(s, cfg, error)
    type(study_cfg_t), intent(in) :: s
    type(config_t), intent(in) :: cfg
    type(error_t), allocatable, intent(out) :: error
    type(problems_t) :: probs
    integer :: k, j, np, ngrid
    integer(i8) :: ngrid8
    character(len=:), allocatable :: nm
    np = min(max(s%n_params, 0), MAX_PARAMS)
    do k = 1, np
      if (index(s%param_name(k), 'speed') == 1) then
        call need_sane(probs, s%param_min(k), "&study: param_min(" // str(k) // ")", MAX_SPEED)
        call need_sane(probs, s%param_max(k), "&study: param_max(" // str(k) // ")", MAX_SPEED)
      else
        call need_sane(probs, s%param_min(k), "&study: param_min(" // str(k) // ")", MAX_LENGTH)
        call need_sane(probs, s%param_max(k), "&study: param_max(" // str(k) // ")", MAX_LENGTH)
      end if
    end do
    ! non-finite bounds are reported alone (the comparisons below would trap on NaN)
    if (probs%n > 0) then
      call probs%to_error("", error); return
    end if
    call probs%need(s%n_params >= 1 .and. s%n_params <= MAX_PARAMS, "&study: n_params must be in 1.." // &
      str(MAX_PARAMS) // " (got " // str(s%n_params) // ")")
    do k = 1, np
      nm = trim(s%param_name(k))
      if (.not. any(KNOWN_PARAMS == nm)) call probs%need(.false., "&study: param_name(" // str(k) // ") = '" // &
        nm // "' is not a known parameter (known: " // KNOWN_PARAMS_TEXT // ")")
      do j = 1, k - 1
        call probs%need(s%param_name(j) /= s%param_name(k), "&study: parameter '" // nm // "' is given twice")
      end do
      if (.not. (s%param_min(k) < s%param_max(k))) then
        call probs%need(.false., "&study: empty range for parameter " // str(k) // " '" // nm // &
          "': param_min = " // str(s%param_min(k)) // " must be < param_max = " // str(s%param_max(k)))
      else if (nm == 'l_exit') then
        call probs%need(s%param_min(k) > 0 .and. s%param_max(k) <= cfg%scene%hall_length, &
          "&study: l_exit range [" // str(s%param_min(k)) // ", " // str(s%param_max(k)) // &
          "] must lie in (0, hall_length = " // str(cfg%scene%hall_length) // "]")
        if (cfg%scene%exit_center >= 0) call probs%need(cfg%scene%exit_center - s%param_max(k) / 2 >= 0 .and. &
          cfg%scene%exit_center + s%param_max(k) / 2 <= cfg%scene%hall_length, &
          "&study: l_exit up to " // str(s%param_max(k)) // " puts the opening outside the wall (exit_center = " &
          // str(cfg%scene%exit_center) // ")")
      else if (nm == 'l_exit2') then
        call probs%need(s%param_min(k) > 0 .and. s%param_max(k) <= cfg%scene%hall_width, &
          "&study: l_exit2 range [" // str(s%param_min(k)) // ", " // str(s%param_max(k)) // &
          "] must lie in (0, hall_width = " // str(cfg%scene%hall_width) // "]")
        if (cfg%scene%exit2_center >= 0) call probs%need(cfg%scene%exit2_center - s%param_max(k) / 2 >= 0 .and. &
          cfg%scene%exit2_center + s%param_max(k) / 2 <= cfg%scene%hall_width, &
          "&study: l_exit2 up to " // str(s%param_max(k)) // " puts the second opening outside the right wall " // &
          "(exit2_center = " // str(cfg%scene%exit2_center) // ")")
      else if (nm == 'speed_mean') then
        call probs%need(s%param_min(k) > 0, "&study: param_min(" // str(k) // ") = " // str(s%param_min(k)) // &
          ": the speed_mean range must be > 0")
      else if (nm == 'speed_spread') then
        call probs%need(s%param_min(k) >= 0, "&study: param_min(" // str(k) // ") = " // str(s%param_min(k)) // &
          ": the speed_spread range must be >= 0")
      else if (nm == 'speed' .or. nm == 'speeds') then
        call probs%need(s%param_min(k) >= 0, "&study: " // nm // " range must be >= 0 (param_min = " // &
          str(s%param_min(k)) // ")")
      end if
      ! prescribed desired velocities ignore the speeds: every sample would be the same
      if (index(nm, 'speed') == 1) call probs%need(cfg%desired%mode /= 'file', "&study: parameter '" // nm // &
        "' has no effect with &desired mode = 'file' (prescribed velocities): every sample would be identical")
    end do
    if (any(s%param_name(1:np) == 'speed') .and. any(s%param_name(1:np) == 'speeds')) &
      call probs%need(.false., "&study: 'speed' (one common speed) and 'speeds' (one per agent) exclude each other")
    call check_spread(s, np, probs)
    do k = np + 1, MAX_PARAMS
      call probs%need(len_trim(s%param_name(k)) == 0, "&study: param_name(" // str(k) // ") = '" // &
        trim(s%param_name(k)) // "' is beyond n_params = " // str(s%n_params))
    end do
    call probs%need(s%n_train >= 1, "&study: n_train must be >= 1 (got " // str(s%n_train) // ": zero samples)")
    call probs%need(s%n_valid >= 0, "&study: n_valid must be >= 0 (got " // str(s%n_valid) // ")")
    call probs%need(s%n_train <= MAX_SAMPLES, "&study: n_train = " // str(s%n_train) // " exceeds " // &
      str(MAX_SAMPLES) // " samples")
    call probs%need(s%n_valid <= MAX_SAMPLES, "&study: n_valid = " // str(s%n_valid) // " exceeds " // &
      str(MAX_SAMPLES) // " samples")
    ! the database stores one column per sample and step: the count must fit its indices
    if (cfg%time%n_steps >= 1 .and. s%n_train >= 0 .and. s%n_valid >= 0) then
      call probs%need((int(s%n_train, i8) + s%n_valid) * cfg%time%n_steps <= int(huge(1), i8), &
        "&study: (n_train + n_valid) * n_steps = " // str((int(s%n_train, i8) + s%n_valid) * cfg%time%n_steps) // &
        " snapshots exceeds " // str(huge(1)))
    end if
    call probs%need(s%seed >= 0, "&study: seed must be >= 0 (got " // str(s%seed) // ")")
    call probs%need(len_trim(s%database) > 0, "&study: database must name a file")
    select case (trim(s%sampling))
    case ('random')
    case ('grid')
      call probs%need(.not. any(s%param_name(1:np) == 'speeds'), "&study: sampling = 'grid' cannot vary " // &
        "'speeds' (one component per agent); use 'speed' or sampling = 'random'")
      call probs%need(.not. any(s%param_name(1:np) == 'speed_spread'), "&study: sampling = 'grid' cannot vary " // &
        "'speed_spread' (its speed_seed component is drawn); use sampling = 'random'")
      call probs%need(all(s%grid_n(1:np) >= 1), "&study: sampling = 'grid' needs grid_n(1:n_params) >= 1")
      if (all(s%grid_n(1:np) >= 1) .and. np >= 1) then
        ngrid8 = product(int(s%grid_n(1:np), i8))
        ngrid = int(min(ngrid8, int(huge(1), i8)))
        call probs%need(ngrid8 == s%n_train, "&study: grid_n gives " // str(ngrid8) // " training samples but n_train = " &
          // str(s%n_train))
      end if
    case default
      call probs%need(.false., "&study: sampling = '" // trim(s%sampling) // "' is not one of 'random', 'grid'")
    end select
    call probs%need(.not. cfg%time%until_empty, "&time: until_empty = .true. is not allowed in a study " // &
      "(every sample runs n_steps steps)")
    call probs%need(cfg%time%n_steps >= 1, "&time: n_steps must be >= 1 in a study (got " // str(cfg%time%n_steps) // ")")
    call probs%to_error("", error)

  end subroutine check_study

  !> The heterogeneous population's parameters: 'speed_mean' and 'speed_spread' together, without
  !> 'speed' / 'speeds', and spread <= mean everywhere in the box (no negative speed).
  subroutine check_spread(s, np, probs)
    type(study_cfg_t), intent(in) :: s
    integer, intent(in) :: np
    type(problems_t), intent(inout) :: probs
    integer :: km, ks
    km = findloc(s%param_name(1:np), 'speed_mean', dim=1)
    ks = findloc(s%param_name(1:np), 'speed_spread', dim=1)
    if (km == 0 .and. ks == 0) return
    if (km == 0 .or. ks == 0) then
      call probs%need(.false., "&study: param_name: 'speed_mean' and 'speed_spread' go together (the mean " // &
        "and the spread of the agents' speeds)"); return
    end if
    call probs%need(.not. any(s%param_name(1:np) == 'speed' .or. s%param_name(1:np) == 'speeds'), &
      "&study: param_name: 'speed_mean' / 'speed_spread' exclude 'speed' and 'speeds'")
    call probs%need(s%param_max(ks) <= s%param_min(km), "&study: param_max(" // str(ks) // ") = " // &
      str(s%param_max(ks)) // ": the speed_spread range must not exceed param_min(" // str(km) // ") = " // &
      str(s%param_min(km)) // " of speed_mean (a speed mean - spread < 0)")
  end subroutine check_spread

  !> &study as a re-readable namelist group (without database when with_database is false).
  function study_echo(s, with_database) result(t)
    type(study_cfg_t), intent(in) :: s
    logical, intent(in), optional :: with_database
    character(len=:), allocatable :: t
    integer :: k, np
    logical :: db
    character(len=32) :: b
    db = .true.
    if (present(with_database)) db = with_database
    np = min(max(s%n_params, 0), MAX_PARAMS)
    t = "&study n_params = " // str(s%n_params) // ", param_name = "
    do k = 1, np
      t = t // "'" // trim(s%param_name(k)) // "'" // merge(", ", "  ", k < np)
    end do
    t = trim(t) // ", param_min = "
    do k = 1, np
      write(b, '(es23.16)') s%param_min(k)
      t = t // trim(adjustl(b)) // merge(", ", "  ", k < np)
    end do
    t = trim(t) // ", param_max = "
    do k = 1, np
      write(b, '(es23.16)') s%param_max(k)
      t = t // trim(adjustl(b)) // merge(", ", "  ", k < np)
    end do
    t = trim(t) // ", sampling = '" // trim(s%sampling) // "'"
    if (s%sampling == 'grid') then
      t = t // ", grid_n = "
      do k = 1, np
        t = t // str(s%grid_n(k)) // merge(", ", "  ", k < np)
      end do
      t = trim(t)
    end if
    t = t // ", n_train = " // str(s%n_train) // ", n_valid = " // str(s%n_valid) // ", seed = " // &
      str(s%seed)
    if (db) t = t // ", database = '" // trim(s%database) // "'"
    t = t // " /" // new_line('a')
  end function study_echo

  !> Fingerprint of everything that determines the snapshots: the model configuration (without
  !> its source line and &output) and &study (without the database name).
  function study_hash(cfg, s, schema_version) result(h)
    type(config_t), intent(in) :: cfg
    type(study_cfg_t), intent(in) :: s
    integer, intent(in) :: schema_version
    character(len=16) :: h
    character(len=:), allocatable :: e, kept
    integer :: i0, i1
    e = config_echo(cfg)
    kept = ""
    i0 = 1
    do while (i0 <= len(e))
      i1 = index(e(i0:), new_line('a'))
      if (i1 == 0) then
        i1 = len(e)
      else
        i1 = i0 + i1 - 1
      end if
      if (e(i0:i0) /= '!' .and. index(e(i0:i1), '&output') /= 1) kept = kept // e(i0:i1)
      i0 = i1 + 1
    end do
    h = hash_text(SNAP_SCHEMA // " v" // str(schema_version) // new_line('a') // kept // &
      study_echo(s, with_database=.false.))
  end function study_hash
end module cr_study_config
