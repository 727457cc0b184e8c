!> One run of the snapshot stage of a parameter study (what `crowd_snapshots` does): the
!> samples, the resume from the pieces of earlier runs (verified; bad ones stop the run or are
!> moved to quarantine), the dynamic schedule with batched pieces, and the database: each
!> sample goes into it (cr_snapshot_file's writer, `put`) from the rank that computed or
!> verified it, as soon as that rank has it; the writer's `finish` adds the multipliers, the
!> checksums and `complete = 1`. Collective over env.
!>
!> `execute` leaves the figures of the run in the type (every rank); `summary_text` and
!> `write_summary` report them (rank 0).
module cr_study_run
  use, intrinsic :: iso_fortran_env, only: compiler_version
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_strings, only: str, shorten
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_config, only: config_t, config_echo
  use cr_fom, only: fom_t
  use cr_h5file, only: h5_library_version
  use cr_scene, only: scene_t
  use cr_qoi, only: qoi_t, compute_qoi, qoi_pack_size, pack_qoi, unpack_qoi
  use cr_fsys, only: remove_dir, remove_file, file_exists, file_size
  use cr_json, only: json_writer_t
  use cr_study_config, only: study_cfg_t, study_echo, study_hash
  use cr_sampling, only: param_space_t, sample_set_t, generate_samples
  use cr_scheduler, only: scheduler_t
  use cr_snapshot_piece, only: sample_result_t, compute_sample, piece_path
  use cr_piece_store, only: piece_index_t, piece_batch_t, scan_pieces, set_of_sample
  use cr_snapshot_file, only: SNAP_SCHEMA_VERSION, db_meta_t, snap_write_stats_t, snap_writer_t, &
    probe_snap_database, scene_vertex_list
    use cr_exit_codes, only: EXIT_FAILURE, EXIT_BAD_INPUT
  implicit none
  private
  public :: run_options_t, study_run_t, EXIT_STOPPED

  !> exit status of a run stopped by --stop-after
  integer, parameter :: EXIT_STOPPED = 3
  !> phase boundaries recorded by every rank (the summary's `phase_marks`, a timeline per rank)
  integer, parameter :: N_MARKS = 18
  character(len=*), parameter :: MARK_NAMES = "setup_local,counter_created,probe_shared,pieces_scanned," // &
    "database_begun,loop_start,last_ticket,last_piece_written,places_settled,counter_freed,end_reduced," // &
    "dictionary_shared,blocks_written,reported,database_finished,pieces_removed,directory_removed,end"
  !> the marks where the ranks first meet (the counter's creation), where a rank's sample loop
  !> starts and where it ends (its last sample done and the samples it held written; the wait
  !> for the other ranks' last samples comes after, at the counter's release)
  integer, parameter :: MARK_MEET = 2, MARK_LOOP0 = 6, MARK_LOOP_END = 9
  character(len=*), parameter :: CROWDROM_VERSION = "crowdrom 0.1.0"

  !> Options of a run (command line).
  type :: run_options_t
    !> compute at most this many samples, then stop without the database (< 0: no limit)
    integer :: stop_after = -1
    !> move bad pieces aside and recompute them instead of stopping
    logical :: quarantine = .false.
    !> time slice of one piece (s); 0: one sample per piece
    real(wp) :: batch_seconds = 2
  end type run_options_t

  !> A run of the snapshot stage and its figures (every rank holds them after execute).
  type :: study_run_t
    character(len=:), allocatable :: db
    character(len=16) :: hash = ''
    !> the database was already complete: nothing was done
    logical :: no_op = .false.
    integer :: n_tot = 0, n_train = 0, n_valid = 0, n_run = 0, n_prev = 0
    !> samples computed and busy time (samples and their pieces, s) of each rank [P]
    integer, allocatable :: nsamp(:)
    real(wp), allocatable :: busy(:)
    !> sum of the busy times (and of those in the sample loop); wall times: total (the longest
    !> rank's), setup, sample loop, assembly; assembly start
    real(wp) :: sum_time = 0, sum_loop = 0, t_total = 0, t_setup = 0, t_compute = 0, t_asm = 0, t_asm_start = 0
    !> rank 0's time putting the samples of earlier runs' pieces into the database (setup, s)
    real(wp) :: t_put_resumed = 0
    !> rank 0's HDF5 layout of the database in begin (its serial work in the setup, s)
    real(wp) :: t_layout = 0
    !> the database writer's figures (its put time is this rank's; part of the busy time)
    type(snap_write_stats_t) :: wstats
    !> sum over ranks of the time spent putting computed samples into the database (s)
    real(wp) :: t_put_all = 0
    !> inputs of the scaling model: counter operations and their time (summed over ranks),
    !> pieces written, their bytes and write time (summed), collective latency (s)
    real(wp) :: counter(2) = 0, pieces_out(3) = 0, t_coll = 0
    real(wp) :: batch_seconds = 2
    !> when each rank passed each phase boundary (s since its start of the run) [N_MARKS, P]
    real(wp), allocatable :: marks(:, :)
    !> each rank's time on its samples' multiplier blocks in the end of the database (and on
    !> samples it held while the places were in transit), part of its busy time [P]
    real(wp), allocatable :: end_blocks(:)
    !> each rank's serial work on the database that no other rank does (rank 0: the HDF5 layout,
    !> the multiplier datasets, dictionary, checksums, close and rename), part of its busy time
    !> (work, not waiting: the other ranks meanwhile compute samples or wait, and their waiting
    !> is not busy) [P]
    real(wp), allocatable :: serial(:)
    !> sum of the busy times without the serial database work (the definition before it was
    !> counted: samples, pieces, blocks)
    real(wp) :: sum_time_no_serial = 0
    !> totals over the database
    integer :: nonconverged_steps = 0, nonconverged_samples = 0
    real(wp) :: kkt_max = 0, time_max = 0
    integer(i8) :: bytes = 0
  contains
    procedure :: execute
    procedure :: summary_text
    procedure :: write_summary
  end type study_run_t

  !> The state one run of the stage carries from step to step of `execute`.
  type :: run_state_t
    !> the reference model (scene, common initial positions, speeds), the parameter space and
    !> the training and validation samples
    type(fom_t) :: fom_ref
    type(param_space_t) :: space
    type(sample_set_t) :: sets(2)
    type(scheduler_t) :: sched
    !> the pieces of earlier runs, this rank's batch of pieces, the samples it verified
    type(piece_index_t) :: pieces
    type(piece_batch_t) :: batch
    type(sample_result_t), allocatable :: held(:)
    type(db_meta_t) :: meta
    type(snap_writer_t) :: writer
    !> the counter's failure on this rank (passed to the writer's begin as prior failure)
    type(error_t), allocatable :: e_counter
    !> initial positions; the figures reduced over the ranks
    real(wp), allocatable :: q0(:), redu(:)
    !> every sample's quantities of interest (pack_qoi; this rank's columns, summed on rank 0)
    real(wp), allocatable :: qbuf(:,:)
    type(qoi_t), allocatable :: qois(:)
    !> the samples still to run (global sample numbers)
    integer, allocatable :: todo(:)
    character(len=:), allocatable :: dir
    !> totals of this rank's samples (non-converged steps and samples; largest KKT residual and
    !> sample time), the scene's vertex count, this rank's samples
    integer :: ci(2) = 0, nv = 0, n_mine = 0
    real(wp) :: cr(2) = 0
    !> clocks: start of the run, of the loop, of the database's end; this rank's busy time, the
    !> held samples' time at the end of the loop; the phase marks
    real(wp) :: t_start = 0, t_loop = 0, t_asm0 = 0, busy_mine = 0, t_held0 = 0
    real(wp) :: mk(N_MARKS) = 0
  end type run_state_t

