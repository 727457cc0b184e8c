!> The run of crowd_fom: one full-order simulation of one scene, from the validated
!> configuration to the HDF5 trajectory (cr_fom_file) and the summary. Serial: the driver calls
!> it on rank 0 only.
module cr_fom_run
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_logger, only: logger_t
  use cr_config, only: config_t, config_echo
  use cr_fom, only: fom_t, step_record_t
  use cr_fom_file, only: fom_writer_t
  use cr_qoi, only: qoi_t, qoi_acc_t
  use cr_pdda_file, only: pdda_writer_t
  use cr_json, only: json_writer_t
  implicit none
  private
  public :: fom_run

  !> What the steps of fom_run share: the model, the outputs (HDF5 trajectory, and the
  !> archive when with_pdda), the step records [n_target] of the k steps done, the quantities
  !> of interest accumulated, the warnings given and the wall time of the stepping.
  type :: fom_run_state_t
    type(fom_t) :: fom
    type(fom_writer_t) :: out
    type(pdda_writer_t) :: pdda
    logical :: with_pdda = .false.
    type(step_record_t), allocatable :: recs(:)
    type(qoi_acc_t) :: acc
    integer :: n_target = 0, k = 0, n_warned = 0
    logical :: warned_rho = .false.
    real(wp) :: t_total = 0
  end type fom_run_state_t

