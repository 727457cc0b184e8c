!> The ROM-run file (schema "crowdrom-romrun", version 1; layout in docs/file-formats.md): written
!> by crowd_rom, read by the Python scripts (ML correction, figures) and by `read_romrun` (tests,
!> tools).
!>
!> Writing is streamed: `open` writes the header, `write_set` one (setting, set) group as soon
!> as it is computed, `close` the sweep table and commits the file (temporary name + rename);
!> `abort` leaves any previous file untouched. The reader accepts the versions in
!> ROMRUN_VERSIONS_READ and validates shapes against the header and settings, and that the
!> parameters are finite (reduced trajectories may legitimately hold diverged values).
module cr_romrun_file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, prefix_error
  use cr_strings, only: str
  use cr_h5file, only: h5file_t
  use cr_product_check, only: check_schema, need_finite, need_dims, product_error
  use cr_qoi, only: qoi_t
  use cr_qoi_file, only: write_qoi_group, read_qoi_group
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: ROMRUN_SCHEMA, ROMRUN_SCHEMA_VERSION, ROMRUN_VERSIONS_READ, romrun_header_t, romrun_row_t, &
    romrun_set_t, romrun_t, romrun_writer_t, read_romrun, speedup, row_measures_t, EVAC_PCT

  character(len=*), parameter :: ROMRUN_SCHEMA = "crowdrom-romrun"
  integer, parameter :: ROMRUN_SCHEMA_VERSION = 1
  !> versions the reader accepts
  integer, parameter :: ROMRUN_VERSIONS_READ(1) = [1]

  !> Root attributes and the full-order timing of a sweep.
  type :: romrun_header_t
    character(len=:), allocatable :: config, rom_file, database, db_hash, param_names
    integer :: n_agents = 0, n_steps = 0, n_settings = 0
    real(wp) :: dt = 0, radius = 0
    !> training box [n_mu]
    real(wp), allocatable :: param_min(:), param_max(:)
    !> full-order reference: time per step (paper's Uzawa, fastest exact solver) and its setup
    real(wp) :: t_uz = 0, t_ex = 0, tolerance = 0, uzawa_eps = 0, kkt_uz = 0, kkt_ex = 0
    !> one whole exact full-order query (parameter setup, scene, desired velocity, every step),
    !> mean over the timing samples (written, not read back: 0 from older files)
    real(wp) :: t_query_ex = 0
    character(len=:), allocatable :: exact_solver, uzawa_rows
    integer :: uzawa_steps = 0, timing_samples = 0, nc_uz = 0
    !> the exact solver asked for ('fastest' or a name; exact_solver is the one used) and the
    !> timings of every exact solver timed, "name t_step t_query; ..." (read back as '' from
    !> older files)
    character(len=:), allocatable :: exact_asked, exact_timings
  end type romrun_header_t

  !> Evacuation fractions (per cent of the agents out of the hall) of the evacuation times.
  integer, parameter :: EVAC_PCT(2) = [50, 90]

  !> Accuracy aggregates of one row (one setting on one set of samples), computed by
  !> cr_rom_metrics; -1: not available.
  type :: row_measures_t
    integer :: n_samples = 0, n_diverged = 0
    real(wp) :: e_avg = -1, e_max = -1, e_disp = -1, mobility = -1
    real(wp) :: overlap_aa = 0, overlap_aw = 0
    !> mean relative error of the evacuation times |t_rom - t_fom| / max(t_fom, h) over the
    !> samples where both reach the fraction (t_n of them); t_rom_missed: samples where the
    !> full model reaches it and the reduced one does not; t_fom_missed: the full model does
    !> not reach it (no reference)
    real(wp) :: t_err(2) = -1
    integer :: t_n(2) = 0, t_rom_missed(2) = 0, t_fom_missed(2) = 0
    integer :: not_left = 0, not_left_fom = -1
  end type row_measures_t

  !> One row of the sweep table (one setting on one set).
  type :: romrun_row_t
    integer :: setting = 0, n = 0, r = 0, nb = 0, m(3) = 0
    character(len=8) :: set = '', hyper = '', contacts = '', solver = ''
    real(wp) :: e_avg = -1, e_max = -1, e_proj = -1, overlap = 0, t_step = 0, mobility = -1
    integer :: not_left = 0, not_left_fom = -1, infeasible = 0, capped = 0, extrapolating = 0
    !> samples whose reduced trajectory diverged (stopped; excluded from every average)
    integer :: diverged = 0
    !> one whole reduced query (per-parameter setup plus the trajectory), mean over the samples
    !> that did not diverge (written, not read back: 0 from older files)
    real(wp) :: t_query = 0
    !> the accuracy measures of the row (cr_rom_metrics)
    type(row_measures_t) :: meas
    !> after each reduced step: 'none' or 'local' (local exact correction); with 'local', the
    !> mean and largest fraction of the agents corrected per step and the mean wall time of
    !> the correction per step (included in t_step) [s], over the samples that did not diverge;
    !> the steps whose correction even the full projection could not solve to the tolerance,
    !> over every sample (written to the table and the summary only, not to this file)
    character(len=8) :: correction = 'none'
    real(wp) :: corr_frac = 0, corr_frac_max = 0, t_correct = 0
    integer :: corr_unsolved = 0
  end type romrun_row_t

  !> One setting run on one set of samples (n samples, N_T steps, nb basis vectors).
  type :: romrun_set_t
    !> setting number, its pair (N, R, basis size, index in the ROM file), hyper-reduction,
    !> contacts, solver, points m_v, m_b, m_d
    integer :: setting = 0, n = 0, r = 0, nb = 0, pair = 0, m(3) = 0
    character(len=8) :: hyper = '', contacts = '', solver = ''
    character(len=8) :: name = ''
    !> the setting's summary attributes are stored with this set (the last set run)
    logical :: summary = .false.
    real(wp) :: e_avg = -1, t_step = 0, speedup_uzawa = 0, speedup_exact = 0
    integer :: samples_diverged = 0
    !> parameters [n_mu, n]; coefficients [nb, N_T n]; multiplier coefficients [R or 0, N_T n];
    !> positions [n_dof, (N_T + 1) n]; relative position error in time [N_T + 1, n]
    real(wp), allocatable :: params(:,:), alpha(:,:), beta(:,:), positions(:,:), err_time(:,:)
    !> per sample [n]
    real(wp), allocatable :: e_mu(:), e_proj(:), max_overlap(:), mobility(:), time(:)
    integer, allocatable :: n_not_left(:), n_not_left_fom(:), n_infeasible(:), n_capped(:), extrapolating(:)
    !> step at which the reduced trajectory diverged (0: never) [n]
    integer, allocatable :: diverged_step(:)
    !> displacement error, deepest agent-agent and agent-wall overlaps [n]
    real(wp), allocatable :: e_disp(:), overlap_aa(:), overlap_aw(:)
    !> agents out at t = nu h [N_T + 1, n] and the times of EVAC_PCT % out [2, n], reduced and
    !> (with a full-order reference) full
    integer, allocatable :: evac_rom(:,:), evac_fom(:,:)
    real(wp), allocatable :: t_out_rom(:,:), t_out_fom(:,:)
    !> 'none' or 'local'; with 'local': agents corrected at each step [N_T, n] and the wall time
    !> of the corrections of each sample [n] (not allocated for 'none')
    character(len=8) :: correction = 'none'
    integer, allocatable :: n_corrected(:,:)
    real(wp), allocatable :: t_correct(:)
    !> quantities of interest of the reduced trajectories [n] (group qoi; not allocated: none)
    type(qoi_t), allocatable :: qoi(:)
  end type romrun_set_t

  !> A ROM-run file as read back.
  type :: romrun_t
    type(romrun_header_t) :: hdr
    type(romrun_set_t), allocatable :: sets(:)
    type(romrun_row_t), allocatable :: rows(:)
  end type romrun_t

  !> Streaming writer.
  type :: romrun_writer_t
    type(h5file_t) :: h5
  contains
    procedure :: open => writer_open
    procedure :: write_set => writer_write_set
    procedure :: write_table => writer_write_table
    procedure :: commit => writer_commit
    procedure :: close => writer_close
    procedure :: abort => writer_abort
  end type romrun_writer_t

contains

  !> a / b, or 0 when either is not positive.
  pure real(wp) function speedup(a, b)
    real(wp), intent(in) :: a, b
    speedup = 0
    if (b > 0 .and. a > 0) speedup = a / b
  end function speedup

  !> Create the file (temporary name) and write the header.
  subroutine writer_open(this, path, hdr, error)
    class(romrun_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: path
    type(romrun_header_t), intent(in) :: hdr
    type(error_t), allocatable, intent(out) :: error
    call this%h5%create(path, error)
    if (allocated(error)) return
    associate (h5 => this%h5)
      call h5%write_attr("/", "schema", ROMRUN_SCHEMA, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "schema_version", ROMRUN_SCHEMA_VERSION, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "program", "crowd_rom", error); if (allocated(error)) goto 9
      call h5%write_attr("/", "config", hdr%config, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "rom_file", hdr%rom_file, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "database", hdr%database, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "database_config_hash", hdr%db_hash, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "n_agents", hdr%n_agents, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "n_steps", hdr%n_steps, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "dt", hdr%dt, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "agent_radius", hdr%radius, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "param_names", hdr%param_names, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "param_min", hdr%param_min, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "param_max", hdr%param_max, error); if (allocated(error)) goto 9
      call h5%write_attr("/", "n_settings", hdr%n_settings, error); if (allocated(error)) goto 9
      call h5%make_group("fom_timing", error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "t_step_uzawa", hdr%t_uz, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "t_step_exact", hdr%t_ex, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "t_query_exact", hdr%t_query_ex, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "exact_solver", hdr%exact_solver, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "tolerance", hdr%tolerance, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "uzawa_eps", hdr%uzawa_eps, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "uzawa_steps", hdr%uzawa_steps, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "uzawa_rows", hdr%uzawa_rows, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "samples", hdr%timing_samples, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "kkt_max_uzawa", hdr%kkt_uz, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "kkt_max_exact", hdr%kkt_ex, error); if (allocated(error)) goto 9
      call h5%write_attr("fom_timing", "nonconverged_steps_uzawa", hdr%nc_uz, error); if (allocated(error)) goto 9
      if (allocated(hdr%exact_asked)) then
        call h5%write_attr("fom_timing", "exact_solver_asked", hdr%exact_asked, error); if (allocated(error)) goto 9
      end if
      if (allocated(hdr%exact_timings)) then
        call h5%write_attr("fom_timing", "exact_solver_timings", hdr%exact_timings, error)
        if (allocated(error)) goto 9
      end if
    end associate
9   if (allocated(error)) call this%h5%abort()
  end subroutine writer_open

  !> Write group setting_<k>/<set> (and the setting's attributes).
  subroutine writer_write_set(this, s, error)
    class(romrun_writer_t), intent(inout) :: this
    type(romrun_set_t), intent(in) :: s
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: g
    g = "setting_" // str(s%setting)
    associate (h5 => this%h5)
      call h5%make_group(g // "/" // trim(s%name), error); if (allocated(error)) return
      call h5%write_attr(g, "n", s%n, error); if (allocated(error)) return
      call h5%write_attr(g, "r", s%r, error); if (allocated(error)) return
      call h5%write_attr(g, "n_basis", s%nb, error); if (allocated(error)) return
      call h5%write_attr(g, "pair", s%pair, error); if (allocated(error)) return
      call h5%write_attr(g, "hyper", trim(s%hyper), error); if (allocated(error)) return
      call h5%write_attr(g, "contacts", trim(s%contacts), error); if (allocated(error)) return
      call h5%write_attr(g, "solver", trim(s%solver), error); if (allocated(error)) return
      call h5%write_attr(g, "m_v", s%m(1), error); if (allocated(error)) return
      call h5%write_attr(g, "m_b", s%m(2), error); if (allocated(error)) return
      call h5%write_attr(g, "m_d", s%m(3), error); if (allocated(error)) return
      call h5%write_attr(g, "correction", trim(s%correction), error); if (allocated(error)) return
      if (s%summary) then
        call h5%write_attr(g, "E_avg", s%e_avg, error); if (allocated(error)) return
        call h5%write_attr(g, "samples_diverged", s%samples_diverged, error); if (allocated(error)) return
        call h5%write_attr(g, "t_step", s%t_step, error); if (allocated(error)) return
        call h5%write_attr(g, "speedup_uzawa", s%speedup_uzawa, error); if (allocated(error)) return
        call h5%write_attr(g, "speedup_exact", s%speedup_exact, error); if (allocated(error)) return
      end if
      g = g // "/" // trim(s%name)
      call h5%write(g // "/params", s%params, error); if (allocated(error)) return
      call h5%write(g // "/alpha", s%alpha, error); if (allocated(error)) return
      if (size(s%beta, 1) > 0) then
        call h5%write(g // "/beta", s%beta, error); if (allocated(error)) return
      end if
      call h5%write(g // "/positions", s%positions, error); if (allocated(error)) return
      call h5%write(g // "/err_time", s%err_time, error); if (allocated(error)) return
      call h5%write(g // "/E_mu", s%e_mu, error); if (allocated(error)) return
      call h5%write(g // "/E_proj", s%e_proj, error); if (allocated(error)) return
      call h5%write(g // "/max_overlap", s%max_overlap, error); if (allocated(error)) return
      call h5%write(g // "/mobility", s%mobility, error); if (allocated(error)) return
      call h5%write(g // "/n_not_left", s%n_not_left, error); if (allocated(error)) return
      call h5%write(g // "/n_not_left_fom", s%n_not_left_fom, error); if (allocated(error)) return
      call h5%write(g // "/n_infeasible", s%n_infeasible, error); if (allocated(error)) return
      call h5%write(g // "/n_capped", s%n_capped, error); if (allocated(error)) return
      call h5%write(g // "/extrapolating", s%extrapolating, error); if (allocated(error)) return
      call h5%write(g // "/time", s%time, error); if (allocated(error)) return
      call h5%write(g // "/diverged_step", s%diverged_step, error); if (allocated(error)) return
      call h5%write(g // "/E_disp", s%e_disp, error); if (allocated(error)) return
      call h5%write(g // "/max_overlap_agents", s%overlap_aa, error); if (allocated(error)) return
      call h5%write(g // "/max_overlap_walls", s%overlap_aw, error); if (allocated(error)) return
      ! evacuation: agents out at t = nu h [n_S, N_T + 1] and the times of EVAC_PCT % out [n_S, 2]
      call h5%write(g // "/evac_rom", s%evac_rom, error); if (allocated(error)) return
      call h5%write(g // "/t_out_rom", s%t_out_rom, error); if (allocated(error)) return
      if (allocated(s%evac_fom)) then
        call h5%write(g // "/evac_fom", s%evac_fom, error); if (allocated(error)) return
        call h5%write(g // "/t_out_fom", s%t_out_fom, error); if (allocated(error)) return
      end if
      call h5%write_attr(g // "/evac_rom", "evac_pct", EVAC_PCT, error); if (allocated(error)) return
      if (allocated(s%n_corrected)) then
        call h5%write(g // "/n_corrected", s%n_corrected, error); if (allocated(error)) return
        call h5%write(g // "/t_correct", s%t_correct, error); if (allocated(error)) return
      end if
      if (allocated(s%qoi)) then
        call write_qoi_group(h5, g // "/qoi", s%qoi, error); if (allocated(error)) return
      end if
    end associate
  end subroutine writer_write_set

  !> Write the sweep table and commit the file.
  subroutine writer_close(this, hdr, rows, error)
    class(romrun_writer_t), intent(inout) :: this
    type(romrun_header_t), intent(in) :: hdr
    type(romrun_row_t), intent(in) :: rows(:)
    type(error_t), allocatable, intent(out) :: error
    call this%write_table(hdr, rows, error)
    if (.not. allocated(error)) call this%commit(error)
  end subroutine writer_close

  !> Rename the temporary file to its final name (after write_table).
  subroutine writer_commit(this, error)
    class(romrun_writer_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    call this%h5%commit(error)
  end subroutine writer_commit

  !> Write the sweep table (group /table).
  subroutine writer_write_table(this, hdr, rows, error)
    class(romrun_writer_t), intent(inout) :: this
    type(romrun_header_t), intent(in) :: hdr
    type(romrun_row_t), intent(in) :: rows(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: k, j
    associate (h5 => this%h5)
      call h5%make_group("table", error); if (allocated(error)) return
      call h5%write("table/setting", rows%setting, error); if (allocated(error)) return
      call h5%write("table/n", rows%n, error); if (allocated(error)) return
      call h5%write("table/r", rows%r, error); if (allocated(error)) return
      call h5%write("table/n_basis", rows%nb, error); if (allocated(error)) return
      call h5%write("table/E_avg", rows%e_avg, error); if (allocated(error)) return
      call h5%write("table/E_max", rows%e_max, error); if (allocated(error)) return
      call h5%write("table/E_proj_avg", rows%e_proj, error); if (allocated(error)) return
      call h5%write("table/max_overlap", rows%overlap, error); if (allocated(error)) return
      call h5%write("table/mobility", rows%mobility, error); if (allocated(error)) return
      call h5%write("table/agents_not_left", rows%not_left, error); if (allocated(error)) return
      call h5%write("table/agents_not_left_fom", rows%not_left_fom, error); if (allocated(error)) return
      call h5%write("table/infeasible_steps", rows%infeasible, error); if (allocated(error)) return
      call h5%write("table/capped_steps", rows%capped, error); if (allocated(error)) return
      call h5%write("table/t_step_rom", rows%t_step, error); if (allocated(error)) return
      call h5%write("table/samples_diverged", rows%diverged, error); if (allocated(error)) return
      call h5%write("table/E_disp", rows%meas%e_disp, error); if (allocated(error)) return
      call h5%write("table/max_overlap_agents", rows%meas%overlap_aa, error); if (allocated(error)) return
      call h5%write("table/max_overlap_walls", rows%meas%overlap_aw, error); if (allocated(error)) return
      do k = 1, size(EVAC_PCT)
        call h5%write("table/t" // str(EVAC_PCT(k)) // "_err", [(rows(j)%meas%t_err(k), j = 1, size(rows))], error)
        if (allocated(error)) return
        call h5%write("table/t" // str(EVAC_PCT(k)) // "_n", [(rows(j)%meas%t_n(k), j = 1, size(rows))], error)
        if (allocated(error)) return
        call h5%write("table/t" // str(EVAC_PCT(k)) // "_rom_missed", [(rows(j)%meas%t_rom_missed(k), &
          j = 1, size(rows))], error)
        if (allocated(error)) return
        call h5%write("table/t" // str(EVAC_PCT(k)) // "_fom_missed", [(rows(j)%meas%t_fom_missed(k), &
          j = 1, size(rows))], error)
        if (allocated(error)) return
      end do
      call h5%write("table/speedup_uzawa", [(speedup(hdr%t_uz, rows(k)%t_step), k = 1, size(rows))], error)
      if (allocated(error)) return
      call h5%write("table/speedup_exact", [(speedup(hdr%t_ex, rows(k)%t_step), k = 1, size(rows))], error)
      if (allocated(error)) return
      call h5%write("table/t_query_rom", rows%t_query, error); if (allocated(error)) return
      call h5%write("table/t_query_fom_exact", [(hdr%t_query_ex, k = 1, size(rows))], error)
      if (allocated(error)) return
      call h5%write("table/speedup_query_exact", [(speedup(hdr%t_query_ex, rows(k)%t_query), k = 1, size(rows))], &
        error)
      if (allocated(error)) return
      call h5%write("table/corrected_fraction", rows%corr_frac, error); if (allocated(error)) return
      call h5%write("table/corrected_fraction_max", rows%corr_frac_max, error); if (allocated(error)) return
      call h5%write("table/t_correct_step", rows%t_correct, error); if (allocated(error)) return
      call h5%write_attr("table", "columns", "see the CSV header; strings (set, hyper, contacts, solver, " // &
        "correction) in the setting_<k> attributes, the exact solver in fom_timing", error)
    end associate
  end subroutine writer_write_table

  !> Close and delete the temporary file.
  subroutine writer_abort(this)
    class(romrun_writer_t), intent(inout) :: this
    call this%h5%abort()
  end subroutine writer_abort

  ! ------------------------------------------------------------------ read

  !> Read and validate a ROM-run file (serial): the root and fom_timing attributes
  !> (read_romrun_header), each setting's sets (read_romrun_set) and the table
  !> (read_romrun_table).
  subroutine read_romrun(path, run, error)
    character(len=*), intent(in) :: path
    type(romrun_t), intent(out) :: run
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    type(romrun_set_t), allocatable :: tmp(:)
    character(len=:), allocatable :: g, sv
    integer :: version, ks, is, nset
    call h5%open(path, error)
    if (allocated(error)) then
      error%code = EXIT_BAD_INPUT; return
    end if
    call check_schema(h5, path, ROMRUN_SCHEMA, ROMRUN_VERSIONS_READ, "ROM-run file", version, error)
    if (allocated(error)) goto 9
    call read_romrun_header(h5, path, run%hdr, error)
    if (allocated(error)) goto 9
    allocate(tmp(2 * run%hdr%n_settings))
    nset = 0
    do ks = 1, run%hdr%n_settings
      g = "setting_" // str(ks)
      if (.not. h5%exists(g)) then
        call product_error(path, "group '" // g // "' missing (n_settings = " // str(run%hdr%n_settings) // ")", error)
        goto 9
      end if
      do is = 1, 3
        sv = trim(merge('train', 'valid', is == 1))
        if (is == 3) sv = 'given'
        if (.not. h5%exists(g // "/" // sv)) cycle
        nset = nset + 1
        call read_romrun_set(h5, path, ks, sv, run%hdr%n_steps, 2 * run%hdr%n_agents, tmp(nset), error)
        if (allocated(error)) goto 9
      end do
    end do
    run%sets = tmp(1:nset)
    call read_romrun_table(h5, path, run, error)
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= EXIT_BAD_INPUT) call prefix_error(error, "ROM-run file '" // path // "'")
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_romrun

  !> The root and fom_timing attributes of a ROM-run file, checked.
  subroutine read_romrun_header(h5, path, h, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: path
    type(romrun_header_t), intent(inout) :: h
    type(error_t), allocatable, intent(out) :: error
    type(error_t), allocatable :: e2
    call h5%read_attr("/", "config", h%config, error); if (allocated(error)) return
    call h5%read_attr("/", "rom_file", h%rom_file, error); if (allocated(error)) return
    call h5%read_attr("/", "database", h%database, error); if (allocated(error)) return
    call h5%read_attr("/", "database_config_hash", h%db_hash, error); if (allocated(error)) return
    call h5%read_attr("/", "n_agents", h%n_agents, error); if (allocated(error)) return
    call h5%read_attr("/", "n_steps", h%n_steps, error); if (allocated(error)) return
    call h5%read_attr("/", "dt", h%dt, error); if (allocated(error)) return
    call h5%read_attr("/", "agent_radius", h%radius, error); if (allocated(error)) return
    call h5%read_attr("/", "param_names", h%param_names, error); if (allocated(error)) return
    call h5%read_attr("/", "param_min", h%param_min, error); if (allocated(error)) return
    call h5%read_attr("/", "param_max", h%param_max, error); if (allocated(error)) return
    call h5%read_attr("/", "n_settings", h%n_settings, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "t_step_uzawa", h%t_uz, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "t_step_exact", h%t_ex, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "exact_solver", h%exact_solver, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "tolerance", h%tolerance, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "uzawa_eps", h%uzawa_eps, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "uzawa_steps", h%uzawa_steps, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "uzawa_rows", h%uzawa_rows, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "samples", h%timing_samples, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "kkt_max_uzawa", h%kkt_uz, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "kkt_max_exact", h%kkt_ex, error); if (allocated(error)) return
    call h5%read_attr("fom_timing", "nonconverged_steps_uzawa", h%nc_uz, error); if (allocated(error)) return
    ! written since the 'fastest' reference (absent from older files of the same version)
    call h5%read_attr("fom_timing", "exact_solver_asked", h%exact_asked, e2)
    if (allocated(e2)) then
      h%exact_asked = h%exact_solver; deallocate(e2)
    end if
    call h5%read_attr("fom_timing", "exact_solver_timings", h%exact_timings, e2)
    if (allocated(e2)) then
      h%exact_timings = ''; deallocate(e2)
    end if
    if (h%n_agents < 1 .or. h%n_steps < 1 .or. h%n_settings < 0 .or. size(h%param_min) /= size(h%param_max)) then
      call product_error(path, "root attributes out of range (n_agents " // str(h%n_agents) // ", n_steps " // &
        str(h%n_steps) // ", n_settings " // str(h%n_settings) // ")", error); return
    end if
    call need_finite(path, "param_min", h%param_min, error); if (allocated(error)) return
    call need_finite(path, "param_max", h%param_max, error)
  end subroutine read_romrun_header

  !> Set sv ('train', 'valid', 'given') of setting ks: the setting's attributes and the set's
  !> datasets (nt steps, nd degrees of freedom), each checked against the sizes.
  subroutine read_romrun_set(h5, path, ks, sv, nt, nd, s, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: path, sv
    integer, intent(in) :: ks, nt, nd
    type(romrun_set_t), intent(inout) :: s
    type(error_t), allocatable, intent(out) :: error
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: g
    integer :: n
    g = "setting_" // str(ks)
    s%setting = ks; s%name = sv
    call h5%read_attr(g, "n", s%n, error); if (allocated(error)) return
    call h5%read_attr(g, "r", s%r, error); if (allocated(error)) return
    call h5%read_attr(g, "n_basis", s%nb, error); if (allocated(error)) return
    call h5%read_attr(g, "pair", s%pair, error); if (allocated(error)) return
    call read_str8(h5, g, "hyper", s%hyper, error); if (allocated(error)) return
    call read_str8(h5, g, "contacts", s%contacts, error); if (allocated(error)) return
    call read_str8(h5, g, "solver", s%solver, error); if (allocated(error)) return
    call h5%read_attr(g, "m_v", s%m(1), error); if (allocated(error)) return
    call h5%read_attr(g, "m_b", s%m(2), error); if (allocated(error)) return
    call h5%read_attr(g, "m_d", s%m(3), error); if (allocated(error)) return
    ! written since the local correction (absent from older files: 'none')
    call read_str8(h5, g, "correction", s%correction, error)
    if (allocated(error)) then
      s%correction = 'none'; deallocate(error)
    end if
    call h5%read_attr(g, "E_avg", s%e_avg, e2)
    s%summary = .not. allocated(e2)
    if (allocated(e2)) deallocate(e2)
    if (s%summary) then
      call h5%read_attr(g, "samples_diverged", s%samples_diverged, error); if (allocated(error)) return
      call h5%read_attr(g, "t_step", s%t_step, error); if (allocated(error)) return
      call h5%read_attr(g, "speedup_uzawa", s%speedup_uzawa, error); if (allocated(error)) return
      call h5%read_attr(g, "speedup_exact", s%speedup_exact, error); if (allocated(error)) return
    end if
    g = g // "/" // sv
    call h5%read(g // "/params", s%params, error); if (allocated(error)) return
    n = size(s%params, 2)
    call need_finite(path, g // "/params", s%params, error); if (allocated(error)) return
    call need_dims(h5, path, g // "/alpha", [int(s%nb, i8), int(nt, i8) * n], "n_basis x n_steps n_samples", &
      error); if (allocated(error)) return
    call need_dims(h5, path, g // "/positions", [int(nd, i8), int(nt + 1, i8) * n], &
      "2 n_agents x (n_steps + 1) n_samples", error); if (allocated(error)) return
    call need_dims(h5, path, g // "/err_time", [int(nt + 1, i8), int(n, i8)], "(n_steps + 1) x n_samples", &
      error); if (allocated(error)) return
    call h5%read(g // "/alpha", s%alpha, error); if (allocated(error)) return
    if (h5%exists(g // "/beta")) then
      call h5%read(g // "/beta", s%beta, error); if (allocated(error)) return
    else
      allocate(s%beta(0, nt * n))
    end if
    call h5%read(g // "/positions", s%positions, error); if (allocated(error)) return
    call h5%read(g // "/err_time", s%err_time, error); if (allocated(error)) return
    call read_sample_vectors(h5, path, g, n, s, error); if (allocated(error)) return
    call read_romrun_extras(h5, path, g, nt, n, s, error)
  end subroutine read_romrun_set

  !> The per-sample vectors [n] of set group g.
  subroutine read_sample_vectors(h5, path, g, n, s, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: path, g
    integer, intent(in) :: n
    type(romrun_set_t), intent(inout) :: s
    type(error_t), allocatable, intent(out) :: error
    call read_vec(h5, path, g // "/E_mu", n, s%e_mu, error); if (allocated(error)) return
    call read_vec(h5, path, g // "/E_proj", n, s%e_proj, error); if (allocated(error)) return
    call read_vec(h5, path, g // "/max_overlap", n, s%max_overlap, error); if (allocated(error)) return
    call read_vec(h5, path, g // "/mobility", n, s%mobility, error); if (allocated(error)) return
    call read_vec(h5, path, g // "/time", n, s%time, error); if (allocated(error)) return
    call read_ivec(h5, path, g // "/n_not_left", n, s%n_not_left, error); if (allocated(error)) return
    call read_ivec(h5, path, g // "/n_not_left_fom", n, s%n_not_left_fom, error); if (allocated(error)) return
    call read_ivec(h5, path, g // "/n_infeasible", n, s%n_infeasible, error); if (allocated(error)) return
    call read_ivec(h5, path, g // "/n_capped", n, s%n_capped, error); if (allocated(error)) return
    call read_ivec(h5, path, g // "/extrapolating", n, s%extrapolating, error); if (allocated(error)) return
    call read_ivec(h5, path, g // "/diverged_step", n, s%diverged_step, error); if (allocated(error)) return
    call read_vec(h5, path, g // "/E_disp", n, s%e_disp, error); if (allocated(error)) return
    call read_vec(h5, path, g // "/max_overlap_agents", n, s%overlap_aa, error); if (allocated(error)) return
    call read_vec(h5, path, g // "/max_overlap_walls", n, s%overlap_aw, error)
  end subroutine read_sample_vectors

  !> The evacuation curves, the local correction's figures and the QoIs of set group g (the
  !> full-order curves, the correction and the QoIs where the file has them).
  subroutine read_romrun_extras(h5, path, g, nt, n, s, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: path, g
    integer, intent(in) :: nt, n
    type(romrun_set_t), intent(inout) :: s
    type(error_t), allocatable, intent(out) :: error
    call need_dims(h5, path, g // "/evac_rom", [int(nt + 1, i8), int(n, i8)], "(n_steps + 1) x n_samples", &
      error); if (allocated(error)) return
    call h5%read(g // "/evac_rom", s%evac_rom, error); if (allocated(error)) return
    call h5%read(g // "/t_out_rom", s%t_out_rom, error); if (allocated(error)) return
    if (h5%exists(g // "/evac_fom")) then
      call need_dims(h5, path, g // "/evac_fom", [int(nt + 1, i8), int(n, i8)], "(n_steps + 1) x n_samples", &
        error); if (allocated(error)) return
      call h5%read(g // "/evac_fom", s%evac_fom, error); if (allocated(error)) return
      call h5%read(g // "/t_out_fom", s%t_out_fom, error); if (allocated(error)) return
    end if
    if (h5%exists(g // "/n_corrected")) then
      call need_dims(h5, path, g // "/n_corrected", [int(nt, i8), int(n, i8)], "n_steps x n_samples", &
        error); if (allocated(error)) return
      call h5%read(g // "/n_corrected", s%n_corrected, error); if (allocated(error)) return
      call read_vec(h5, path, g // "/t_correct", n, s%t_correct, error); if (allocated(error)) return
    end if
    if (h5%exists(g // "/qoi")) then
      call read_qoi_group(h5, path, g // "/qoi", s%qoi, error); if (allocated(error)) return
      if (size(s%qoi) /= n) then
        call product_error(path, "group '" // g // "/qoi' has " // str(size(s%qoi)) // " rows for " // &
          str(n) // " samples", error); return
      end if
    end if
  end subroutine read_romrun_extras

  !> A string attribute of at most 8 characters.
  subroutine read_str8(h5, obj, name, out, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: obj, name
    character(len=8), intent(inout) :: out
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: v
    call h5%read_attr(obj, name, v, error)
    if (.not. allocated(error)) out = v
  end subroutine read_str8

  !> A real vector of n entries (one per sample).
  subroutine read_vec(h5, path, name, n, x, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: path, name
    integer, intent(in) :: n
    real(wp), allocatable, intent(out) :: x(:)
    type(error_t), allocatable, intent(out) :: error
    call need_dims(h5, path, name, [int(n, i8)], "n_samples", error); if (allocated(error)) return
    call h5%read(name, x, error)
  end subroutine read_vec

  !> An integer vector of n entries (one per sample).
  subroutine read_ivec(h5, path, name, n, x, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: path, name
    integer, intent(in) :: n
    integer, allocatable, intent(out) :: x(:)
    type(error_t), allocatable, intent(out) :: error
    call need_dims(h5, path, name, [int(n, i8)], "n_samples", error); if (allocated(error)) return
    call h5%read(name, x, error)
  end subroutine read_ivec

  !> The table of a ROM-run file (one row per setting and set), its settings checked.
  subroutine read_romrun_table(h5, path, run, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: path
    type(romrun_t), intent(inout) :: run
    type(error_t), allocatable, intent(out) :: error
    integer(i8), allocatable :: d(:)
    integer, allocatable :: iv(:)
    real(wp), allocatable :: rv(:)
    integer :: nr, k
    call h5%get_dims("table/setting", d, error); if (allocated(error)) return
    nr = int(d(1))
    allocate(run%rows(nr))
    call h5%read("table/setting", iv, error); if (allocated(error)) return
    run%rows%setting = iv
    call h5%read("table/n", iv, error); if (allocated(error)) return
    run%rows%n = iv
    call h5%read("table/r", iv, error); if (allocated(error)) return
    run%rows%r = iv
    call h5%read("table/n_basis", iv, error); if (allocated(error)) return
    run%rows%nb = iv
    call h5%read("table/E_avg", rv, error); if (allocated(error)) return
    run%rows%e_avg = rv
    call h5%read("table/E_max", rv, error); if (allocated(error)) return
    run%rows%e_max = rv
    call h5%read("table/E_proj_avg", rv, error); if (allocated(error)) return
    run%rows%e_proj = rv
    call h5%read("table/max_overlap", rv, error); if (allocated(error)) return
    run%rows%overlap = rv
    call h5%read("table/mobility", rv, error); if (allocated(error)) return
    run%rows%mobility = rv
    call h5%read("table/agents_not_left", iv, error); if (allocated(error)) return
    run%rows%not_left = iv
    call h5%read("table/agents_not_left_fom", iv, error); if (allocated(error)) return
    run%rows%not_left_fom = iv
    call h5%read("table/infeasible_steps", iv, error); if (allocated(error)) return
    run%rows%infeasible = iv
    call h5%read("table/capped_steps", iv, error); if (allocated(error)) return
    run%rows%capped = iv
    call h5%read("table/t_step_rom", rv, error); if (allocated(error)) return
    run%rows%t_step = rv
    call h5%read("table/samples_diverged", iv, error); if (allocated(error)) return
    run%rows%diverged = iv
    call h5%read("table/E_disp", rv, error); if (allocated(error)) return
    run%rows%meas%e_disp = rv
    if (h5%exists("table/corrected_fraction")) then
      call h5%read("table/corrected_fraction", rv, error); if (allocated(error)) return
      run%rows%corr_frac = rv
      call h5%read("table/corrected_fraction_max", rv, error); if (allocated(error)) return
      run%rows%corr_frac_max = rv
      call h5%read("table/t_correct_step", rv, error); if (allocated(error)) return
      run%rows%t_correct = rv
    end if
    do k = 1, nr
      if (run%rows(k)%setting < 1 .or. run%rows(k)%setting > run%hdr%n_settings) then
        call product_error(path, "dataset 'table/setting': setting " // str(run%rows(k)%setting) // &
          " at row " // str(k) // " outside 1.." // str(run%hdr%n_settings), error); return
      end if
    end do
  end subroutine read_romrun_table
end module cr_romrun_file
