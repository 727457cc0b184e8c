!> The quantities of interest (cr_qoi) on file: a QoI group (one row per trajectory: curves,
!> evacuation times with their censoring flags, flows, trust indicators; every dataset with its
!> checksum, cr_digest) that the snapshot database, the ROM-run file and the full-order output
!> hold, and the QoI product (schema "crowdrom-qoi", version 1; docs/queries.md): one file per
!> run and model, rows = queries, with the parameters, the per-query flags and CPU seconds, the
!> model name and the producer's configuration echo, and the QoI group `qoi`.
!>
!> Shapes in Fortran order (h5py reads them reversed), n rows: curve [n_steps + 1, n_exits, n],
!> curve_total [n_steps + 1, n], t_evac and censored [3, n] (t50, t90, t100), exit_width,
!> flow_rate, flow, flow_defined [n_exits, n], overlap_agents, overlap_obstacles, n_through,
!> displacement [n]; flags are integers 0/1. The product is written under a temporary name and
!> renamed when complete (cr_h5file); the readers check schema, version, shapes against the
!> attributes, ranges, finiteness and checksums.
module cr_qoi_file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_h5file, only: h5file_t
  use cr_digest, only: digest_of, put_digest, check_digest, DIGEST_ALGORITHM
  use cr_product_check, only: check_schema, need_finite, need_range, need_dims, product_error
  use cr_qoi, only: qoi_t, QOI_PCT, QOI_FLOW_LO, QOI_FLOW_HI
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: QOI_SCHEMA, QOI_SCHEMA_VERSION, QOI_VERSIONS_READ, QOI_UNITS, qoi_product_t, write_qoi_product, &
    read_qoi_product, write_qoi_group, read_qoi_group

  character(len=*), parameter :: QOI_SCHEMA = "crowdrom-qoi"
  integer, parameter :: QOI_SCHEMA_VERSION = 1
  !> versions the reader accepts
  integer, parameter :: QOI_VERSIONS_READ(1) = [1]
  character(len=*), parameter :: QOI_UNITS = "time: s, t_evac: s, exit_width: m, flow_rate: 1/s, " // &
    "flow: 1/(m s), overlaps: m, displacement: m, cpu_seconds: s"

  !> A QoI product: one row per query (n_queries = size(qoi)).
  type :: qoi_product_t
    !> producing program, model ("exact", "rom setting k", "ml <regressor>"), configuration echo,
    !> comma-separated parameter names
    character(len=:), allocatable :: program, model, config, param_names
    !> agent radius, time step [s]
    real(wp) :: radius = 0, dt = 0
    !> parameter values [n_params, n_queries]
    real(wp), allocatable :: params(:,:)
    !> per query [n_queries]: outside the training box, CPU seconds of the query
    logical, allocatable :: outside_box(:)
    real(wp), allocatable :: cpu_seconds(:)
    !> the quantities of interest [n_queries]
    type(qoi_t), allocatable :: qoi(:)
  end type qoi_product_t

