!> Configuration of crowd_predict (prediction for new parameters): one namelist group
!> &predict. A ROM file (crowd_offline, version 3: it holds the study) and a list of queries
!> (parameters) -> the quantities of interest per query (and the positions on request).
!>
!> model = 'rom' runs one reduced setting, as one entry of crowd_rom's &sweep (n, r, hyper,
!> contacts, m_v, m_b, m_d, correction) with the reduced solver `solver`; model = 'exact' runs
!> the full model of the study's configuration (its &solver) on the same list; model =
!> 'positions' runs nothing: the trajectories are given in the HDF5 params_file (dataset
!> `positions`, query k's frames 0..n_steps in rows (k - 1)(n_steps + 1) + 1.., the layout of the
!> product's positions) and only measured (the ML correction's QoIs, scripts/pipeline/ml_correct.py).
!> `label` (default: derived from the model) names the model in the product.
!>
!> The list: `params_file` (a text file, a header naming the columns then one query per row,
!> or an HDF5 file with a dataset `params_dataset` [n_queries rows, one column per component]
!> and its attribute `param_names`), or else n_queries queries drawn with `seed`: parameter k
!> of the study from dist(k) ('uniform' on [dist_a, dist_b]; 'normal' of mean dist_a and
!> standard deviation dist_b; 'lognormal': exp of a normal of mean dist_a and deviation dist_b;
!> 'truncnormal': normal(dist_a, dist_b) restricted to [dist_lo, dist_hi]); a parameter whose
!> dist(k) is '' is uniform in the study's training box.
module cr_predict_config
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, problems_t
  use cr_strings, only: str
  use cr_reduced_solver, only: is_reduced_solver, known_reduced_solvers
  use cr_namelist_text, only: namelist_text_t, nml_status
  use cr_paths, only: io_paths_t
  use cr_sane, only: need_sane
  use cr_hyper_factory, only: hyper_known, hyper_name_list
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: predict_cfg_t, read_predict, check_predict, check_predict_paths, predict_echo, MAX_DIST, DIST_NAMES

  integer, parameter :: MAX_PATH = 512
  !> largest number of distributions (one per study parameter)
  integer, parameter :: MAX_DIST = 16
  character(len=*), parameter :: DIST_NAMES(4) = [character(len=11) :: 'uniform', 'normal', 'lognormal', 'truncnormal']
  !> largest magnitude of a distribution's numbers
  real(wp), parameter :: MAX_DIST_VALUE = 1.0e6_wp
  !> smallest probability of a truncnormal's window (the sampler draws until inside)
  real(wp), parameter :: MIN_MASS = 1.0e-3_wp
  !> unset real
  real(wp), parameter :: UNSET = -huge(1.0_wp)

  !> &predict.
  type :: predict_cfg_t
    !> ROM file (crowd_offline, version 3) and the QoI product written
    character(len=MAX_PATH) :: rom_file = ''
    character(len=MAX_PATH) :: output = ''
    !> 'rom' (one reduced setting), 'exact' (the full model) or 'positions' (given trajectories)
    character(len=16) :: model = 'rom'
    !> the model's name in the product ('' = derived from the model and its setting)
    character(len=128) :: label = ''
    !> the reduced setting (as one entry of crowd_rom's &sweep) and the reduced solver
    integer :: n = 0, r = 0
    character(len=8) :: hyper = 'eq'
    character(len=8) :: contacts = 'cone'
    integer :: m_v = 0, m_b = 0, m_d = 0
    character(len=8) :: correction = 'none'
    character(len=8) :: solver = 'dual'
    !> the list from a file: text or HDF5 (dataset params_dataset)
    character(len=MAX_PATH) :: params_file = ''
    character(len=64) :: params_dataset = 'params'
    !> or drawn: n_queries queries with seed, one distribution per study parameter
    integer :: n_queries = 0
    integer :: seed = 1
    character(len=16) :: dist_param(MAX_DIST) = ''
    character(len=11) :: dist(MAX_DIST) = ''
    real(wp) :: dist_a(MAX_DIST) = UNSET, dist_b(MAX_DIST) = UNSET
    real(wp) :: dist_lo(MAX_DIST) = UNSET, dist_hi(MAX_DIST) = UNSET
    !> queries outside the training box: 'flag' (computed, flagged) or 'refuse' (nothing runs)
    character(len=8) :: out_of_box = 'flag'
    !> also write every query's positions
    logical :: trajectories = .false.
  end type predict_cfg_t

contains

  !> Read &predict (required).
  subroutine read_predict(t, c, error)
    type(namelist_text_t), intent(in) :: t
    type(predict_cfg_t), intent(inout) :: c
    type(error_t), allocatable, intent(out) :: error
    character(len=MAX_PATH) :: rom_file, output, params_file
    character(len=64) :: params_dataset
    character(len=16) :: model
    character(len=128) :: label
    character(len=8) :: hyper, contacts, correction, solver, out_of_box
    integer :: n, r, m_v, m_b, m_d, n_queries, seed
    character(len=16) :: dist_param(MAX_DIST)
    character(len=11) :: dist(MAX_DIST)
    real(wp), dimension(MAX_DIST) :: dist_a, dist_b, dist_lo, dist_hi
    logical :: trajectories
    namelist /predict/ rom_file, output, model, label, n, r, hyper, contacts, m_v, m_b, m_d, correction, solver, &
      params_file, params_dataset, n_queries, seed, dist_param, dist, dist_a, dist_b, dist_lo, dist_hi, &
      out_of_box, trajectories
    integer :: ios
    character(len=512) :: msg
    if (.not. t%has_group('predict')) then
      call set_error(error, t%path // ": namelist group &predict is missing", EXIT_BAD_INPUT); return
    end if
    rom_file = c%rom_file; output = c%output; model = c%model; label = c%label; n = c%n; r = c%r; hyper = c%hyper
    contacts = c%contacts; m_v = c%m_v; m_b = c%m_b; m_d = c%m_d; correction = c%correction; solver = c%solver
    params_file = c%params_file; params_dataset = c%params_dataset; n_queries = c%n_queries; seed = c%seed
    dist_param = c%dist_param; dist = c%dist; dist_a = c%dist_a; dist_b = c%dist_b; dist_lo = c%dist_lo
    dist_hi = c%dist_hi; out_of_box = c%out_of_box; trajectories = c%trajectories
    msg = ''
    read(t%lines, nml=predict, iostat=ios, iomsg=msg)
    call nml_status(t, 'predict', ios, msg, error); if (allocated(error)) return
    c%rom_file = rom_file; c%output = output; c%model = model; c%label = label; c%n = n; c%r = r; c%hyper = hyper
    c%contacts = contacts; c%m_v = m_v; c%m_b = m_b; c%m_d = m_d; c%correction = correction; c%solver = solver
    c%params_file = params_file; c%params_dataset = params_dataset; c%n_queries = n_queries; c%seed = seed
    c%dist_param = dist_param; c%dist = dist; c%dist_a = dist_a; c%dist_b = dist_b; c%dist_lo = dist_lo
    c%dist_hi = dist_hi; c%out_of_box = out_of_box; c%trajectories = trajectories
  end subroutine read_predict

  !> Validate &predict (ranges and consistency; the parameter names are checked against the
  !> study once the ROM file is read); every problem reported at once.
  subroutine check_predict(path, c, error)
    character(len=*), intent(in) :: path
    type(predict_cfg_t), intent(in) :: c
    type(error_t), allocatable, intent(out) :: error
    type(problems_t) :: probs
    integer :: k
    character(len=:), allocatable :: d
    do k = 1, MAX_DIST
      if (c%dist_a(k) /= UNSET) call need_sane(probs, c%dist_a(k), "&predict: dist_a(" // str(k) // ")", MAX_DIST_VALUE)
      if (c%dist_b(k) /= UNSET) call need_sane(probs, c%dist_b(k), "&predict: dist_b(" // str(k) // ")", MAX_DIST_VALUE)
      if (c%dist_lo(k) /= UNSET) call need_sane(probs, c%dist_lo(k), "&predict: dist_lo(" // str(k) // ")", &
        MAX_DIST_VALUE)
      if (c%dist_hi(k) /= UNSET) call need_sane(probs, c%dist_hi(k), "&predict: dist_hi(" // str(k) // ")", &
        MAX_DIST_VALUE)
    end do
    if (probs%n > 0) then
      call probs%to_error(path, error); return
    end if
    call probs%need(len_trim(c%rom_file) > 0, "&predict: rom_file must be given")
    call probs%need(len_trim(c%output) > 0, "&predict: output must be given")
    call probs%need(c%model == 'rom' .or. c%model == 'exact' .or. c%model == 'positions', "&predict: model must " // &
      "be 'rom', 'exact' or 'positions' (got '" // trim(c%model) // "')")
    call probs%need(c%model /= 'positions' .or. len_trim(c%params_file) > 0, "&predict: model = 'positions' " // &
      "needs params_file (an HDF5 file with the parameters and the dataset 'positions')")
    call probs%need(c%model /= 'positions' .or. .not. c%trajectories, "&predict: model = 'positions' writes " // &
      "no trajectories (they are its input)")
    if (c%model == 'rom') then
      call probs%need(c%n >= 1 .and. c%r >= 0, "&predict: model = 'rom' needs n >= 1 and r >= 0 (a pair (N, R) of " // &
        "the ROM file)")
      call probs%need(hyper_known(c%hyper), "&predict: hyper must be one of " // hyper_name_list() // " (got '" // &
        trim(c%hyper) // "')")
      call probs%need(c%contacts == 'cone' .or. c%contacts == 'online', "&predict: contacts must be 'cone' or " // &
        "'online' (got '" // trim(c%contacts) // "')")
      call probs%need(c%contacts /= 'online' .or. c%hyper == 'none', "&predict: contacts = 'online' needs " // &
        "hyper = 'none'")
      call probs%need(c%m_v >= 0 .and. c%m_b >= 0 .and. c%m_d >= 0, "&predict: m_v, m_b, m_d must be >= 0 (0: defaults)")
      call probs%need(c%correction == 'none' .or. c%correction == 'local', "&predict: correction must be 'none' " // &
        "or 'local' (got '" // trim(c%correction) // "')")
      call probs%need(is_reduced_solver(c%solver), "&predict: solver must be one of " // known_reduced_solvers // &
        " (got '" // trim(c%solver) // "')")
    end if
    call probs%need(c%out_of_box == 'flag' .or. c%out_of_box == 'refuse', "&predict: out_of_box must be 'flag' " // &
      "or 'refuse' (got '" // trim(c%out_of_box) // "')")
    call probs%need(len_trim(c%params_file) > 0 .neqv. c%n_queries > 0, "&predict: give either params_file or " // &
      "n_queries >= 1 (a sampling rule), not both")
    call probs%need(c%n_queries >= 0, "&predict: n_queries must be >= 0")
    call probs%need(len_trim(c%params_dataset) > 0, "&predict: params_dataset must not be empty")
    do k = 1, MAX_DIST
      if (len_trim(c%dist_param(k)) == 0 .and. len_trim(c%dist(k)) == 0) cycle
      d = "&predict: dist(" // str(k) // ")"
      call probs%need(len_trim(c%params_file) == 0, d // ": a distribution needs the sampling rule (no params_file)")
      call probs%need(len_trim(c%dist_param(k)) > 0, "&predict: dist_param(" // str(k) // ") must name a parameter " // &
        "of the study")
      call probs%need(any(c%dist(k) == DIST_NAMES), d // " must be 'uniform', 'normal', 'lognormal' or " // &
        "'truncnormal' (got '" // trim(c%dist(k)) // "')")
      call probs%need(c%dist_a(k) /= UNSET .and. c%dist_b(k) /= UNSET, d // " needs dist_a and dist_b")
      if (c%dist_a(k) == UNSET .or. c%dist_b(k) == UNSET) cycle
      select case (trim(c%dist(k)))
      case ('uniform')
        call probs%need(c%dist_a(k) < c%dist_b(k), d // " = 'uniform' needs dist_a < dist_b (got " // &
          str(c%dist_a(k)) // ", " // str(c%dist_b(k)) // ")")
      case ('normal', 'lognormal', 'truncnormal')
        call probs%need(c%dist_b(k) > 0, d // ": the spread dist_b must be > 0 (got " // str(c%dist_b(k)) // ")")
      end select
      if (c%dist(k) == 'truncnormal') then
        call probs%need(c%dist_lo(k) /= UNSET .and. c%dist_hi(k) /= UNSET, d // " = 'truncnormal' needs dist_lo " // &
          "and dist_hi")
        if (c%dist_lo(k) /= UNSET .and. c%dist_hi(k) /= UNSET .and. c%dist_b(k) > 0) then
          call probs%need(c%dist_lo(k) < c%dist_hi(k), d // ": dist_lo must be < dist_hi")
          ! the rejection sampler needs a window of reasonable probability
          call probs%need(window_mass(c%dist_a(k), c%dist_b(k), c%dist_lo(k), c%dist_hi(k)) >= MIN_MASS, d // &
            ": the normal distribution puts less than " // str(MIN_MASS) // " of its mass in [dist_lo, dist_hi]")
        end if
      end if
      if (any(c%dist_param(k) == c%dist_param(1:k - 1))) call probs%need(.false., "&predict: dist_param(" // &
        str(k) // ") = '" // trim(c%dist_param(k)) // "' is given twice")
    end do
    call probs%to_error(path, error)
  end subroutine check_predict

  !> Probability that a normal(a, b) deviate lies in [lo, hi].
  pure real(wp) function window_mass(a, b, lo, hi) result(p)
    real(wp), intent(in) :: a, b, lo, hi
    p = 0.5_wp * (erf((hi - a) / (b * sqrt(2.0_wp))) - erf((lo - a) / (b * sqrt(2.0_wp))))
  end function window_mass

  !> The outputs (&predict output, --summary) checked against the inputs, before any work.
  subroutine check_predict_paths(input, summary, c, error)
    character(len=*), intent(in) :: input, summary
    type(predict_cfg_t), intent(in) :: c
    type(error_t), allocatable, intent(out) :: error
    type(io_paths_t) :: paths
    call paths%input("file", input)
    call paths%input("&predict rom_file", c%rom_file)
    call paths%input("&predict params_file", c%params_file)
    call paths%output("&predict output", c%output)
    call paths%output("--summary", summary)
    call paths%check(input, error)
  end subroutine check_predict_paths

  !> &predict as re-readable namelist text.
  function predict_echo(c) result(s)
    type(predict_cfg_t), intent(in) :: c
    character(len=:), allocatable :: s
    character(len=*), parameter :: nl = new_line('a')
    integer :: k
    s = "&predict rom_file = '" // trim(c%rom_file) // "', output = '" // trim(c%output) // "', model = '" // &
      trim(c%model) // "', label = '" // trim(c%label) // "'," // nl // "  n = " // str(c%n) // ", r = " // &
      str(c%r) // ", hyper = '" // trim(c%hyper) // &
      "', contacts = '" // trim(c%contacts) // "', m_v = " // str(c%m_v) // ", m_b = " // str(c%m_b) // ", m_d = " // &
      str(c%m_d) // ", correction = '" // trim(c%correction) // "', solver = '" // trim(c%solver) // "'," // nl // &
      "  params_file = '" // trim(c%params_file) // "', params_dataset = '" // trim(c%params_dataset) // &
      "', n_queries = " // str(c%n_queries) // ", seed = " // str(c%seed) // ", out_of_box = '" // &
      trim(c%out_of_box) // "', trajectories = " // trim(merge(".true. ", ".false.", c%trajectories))
    do k = 1, MAX_DIST
      if (len_trim(c%dist_param(k)) == 0) cycle
      s = s // "," // nl // "  dist_param(" // str(k) // ") = '" // trim(c%dist_param(k)) // "', dist(" // str(k) // &
        ") = '" // trim(c%dist(k)) // "', dist_a(" // str(k) // ") = " // str(c%dist_a(k), "es23.16") // &
        ", dist_b(" // str(k) // ") = " // str(c%dist_b(k), "es23.16")
      if (c%dist(k) == 'truncnormal') s = s // ", dist_lo(" // str(k) // ") = " // str(c%dist_lo(k), "es23.16") // &
        ", dist_hi(" // str(k) // ") = " // str(c%dist_hi(k), "es23.16")
    end do
    s = s // " /" // nl
  end function predict_echo
end module cr_predict_config
