!> The run of crowd_project: exact position projection of the configurations of a request file
!> (docs/model.md#exact-position-projection). The request (written by scripts/pipeline/ml_correct.py; layout
!> in cr_projection_file) names the snapshot database the positions belong to: its configuration
!> gives the scene of each sample (the parameters mapped by cr_param_model, as in every stage), the
!> &solver settings and the &contacts cutoff factor. The configurations of a sample are a
!> trajectory: the first is projected on its own, each later one starts from the projection of the
!> one before (a configuration without overlap: see cr_position_projection for why deep overlaps
!> need such a start). The result file named by the request is written atomically.
module cr_project_run
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_logger, only: logger_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: project_request

contains

  !> Project every configuration of the request file `input` and write the result file it
  !> names (atomically); `summary` (if not empty): also the totals as JSON.
  subroutine project_request(input, summary, log, error)
    use cr_projection_file, only: proj_request_t, proj_result_t, read_proj_request, write_proj_result
    use cr_snapshot_file, only: snap_header_t, read_snap_header
    use cr_namelist_text, only: namelist_text_t
    use cr_config, only: config_t, parse_config
    use cr_param_model, only: param_model_t
    use cr_scene, only: scene_t
    use cr_projection, only: projection_settings_t
    use cr_position_projection, only: position_projection_t, pproj_stats_t
    use cr_qoi, only: max_overlaps
    character(len=*), intent(in) :: input, summary
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    type(proj_request_t) :: req
    type(proj_result_t) :: res
    type(snap_header_t) :: hdr
    type(namelist_text_t) :: t
    type(config_t) :: cfg
    type(param_model_t) :: pm
    type(scene_t) :: scene
    type(projection_settings_t) :: settings
    type(position_projection_t) :: pp
    type(pproj_stats_t) :: st
    integer :: s, j, c, n_conf, n_dof
    integer(8) :: c0, c1, rate
    character(len=:), allocatable :: where

    call log%stage_begin("crowd_project: setup")
    call read_proj_request(input, req, error)
    if (allocated(error)) return
    ! the result and the summary against the request, the database and each other, before
    ! any work (resolved paths: ./db.h5 is db.h5)
    block
      use cr_paths, only: io_paths_t
      type(io_paths_t) :: paths
      call paths%input("request", input)
      call paths%input("attribute 'database'", req%database)
      call paths%output("attribute 'output'", req%output)
      call paths%output("--summary", summary)
      call paths%check("projection request '" // input // "'", error)
      if (allocated(error)) return
    end block
    where = "projection request '" // input // "': attribute 'database'"
    call read_snap_header(req%database, where, hdr, error)
    if (allocated(error)) return
    if (hdr%n_agents /= req%n_agents .or. hdr%n_params /= req%n_params) then
      call set_error(error, where // ": '" // req%database // "' has " // str(hdr%n_agents) // " agents and " // &
        str(hdr%n_params) // " parameter components, the request " // str(req%n_agents) // " and " // &
        str(req%n_params), EXIT_BAD_INPUT); return
    end if
    call t%set_text(req%database // " (attribute config)", hdr%config_text)
    call parse_config(t, cfg, error)
    if (allocated(error)) return
    call pm%init_from_components(hdr%param_names, hdr%n_agents, error)
    if (allocated(error)) then
      call prefix_error(error, "'" // req%database // "': attribute 'param_names'"); return
    end if
    call check_params(input, req, cfg, pm, error)
    if (allocated(error)) return
    settings = cfg%solver
    if (len_trim(req%solver) > 0) settings%name = req%solver
    if (req%tol > 0) settings%tol = req%tol
    call pp%init(settings, cfg%contacts%cutoff_factor, error, refine_max=req%refine_max)
    if (allocated(error)) then
      call prefix_error(error, "projection request '" // input // "'"); return
    end if
    n_dof = 2 * req%n_agents
    n_conf = size(req%positions, 2)
    call res%allocate_for(n_dof, n_conf)
    res%solver = trim(settings%name); res%tol = settings%tol
    res%cutoff_factor = cfg%contacts%cutoff_factor
    call log%info("   " // str(req%n_samples) // " samples x " // str(req%configs_per_sample) // &
      " configurations of " // str(req%n_agents) // " agents (radius " // str(hdr%radius) // "); solver '" // &
      res%solver // "', tol " // str(res%tol) // ", database '" // req%database // "'")
    call log%stage_end()

    call log%stage_begin("crowd_project: projections")
    call log%progress_start()
    call system_clock(c0, rate)
    do s = 1, req%n_samples
      call pm%scene_of(req%params(:, s), cfg, scene, error)
      if (allocated(error)) then
        call prefix_error(error, "scene of sample " // str(s)); return
      end if
      do j = 1, req%configs_per_sample
        c = (s - 1) * req%configs_per_sample + j
        if (j == 1) then
          call pp%project(scene, hdr%radius, req%positions(:, c), res%positions(:, c), st, error)
        else
          call pp%project(scene, hdr%radius, req%positions(:, c), res%positions(:, c), st, error, &
            q_start=res%positions(:, c - 1))
        end if
        if (allocated(error)) then
          call prefix_error(error, "sample " // str(s) // ", configuration " // str(j)); return
        end if
        res%time(c) = st%t_total; res%displacement(c) = st%displacement; res%max_move(c) = st%max_move
        res%depth_in(c) = st%depth_in; res%kkt(c) = st%kkt
        res%n_overlaps(c) = st%n_overlaps; res%n_moved(c) = st%n_moved; res%n_free(c) = st%n_free
        res%solves(c) = st%solves; res%iterations(c) = st%iterations
        res%restarts(c) = st%restarts; res%refines(c) = st%refines
        res%refined(c) = merge(1, 0, st%refined)
        call max_overlaps(scene, hdr%radius, req%positions(:, c:c), res%oaa_before(c), res%oaw_before(c))
        call max_overlaps(scene, hdr%radius, res%positions(:, c:c), res%oaa_after(c), res%oaw_after(c))
      end do
      call log%progress("sample", s, req%n_samples)
    end do
    call system_clock(c1)
    res%t_total = real(c1 - c0, wp) / real(rate, wp)
    call log%stage_end()
    call write_proj_result(req, res, error)
    if (allocated(error)) return
    call log%info("projected " // str(n_conf) // " configurations: " // str(count(res%n_overlaps > 0)) // &
      " had overlaps (deepest " // str(maxval(res%depth_in), "es9.2") // " m), deepest after " // &
      str(max(maxval(res%oaa_after), maxval(res%oaw_after)), "es9.2") // " m; projection time " // &
      str(sum(res%time) / n_conf, "es9.2") // " s per configuration; refinement short of its tolerance in " // &
      str(count(res%refined == 0)) // "; wrote " // req%output)
    if (len(summary) > 0) call write_summary(summary, req, res, error)
  end subroutine project_request

  !> Every sample's parameters give a valid scene (the checks of an input file, e.g. an exit
  !> no wider than the hall and > 0), before any work: an input error naming the sample.
  subroutine check_params(input, req, cfg, pm, error)
    use cr_projection_file, only: proj_request_t
    use cr_config, only: config_t
    use cr_param_model, only: param_model_t
    use cr_config_check, only: check_config
    character(len=*), intent(in) :: input
    type(proj_request_t), intent(in) :: req
    type(config_t), intent(in) :: cfg
    type(param_model_t), intent(in) :: pm
    type(error_t), allocatable, intent(out) :: error
    type(config_t) :: c
    real(wp), allocatable :: speeds(:)
    integer :: s
    do s = 1, req%n_samples
      c = cfg
      allocate(speeds(req%n_agents))
      speeds = cfg%agents%speed
      call pm%apply(req%params(:, s), c, speeds)
      deallocate(speeds)
      call check_config(c, error)
      if (allocated(error)) then
        error%code = EXIT_BAD_INPUT
        call prefix_error(error, "projection request '" // input // "': dataset 'params': sample " // str(s) // &
          " gives no valid scene")
        return
      end if
    end do
  end subroutine check_params

  !> Totals as JSON.
  subroutine write_summary(path, req, res, error)
    use cr_json, only: json_writer_t
    use cr_projection_file, only: proj_request_t, proj_result_t
    character(len=*), intent(in) :: path
    type(proj_request_t), intent(in) :: req
    type(proj_result_t), intent(in) :: res
    type(error_t), allocatable, intent(out) :: error
    type(json_writer_t) :: js
    call js%add("program", "crowd_project")
    call js%add("request", req%path)
    call js%add("output", req%output)
    call js%add("solver", res%solver)
    call js%add("tol", res%tol)
    call js%add("configurations", size(res%time))
    call js%add("configurations_with_overlap", count(res%n_overlaps > 0))
    call js%add("deepest_overlap_before", maxval(res%depth_in))
    call js%add("deepest_overlap_agents_after", maxval(res%oaa_after))
    call js%add("deepest_overlap_walls_after", maxval(res%oaw_after))
    call js%add("time_per_configuration", sum(res%time) / size(res%time))
    call js%add("time_total", res%t_total)
    call js%add("refinement_short", count(res%refined == 0))
    call js%write_file(path, error)
  end subroutine write_summary
end module cr_project_run
