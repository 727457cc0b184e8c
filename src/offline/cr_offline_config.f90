!> Configuration of crowd_offline (reduced bases from a snapshot database), one namelist group
!> per concern: &offline (the files), &pod, &cone, &pga, &infsup, &pairs (the reduced models to
!> prepare), &hyper. One type, read and validated here.
module cr_offline_config
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, problems_t
  use cr_strings, only: str
  use cr_namelist_text, only: namelist_text_t
  use cr_config, only: nml_status
  use cr_pod, only: POD_METHODS
  use cr_paths, only: io_paths_t
  use cr_sane, only: need_sane
  implicit none
  private
  public :: check_offline_paths
  public :: offline_cfg_t, read_offline, check_offline, offline_echo, MAX_GRID

  integer, parameter :: MAX_GRID = 32, MAX_PATH = 512

  !> Reduced-basis construction settings.
  type :: offline_cfg_t
    !> snapshot database to read and ROM file to write
    character(len=MAX_PATH) :: database = ''
    character(len=MAX_PATH) :: rom_file = ''
    !> velocity POD: 'tsqr', 'rsvd', 'scalapack' or 'snapshots' (method of snapshots)
    character(len=16) :: pod_method = 'tsqr'
    !> truncation: fixed number of modes (pod_n > 0) or energy (1 - retained <= pod_energy)
    integer :: pod_n = 0
    real(wp) :: pod_energy = 1.0e-4_wp
    !> randomized SVD: modes sought, oversampling, power iterations, sketch, seed
    integer :: rsvd_rank = 50
    integer :: rsvd_oversampling = 10
    integer :: rsvd_power = 2
    character(len=16) :: rsvd_sketch = 'gaussian'
    integer :: rsvd_seed = 1
    !> multiplier cone: 'gis', 'mcpg' (the ROM uses it) and whether to run the other too
    character(len=8) :: cone_method = 'gis'
    logical :: cone_compare = .false.
    real(wp) :: cone_delta = 1.0e-6_wp
    integer :: cone_r_max = 100
    integer :: mcpg_r_max = 100
    !> supremizer enrichment (PGA)
    logical :: pga = .true.
    real(wp) :: pga_delta = 1.0e-4_wp
    integer :: pga_max_add = 200
    !> reduced inf-sup table: N and R values and the number of training configurations
    integer :: infsup_n(MAX_GRID) = 0
    integer :: infsup_r(MAX_GRID) = 0
    integer :: infsup_samples = 20
    !> ROM pairs to prepare for crowd_rom: (rom_n(k), rom_r(k)) = (POD modes, cone vectors)
    !> for every rom_n(k) > 0 (rom_r(k) = 0: no constraint at all); none given: one pair (all
    !> POD modes, the whole cone)
    integer :: rom_n(MAX_GRID) = 0
    integer :: rom_r(MAX_GRID) = -1
    !> hyper-reduction (EIM and EQ of s1 = v(q), s2 = B(q), s3 = d(q)) for every pair;
    !> points stored up to hyper_m_factor times the paper's defaults m(v) = 2 N, m(B) = R,
    !> m(d) = 2 R (capped by the candidates); EQ stops early at relative error eq_tol
    logical :: hyper = .true.
    !> POD vs randomized POD comparison (the paper's rPOD figure): for each k > 0 the time and
    !> spectrum of pod_rsvd with rank k against the exact method of snapshots
    integer :: pod_compare_n(MAX_GRID) = 0
    real(wp) :: hyper_m_factor = 2.0_wp
    real(wp) :: eq_tol = 1.0e-10_wp
  end type offline_cfg_t

contains

  !> Read the groups of crowd_offline (defaults for absent groups): &offline (files), &pod,
  !> &cone, &pga, &infsup, &pairs, &hyper.
  subroutine read_offline(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(offline_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    call read_files(error); if (allocated(error)) return
    call read_pod(error); if (allocated(error)) return
    call read_cone(error); if (allocated(error)) return
    call read_pga(error); if (allocated(error)) return
    call read_infsup(error); if (allocated(error)) return
    call read_pairs(error); if (allocated(error)) return
    call read_hyper(error)

  contains

    subroutine read_files(error)
      type(error_t), allocatable, intent(out) :: error
      character(len=MAX_PATH) :: database, rom_file
      namelist /offline/ database, rom_file
      integer :: ios
      character(len=512) :: msg
      database = c%database; rom_file = c%rom_file
      msg = ''
      read(t%lines, nml=offline, iostat=ios, iomsg=msg)
      call nml_status(t, 'offline', ios, msg, error); if (allocated(error)) return
      c%database = database; c%rom_file = rom_file
    end subroutine read_files

    subroutine read_pod(error)
      type(error_t), allocatable, intent(out) :: error
      character(len=16) :: method, rsvd_sketch
      integer :: n, rsvd_rank, rsvd_oversampling, rsvd_power, rsvd_seed, compare_n(MAX_GRID)
      real(wp) :: energy
      namelist /pod/ method, n, energy, rsvd_rank, rsvd_oversampling, rsvd_power, rsvd_sketch, rsvd_seed, compare_n
      integer :: ios
      character(len=512) :: msg
      method = c%pod_method; n = c%pod_n; energy = c%pod_energy; rsvd_rank = c%rsvd_rank
      rsvd_oversampling = c%rsvd_oversampling; rsvd_power = c%rsvd_power; rsvd_sketch = c%rsvd_sketch
      rsvd_seed = c%rsvd_seed; compare_n = c%pod_compare_n
      msg = ''
      read(t%lines, nml=pod, iostat=ios, iomsg=msg)
      call nml_status(t, 'pod', ios, msg, error); if (allocated(error)) return
      c%pod_method = method; c%pod_n = n; c%pod_energy = energy; c%rsvd_rank = rsvd_rank
      c%rsvd_oversampling = rsvd_oversampling; c%rsvd_power = rsvd_power; c%rsvd_sketch = rsvd_sketch
      c%rsvd_seed = rsvd_seed; c%pod_compare_n = compare_n
    end subroutine read_pod

    subroutine read_cone(error)
      type(error_t), allocatable, intent(out) :: error
      character(len=8) :: method
      logical :: compare
      real(wp) :: delta
      integer :: r_max, mcpg_r_max
      namelist /cone/ method, compare, delta, r_max, mcpg_r_max
      integer :: ios
      character(len=512) :: msg
      method = c%cone_method; compare = c%cone_compare; delta = c%cone_delta; r_max = c%cone_r_max
      mcpg_r_max = c%mcpg_r_max
      msg = ''
      read(t%lines, nml=cone, iostat=ios, iomsg=msg)
      call nml_status(t, 'cone', ios, msg, error); if (allocated(error)) return
      c%cone_method = method; c%cone_compare = compare; c%cone_delta = delta; c%cone_r_max = r_max
      c%mcpg_r_max = mcpg_r_max
    end subroutine read_cone

    subroutine read_pga(error)
      type(error_t), allocatable, intent(out) :: error
      logical :: enabled
      real(wp) :: delta
      integer :: max_add
      namelist /pga/ enabled, delta, max_add
      integer :: ios
      character(len=512) :: msg
      enabled = c%pga; delta = c%pga_delta; max_add = c%pga_max_add
      msg = ''
      read(t%lines, nml=pga, iostat=ios, iomsg=msg)
      call nml_status(t, 'pga', ios, msg, error); if (allocated(error)) return
      c%pga = enabled; c%pga_delta = delta; c%pga_max_add = max_add
    end subroutine read_pga

    subroutine read_infsup(error)
      type(error_t), allocatable, intent(out) :: error
      integer :: n(MAX_GRID), r(MAX_GRID), samples
      namelist /infsup/ n, r, samples
      integer :: ios
      character(len=512) :: msg
      n = c%infsup_n; r = c%infsup_r; samples = c%infsup_samples
      msg = ''
      read(t%lines, nml=infsup, iostat=ios, iomsg=msg)
      call nml_status(t, 'infsup', ios, msg, error); if (allocated(error)) return
      c%infsup_n = n; c%infsup_r = r; c%infsup_samples = samples
    end subroutine read_infsup

    subroutine read_pairs(error)
      type(error_t), allocatable, intent(out) :: error
      integer :: n(MAX_GRID), r(MAX_GRID)
      namelist /pairs/ n, r
      integer :: ios
      character(len=512) :: msg
      n = c%rom_n; r = c%rom_r
      msg = ''
      read(t%lines, nml=pairs, iostat=ios, iomsg=msg)
      call nml_status(t, 'pairs', ios, msg, error); if (allocated(error)) return
      c%rom_n = n; c%rom_r = r
    end subroutine read_pairs

    subroutine read_hyper(error)
      type(error_t), allocatable, intent(out) :: error
      logical :: enabled
      real(wp) :: m_factor, eq_tol
      namelist /hyper/ enabled, m_factor, eq_tol
      integer :: ios
      character(len=512) :: msg
      enabled = c%hyper; m_factor = c%hyper_m_factor; eq_tol = c%eq_tol
      msg = ''
      read(t%lines, nml=hyper, iostat=ios, iomsg=msg)
      call nml_status(t, 'hyper', ios, msg, error); if (allocated(error)) return
      c%hyper = enabled; c%hyper_m_factor = m_factor; c%eq_tol = eq_tol
    end subroutine read_hyper
  end subroutine read_offline

  !> crowd_offline's outputs (&offline rom_file, the --summary file) checked against its
  !> inputs (the namelist, the snapshot database) and each other, before any work.
  subroutine check_offline_paths(input, summary, c, error)
    character(len=*), intent(in) :: input, summary
    type(offline_cfg_t), intent(in) :: c
    type(error_t), allocatable, intent(out) :: error
    type(io_paths_t) :: paths
    call paths%input("file", input)
    call paths%input("&offline database", c%database)
    call paths%output("&offline rom_file", c%rom_file)
    call paths%output("--summary", summary)
    call paths%check(input, error)
  end subroutine check_offline_paths

  !> Validate the groups of crowd_offline; all problems reported at once.
  subroutine check_offline(path, c, error)
    character(len=*), intent(in) :: path
    type(offline_cfg_t), intent(in) :: c
    type(error_t), allocatable, intent(out) :: error
    type(problems_t) :: probs
    ! every real finite and of a sane magnitude, first: the range checks below would trap on NaN
    call need_sane(probs, c%pod_energy, "&pod: energy", 1.0_wp)
    call need_sane(probs, c%cone_delta, "&cone: delta", 1.0e6_wp)
    call need_sane(probs, c%pga_delta, "&pga: delta", 1.0e6_wp)
    call need_sane(probs, c%hyper_m_factor, "&hyper: m_factor", 1.0e6_wp)
    call need_sane(probs, c%eq_tol, "&hyper: eq_tol", 1.0_wp)
    if (probs%n > 0) then
      call probs%to_error(path, error); return
    end if
    call probs%need(len_trim(c%database) > 0, "&offline: database must be given")
    call probs%need(len_trim(c%rom_file) > 0, "&offline: rom_file must be given")
    call probs%need(any(c%pod_method == POD_METHODS), &
      "&pod: method must be 'tsqr', 'rsvd', 'scalapack' or 'snapshots' (got '" // trim(c%pod_method) // "')")
    call probs%need(c%pod_n >= 0, "&pod: n must be >= 0 (0: truncate by energy)")
    call probs%need(c%pod_energy >= 0 .and. c%pod_energy <= 1, "&pod: energy must be in [0, 1]")
    call probs%need(c%rsvd_rank >= 1, "&pod: rsvd_rank must be >= 1")
    call probs%need(c%rsvd_oversampling >= 0, "&pod: rsvd_oversampling must be >= 0")
    call probs%need(c%rsvd_power >= 0, "&pod: rsvd_power must be >= 0")
    call probs%need(c%rsvd_sketch == 'gaussian' .or. c%rsvd_sketch == 'srft', &
      "&pod: rsvd_sketch must be 'gaussian' or 'srft'")
    call probs%need(all(c%pod_compare_n >= 0), "&pod: compare_n must be >= 0")
    call probs%need(c%cone_method == 'gis' .or. c%cone_method == 'mcpg', "&cone: method must be 'gis' or 'mcpg'")
    call probs%need(c%cone_delta >= 0, "&cone: delta must be >= 0")
    call probs%need(c%cone_r_max >= 0 .and. c%mcpg_r_max >= 0, "&cone: r_max and mcpg_r_max must be >= 0")
    call probs%need(c%pga_delta > 0, "&pga: delta must be > 0 (got " // str(c%pga_delta) // ")")
    call probs%need(c%pga_max_add >= 0, "&pga: max_add must be >= 0")
    call probs%need(all(c%infsup_n >= 0) .and. all(c%infsup_r >= 0), "&infsup: n and r must be >= 0")
    call probs%need(c%infsup_samples >= 0, "&infsup: samples must be >= 0")
    call probs%need(all(c%rom_n >= 0), "&pairs: n must be >= 0")
    call probs%need(all(c%rom_r >= 0 .or. c%rom_n == 0), "&pairs: r(k) >= 0 must be given for every n(k) > 0")
    call probs%need(all(c%rom_r < 0 .or. c%rom_n > 0), "&pairs: r(k) given without n(k)")
    call probs%need(c%hyper_m_factor >= 1, "&hyper: m_factor must be >= 1 (got " // str(c%hyper_m_factor) // ")")
    call probs%need(c%eq_tol >= 0 .and. c%eq_tol < 1, "&hyper: eq_tol must be in [0, 1)")
    call probs%to_error(path, error)
  end subroutine check_offline

  !> The groups as re-readable namelist text.
  function offline_echo(c) result(s)
    type(offline_cfg_t), intent(in) :: c
    character(len=:), allocatable :: s
    character(len=*), parameter :: nl = new_line('a')
    s = "&offline database = '" // trim(c%database) // "', rom_file = '" // trim(c%rom_file) // "' /" // nl // &
      "&pod method = '" // trim(c%pod_method) // "', n = " // str(c%pod_n) // ", energy = " // &
      str(c%pod_energy, "es23.16") // ", rsvd_rank = " // str(c%rsvd_rank) // ", rsvd_oversampling = " // &
      str(c%rsvd_oversampling) // ", rsvd_power = " // str(c%rsvd_power) // ", rsvd_sketch = '" // &
      trim(c%rsvd_sketch) // "', rsvd_seed = " // str(c%rsvd_seed) // ", compare_n = " // int_list(c%pod_compare_n) // &
      " /" // nl // &
      "&cone method = '" // trim(c%cone_method) // "', compare = " // merge("T", "F", c%cone_compare) // &
      ", delta = " // str(c%cone_delta, "es23.16") // ", r_max = " // str(c%cone_r_max) // ", mcpg_r_max = " // &
      str(c%mcpg_r_max) // " /" // nl // &
      "&pga enabled = " // merge("T", "F", c%pga) // ", delta = " // str(c%pga_delta, "es23.16") // &
      ", max_add = " // str(c%pga_max_add) // " /" // nl // &
      "&infsup n = " // int_list(c%infsup_n) // ", r = " // int_list(c%infsup_r) // ", samples = " // &
      str(c%infsup_samples) // " /" // nl // &
      "&pairs n = " // int_list(c%rom_n) // ", r = " // int_list(c%rom_r) // " /" // nl // &
      "&hyper enabled = " // merge("T", "F", c%hyper) // ", m_factor = " // str(c%hyper_m_factor, "es23.16") // &
      ", eq_tol = " // str(c%eq_tol, "es23.16") // " /" // nl
  contains
    function int_list(a) result(t)
      integer, intent(in) :: a(:)
      character(len=:), allocatable :: t
      integer :: k
      t = str(a(1))
      do k = 2, size(a)
        if (all(a(k:) == a(size(a)))) exit
        t = t // ", " // str(a(k))
      end do
    end function int_list
  end function offline_echo
end module cr_offline_config
