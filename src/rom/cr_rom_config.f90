!> Configuration of crowd_rom (the online reduced model and its accuracy/speed sweep), one
!> namelist group per concern: &rom (files, samples, timing repeats), &sweep (the settings),
!> &reduced (the reduced solver), &fom_timing (the full-order reference timing).
!>
!> A sweep is a list of settings k = 1..n_settings, one per positive entry of &sweep n(:):
!> (n(k), r(k)) chooses a reduced model prepared by crowd_offline, hyper(k) its assembly
!> ('none': exact projection of the selected terms, 'eim', 'eq'), contacts(k) the enforced
!> constraints ('cone': the reduced cone; 'online': the contacts near in the reduced
!> positions at each step), m_v/m_b/m_d(k) the interpolation / quadrature points (0: the
!> paper's defaults 2 Nb, R, 2 R, capped by what the ROM file stores), correction(k) what
!> happens after each reduced step ('none': the reduced positions as they are; 'local': the
!> local exact correction of cr_local_correction with the exact full-order solver of
!> &fom_timing, the positions then carried in full, see cr_rom_stepper), sets(k) the
!> parameter sets it runs on ('': all those of &rom sets).
module cr_rom_config
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, problems_t
  use cr_strings, only: str
  use cr_reduced_solver, only: is_reduced_solver, known_reduced_solvers
  use cr_namelist_text, only: namelist_text_t
  use cr_config, only: nml_status
  use cr_paths, only: io_paths_t
  use cr_sane, only: need_sane, MAX_SPEED
  use cr_hyper_factory, only: hyper_known, hyper_name_list
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: check_rom_paths
  public :: rom_cfg_t, read_rom, read_rom_groups, check_rom, rom_echo, MAX_SETTINGS, MAX_MU, EXACT_SOLVERS

  integer, parameter :: MAX_SETTINGS = 64, MAX_PATH = 512, MAX_MU = 1024
  !> the exact full-order solvers &fom_timing exact_solver = 'fastest' times
  character(len=*), parameter :: EXACT_SOLVERS(2) = [character(len=17) :: 'sparse_active_set', 'active_set']

  !> Online reduced-model run.
  type :: rom_cfg_t
    !> ROM file (crowd_offline) and snapshot database ('' = the one named in the ROM file)
    character(len=MAX_PATH) :: rom_file = ''
    character(len=MAX_PATH) :: database = ''
    !> result file (schema crowdrom-romrun) and the sweep table (CSV; '' = output with .csv)
    character(len=MAX_PATH) :: output = ''
    character(len=MAX_PATH) :: table = ''
    !> parameters: 'valid', 'train', 'both' (database samples) or 'given' (mu below)
    character(len=8) :: sets = 'valid'
    !> use only the first n_samples samples of each set (0: all)
    integer :: n_samples = 0
    !> the parameter of sets = 'given' (expanded components, as in the database's params)
    real(wp) :: mu(MAX_MU) = -huge(1.0_wp)
    !> settings of the sweep
    integer :: n(MAX_SETTINGS) = 0
    integer :: r(MAX_SETTINGS) = 0
    character(len=8) :: hyper(MAX_SETTINGS) = 'eq'
    character(len=8) :: contacts(MAX_SETTINGS) = 'cone'
    integer :: m_v(MAX_SETTINGS) = 0
    integer :: m_b(MAX_SETTINGS) = 0
    integer :: m_d(MAX_SETTINGS) = 0
    !> after each reduced step: 'none' or 'local' (local exact correction)
    character(len=8) :: correction(MAX_SETTINGS) = 'none'
    !> the parameter sets of this setting: '' (those of &rom sets) or one of them ('valid',
    !> 'train'): an expensive setting (e.g. the local correction) measured on the validation
    !> set only while the ML correction's setting runs on both
    character(len=8) :: setting_sets(MAX_SETTINGS) = ''
    !> reduced solver: 'dual' (warm-started dual active set on the active rows' Gram, with
    !> 'nnls' as certified fallback), 'nnls' (Lawson-Hanson active set, warm started) or
    !> 'uzawa' (the paper's)
    character(len=8) :: solver = 'dual'
    integer :: nnls_max_iter = 0
    !> reduced Uzawa: rho = uzawa_rho_factor / h^2, stopping test, cap
    real(wp) :: uzawa_rho_factor = 0.2_wp
    real(wp) :: uzawa_eps = 1.0e-12_wp
    integer :: uzawa_max_iter = 1000000
    !> full-order reference timing: samples; the paper's Uzawa (rho = 0.2 / h^2, cold start,
    !> stopped at relative changes <= fom_uzawa_eps) and the exact solver (scaled KKT <= fom_tol)
    integer :: fom_timing_samples = 3
    real(wp) :: fom_tol = 1.0e-10_wp
    real(wp) :: fom_uzawa_eps = 1.0e-12_wp
    !> time the Uzawa reference on the first fom_uzawa_steps steps only (0: all steps); the
    !> paper's Uzawa can need 1e5-1e6 iterations per step on congested scenes
    integer :: fom_uzawa_steps = 0
    !> rows of the Uzawa reference: 'all' (the paper's full-order model: every agent pair and
    !> agent-obstacle pair is a constraint row) or 'near' (this project's neighbour list)
    character(len=8) :: fom_uzawa_rows = 'all'
    !> exact full-order solver of the reference (and of the local correction): 'fastest'
    !> (time every exact solver of this build, EXACT_SOLVERS, and keep the fastest per step),
    !> or one of them by name ('gpcg' also accepted)
    character(len=32) :: fom_exact_solver = 'fastest'
    !> repetitions of each reduced run for the timing (the fastest is kept)
    integer :: timing_repeats = 3
  end type rom_cfg_t

contains

  !> Read the groups of crowd_rom: &rom (required: files and samples), &sweep (the settings),
  !> &reduced (the reduced solver), &fom_timing (the full-order reference timing).
  subroutine read_rom(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(rom_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    if (.not. t%has_group('rom')) then
      call set_error(error, t%path // ": namelist group &rom is missing", EXIT_BAD_INPUT); return
    end if
    call read_rom_groups(t, c, error)
  end subroutine read_rom

  !> Read whichever of crowd_rom's groups (&rom, &sweep, &reduced, &fom_timing) `t` holds (an
  !> absent group keeps its defaults): the variables of each group present are checked, also
  !> in a file read by another program.
  subroutine read_rom_groups(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(rom_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    call read_files(error); if (allocated(error)) return
    call read_sweep(error); if (allocated(error)) return
    call read_reduced(error); if (allocated(error)) return
    call read_timing(error); if (allocated(error)) return
    if (len_trim(c%table) == 0 .and. len_trim(c%output) > 0) then
      if (index(c%output, '.h5', back=.true.) == len_trim(c%output) - 2 .and. len_trim(c%output) > 3) then
        c%table = c%output(1:len_trim(c%output) - 3) // '.csv'
      else
        c%table = trim(c%output) // '.csv'
      end if
    end if

  contains

    subroutine read_files(error)
      type(error_t), allocatable, intent(out) :: error
      character(len=MAX_PATH) :: rom_file, database, output, table
      character(len=8) :: sets
      integer :: n_samples, timing_repeats
      real(wp) :: mu(MAX_MU)
      namelist /rom/ rom_file, database, output, table, sets, n_samples, mu, timing_repeats
      integer :: ios
      character(len=512) :: msg
      rom_file = c%rom_file; database = c%database; output = c%output; table = c%table; sets = c%sets
      n_samples = c%n_samples; mu = c%mu; timing_repeats = c%timing_repeats
      msg = ''
      read(t%lines, nml=rom, iostat=ios, iomsg=msg)
      call nml_status(t, 'rom', ios, msg, error); if (allocated(error)) return
      c%rom_file = rom_file; c%database = database; c%output = output; c%table = table; c%sets = sets
      c%n_samples = n_samples; c%mu = mu; c%timing_repeats = timing_repeats
    end subroutine read_files

    subroutine read_sweep(error)
      type(error_t), allocatable, intent(out) :: error
      character(len=8) :: hyper(MAX_SETTINGS), contacts(MAX_SETTINGS), correction(MAX_SETTINGS), sets(MAX_SETTINGS)
      integer :: n(MAX_SETTINGS), r(MAX_SETTINGS), m_v(MAX_SETTINGS), m_b(MAX_SETTINGS), m_d(MAX_SETTINGS)
      namelist /sweep/ n, r, hyper, contacts, m_v, m_b, m_d, correction, sets
      integer :: ios
      character(len=512) :: msg
      n = c%n; r = c%r; hyper = c%hyper; contacts = c%contacts; m_v = c%m_v; m_b = c%m_b; m_d = c%m_d
      correction = c%correction; sets = c%setting_sets
      msg = ''
      read(t%lines, nml=sweep, iostat=ios, iomsg=msg)
      call nml_status(t, 'sweep', ios, msg, error); if (allocated(error)) return
      c%n = n; c%r = r; c%hyper = hyper; c%contacts = contacts; c%m_v = m_v; c%m_b = m_b; c%m_d = m_d
      c%correction = correction; c%setting_sets = sets
    end subroutine read_sweep

    subroutine read_reduced(error)
      type(error_t), allocatable, intent(out) :: error
      character(len=8) :: solver
      integer :: nnls_max_iter, uzawa_max_iter
      real(wp) :: uzawa_rho_factor, uzawa_eps
      namelist /reduced/ solver, nnls_max_iter, uzawa_rho_factor, uzawa_eps, uzawa_max_iter
      integer :: ios
      character(len=512) :: msg
      solver = c%solver; nnls_max_iter = c%nnls_max_iter; uzawa_rho_factor = c%uzawa_rho_factor
      uzawa_eps = c%uzawa_eps; uzawa_max_iter = c%uzawa_max_iter
      msg = ''
      read(t%lines, nml=reduced, iostat=ios, iomsg=msg)
      call nml_status(t, 'reduced', ios, msg, error); if (allocated(error)) return
      c%solver = solver; c%nnls_max_iter = nnls_max_iter; c%uzawa_rho_factor = uzawa_rho_factor
      c%uzawa_eps = uzawa_eps; c%uzawa_max_iter = uzawa_max_iter
    end subroutine read_reduced

    subroutine read_timing(error)
      type(error_t), allocatable, intent(out) :: error
      character(len=32) :: exact_solver
      character(len=8) :: uzawa_rows
      integer :: samples, uzawa_steps
      real(wp) :: tol, uzawa_eps
      namelist /fom_timing/ samples, tol, uzawa_eps, uzawa_steps, uzawa_rows, exact_solver
      integer :: ios
      character(len=512) :: msg
      samples = c%fom_timing_samples; tol = c%fom_tol; uzawa_eps = c%fom_uzawa_eps
      uzawa_steps = c%fom_uzawa_steps; uzawa_rows = c%fom_uzawa_rows; exact_solver = c%fom_exact_solver
      msg = ''
      read(t%lines, nml=fom_timing, iostat=ios, iomsg=msg)
      call nml_status(t, 'fom_timing', ios, msg, error); if (allocated(error)) return
      c%fom_timing_samples = samples; c%fom_tol = tol; c%fom_uzawa_eps = uzawa_eps
      c%fom_uzawa_steps = uzawa_steps; c%fom_uzawa_rows = uzawa_rows; c%fom_exact_solver = exact_solver
    end subroutine read_timing
  end subroutine read_rom_groups

  !> crowd_rom's outputs (&rom output and table, the --summary file) checked against its
  !> inputs (the namelist, the ROM file, the snapshot database `database`, which may come
  !> from the ROM file) and each other, before any work.
  subroutine check_rom_paths(input, summary, c, database, error)
    character(len=*), intent(in) :: input, summary, database
    type(rom_cfg_t), intent(in) :: c
    type(error_t), allocatable, intent(out) :: error
    type(io_paths_t) :: paths
    call paths%input("file", input)
    call paths%input("&rom rom_file", c%rom_file)
    call paths%input("snapshot database", database)
    call paths%output("&rom output", c%output)
    call paths%output("&rom table", c%table)
    call paths%output("--summary", summary)
    call paths%check(input, error)
  end subroutine check_rom_paths

  !> Validate &rom; all problems reported at once.
  subroutine check_rom(path, c, error)
    character(len=*), intent(in) :: path
    type(rom_cfg_t), intent(in) :: c
    type(error_t), allocatable, intent(out) :: error
    type(problems_t) :: probs
    integer :: k
    ! every real finite and of a sane magnitude (a parameter of Inf or 1e308 would never end)
    call need_sane(probs, c%uzawa_rho_factor, "&reduced: uzawa_rho_factor", 1.0e12_wp)
    call need_sane(probs, c%uzawa_eps, "&reduced: uzawa_eps", 1.0_wp)
    call need_sane(probs, c%fom_tol, "&fom_timing: tol", 1.0_wp)
    call need_sane(probs, c%fom_uzawa_eps, "&fom_timing: uzawa_eps", 1.0_wp)
    do k = 1, MAX_MU
      if (c%mu(k) == -huge(1.0_wp)) cycle
      call need_sane(probs, c%mu(k), "&rom: mu(" // str(k) // ")", MAX_SPEED)
    end do
    if (probs%n > 0) then
      call probs%to_error(path, error); return
    end if
    call probs%need(len_trim(c%rom_file) > 0, "&rom: rom_file must be given")
    call probs%need(len_trim(c%output) > 0, "&rom: output must be given")
    call probs%need(any(c%sets == [character(len=8) :: 'valid', 'train', 'both', 'given']), &
      "&rom: sets must be 'valid', 'train', 'both' or 'given' (got '" // trim(c%sets) // "')")
    call probs%need(c%sets /= 'given' .or. c%mu(1) > -huge(1.0_wp), "&rom: sets = 'given' needs mu")
    call probs%need(c%n_samples >= 0, "&rom: n_samples must be >= 0 (0: all)")
    call probs%need(all(c%n >= 0), "&sweep: n(:) must be >= 0")
    call probs%need(all(c%r >= 0), "&sweep: r(:) must be >= 0")
    do k = 1, MAX_SETTINGS
      if (c%n(k) == 0) cycle
      call probs%need(hyper_known(c%hyper(k)), &
        "&sweep: hyper(" // str(k) // ") must be one of " // hyper_name_list() // " (got '" // trim(c%hyper(k)) // "')")
      call probs%need(c%contacts(k) == 'cone' .or. c%contacts(k) == 'online', &
        "&sweep: contacts(" // str(k) // ") must be 'cone' or 'online' (got '" // trim(c%contacts(k)) // "')")
      call probs%need(c%contacts(k) /= 'online' .or. c%hyper(k) == 'none', &
        "&sweep: contacts(" // str(k) // ") = 'online' needs hyper(" // str(k) // ") = 'none' (the online rows " // &
        "are assembled exactly)")
      call probs%need(c%m_v(k) >= 0 .and. c%m_b(k) >= 0 .and. c%m_d(k) >= 0, &
        "&sweep: m_v, m_b, m_d(" // str(k) // ") must be >= 0 (0: defaults)")
      call probs%need(c%correction(k) == 'none' .or. c%correction(k) == 'local', &
        "&sweep: correction(" // str(k) // ") must be 'none' or 'local' (got '" // trim(c%correction(k)) // "')")
      call probs%need(len_trim(c%setting_sets(k)) == 0 .or. c%setting_sets(k) == c%sets .or. &
        (c%sets == 'both' .and. any(c%setting_sets(k) == [character(len=8) :: 'valid', 'train'])), &
        "&sweep: sets(" // str(k) // ") must be '' or one of the sets of &rom sets = '" // trim(c%sets) // &
        "' (got '" // trim(c%setting_sets(k)) // "')")
    end do
    call probs%need(is_reduced_solver(c%solver), "&reduced: solver must be one of " // known_reduced_solvers // &
      " (got '" // trim(c%solver) // "')")
    call probs%need(c%nnls_max_iter >= 0, "&reduced: nnls_max_iter must be >= 0 (0: default)")
    call probs%need(c%uzawa_rho_factor > 0, "&reduced: uzawa_rho_factor must be > 0")
    call probs%need(c%uzawa_eps > 0, "&reduced: uzawa_eps must be > 0")
    call probs%need(c%uzawa_max_iter >= 1, "&reduced: uzawa_max_iter must be >= 1")
    call probs%need(c%fom_timing_samples >= 0, "&fom_timing: samples must be >= 0")
    call probs%need(c%fom_tol > 0, "&fom_timing: tol must be > 0")
    call probs%need(c%fom_uzawa_eps > 0, "&fom_timing: uzawa_eps must be > 0")
    call probs%need(c%fom_uzawa_steps >= 0, "&fom_timing: uzawa_steps must be >= 0 (0: all steps)")
    call probs%need(c%fom_uzawa_rows == 'all' .or. c%fom_uzawa_rows == 'near', &
      "&fom_timing: uzawa_rows must be 'all' or 'near' (got '" // trim(c%fom_uzawa_rows) // "')")
    call probs%need(any(c%fom_exact_solver == [character(len=32) :: 'fastest', 'sparse_active_set', 'active_set', &
      'gpcg']), "&fom_timing: exact_solver must be 'fastest', 'sparse_active_set', 'active_set' or 'gpcg' (got '" // &
      trim(c%fom_exact_solver) // "')")
    call probs%need(c%timing_repeats >= 1, "&rom: timing_repeats must be >= 1")
    call probs%to_error(path, error)
  end subroutine check_rom

  !> The groups as re-readable namelist text.
  function rom_echo(c) result(s)
    type(rom_cfg_t), intent(in) :: c
    character(len=:), allocatable :: s
    character(len=*), parameter :: nl = new_line('a')
    integer :: k
    s = "&rom rom_file = '" // trim(c%rom_file) // "', database = '" // trim(c%database) // "', output = '" // &
      trim(c%output) // "', table = '" // trim(c%table) // "', sets = '" // trim(c%sets) // "', n_samples = " // &
      str(c%n_samples) // ", timing_repeats = " // str(c%timing_repeats)
    if (c%sets == 'given') then
      s = s // nl // "  mu = " // str(c%mu(1), "es23.16")
      do k = 2, MAX_MU
        if (c%mu(k) <= -huge(1.0_wp)) exit
        s = s // ", " // str(c%mu(k), "es23.16")
      end do
    end if
    s = s // " /" // nl // "&sweep"
    do k = 1, MAX_SETTINGS
      if (c%n(k) == 0) cycle
      s = s // nl // "  n(" // str(k) // ") = " // str(c%n(k)) // ", r(" // str(k) // ") = " // &
        str(c%r(k)) // ", hyper(" // str(k) // ") = '" // trim(c%hyper(k)) // "', contacts(" // str(k) // &
        ") = '" // trim(c%contacts(k)) // "', m_v(" // str(k) // ") = " // str(c%m_v(k)) // ", m_b(" // &
        str(k) // ") = " // str(c%m_b(k)) // ", m_d(" // str(k) // ") = " // str(c%m_d(k)) // &
        ", correction(" // str(k) // ") = '" // trim(c%correction(k)) // "'"
      if (len_trim(c%setting_sets(k)) > 0) s = s // ", sets(" // str(k) // ") = '" // trim(c%setting_sets(k)) // "'"
    end do
    s = s // " /" // nl // "&reduced solver = '" // trim(c%solver) // "', nnls_max_iter = " // str(c%nnls_max_iter) // &
      ", uzawa_rho_factor = " // str(c%uzawa_rho_factor, "es23.16") // ", uzawa_eps = " // &
      str(c%uzawa_eps, "es23.16") // ", uzawa_max_iter = " // str(c%uzawa_max_iter) // " /" // nl // &
      "&fom_timing samples = " // str(c%fom_timing_samples) // ", tol = " // str(c%fom_tol, "es23.16") // &
      ", uzawa_eps = " // str(c%fom_uzawa_eps, "es23.16") // ", uzawa_steps = " // str(c%fom_uzawa_steps) // &
      ", uzawa_rows = '" // trim(c%fom_uzawa_rows) // "', exact_solver = '" // trim(c%fom_exact_solver) // "' /" // nl
  end function rom_echo
end module cr_rom_config