contains

  !> Collective: run the stage for configuration cfg and study (see the module header): the
  !> setup (reference model, samples, the database probe), the resume and the database's
  !> layout, the sample loop, then either the stop of --stop-after or the database's end, the
  !> removal of the pieces and the run's figures.
  subroutine execute(this, env, log, cfg, study, opts, error)
    class(study_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(config_t), intent(in) :: cfg
    type(study_cfg_t), intent(in) :: study
    type(run_options_t), intent(in) :: opts
    type(error_t), allocatable, intent(out) :: error
    type(run_state_t) :: st
    logical :: finished
    call setup_run(this, st, env, log, cfg, study, opts, finished, error)
    if (finished .or. allocated(error)) return
    call resume_and_begin(this, st, env, log, cfg, study, opts, error)
    if (allocated(error)) return
    call sample_loop(this, st, env, log, cfg, error)
    call pack_loop_figures(this, st, env)
    if (this%n_run < size(st%todo)) then
      call stop_run(this, st, env, log, error)
      return
    end if
    call finish_database(this, st, env, log, cfg, error)
    if (allocated(error)) return
    call remove_pieces(this, st, env)
    call end_figures(this, st, env, log, error)
  end subroutine execute

  !> The setup: the reference model (scene and the common initial positions, rank 0's
  !> broadcast), the samples, the ticket counter and rank 0's probe of an existing database.
  !> finished: the run ends here (database already complete, or refused: error).
  subroutine setup_run(this, st, env, log, cfg, study, opts, finished, error)
    class(study_run_t), intent(inout) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(config_t), intent(in) :: cfg
    type(study_cfg_t), intent(in) :: study
    type(run_options_t), intent(in) :: opts
    logical, intent(out) :: finished
    type(error_t), allocatable, intent(out) :: error
    integer :: status
    character(len=:), allocatable :: msg
    finished = .false.
    st%t_start = env%wtime()
    this%db = trim(study%database)
    st%dir = this%db // ".pieces"
    this%batch_seconds = opts%batch_seconds
    call log%stage_begin("crowd_snapshots: setup")
    if (env%is_root()) call log%info(config_echo(cfg) // study_echo(study))
    ! the reference model: scene and the common initial positions (rank 0's are broadcast)
    st%mk = 0
    call st%fom_ref%init(cfg, error)
    if (allocated(error)) return
    call st%space%init(study, st%fom_ref%n_agents)
    call generate_samples(study, st%space, st%sets(1), st%sets(2), error)
    if (allocated(error)) return
    this%n_train = st%sets(1)%n; this%n_valid = st%sets(2)%n
    this%n_tot = st%sets(1)%n + st%sets(2)%n
    this%hash = study_hash(cfg, study, SNAP_SCHEMA_VERSION)
    call log%info("   " // str(st%fom_ref%n_agents) // " agents, " // str(cfg%time%n_steps) // &
      " steps per sample, " // str(st%space%n_expanded) // " parameter components (" // &
      shorten(st%space%component_names(), 60) // "), " // str(st%sets(1)%n) // " training + " // &
      str(st%sets(2)%n) // " validation samples on " // str(env%size) // " ranks; config_hash " // this%hash)

    st%mk(1) = env%wtime() - st%t_start

    ! the ticket counter first: its creation is where the ranks first meet (a rank still in the
    ! driver's input checks is waited for here); rank 0 zeroes it before the broadcast below,
    ! which is then the barrier before any rank's first ticket (the number of tickets is set
    ! once the pieces are known)
    call st%sched%init(env, 0, st%e_counter, barrier=.false.)
    st%mk(2) = env%wtime() - st%t_start
    ! an existing database: done already, or refused; rank 0's answer (or its failure to zero
    ! the counter) and initial positions in one broadcast
    status = 0; msg = ""
    if (env%is_root()) then
      if (allocated(st%e_counter)) then
        status = 3; msg = st%e_counter%message
      else
        call probe_snap_database(this%db, this%hash, status, msg)
      end if
    end if
    st%q0 = [real(status, wp), st%fom_ref%q]
    call env%bcast(st%q0, error)
    if (allocated(error)) then
      call st%sched%free(); return
    end if
    status = nint(st%q0(1))
    st%q0 = st%q0(2:)
    st%mk(3) = env%wtime() - st%t_start
    if (status >= 2) then
      call env%bcast(msg, error)
      if (.not. allocated(error)) call set_error(error, msg, merge(EXIT_BAD_INPUT, EXIT_FAILURE, status == 2))
      call st%sched%free()
      return
    end if
    if (status == 1) then
      this%no_op = .true.
      finished = .true.
      call st%sched%free()
      call log%info("database '" // this%db // "' is already complete for this configuration: nothing to do")
      call log%stage_end()
    end if
  end subroutine setup_run

  !> The pieces of earlier runs, verified (bad ones stop the run, or are moved aside on
  !> request), the samples still to run, and the database laid out (temporary name until
  !> finished) with the samples of the earlier pieces put into it by the ranks that verified them.
  subroutine resume_and_begin(this, st, env, log, cfg, study, opts, error)
    class(study_run_t), intent(inout) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(config_t), intent(in) :: cfg
    type(study_cfg_t), intent(in) :: study
    type(run_options_t), intent(in) :: opts
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: msg
    integer, allocatable :: done(:)
    integer :: g, j
    call scan_pieces(env, st%dir, this%hash, st%sets, 2 * st%fom_ref%n_agents, cfg%time%n_steps, opts%quarantine, &
      st%pieces, st%held, msg, error)
    if (allocated(error)) then
      call st%sched%free(); return
    end if
    st%mk(4) = env%wtime() - st%t_start
    if (len(msg) > 0) call log%warn(msg // "the samples of the " // str(st%pieces%n_quarantined) // &
      " bad piece(s) are recomputed")
    allocate(done(this%n_tot))
    done = merge(1, 0, st%pieces%piece_of > 0)
    this%n_prev = count(done == 1)
    st%todo = pack([(g, g = 1, this%n_tot)], done == 0)
    this%n_run = size(st%todo)
    if (opts%stop_after >= 0) this%n_run = min(this%n_run, opts%stop_after)
    if (this%n_prev > 0) call log%info("   resuming: " // str(this%n_prev) // " of " // str(this%n_tot) // &
      " samples already complete in '" // st%dir // "'")
    ! the database (temporary name until finished), with the samples of the earlier pieces
    call fill_meta(this, st, env, cfg, study)
    st%nv = size(scene_vertex_list(st%fom_ref%scene))
    allocate(st%qbuf(qoi_pack_size(cfg%time%n_steps, st%fom_ref%scene%n_exits()), this%n_tot))
    st%qbuf = 0
    st%ci = 0; st%cr = 0
    st%sched%n_tasks = this%n_run
    ! the database: rank 0 lays it out while the other ranks start on their samples (the places
    ! follow by a nonblocking broadcast; a failure of the layout, or of the counter on a rank
    ! other than 0, makes that rank's puts fail, and every rank learns it in finish)
    if (env%is_root() .and. allocated(st%e_counter)) deallocate(st%e_counter)
    call st%writer%begin(env, this%db, st%meta, st%q0, st%fom_ref%scene, error, prior=st%e_counter)
    if (allocated(error)) then
      call st%sched%free(); return
    end if
    this%t_layout = st%writer%stats%t_serial
    msg = ""
    ! (the samples of earlier pieces: every rank waits for the places first)
    if (size(st%held) > 0) call st%writer%wait_places(error)
    do j = 1, size(st%held)
      if (allocated(error)) exit
      call put(st, cfg, st%held(j), error)
    end do
    deallocate(st%held)
    if (allocated(error)) then
      msg = error%message; deallocate(error)
    end if
    this%t_put_resumed = st%writer%stats%t_put
    if (len(msg) > 0) call set_error(error, msg)
    ! (every rank knows whether there were earlier pieces)
    if (st%pieces%n_pieces > 0) call env%agree_error(error)
    if (allocated(error)) then
      call st%sched%free(); call st%writer%discard(); return
    end if
    st%mk(5) = env%wtime() - st%t_start
    call log%stage_end()
  end subroutine resume_and_begin

  !> The samples, dynamically assigned: each computed, added to this rank's piece batch and put
  !> into the database; a failure ends this rank's loop (error, with the sample named).
  subroutine sample_loop(this, st, env, log, cfg, error)
    class(study_run_t), intent(inout) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(config_t), intent(in) :: cfg
    type(error_t), allocatable, intent(out) :: error
    type(sample_result_t) :: res
    character(len=:), allocatable :: msg
    integer :: g, k, is, t
    real(wp) :: t0, t_sample
    call log%stage_begin("crowd_snapshots: " // str(this%n_run) // " full-order runs on " // str(env%size) // " ranks")
    call log%progress_start()
    st%t_loop = env%wtime()
    st%mk(6) = st%t_loop - st%t_start
    call st%batch%init(env, st%dir, this%hash, this%batch_seconds)
    msg = ""
    st%n_mine = 0; st%busy_mine = 0; this%sum_time = 0
    do
      ! (places arrived: samples held meanwhile written; rank 0's failed layout stops the loop)
      call st%writer%poll(error)
      if (allocated(error)) then
        msg = error%message; deallocate(error); exit
      end if
      t = st%sched%next(error)
      if (allocated(error)) then
        msg = "rank " // str(env%rank) // ": " // error%message; deallocate(error); exit
      end if
      if (t == 0) then
        st%mk(7) = env%wtime() - st%t_start
        exit
      end if
      g = st%todo(t)
      call set_of_sample(st%sets, g, is, k)
      t0 = env%wtime()
      res%set = st%sets(is)%name
      res%index = k
      res%rank = env%rank
      res%start = t0 - st%t_start
      call compute_sample(cfg, st%space, st%sets(is)%mu(:, k), st%q0, st%fom_ref%speeds, res, error)
      if (.not. allocated(error)) then
        res%time = env%wtime() - t0
        call st%batch%add(res, g, st%sets, env%wtime() - st%t_start, error)
      end if
      if (.not. allocated(error)) call put(st, cfg, res, error)
      if (allocated(error)) then
        msg = trim(st%sets(is)%name) // " sample " // str(k) // " (mu = " // &
          shorten(mu_text(st%sets(is)%mu(:, k)), 60) // ") on rank " // str(env%rank) // ": " // error%message
        deallocate(error)
        exit
      end if
      t_sample = env%wtime() - t0
      st%busy_mine = st%busy_mine + t_sample
      st%n_mine = st%n_mine + 1
      ! (ticket t: t - 1 samples were handed out before this one)
      if (env%is_root()) call log%progress("samples started", this%n_prev + t, this%n_tot)
    end do
    ! the samples of the last, unfinished time slice go into a piece only when the run stops
    ! before the database is finished (--stop-after); otherwise they are in the database a few
    ! moments later, and a run killed in between loses at most that one slice of work per
    ! rank, as it could in any slice (a piece written only to be deleted is not written)
    if (len(msg) == 0 .and. this%n_run < size(st%todo)) then
      t0 = env%wtime()
      call st%batch%flush(st%sets, error)
      st%busy_mine = st%busy_mine + (env%wtime() - t0)
      if (allocated(error)) then
        msg = "rank " // str(env%rank) // ": " // error%message; deallocate(error)
      end if
    end if
    st%mk(8) = env%wtime() - st%t_start
    if (len(msg) > 0) call set_error(error, msg)
  end subroutine sample_loop

  !> Every rank's figures at the end of the loop (per-rank slots [P] for busy time, samples,
  !> largest KKT residual and sample time; then sums) into st%redu, summed over the ranks in
  !> the end reduction of the database (finish), or, when the run stops before the database,
  !> in one reduction of their own with every rank's failure flag.
  subroutine pack_loop_figures(this, st, env)
    class(study_run_t), intent(inout) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    integer :: p
    this%counter = [real(st%sched%n_calls(), wp), st%sched%t_calls()]
    this%pieces_out = [real(st%batch%n_pieces, wp), real(st%batch%bytes_written, wp), st%batch%t_write]
    ! samples held while the places were in transit and written by poll: busy, in the loop
    st%busy_mine = st%busy_mine + st%writer%stats%t_held
    st%t_held0 = st%writer%stats%t_held
    p = env%size
    allocate(st%redu(4 * p + 8))
    st%redu = 0
    st%redu(env%rank + 1) = st%busy_mine
    st%redu(p + env%rank + 1) = st%n_mine
    st%redu(2 * p + env%rank + 1) = st%cr(1)
    st%redu(3 * p + env%rank + 1) = st%cr(2)
    st%redu(4 * p + 1:) = [this%counter, this%pieces_out, st%writer%stats%t_put - this%t_put_resumed, real(st%ci, wp)]
  end subroutine pack_loop_figures

  !> --stop-after: the loop's figures and every rank's failure flag in one reduction, the
  !> database discarded, and the stop reported as error (EXIT_STOPPED) unless a failure came first.
  subroutine stop_run(this, st, env, log, error)
    class(study_run_t), intent(inout) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(inout) :: error
    call stop_reduction(st, env, error)
    st%mk(9) = env%wtime() - st%t_start
    call st%sched%free()
    st%mk(10:15) = env%wtime() - st%t_start
    this%t_compute = env%wtime() - st%t_loop
    if (allocated(error)) then
      call st%writer%discard(); return
    end if
    call take_figures(this, st%redu, env%size)
    this%t_setup = st%t_loop - st%t_start
    call log%info("   samples " // str(this%n_prev + this%n_run) // " of " // str(this%n_tot) // " complete")
    call log%stage_end()
    call st%writer%discard()
    call set_error(error, "stopped after " // str(this%n_run) // " samples as requested by --stop-after (" // &
      str(this%n_prev + this%n_run) // " of " // str(this%n_tot) // " complete, database not assembled): " // &
      "run again without --stop-after to finish", EXIT_STOPPED)
  end subroutine stop_run

  !> The database: the end reduction (with the loop's figures), the multipliers, checksums,
  !> complete = 1 and the commit.
  subroutine finish_database(this, st, env, log, cfg, error)
    class(study_run_t), intent(inout) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(config_t), intent(in) :: cfg
    type(error_t), allocatable, intent(inout) :: error
    st%t_asm0 = env%wtime()
    this%t_asm_start = st%t_asm0 - st%t_start
    this%t_compute = st%t_asm0 - st%t_loop
    this%t_setup = st%t_loop - st%t_start
    if (.not. allocated(error)) then
      call log%info("   samples " // str(this%n_prev + this%n_run) // " of " // str(this%n_tot) // " computed")
    end if
    call log%stage_end()
    call log%stage_begin("crowd_snapshots: finishing '" // this%db // "'")
    ! this rank's part of the end first (the places, its contacts), then the counter's release,
    ! where the ranks leaving the loop early wait for the others, then the collective end
    call st%writer%end_local(error)
    st%mk(9) = st%writer%stats%marks(1) - st%t_start
    call st%sched%free()
    st%mk(10) = env%wtime() - st%t_start
    call gather_qoi(this, st, env, cfg, error)
    call st%writer%finish(error, st%redu, st%qois)
    this%wstats = st%writer%stats
    st%mk(11:15) = st%writer%stats%marks(2:6) - st%t_start
    if (allocated(error)) return
    call take_figures(this, st%redu, env%size)
  end subroutine finish_database

  !> The database is committed (every rank knows it from finish's last broadcast): the pieces
  !> go (each rank its own, rank 0 those of earlier runs and the temporaries of pieces a killed
  !> run did not finish); then every rank tries to remove the directory, so the last one to
  !> finish removes it (no rank waits for another).
  subroutine remove_pieces(this, st, env)
    class(study_run_t), intent(inout) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    integer :: j, g, is, k, ierr
    logical :: quarantined
    j = 1
    do while (j < size(st%batch%written))
      call set_of_sample(st%sets, st%batch%written(j + 1), is, k)
      ierr = remove_file(piece_path(st%dir, st%sets(is)%name, k))
      j = j + st%batch%written(j) + 1
    end do
    if (env%is_root()) then
      do g = 1, st%pieces%n_pieces
        ierr = remove_file(st%pieces%path_of(g))
      end do
      if (.not. st%pieces%fresh) then
        do g = 1, this%n_tot
          call set_of_sample(st%sets, g, is, k)
          ierr = remove_file(piece_path(st%dir, st%sets(is)%name, k) // ".partial")
        end do
      end if
    end if
    st%mk(16) = env%wtime() - st%t_start
    ! (the directory exists only if a piece was ever written: a rank that removed nothing here,
    ! and rank 0 of a study whose directory did not exist, need not look)
    quarantined = .false.
    if (st%batch%n_pieces > 0 .or. (env%is_root() .and. .not. st%pieces%fresh)) then
      quarantined = file_exists(st%dir // "/quarantine/.")
      if (.not. quarantined) ierr = remove_dir(st%dir)
    end if
    st%mk(17) = env%wtime() - st%t_start
  end subroutine remove_pieces

  !> The run's figures, after its clock has stopped: the scaling model's collective latency,
  !> every rank's phase marks and its busy time at the end (its samples' multiplier blocks and
  !> the samples it held while the places were in transit) and its serial database work, in
  !> one reduction; then the word on the pieces directory.
  subroutine end_figures(this, st, env, log, error)
    class(study_run_t), intent(inout) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(inout) :: error
    integer :: p
    p = env%size
    this%t_asm = env%wtime() - st%t_asm0
    call log%stage_end()
    this%t_total = env%wtime() - st%t_start
    st%mk(18) = this%t_total
    if (env%is_root()) this%bytes = file_size(this%db)
    this%t_coll = env%collective_latency(20, error)
    if (allocated(error)) return
    deallocate(st%redu)
    allocate(st%redu((N_MARKS + 2) * p))
    st%redu = 0
    st%redu(env%rank * (N_MARKS + 2) + 1:(env%rank + 1) * (N_MARKS + 2)) = [st%mk, &
      st%writer%stats%t_blocks + (st%writer%stats%t_held - st%t_held0), st%writer%stats%t_serial]
    call env%allreduce(st%redu, 'sum', error)
    if (allocated(error)) return
    this%marks = reshape(st%redu, [N_MARKS + 2, p])
    this%end_blocks = this%marks(N_MARKS + 1, :)
    this%serial = this%marks(N_MARKS + 2, :)
    this%marks = this%marks(1:N_MARKS, :)
    this%busy = this%busy + this%end_blocks
    this%sum_time_no_serial = sum(this%busy)
    this%busy = this%busy + this%serial
    this%sum_time = sum(this%busy)
    ! the run ends when its last rank ends: rank 0's time to where the ranks first meet (the
    ! counter's creation: before it a rank may wait for a partner still in the driver's input
    ! checks), then the longest rank's time after it (each on its own clock)
    this%t_total = this%marks(MARK_MEET, 1) + maxval(this%marks(N_MARKS, :) - this%marks(MARK_MEET, :))
    ! the sample loop: from its start to its last sample (held samples written), the longest rank's
    this%t_compute = maxval(this%marks(MARK_LOOP_END, :) - this%marks(MARK_LOOP0, :))
    ! (every rank has passed its removal now)
    if (env%is_root()) then
      if (file_exists(st%dir // "/quarantine/.")) then
        call log%info("   bad pieces kept in '" // st%dir // "/quarantine' (inspect, then remove them)")
      else if (file_exists(st%dir // "/.")) then
        call log%warn("could not remove '" // st%dir // "' (foreign files in it?)")
      end if
    end if
  end subroutine end_figures

  !> Map sample r's scene, count it in the totals, and put it into the database.
  subroutine put(st, cfg, r, error)
    type(run_state_t), intent(inout) :: st
    type(config_t), intent(in) :: cfg
    type(sample_result_t), intent(inout) :: r
    type(error_t), allocatable, intent(out) :: error
    type(scene_t) :: sc
    call st%space%scene_of(r%mu, cfg, sc, error)
    if (allocated(error)) then
      error%message = "scene of " // trim(r%set) // " sample " // str(r%index) // ": " // error%message
      return
    end if
    r%scene_v = scene_vertex_list(sc)
    if (size(r%scene_v) /= st%nv) then
      call set_error(error, "scene of " // trim(r%set) // " sample " // str(r%index) // &
        " has another vertex layout"); return
    end if
    r%scene_exit = [sc%x_lo, sc%width, sc%x_hi, sc%width]
    call sample_qoi(st, cfg, r, sc, error); if (allocated(error)) return
    st%ci(1) = st%ci(1) + count(r%converged == 0)
    if (any(r%converged == 0)) st%ci(2) = st%ci(2) + 1
    if (size(r%kkt) > 0) st%cr(1) = max(st%cr(1), maxval(r%kkt))
    st%cr(2) = max(st%cr(2), r%time)
    call st%writer%put(r, error)
  end subroutine put

  !> The quantities of interest of sample r (scene sc) into its column of st%qbuf.
  subroutine sample_qoi(st, cfg, r, sc, error)
    type(run_state_t), intent(inout) :: st
    type(config_t), intent(in) :: cfg
    type(sample_result_t), intent(in) :: r
    type(scene_t), intent(in) :: sc
    type(error_t), allocatable, intent(out) :: error
    type(qoi_t) :: qoi
    integer :: gs
    if (sc%n_exits() /= st%fom_ref%scene%n_exits()) then
      call set_error(error, "scene of " // trim(r%set) // " sample " // str(r%index) // " has " // &
        str(sc%n_exits()) // " exits, the reference scene " // str(st%fom_ref%scene%n_exits())); return
    end if
    call compute_qoi(sc, st%fom_ref%radius, cfg%time%dt, r%q, qoi, error)
    if (allocated(error)) return
    gs = r%index
    if (trim(r%set) /= trim(st%sets(1)%name)) gs = gs + st%sets(1)%n
    call pack_qoi(qoi, st%qbuf(:, gs))
  end subroutine sample_qoi

  !> Collective: every sample's QoIs to rank 0 (st%qois; a failure joins error, collectively
  !> known in finish).
  subroutine gather_qoi(this, st, env, cfg, error)
    class(study_run_t), intent(in) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(config_t), intent(in) :: cfg
    type(error_t), allocatable, intent(inout) :: error
    type(error_t), allocatable :: e
    integer :: gs
    call env%reduce_sum_root(st%qbuf, e)
    if (allocated(e)) then
      if (.not. allocated(error)) call move_alloc(e, error)
      return
    end if
    if (.not. env%is_root()) return
    allocate(st%qois(this%n_tot))
    do gs = 1, this%n_tot
      call unpack_qoi(st%qbuf(:, gs), st%fom_ref%n_agents, cfg%time%n_steps, st%fom_ref%scene%n_exits(), &
        cfg%time%dt, st%qois(gs))
    end do
  end subroutine gather_qoi

  !> --stop-after: the loop's figures and every rank's failure flag in one reduction (the
  !> message of a failure is agreed only when there is one).
  subroutine stop_reduction(st, env, error)
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(error_t), allocatable, intent(inout) :: error
    real(wp), allocatable :: r2(:)
    type(error_t), allocatable :: e3
    r2 = [st%redu, real(merge(1, 0, allocated(error)), wp)]
    call env%allreduce(r2, 'sum', e3)
    if (allocated(e3)) then
      if (allocated(error)) deallocate(error)
      call move_alloc(e3, error)
      return
    end if
    st%redu = r2(1:size(st%redu))
    if (r2(size(r2)) > 0) call env%agree_error(error)
  end subroutine stop_reduction

  !> The figures of the loop from the summed reduction redu (p ranks).
  subroutine take_figures(this, redu, p)
    class(study_run_t), intent(inout) :: this
    real(wp), intent(in) :: redu(:)
    integer, intent(in) :: p
    this%busy = redu(1:p)
    this%nsamp = nint(redu(p + 1:2 * p))
    this%sum_time = sum(this%busy)
    this%sum_loop = this%sum_time
    this%kkt_max = maxval(redu(2 * p + 1:3 * p)); this%time_max = maxval(redu(3 * p + 1:4 * p))
    associate (r => redu(4 * p + 1:))
      this%counter = r(1:2); this%pieces_out = r(3:5); this%t_put_all = r(6)
      this%nonconverged_steps = nint(r(7)); this%nonconverged_samples = nint(r(8))
    end associate
  end subroutine take_figures

  !> The database's metadata (its texts only on rank 0, which writes them).
  subroutine fill_meta(this, st, env, cfg, study)
    class(study_run_t), intent(in) :: this
    type(run_state_t), intent(inout) :: st
    type(env_t), intent(in) :: env
    type(config_t), intent(in) :: cfg
    type(study_cfg_t), intent(in) :: study
    st%meta%hash = this%hash
    if (env%is_root()) then
      st%meta%config_text = config_echo(cfg) // study_echo(study)
      st%meta%input_text = cfg%text
      st%meta%param_names = st%space%component_names()
      st%meta%version = CROWDROM_VERSION
      st%meta%hdf5_version = h5_library_version()
      st%meta%mpi_version = env%library_version()
      st%meta%compiler = compiler_version()
    end if
    st%meta%n_agents = st%fom_ref%n_agents
    st%meta%n_steps = cfg%time%n_steps
    st%meta%n_expanded = st%space%n_expanded
    st%meta%n_train = st%sets(1)%n
    st%meta%n_valid = st%sets(2)%n
    ! the contact radius (the body radius plus half the social distance): the reduced stages
    ! evaluate their contacts with the database's radius
    st%meta%radius = st%fom_ref%contact_radius
    st%meta%dt = st%fom_ref%dt
  end subroutine fill_meta

  !> Busy-time efficiencies (sample loop, whole run) and load balance of a run.
  subroutine efficiencies(this, p, eff_loop, eff_total, balance)
    class(study_run_t), intent(in) :: this
    integer, intent(in) :: p
    real(wp), intent(out) :: eff_loop, eff_total, balance
    eff_loop = 0; eff_total = 0; balance = 1
    if (this%t_compute > 0) eff_loop = this%sum_loop / (p * this%t_compute)
    if (this%t_total > 0) eff_total = this%sum_time / (p * this%t_total)
    if (maxval(this%busy) > 0) balance = sum(this%busy) / p / maxval(this%busy)
  end subroutine efficiencies

  !> The summary printed at the end of a run.
  function summary_text(this) result(text)
    class(study_run_t), intent(in) :: this
    character(len=:), allocatable :: text
    real(wp) :: eff_loop, eff_total, balance, eff_noser
    integer :: r, p
    p = size(this%busy)
    call efficiencies(this, p, eff_loop, eff_total, balance)
    eff_noser = 0
    if (this%t_total > 0) eff_noser = this%sum_time_no_serial / (p * this%t_total)
    text = "summary:" // new_line('a') // &
      "  database            " // this%db // " (" // str(real(this%bytes, wp) / 1.0e6_wp, 'f0.2') // " MB)" // &
      new_line('a') // &
      "  samples             " // str(this%n_tot) // " (" // str(this%n_train) // " train + " // str(this%n_valid) // &
      " valid), computed now " // str(this%n_run) // ", resumed " // str(this%n_prev) // new_line('a') // &
      "  time per sample     mean " // str(this%sum_time / max(this%n_run, 1), 'f0.3') // " s (with its piece " // &
      "file), max of the model runs in the database " // str(this%time_max, 'f0.3') // " s" // new_line('a') // &
      "  ranks               " // str(p) // new_line('a')
    do r = 1, p
      text = text // "    rank " // str(r - 1) // ": " // str(this%nsamp(r)) // " samples, busy " // &
        str(this%busy(r), 'f0.2') // " s" // new_line('a')
    end do
    text = text // &
      "  load balance        " // str(balance, 'f0.3') // " (mean / max busy time)" // new_line('a') // &
      "  busy-time efficiency " // str(eff_loop, 'f0.3') // " (sample loop), " // str(eff_total, 'f0.3') // &
      " (whole run: sum of busy times / (P x wall)), " // str(eff_noser, 'f0.3') // &
      " without rank 0's serial database work" // new_line('a') // &
      "  overheads           counter " // str(1.0e6_wp * this%counter(2) / max(this%counter(1), 1.0_wp), 'f0.1') // &
      " us per operation, " // str(nint(this%pieces_out(1))) // " pieces (" // &
      str(this%pieces_out(2) / 1.0e6_wp, 'f0.2') // " MB, " // str(this%pieces_out(3), 'f0.3') // " s), collective " // &
      str(1.0e6_wp * this%t_coll, 'f0.1') // " us" // new_line('a') // &
      "  wall time           " // str(this%t_total, 'f0.2') // " s (samples " // str(this%t_compute, 'f0.2') // &
      " s, end of the database " // str(this%t_asm, 'f0.3') // " s:" // &
      " dictionary " // str(this%wstats%t_dict, 'f0.3') // ", layout " // str(this%wstats%t_layout, 'f0.3') // &
      ", write " // str(this%wstats%t_write, 'f0.3') // ", seal " // str(this%wstats%t_seal, 'f0.3') // ")" // &
      new_line('a') // &
      "  non-converged steps " // str(this%nonconverged_steps) // " in " // str(this%nonconverged_samples) // &
      " samples (largest KKT residual " // str(this%kkt_max) // ")" // new_line('a') // &
      "  contact dictionary  " // str(this%wstats%n_dict) // " contacts, " // str(this%wstats%nnz) // &
      " stored multipliers"
  end function summary_text

  !> Rank 0: the summary as JSON (`input`: the input file's name).
  subroutine write_summary(this, path, input, error)
    class(study_run_t), intent(in) :: this
    character(len=*), intent(in) :: path, input
    type(error_t), allocatable, intent(out) :: error
    type(json_writer_t) :: js
    real(wp) :: eff_loop, eff_total, balance, eff_noser
    integer :: p
    p = size(this%busy)
    call efficiencies(this, p, eff_loop, eff_total, balance)
    eff_noser = 0
    if (this%t_total > 0) eff_noser = this%sum_time_no_serial / (p * this%t_total)
    call js%add("program", "crowd_snapshots")
    call js%add("input", input)
    call js%add("database", this%db)
    call js%add("database_bytes", this%bytes)
    call js%add("config_hash", trim(this%hash))
    call js%add("ranks", p)
    call js%add("samples_total", this%n_tot)
    call js%add("samples_train", this%n_train)
    call js%add("samples_valid", this%n_valid)
    call js%add("samples_computed", this%n_run)
    call js%add("samples_resumed", this%n_prev)
    call js%add("time_per_sample_mean", this%sum_time / max(this%n_run, 1))
    call js%add("time_per_sample_max", this%time_max)
    call js%add("samples_per_rank", this%nsamp)
    call js%add("busy_time_per_rank", this%busy)
    if (allocated(this%end_blocks)) call js%add("end_block_time_per_rank", this%end_blocks)
    if (allocated(this%serial)) call js%add("serial_database_time_per_rank", this%serial)
    call js%add("load_balance", balance)
    call js%add("parallel_efficiency", eff_total)
    call js%add("parallel_efficiency_sample_loop", eff_loop)
    call js%add("wall_time", this%t_total)
    call js%add("wall_time_samples", this%t_compute)
    call js%add("wall_time_assembly", this%t_asm)
    call js%add("busy_time_efficiency", eff_total)
    call js%add("busy_time_efficiency_sample_loop", eff_loop)
    call js%add("busy_time_efficiency_without_serial", eff_noser)
    call js%add("wall_time_setup", this%t_setup)
    call js%add("database_layout_time", this%t_layout)
    call js%add("assembly_start", this%t_asm_start)
    call js%add("counter_operations", nint(this%counter(1)))
    call js%add("counter_latency_mean", this%counter(2) / max(this%counter(1), 1.0_wp))
    call js%add("collective_latency", this%t_coll)
    call js%add("pieces_written", nint(this%pieces_out(1)))
    call js%add("piece_bytes_written", this%pieces_out(2))
    call js%add("piece_write_time", this%pieces_out(3))
    call js%add("database_put_time", this%t_put_all)
    call js%add("database_put_time_resumed", this%t_put_resumed)
    call js%add("assembly_dictionary_time", this%wstats%t_dict)
    call js%add("assembly_layout_time", this%wstats%t_layout)
    call js%add("assembly_write_time", this%wstats%t_write)
    call js%add("assembly_seal_time", this%wstats%t_seal)
    call js%add("assembly_bytes_written", real(this%wstats%bytes, wp))
    call js%add("batch_seconds", this%batch_seconds)
    call js%add("phase_names", MARK_NAMES)
    if (allocated(this%marks)) call js%add("phase_marks", reshape(this%marks, [size(this%marks)]))
    call js%add("nonconverged_steps", this%nonconverged_steps)
    call js%add("nonconverged_samples", this%nonconverged_samples)
    call js%add("largest_kkt_residual", this%kkt_max)
    call js%add("contacts_in_dictionary", this%wstats%n_dict)
    call js%add("stored_multipliers", this%wstats%nnz)
    call js%write_file(path, error)
  end subroutine write_summary

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
end module cr_study_run
