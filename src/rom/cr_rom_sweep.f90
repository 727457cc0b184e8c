!> The online sweep of crowd_rom (the driver keeps argument handling, one call per stage and
!> the summary): for every setting of &sweep and every sample of the chosen sets,
!> the reduced model is stepped and measured against the full-order trajectories where they
!> exist (E_mu, E_avg, displacement and evacuation-time errors, overlaps agent/wall, mobility,
!> agents that fail to leave); the full-order model is timed on the same samples (the paper's
!> Uzawa and the exact solver) for the speedups per step and per whole query.
!>
!> Stages (each returns error_t, none stops):
!>   init            read the ROM file and its study, the parameter sets and the settings;
!>   time_reference  time the full-order model (&fom_timing): the paper's Uzawa and the exact
!>                   solver, by default the fastest exact solver of this build (every solver
!>                   of EXACT_SOLVERS timed on the same samples, the fastest per step kept);
!>   run             run every setting, write the ROM-run file (&rom output, schema
!>                   crowdrom-romrun) and the table (&rom table, CSV), both atomically;
!>                   settings with &sweep correction = 'local' correct every reduced step
!>                   with cr_local_correction, using that same exact solver at the
!>                   &fom_timing tolerance (positions carried in full, see cr_rom_stepper);
!>   print_table / write_summary  the printed table and the JSON summary (--summary).
module cr_rom_sweep
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str, shorten
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_config, only: config_t
  use cr_rom_config, only: rom_cfg_t, rom_echo, MAX_SETTINGS, check_rom_paths, EXACT_SOLVERS
  use cr_projection, only: projection_settings_t
  use cr_local_correction, only: local_correction_t
  use cr_rom_file, only: rom_file_t, rom_pair_t, read_rom_file, read_rom_pair, find_pair
  use cr_rom_study, only: rom_study_t, sample_block_t, open_study, read_block_set
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t, make_reduced_ops, eim_exact_rows
  use cr_rom_stepper, only: rom_solver_cfg_t, rom_traj_t, run_trajectory
  use cr_rom_metrics, only: projection_error, sample_measures_t, row_measures_t, measure_sample, &
    aggregate_measures, EVAC_PCT
  use cr_rom_guard, only: rom_guard_t
  use cr_rom_query, only: query_setup, query_positions
  use cr_fom, only: fom_t, step_record_t
  use cr_romrun_file, only: romrun_header_t, romrun_row_t, romrun_set_t, romrun_writer_t, speedup
  use cr_fsys, only: rename_file, remove_file, write_whole_file
  use cr_json, only: json_writer_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: rom_sweep_t, fom_reference_t

  !> The full-order reference timed in this run (0: not timed).
  type :: fom_reference_t
    !> time per step: the paper's Uzawa and the exact solver [s]; largest scaled KKT residuals
    real(wp) :: t_uz = 0, t_ex = 0, kkt_uz = 0, kkt_ex = 0
    !> one whole exact full-order query: setup for the parameter plus every step [s]
    real(wp) :: t_query = 0
    !> Uzawa / exact steps that did not converge
    integer :: nc_uz = 0, nc_ex = 0
    !> the exact solver of the reference and of the local correction (with exact_solver =
    !> 'fastest': the fastest per step of EXACT_SOLVERS, sparse_active_set when not timed)
    character(len=32) :: exact_solver = ''
    !> every exact solver timed: "name t_step t_query" joined by "; "
    character(len=:), allocatable :: timings
  end type fom_reference_t

  !> One sweep: its configuration, the study it runs on and its results.
  type :: rom_sweep_t
    type(rom_cfg_t) :: cfg
    !> the input file (for messages) and "<input>: &rom"
    character(len=:), allocatable :: input, where
    !> the snapshot database (from &rom database or the ROM file)
    character(len=:), allocatable :: dbpath
    type(rom_file_t) :: hdr
    type(rom_study_t) :: st
    !> the parameter sets run (the last one carries the setting's summary attributes)
    type(sample_block_t), allocatable :: blocks(:)
    !> indices of the &sweep settings run, and their pair in the ROM file
    integer, allocatable :: setting_ids(:), pair_of(:)
    type(fom_reference_t) :: ref
    !> the table: one row per (setting, set), after run
    type(romrun_row_t), allocatable :: rows(:)
  contains
    procedure :: init
    procedure :: time_reference
    procedure :: run
    procedure :: print_table
    procedure :: write_summary
    procedure :: free
  end type rom_sweep_t

  !> What run_setting carries from sample to sample of one block: the work of a query
  !> (context, guard, trajectories, checked positions) and every per-sample figure [n] or
  !> column block, then the sums over the block.
  type :: setting_acc_t
    type(eval_ctx_t) :: ctx
    type(rom_guard_t) :: guard
    type(rom_traj_t) :: traj, tr2
    real(wp), allocatable :: qr(:,:)
    !> reduced coefficients [nb, nt n] and [r, nt n], positions [n_dof, (nt + 1) n], error in
    !> time [nt + 1, n]
    real(wp), allocatable :: alpha(:,:), beta(:,:), pos(:,:), err_time(:,:)
    real(wp), allocatable :: e_mu(:), e_proj(:), overlap(:), time(:), mobility(:), query(:)
    !> step where the trajectory diverged (0: never), steps done
    integer, allocatable :: div_step(:), n_done(:)
    integer, allocatable :: not_left(:), not_left_fom(:), infeas(:), capped(:), extrap(:)
    type(sample_measures_t), allocatable :: ms(:)
    !> the local correction: agents corrected [nt, n] and its time [n]
    integer, allocatable :: ncorr(:,:)
    real(wp), allocatable :: tcorr(:)
    !> sums over the block: NNLS fall-backs of the dual active set, active rows, rows added and
    !> dropped, reasons; the correction's conflict steps and seed agents; time per part
    integer :: n_fallback = 0, active_sum = 0, n_adds = 0, n_drops = 0, why(3) = 0, n_conflict = 0, n_seed = 0
    real(wp) :: t_parts(3) = 0
  end type setting_acc_t

contains

  !> Read the ROM file (&rom rom_file) and the study it was built from, the parameter sets
  !> (&rom sets) and the settings (&sweep); check the outputs against every input (summary:
  !> the --summary path, '' when none). cfg must have passed check_rom.
  subroutine init(this, input, summary, cfg, log, error)
    class(rom_sweep_t), intent(inout) :: this
    character(len=*), intent(in) :: input, summary
    type(rom_cfg_t), intent(in) :: cfg
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    integer :: ks
    type(sample_block_t) :: given
    call this%free()
    this%cfg = cfg
    this%input = input
    this%where = input // ": &rom"
    call log%stage_begin("crowd_rom: read ROM file and study")
    call read_rom_file(trim(this%cfg%rom_file), this%where // ": rom_file", this%hdr, error)
    if (allocated(error)) return
    this%dbpath = trim(this%cfg%database)
    if (len(this%dbpath) == 0) this%dbpath = this%hdr%database
    call check_rom_paths(input, summary, this%cfg, this%dbpath, error)
    if (allocated(error)) return
    call open_study(this%dbpath, this%where // ": database", this%hdr, this%st, error)
    if (allocated(error)) return
    call log%info("   " // str(this%st%n_agents) // " agents, " // str(this%st%n_steps) // " steps, parameters " // &
      shorten(this%st%param_names, 60) // "; ROM pairs (N, R) stored: " // pair_list(this%hdr))
    ! parameter sets
    select case (trim(this%cfg%sets))
    case ('valid', 'train')
      allocate(this%blocks(1))
      call read_block_set(this%st, trim(this%cfg%sets), this%cfg%n_samples, this%blocks(1), error)
    case ('both')
      allocate(this%blocks(2))
      call read_block_set(this%st, 'train', this%cfg%n_samples, this%blocks(1), error)
      if (.not. allocated(error)) call read_block_set(this%st, 'valid', this%cfg%n_samples, this%blocks(2), error)
    case ('given')
      ! built in a local block: an intent(out) argument must not alias a part of `this`
      call given_block(this, given, error)
      allocate(this%blocks(1))
      if (.not. allocated(error)) this%blocks(1) = given
    case default
      call set_error(error, this%where // ": sets '" // trim(this%cfg%sets) // "' unknown", EXIT_BAD_INPUT)
    end select
    if (allocated(error)) return
    ! settings
    this%setting_ids = pack([(ks, ks = 1, MAX_SETTINGS)], this%cfg%n > 0)
    if (size(this%setting_ids) == 0) then
      call set_error(error, this%where // ": no setting given (n(1) = N, r(1) = R, ...)", EXIT_BAD_INPUT); return
    end if
    allocate(this%pair_of(size(this%setting_ids)))
    do ks = 1, size(this%setting_ids)
      call find_pair(this%hdr, this%cfg%n(this%setting_ids(ks)), this%cfg%r(this%setting_ids(ks)), &
        this%where // ": setting " // str(this%setting_ids(ks)), this%pair_of(ks), error)
      if (allocated(error)) return
    end do
    call log%stage_end()
  end subroutine init

  !> Time the full-order model on the first &fom_timing samples of the last set: the paper's
  !> Uzawa and the exact solver (nothing when samples = 0).
  subroutine time_reference(this, env, log, error)
    class(rom_sweep_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    character(len=32), allocatable :: names(:)
    real(wp), allocatable :: t(:), kkt(:), tq(:)
    integer, allocatable :: nc(:)
    real(wp) :: t1(1), kkt1(1), tq1(1)
    integer :: nc1(1), k
    this%ref = fom_reference_t()
    this%ref%timings = ''
    if (this%cfg%fom_exact_solver == 'fastest') then
      names = EXACT_SOLVERS
    else
      names = [this%cfg%fom_exact_solver]
    end if
    this%ref%exact_solver = names(1)
    if (this%cfg%fom_timing_samples <= 0) return
    allocate(t(size(names)), kkt(size(names)), tq(size(names)), nc(size(names)))
    associate (blk => this%blocks(size(this%blocks)), r => this%ref)
      call log%stage_begin("crowd_rom: full-order timing (paper's uzawa on " // trim(this%cfg%fom_uzawa_rows) // &
        " rows, eps " // str(this%cfg%fom_uzawa_eps) // "; exact solver " // trim(this%cfg%fom_exact_solver) // &
        ", KKT tolerance " // str(this%cfg%fom_tol) // ")")
      call fom_timing(this, env, log, blk, ['uzawa'], t1, kkt1, nc1, tq1, error)
      if (allocated(error)) return
      r%t_uz = t1(1); r%kkt_uz = kkt1(1); r%nc_uz = nc1(1)
      call log%info("   uzawa " // str(r%t_uz, "es10.3") // " s/step (largest KKT " // str(r%kkt_uz, "es9.2") // &
        ", " // str(r%nc_uz) // " non-converged steps)")
      call fom_timing(this, env, log, blk, names, t, kkt, nc, tq, error)
      if (allocated(error)) return
      do k = 1, size(names)
        call log%info("   " // trim(names(k)) // " " // str(t(k), "es10.3") // " s/step (largest KKT " // &
          str(kkt(k), "es9.2") // ", " // str(nc(k)) // " non-converged steps), " // str(tq(k), "es10.3") // &
          " s per whole query")
        if (k > 1) r%timings = r%timings // "; "
        r%timings = r%timings // trim(names(k)) // " " // str(t(k), "es10.3") // " " // str(tq(k), "es10.3")
        if (k == 1 .or. t(k) < r%t_ex) then
          r%t_ex = t(k); r%kkt_ex = kkt(k); r%nc_ex = nc(k); r%t_query = tq(k); r%exact_solver = names(k)
        end if
      end do
      if (size(names) > 1) call log%info("   reference: " // trim(r%exact_solver) // ", the fastest exact " // &
        "solver per step of this build (timed interleaved on the same samples)")
      call log%stage_end()
    end associate
  end subroutine time_reference

  !> Run every setting on every set; write the ROM-run file and the table (both or neither).
  subroutine run(this, env, log, error)
    class(rom_sweep_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    type(rom_pair_t), allocatable :: pairs(:)
    logical, allocatable :: loaded(:)
    type(romrun_writer_t) :: out
    type(romrun_header_t) :: rhdr
    integer :: ks, ib, kp, nrow, k
    call make_header(this, rhdr)
    call out%open(trim(this%cfg%output), rhdr, error)
    if (allocated(error)) then
      call prefix_error(error, this%where // ": output"); error%code = EXIT_BAD_INPUT; return
    end if
    allocate(pairs(this%hdr%n_pairs), loaded(this%hdr%n_pairs))
    loaded = .false.
    if (allocated(this%rows)) deallocate(this%rows)
    allocate(this%rows(size(this%setting_ids) * size(this%blocks)))
    nrow = 0
    do ks = 1, size(this%setting_ids)
      kp = this%pair_of(ks)
      if (.not. loaded(kp)) then
        call read_rom_pair(this%hdr, kp, pairs(kp), error); if (allocated(error)) goto 9
        loaded(kp) = .true.
      end if
      call log%stage_begin("crowd_rom: setting " // str(ks) // " of " // str(size(this%setting_ids)) // &
        ": (N, R) = (" // str(pairs(kp)%n) // ", " // str(pairs(kp)%r) // "), basis " // str(pairs(kp)%nb) // &
        ", hyper " // trim(this%cfg%hyper(this%setting_ids(ks))) // ", contacts " // &
        trim(this%cfg%contacts(this%setting_ids(ks))) // ", solver " // trim(this%cfg%solver) // &
        ", correction " // trim(this%cfg%correction(this%setting_ids(ks))))
      do ib = 1, size(this%blocks)
        if (.not. runs_on(this, this%setting_ids(ks), this%blocks(ib))) cycle
        nrow = nrow + 1
        call run_setting(this, env, log, out, ks, this%setting_ids(ks), pairs(kp), this%blocks(ib), &
          this%rows(nrow), error)
        if (allocated(error)) goto 9
      end do
      call log%stage_end()
    end do
    this%rows = this%rows(1:nrow)   ! settings with &sweep sets(k) skip a set
    call out%write_table(rhdr, this%rows, error); if (allocated(error)) goto 9
    ! the run file and the table are one result: the table is written completely first, then
    ! both are renamed; if the run file's commit fails, neither replaces an earlier result (a
    ! rename of the table failing after it is reported, the table left as <table>.partial)
    call write_csv(this, error); if (allocated(error)) goto 9
    call out%commit(error)
    if (allocated(error)) then
      ! neither replaces an earlier result, and no temporary is left behind
      call out%abort()
      k = remove_file(trim(this%cfg%table) // ".partial"); return
    end if
    if (rename_file(trim(this%cfg%table) // ".partial", trim(this%cfg%table)) /= 0) then
      ! the run file already replaced the earlier one (moving it back would leave no run file
      ! at all): it stays, and the error says the table did not follow
      call set_error(error, this%where // ": table: cannot rename '" // trim(this%cfg%table) // ".partial' to '" // &
        trim(this%cfg%table) // "': the new run file is '" // trim(this%cfg%output) // "', its table is left as '" // &
        trim(this%cfg%table) // ".partial'")
    end if
    return
9   call out%abort()
  end subroutine run

  !> Whether setting kset runs on the parameter set blk (&sweep sets(kset): '' = every set).
  pure logical function runs_on(this, kset, blk)
    type(rom_sweep_t), intent(in) :: this
    integer, intent(in) :: kset
    type(sample_block_t), intent(in) :: blk
    runs_on = len_trim(this%cfg%setting_sets(kset)) == 0 .or. &
      trim(this%cfg%setting_sets(kset)) == trim(blk%name)
  end function runs_on

  !> Free everything (init may be called again).
  subroutine free(this)
    class(rom_sweep_t), intent(inout) :: this
    type(rom_sweep_t) :: fresh
    select type (this)
    type is (rom_sweep_t)
      this = fresh
    end select
  end subroutine free

  !> The ROM-run header of this sweep.
  subroutine make_header(this, rhdr)
    type(rom_sweep_t), intent(in) :: this
    type(romrun_header_t), intent(out) :: rhdr
    rhdr%config = rom_echo(this%cfg)
    rhdr%rom_file = trim(this%cfg%rom_file); rhdr%database = this%dbpath; rhdr%db_hash = this%st%hash
    rhdr%n_agents = this%st%n_agents; rhdr%n_steps = this%st%n_steps; rhdr%dt = this%st%dt
    rhdr%radius = this%st%radius
    rhdr%param_names = this%st%param_names; rhdr%param_min = this%st%space%lo; rhdr%param_max = this%st%space%hi
    rhdr%n_settings = size(this%setting_ids)
    rhdr%t_uz = this%ref%t_uz; rhdr%t_ex = this%ref%t_ex; rhdr%t_query_ex = this%ref%t_query
    rhdr%exact_solver = trim(this%ref%exact_solver)
    rhdr%exact_asked = trim(this%cfg%fom_exact_solver)
    rhdr%exact_timings = this%ref%timings
    rhdr%tolerance = this%cfg%fom_tol; rhdr%uzawa_eps = this%cfg%fom_uzawa_eps
    rhdr%uzawa_steps = this%cfg%fom_uzawa_steps
    rhdr%uzawa_rows = trim(this%cfg%fom_uzawa_rows); rhdr%timing_samples = this%cfg%fom_timing_samples
    rhdr%kkt_uz = this%ref%kkt_uz; rhdr%kkt_ex = this%ref%kkt_ex; rhdr%nc_uz = this%ref%nc_uz
  end subroutine make_header

  !> Run setting ks (index kset in the &sweep arrays) on one block of samples; write its group:
  !> the reduced operators and solver (prepare), every sample stepped and measured (run_sample),
  !> the row of the table (aggregate_row), its log lines (report_row) and the output group
  !> (pack_set).
  subroutine run_setting(this, env, log, out, ks, kset, pair, blk, row, error)
    type(rom_sweep_t), intent(in) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(romrun_writer_t), intent(inout) :: out
    integer, intent(in) :: ks, kset
    type(rom_pair_t), intent(in) :: pair
    type(sample_block_t), intent(in) :: blk
    type(romrun_row_t), intent(out) :: row
    type(error_t), allocatable, intent(out) :: error
    class(reduced_ops_t), allocatable :: ops
    type(rom_solver_cfg_t) :: scfg
    type(local_correction_t), allocatable :: corr
    type(setting_acc_t) :: acc
    type(romrun_set_t) :: out_set
    integer :: k
    call prepare_setting(this, kset, pair, blk, ops, scfg, corr, acc, error)
    if (allocated(error)) return
    call log%progress_start()
    do k = 1, blk%n
      call run_sample(this, env, ks, k, pair, blk, ops, scfg, corr, acc, row, error)
      if (allocated(error)) return
      if (acc%div_step(k) > 0) call log%warn("setting " // str(ks) // ", " // trim(blk%name) // " sample " // &
        str(k) // ": the reduced trajectory diverged at step " // str(acc%div_step(k)) // " (non-finite values " // &
        "or an agent outside the hall's box inflated by its diagonal + 2 c_max T): stopped there, positions " // &
        "frozen, sample excluded from the averages")
      call log%progress(trim(blk%name) // " sample", k, blk%n)
    end do
    call aggregate_row(this, ks, kset, pair, blk, ops, allocated(corr), acc, row)
    call report_row(this, log, pair, blk, ops, allocated(corr), acc, row)
    call pack_set(this, ks, kset, pair, blk, ops, acc, row, out_set)
    if (allocated(corr)) call corr%free()
    call out%write_set(out_set, error)
  end subroutine run_setting

  !> The reduced operators of setting kset, the reduced solver's settings, the local correction
  !> (with &sweep correction = 'local': the exact full-order solver of the reference, at the
  !> reference's tolerance) and the accumulators of the block's samples.
  subroutine prepare_setting(this, kset, pair, blk, ops, scfg, corr, acc, error)
    type(rom_sweep_t), intent(in) :: this
    integer, intent(in) :: kset
    type(rom_pair_t), intent(in) :: pair
    type(sample_block_t), intent(in) :: blk
    class(reduced_ops_t), allocatable, intent(out) :: ops
    type(rom_solver_cfg_t), intent(out) :: scfg
    type(local_correction_t), allocatable, intent(inout) :: corr
    type(setting_acc_t), intent(out) :: acc
    type(error_t), allocatable, intent(out) :: error
    type(projection_settings_t) :: psett
    integer :: nt, n
    nt = this%st%n_steps
    n = blk%n
    call make_reduced_ops(trim(this%cfg%hyper(kset)), trim(this%cfg%contacts(kset)), pair, &
      [this%cfg%m_v(kset), this%cfg%m_b(kset), this%cfg%m_d(kset)], this%st%cfg%contacts%cutoff_factor, &
      this%where // ": setting " // str(kset), ops, error)
    if (allocated(error)) return
    scfg%name = this%cfg%solver
    scfg%nnls_max_iter = this%cfg%nnls_max_iter
    scfg%uzawa_rho_factor = this%cfg%uzawa_rho_factor
    scfg%uzawa_eps = this%cfg%uzawa_eps
    scfg%uzawa_max_iter = this%cfg%uzawa_max_iter
    if (this%cfg%correction(kset) == 'local') then
      allocate(corr)
      psett = this%st%cfg%solver
      psett%name = this%ref%exact_solver
      psett%tol = this%cfg%fom_tol
      call corr%init(psett, this%st%cfg%contacts%cutoff_factor, error)
      if (allocated(error)) then
        call prefix_error(error, this%where // ": setting " // str(kset)); return
      end if
      allocate(acc%ncorr(nt, n), acc%tcorr(n))
      acc%ncorr = 0; acc%tcorr = 0
    end if
    allocate(acc%alpha(pair%nb, nt * n), acc%beta(merge(pair%r, 0, ops%fixed_rows), nt * n), &
      acc%pos(this%st%n_dof, (nt + 1) * n), acc%err_time(nt + 1, n), acc%e_mu(n), acc%e_proj(n), &
      acc%overlap(n), acc%time(n), acc%mobility(n), acc%not_left(n), acc%not_left_fom(n), acc%infeas(n), &
      acc%capped(n), acc%extrap(n), acc%div_step(n), acc%n_done(n), acc%ms(n), acc%query(n))
    acc%div_step = 0
    acc%err_time = -1; acc%e_mu = -1; acc%e_proj = -1; acc%not_left_fom = -1; acc%mobility = -1
  end subroutine prepare_setting

  !> Sample k of blk: the whole query as a user pays it (the per-parameter setup: scene,
  !> speeds, desired velocity, divergence guard; plus the trajectory: fastest repeat,
  !> per-trajectory setup included), every agent checked (cr_rom_query), its figures kept in
  !> acc and its measures against the full-order trajectory where there is one.
  subroutine run_sample(this, env, ks, k, pair, blk, ops, scfg, corr, acc, row, error)
    type(rom_sweep_t), intent(in) :: this
    type(env_t), intent(in) :: env
    integer, intent(in) :: ks, k
    type(rom_pair_t), intent(in) :: pair
    type(sample_block_t), intent(in) :: blk
    class(reduced_ops_t), intent(inout) :: ops
    type(rom_solver_cfg_t), intent(in) :: scfg
    type(local_correction_t), allocatable, intent(inout) :: corr
    type(setting_acc_t), intent(inout) :: acc
    type(romrun_row_t), intent(inout) :: row
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: w0, w_setup, w_run
    integer :: nt, rep
    nt = this%st%n_steps
    associate (traj => acc%traj, tr2 => acc%tr2, ctx => acc%ctx, guard => acc%guard)
    w0 = env%wtime()
    call query_setup(this%st, blk%mu(:, k), ctx, guard, error)
    if (allocated(error)) return
    w_setup = env%wtime() - w0
    w0 = env%wtime()
    call run_trajectory(ops, ctx, this%st%q0, nt, scfg, traj, error, guard=guard, corr=corr)
    w_run = env%wtime() - w0
    if (allocated(error)) then
      call prefix_error(error, "setting " // str(ks) // ", " // trim(blk%name) // " sample " // str(k)); return
    end if
    do rep = 2, this%cfg%timing_repeats
      w0 = env%wtime()
      call run_trajectory(ops, ctx, this%st%q0, nt, scfg, tr2, error, guard=guard, corr=corr)
      w_run = min(w_run, env%wtime() - w0)
      if (allocated(error)) return
      if (tr2%time < traj%time) then
        traj%time = tr2%time; traj%time_positions = tr2%time_positions
        traj%time_assemble = tr2%time_assemble; traj%time_solve = tr2%time_solve
        traj%time_correct = tr2%time_correct
      end if
    end do
    call query_positions(this%st, pair%v, guard, traj, acc%qr)
    if (allocated(corr)) then
      acc%ncorr(:, k) = traj%n_corrected
      acc%tcorr(k) = traj%time_correct
      acc%n_conflict = acc%n_conflict + traj%conflict_steps
      acc%n_seed = acc%n_seed + traj%n_conflict_agents
      row%corr_unsolved = row%corr_unsolved + traj%corr_unsolved
    end if
    acc%div_step(k) = traj%diverged_step
    acc%n_done(k) = merge(traj%diverged_step, nt, traj%diverged_step > 0)
    acc%alpha(:, (k - 1) * nt + 1:k * nt) = traj%alpha
    if (size(acc%beta, 1) > 0) acc%beta(:, (k - 1) * nt + 1:k * nt) = traj%beta
    acc%pos(:, (k - 1) * (nt + 1) + 1:k * (nt + 1)) = acc%qr
    acc%time(k) = traj%time
    acc%query(k) = w_setup + max(w_run, traj%time)
    acc%infeas(k) = traj%n_infeasible
    acc%capped(k) = traj%n_capped
    acc%n_fallback = acc%n_fallback + traj%n_fallback; acc%active_sum = acc%active_sum + traj%active_sum
    acc%n_adds = acc%n_adds + traj%dual_adds; acc%n_drops = acc%n_drops + traj%dual_drops
    acc%why = acc%why + traj%dual_why
    acc%t_parts = acc%t_parts + [traj%time_positions, traj%time_assemble, traj%time_solve]
    end associate
    acc%extrap(k) = merge(1, 0, any(blk%mu(:, k) < this%st%space%lo - 1.0e-12_wp * abs(this%st%space%lo)) .or. &
      any(blk%mu(:, k) > this%st%space%hi + 1.0e-12_wp * abs(this%st%space%hi)))
    call measure_one(this, k, pair, blk, acc, error)
    if (allocated(error)) then
      call prefix_error(error, "setting " // str(ks) // ", " // trim(blk%name) // " sample " // str(k)); return
    end if
  end subroutine run_sample

  !> The measures of sample k's reduced positions acc%qr (against the full-order trajectory
  !> and QoIs where blk has them) into acc.
  subroutine measure_one(this, k, pair, blk, acc, error)
    type(rom_sweep_t), intent(in) :: this
    integer, intent(in) :: k
    type(rom_pair_t), intent(in) :: pair
    type(sample_block_t), intent(in) :: blk
    type(setting_acc_t), intent(inout) :: acc
    type(error_t), allocatable, intent(out) :: error
    integer :: nt
    nt = this%st%n_steps
    if (blk%has_fom) then
      if (allocated(blk%qoi)) then
        ! the full-order QoIs as crowd_snapshots stored them (the same definitions)
        ! the full-order QoIs as crowd_snapshots stored them (the same definitions, the body
        ! radius)
        call measure_sample(acc%ctx%scene, this%st%body_radius, this%st%dt, acc%qr, acc%ms(k), error, &
          q=blk%q(:, (k - 1) * (nt + 1) + 1:k * (nt + 1)), err=acc%err_time(:, k), qoi_fom=blk%qoi(k), &
          contact_radius=this%st%radius)
      else
        call measure_sample(acc%ctx%scene, this%st%body_radius, this%st%dt, acc%qr, acc%ms(k), error, &
          q=blk%q(:, (k - 1) * (nt + 1) + 1:k * (nt + 1)), err=acc%err_time(:, k), contact_radius=this%st%radius)
      end if
      acc%e_proj(k) = projection_error(blk%u(:, (k - 1) * nt + 1:k * nt), pair%v)
    else
      call measure_sample(acc%ctx%scene, this%st%body_radius, this%st%dt, acc%qr, acc%ms(k), error, &
        contact_radius=this%st%radius)
    end if
    if (allocated(error)) return
    acc%ms(k)%diverged = acc%div_step(k) > 0
    acc%e_mu(k) = acc%ms(k)%e_mu
    acc%mobility(k) = acc%ms(k)%mobility
    acc%overlap(k) = max(acc%ms(k)%overlap_aa, acc%ms(k)%overlap_aw)
    acc%not_left(k) = acc%ms(k)%not_left
    acc%not_left_fom(k) = acc%ms(k)%not_left_fom
  end subroutine measure_one

  !> The row of the table of setting ks on blk: every aggregate over the samples that did not
  !> diverge (their count is reported); with the local correction (corrected), its fractions
  !> over the same samples and its time per step.
  subroutine aggregate_row(this, ks, kset, pair, blk, ops, corrected, acc, row)
    type(rom_sweep_t), intent(in) :: this
    integer, intent(in) :: ks, kset
    type(rom_pair_t), intent(in) :: pair
    type(sample_block_t), intent(in) :: blk
    class(reduced_ops_t), intent(in) :: ops
    logical, intent(in) :: corrected
    type(setting_acc_t), intent(in) :: acc
    type(romrun_row_t), intent(inout) :: row
    logical, allocatable :: ok(:)
    integer :: j
    row%setting = ks; row%n = pair%n; row%r = pair%r; row%nb = pair%nb; row%m = ops%m
    row%set = blk%name; row%hyper = this%cfg%hyper(kset); row%contacts = this%cfg%contacts(kset)
    row%solver = this%cfg%solver
    row%correction = this%cfg%correction(kset)
    row%t_step = sum(acc%time) / max(1, sum(acc%n_done))
    call aggregate_measures(acc%ms, this%st%dt, row%meas)
    ok = acc%div_step == 0
    if (any(ok)) then
      row%t_query = sum(acc%query, mask=ok) / count(ok)
    else
      row%t_query = sum(acc%query) / blk%n
    end if
    row%diverged = row%meas%n_diverged
    row%overlap = max(row%meas%overlap_aa, row%meas%overlap_aw)
    row%not_left = row%meas%not_left; row%infeasible = sum(acc%infeas); row%capped = sum(acc%capped)
    row%extrapolating = sum(acc%extrap)
    row%e_avg = row%meas%e_avg; row%e_max = row%meas%e_max; row%mobility = row%meas%mobility
    row%not_left_fom = row%meas%not_left_fom
    if (blk%has_fom .and. any(ok)) row%e_proj = sum(acc%e_proj, mask=ok) / count(ok)
    if (corrected) then
      if (any(ok)) then
        row%corr_frac = real(sum(acc%ncorr(:, pack([(j, j = 1, blk%n)], ok))), wp) / &
          (real(this%st%n_agents, wp) * max(1, sum(acc%n_done, mask=ok)))
        row%corr_frac_max = real(maxval(acc%ncorr(:, pack([(j, j = 1, blk%n)], ok))), wp) / this%st%n_agents
      end if
      row%t_correct = sum(acc%tcorr) / max(1, sum(acc%n_done))
    end if
  end subroutine aggregate_row

  !> The log lines of the row of setting ks on blk: its accuracy and speed, the EIM's exact
  !> rows, the dual active set's and the local correction's figures, the time per step by part
  !> and the warnings (diverged, infeasible, capped, extrapolating).
  subroutine report_row(this, log, pair, blk, ops, corrected, acc, row)
    type(rom_sweep_t), intent(in) :: this
    type(logger_t), intent(inout) :: log
    type(rom_pair_t), intent(in) :: pair
    type(sample_block_t), intent(in) :: blk
    class(reduced_ops_t), intent(in) :: ops
    logical, intent(in) :: corrected
    type(setting_acc_t), intent(in) :: acc
    type(romrun_row_t), intent(in) :: row
    integer :: nt, steps
    nt = this%st%n_steps
    steps = max(1, nt * blk%n)
    call log%info("   " // trim(blk%name) // ": E_avg " // str(row%e_avg, "es9.2") // ", E_max " // &
      str(row%e_max, "es9.2") // ", best approximation " // str(row%e_proj, "es9.2") // ", deepest overlap " // &
      str(row%overlap, "es9.2") // ", agents not out " // str(row%not_left) // " (FOM " // str(row%not_left_fom) // &
      "), mobility " // str(row%mobility, "f6.3") // ", infeasible steps " // str(row%infeasible) // &
      ", capped " // str(row%capped) // ", " // &
      str(row%t_step, "es9.2") // " s/step, " // str(row%t_query, "es9.2") // " s per whole query")
    call log%info("   " // trim(blk%name) // ": displacement error " // str(row%meas%e_disp, "es9.2") // &
      ", overlap agent-agent " // str(row%meas%overlap_aa, "es9.2") // ", agent-wall " // &
      str(row%meas%overlap_aw, "es9.2") // ", evacuation-time error " // evac_text(row%meas, 1) // "; " // &
      evac_text(row%meas, 2))
    if (eim_exact_rows(ops) > 0) call log%info("   EIM: " // str(eim_exact_rows(ops)) // " row evaluations " // &
      "were exact (interpolated normal shorter than 1/2), over " // str(sum(acc%n_done) * this%cfg%timing_repeats) // &
      " steps of " // str(pair%r) // " rows")
    if (row%diverged > 0) call log%warn(str(row%diverged) // " of " // str(blk%n) // " " // trim(blk%name) // &
      " reduced trajectories diverged: E_avg and every other aggregate of this row are over the other " // &
      str(blk%n - row%diverged) // " samples (column samples_diverged)")
    if (this%cfg%solver == 'dual') call log%info("   dual active set: " // str(acc%n_fallback) // " of " // &
      str(nt * blk%n) // " steps fell back to the NNLS (found infeasible " // str(acc%why(1)) // &
      ", capped or > 3/4 Nb active " // str(acc%why(2)) // ", not certified " // str(acc%why(3)) // &
      "); per step: active rows " // str(real(acc%active_sum, wp) / steps, "f6.1") // ", rows added " // &
      str(real(acc%n_adds, wp) / steps, "f6.2") // ", dropped " // str(real(acc%n_drops, wp) / steps, "f6.2"))
    if (corrected) call log%info("   local correction (" // trim(this%ref%exact_solver) // "): " // &
      str(100 * row%corr_frac, "f7.3") // "% of the agents corrected per step (largest " // &
      str(100 * row%corr_frac_max, "f7.3") // "%), of which in a violated row " // &
      str(100 * real(acc%n_seed, wp) / (real(this%st%n_agents, wp) * max(1, sum(acc%n_done))), "f7.3") // &
      "% (the rest: their neighbours); conflicts on " // str(acc%n_conflict) // " of " // &
      str(sum(acc%n_done)) // " steps, " // str(row%t_correct, "es9.2") // " s per step")
    if (row%corr_unsolved > 0) call log%warn(str(row%corr_unsolved) // " corrected steps were not solved to the " // &
      "tolerance even by the projection with every agent free (infeasible step): the exact solver's best " // &
      "iterate was used (column correction_unsolved_steps)")
    call log%info("   time per step (fastest repeat of each sample): positions " // &
      str(acc%t_parts(1) / steps, "es9.2") // " s, assembly " // str(acc%t_parts(2) / steps, "es9.2") // &
      " s, solve " // str(acc%t_parts(3) / steps, "es9.2") // " s")
    if (this%st%cfg%desired%speed_model == 'weidmann') call log%info("   density-dependent speed: " // &
      "the local density of " // str(size(ops%agents)) // " of " // str(this%st%n_agents) // &
      " agents per step (those the assembly reads)")
    if (row%infeasible > 0) call log%warn(str(row%infeasible) // " reduced steps were infeasible (the reduced " // &
      "positions already overlap): least-violation coefficients used")
    if (row%capped > 0) call log%warn(str(row%capped) // " reduced solves stopped at their iteration cap " // &
      "(nnls_max_iter / uzawa_max_iter): those steps are not converged")
    if (row%extrapolating > 0) call log%warn(str(row%extrapolating) // " of " // str(blk%n) // " " // &
      trim(blk%name) // " parameters lie outside the training box: the reduced model extrapolates")
  end subroutine report_row

  !> The output group of setting ks on blk (the romrun file's set): the setting, the row's
  !> summary figures and every per-sample array, moved out of acc.
  subroutine pack_set(this, ks, kset, pair, blk, ops, acc, row, out_set)
    type(rom_sweep_t), intent(in) :: this
    integer, intent(in) :: ks, kset
    type(rom_pair_t), intent(in) :: pair
    type(sample_block_t), intent(in) :: blk
    class(reduced_ops_t), intent(in) :: ops
    type(setting_acc_t), intent(inout) :: acc
    type(romrun_row_t), intent(in) :: row
    type(romrun_set_t), intent(out) :: out_set
    integer :: k, nt
    nt = this%st%n_steps
    out_set%setting = ks; out_set%n = pair%n; out_set%r = pair%r; out_set%nb = pair%nb; out_set%pair = pair%index
    out_set%m = ops%m
    out_set%hyper = this%cfg%hyper(kset); out_set%contacts = this%cfg%contacts(kset); out_set%solver = this%cfg%solver
    out_set%correction = this%cfg%correction(kset)
    if (allocated(acc%ncorr)) then
      call move_alloc(acc%ncorr, out_set%n_corrected); call move_alloc(acc%tcorr, out_set%t_correct)
    end if
    out_set%name = blk%name
    out_set%summary = trim(blk%name) == trim(this%blocks(size(this%blocks))%name) .or. &
      trim(blk%name) == trim(this%cfg%setting_sets(kset))
    out_set%e_avg = row%e_avg; out_set%samples_diverged = row%diverged; out_set%t_step = row%t_step
    out_set%speedup_uzawa = speedup(this%ref%t_uz, row%t_step); out_set%speedup_exact = speedup(this%ref%t_ex, row%t_step)
    out_set%params = blk%mu
    call move_alloc(acc%alpha, out_set%alpha); call move_alloc(acc%beta, out_set%beta)
    call move_alloc(acc%pos, out_set%positions); call move_alloc(acc%err_time, out_set%err_time)
    call move_alloc(acc%e_mu, out_set%e_mu); call move_alloc(acc%e_proj, out_set%e_proj)
    call move_alloc(acc%overlap, out_set%max_overlap); call move_alloc(acc%mobility, out_set%mobility)
    call move_alloc(acc%not_left, out_set%n_not_left); call move_alloc(acc%not_left_fom, out_set%n_not_left_fom)
    call move_alloc(acc%infeas, out_set%n_infeasible); call move_alloc(acc%capped, out_set%n_capped)
    call move_alloc(acc%extrap, out_set%extrapolating); call move_alloc(acc%time, out_set%time)
    call move_alloc(acc%div_step, out_set%diverged_step)
    out_set%e_disp = acc%ms%e_disp; out_set%overlap_aa = acc%ms%overlap_aa; out_set%overlap_aw = acc%ms%overlap_aw
    allocate(out_set%evac_rom(nt + 1, blk%n), out_set%t_out_rom(size(EVAC_PCT), blk%n))
    do k = 1, blk%n
      out_set%evac_rom(:, k) = acc%ms(k)%evac_rom
      out_set%t_out_rom(:, k) = acc%ms(k)%t_rom
    end do
    allocate(out_set%qoi(blk%n))
    do k = 1, blk%n
      out_set%qoi(k) = acc%ms(k)%qoi_rom
    end do
    if (blk%has_fom) then
      allocate(out_set%evac_fom(nt + 1, blk%n), out_set%t_out_fom(size(EVAC_PCT), blk%n))
      do k = 1, blk%n
        out_set%evac_fom(:, k) = acc%ms(k)%evac_fom
        out_set%t_out_fom(:, k) = acc%ms(k)%t_fom
      end do
    end if
  end subroutine pack_set

  !> "t50: error e over n samples (ROM misses a, no FOM reference b)".
  function evac_text(m, j) result(s)
    type(row_measures_t), intent(in) :: m
    integer, intent(in) :: j
    character(len=:), allocatable :: s
    s = "t" // str(EVAC_PCT(j)) // " " // str(m%t_err(j), "es9.2") // " over " // str(m%t_n(j)) // &
      " samples (reduced never reaches it: " // str(m%t_rom_missed(j)) // ", full: " // str(m%t_fom_missed(j)) // ")"
  end function evac_text


  !> Mean time per full-order step over the first fom_timing_samples samples of blk for each
  !> solver of `solvers` (t_step, kkt_max, n_nonconv, t_query [size(solvers)]), and t_query:
  !> the mean wall time of one whole query (parameter applied, model built with its scene and
  !> desired velocity, every step timed). The solvers are interleaved sample by sample, so
  !> that a change of the machine's load during the timing biases none of them; each exact
  !> solver's sample counts with the fastest of timing_repeats runs, as the reduced model's.
  subroutine fom_timing(this, env, log, blk, solvers, t_step, kkt_max, n_nonconv, t_query, error)
    type(rom_sweep_t), intent(in) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(sample_block_t), intent(in) :: blk
    character(len=*), intent(in) :: solvers(:)
    real(wp), intent(out) :: t_step(:), kkt_max(:)
    integer, intent(out) :: n_nonconv(:)
    real(wp), intent(out) :: t_query(:)
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: w0, ts, ts_best, tq_best
    type(config_t) :: c2
    type(step_record_t) :: rec
    real(wp), allocatable :: speeds(:)
    integer :: k, nu, ns, j, rep, n_rep
    integer :: nsteps(size(solvers))
    character(len=:), allocatable :: solver
    t_step = 0; kkt_max = 0; n_nonconv = 0; t_query = 0
    nsteps = this%st%n_steps
    where (solvers == 'uzawa' .and. this%cfg%fom_uzawa_steps > 0) nsteps = min(nsteps, this%cfg%fom_uzawa_steps)
    ns = min(this%cfg%fom_timing_samples, blk%n)
    call log%progress_start()
    do k = 1, ns
      do j = 1, size(solvers)
        solver = trim(solvers(j))
        c2 = this%st%cfg
        c2%solver%name = solver
        c2%solver%tol = this%cfg%fom_tol
        if (solver == 'uzawa') then
          ! the paper's full-order model: cold start, its own stopping test
          c2%solver%uzawa_eps = this%cfg%fom_uzawa_eps
          c2%solver%warm_start = .false.
          ! every pair and agent-obstacle pair a row, as in the paper (cutoff beyond the scene)
          if (this%cfg%fom_uzawa_rows == 'all') c2%contacts%cutoff_factor = 1.0e9_wp
        end if
        ! the exact solvers as the reduced model is timed: the fastest of timing_repeats runs of
        ! each sample (the paper's Uzawa, far slower, once)
        n_rep = 1
        if (solver /= 'uzawa') n_rep = max(1, this%cfg%timing_repeats)
        ts_best = huge(1.0_wp); tq_best = huge(1.0_wp)
        do rep = 1, n_rep
          speeds = this%st%speeds
          w0 = env%wtime()
          call this%st%space%apply(blk%mu(:, k), c2, speeds)
          ts = 0
          fresh: block
            type(fom_t) :: fom
            call fom%init(c2, error, q0=this%st%q0, speeds=speeds)
            if (allocated(error)) return
            do nu = 1, nsteps(j)
              call fom%advance(rec, error)
              if (allocated(error)) then
                call prefix_error(error, "full-order timing (" // solver // ")"); return
              end if
              ts = ts + rec%t_step
              if (rep == 1) then
                kkt_max(j) = max(kkt_max(j), rec%kkt)
                if (.not. rec%converged) n_nonconv(j) = n_nonconv(j) + 1
              end if
            end do
            tq_best = min(tq_best, env%wtime() - w0)
            ts_best = min(ts_best, ts)
          end block fresh
        end do
        t_step(j) = t_step(j) + ts_best
        t_query(j) = t_query(j) + tq_best
      end do
      call log%progress("full-order sample", k, ns)
    end do
    t_step = t_step / max(1, ns * nsteps)
    t_query = t_query / max(1, ns)
  end subroutine fom_timing

  !> The one sample of sets = 'given'.
  subroutine given_block(this, blk, error)
    type(rom_sweep_t), intent(in) :: this
    type(sample_block_t), intent(out) :: blk
    type(error_t), allocatable, intent(out) :: error
    integer :: nmu
    nmu = count(this%cfg%mu > -huge(1.0_wp))
    if (nmu /= this%st%space%n_expanded) then
      call set_error(error, this%where // ": mu has " // str(nmu) // " values but the study has " // &
        str(this%st%space%n_expanded) // " parameter components (" // shorten(this%st%param_names, 60) // ")", EXIT_BAD_INPUT)
      return
    end if
    call this%st%space%check_values(this%cfg%mu(1:nmu), this%st%cfg, this%where // ": mu", error)
    if (allocated(error)) return
    blk%name = 'given'
    blk%n = 1
    blk%mu = reshape(this%cfg%mu(1:nmu), [nmu, 1])
    allocate(blk%q(this%st%n_dof, 0), blk%u(this%st%n_dof, 0))
    blk%has_fom = .false.
  end subroutine given_block

  !> One line of the CSV table.
  function csv_line(this, r) result(s)
    type(rom_sweep_t), intent(in) :: this
    type(romrun_row_t), intent(in) :: r
    character(len=:), allocatable :: s
    associate (f => this%ref)
      s = str(r%setting) // "," // trim(r%set) // "," // str(r%n) // "," // str(r%r) // "," // str(r%nb) // "," // &
        trim(r%hyper) // "," // trim(r%contacts) // "," // trim(r%solver) // "," // str(r%m(1)) // "," // &
        str(r%m(2)) // "," // str(r%m(3)) // "," // e(r%e_avg) // "," // e(r%e_max) // "," // e(r%e_proj) // &
        "," // e(r%overlap) // "," // str(r%not_left) // "," // str(r%not_left_fom) // "," // str(r%infeasible) // &
        "," // str(r%capped) // "," // e(r%t_step) // "," // e(f%t_uz) // "," // e(f%t_ex) // "," // &
        e(speedup(f%t_uz, r%t_step)) // "," // e(speedup(f%t_ex, r%t_step)) // "," // str(r%extrapolating) // "," // &
        e(r%mobility) // "," // str(r%diverged) // "," // e(r%meas%e_disp) // "," // e(r%meas%overlap_aa) // "," // &
        e(r%meas%overlap_aw) // "," // evac_csv(r%meas, 1) // "," // evac_csv(r%meas, 2) // "," // &
        e(r%t_query) // "," // e(f%t_query) // "," // e(speedup(f%t_query, r%t_query)) // "," // &
        trim(r%correction) // "," // e(r%corr_frac) // "," // e(r%corr_frac_max) // "," // e(r%t_correct) // "," // &
        trim(f%exact_solver) // "," // str(r%corr_unsolved)
    end associate
  end function csv_line

  function evac_csv(m, j) result(s)
    type(row_measures_t), intent(in) :: m
    integer, intent(in) :: j
    character(len=:), allocatable :: s
    s = e(m%t_err(j)) // "," // str(m%t_n(j)) // "," // str(m%t_rom_missed(j)) // "," // str(m%t_fom_missed(j))
  end function evac_csv

  !> The table, written (and checked on disk) under a temporary name; run renames it together
  !> with the run file.
  subroutine write_csv(this, error)
    type(rom_sweep_t), intent(in) :: this
    type(error_t), allocatable, intent(out) :: error
    integer :: k
    character(len=:), allocatable :: text, msg
    text = "setting,set,n,r,n_basis,hyper,contacts,solver,m_v,m_b,m_d,E_avg,E_max,E_proj_avg," // &
      "max_overlap,agents_not_left,agents_not_left_fom,infeasible_steps,capped_steps,t_step_rom," // &
      "t_step_fom_uzawa,t_step_fom_exact,speedup_uzawa,speedup_exact,extrapolating,mobility,samples_diverged," // &
      "E_disp,max_overlap_agents,max_overlap_walls,t50_err,t50_n,t50_rom_missed,t50_fom_missed," // &
      "t90_err,t90_n,t90_rom_missed,t90_fom_missed,t_query_rom,t_query_fom_exact,speedup_query_exact," // &
      "correction,corrected_fraction,corrected_fraction_max,t_correct_step,fom_exact_solver," // &
      "correction_unsolved_steps" // &
      new_line('a')
    do k = 1, size(this%rows)
      text = text // csv_line(this, this%rows(k)) // new_line('a')
    end do
    call write_whole_file(trim(this%cfg%table) // ".partial", text, msg)
    if (len(msg) > 0) call set_error(error, this%where // ": table: " // msg)
  end subroutine write_csv

  !> The sweep table on the log (after run).
  subroutine print_table(this, log)
    class(rom_sweep_t), intent(in) :: this
    type(logger_t), intent(inout) :: log
    integer :: k
    if (.not. allocated(this%rows)) return
    associate (rows => this%rows, f => this%ref)
      call log%info("")
      call log%info("| setting | set | N | R | Nb | hyper | contacts | m_v,m_b,m_d | E_avg | E_max | best approx. |" // &
        " E_disp | t50 err | t90 err | overlap agents / walls | not out (FOM) | mobility | infeas. | diverged |" // &
        " t_step ROM [s] | speedup vs uzawa | speedup vs " // trim(f%exact_solver) // &
        " | t_query ROM [s] | query speedup vs " // trim(f%exact_solver) // " | correction | corrected/step |")
      call log%info("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|" // &
        "---|---|")
      do k = 1, size(rows)
        associate (r => rows(k))
          call log%info("| " // str(r%setting) // " | " // trim(r%set) // " | " // str(r%n) // " | " // str(r%r) // &
            " | " // str(r%nb) // " | " // trim(r%hyper) // " | " // trim(r%contacts) // " | " // str(r%m(1)) // "," // &
            str(r%m(2)) // "," // str(r%m(3)) // " | " // str(r%e_avg, "es9.2") // trim(merge("*", " ", r%diverged > 0)) // &
            " | " // str(r%e_max, "es9.2") // " | " // str(r%e_proj, "es9.2") // " | " // str(r%meas%e_disp, "es9.2") // &
            " | " // tcell(r%meas, 1) // " | " // tcell(r%meas, 2) // " | " // str(r%meas%overlap_aa, "es9.2") // &
            " / " // str(r%meas%overlap_aw, "es9.2") // " | " // str(r%not_left) // &
            " (" // str(r%not_left_fom) // ") | " // str(r%mobility, "f6.3") // " | " // str(r%infeasible) // &
            " | " // str(r%diverged) // " | " // str(r%t_step, "es9.2") // " | " // &
            str(speedup(f%t_uz, r%t_step), "f9.1") // " | " // str(speedup(f%t_ex, r%t_step), "f9.1") // " | " // &
            str(r%t_query, "es9.2") // " | " // str(speedup(f%t_query, r%t_query), "f9.1") // " | " // &
            trim(r%correction) // " | " // corr_cell(r) // " |")
        end associate
      end do
      if (any(rows%diverged > 0)) call log%info("* some samples of this row diverged (column diverged): its " // &
        "figures are over the other samples only")
      call log%info("t50/t90 err: mean |t_ROM - t_FOM| / t_FOM of the times at which 50% / 90% of the agents are " // &
        "out, over the (n) samples where both reach it; 'ROM never k': k samples where only the full model " // &
        "reaches it within the horizon")
      call log%info("t_query: one whole query as a user pays it, per sample: the per-parameter setup (scene, " // &
        "desired velocity) plus the whole trajectory; the " // trim(f%exact_solver) // " full model's " // &
        "whole query takes " // str(f%t_query, "es9.2") // " s")
      if (this%cfg%fom_exact_solver == 'fastest' .and. len(f%timings) > 0) call log%info("exact full model: " // &
        trim(f%exact_solver) // ", the fastest per step of (name, s/step, s/query) " // f%timings)
      if (any(rows%correction == 'local')) call log%info("corrected/step: mean (largest) per cent of the agents " // &
        "whose velocity the local exact correction solved for, per step; 'k unsolved': k steps that even the " // &
        "projection with every agent free could not solve to the tolerance")
    end associate
  end subroutine print_table

  !> Correction cell of the printed table.
  function corr_cell(r) result(s)
    type(romrun_row_t), intent(in) :: r
    character(len=:), allocatable :: s
    if (r%correction == 'local') then
      s = str(100 * r%corr_frac, "f7.3") // "% (" // str(100 * r%corr_frac_max, "f7.3") // "%)"
      if (r%corr_unsolved > 0) s = s // ", " // str(r%corr_unsolved) // " unsolved"
    else
      s = "-"
    end if
  end function corr_cell

  !> Evacuation-time cell of the printed table.
  function tcell(m, j) result(s)
    type(row_measures_t), intent(in) :: m
    integer, intent(in) :: j
    character(len=:), allocatable :: s
    if (m%t_n(j) > 0) then
      s = str(m%t_err(j), "es9.2") // " (" // str(m%t_n(j)) // ")"
    else
      s = "n/a"
    end if
    if (m%t_rom_missed(j) > 0) s = s // ", ROM never " // str(m%t_rom_missed(j))
  end function tcell

  !> The JSON summary of the sweep (after run) at `path`.
  subroutine write_summary(this, path, error)
    class(rom_sweep_t), intent(in) :: this
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    type(json_writer_t) :: js
    integer :: j, k
    if (.not. allocated(this%rows)) then
      call set_error(error, "crowd_rom: summary asked before the sweep ran"); return
    end if
    associate (rows => this%rows, f => this%ref)
      call js%add("program", "crowd_rom")
      call js%add("output", trim(this%cfg%output))
      call js%add("settings", size(this%setting_ids))
      call js%add("t_step_fom_uzawa", f%t_uz)
      call js%add("t_step_fom_exact", f%t_ex)
      call js%add("t_query_fom_exact", f%t_query)
      call js%add("fom_exact_solver", trim(f%exact_solver))
      call js%add("fom_exact_solver_asked", trim(this%cfg%fom_exact_solver))
      call js%add("fom_exact_timings", f%timings)
      call js%add("e_avg_last", rows(size(rows))%e_avg)
      call js%add("max_overlap", maxval(rows%overlap))
      call js%add("infeasible_steps", sum(rows%infeasible))
      call js%add("capped_steps", sum(rows%capped))
      call js%add("t_step_rom_min", minval(rows%t_step))
      call js%add("e_avg_max", maxval(rows%e_avg))
      call js%add("mobility_min", minval(rows%mobility))
      call js%add("mobility_max", maxval(rows%mobility))
      call js%add("agents_not_left", sum(rows%not_left))
      call js%add("agents_not_left_fom", sum(rows%not_left_fom))
      call js%add("extrapolating_samples", sum(rows%extrapolating))
      call js%add("samples_diverged", sum(rows%diverged))
      call js%add("rows_with_diverged_samples", count(rows%diverged > 0))
      call js%add("correction_unsolved_steps", sum(rows%corr_unsolved))
      ! one array per column, in table order (-1: not available; t*_err over t*_n samples)
      call js%begin_object("rows")
      call js%add("setting", rows%setting)
      call js%add("samples_diverged", rows%diverged)
      call js%add("E_avg", rows%e_avg)
      call js%add("E_disp", rows%meas%e_disp)
      call js%add("mobility", rows%mobility)
      call js%add("max_overlap_agents", rows%meas%overlap_aa)
      call js%add("max_overlap_walls", rows%meas%overlap_aw)
      do j = 1, size(EVAC_PCT)
        call js%add("t" // str(EVAC_PCT(j)) // "_err", [(rows(k)%meas%t_err(j), k = 1, size(rows))])
        call js%add("t" // str(EVAC_PCT(j)) // "_n", [(rows(k)%meas%t_n(j), k = 1, size(rows))])
        call js%add("t" // str(EVAC_PCT(j)) // "_rom_missed", [(rows(k)%meas%t_rom_missed(j), k = 1, size(rows))])
        call js%add("t" // str(EVAC_PCT(j)) // "_fom_missed", [(rows(k)%meas%t_fom_missed(j), k = 1, size(rows))])
      end do
      call js%add("t_step_rom", rows%t_step)
      call js%add("speedup_exact", [(speedup(f%t_ex, rows(k)%t_step), k = 1, size(rows))])
      call js%add("t_query_rom", rows%t_query)
      call js%add("t_query_fom_exact", [(f%t_query, k = 1, size(rows))])
      call js%add("speedup_query_exact", [(speedup(f%t_query, rows(k)%t_query), k = 1, size(rows))])
      call js%add("correction_local", [(merge(1, 0, rows(k)%correction == 'local'), k = 1, size(rows))])
      call js%add("corrected_fraction", rows%corr_frac)
      call js%add("corrected_fraction_max", rows%corr_frac_max)
      call js%add("t_correct_step", rows%t_correct)
      call js%add("correction_unsolved_steps", rows%corr_unsolved)
      call js%end_object()
    end associate
    call js%write_file(path, error)
  end subroutine write_summary

  function e(x) result(s)
    real(wp), intent(in) :: x
    character(len=:), allocatable :: s
    s = str(x, "es12.5")
    s = trim(adjustl(s))
  end function e

  function pair_list(hdr) result(s)
    type(rom_file_t), intent(in) :: hdr
    character(len=:), allocatable :: s
    integer :: k
    s = ""
    do k = 1, hdr%n_pairs
      s = s // " (" // str(hdr%pair_n(k)) // ", " // str(hdr%pair_r(k)) // ")"
    end do
  end function pair_list
end module cr_rom_sweep
