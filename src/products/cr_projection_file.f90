!> The files of the position projection (crowd_project, docs/file-formats.md):
!> - the request (schema "crowdrom-projreq", version 1), written by scripts/pipeline/ml_correct.py:
!>   root attributes `database` (snapshot database the positions belong to: its configuration
!>   gives the scene, &solver and &contacts), `output` (result file to write), `n_agents`,
!>   `configs_per_sample`, `solver` ('' = the database's &solver name), `tol` (0 = the
!>   database's &solver tol), `refine_max` (refinement projections at most, >= 0; optional,
!>   default 50); datasets `positions` [2 n_a, n_conf] (h5py [n_conf, 2 n_a]) and
!>   `params` [n_mu, n_S] (h5py [n_S, n_mu]), n_conf = n_S * configs_per_sample, the
!>   configurations of sample s being the columns (s - 1) * configs_per_sample + 1 ..;
!> - the result (schema "crowdrom-projected", version 2; version 1 also had `grows`, always 0),
!>   written atomically: root attributes
!>   `request`, `database`, `solver`, `tol`, `cutoff_factor`, `n_agents`, `n_samples`,
!>   `configs_per_sample`, `t_total`; datasets `positions` [2 n_a, n_conf] (the projected
!>   configurations) and per configuration [n_conf]: `time` (s), `displacement`
!>   (|q_out - q_in|_2, m), `max_move` (m), `depth_in` (deepest overlap of the input, m),
!>   `overlap_agents_before`, `overlap_walls_before`, `overlap_agents_after`,
!>   `overlap_walls_after` (deepest agent-agent / agent-obstacle overlap, 0: none, m), `kkt`,
!>   `n_overlaps`, `n_moved`, `n_free`, `solves`, `iterations`, `restarts`, `refines`
!>   (refinement projections), `refined` (1: the refinement met its tolerance).
module cr_projection_file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_h5file, only: h5file_t
  use cr_product_check, only: check_schema, need_finite, need_dims, product_error
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: PROJREQ_SCHEMA, PROJRES_SCHEMA, proj_request_t, proj_result_t, read_proj_request, &
    write_proj_result

  character(len=*), parameter :: PROJREQ_SCHEMA = "crowdrom-projreq"
  character(len=*), parameter :: PROJRES_SCHEMA = "crowdrom-projected"
  !> request versions read; result version written (2: without the always-zero `grows`)
  integer, parameter :: PROJREQ_VERSIONS_READ(1) = [1]
  integer, parameter :: PROJRES_SCHEMA_VERSION = 2

  !> A projection request.
  type :: proj_request_t
    character(len=:), allocatable :: path, database, output, solver
    integer :: n_agents = 0, configs_per_sample = 0, n_samples = 0, n_params = 0, refine_max = 0
    real(wp) :: tol = 0
    !> positions [2 n_a, n_conf]; parameters [n_mu, n_S]
    real(wp), allocatable :: positions(:,:), params(:,:)
  end type proj_request_t

  !> The result of a request (per configuration c = 1..n_conf).
  type :: proj_result_t
    character(len=:), allocatable :: solver
    real(wp) :: tol = 0, cutoff_factor = 0, t_total = 0
    !> projected positions [2 n_a, n_conf]
    real(wp), allocatable :: positions(:,:)
    !> [n_conf]
    real(wp), allocatable :: time(:), displacement(:), max_move(:), depth_in(:), oaa_before(:), &
      oaw_before(:), oaa_after(:), oaw_after(:), kkt(:)
    integer, allocatable :: n_overlaps(:), n_moved(:), n_free(:), solves(:), iterations(:), &
      restarts(:), refines(:), refined(:)
  contains
    procedure :: allocate_for
  end type proj_result_t

