!> The run of crowd_predict: a ROM file (version 3, with its study) and a list of queries ->
!> per query the quantities of interest of the reduced (model = 'rom') or full (model =
!> 'exact') trajectory, written as one QoI product (and the positions on request).
!>
!> Stages (each returns error_t, none stops):
!>   init   read the ROM file and its study (no database), the list of queries (cr_query_list),
!>          refuse queries outside the training box with out_of_box = 'refuse', find the pair;
!>   run    load the reduced operators once (rom), then the queries are handed out dynamically
!>          (cr_scheduler: one ticket per query, rank 0 computes too); each query runs the one
!>          reduced stepping path (cr_rom_query + cr_rom_stepper, as crowd_rom's sweep) or the
!>          full model, its result is packed into one record, and the records are gathered on
!>          rank 0 in query order: nothing a rank computes depends on which rank computes it
!>          or on what it computed before, so the product is the same for any number of ranks;
!>   write  rank 0 writes the product (temporary + rename);
!>   print_summary / write_summary.
module cr_predict_run
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str, shorten
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_config, only: config_t
  use cr_fom, only: fom_t, step_record_t
  use cr_scene, only: scene_t
  use cr_rom_file, only: rom_file_t, rom_pair_t, read_rom_file, read_rom_pair, find_pair
  use cr_rom_study, only: rom_study_t, open_rom_study
  use cr_reduced_ops, only: reduced_ops_t, eval_ctx_t, make_reduced_ops
  use cr_rom_stepper, only: rom_solver_cfg_t, rom_traj_t, run_trajectory
  use cr_rom_guard, only: rom_guard_t
  use cr_rom_query, only: query_setup, query_positions
  use cr_local_correction, only: local_correction_t
  use cr_projection, only: projection_settings_t
  use cr_scheduler, only: scheduler_t
  use cr_predict_config, only: predict_cfg_t, predict_echo, check_predict_paths
  use cr_query_list, only: query_list_t, load_queries
  use cr_predict_output, only: query_record_t, record_size, pack_record, unpack_record, predict_product_t, &
    write_predict_product
  use cr_json, only: json_writer_t
  use cr_h5file, only: h5file_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: predict_run_t

  !> One prediction run.
  type :: predict_run_t
    type(predict_cfg_t) :: cfg
    !> the input (for messages) and "<input>: &predict"
    character(len=:), allocatable :: input, where
    type(rom_file_t) :: hdr
    type(rom_study_t) :: st
    type(query_list_t) :: list
    !> the pair of the reduced setting in the ROM file and its basis size (model = 'rom')
    integer :: kp = 0, nb = 0
    !> rank 0 after run: the records in query order
    type(query_record_t), allocatable :: rec(:)
    !> wall time of the query loop and the summed CPU time of the queries [s]
    real(wp) :: t_wall = 0, t_cpu = 0
    integer :: n_ranks = 1
    !> model = 'positions': the params_file, open on every rank during run, and the CPU seconds
    !> that produced each query's positions (its dataset 'cpu_seconds', else 0) [n_queries]
    type(h5file_t) :: given
    real(wp), allocatable :: given_cpu(:)
  contains
    procedure :: init
    procedure :: run
    procedure :: write
    procedure :: print_summary
    procedure :: write_summary
    procedure :: free
  end type predict_run_t

contains

  !> Read the ROM file and its study, the queries; check the outputs against the inputs.
  subroutine init(this, input, summary, cfg, log, error)
    class(predict_run_t), intent(inout) :: this
    character(len=*), intent(in) :: input, summary
    type(predict_cfg_t), intent(in) :: cfg
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    integer :: n_out
    call this%free()
    this%cfg = cfg
    this%input = input
    this%where = input // ": &predict"
    call check_predict_paths(input, summary, cfg, error)
    if (allocated(error)) return
    call log%stage_begin("crowd_predict: read ROM file and queries")
    call read_rom_file(trim(cfg%rom_file), this%where // ": rom_file", this%hdr, error)
    if (allocated(error)) return
    call open_rom_study(this%hdr, this%where // ": rom_file", this%st, error)
    if (allocated(error)) return
    call load_queries(cfg, this%st%space, this%st%cfg, this%where, this%list, error)
    if (allocated(error)) return
    n_out = count(this%list%out_of_box)
    call log%info("   " // str(this%st%n_agents) // " agents, " // str(this%st%n_steps) // " steps, parameters " // &
      shorten(this%st%param_names, 60) // "; " // str(this%list%n) // " queries (" // this%list%source // "), " // &
      str(n_out) // " outside the training box")
    if (n_out > 0 .and. cfg%out_of_box == 'refuse') then
      call set_error(error, this%where // ": " // str(n_out) // " of " // str(this%list%n) // " queries lie outside " // &
        "the training box (first: query " // str(findloc(this%list%out_of_box, .true., 1)) // "; out_of_box = " // &
        "'refuse')", EXIT_BAD_INPUT); return
    end if
    if (cfg%model == 'positions') then
      call check_given(this, error)
      if (allocated(error)) return
    end if
    if (cfg%model == 'rom') then
      call find_pair(this%hdr, cfg%n, cfg%r, this%where, this%kp, error)
      if (allocated(error)) return
      this%nb = this%hdr%pair_nb(this%kp)
    end if
    call log%stage_end()
  end subroutine init

  !> model = 'positions': the params_file's dataset 'positions' holds n_steps + 1 frames of
  !> n_dof positions per query.
  subroutine check_given(this, error)
    type(predict_run_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    type(error_t), allocatable :: e2
    integer(i8), allocatable :: dims(:)
    character(len=:), allocatable :: what
    what = this%where // ": params_file '" // trim(this%cfg%params_file) // "'"
    call this%given%open(trim(this%cfg%params_file), error)
    if (allocated(error)) then
      error%message = what // ": " // error%message; error%code = EXIT_BAD_INPUT; return
    end if
    if (.not. this%given%exists("positions")) then
      call set_error(error, what // ": no dataset 'positions' (model = 'positions')", EXIT_BAD_INPUT)
    else
      call this%given%get_dims("positions", dims, error)
      if (.not. allocated(error)) then
        if (size(dims) /= 2) then
          call set_error(error, what // ": dataset 'positions' must be 2-dimensional", EXIT_BAD_INPUT)
        else if (dims(1) /= this%st%n_dof .or. dims(2) /= this%list%n * (this%st%n_steps + 1)) then
          call set_error(error, what // ": dataset 'positions' has " // str(dims(2)) // " x " // str(dims(1)) // &
            " entries, expected n_queries (n_steps + 1) x n_dof = " // str(this%list%n * (this%st%n_steps + 1)) // &
            " x " // str(this%st%n_dof), EXIT_BAD_INPUT)
        end if
      end if
    end if
    if (.not. allocated(error)) then
      if (this%given%exists("cpu_seconds")) then
        call this%given%read("cpu_seconds", this%given_cpu, error)
        if (.not. allocated(error)) then
          if (size(this%given_cpu) /= this%list%n .or. .not. all(this%given_cpu >= 0 .and. &
              this%given_cpu <= huge(1.0_wp))) call set_error(error, what // ": dataset 'cpu_seconds' must hold " // &
            str(this%list%n) // " finite values >= 0", EXIT_BAD_INPUT)
        end if
      else
        allocate(this%given_cpu(this%list%n))
        this%given_cpu = 0
      end if
    end if
    call this%given%close(e2)
    if (allocated(e2) .and. .not. allocated(error)) call move_alloc(e2, error)
  end subroutine check_given

  !> Every query, distributed dynamically over the ranks of env; the records gathered on rank 0.
  subroutine run(this, env, log, error)
    class(predict_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    type(rom_pair_t) :: pair
    class(reduced_ops_t), allocatable :: ops
    type(local_correction_t), allocatable :: corr
    type(scheduler_t) :: sched
    real(wp), allocatable :: mine(:,:)
    integer, allocatable :: ids(:)
    integer :: k, n_mine, lrec
    real(wp) :: w0
    type(error_t), allocatable :: e2
    this%n_ranks = env%size
    if (this%cfg%model == 'rom') then
      call log%stage_begin("crowd_predict: load the reduced model (N, R) = (" // str(this%cfg%n) // ", " // &
        str(this%cfg%r) // "), hyper " // trim(this%cfg%hyper) // ", contacts " // trim(this%cfg%contacts) // &
        ", correction " // trim(this%cfg%correction))
      call load_model(this, pair, ops, corr, error)
      call env%agree_error(error)
      if (allocated(error)) return
      call log%stage_end()
    end if
    lrec = record_size(this%st%n_steps, this%st%n_dof, this%nb, this%cfg%trajectories)
    allocate(mine(lrec, 16), ids(16))
    if (this%cfg%model == 'positions') then
      call this%given%open(trim(this%cfg%params_file), error)
      if (allocated(error)) call prefix_error(error, this%where // ": params_file")
      call env%agree_error(error)
      if (allocated(error)) return
    end if
    call log%stage_begin("crowd_predict: " // str(this%list%n) // " queries (" // trim(this%cfg%model) // ") on " // &
      str(env%size) // " rank(s)")
    call sched%init(env, this%list%n, error)
    if (allocated(error)) return
    call log%progress_start()
    w0 = env%wtime()
    n_mine = 0
    do
      k = sched%next(error)
      if (allocated(error) .or. k == 0) exit
      if (n_mine == size(ids)) then
        mine = reshape(mine, [lrec, 2 * size(ids)], pad=[0.0_wp])
        ids = [ids, spread(0, 1, size(ids))]
      end if
      n_mine = n_mine + 1
      ids(n_mine) = k
      call one_query(this, pair, ops, corr, k, mine(:, n_mine), error)
      if (allocated(error)) then
        call prefix_error(error, this%where // ": query " // str(k)); exit
      end if
      call log%progress("query", min(k, this%list%n), this%list%n)
    end do
    if (this%given%is_open()) call this%given%close(e2)
    if (allocated(e2) .and. .not. allocated(error)) call move_alloc(e2, error)
    call env%agree_error(error)
    call sched%free()
    if (allocated(error)) return
    this%t_wall = env%wtime() - w0
    call gather_records(this, env, mine(:, 1:n_mine), ids(1:n_mine), error)
    if (allocated(error)) return
    call log%stage_end()
    if (allocated(corr)) call corr%free()
  end subroutine run

  !> The pair, the reduced operators and the local correction of the setting (once per run).
  subroutine load_model(this, pair, ops, corr, error)
    type(predict_run_t), intent(in) :: this
    type(rom_pair_t), intent(out) :: pair
    class(reduced_ops_t), allocatable, intent(out) :: ops
    type(local_correction_t), allocatable, intent(out) :: corr
    type(error_t), allocatable, intent(out) :: error
    type(projection_settings_t) :: psett
    call read_rom_pair(this%hdr, this%kp, pair, error)
    if (allocated(error)) return
    call make_reduced_ops(trim(this%cfg%hyper), trim(this%cfg%contacts), pair, [this%cfg%m_v, this%cfg%m_b, &
      this%cfg%m_d], this%st%cfg%contacts%cutoff_factor, this%where, ops, error)
    if (allocated(error)) return
    if (this%cfg%correction == 'local') then
      ! the study's exact solver at its tolerance
      allocate(corr)
      psett = this%st%cfg%solver
      call corr%init(psett, this%st%cfg%contacts%cutoff_factor, error)
      if (allocated(error)) call prefix_error(error, this%where // ": correction")
    end if
  end subroutine load_model

  !> Query k: its trajectory (reduced or full) and its record.
  subroutine one_query(this, pair, ops, corr, k, packed, error)
    type(predict_run_t), intent(inout) :: this
    type(rom_pair_t), intent(in) :: pair
    class(reduced_ops_t), allocatable, intent(inout) :: ops
    type(local_correction_t), allocatable, intent(inout) :: corr
    integer, intent(in) :: k
    real(wp), intent(out) :: packed(:)
    type(error_t), allocatable, intent(out) :: error
    type(query_record_t) :: r
    type(scene_t) :: scene
    real(wp), allocatable :: qr(:,:)
    real(wp) :: c0, c1
    call cpu_time(c0)
    select case (trim(this%cfg%model))
    case ('rom')
      call rom_query(this, pair, ops, corr, this%list%mu(:, k), qr, scene, r, error)
    case ('exact')
      call exact_query(this, this%list%mu(:, k), qr, scene, r, error)
    case default
      call given_query(this, k, qr, scene, error)
    end select
    if (allocated(error)) return
    ! the QoIs with the body radius (cr_rom_study: as crowd_fom and crowd_snapshots)
    call r%measure(scene, this%st%body_radius, this%st%dt, qr, error)
    if (allocated(error)) return
    call cpu_time(c1)
    r%cpu = c1 - c0
    if (this%cfg%model == 'positions') r%cpu = r%cpu + this%given_cpu(k)
    r%out_of_box = this%list%out_of_box(k)
    if (this%cfg%trajectories) call move_alloc(qr, r%q)
    call pack_record(r, packed)
  end subroutine one_query

  !> The reduced trajectory of mu: the sweep's stepping path (cr_rom_query, cr_rom_stepper).
  subroutine rom_query(this, pair, ops, corr, mu, qr, scene, r, error)
    type(predict_run_t), intent(in) :: this
    type(rom_pair_t), intent(in) :: pair
    class(reduced_ops_t), allocatable, intent(inout) :: ops
    type(local_correction_t), allocatable, intent(inout) :: corr
    real(wp), intent(in) :: mu(:)
    real(wp), allocatable, intent(out) :: qr(:,:)
    type(scene_t), intent(out) :: scene
    type(query_record_t), intent(inout) :: r
    type(error_t), allocatable, intent(out) :: error
    type(eval_ctx_t) :: ctx
    type(rom_guard_t) :: guard
    type(rom_solver_cfg_t) :: scfg
    type(rom_traj_t) :: traj
    scfg%name = this%cfg%solver
    call query_setup(this%st, mu, ctx, guard, error)
    if (allocated(error)) return
    call run_trajectory(ops, ctx, this%st%q0, this%st%n_steps, scfg, traj, error, guard=guard, corr=corr)
    if (allocated(error)) return
    call query_positions(this%st, pair%v, guard, traj, qr)
    r%diverged_step = traj%diverged_step
    r%n_infeasible = traj%n_infeasible
    r%n_capped = traj%n_capped
    if (this%cfg%trajectories) call move_alloc(traj%alpha, r%alpha)
    scene = ctx%scene
  end subroutine rom_query

  !> The full-order trajectory of mu: the study's configuration and solver, as crowd_snapshots.
  subroutine exact_query(this, mu, q, scene, r, error)
    type(predict_run_t), intent(in) :: this
    real(wp), intent(in) :: mu(:)
    real(wp), allocatable, intent(out) :: q(:,:)
    type(scene_t), intent(out) :: scene
    type(query_record_t), intent(inout) :: r
    type(error_t), allocatable, intent(out) :: error
    type(config_t) :: c
    type(fom_t) :: fom
    type(step_record_t) :: rec
    real(wp), allocatable :: speeds(:)
    integer :: nu
    c = this%st%cfg
    speeds = this%st%speeds
    call this%st%space%apply(mu, c, speeds)
    call fom%init(c, error, q0=this%st%q0, speeds=speeds)
    if (allocated(error)) return
    allocate(q(this%st%n_dof, this%st%n_steps + 1))
    q(:, 1) = fom%q
    do nu = 1, this%st%n_steps
      call fom%advance(rec, error)
      if (allocated(error)) return
      q(:, nu + 1) = fom%q
      if (.not. rec%converged) r%n_capped = r%n_capped + 1
    end do
    scene = fom%scene
  end subroutine exact_query

  !> Query k of model = 'positions': its frames of the params_file's dataset 'positions' and
  !> the scene of its parameters.
  subroutine given_query(this, k, q, scene, error)
    type(predict_run_t), intent(inout) :: this
    integer, intent(in) :: k
    real(wp), allocatable, intent(out) :: q(:,:)
    type(scene_t), intent(out) :: scene
    type(error_t), allocatable, intent(out) :: error
    integer :: nc
    nc = this%st%n_steps + 1
    allocate(q(this%st%n_dof, nc))
    call this%given%read_block("positions", q, (k - 1) * nc, error)
    if (allocated(error)) then
      call prefix_error(error, "params_file: dataset 'positions'"); error%code = EXIT_BAD_INPUT; return
    end if
    call need_finite_q(q, error); if (allocated(error)) return
    call this%st%space%scene_of(this%list%mu(:, k), this%st%cfg, scene, error)
  end subroutine given_query

  !> Given positions must be finite.
  subroutine need_finite_q(q, error)
    real(wp), intent(in) :: q(:,:)
    type(error_t), allocatable, intent(out) :: error
    if (all(abs(q) <= huge(1.0_wp))) return
    call set_error(error, "params_file: dataset 'positions': a value is not finite", EXIT_BAD_INPUT)
  end subroutine need_finite_q

  !> Rank 0 receives every rank's records and puts them in query order (this%rec).
  subroutine gather_records(this, env, mine, ids, error)
    type(predict_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    real(wp), intent(in) :: mine(:,:)
    integer, intent(in) :: ids(:)
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: counts(:), displs(:), all_ids(:)
    real(wp), allocatable :: all(:,:)
    integer :: j, lrec
    lrec = size(mine, 1)
    call env%block_counts(size(ids), counts, displs, error); if (allocated(error)) return
    if (sum(counts) /= this%list%n) then
      call set_error(error, "crowd_predict: " // str(sum(counts)) // " records for " // str(this%list%n) // " queries")
      return
    end if
    allocate(all_ids(this%list%n))
    call env%allgatherv(ids, all_ids, counts, displs, error); if (allocated(error)) return
    if (env%is_root()) then
      allocate(all(lrec, this%list%n))
    else
      allocate(all(lrec, 0))
    end if
    call env%gatherv(mine, all, lrec * counts, lrec * displs, 0, error); if (allocated(error)) return
    if (.not. env%is_root()) return
    allocate(this%rec(this%list%n))
    do j = 1, this%list%n
      call unpack_record(all(:, j), this%st%n_steps, this%st%n_dof, this%nb, this%cfg%trajectories, this%st%dt, &
        this%rec(all_ids(j)))
    end do
    this%t_cpu = sum(this%rec%cpu)
  end subroutine gather_records

  !> Rank 0: the product (&predict output).
  subroutine write(this, env, error)
    class(predict_run_t), intent(in) :: this
    type(env_t), intent(in) :: env
    type(error_t), allocatable, intent(out) :: error
    type(predict_product_t) :: p
    if (env%is_root()) then
      p%config = predict_echo(this%cfg) // this%hdr%study_config
      p%model = model_name(this)
      p%rom_file = trim(this%cfg%rom_file)
      p%source = this%list%source
      p%param_names = this%st%param_names
      p%param_min = this%st%space%lo; p%param_max = this%st%space%hi
      p%n_agents = this%st%n_agents; p%n_steps = this%st%n_steps; p%dt = this%st%dt; p%radius = this%st%radius
      p%n_ranks = this%n_ranks; p%t_wall = this%t_wall
      if (this%cfg%model == 'rom') then
        p%pair = this%kp; p%pair_n = this%cfg%n; p%pair_r = this%cfg%r; p%n_basis = this%nb
      end if
      call write_predict_product(trim(this%cfg%output), p, this%list%mu, this%rec, error)
      if (allocated(error)) call prefix_error(error, this%where // ": output")
    end if
    call env%agree_error(error)
  end subroutine write

  !> "exact" or "rom setting (N, R, hyper, contacts, correction)".
  function model_name(this) result(s)
    type(predict_run_t), intent(in) :: this
    character(len=:), allocatable :: s
    if (len_trim(this%cfg%label) > 0) then
      s = trim(this%cfg%label)
    else if (this%cfg%model == 'positions') then
      s = "given positions"
    else if (this%cfg%model == 'exact') then
      s = "exact " // trim(this%st%cfg%solver%name)
    else
      s = "rom n=" // str(this%cfg%n) // " r=" // str(this%cfg%r) // " hyper=" // trim(this%cfg%hyper) // &
        " contacts=" // trim(this%cfg%contacts) // " correction=" // trim(this%cfg%correction) // " solver=" // &
        trim(this%cfg%solver)
    end if
  end function model_name

  !> The totals on the log (rank 0, after run).
  subroutine print_summary(this, log)
    class(predict_run_t), intent(in) :: this
    type(logger_t), intent(inout) :: log
    if (.not. allocated(this%rec)) return
    call log%info("summary: " // str(this%list%n) // " queries (" // model_name(this) // "), " // &
      str(count(this%list%out_of_box)) // " outside the training box, " // str(count(this%rec%diverged_step > 0)) // &
      " diverged; " // str(this%t_cpu, "es10.3") // " CPU s in the queries (" // &
      str(this%list%n / max(this%t_cpu, tiny(1.0_wp)), "es10.3") // " queries per CPU second), wall " // &
      str(this%t_wall, "es10.3") // " s on " // str(this%n_ranks) // " rank(s); output " // trim(this%cfg%output))
  end subroutine print_summary

  !> The JSON summary (rank 0, after run).
  subroutine write_summary(this, path, error)
    class(predict_run_t), intent(in) :: this
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    type(json_writer_t) :: js
    call js%add("program", "crowd_predict")
    call js%add("output", trim(this%cfg%output))
    call js%add("model", model_name(this))
    call js%add("queries", this%list%n)
    call js%add("out_of_box", count(this%list%out_of_box))
    call js%add("diverged", count(this%rec%diverged_step > 0))
    call js%add("ranks", this%n_ranks)
    call js%add("cpu_seconds", this%t_cpu)
    call js%add("wall_seconds", this%t_wall)
    call js%add("queries_per_cpu_second", this%list%n / max(this%t_cpu, tiny(1.0_wp)))
    call js%write_file(path, error)
  end subroutine write_summary

  !> Free everything (init may be called again).
  subroutine free(this)
    class(predict_run_t), intent(inout) :: this
    type(predict_run_t) :: fresh
    select type (this)
    type is (predict_run_t)
      this = fresh
    end select
  end subroutine free
end module cr_predict_run
