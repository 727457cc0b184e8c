!> crowd_rom: the online reduced model and its accuracy/speed sweep (serial).
!>
!>   crowd_rom input.nml [--summary FILE]
!>
!> The input holds a &rom group (see README). The scene, time step and parameter space come
!> from the snapshot database the ROM file was built from. For every setting of the sweep
!> and every sample of the chosen sets, the reduced model is stepped; where full-order
!> trajectories exist, E_mu, E_avg, the velocity best-approximation error, overlaps and
!> agents that fail to leave are reported, with the time per reduced step and the speedup
!> over the full-order model (the paper's Uzawa and the fastest exact solver, both timed in
!> this run at the same tolerance). Results: the HDF5 file &rom output (schema
!> crowdrom-romrun) and the table &rom table (CSV), both written atomically.
program crowd_rom
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str, shorten
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish
  use cr_config, only: config_t, FOM_GROUPS
  use cr_inputs, only: check_input_groups
  use cr_namelist_text, only: namelist_text_t
  use cr_rom_config, only: rom_cfg_t, read_rom, check_rom, rom_echo, MAX_SETTINGS, check_rom_paths
  use cr_rom_file, only: rom_file_t, rom_pair_t, read_rom_file, read_rom_pair, find_pair
  use cr_rom_study, only: rom_study_t, sample_block_t, open_study, read_block_set
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t, make_reduced_ops, eim_exact_rows
  use cr_rom_stepper, only: rom_solver_cfg_t, rom_traj_t, run_trajectory, reduced_positions
  use cr_rom_metrics, only: projection_error, sample_measures_t, row_measures_t, measure_sample, &
    aggregate_measures, EVAC_PCT
  use cr_rom_guard, only: rom_guard_t
  use cr_fom, only: fom_t, step_record_t
  use cr_romrun_file, only: romrun_header_t, romrun_row_t, romrun_set_t, romrun_writer_t, speedup
  use cr_fsys, only: rename_file, remove_file, write_whole_file
  use cr_json, only: json_writer_t
  implicit none

  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(rom_cfg_t) :: rcfg
  type(namelist_text_t) :: nml
  type(error_t), allocatable :: error
  integer :: code
  ! state of the run, shared by the procedures below
  type(rom_file_t) :: hdr
  type(rom_study_t) :: st
  type(sample_block_t), allocatable :: blocks(:)
  type(romrun_writer_t) :: out
  type(romrun_header_t) :: rhdr
  character(len=:), allocatable :: dbpath, where
  integer, allocatable :: setting_ids(:)
  real(wp) :: t_uz = 0, t_ex = 0, kkt_uz = 0, kkt_ex = 0
  !> one whole exact full-order query: setup for the parameter plus every step (seconds)
  real(wp) :: t_qex = 0
  integer :: nc_uz = 0, nc_ex = 0

  call program_start("crowd_rom", env, log, cli, error)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error) .and. env%size > 1) call set_error(error, "crowd_rom is serial: run it " // &
    "without mpirun (or with -np 1); the parallel stages are crowd_snapshots and crowd_offline", 2)
  if (.not. allocated(error)) call nml%load(cli%input, env, error)
  if (.not. allocated(error)) call nml%require_groups('crowd_rom', ['rom'], FOM_GROUPS, error)
  if (.not. allocated(error)) call read_rom(nml, rcfg, error)
  if (.not. allocated(error)) call check_input_groups(nml, error)
  if (.not. allocated(error)) call check_rom(cli%input, rcfg, error)
  if (.not. allocated(error)) call check_rom_paths(cli%input, cli%summary, rcfg, trim(rcfg%database), error)
  if (.not. allocated(error)) call run(error)
  code = program_finish(env, log, error)
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: crowd_rom input.nml [--summary FILE]"
    print '(a)', ""
    print '(a)', "Runs the reduced model of a ROM file (crowd_offline) for the validation (or training,"
    print '(a)', "or given) parameters of its study, for every setting of the &rom sweep (N, R,"
    print '(a)', "hyper-reduction none | eim | eq, contacts cone | online, m_v, m_b, m_d); reports"
    print '(a)', "E_avg, overlaps, agents that fail to leave, time per step and the speedup over the"
    print '(a)', "full-order model; writes &rom output (HDF5) and &rom table (CSV). Serial."
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 1 other failure."
  end subroutine print_help

  subroutine run(error)
    type(error_t), allocatable, intent(out) :: error
    type(rom_pair_t), allocatable :: pairs(:)
    logical, allocatable :: loaded(:)
    type(romrun_row_t), allocatable :: rows(:)
    integer, allocatable :: pair_of(:)
    integer :: ks, ib, kp, nrow, k

    where = cli%input // ": &rom"
    call log%stage_begin("crowd_rom: read ROM file and study")
    call read_rom_file(trim(rcfg%rom_file), where // ": rom_file", hdr, error)
    if (allocated(error)) return
    dbpath = trim(rcfg%database)
    if (len(dbpath) == 0) dbpath = hdr%database
    call check_rom_paths(cli%input, cli%summary, rcfg, dbpath, error)
    if (allocated(error)) return
    call open_study(dbpath, where // ": database", hdr, st, error)
    if (allocated(error)) return
    call log%info("   " // str(st%n_agents) // " agents, " // str(st%n_steps) // " steps, parameters " // &
      shorten(st%param_names, 60) // "; ROM pairs (N, R) stored: " // pair_list(hdr))
    ! parameter sets
    select case (trim(rcfg%sets))
    case ('valid', 'train')
      allocate(blocks(1))
      call read_block_set(st, trim(rcfg%sets), rcfg%n_samples, blocks(1), error)
    case ('both')
      allocate(blocks(2))
      call read_block_set(st, 'train', rcfg%n_samples, blocks(1), error)
      if (.not. allocated(error)) call read_block_set(st, 'valid', rcfg%n_samples, blocks(2), error)
    case ('given')
      allocate(blocks(1))
      call given_block(st, blocks(1), error)
    end select
    if (allocated(error)) return
    ! settings
    setting_ids = pack([(ks, ks = 1, MAX_SETTINGS)], rcfg%n > 0)
    if (size(setting_ids) == 0) then
      call set_error(error, where // ": no setting given (n(1) = N, r(1) = R, ...)", 2); return
    end if
    allocate(pairs(hdr%n_pairs), loaded(hdr%n_pairs))
    loaded = .false.
    allocate(pair_of(size(setting_ids)))
    do ks = 1, size(setting_ids)
      call find_pair(hdr, rcfg%n(setting_ids(ks)), rcfg%r(setting_ids(ks)), where // ": setting " // &
        str(setting_ids(ks)), pair_of(ks), error)
      if (allocated(error)) return
    end do
    call log%stage_end()

    ! full-order reference timing
    t_uz = 0; t_ex = 0; kkt_uz = 0; kkt_ex = 0; nc_uz = 0; nc_ex = 0; t_qex = 0
    if (rcfg%fom_timing_samples > 0) then
      call log%stage_begin("crowd_rom: full-order timing (paper's uzawa on " // trim(rcfg%fom_uzawa_rows) // &
        " rows, eps " // str(rcfg%fom_uzawa_eps) // &
        "; " // trim(rcfg%fom_exact_solver) // ", KKT tolerance " // str(rcfg%fom_tol) // ")")
      call fom_timing(st, blocks(size(blocks)), 'uzawa', t_uz, kkt_uz, nc_uz, error)
      if (allocated(error)) return
      call fom_timing(st, blocks(size(blocks)), trim(rcfg%fom_exact_solver), t_ex, kkt_ex, nc_ex, error, &
        t_query=t_qex)
      if (allocated(error)) return
      call log%info("   uzawa " // str(t_uz, "es10.3") // " s/step (largest KKT " // str(kkt_uz, "es9.2") // ", " // &
        str(nc_uz) // " non-converged steps); " // trim(rcfg%fom_exact_solver) // " " // str(t_ex, "es10.3") // &
        " s/step (largest KKT " // str(kkt_ex, "es9.2") // "), " // str(t_qex, "es10.3") // " s per whole query")
      call log%stage_end()
    end if

    ! output file
    call make_header()
    call out%open(trim(rcfg%output), rhdr, error)
    if (allocated(error)) then
      call prefix_error(error, where // ": output"); error%code = 2; return
    end if

    allocate(rows(size(setting_ids) * size(blocks)))
    nrow = 0
    do ks = 1, size(setting_ids)
      kp = pair_of(ks)
      if (.not. loaded(kp)) then
        call read_rom_pair(hdr, kp, pairs(kp), error); if (allocated(error)) goto 9
        loaded(kp) = .true.
      end if
      call log%stage_begin("crowd_rom: setting " // str(ks) // " of " // str(size(setting_ids)) // ": (N, R) = (" // &
        str(pairs(kp)%n) // ", " // str(pairs(kp)%r) // "), basis " // str(pairs(kp)%nb) // ", hyper " // &
        trim(rcfg%hyper(setting_ids(ks))) // ", contacts " // trim(rcfg%contacts(setting_ids(ks))) // &
        ", solver " // trim(rcfg%solver))
      do ib = 1, size(blocks)
        nrow = nrow + 1
        call run_setting(ks, setting_ids(ks), pairs(kp), blocks(ib), rows(nrow), error)
        if (allocated(error)) goto 9
      end do
      call log%stage_end()
    end do
    call out%write_table(rhdr, rows(1:nrow), error); if (allocated(error)) goto 9
    ! the run file and the table are one result: the table is written completely first, then
    ! both are renamed; if either fails, neither replaces an earlier result
    call write_csv(rows(1:nrow), error); if (allocated(error)) goto 9
    call out%commit(error)
    if (allocated(error)) then
      k = remove_file(trim(rcfg%table) // ".partial"); return
    end if
    if (rename_file(trim(rcfg%table) // ".partial", trim(rcfg%table)) /= 0) then
      call set_error(error, where // ": table: cannot rename '" // trim(rcfg%table) // ".partial' to '" // &
        trim(rcfg%table) // "'; the run file is kept as '" // trim(rcfg%output) // ".partial'")
      k = rename_file(trim(rcfg%output), trim(rcfg%output) // ".partial")
      return
    end if
    call print_table(rows(1:nrow))
    if (len(cli%summary) > 0) call write_summary(rows(1:nrow), error)
    return
9   call out%abort()
  end subroutine run

    !> The ROM-run header of this sweep.
    subroutine make_header()
      rhdr%config = rom_echo(rcfg)
      rhdr%rom_file = trim(rcfg%rom_file); rhdr%database = dbpath; rhdr%db_hash = st%hash
      rhdr%n_agents = st%n_agents; rhdr%n_steps = st%n_steps; rhdr%dt = st%dt; rhdr%radius = st%radius
      rhdr%param_names = st%param_names; rhdr%param_min = st%space%lo; rhdr%param_max = st%space%hi
      rhdr%n_settings = size(setting_ids)
      rhdr%t_uz = t_uz; rhdr%t_ex = t_ex; rhdr%t_query_ex = t_qex; rhdr%exact_solver = trim(rcfg%fom_exact_solver)
      rhdr%tolerance = rcfg%fom_tol; rhdr%uzawa_eps = rcfg%fom_uzawa_eps; rhdr%uzawa_steps = rcfg%fom_uzawa_steps
      rhdr%uzawa_rows = trim(rcfg%fom_uzawa_rows); rhdr%timing_samples = rcfg%fom_timing_samples
      rhdr%kkt_uz = kkt_uz; rhdr%kkt_ex = kkt_ex; rhdr%nc_uz = nc_uz
    end subroutine make_header

    !> Run setting ks (index kset in the &rom arrays) on one block of samples.
    subroutine run_setting(ks, kset, pair, blk, row, error)
      integer, intent(in) :: ks, kset
      type(rom_pair_t), intent(in) :: pair
      type(sample_block_t), intent(in) :: blk
      type(romrun_row_t), intent(out) :: row
      type(error_t), allocatable, intent(out) :: error
      class(reduced_ops_t), allocatable :: ops
      type(rom_solver_cfg_t) :: scfg
      type(rom_traj_t) :: traj, tr2
      type(eval_ctx_t) :: ctx
      type(rom_guard_t) :: guard
      logical, allocatable :: ok(:)
      integer, allocatable :: div_step(:), n_done(:)
      real(wp) :: c_max
      integer :: kbad
      real(wp), allocatable :: alpha(:,:), beta(:,:), pos(:,:), qr(:,:), err_time(:,:)
      real(wp), allocatable :: e_mu(:), e_proj(:), overlap(:), time(:), mobility(:), query(:)
      real(wp) :: w0, w_setup, w_run
      integer, allocatable :: not_left(:), not_left_fom(:), infeas(:), capped(:), extrap(:)
      type(sample_measures_t), allocatable :: ms(:)
      type(romrun_set_t) :: out_set
      integer :: k, nt, nb, rep, n_fallback, active_sum, n_adds, n_drops, why(3)
      real(wp) :: t_parts(3)
      nt = st%n_steps
      call make_reduced_ops(trim(rcfg%hyper(kset)), trim(rcfg%contacts(kset)), pair, &
        [rcfg%m_v(kset), rcfg%m_b(kset), rcfg%m_d(kset)], st%cfg%contacts%cutoff_factor, &
        where // ": setting " // str(kset), ops, error)
      if (allocated(error)) return
      scfg%name = rcfg%solver
      scfg%nnls_max_iter = rcfg%nnls_max_iter
      scfg%uzawa_rho_factor = rcfg%uzawa_rho_factor
      scfg%uzawa_eps = rcfg%uzawa_eps
      scfg%uzawa_max_iter = rcfg%uzawa_max_iter
      nb = pair%nb
      allocate(alpha(nb, nt * blk%n), beta(merge(pair%r, 0, ops%fixed_rows), nt * blk%n), &
        pos(st%n_dof, (nt + 1) * blk%n), err_time(nt + 1, blk%n), e_mu(blk%n), e_proj(blk%n), &
        overlap(blk%n), time(blk%n), mobility(blk%n), not_left(blk%n), not_left_fom(blk%n), infeas(blk%n), capped(blk%n), &
        extrap(blk%n), div_step(blk%n), n_done(blk%n), ms(blk%n), query(blk%n))
      div_step = 0
      err_time = -1; e_mu = -1; e_proj = -1; not_left_fom = -1; mobility = -1
      n_fallback = 0; active_sum = 0; n_adds = 0; n_drops = 0; t_parts = 0; why = 0
      call log%progress_start()
      do k = 1, blk%n
        ! the whole query as a user pays it: the per-parameter setup (scene, speeds, desired
        ! velocity, divergence guard) plus the trajectory (fastest repeat, per-trajectory setup included)
        w0 = env%wtime()
        call ctx_reset(ctx)
        call st%space%sample_model(blk%mu(:, k), st%cfg, st%speeds, st%radius, ctx%scene, ctx%speeds, &
          ctx%desired, error)
        if (allocated(error)) return
        ctx%radius = st%radius
        ctx%h = st%dt
        c_max = maxval(abs(ctx%speeds), mask=[(.true., kbad = 1, size(ctx%speeds))])
        if (size(ctx%speeds) == 0) c_max = 0
        if (ctx%desired%from_file) c_max = max(c_max, sqrt(2.0_wp) * maxval(abs(ctx%desired%fixed)))
        call guard%init(ctx%scene, c_max, st%dt * nt, st%n_agents)
        w_setup = env%wtime() - w0
        w0 = env%wtime()
        call run_trajectory(ops, ctx, st%q0, nt, scfg, traj, error, guard=guard)
        w_run = env%wtime() - w0
        if (allocated(error)) then
          call prefix_error(error, "setting " // str(ks) // ", " // trim(blk%name) // " sample " // str(k)); return
        end if
        do rep = 2, rcfg%timing_repeats
          w0 = env%wtime()
          call run_trajectory(ops, ctx, st%q0, nt, scfg, tr2, error, guard=guard)
          w_run = min(w_run, env%wtime() - w0)
          if (allocated(error)) return
          if (tr2%time < traj%time) then
            traj%time = tr2%time; traj%time_positions = tr2%time_positions
            traj%time_assemble = tr2%time_assemble; traj%time_solve = tr2%time_solve
          end if
        end do
        qr = reduced_positions(st%q0, pair%v, traj%alpha, st%dt)
        ! every agent checked (the stepper checks only the agents its assembly reads)
        kbad = guard%first_outside(qr)
        if (kbad > 0) then
          if (traj%diverged_step == 0 .or. kbad - 1 < traj%diverged_step) then
            traj%diverged_step = kbad - 1
            traj%alpha(:, kbad - 1:) = 0
            traj%beta(:, kbad - 1:) = 0
            qr = reduced_positions(st%q0, pair%v, traj%alpha, st%dt)
          end if
        end if
        div_step(k) = traj%diverged_step
        n_done(k) = merge(traj%diverged_step, nt, traj%diverged_step > 0)
        if (div_step(k) > 0) call log%warn("setting " // str(ks) // ", " // trim(blk%name) // " sample " // str(k) // &
          ": the reduced trajectory diverged at step " // str(div_step(k)) // " (non-finite values or an agent " // &
          "outside the hall's box inflated by its diagonal + 2 c_max T): stopped there, positions frozen, " // &
          "sample excluded from the averages")
        alpha(:, (k - 1) * nt + 1:k * nt) = traj%alpha
        if (size(beta, 1) > 0) beta(:, (k - 1) * nt + 1:k * nt) = traj%beta
        pos(:, (k - 1) * (nt + 1) + 1:k * (nt + 1)) = qr
        time(k) = traj%time
        query(k) = w_setup + max(w_run, traj%time)
        infeas(k) = traj%n_infeasible
        capped(k) = traj%n_capped
        n_fallback = n_fallback + traj%n_fallback; active_sum = active_sum + traj%active_sum
        n_adds = n_adds + traj%dual_adds; n_drops = n_drops + traj%dual_drops; why = why + traj%dual_why
        t_parts = t_parts + [traj%time_positions, traj%time_assemble, traj%time_solve]
        extrap(k) = merge(1, 0, any(blk%mu(:, k) < st%space%lo - 1.0e-12_wp * abs(st%space%lo)) .or. &
          any(blk%mu(:, k) > st%space%hi + 1.0e-12_wp * abs(st%space%hi)))
        if (blk%has_fom) then
          call measure_sample(ctx%scene, st%radius, st%dt, qr, ms(k), q=blk%q(:, (k - 1) * (nt + 1) + 1:k * (nt + 1)), &
            err=err_time(:, k))
          e_proj(k) = projection_error(blk%u(:, (k - 1) * nt + 1:k * nt), pair%v)
        else
          call measure_sample(ctx%scene, st%radius, st%dt, qr, ms(k))
        end if
        ms(k)%diverged = div_step(k) > 0
        e_mu(k) = ms(k)%e_mu
        mobility(k) = ms(k)%mobility
        overlap(k) = max(ms(k)%overlap_aa, ms(k)%overlap_aw)
        not_left(k) = ms(k)%not_left
        not_left_fom(k) = ms(k)%not_left_fom
        call log%progress(trim(blk%name) // " sample", k, blk%n)
      end do
      row%setting = ks; row%n = pair%n; row%r = pair%r; row%nb = nb; row%m = ops%m
      row%set = blk%name; row%hyper = rcfg%hyper(kset); row%contacts = rcfg%contacts(kset); row%solver = rcfg%solver
      row%t_step = sum(time) / max(1, sum(n_done))
      ! every aggregate over the samples that did not diverge (their count is reported)
      call aggregate_measures(ms, st%dt, row%meas)
      ok = div_step == 0
      if (any(ok)) then
        row%t_query = sum(query, mask=ok) / count(ok)
      else
        row%t_query = sum(query) / blk%n
      end if
      row%diverged = row%meas%n_diverged
      row%overlap = max(row%meas%overlap_aa, row%meas%overlap_aw)
      row%not_left = row%meas%not_left; row%infeasible = sum(infeas); row%capped = sum(capped)
      row%extrapolating = sum(extrap)
      row%e_avg = row%meas%e_avg; row%e_max = row%meas%e_max; row%mobility = row%meas%mobility
      row%not_left_fom = row%meas%not_left_fom
      if (blk%has_fom .and. any(ok)) row%e_proj = sum(e_proj, mask=ok) / count(ok)
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
        "were exact (interpolated normal shorter than 1/2), over " // str(sum(n_done) * rcfg%timing_repeats) // &
        " steps of " // str(pair%r) // " rows")
      if (row%diverged > 0) call log%warn(str(row%diverged) // " of " // str(blk%n) // " " // trim(blk%name) // &
        " reduced trajectories diverged: E_avg and every other aggregate of this row are over the other " // &
        str(blk%n - row%diverged) // " samples (column samples_diverged)")
      if (rcfg%solver == 'dual') call log%info("   dual active set: " // str(n_fallback) // " of " // &
        str(nt * blk%n) // " steps fell back to the NNLS (found infeasible " // str(why(1)) // ", capped or > 3/4 Nb active " // &
        str(why(2)) // ", not certified " // str(why(3)) // "); per step: active rows " // &
        str(real(active_sum, wp) / max(1, nt * blk%n), "f6.1") // ", rows added " // &
        str(real(n_adds, wp) / max(1, nt * blk%n), "f6.2") // ", dropped " // &
        str(real(n_drops, wp) / max(1, nt * blk%n), "f6.2"))
      call log%info("   time per step (fastest repeat of each sample): positions " // &
        str(t_parts(1) / max(1, nt * blk%n), "es9.2") // " s, assembly " // str(t_parts(2) / max(1, nt * blk%n), "es9.2") // &
        " s, solve " // str(t_parts(3) / max(1, nt * blk%n), "es9.2") // " s")
      if (row%infeasible > 0) call log%warn(str(row%infeasible) // " reduced steps were infeasible (the reduced " // &
        "positions already overlap): least-violation coefficients used")
      if (row%capped > 0) call log%warn(str(row%capped) // " reduced solves stopped at their iteration cap " // &
        "(nnls_max_iter / uzawa_max_iter): those steps are not converged")
      if (row%extrapolating > 0) call log%warn(str(row%extrapolating) // " of " // str(blk%n) // " " // &
        trim(blk%name) // " parameters lie outside the training box: the reduced model extrapolates")
      ! output group
      out_set%setting = ks; out_set%n = pair%n; out_set%r = pair%r; out_set%nb = nb; out_set%pair = pair%index
      out_set%m = ops%m
      out_set%hyper = rcfg%hyper(kset); out_set%contacts = rcfg%contacts(kset); out_set%solver = rcfg%solver
      out_set%name = blk%name
      out_set%summary = trim(blk%name) == trim(blocks(size(blocks))%name)
      out_set%e_avg = row%e_avg; out_set%samples_diverged = row%diverged; out_set%t_step = row%t_step
      out_set%speedup_uzawa = speedup(t_uz, row%t_step); out_set%speedup_exact = speedup(t_ex, row%t_step)
      out_set%params = blk%mu
      call move_alloc(alpha, out_set%alpha); call move_alloc(beta, out_set%beta)
      call move_alloc(pos, out_set%positions); call move_alloc(err_time, out_set%err_time)
      call move_alloc(e_mu, out_set%e_mu); call move_alloc(e_proj, out_set%e_proj)
      call move_alloc(overlap, out_set%max_overlap); call move_alloc(mobility, out_set%mobility)
      call move_alloc(not_left, out_set%n_not_left); call move_alloc(not_left_fom, out_set%n_not_left_fom)
      call move_alloc(infeas, out_set%n_infeasible); call move_alloc(capped, out_set%n_capped)
      call move_alloc(extrap, out_set%extrapolating); call move_alloc(time, out_set%time)
      call move_alloc(div_step, out_set%diverged_step)
      out_set%e_disp = ms%e_disp; out_set%overlap_aa = ms%overlap_aa; out_set%overlap_aw = ms%overlap_aw
      allocate(out_set%evac_rom(nt + 1, blk%n), out_set%t_out_rom(size(EVAC_PCT), blk%n))
      do k = 1, blk%n
        out_set%evac_rom(:, k) = ms(k)%evac_rom
        out_set%t_out_rom(:, k) = ms(k)%t_rom
      end do
      if (blk%has_fom) then
        allocate(out_set%evac_fom(nt + 1, blk%n), out_set%t_out_fom(size(EVAC_PCT), blk%n))
        do k = 1, blk%n
          out_set%evac_fom(:, k) = ms(k)%evac_fom
          out_set%t_out_fom(:, k) = ms(k)%t_fom
        end do
      end if
      call out%write_set(out_set, error)
    end subroutine run_setting

    !> "t50: error e over n samples (ROM misses a, no FOM reference b)".
    function evac_text(m, j) result(s)
      type(row_measures_t), intent(in) :: m
      integer, intent(in) :: j
      character(len=:), allocatable :: s
      s = "t" // str(EVAC_PCT(j)) // " " // str(m%t_err(j), "es9.2") // " over " // str(m%t_n(j)) // &
        " samples (reduced never reaches it: " // str(m%t_rom_missed(j)) // ", full: " // str(m%t_fom_missed(j)) // ")"
    end function evac_text

    !> Mean time per full-order step over the first fom_timing_samples samples of blk.
    !> t_query: mean wall time of one whole query (parameter applied, model built with its scene
    !> and desired velocity, every step).
    subroutine fom_timing(st, blk, solver, t_step, kkt_max, n_nonconv, error, t_query)
      type(rom_study_t), intent(in) :: st
      type(sample_block_t), intent(in) :: blk
      character(len=*), intent(in) :: solver
      real(wp), intent(out) :: t_step, kkt_max
      integer, intent(out) :: n_nonconv
      type(error_t), allocatable, intent(out) :: error
      real(wp), intent(out), optional :: t_query
      real(wp) :: w0, t_q
      type(config_t) :: c2
      type(step_record_t) :: rec
      real(wp), allocatable :: speeds(:)
      integer :: k, nu, ns, nsteps
      t_step = 0; kkt_max = 0; n_nonconv = 0; t_q = 0
      if (present(t_query)) t_query = 0
      nsteps = st%n_steps
      if (solver == 'uzawa' .and. rcfg%fom_uzawa_steps > 0) nsteps = min(nsteps, rcfg%fom_uzawa_steps)
      ns = min(rcfg%fom_timing_samples, blk%n)
      call log%progress_start()
      do k = 1, ns
        c2 = st%cfg
        c2%solver%name = solver
        c2%solver%tol = rcfg%fom_tol
        if (solver == 'uzawa') then
          ! the paper's full-order model: cold start, its own stopping test
          c2%solver%uzawa_eps = rcfg%fom_uzawa_eps
          c2%solver%warm_start = .false.
          ! every pair and agent-obstacle pair a row, as in the paper (cutoff beyond the scene)
          if (rcfg%fom_uzawa_rows == 'all') c2%contacts%cutoff_factor = 1.0e9_wp
        end if
        speeds = st%speeds
        w0 = env%wtime()
        call st%space%apply(blk%mu(:, k), c2, speeds)
        fresh: block
          type(fom_t) :: fom
          call fom%init(c2, error, q0=st%q0, speeds=speeds)
          if (allocated(error)) return
          do nu = 1, nsteps
            call fom%advance(rec, error)
            if (allocated(error)) then
              call prefix_error(error, "full-order timing (" // solver // ")"); return
            end if
            t_step = t_step + rec%t_step
            kkt_max = max(kkt_max, rec%kkt)
            if (.not. rec%converged) n_nonconv = n_nonconv + 1
          end do
          t_q = t_q + (env%wtime() - w0)
        end block fresh
        call log%progress("full-order " // solver // " sample", k, ns)
      end do
      t_step = t_step / max(1, ns * nsteps)
      if (present(t_query)) t_query = t_q / max(1, ns)
    end subroutine fom_timing

    !> The one sample of sets = 'given'.
    subroutine given_block(st, blk, error)
      type(rom_study_t), intent(in) :: st
      type(sample_block_t), intent(out) :: blk
      type(error_t), allocatable, intent(out) :: error
      integer :: nmu
      nmu = count(rcfg%mu > -huge(1.0_wp))
      if (nmu /= st%space%n_expanded) then
        call set_error(error, where // ": mu has " // str(nmu) // " values but the study has " // &
          str(st%space%n_expanded) // " parameter components (" // shorten(st%param_names, 60) // ")", 2); return
      end if
      call st%space%check_values(rcfg%mu(1:nmu), st%cfg, where // ": mu", error)
      if (allocated(error)) return
      blk%name = 'given'
      blk%n = 1
      blk%mu = reshape(rcfg%mu(1:nmu), [nmu, 1])
      allocate(blk%q(st%n_dof, 0), blk%u(st%n_dof, 0))
      blk%has_fom = .false.
    end subroutine given_block

    function csv_line(r) result(s)
      type(romrun_row_t), intent(in) :: r
      character(len=:), allocatable :: s
      s = str(r%setting) // "," // trim(r%set) // "," // str(r%n) // "," // str(r%r) // "," // str(r%nb) // "," // &
        trim(r%hyper) // "," // trim(r%contacts) // "," // trim(r%solver) // "," // str(r%m(1)) // "," // &
        str(r%m(2)) // "," // str(r%m(3)) // "," // e(r%e_avg) // "," // e(r%e_max) // "," // e(r%e_proj) // &
        "," // e(r%overlap) // "," // str(r%not_left) // "," // str(r%not_left_fom) // "," // str(r%infeasible) // &
        "," // str(r%capped) // "," // e(r%t_step) // "," // e(t_uz) // "," // e(t_ex) // "," // &
        e(speedup(t_uz, r%t_step)) // "," // e(speedup(t_ex, r%t_step)) // "," // str(r%extrapolating) // "," // &
        e(r%mobility) // "," // str(r%diverged) // "," // e(r%meas%e_disp) // "," // e(r%meas%overlap_aa) // "," // &
        e(r%meas%overlap_aw) // "," // evac_csv(r%meas, 1) // "," // evac_csv(r%meas, 2) // "," // &
        e(r%t_query) // "," // e(t_qex) // "," // e(speedup(t_qex, r%t_query))
    end function csv_line

    function evac_csv(m, j) result(s)
      type(row_measures_t), intent(in) :: m
      integer, intent(in) :: j
      character(len=:), allocatable :: s
      s = e(m%t_err(j)) // "," // str(m%t_n(j)) // "," // str(m%t_rom_missed(j)) // "," // str(m%t_fom_missed(j))
    end function evac_csv

    subroutine write_csv(rows, error)
      type(romrun_row_t), intent(in) :: rows(:)
      type(error_t), allocatable, intent(out) :: error
      integer :: k
      character(len=:), allocatable :: text, msg
      ! written (and checked on disk) under a temporary name; run() renames it together with
      ! the run file
      text = "setting,set,n,r,n_basis,hyper,contacts,solver,m_v,m_b,m_d,E_avg,E_max,E_proj_avg," // &
        "max_overlap,agents_not_left,agents_not_left_fom,infeasible_steps,capped_steps,t_step_rom," // &
        "t_step_fom_uzawa,t_step_fom_exact,speedup_uzawa,speedup_exact,extrapolating,mobility,samples_diverged," // &
        "E_disp,max_overlap_agents,max_overlap_walls,t50_err,t50_n,t50_rom_missed,t50_fom_missed," // &
        "t90_err,t90_n,t90_rom_missed,t90_fom_missed,t_query_rom,t_query_fom_exact,speedup_query_exact" // &
        new_line('a')
      do k = 1, size(rows)
        text = text // csv_line(rows(k)) // new_line('a')
      end do
      call write_whole_file(trim(rcfg%table) // ".partial", text, msg)
      if (len(msg) > 0) call set_error(error, where // ": table: " // msg)
    end subroutine write_csv

    subroutine print_table(rows)
      type(romrun_row_t), intent(in) :: rows(:)
      integer :: k
      call log%info("")
      call log%info("| setting | set | N | R | Nb | hyper | contacts | m_v,m_b,m_d | E_avg | E_max | best approx. |" // &
        " E_disp | t50 err | t90 err | overlap agents / walls | not out (FOM) | mobility | infeas. | diverged |" // &
        " t_step ROM [s] | speedup vs uzawa | speedup vs " // trim(rcfg%fom_exact_solver) // &
        " | t_query ROM [s] | query speedup vs " // trim(rcfg%fom_exact_solver) // " |")
      call log%info("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
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
            str(speedup(t_uz, r%t_step), "f9.1") // " | " // str(speedup(t_ex, r%t_step), "f9.1") // " | " // &
            str(r%t_query, "es9.2") // " | " // str(speedup(t_qex, r%t_query), "f9.1") // " |")
        end associate
      end do
      if (any(rows%diverged > 0)) call log%info("* some samples of this row diverged (column diverged): its figures " // &
        "are over the other samples only")
      call log%info("t50/t90 err: mean |t_ROM - t_FOM| / t_FOM of the times at which 50% / 90% of the agents are out, " // &
        "over the (n) samples where both reach it; 'ROM never k': k samples where only the full model reaches it " // &
        "within the horizon")
      call log%info("t_query: one whole query as a user pays it, per sample: the per-parameter setup (scene, " // &
        "desired velocity) plus the whole trajectory; the " // trim(rcfg%fom_exact_solver) // " full model's " // &
        "whole query takes " // str(t_qex, "es9.2") // " s")
    end subroutine print_table

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

    subroutine write_summary(rows, error)
      type(romrun_row_t), intent(in) :: rows(:)
      type(error_t), allocatable, intent(out) :: error
      type(json_writer_t) :: js
      integer :: j, k
      call js%add("program", "crowd_rom")
      call js%add("output", trim(rcfg%output))
      call js%add("settings", size(setting_ids))
      call js%add("t_step_fom_uzawa", t_uz)
      call js%add("t_step_fom_exact", t_ex)
      call js%add("t_query_fom_exact", t_qex)
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
      call js%add("t_query_rom", rows%t_query)
      call js%add("t_query_fom_exact", [(t_qex, k = 1, size(rows))])
      call js%add("speedup_query_exact", [(speedup(t_qex, rows(k)%t_query), k = 1, size(rows))])
      call js%end_object()
      call js%write_file(cli%summary, error)
    end subroutine write_summary

  !> A fresh evaluation context (scene and desired velocity are rebuilt per sample).
  subroutine ctx_reset(ctx)
    type(eval_ctx_t), intent(inout) :: ctx
    type(eval_ctx_t) :: fresh
    ctx = fresh
  end subroutine ctx_reset

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
end program crowd_rom
