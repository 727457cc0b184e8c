!> &offline: configuration of crowd_offline (reduced bases from a snapshot database).
module cr_offline_config
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, problems_t
  use cr_strings, only: str
  use cr_namelist_text, only: namelist_text_t
  use cr_paths, only: io_paths_t
  use cr_config_check, only: need_sane
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

  !> Read &offline (defaults when the group is absent).
  subroutine read_offline(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(offline_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    character(len=MAX_PATH) :: database, rom_file
    character(len=16) :: pod_method, rsvd_sketch
    character(len=8) :: cone_method
    integer :: pod_n, rsvd_rank, rsvd_oversampling, rsvd_power, rsvd_seed, cone_r_max, mcpg_r_max
    integer :: pga_max_add, infsup_n(MAX_GRID), infsup_r(MAX_GRID), infsup_samples
    integer :: rom_n(MAX_GRID), rom_r(MAX_GRID), pod_compare_n(MAX_GRID)
    real(wp) :: pod_energy, cone_delta, pga_delta, hyper_m_factor, eq_tol
    logical :: cone_compare, pga, hyper
    namelist /offline/ database, rom_file, pod_method, pod_n, pod_energy, rsvd_rank, rsvd_oversampling, &
      rsvd_power, rsvd_sketch, rsvd_seed, cone_method, cone_compare, cone_delta, cone_r_max, mcpg_r_max, &
      pga, pga_delta, pga_max_add, infsup_n, infsup_r, infsup_samples, rom_n, rom_r, hyper, &
      hyper_m_factor, eq_tol, pod_compare_n
    integer :: ios
    character(len=512) :: msg
    database = c%database; rom_file = c%rom_file; pod_method = c%pod_method; pod_n = c%pod_n
    pod_energy = c%pod_energy; rsvd_rank = c%rsvd_rank; rsvd_oversampling = c%rsvd_oversampling
    rsvd_power = c%rsvd_power; rsvd_sketch = c%rsvd_sketch; rsvd_seed = c%rsvd_seed
    cone_method = c%cone_method; cone_compare = c%cone_compare; cone_delta = c%cone_delta
    cone_r_max = c%cone_r_max; mcpg_r_max = c%mcpg_r_max; pga = c%pga; pga_delta = c%pga_delta
    pga_max_add = c%pga_max_add; infsup_n = c%infsup_n; infsup_r = c%infsup_r
    infsup_samples = c%infsup_samples
    pod_compare_n = c%pod_compare_n
    rom_n = c%rom_n; rom_r = c%rom_r; hyper = c%hyper; hyper_m_factor = c%hyper_m_factor; eq_tol = c%eq_tol
    msg = ''
    read(t%lines, nml=offline, iostat=ios, iomsg=msg)
    if (ios /= 0) then
      if (.not. (is_iostat_end(ios) .and. .not. t%has_group('offline'))) then
        call set_error(error, t%path // ": namelist group &offline: " // trim(msg), 2); return
      end if
    end if
    c%database = database; c%rom_file = rom_file; c%pod_method = pod_method; c%pod_n = pod_n
    c%pod_energy = pod_energy; c%rsvd_rank = rsvd_rank; c%rsvd_oversampling = rsvd_oversampling
    c%rsvd_power = rsvd_power; c%rsvd_sketch = rsvd_sketch; c%rsvd_seed = rsvd_seed
    c%cone_method = cone_method; c%cone_compare = cone_compare; c%cone_delta = cone_delta
    c%cone_r_max = cone_r_max; c%mcpg_r_max = mcpg_r_max; c%pga = pga; c%pga_delta = pga_delta
    c%pga_max_add = pga_max_add; c%infsup_n = infsup_n; c%infsup_r = infsup_r
    c%infsup_samples = infsup_samples
    c%pod_compare_n = pod_compare_n
    c%rom_n = rom_n; c%rom_r = rom_r; c%hyper = hyper; c%hyper_m_factor = hyper_m_factor; c%eq_tol = eq_tol
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

  !> Validate &offline; all problems reported at once.
  subroutine check_offline(path, c, error)
    character(len=*), intent(in) :: path
    type(offline_cfg_t), intent(in) :: c
    type(error_t), allocatable, intent(out) :: error
    type(problems_t) :: probs
    ! every real finite and of a sane magnitude, first: the range checks below would trap on NaN
    call need_sane(probs, c%pod_energy, "&offline: pod_energy", 1.0_wp)
    call need_sane(probs, c%cone_delta, "&offline: cone_delta", 1.0e6_wp)
    call need_sane(probs, c%pga_delta, "&offline: pga_delta", 1.0e6_wp)
    call need_sane(probs, c%hyper_m_factor, "&offline: hyper_m_factor", 1.0e6_wp)
    call need_sane(probs, c%eq_tol, "&offline: eq_tol", 1.0_wp)
    if (probs%n > 0) then
      call probs%to_error(path, error); return
    end if
    call probs%need(len_trim(c%database) > 0, "&offline: database must be given")
    call probs%need(len_trim(c%rom_file) > 0, "&offline: rom_file must be given")
    call probs%need(any(c%pod_method == [character(len=16) :: 'tsqr', 'rsvd', 'scalapack', 'snapshots']), &
      "&offline: pod_method must be 'tsqr', 'rsvd', 'scalapack' or 'snapshots' (got '" // trim(c%pod_method) // "')")
    call probs%need(c%pod_n >= 0, "&offline: pod_n must be >= 0 (0: truncate by pod_energy)")
    call probs%need(c%pod_energy >= 0 .and. c%pod_energy <= 1, "&offline: pod_energy must be in [0, 1]")
    call probs%need(c%rsvd_rank >= 1, "&offline: rsvd_rank must be >= 1")
    call probs%need(c%rsvd_oversampling >= 0, "&offline: rsvd_oversampling must be >= 0")
    call probs%need(c%rsvd_power >= 0, "&offline: rsvd_power must be >= 0")
    call probs%need(c%rsvd_sketch == 'gaussian' .or. c%rsvd_sketch == 'srft', &
      "&offline: rsvd_sketch must be 'gaussian' or 'srft'")
    call probs%need(c%cone_method == 'gis' .or. c%cone_method == 'mcpg', "&offline: cone_method must be 'gis' or 'mcpg'")
    call probs%need(c%cone_delta >= 0, "&offline: cone_delta must be >= 0")
    call probs%need(c%cone_r_max >= 0 .and. c%mcpg_r_max >= 0, "&offline: cone_r_max and mcpg_r_max must be >= 0")
    call probs%need(c%pga_delta > 0, "&offline: pga_delta must be > 0 (got " // str(c%pga_delta) // ")")
    call probs%need(c%pga_max_add >= 0, "&offline: pga_max_add must be >= 0")
    call probs%need(all(c%infsup_n >= 0) .and. all(c%infsup_r >= 0), "&offline: infsup_n and infsup_r must be >= 0")
    call probs%need(c%infsup_samples >= 0, "&offline: infsup_samples must be >= 0")
    call probs%need(all(c%rom_n >= 0), "&offline: rom_n must be >= 0")
    call probs%need(all(c%rom_r >= 0 .or. c%rom_n == 0), &
      "&offline: rom_r(k) >= 0 must be given for every rom_n(k) > 0")
    call probs%need(all(c%rom_r < 0 .or. c%rom_n > 0), "&offline: rom_r(k) given without rom_n(k)")
    call probs%need(all(c%pod_compare_n >= 0), "&offline: pod_compare_n must be >= 0")
    call probs%need(c%hyper_m_factor >= 1, "&offline: hyper_m_factor must be >= 1 (got " // str(c%hyper_m_factor) // ")")
    call probs%need(c%eq_tol >= 0 .and. c%eq_tol < 1, "&offline: eq_tol must be in [0, 1)")
    call probs%to_error(path, error)
  end subroutine check_offline

  !> The group as re-readable namelist text.
  function offline_echo(c) result(s)
    type(offline_cfg_t), intent(in) :: c
    character(len=:), allocatable :: s
    character(len=1024) :: b
    write(b, '(a, i0, a, es23.16, a, i0, a, i0, a, i0)') ", pod_n = ", c%pod_n, ", pod_energy = ", c%pod_energy, &
      ", rsvd_rank = ", c%rsvd_rank, ", rsvd_oversampling = ", c%rsvd_oversampling, ", rsvd_power = ", c%rsvd_power
    s = "&offline database = '" // trim(c%database) // "', rom_file = '" // trim(c%rom_file) // &
      "', pod_method = '" // trim(c%pod_method) // "'" // trim(b)
    write(b, '(a, i0, a, es23.16, a, i0, a, i0, a, l1, a, es23.16, a, i0, a, i0)') "', rsvd_seed = ", c%rsvd_seed, &
      ", cone_delta = ", c%cone_delta, ", cone_r_max = ", c%cone_r_max, ", mcpg_r_max = ", c%mcpg_r_max, &
      ", pga = ", c%pga, ", pga_delta = ", c%pga_delta, ", pga_max_add = ", c%pga_max_add, &
      ", infsup_samples = ", c%infsup_samples
    s = s // ", rsvd_sketch = '" // trim(c%rsvd_sketch) // trim(b) // ", cone_method = '" // trim(c%cone_method) // &
      "', cone_compare = " // merge("T", "F", c%cone_compare) // ", hyper = " // merge("T", "F", c%hyper)
    write(b, '(a, es23.16, a, es23.16)') ", hyper_m_factor = ", c%hyper_m_factor, ", eq_tol = ", c%eq_tol
    s = s // trim(b) // ", rom_n = " // int_list(c%rom_n) // ", rom_r = " // int_list(c%rom_r) // &
      ", pod_compare_n = " // int_list(c%pod_compare_n) // " /" // new_line('a')
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
