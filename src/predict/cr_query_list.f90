!> The list of queries (parameter vectors) of crowd_predict: read from a text or HDF5 file, or
!> drawn by a sampling rule, then validated against the study (component names, finite values,
!> a valid scene) and flagged where outside the training box.
!>
!> Text file: '#' starts a comment; the first other line is the header, the component names
!> of the study separated by commas or blanks, in any order ("l_exit, speed" or, for the
!> per-agent parameter 'speeds', speed_1 .. speed_N); then one query per line, one value per
!> column. HDF5 file: dataset `params_dataset` with one row per query (h5py shape
!> [n_queries, n_columns]) and the attribute `param_names` (the header, comma-separated) on the
!> dataset or on the root.
!>
!> Sampling: query k (1-based) uses its own random stream (seed, k) of cr_random, so the list
!> depends only on the seed and never on the number of ranks; each component of a parameter
!> is drawn independently from the parameter's distribution (uniform in the training box by
!> default), except the population's seed component (speed_seed), an integer uniform on its
!> range as in the study's sampling.
module cr_query_list
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_random, only: rng_t
  use cr_h5file, only: h5file_t
  use cr_sampling, only: param_space_t
  use cr_config, only: config_t
  use cr_predict_config, only: predict_cfg_t, MAX_DIST
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: query_list_t, load_queries

  !> relative tolerance of the training-box test (as crowd_rom's extrapolation flag)
  real(wp), parameter :: BOX_TOL = 1.0e-12_wp
  !> longest accepted line of a text list
  integer, parameter :: MAX_LINE = 65536

  !> The queries of a run.
  type :: query_list_t
    integer :: n = 0
    !> parameter values [n_expanded, n] (the study's component order)
    real(wp), allocatable :: mu(:,:)
    !> outside the study's training box [n]
    logical, allocatable :: out_of_box(:)
    !> where the list came from (for the log and the product)
    character(len=:), allocatable :: source
  end type query_list_t

contains

  !> The queries of &predict for the study's parameter space `space` and reference
  !> configuration `cfg`; `where` starts messages ("input.nml: &predict"). Input errors code 2.
  subroutine load_queries(c, space, cfg, where, list, error)
    type(predict_cfg_t), intent(in) :: c
    type(param_space_t), intent(in) :: space
    type(config_t), intent(in) :: cfg
    character(len=*), intent(in) :: where
    type(query_list_t), intent(out) :: list
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: what
    integer :: k
    if (len_trim(c%params_file) > 0) then
      what = where // ": params_file '" // trim(c%params_file) // "'"
      if (is_hdf5(trim(c%params_file))) then
        call read_h5_list(trim(c%params_file), trim(c%params_dataset), space, what, list, error)
      else
        call read_text_list(trim(c%params_file), space, what, list, error)
      end if
      if (allocated(error)) return
      list%source = "file " // trim(c%params_file)
    else
      what = where // ": sampling"
      call draw_list(c, space, where, list, error)
      if (allocated(error)) return
      list%source = "sampling, seed " // str(c%seed)
    end if
    if (list%n == 0) then
      call set_error(error, what // ": the list holds no query", EXIT_BAD_INPUT); return
    end if
    do k = 1, list%n
      call space%check_values(list%mu(:, k), cfg, what // ": query " // str(k), error)
      if (allocated(error)) then
        error%code = EXIT_BAD_INPUT; return
      end if
    end do
    allocate(list%out_of_box(list%n))
    do k = 1, list%n
      list%out_of_box(k) = any(list%mu(:, k) < space%lo - BOX_TOL * abs(space%lo)) .or. &
        any(list%mu(:, k) > space%hi + BOX_TOL * abs(space%hi))
    end do
  end subroutine load_queries

  !> Whether `path` starts with the HDF5 signature.
  logical function is_hdf5(path)
    character(len=*), intent(in) :: path
    character(len=8) :: sig
    integer :: u, ios
    is_hdf5 = .false.
    open(newunit=u, file=path, access='stream', form='unformatted', status='old', action='read', iostat=ios)
    if (ios /= 0) return
    read(u, iostat=ios) sig
    close(u)
    is_hdf5 = ios == 0 .and. sig == char(137) // "HDF" // char(13) // char(10) // char(26) // char(10)
  end function is_hdf5

  !> Column -> component map of a header (names separated by commas or blanks): col(j) is the
  !> component of column j; every component must appear exactly once.
  subroutine map_header(header, space, what, col, error)
    character(len=*), intent(in) :: header, what
    type(param_space_t), intent(in) :: space
    integer, allocatable, intent(out) :: col(:)
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: names(:), known(:)
    integer :: j, m
    logical, allocatable :: seen(:)
    call split(space%component_names(), known)
    call split(header, names)
    allocate(col(size(names)), seen(size(known)))
    seen = .false.
    do j = 1, size(names)
      col(j) = findloc(known, names(j), 1)
      if (col(j) == 0) then
        call set_error(error, what // ": column '" // trim(names(j)) // "' is not a parameter of the study (" // &
          "components: " // space%component_names() // ")", EXIT_BAD_INPUT); return
      end if
      if (seen(col(j))) then
        call set_error(error, what // ": column '" // trim(names(j)) // "' is given twice", EXIT_BAD_INPUT); return
      end if
      seen(col(j)) = .true.
    end do
    m = count(.not. seen)
    if (m > 0) then
      j = findloc(seen, .false., 1)
      call set_error(error, what // ": " // str(m) // " component(s) of the study have no column (first: '" // &
        trim(known(j)) // "'; the header must name " // str(size(known)) // " columns: " // &
        space%component_names() // ")", EXIT_BAD_INPUT)
    end if
  end subroutine map_header

  !> Tokens of s separated by commas and blanks.
  subroutine split(s, tok)
    character(len=*), intent(in) :: s
    character(len=:), allocatable, intent(out) :: tok(:)
    integer :: i, n, i0, pass, w
    w = 1
    do pass = 1, 2
      n = 0; i0 = 0
      do i = 1, len(s) + 1
        if (i <= len(s)) then
          if (.not. is_sep(s(i:i))) then
            if (i0 == 0) i0 = i
            cycle
          end if
        end if
        if (i0 > 0) then
          n = n + 1
          if (pass == 1) w = max(w, i - i0)
          if (pass == 2) tok(n) = s(i0:i - 1)
          i0 = 0
        end if
      end do
      if (pass == 1) allocate(character(len=w) :: tok(n))
    end do
  contains
    pure logical function is_sep(ch)
      character, intent(in) :: ch
      is_sep = ch == ',' .or. ch == ' ' .or. ch == char(9) .or. ch == char(13)
    end function is_sep
  end subroutine split

  !> A text list (module header).
  subroutine read_text_list(path, space, what, list, error)
    character(len=*), intent(in) :: path, what
    type(param_space_t), intent(in) :: space
    type(query_list_t), intent(inout) :: list
    type(error_t), allocatable, intent(out) :: error
    character(len=MAX_LINE) :: line
    character(len=:), allocatable :: tok(:)
    integer, allocatable :: col(:)
    real(wp), allocatable :: mu(:,:)
    real(wp) :: x
    integer :: u, ios, lineno, j
    character(len=256) :: msg
    open(newunit=u, file=path, status='old', action='read', iostat=ios, iomsg=msg)
    if (ios /= 0) then
      call set_error(error, what // ": cannot open (" // trim(msg) // ")", EXIT_BAD_INPUT); return
    end if
    allocate(mu(space%n_expanded, 64))
    lineno = 0
    list%n = 0
    do
      read(u, '(a)', iostat=ios) line
      if (ios /= 0) exit
      lineno = lineno + 1
      if (index(line, '#') > 0) line = line(1:index(line, '#') - 1)
      if (len_trim(line) == 0) cycle
      if (.not. allocated(col)) then
        call map_header(trim(line), space, what, col, error)
        if (allocated(error)) goto 9
        cycle
      end if
      call split(trim(line), tok)
      if (size(tok) /= size(col)) then
        call set_error(error, what // ": line " // str(lineno) // " has " // str(size(tok)) // " values, the " // &
          "header names " // str(size(col)) // " columns", EXIT_BAD_INPUT); goto 9
      end if
      if (list%n == size(mu, 2)) mu = reshape(mu, [size(mu, 1), 2 * size(mu, 2)], pad=[0.0_wp])
      list%n = list%n + 1
      do j = 1, size(tok)
        read(tok(j), *, iostat=ios) x
        if (ios /= 0) then
          call set_error(error, what // ": line " // str(lineno) // ", column " // str(j) // ": '" // trim(tok(j)) // &
            "' is not a number", EXIT_BAD_INPUT); goto 9
        end if
        if (.not. ieee_is_finite(x)) then
          call set_error(error, what // ": line " // str(lineno) // ", column " // str(j) // ": '" // trim(tok(j)) // &
            "' is not a finite number", EXIT_BAD_INPUT); goto 9
        end if
        mu(col(j), list%n) = x
      end do
    end do
    if (.not. allocated(col)) then
      call set_error(error, what // ": no header line (the component names " // space%component_names() // ")", EXIT_BAD_INPUT)
      goto 9
    end if
    list%mu = mu(:, 1:list%n)
9   close(u)
  end subroutine read_text_list

  !> An HDF5 list (module header).
  subroutine read_h5_list(path, dset, space, what, list, error)
    character(len=*), intent(in) :: path, dset, what
    type(param_space_t), intent(in) :: space
    type(query_list_t), intent(inout) :: list
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: header
    integer, allocatable :: col(:)
    real(wp), allocatable :: raw(:,:)
    integer :: j, k
    call h5%open(path, error)
    if (allocated(error)) then
      error%message = what // ": cannot open (" // error%message // ")"; error%code = EXIT_BAD_INPUT; return
    end if
    if (.not. h5%exists(dset)) then
      call set_error(error, what // ": no dataset '" // dset // "'", EXIT_BAD_INPUT); goto 9
    end if
    call h5%read_attr(dset, "param_names", header, error)
    if (allocated(error)) then
      deallocate(error)
      call h5%read_attr("/", "param_names", header, error)
    end if
    if (allocated(error)) then
      call set_error(error, what // ": no attribute 'param_names' on dataset '" // dset // "' or the root (the " // &
        "column names, comma-separated)", EXIT_BAD_INPUT); goto 9
    end if
    call map_header(header, space, what // ": dataset '" // dset // "'", col, error); if (allocated(error)) goto 9
    call h5%read(dset, raw, error)
    if (allocated(error)) then
      call prefix_error(error, what // ": dataset '" // dset // "'"); error%code = EXIT_BAD_INPUT; goto 9
    end if
    if (size(raw, 1) /= size(col)) then
      call set_error(error, what // ": dataset '" // dset // "' has " // str(size(raw, 1)) // " columns, " // &
        "param_names names " // str(size(col)), EXIT_BAD_INPUT); goto 9
    end if
    list%n = size(raw, 2)
    allocate(list%mu(space%n_expanded, list%n))
    do k = 1, list%n
      do j = 1, size(col)
        if (.not. ieee_is_finite(raw(j, k))) then
          call set_error(error, what // ": dataset '" // dset // "', query " // str(k) // ", column " // str(j) // &
            ": " // str(raw(j, k)) // " is not a finite number", EXIT_BAD_INPUT); goto 9
        end if
        list%mu(col(j), k) = raw(j, k)
      end do
    end do
9   call h5%close(e2)
  end subroutine read_h5_list

  !> The sampling rule's list: parameter p of the study from its distribution (default:
  !> uniform in the training box), query k from stream (seed, k).
  subroutine draw_list(c, space, where, list, error)
    type(predict_cfg_t), intent(in) :: c
    type(param_space_t), intent(in) :: space
    character(len=*), intent(in) :: where
    type(query_list_t), intent(inout) :: list
    type(error_t), allocatable, intent(out) :: error
    integer :: dist_of(space%n_params)
    integer :: k, p, j, i
    type(rng_t) :: rng
    dist_of = 0
    do j = 1, MAX_DIST
      if (len_trim(c%dist_param(j)) == 0) cycle
      p = findloc(space%names, c%dist_param(j), 1)
      if (p == 0) then
        call set_error(error, where // ": dist_param(" // str(j) // ") = '" // trim(c%dist_param(j)) // "' is not " // &
          "a parameter of the study (parameters: " // names_text(space) // ")", EXIT_BAD_INPUT); return
      end if
      dist_of(p) = j
    end do
    list%n = c%n_queries
    allocate(list%mu(space%n_expanded, list%n))
    do k = 1, list%n
      call rng%seed(c%seed, k)
      do p = 1, space%n_params
        do i = space%first(p), space%first(p) + space%width(p) - 1
          ! the population's seed (speed_seed) is a label, not a quantity: an integer uniform on
          ! its range whatever the distribution of its parameter, as in the study's sampling
          if (dist_of(p) == 0 .or. space%integral(i)) then
            list%mu(i, k) = space%uniform_value(i, rng%uniform())
          else
            list%mu(i, k) = draw(rng, dist_of(p))
          end if
        end do
      end do
    end do

  contains

    real(wp) function draw(rng, j) result(x)
      type(rng_t), intent(inout) :: rng
      integer, intent(in) :: j
      integer :: tries
      select case (trim(c%dist(j)))
      case ('uniform')
        x = c%dist_a(j) + (c%dist_b(j) - c%dist_a(j)) * rng%uniform()
      case ('normal')
        x = c%dist_a(j) + c%dist_b(j) * rng%normal()
      case ('lognormal')
        x = exp(c%dist_a(j) + c%dist_b(j) * rng%normal())
      case default   ! truncnormal: rejection (the window holds at least 1e-3 of the mass, checked)
        do tries = 1, 1000000
          x = c%dist_a(j) + c%dist_b(j) * rng%normal()
          if (x >= c%dist_lo(j) .and. x <= c%dist_hi(j)) return
        end do
        x = min(max(x, c%dist_lo(j)), c%dist_hi(j))
      end select
    end function draw
  end subroutine draw_list

  function names_text(space) result(s)
    type(param_space_t), intent(in) :: space
    character(len=:), allocatable :: s
    integer :: p
    s = ""
    do p = 1, space%n_params
      if (p > 1) s = s // ", "
      s = s // trim(space%names(p))
    end do
  end function names_text
end module cr_query_list