contains

  !> Read and validate a request: schema and version, attributes in range, dataset shapes
  !> against the attributes, finite positions and parameters, an output that is not the
  !> request itself. Input errors (code 2) name the file and the item.
  subroutine read_proj_request(path, req, error)
    character(len=*), intent(in) :: path
    type(proj_request_t), intent(out) :: req
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    integer(i8), allocatable :: d(:)
    integer :: version
    req%path = path
    call h5%open(path, e2)
    if (allocated(e2)) then
      ! the message is copied out of e2 before error (intent(out) in set_error) is allocated
      call set_error(error, "'" // path // "': cannot open the projection request (" // e2%message // ")", EXIT_BAD_INPUT)
      return
    end if
    call body(error)
    call h5%close(e2)
    if (.not. allocated(error) .and. allocated(e2)) call move_alloc(e2, error)
  contains
    subroutine body(error)
      type(error_t), allocatable, intent(out) :: error
      call check_schema(h5, path, PROJREQ_SCHEMA, PROJREQ_VERSIONS_READ, "projection request", version, error)
      if (allocated(error)) return
      call h5%read_attr("/", "database", req%database, error); if (allocated(error)) goto 9
      call h5%read_attr("/", "output", req%output, error); if (allocated(error)) goto 9
      call h5%read_attr("/", "solver", req%solver, error); if (allocated(error)) goto 9
      call h5%read_attr("/", "tol", req%tol, error); if (allocated(error)) goto 9
      call h5%read_attr("/", "n_agents", req%n_agents, error); if (allocated(error)) goto 9
      call h5%read_attr("/", "configs_per_sample", req%configs_per_sample, error); if (allocated(error)) goto 9
      ! optional: 50 refinement projections when absent
      call h5%read_attr("/", "refine_max", req%refine_max, error)
      if (allocated(error)) then
        deallocate(error); req%refine_max = 50
      end if
      if (len_trim(req%database) == 0 .or. len_trim(req%output) == 0) then
        call product_error(path, "attributes 'database' and 'output' must name files", error); return
      end if
      if (trim(req%output) == trim(path)) then
        call product_error(path, "attribute 'output' names the request itself", error); return
      end if
      if (req%n_agents < 1 .or. req%configs_per_sample < 1) then
        call product_error(path, "attributes 'n_agents' = " // str(req%n_agents) // " and 'configs_per_sample' = " // &
          str(req%configs_per_sample) // " must be >= 1", error); return
      end if
      if (req%refine_max < 0) then
        call product_error(path, "attribute 'refine_max' = " // str(req%refine_max) // " must be >= 0", error); return
      end if
      if (.not. (req%tol >= 0 .and. req%tol < 1)) then
        call product_error(path, "attribute 'tol' = " // str(req%tol) // " outside [0, 1) (0: the database's)", error)
        return
      end if
      call h5%get_dims("params", d, error); if (allocated(error)) goto 9
      if (size(d) /= 2) then
        call product_error(path, "dataset 'params' must be 2-D [n_mu, n_S]", error); return
      end if
      req%n_params = int(d(1)); req%n_samples = int(d(2))
      if (req%n_samples < 1) then
        call product_error(path, "dataset 'params' has no sample", error); return
      end if
      call need_dims(h5, path, "positions", [int(2 * req%n_agents, i8), &
        int(req%n_samples, i8) * req%configs_per_sample], "n_agents, configs_per_sample and params", error)
      if (allocated(error)) return
      call h5%read("params", req%params, error); if (allocated(error)) goto 9
      call h5%read("positions", req%positions, error); if (allocated(error)) goto 9
      call need_finite(path, "params", req%params, error); if (allocated(error)) return
      call need_finite(path, "positions", req%positions, error)
      return
9     error%code = EXIT_BAD_INPUT
      call prefix_error(error, "projection request '" // path // "'")
    end subroutine body
  end subroutine read_proj_request

  !> Room for n_dof x n_conf results.
  subroutine allocate_for(this, n_dof, n_conf)
    class(proj_result_t), intent(inout) :: this
    integer, intent(in) :: n_dof, n_conf
    allocate(this%positions(n_dof, n_conf))
    allocate(this%time(n_conf), this%displacement(n_conf), this%max_move(n_conf), this%depth_in(n_conf), &
      this%oaa_before(n_conf), this%oaw_before(n_conf), this%oaa_after(n_conf), this%oaw_after(n_conf), &
      this%kkt(n_conf))
    allocate(this%n_overlaps(n_conf), this%n_moved(n_conf), this%n_free(n_conf), this%solves(n_conf), &
      this%iterations(n_conf), this%restarts(n_conf), this%refines(n_conf), &
      this%refined(n_conf))
  end subroutine allocate_for

  !> Write the result of `req` to req%output (a temporary renamed when complete: an earlier
  !> file of that name stays untouched when the write fails).
  subroutine write_proj_result(req, res, error)
    type(proj_request_t), intent(in) :: req
    type(proj_result_t), intent(in) :: res
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    call h5%create(req%output, error)
    if (allocated(error)) return
    call body(error)
    if (allocated(error)) then
      call h5%abort(); return
    end if
    call h5%commit(error)
  contains
    subroutine body(error)
      type(error_t), allocatable, intent(out) :: error
      call h5%write_attr("/", "schema", PROJRES_SCHEMA, error); if (allocated(error)) return
      call h5%write_attr("/", "schema_version", PROJRES_SCHEMA_VERSION, error); if (allocated(error)) return
      call h5%write_attr("/", "request", req%path, error); if (allocated(error)) return
      call h5%write_attr("/", "database", req%database, error); if (allocated(error)) return
      call h5%write_attr("/", "solver", res%solver, error); if (allocated(error)) return
      call h5%write_attr("/", "tol", res%tol, error); if (allocated(error)) return
      call h5%write_attr("/", "cutoff_factor", res%cutoff_factor, error); if (allocated(error)) return
      call h5%write_attr("/", "refine_max", req%refine_max, error); if (allocated(error)) return
      call h5%write_attr("/", "n_agents", req%n_agents, error); if (allocated(error)) return
      call h5%write_attr("/", "n_samples", req%n_samples, error); if (allocated(error)) return
      call h5%write_attr("/", "configs_per_sample", req%configs_per_sample, error); if (allocated(error)) return
      call h5%write_attr("/", "t_total", res%t_total, error); if (allocated(error)) return
      call h5%write_attr("/", "units", "length: m, time: s", error); if (allocated(error)) return
      call h5%write("positions", res%positions, error); if (allocated(error)) return
      call h5%write("time", res%time, error); if (allocated(error)) return
      call h5%write("displacement", res%displacement, error); if (allocated(error)) return
      call h5%write("max_move", res%max_move, error); if (allocated(error)) return
      call h5%write("depth_in", res%depth_in, error); if (allocated(error)) return
      call h5%write("overlap_agents_before", res%oaa_before, error); if (allocated(error)) return
      call h5%write("overlap_walls_before", res%oaw_before, error); if (allocated(error)) return
      call h5%write("overlap_agents_after", res%oaa_after, error); if (allocated(error)) return
      call h5%write("overlap_walls_after", res%oaw_after, error); if (allocated(error)) return
      call h5%write("kkt", res%kkt, error); if (allocated(error)) return
      call h5%write("n_overlaps", res%n_overlaps, error); if (allocated(error)) return
      call h5%write("n_moved", res%n_moved, error); if (allocated(error)) return
      call h5%write("n_free", res%n_free, error); if (allocated(error)) return
      call h5%write("solves", res%solves, error); if (allocated(error)) return
      call h5%write("iterations", res%iterations, error); if (allocated(error)) return
      call h5%write("restarts", res%restarts, error); if (allocated(error)) return
      call h5%write("refines", res%refines, error); if (allocated(error)) return
      call h5%write("refined", res%refined, error)
    end subroutine body
  end subroutine write_proj_result
end module cr_projection_file
