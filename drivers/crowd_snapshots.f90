!> crowd_snapshots: run a parameter study of the full-order model over MPI ranks and write one
!> resumable snapshot database.
!>
!>   mpirun -np P crowd_snapshots study.nml [--summary FILE] [--stop-after K]
!>
!> Every rank generates the same training / validation samples from &study. Samples already
!> stored as pieces (`<database>.pieces/`) by an earlier, interrupted run of the same
!> configuration are skipped; the others are handed out dynamically (shared counter, MPI
!> one-sided) and each completed sample is written to its own piece file. When every sample is
!> there, the database is assembled with parallel HDF5 under a temporary name, renamed, and the
!> pieces are removed. A database or pieces from a different configuration are refused.
program crowd_snapshots
  use, intrinsic :: iso_fortran_env, only: compiler_version
  use mpi_f08
  use hdf5, only: h5get_libversion_f
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_strings, only: str, shorten
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish, log_level_of
  use cr_config, only: config_t, read_config, config_echo
  use cr_inputs, only: check_input_groups
  use cr_config_check, only: check_config
  use cr_namelist_text, only: namelist_text_t
  use cr_fom, only: fom_t
  use cr_fsys, only: remove_dir, remove_file, file_exists, file_size
  use cr_json, only: json_writer_t
  use cr_study_config, only: study_cfg_t, read_study, check_study, study_echo, study_hash, check_study_paths
  use cr_sampling, only: param_space_t, sample_set_t, generate_samples
  use cr_scheduler, only: scheduler_t, collective_latency
  use cr_snapshot_piece, only: sample_result_t, compute_sample, piece_path
  use cr_piece_store, only: piece_index_t, piece_batch_t, scan_pieces
  use cr_snapshot_file, only: SNAP_SCHEMA_VERSION, db_meta_t
  use cr_snapshot_db, only: db_totals_t, probe_database, assemble_database, collective_error
  implicit none
  character(len=*), parameter :: CROWDROM_VERSION = "crowdrom 0.1.0"
  !> exit status of a run stopped by --stop-after
  integer, parameter :: EXIT_STOPPED = 3
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(config_t) :: cfg
  type(study_cfg_t) :: study
  type(namelist_text_t) :: nml
  type(error_t), allocatable :: error
  integer :: code
  ! state of the run shared by run, set_of and report
  type(sample_set_t) :: sets(2)
  type(db_totals_t) :: totals
  character(len=:), allocatable :: db
  character(len=16) :: hash
  integer :: n_tot, n_run, n_prev
  integer, allocatable :: nsamp(:)
  real(wp), allocatable :: busy(:)
  real(wp) :: sum_time, t_compute, t_asm, t_total
  !> inputs of the scaling model (summed over ranks): counter operations and their time, pieces
  !> written, their bytes and write time; collective latency; setup time and assembly start
  real(wp) :: counter(2), pieces_out(3), t_coll, t_setup, t_asm_start
  integer(i8) :: bytes

  call program_start("crowd_snapshots", env, log, cli, error, allow_stop_after=.true.)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error)) call read_config(cli%input, env, cfg, error, nml, &
    program='crowd_snapshots', needed=[character(len=8) :: 'scene', 'agents', 'study'])
  if (.not. allocated(error)) call check_input_groups(nml, error)
  if (.not. allocated(error)) call check_config(cfg, error)
  if (.not. allocated(error)) call read_study(nml, study, error)
  if (.not. allocated(error)) call check_study(study, cfg, error)
  if (.not. allocated(error)) call check_study_paths(cli%input, cli%summary, cfg, study, error)
  if (.not. allocated(error)) then
    log%level = log_level_of(cfg%output%log_level)
    call run(error)
  end if
  code = program_finish(env, log, error)
  ! a plain (quiet) stop: the error line was printed; no runtime backtrace on bad input
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: mpirun -np P crowd_snapshots study.nml [--summary FILE] [--stop-after K]"
    print '(a)', "         [--quarantine-bad-pieces] [--batch-seconds S]"
    print '(a)', ""
    print '(a)', "Parameter study of the full-order crowd model: samples the parameters of &study,"
    print '(a)', "spreads the runs over the MPI ranks (dynamic assignment) and writes one snapshot"
    print '(a)', "database (&study database; schema in README.md)."
    print '(a)', "A killed run resumes where it stopped when the same command is run again."
    print '(a)', ""
    print '(a)', "  --summary FILE   also write the run summary as JSON"
    print '(a)', "  --stop-after K   testing hook: compute at most K samples, then exit with status 3"
    print '(a)', "                   without assembling the database (a rerun resumes)"
    print '(a)', "  --quarantine-bad-pieces  move pieces that fail their checks (checksum, identity,"
    print '(a)', "                   finiteness) to <database>.pieces/quarantine/ and recompute them;"
    print '(a)', "                   without it a bad piece stops the run (status 2) naming it"
    print '(a)', "  --batch-seconds S  time slice of one piece file (default 2 s; 0: one sample per piece)"
    print '(a)', "  -h, --help       this text"
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 3 stopped by --stop-after, 1 other failure."
  end subroutine print_help

  subroutine run(error)
    type(error_t), allocatable, intent(out) :: error
    type(fom_t) :: fom_ref
    type(param_space_t) :: space
    type(db_meta_t) :: meta
    type(scheduler_t) :: sched
    type(sample_result_t) :: res
    type(piece_index_t) :: pieces
    type(piece_batch_t) :: batch
    real(wp), allocatable :: q0(:)
    integer, allocatable :: done(:), todo(:)
    character(len=:), allocatable :: dir, msg
    integer :: status, g, k, is, t, n_mine, ndone, ierr, maj, mnr, rel, vlen
    real(wp) :: t0, t_start, t_loop, t_sample, busy_mine
    character(len=MPI_MAX_LIBRARY_VERSION_STRING) :: mpiv

    t_start = env%wtime()
    db = trim(study%database)
    dir = db // ".pieces"
    call log%stage_begin("crowd_snapshots: setup")
    call log%info(config_echo(cfg) // study_echo(study))
    ! the reference model: scene and the common initial positions (placed once, on rank 0)
    call fom_ref%init(cfg, error)
    if (allocated(error)) return
    q0 = fom_ref%q
    call MPI_Bcast(q0, size(q0), MPI_DOUBLE_PRECISION, 0, env%comm, ierr)
    call space%init(study, fom_ref%n_agents)
    call generate_samples(study, space, sets(1), sets(2), error)
    if (allocated(error)) return
    n_tot = sets(1)%n + sets(2)%n
    hash = study_hash(cfg, study, SNAP_SCHEMA_VERSION)
    call log%info("   " // str(fom_ref%n_agents) // " agents, " // str(cfg%time%n_steps) // " steps per sample, " // &
      str(space%n_expanded) // " parameter components (" // shorten(space%component_names(), 60) // "), " // &
      str(sets(1)%n) // " training + " // str(sets(2)%n) // " validation samples on " // str(env%size) // &
      " ranks; config_hash " // hash)

    ! an existing database: done already, or refused
    status = 0; msg = ""
    if (env%is_root()) call probe_database(db, hash, status, msg)
    call MPI_Bcast(status, 1, MPI_INTEGER, 0, env%comm, ierr)
    call env%bcast_string(msg)
    if (status == 2) then
      call set_error(error, msg, 2); return
    end if
    if (status == 1) then
      call log%info("database '" // db // "' is already complete for this configuration: nothing to do")
      call log%stage_end()
      return
    end if

    ! pieces of earlier runs, verified (bad ones stop the run, or are moved aside on request)
    call scan_pieces(env, dir, hash, sets, 2 * fom_ref%n_agents, cfg%time%n_steps, cli%quarantine, pieces, &
      msg, error)
    if (allocated(error)) return
    if (len(msg) > 0) call log%warn(msg // "the samples of the " // str(pieces%n_quarantined) // &
      " bad piece(s) are recomputed")
    allocate(done(n_tot))
    done = merge(1, 0, pieces%piece_of > 0)
    n_prev = count(done == 1)
    todo = pack([(g, g = 1, n_tot)], done == 0)
    n_run = size(todo)
    if (cli%stop_after >= 0) n_run = min(n_run, cli%stop_after)
    if (n_prev > 0) call log%info("   resuming: " // str(n_prev) // " of " // str(n_tot) // &
      " samples already complete in '" // dir // "'")
    call log%stage_end()

    ! the samples, dynamically assigned
    call log%stage_begin("crowd_snapshots: " // str(n_run) // " full-order runs on " // str(env%size) // " ranks")
    call sched%init(env, n_run, error)
    if (allocated(error)) return
    call log%progress_start()
    t_loop = env%wtime()
    call batch%init(dir, hash, merge(cli%batch_seconds, 2.0_wp, cli%batch_seconds >= 0))
    msg = ""
    n_mine = 0; busy_mine = 0; sum_time = 0
    do
      t = sched%next()
      if (t == 0) exit
      g = todo(t)
      call set_of(g, is, k)
      t0 = env%wtime()
      res%set = sets(is)%name
      res%index = k
      res%rank = env%rank
      res%start = t0 - t_start
      call compute_sample(cfg, space, sets(is)%mu(:, k), q0, fom_ref%speeds, res, error)
      if (.not. allocated(error)) then
        res%time = env%wtime() - t0
        call batch%add(res, g, sets, env%wtime() - t_start, error)
      end if
      if (allocated(error)) then
        msg = trim(sets(is)%name) // " sample " // str(k) // " (mu = " // shorten(mu_text(sets(is)%mu(:, k)), 60) // &
          ") on rank " // str(env%rank) // ": " // error%message
        deallocate(error)
        exit
      end if
      t_sample = env%wtime() - t0
      busy_mine = busy_mine + t_sample
      sum_time = sum_time + t_sample
      n_mine = n_mine + 1
      ndone = sched%mark_done()
      if (env%is_root()) call log%progress("samples", n_prev + ndone, n_tot)
    end do
    if (len(msg) == 0) then
      t0 = env%wtime()
      call batch%flush(sets, error)
      busy_mine = busy_mine + (env%wtime() - t0)
      sum_time = sum_time + (env%wtime() - t0)
      if (allocated(error)) then
        msg = "rank " // str(env%rank) // ": " // error%message; deallocate(error)
      end if
    end if
    call collective_error(env, msg, error)
    counter = [real(sched%n_calls, wp), sched%t_calls]
    pieces_out = [real(batch%n_pieces, wp), real(batch%bytes_written, wp), batch%t_write]
    call sched%free()
    if (allocated(error)) return
    call env%barrier()
    t_compute = env%wtime() - t_loop
    allocate(busy(env%size), nsamp(env%size))
    call MPI_Allgather(busy_mine, 1, MPI_DOUBLE_PRECISION, busy, 1, MPI_DOUBLE_PRECISION, env%comm, ierr)
    call MPI_Allgather(n_mine, 1, MPI_INTEGER, nsamp, 1, MPI_INTEGER, env%comm, ierr)
    sum_time = env%sum_real(sum_time)
    call env%sum_real_array(counter)
    call env%sum_real_array(pieces_out)
    t_coll = collective_latency(env, 20)
    t_setup = t_loop - t_start
    call log%info("   samples " // str(n_prev + n_run) // " of " // str(n_tot) // " complete")
    call log%stage_end()
    if (n_run < size(todo)) then
      call set_error(error, "stopped after " // str(n_run) // " samples as requested by --stop-after (" // &
        str(n_prev + n_run) // " of " // str(n_tot) // " complete, database not assembled): run again " // &
        "without --stop-after to finish", EXIT_STOPPED)
      return
    end if

    ! the database
    call log%stage_begin("crowd_snapshots: assembling '" // db // "'")
    t0 = env%wtime()
    t_asm_start = t0 - t_start
    meta%config_text = config_echo(cfg) // study_echo(study)
    meta%input_text = cfg%text
    meta%hash = hash
    meta%param_names = space%component_names()
    meta%version = CROWDROM_VERSION
    call h5get_libversion_f(maj, mnr, rel, ierr)
    meta%hdf5_version = str(maj) // "." // str(mnr) // "." // str(rel)
    call MPI_Get_library_version(mpiv, vlen, ierr)
    meta%mpi_version = trim(mpiv(1:min(vlen, len(mpiv))))
    if (index(meta%mpi_version, new_line('a')) > 0) &
      meta%mpi_version = meta%mpi_version(1:index(meta%mpi_version, new_line('a')) - 1)
    meta%compiler = compiler_version()
    meta%n_agents = fom_ref%n_agents
    meta%n_steps = cfg%time%n_steps
    meta%n_expanded = space%n_expanded
    meta%radius = fom_ref%radius
    meta%dt = fom_ref%dt
    call pieces%add_written(env, dir, sets, batch%written)
    call assemble_database(env, db, pieces, meta, fom_ref, cfg, space, q0, sets, totals, error)
    if (allocated(error)) return
    ! the database is committed: the pieces can go
    if (env%is_root()) then
      do g = 1, pieces%n_pieces
        status = remove_file(pieces%path_of(g))
      end do
      ! temporaries of pieces a killed run did not finish (named after any sample)
      do g = 1, n_tot
        call set_of(g, is, k)
        status = remove_file(piece_path(dir, sets(is)%name, k) // ".partial")
      end do
      if (file_exists(dir // "/quarantine/.")) then
        call log%info("   bad pieces kept in '" // dir // "/quarantine' (inspect, then remove them)")
      else if (remove_dir(dir) /= 0) then
        call log%warn("could not remove '" // dir // "' (foreign files in it?)")
      end if
    end if
    t_asm = env%wtime() - t0
    call log%stage_end()
    t_total = env%wtime() - t_start
    bytes = file_size(db)
    call report()
  end subroutine run

    !> Global sample number g -> set (1 train, 2 valid) and index in the set.
    subroutine set_of(g, is, k)
      integer, intent(in) :: g
      integer, intent(out) :: is, k
      if (g <= sets(1)%n) then
        is = 1; k = g
      else
        is = 2; k = g - sets(1)%n
      end if
    end subroutine set_of

    subroutine report()
      type(json_writer_t) :: js
      character(len=:), allocatable :: text
      real(wp) :: eff_compute, eff_total, balance, mean_busy
      integer :: r
      type(error_t), allocatable :: e2
      eff_compute = 0; eff_total = 0; balance = 1
      if (t_compute > 0) eff_compute = sum_time / (env%size * t_compute)
      if (t_total > 0) eff_total = sum_time / (env%size * t_total)
      mean_busy = sum(busy) / env%size
      if (maxval(busy) > 0) balance = mean_busy / maxval(busy)
      text = "summary:" // new_line('a') // &
        "  database            " // db // " (" // str(real(bytes, wp) / 1.0e6_wp, 'f0.2') // " MB)" // new_line('a') // &
        "  samples             " // str(n_tot) // " (" // str(sets(1)%n) // " train + " // str(sets(2)%n) // &
        " valid), computed now " // str(n_run) // ", resumed " // str(n_prev) // new_line('a') // &
        "  time per sample     mean " // str(sum_time / max(n_run, 1), 'f0.3') // " s (with its piece file), " // &
        "max of the model runs in the database " // str(totals%time_max, 'f0.3') // " s" // new_line('a') // &
        "  ranks               " // str(env%size) // new_line('a')
      do r = 1, env%size
        text = text // "    rank " // str(r - 1) // ": " // str(nsamp(r)) // " samples, busy " // &
          str(busy(r), 'f0.2') // " s" // new_line('a')
      end do
      text = text // &
        "  load balance        " // str(balance, 'f0.3') // " (mean / max busy time)" // new_line('a') // &
        "  busy-time efficiency " // str(eff_compute, 'f0.3') // " (sample loop), " // str(eff_total, 'f0.3') // &
        " (whole run: sum of busy times / (P x wall))" // new_line('a') // &
        "  overheads           counter " // str(1.0e6_wp * counter(2) / max(counter(1), 1.0_wp), 'f0.1') // &
        " us per operation, " // str(nint(pieces_out(1))) // " pieces (" // &
        str(pieces_out(2) / 1.0e6_wp, 'f0.2') // " MB, " // str(pieces_out(3), 'f0.3') // " s), collective " // &
        str(1.0e6_wp * t_coll, 'f0.1') // " us" // new_line('a') // &
        "  wall time           " // str(t_total, 'f0.2') // " s (samples " // str(t_compute, 'f0.2') // &
        " s, assembly " // str(t_asm, 'f0.2') // " s: read " // str(totals%t_read, 'f0.2') // ", dictionary " // &
        str(totals%t_dict, 'f0.2') // ", write " // str(totals%t_write, 'f0.2') // ", header " // &
        str(totals%t_seal, 'f0.2') // ")" // new_line('a') // &
        "  non-converged steps " // str(totals%nonconverged_steps) // " in " // str(totals%nonconverged_samples) // &
        " samples (largest KKT residual " // str(totals%kkt_max) // ")" // new_line('a') // &
        "  contact dictionary  " // str(totals%n_dict) // " contacts, " // str(totals%nnz) // " stored multipliers"
      call log%info(text)
      if (len(cli%summary) == 0 .or. .not. env%is_root()) return
      call js%add("program", "crowd_snapshots")
      call js%add("input", cfg%source)
      call js%add("database", db)
      call js%add("database_bytes", bytes)
      call js%add("config_hash", trim(hash))
      call js%add("ranks", env%size)
      call js%add("samples_total", n_tot)
      call js%add("samples_train", sets(1)%n)
      call js%add("samples_valid", sets(2)%n)
      call js%add("samples_computed", n_run)
      call js%add("samples_resumed", n_prev)
      call js%add("time_per_sample_mean", sum_time / max(n_run, 1))
      call js%add("time_per_sample_max", totals%time_max)
      call js%add("samples_per_rank", nsamp)
      call js%add("busy_time_per_rank", busy)
      call js%add("load_balance", balance)
      call js%add("parallel_efficiency", eff_total)
      call js%add("parallel_efficiency_sample_loop", eff_compute)
      call js%add("wall_time", t_total)
      call js%add("wall_time_samples", t_compute)
      call js%add("wall_time_assembly", t_asm)
      call js%add("busy_time_efficiency", eff_total)
      call js%add("busy_time_efficiency_sample_loop", eff_compute)
      call js%add("wall_time_setup", t_setup)
      call js%add("assembly_start", t_asm_start)
      call js%add("counter_operations", nint(counter(1)))
      call js%add("counter_latency_mean", counter(2) / max(counter(1), 1.0_wp))
      call js%add("collective_latency", t_coll)
      call js%add("pieces_written", nint(pieces_out(1)))
      call js%add("piece_bytes_written", pieces_out(2))
      call js%add("piece_write_time", pieces_out(3))
      call js%add("assembly_read_time", totals%t_read)
      call js%add("assembly_read_bytes", totals%bytes_read)
      call js%add("assembly_dictionary_time", totals%t_dict)
      call js%add("assembly_write_time", totals%t_write)
      call js%add("assembly_header_time", totals%t_seal)
      call js%add("batch_seconds", merge(cli%batch_seconds, 2.0_wp, cli%batch_seconds >= 0))
      call js%add("nonconverged_steps", totals%nonconverged_steps)
      call js%add("nonconverged_samples", totals%nonconverged_samples)
      call js%add("largest_kkt_residual", totals%kkt_max)
      call js%add("contacts_in_dictionary", totals%n_dict)
      call js%add("stored_multipliers", totals%nnz)
      call js%write_file(cli%summary, e2)
      if (allocated(e2)) call log%warn(e2%message)
    end subroutine report

  !> "a, b, c" of a parameter vector.
  function mu_text(mu) result(s)
    real(wp), intent(in) :: mu(:)
    character(len=:), allocatable :: s
    integer :: k
    s = ""
    do k = 1, size(mu)
      s = s // str(mu(k)) // merge(", ", "  ", k < size(mu))
    end do
    s = trim(s)
  end function mu_text

end program crowd_snapshots