contains

  !> Write the QoI group g (created here) of the rows qois (all of the same n_agents, n_steps,
  !> n_exits and h); every dataset gets its checksum.
  subroutine write_qoi_group(h5, g, qois, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: g
    type(qoi_t), intent(in) :: qois(:)
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: curve(:,:,:), total(:,:), cens(:,:), fdef(:,:), thr(:)
    real(wp), allocatable :: t(:,:), w(:,:), rate(:,:), flow(:,:), oaa(:), oaw(:), disp(:)
    integer :: n, nt, ne, na
    real(wp) :: h
    call gather_rows(qois, curve, total, t, cens, w, rate, flow, fdef, oaa, oaw, thr, disp, error)
    if (allocated(error)) return
    n = size(qois); nt = size(total, 1) - 1; ne = size(w, 1)
    call h5%make_group(g, error); if (allocated(error)) return
    call h5%write_attr(g, "n_rows", n, error); if (allocated(error)) return
    na = 0; h = 0
    if (n > 0) then
      na = qois(1)%n_agents; h = qois(1)%h
    end if
    call h5%write_attr(g, "n_agents", na, error); if (allocated(error)) return
    call h5%write_attr(g, "n_steps", nt, error); if (allocated(error)) return
    call h5%write_attr(g, "n_exits", ne, error); if (allocated(error)) return
    call h5%write_attr(g, "dt", h, error); if (allocated(error)) return
    call h5%write_attr(g, "evac_pct", QOI_PCT, error); if (allocated(error)) return
    call h5%write_attr(g, "flow_window_pct", [QOI_FLOW_LO, QOI_FLOW_HI], error); if (allocated(error)) return
    call h5%write_attr(g, "units", QOI_UNITS, error); if (allocated(error)) return
    call h5%write_attr(g, "definitions", "src/model/cr_qoi.f90, docs/queries.md", error); if (allocated(error)) return
    call h5%write(g // "/curve", curve, error); if (allocated(error)) return
    call put_digest(h5, g // "/curve", digest_of(reshape(curve, [nt + 1, ne * n]), 0_i8), error)
    if (allocated(error)) return
    call put_int(g // "/curve_total", total); if (allocated(error)) return
    call put_real(g // "/t_evac", t); if (allocated(error)) return
    call put_int(g // "/censored", cens); if (allocated(error)) return
    call put_real(g // "/exit_width", w); if (allocated(error)) return
    call put_real(g // "/flow_rate", rate); if (allocated(error)) return
    call put_real(g // "/flow", flow); if (allocated(error)) return
    call put_int(g // "/flow_defined", fdef); if (allocated(error)) return
    call put_vec(g // "/overlap_agents", oaa); if (allocated(error)) return
    call put_vec(g // "/overlap_obstacles", oaw); if (allocated(error)) return
    call put_vec(g // "/displacement", disp); if (allocated(error)) return
    call h5%write(g // "/n_through", thr, error); if (allocated(error)) return
    call put_digest(h5, g // "/n_through", digest_of(thr, 0_i8), error)

  contains

    !> a [m, n] with its checksum
    subroutine put_real(name, a)
      character(len=*), intent(in) :: name
      real(wp), intent(in), contiguous :: a(:,:)
      call h5%write(name, a, error)
      if (.not. allocated(error)) call put_digest(h5, name, digest_of(a, 0_i8), error)
    end subroutine put_real

    subroutine put_int(name, a)
      character(len=*), intent(in) :: name
      integer, intent(in), contiguous :: a(:,:)
      call h5%write(name, a, error)
      if (.not. allocated(error)) call put_digest(h5, name, digest_of(a, 0_i8), error)
    end subroutine put_int

    subroutine put_vec(name, a)
      character(len=*), intent(in) :: name
      real(wp), intent(in), contiguous :: a(:)
      call h5%write(name, a, error)
      if (.not. allocated(error)) call put_digest(h5, name, digest_of(a, 0_i8), error)
    end subroutine put_vec
  end subroutine write_qoi_group

  !> The rows of qois as arrays (see the module header); an error when they differ in size.
  subroutine gather_rows(qois, curve, total, t, cens, w, rate, flow, fdef, oaa, oaw, thr, disp, error)
    type(qoi_t), intent(in) :: qois(:)
    integer, allocatable, intent(out) :: curve(:,:,:), total(:,:), cens(:,:), fdef(:,:), thr(:)
    real(wp), allocatable, intent(out) :: t(:,:), w(:,:), rate(:,:), flow(:,:), oaa(:), oaw(:), disp(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: n, nt, ne, k
    n = size(qois); nt = 0; ne = 1
    if (n > 0) then
      nt = qois(1)%n_steps; ne = qois(1)%n_exits
    end if
    do k = 1, n
      if (qois(k)%n_steps /= nt .or. qois(k)%n_exits /= ne .or. qois(k)%n_agents /= qois(1)%n_agents .or. &
          qois(k)%h /= qois(1)%h .or. .not. allocated(qois(k)%curve)) then
        call set_error(error, "qoi group: row " // str(k) // " (" // str(qois(k)%n_steps) // " steps, " // &
          str(qois(k)%n_exits) // " exits, " // str(qois(k)%n_agents) // " agents) differs from row 1 (" // &
          str(nt) // ", " // str(ne) // ", " // str(qois(1)%n_agents) // ") or was not computed"); return
      end if
    end do
    allocate(curve(nt + 1, ne, n), total(nt + 1, n), t(3, n), cens(3, n), w(ne, n), rate(ne, n), flow(ne, n), &
      fdef(ne, n), oaa(n), oaw(n), thr(n), disp(n))
    do k = 1, n
      associate (q => qois(k))
        curve(:, :, k) = q%curve; total(:, k) = q%curve_total
        t(:, k) = q%t_evac; cens(:, k) = merge(1, 0, q%censored)
        w(:, k) = q%width; rate(:, k) = q%flow_rate; flow(:, k) = q%flow; fdef(:, k) = merge(1, 0, q%flow_defined)
        oaa(k) = q%overlap_aa; oaw(k) = q%overlap_aw; thr(k) = q%n_through; disp(k) = q%displacement
      end associate
    end do
  end subroutine gather_rows

  !> Read and check the QoI group g of the open file h5 (named path in messages) into qois.
  subroutine read_qoi_group(h5, path, g, qois, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: path, g
    type(qoi_t), allocatable, intent(out) :: qois(:)
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: curve(:,:,:), total(:,:), cens(:,:), fdef(:,:), thr(:)
    real(wp), allocatable :: t(:,:), w(:,:), rate(:,:), flow(:,:), oaa(:), oaw(:), disp(:)
    integer :: n, na, nt, ne, k
    real(wp) :: h
    if (.not. h5%exists(g)) then
      call product_error(path, "group '" // g // "' (quantities of interest) missing", error); return
    end if
    call h5%read_attr(g, "n_rows", n, error); if (allocated(error)) return
    call h5%read_attr(g, "n_agents", na, error); if (allocated(error)) return
    call h5%read_attr(g, "n_steps", nt, error); if (allocated(error)) return
    call h5%read_attr(g, "n_exits", ne, error); if (allocated(error)) return
    call h5%read_attr(g, "dt", h, error); if (allocated(error)) return
    if (n < 0 .or. na < 0 .or. nt < 0 .or. ne < 1 .or. ne > 2 .or. .not. (h >= 0 .and. h <= huge(h))) then
      call product_error(path, "group '" // g // "': attributes out of range (n_rows " // str(n) // ", n_agents " // &
        str(na) // ", n_steps " // str(nt) // ", n_exits " // str(ne) // ", dt " // str(h) // ")", error); return
    end if
    call read_arrays(); if (allocated(error)) return
    allocate(qois(n))
    do k = 1, n
      associate (q => qois(k))
        q%n_agents = na; q%n_steps = nt; q%n_exits = ne; q%h = h
        allocate(q%curve(0:nt, ne), q%curve_total(0:nt))
        q%curve = curve(:, :, k); q%curve_total = total(:, k)
        q%t_evac = t(:, k); q%censored = cens(:, k) == 1
        q%width = w(:, k); q%flow_rate = rate(:, k); q%flow = flow(:, k); q%flow_defined = fdef(:, k) == 1
        q%overlap_aa = oaa(k); q%overlap_aw = oaw(k); q%n_through = thr(k); q%displacement = disp(k)
      end associate
    end do

  contains

    subroutine read_arrays()
      integer(i8) :: m, s, e, r
      m = n; s = nt + 1; e = ne; r = 3
      call need_dims(h5, path, g // "/curve", [s, e, m], "n_steps + 1 x n_exits x n_rows", error)
      if (allocated(error)) return
      call h5%read(g // "/curve", curve, error); if (allocated(error)) return
      call check_digest(h5, g // "/curve", digest_of(reshape(curve, [nt + 1, ne * n]), 0_i8), "'" // path // "'", error)
      if (allocated(error)) return
      call need_range(path, g // "/curve", reshape(curve, [size(curve)]), 0, na, error); if (allocated(error)) return
      call get_int(g // "/curve_total", [s, m], total, 0, na); if (allocated(error)) return
      call get_real(g // "/t_evac", [r, m], t); if (allocated(error)) return
      call get_int(g // "/censored", [r, m], cens, 0, 1); if (allocated(error)) return
      call get_real(g // "/exit_width", [e, m], w); if (allocated(error)) return
      call get_real(g // "/flow_rate", [e, m], rate); if (allocated(error)) return
      call get_real(g // "/flow", [e, m], flow); if (allocated(error)) return
      call get_int(g // "/flow_defined", [e, m], fdef, 0, 1); if (allocated(error)) return
      call get_vec(g // "/overlap_agents", oaa); if (allocated(error)) return
      call get_vec(g // "/overlap_obstacles", oaw); if (allocated(error)) return
      call get_vec(g // "/displacement", disp); if (allocated(error)) return
      call need_dims(h5, path, g // "/n_through", [m], "n_rows", error); if (allocated(error)) return
      call h5%read(g // "/n_through", thr, error); if (allocated(error)) return
      call check_digest(h5, g // "/n_through", digest_of(thr, 0_i8), "'" // path // "'", error); if (allocated(error)) return
      call need_range(path, g // "/n_through", thr, 0, na, error)
    end subroutine read_arrays

    subroutine get_int(name, d, a, lo, hi)
      character(len=*), intent(in) :: name
      integer(i8), intent(in) :: d(2)
      integer, allocatable, intent(out) :: a(:,:)
      integer, intent(in) :: lo, hi
      call need_dims(h5, path, name, d, "the group's attributes", error); if (allocated(error)) return
      call h5%read(name, a, error); if (allocated(error)) return
      call check_digest(h5, name, digest_of(a, 0_i8), "'" // path // "'", error); if (allocated(error)) return
      call need_range(path, name, reshape(a, [size(a)]), lo, hi, error)
    end subroutine get_int

    subroutine get_real(name, d, a)
      character(len=*), intent(in) :: name
      integer(i8), intent(in) :: d(2)
      real(wp), allocatable, intent(out) :: a(:,:)
      call need_dims(h5, path, name, d, "the group's attributes", error); if (allocated(error)) return
      call h5%read(name, a, error); if (allocated(error)) return
      call check_digest(h5, name, digest_of(a, 0_i8), "'" // path // "'", error); if (allocated(error)) return
      call need_finite(path, name, a, error)
    end subroutine get_real

    subroutine get_vec(name, a)
      character(len=*), intent(in) :: name
      real(wp), allocatable, intent(out) :: a(:)
      call need_dims(h5, path, name, [int(n, i8)], "n_rows", error); if (allocated(error)) return
      call h5%read(name, a, error); if (allocated(error)) return
      call check_digest(h5, name, digest_of(a, 0_i8), "'" // path // "'", error); if (allocated(error)) return
      call need_finite(path, name, a, error)
    end subroutine get_vec
  end subroutine read_qoi_group

  !> Write the QoI product p to path (temporary name, renamed when complete; nothing left on
  !> an error).
  subroutine write_qoi_product(path, p, error)
    character(len=*), intent(in) :: path
    type(qoi_product_t), intent(in) :: p
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    integer :: n
    n = 0
    if (allocated(p%qoi)) n = size(p%qoi)
    if (.not. allocated(p%params) .or. .not. allocated(p%outside_box) .or. .not. allocated(p%cpu_seconds)) then
      call set_error(error, "QoI product '" // path // "': parameters, flags or CPU seconds not set"); return
    end if
    if (size(p%params, 2) /= n .or. size(p%outside_box) /= n .or. size(p%cpu_seconds) /= n) then
      call set_error(error, "QoI product '" // path // "': " // str(n) // " rows of QoIs, " // str(size(p%params, 2)) // &
        " parameter columns, " // str(size(p%outside_box)) // " flags, " // str(size(p%cpu_seconds)) // &
        " CPU times"); return
    end if
    call h5%create(path, error); if (allocated(error)) return
    call header(); if (allocated(error)) goto 9
    call h5%write("params", p%params, error); if (allocated(error)) goto 9
    call put_digest(h5, "params", digest_of(p%params, 0_i8), error); if (allocated(error)) goto 9
    call h5%write("outside_box", merge(1, 0, p%outside_box), error); if (allocated(error)) goto 9
    call put_digest(h5, "outside_box", digest_of(merge(1, 0, p%outside_box), 0_i8), error); if (allocated(error)) goto 9
    call h5%write("cpu_seconds", p%cpu_seconds, error); if (allocated(error)) goto 9
    call put_digest(h5, "cpu_seconds", digest_of(p%cpu_seconds, 0_i8), error); if (allocated(error)) goto 9
    call write_qoi_group(h5, "qoi", p%qoi, error); if (allocated(error)) goto 9
    call h5%commit(error)
9   if (allocated(error)) then
      call prefix_error(error, "QoI product '" // path // "'")
      call h5%abort()
    end if

  contains

    subroutine header()
      call h5%write_attr("/", "schema", QOI_SCHEMA, error); if (allocated(error)) return
      call h5%write_attr("/", "schema_version", QOI_SCHEMA_VERSION, error); if (allocated(error)) return
      call h5%write_attr("/", "program", p%program, error); if (allocated(error)) return
      call h5%write_attr("/", "model", p%model, error); if (allocated(error)) return
      call h5%write_attr("/", "config", p%config, error); if (allocated(error)) return
      call h5%write_attr("/", "param_names", p%param_names, error); if (allocated(error)) return
      call h5%write_attr("/", "n_queries", n, error); if (allocated(error)) return
      call h5%write_attr("/", "n_params", size(p%params, 1), error); if (allocated(error)) return
      call h5%write_attr("/", "agent_radius", p%radius, error); if (allocated(error)) return
      call h5%write_attr("/", "dt", p%dt, error); if (allocated(error)) return
      call h5%write_attr("/", "units", QOI_UNITS, error); if (allocated(error)) return
      call h5%write_attr("/", "checksum_algorithm", DIGEST_ALGORITHM, error)
    end subroutine header
  end subroutine write_qoi_product

  !> Read and check a QoI product.
  subroutine read_qoi_product(path, p, error)
    character(len=*), intent(in) :: path
    type(qoi_product_t), intent(out) :: p
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    integer, allocatable :: flags(:)
    integer :: version, n, np
    call h5%open(path, error)
    if (allocated(error)) then
      error%code = EXIT_BAD_INPUT; return
    end if
    call check_schema(h5, path, QOI_SCHEMA, QOI_VERSIONS_READ, "QoI product", version, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "program", p%program, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "model", p%model, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "config", p%config, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "param_names", p%param_names, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_queries", n, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_params", np, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "agent_radius", p%radius, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "dt", p%dt, error); if (allocated(error)) goto 9
    if (n < 0 .or. np < 0) then
      call product_error(path, "root attributes out of range (n_queries " // str(n) // ", n_params " // str(np) // ")", &
        error); goto 9
    end if
    call need_dims(h5, path, "params", [int(np, i8), int(n, i8)], "n_params x n_queries", error); if (allocated(error)) goto 9
    call h5%read("params", p%params, error); if (allocated(error)) goto 9
    call check_digest(h5, "params", digest_of(p%params, 0_i8), "'" // path // "'", error); if (allocated(error)) goto 9
    call need_finite(path, "params", p%params, error); if (allocated(error)) goto 9
    call need_dims(h5, path, "outside_box", [int(n, i8)], "n_queries", error); if (allocated(error)) goto 9
    call h5%read("outside_box", flags, error); if (allocated(error)) goto 9
    call check_digest(h5, "outside_box", digest_of(flags, 0_i8), "'" // path // "'", error); if (allocated(error)) goto 9
    call need_range(path, "outside_box", flags, 0, 1, error); if (allocated(error)) goto 9
    p%outside_box = flags == 1
    call need_dims(h5, path, "cpu_seconds", [int(n, i8)], "n_queries", error); if (allocated(error)) goto 9
    call h5%read("cpu_seconds", p%cpu_seconds, error); if (allocated(error)) goto 9
    call check_digest(h5, "cpu_seconds", digest_of(p%cpu_seconds, 0_i8), "'" // path // "'", error)
    if (allocated(error)) goto 9
    call need_finite(path, "cpu_seconds", p%cpu_seconds, error); if (allocated(error)) goto 9
    call read_qoi_group(h5, path, "qoi", p%qoi, error); if (allocated(error)) goto 9
    if (size(p%qoi) /= n) call product_error(path, "group 'qoi' has " // str(size(p%qoi)) // " rows, n_queries is " // &
      str(n), error)
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= EXIT_BAD_INPUT) call prefix_error(error, "QoI product '" // path // "'")
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_qoi_product
end module cr_qoi_file