contains

  !> Place the agents, step the model (progress through `log`), write the HDF5 trajectory
  !> (&output file) and log the totals; `summary` (if not empty): also the totals as JSON.
  !> Steps: the model and the outputs opened (open_run), the time stepping (step_run, with
  !> check_step's warnings and write_outputs), the outputs closed (close_run) and the totals
  !> (summary_text, write_summary).
  subroutine fom_run(cfg, summary, log, error)
    type(config_t), intent(in) :: cfg
    character(len=*), intent(in) :: summary
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    type(fom_run_state_t) :: rs
    call open_run(cfg, log, rs, error)
    if (allocated(error)) return
    call step_run(cfg, log, rs, error)
    if (allocated(error)) then
      call rs%out%abort(); call rs%pdda%abort(); return
    end if
    call close_run(cfg, log, rs, error)
    if (allocated(error)) return
    call log%info(summary_text(cfg, rs))
    if (len(summary) > 0) then
      call write_summary(summary, cfg, rs%fom, rs%recs(1:rs%k), rs%t_total, error)
      if (allocated(error)) return
      call log%info("summary written to " // summary)
    end if
  end subroutine fom_run

  !> The model (scene, placement, solver), the HDF5 output with the initial state, the
  !> quantities of interest of every step's positions (not only the output states) and the
  !> trajectory archive (&output pdda_file) when asked for.
  subroutine open_run(cfg, log, rs, error)
    type(config_t), intent(in) :: cfg
    type(logger_t), intent(inout) :: log
    type(fom_run_state_t), intent(inout) :: rs
    type(error_t), allocatable, intent(out) :: error
    call log%stage_begin("crowd_fom: setup")
    call log%info(config_echo(cfg))
    call rs%fom%init(cfg, error)
    if (allocated(error)) return
    associate (fom => rs%fom)
    call log%info("   " // str(fom%n_agents) // " agents of radius " // str(fom%radius) // ", " // &
      str(fom%scene%n_obstacles()) // " obstacles (" // str(fom%scene%n_interior()) // " interior), " // &
      "desired velocity: " // fom%desired%model_name())
    if (cfg%agents%init == 'random') call log%info("   placement: overlap removal took " // &
      str(fom%placement_iterations) // " projection iterations")
    call rs%out%open(trim(cfg%output%file), cfg, fom, error)
    if (allocated(error)) return
    call rs%acc%init(fom%n_agents)
    call rs%acc%add(fom%scene, fom%radius, fom%q)
    rs%with_pdda = len_trim(cfg%output%pdda_file) > 0
    if (rs%with_pdda) then
      call rs%pdda%open(trim(cfg%output%pdda_file), fom%scene, fom%radius, fom%n_agents, &
        cfg%time%dt * cfg%output%every, error)
      if (.not. allocated(error)) call rs%pdda%write_frame(fom%scene, 0, fom%q, error)
      if (allocated(error)) then
        call rs%out%abort(); call rs%pdda%abort(); return
      end if
    end if
    end associate
    call log%stage_end()
  end subroutine open_run

  !> The time stepping: every step recorded, its positions' quantities of interest added, its
  !> warnings (check_step) and its outputs (write_outputs); the wall time of the loop.
  subroutine step_run(cfg, log, rs, error)
    type(config_t), intent(in) :: cfg
    type(logger_t), intent(inout) :: log
    type(fom_run_state_t), intent(inout) :: rs
    type(error_t), allocatable, intent(out) :: error
    type(step_record_t) :: rec
    integer(8) :: c0, c1, rate
    rs%n_target = cfg%time%n_steps
    if (cfg%time%until_empty) rs%n_target = cfg%time%max_steps
    allocate(rs%recs(rs%n_target))
    call log%stage_begin("crowd_fom: time stepping with solver '" // trim(cfg%solver%name) // "'")
    call log%progress_start()
    call system_clock(c0, rate)
    rs%k = 0
    do while (rs%k < rs%n_target)
      if (cfg%time%until_empty .and. rs%fom%n_inside() == 0) exit
      call rs%fom%advance(rec, error)
      if (allocated(error)) return
      rs%k = rs%k + 1
      rs%recs(rs%k) = rec
      call rs%acc%add(rs%fom%scene, rs%fom%radius, rs%fom%q)
      call check_step(cfg, log, rs, rec)
      call write_outputs(cfg, rs, error)
      if (allocated(error)) return
      call log%progress("step", rs%k, rs%n_target)
    end do
    call system_clock(c1)
    rs%t_total = real(c1 - c0, wp) / real(rate, wp)
    call log%stage_end()
  end subroutine step_run

  !> The warnings of step rs%k: not converged (one by one up to MAX_STEP_WARNINGS, then
  !> counted only), and once per run Uzawa's rho beyond its convergence bound.
  subroutine check_step(cfg, log, rs, rec)
    type(config_t), intent(in) :: cfg
    type(logger_t), intent(inout) :: log
    type(fom_run_state_t), intent(inout) :: rs
    type(step_record_t), intent(in) :: rec
    !> non-converged steps warned about one by one
    integer, parameter :: MAX_STEP_WARNINGS = 10
    integer :: k
    k = rs%k
    if (.not. rec%converged) then
      rs%n_warned = rs%n_warned + 1
      if (rs%n_warned <= MAX_STEP_WARNINGS) call log%warn("step " // str(k) // ": projection not converged " // &
        "(KKT residual " // str(rec%kkt) // ", tol " // str(cfg%solver%tol) // ", " // str(rec%iterations) // &
        " iterations)")
      if (rs%n_warned == MAX_STEP_WARNINGS) call log%warn("further non-converged steps are counted (summary: " // &
        "failed steps; stats/converged) but not printed")
    end if
    if (rs%fom%solver%name() == 'uzawa' .and. .not. rs%warned_rho) then
      ! rho L > 2 (no division: L = 0 without rows)
      if (cfg%solver%uzawa_rho_factor / cfg%time%dt**2 * rs%fom%cs%lipschitz_bound() > 2.0_wp) then
        call log%warn("uzawa: rho = " // str(cfg%solver%uzawa_rho_factor / cfg%time%dt**2) // &
          " exceeds the convergence bound 2/||B||^2 >= " // str(2.0_wp / rs%fom%cs%lipschitz_bound()) // &
          " at step " // str(k))
        rs%warned_rho = .true.
      end if
    end if
  end subroutine check_step

  !> The outputs of step rs%k: the HDF5 state every &output every steps and at the last, the
  !> archive's frame every &output every steps (the archive layout holds equally spaced
  !> frames only).
  subroutine write_outputs(cfg, rs, error)
    type(config_t), intent(in) :: cfg
    type(fom_run_state_t), intent(inout) :: rs
    type(error_t), allocatable, intent(out) :: error
    if (mod(rs%k, cfg%output%every) == 0 .or. rs%k == rs%n_target) then
      call rs%out%write_step(rs%fom, error)
      if (allocated(error)) return
    end if
    if (rs%with_pdda .and. mod(rs%k, cfg%output%every) == 0) then
      call rs%pdda%write_frame(rs%fom%scene, rs%k / cfg%output%every, rs%fom%q, error)
    end if
  end subroutine write_outputs

  !> The quantities of interest finished and written with the step records; the HDF5 output
  !> and the archive closed (renamed into place).
  subroutine close_run(cfg, log, rs, error)
    type(config_t), intent(in) :: cfg
    type(logger_t), intent(inout) :: log
    type(fom_run_state_t), intent(inout) :: rs
    type(error_t), allocatable, intent(out) :: error
    type(qoi_t) :: qoi
    call rs%acc%finish(rs%fom%scene, rs%fom%radius, rs%fom%dt, qoi, error)
    if (allocated(error)) then
      call rs%out%abort(); call rs%pdda%abort(); return
    end if
    call rs%out%close(rs%recs(1:rs%k), error, qoi=qoi)
    if (allocated(error)) then
      call rs%pdda%abort(); return
    end if
    call log%info("quantities of interest (group 'qoi' of the output): t50 / t90 / t100 " // t_text(qoi, 1) // &
      " / " // t_text(qoi, 2) // " / " // t_text(qoi, 3) // " s")
    if (rs%with_pdda) then
      call rs%pdda%close(error)
      if (allocated(error)) return
      call log%info("trajectories (Pedestrian Dynamics Data Archive layout) written to " // &
        trim(cfg%output%pdda_file))
    end if
  end subroutine close_run

  !> t_evac(j) in seconds, "> horizon" where censored
  function t_text(qoi, j) result(t)
    type(qoi_t), intent(in) :: qoi
    integer, intent(in) :: j
    character(len=:), allocatable :: t
    t = str(qoi%t_evac(j), 'f0.3')
    if (qoi%censored(j)) t = "> " // t // " (censored)"
  end function t_text

  !> The printed summary of the run: agents, steps, output, smallest gap, largest KKT
  !> residual, failed steps, iterations and time per step.
  function summary_text(cfg, rs) result(text)
    type(config_t), intent(in) :: cfg
    type(fom_run_state_t), intent(in) :: rs
    character(len=:), allocatable :: text
    character(len=:), allocatable :: gap_text
    integer :: k, n_failed, it_max
    real(wp) :: min_gap, kkt_max, it_mean
    k = rs%k
    associate (recs => rs%recs, fom => rs%fom)
    n_failed = count(.not. recs(1:k)%converged)
    min_gap = huge(1.0_wp); kkt_max = 0; it_max = 0; it_mean = 0
    if (k > 0) then
      min_gap = minval(recs(1:k)%min_gap)
      kkt_max = maxval(recs(1:k)%kkt)
      it_max = maxval(recs(1:k)%iterations)
      it_mean = real(sum(recs(1:k)%iterations), wp) / k
    end if
    ! min_gap stays huge when no contact was ever within the cutoff (nothing close)
    gap_text = str(min_gap)
    if (min_gap == huge(1.0_wp)) gap_text = "none (no contact within the cutoff in any step)"
    text = "summary:" // new_line('a') // &
      "  agents              " // str(fom%n_agents) // new_line('a') // &
      "  steps               " // str(k) // new_line('a') // &
      "  agents left / still inside  " // str(fom%n_agents - fom%n_inside()) // " / " // str(fom%n_inside()) // &
      new_line('a') // &
      "  output file         " // trim(cfg%output%file) // new_line('a') // &
      "  smallest gap seen   " // gap_text // " (radius " // str(fom%radius) // ")" // new_line('a') // &
      "  largest KKT residual " // str(kkt_max) // new_line('a') // &
      "  failed steps        " // str(n_failed) // new_line('a') // &
      "  iterations mean/max " // str(it_mean, 'f0.1') // " / " // str(it_max) // new_line('a') // &
      "  time per step       " // str(sum(recs(1:k)%t_step) / max(k, 1)) // " s (solver " // &
      str(sum(recs(1:k)%t_solve) / max(k, 1)) // " s; with output " // str(rs%t_total / max(k, 1)) // " s)"
    end associate
  end function summary_text

  !> The summary as JSON (keys documented in docs/user-guide.md).
  subroutine write_summary(path, cfg, fom, recs, t_total, error)
    character(len=*), intent(in) :: path
    type(config_t), intent(in) :: cfg
    type(fom_t), intent(in) :: fom
    type(step_record_t), intent(in) :: recs(:)
    real(wp), intent(in) :: t_total
    type(error_t), allocatable, intent(out) :: error
    type(json_writer_t) :: js
    integer :: k
    k = size(recs)
    call js%add("program", "crowd_fom")
    call js%add("input", cfg%source)
    call js%add("solver", trim(cfg%solver%name))
    call js%add("agents", fom%n_agents)
    call js%add("steps", k)
    call js%add("agents_left", fom%n_agents - fom%n_inside())
    call js%add("agents_inside", fom%n_inside())
    call js%add("output_file", trim(cfg%output%file))
    if (k > 0) then
      ! omitted when no contact was ever within the cutoff (see stats/min_gap)
      if (minval(recs%min_gap) < huge(1.0_wp)) call js%add("smallest_gap", minval(recs%min_gap))
      call js%add("largest_kkt_residual", maxval(recs%kkt))
      call js%add("failed_steps", count(.not. recs%converged))
      call js%add("iterations_mean", real(sum(recs%iterations), wp) / k)
      call js%add("iterations_max", maxval(recs%iterations))
      call js%add("resolves", sum(recs%resolves))
      call js%add("solver_time_per_step", sum(recs%t_solve) / k)
      call js%add("factorizations_per_step", real(sum(recs%n_factor), wp) / k)
      call js%add("factor_updates_per_step", real(sum(recs%n_modify), wp) / k)
      call js%add("active_set_changes_per_step", real(sum(recs%n_changes), wp) / k)
      call js%add("fallback_solves", sum(recs%n_fallback))
    else
      call js%add("failed_steps", 0)
    end if
    if (k > 0) call js%add("time_per_step", sum(recs%t_step) / k)
    call js%add("wall_time_per_step_with_output", t_total / max(k, 1))
    call js%add("time_total", t_total)
    call js%add("placement_iterations", fom%placement_iterations)
    call js%write_file(path, error)
  end subroutine write_summary
end module cr_fom_run
