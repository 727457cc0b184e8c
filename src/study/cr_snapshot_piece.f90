!> The samples of a study: full-order trajectories (computed by compute_sample) and the "piece"
!> files that make them durable before the database is assembled.
!>
!> A piece is a small serial HDF5 file `<database>.pieces/<set>_<k>.h5`, named after its first
!> sample, holding the samples one rank computed in one time slice (one or more). It is written
!> under a temporary name and renamed when closed (cr_h5file), so a piece exists under its final
!> name only when all its data is on disk: a killed run leaves only complete pieces (and maybe
!> a `.partial`, ignored and overwritten).
!>
!> A piece proves what it is: it records its configuration hash, and for every sample its set,
!> index and parameters (checked against its name and against the study's sampling by
!> check_sample), and every dataset carries a checksum (cr_digest) verified by read_piece,
!> which also checks shapes, finiteness and the multiplier layout.
!>
!> Layout (schema "crowdrom-snapshot-piece" v2): root attributes schema, schema_version,
!> config_hash, n_samples, checksum_algorithm, complete; one group `sample_<j>` (j = 1..n_samples)
!> per sample with attributes set, index, rank, time (s), start (s since the start of the run)
!> and datasets mu [n_expanded], positions [2*n_agents, n_steps+1], velocities / desired
!> [2*n_agents, n_steps], kkt / min_gap / iterations / converged / n_active [n_steps],
!> lambda_offset int64 [n_steps+1], lambda_key int64 / lambda_ia / lambda_ib / lambda_ob /
!> lambda_value [nnz] (only lambda > 0), each with a `checksum` attribute.
module cr_snapshot_piece
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_config, only: config_t
  use cr_fom, only: fom_t, step_record_t
  use cr_sampling, only: param_space_t
  use cr_h5file, only: h5file_t
  use cr_digest, only: digest_of, put_digest, check_digest, DIGEST_ALGORITHM
  implicit none
  private
  public :: sample_result_t, compute_sample, write_piece, read_piece, piece_header, check_sample, &
    piece_path, PIECE_SCHEMA, PIECE_SCHEMA_VERSION

  character(len=*), parameter :: PIECE_SCHEMA = "crowdrom-snapshot-piece"
  integer, parameter :: PIECE_SCHEMA_VERSION = 2

  !> Trajectory and statistics of one sample.
  type :: sample_result_t
    !> 'train' or 'valid', and the sample's index in its set
    character(len=8) :: set = ''
    integer :: index = 0
    !> parameter values [n_expanded]
    real(wp), allocatable :: mu(:)
    !> positions q^0..q^{n_steps} [2*n_agents, n_steps+1]
    real(wp), allocatable :: q(:,:)
    !> velocities u^nu and desired velocities v(q^{nu-1}), nu = 1..n_steps [2*n_agents, n_steps]
    real(wp), allocatable :: u(:,:), v(:,:)
    !> per-step KKT residual and smallest gap [n_steps]
    real(wp), allocatable :: kkt(:), min_gap(:)
    !> per-step solver iterations, converged flag (1/0), active contacts [n_steps]
    integer, allocatable :: iterations(:), converged(:), n_active(:)
    !> sparse multipliers, CSR over the steps: step nu holds entries offset(nu)+1..offset(nu+1)
    integer(i8), allocatable :: offset(:)
    integer(i8), allocatable :: key(:)
    integer, allocatable :: ia(:), ib(:), ob(:)
    real(wp), allocatable :: value(:)
    !> wall time of the sample (s), its start (s since the start of the run) and the rank that
    !> computed it
    real(wp) :: time = 0, start = 0
    integer :: rank = -1
  end type sample_result_t

contains

  !> `<dir>/<set>_<k>.h5` with k zero-padded to 6 digits.
  function piece_path(dir, set, k) result(p)
    character(len=*), intent(in) :: dir, set
    integer, intent(in) :: k
    character(len=:), allocatable :: p
    character(len=16) :: b
    write(b, '(i6.6)') k
    p = dir // "/" // trim(set) // "_" // trim(b) // ".h5"
  end function piece_path

  !> Run the full-order model for parameters mu from the common initial positions q0.
  subroutine compute_sample(cfg_ref, space, mu, q0, ref_speeds, res, error)
    type(config_t), intent(in) :: cfg_ref
    type(param_space_t), intent(in) :: space
    !> parameters [n_expanded]
    real(wp), intent(in) :: mu(:)
    !> initial positions [2*n_agents]
    real(wp), intent(in) :: q0(:)
    !> reference speeds [n_agents] (for parameters that do not set them)
    real(wp), intent(in) :: ref_speeds(:)
    type(sample_result_t), intent(inout) :: res
    type(error_t), allocatable, intent(out) :: error
    type(config_t) :: cfg
    type(fom_t) :: fom
    type(step_record_t) :: rec
    real(wp), allocatable :: speeds(:)
    integer :: ns, nd, nu, l, nnz
    cfg = cfg_ref
    speeds = ref_speeds
    call space%apply(mu, cfg, speeds)
    call fom%init(cfg, error, q0=q0, speeds=speeds)
    if (allocated(error)) return
    ns = cfg%time%n_steps
    nd = 2 * fom%n_agents
    res%mu = mu
    if (allocated(res%q)) deallocate(res%q, res%u, res%v, res%kkt, res%min_gap, res%iterations, &
      res%converged, res%n_active, res%offset, res%key, res%ia, res%ib, res%ob, res%value)
    allocate(res%q(nd, ns + 1), res%u(nd, ns), res%v(nd, ns), res%kkt(ns), res%min_gap(ns), &
      res%iterations(ns), res%converged(ns), res%n_active(ns), res%offset(ns + 1))
    allocate(res%key(16 * fom%n_agents), res%ia(16 * fom%n_agents), res%ib(16 * fom%n_agents), &
      res%ob(16 * fom%n_agents), res%value(16 * fom%n_agents))
    res%q(:, 1) = fom%q
    res%offset(1) = 0
    nnz = 0
    do nu = 1, ns
      call fom%advance(rec, error)
      if (allocated(error)) return
      res%q(:, nu + 1) = fom%q
      res%u(:, nu) = fom%u
      res%v(:, nu) = fom%v
      res%kkt(nu) = rec%kkt
      res%min_gap(nu) = rec%min_gap
      res%iterations(nu) = rec%iterations
      res%converged(nu) = merge(1, 0, rec%converged)
      res%n_active(nu) = rec%n_active
      do l = 1, fom%cs%n
        if (fom%lambda(l) > 0) then
          if (nnz == size(res%key)) call grow()
          nnz = nnz + 1
          res%key(nnz) = fom%cs%key(l)
          res%ia(nnz) = fom%cs%ia(l); res%ib(nnz) = fom%cs%ib(l); res%ob(nnz) = fom%cs%ob(l)
          res%value(nnz) = fom%lambda(l)
        end if
      end do
      res%offset(nu + 1) = nnz
    end do
    res%key = res%key(1:nnz); res%ia = res%ia(1:nnz); res%ib = res%ib(1:nnz)
    res%ob = res%ob(1:nnz); res%value = res%value(1:nnz)

  contains

    subroutine grow()
      integer :: n
      integer(i8), allocatable :: k2(:)
      integer, allocatable :: i2(:)
      real(wp), allocatable :: r2(:)
      n = 2 * size(res%key)
      allocate(k2(n)); k2(1:nnz) = res%key(1:nnz); call move_alloc(k2, res%key)
      allocate(i2(n)); i2(1:nnz) = res%ia(1:nnz); call move_alloc(i2, res%ia)
      allocate(i2(n)); i2(1:nnz) = res%ib(1:nnz); call move_alloc(i2, res%ib)
      allocate(i2(n)); i2(1:nnz) = res%ob(1:nnz); call move_alloc(i2, res%ob)
      allocate(r2(n)); r2(1:nnz) = res%value(1:nnz); call move_alloc(r2, res%value)
    end subroutine grow
  end subroutine compute_sample

  !> Write the samples res(1:n) as one piece (serial HDF5, temporary name renamed when complete).
  subroutine write_piece(path, hash, res, error)
    character(len=*), intent(in) :: path, hash
    !> the samples, in the order they were computed [n >= 1]
    type(sample_result_t), intent(in) :: res(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    character(len=:), allocatable :: g
    integer :: j
    call h5%create(path, error)
    if (allocated(error)) return
    ops: block
      call h5%write_attr("/", "schema", PIECE_SCHEMA, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "schema_version", PIECE_SCHEMA_VERSION, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "config_hash", hash, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "n_samples", size(res), error); if (allocated(error)) exit ops
      call h5%write_attr("/", "checksum_algorithm", DIGEST_ALGORITHM, error); if (allocated(error)) exit ops
      do j = 1, size(res)
        g = "sample_" // str(j)
        call write_sample(g, res(j), error); if (allocated(error)) exit ops
      end do
      call h5%write_attr("/", "complete", 1, error); if (allocated(error)) exit ops
      call h5%commit(error)
    end block ops
    if (allocated(error)) then
      call h5%abort()
      call prefix_error(error, "piece '" // path // "'")
    end if

  contains

    subroutine write_sample(g, r, error)
      character(len=*), intent(in) :: g
      type(sample_result_t), intent(in) :: r
      type(error_t), allocatable, intent(out) :: error
      call h5%make_group(g, error); if (allocated(error)) return
      call h5%write_attr(g, "set", trim(r%set), error); if (allocated(error)) return
      call h5%write_attr(g, "index", r%index, error); if (allocated(error)) return
      call h5%write_attr(g, "rank", r%rank, error); if (allocated(error)) return
      call h5%write_attr(g, "time", r%time, error); if (allocated(error)) return
      call h5%write_attr(g, "start", r%start, error); if (allocated(error)) return
      call h5%write(g // "/mu", r%mu, error); if (allocated(error)) return
      call put_digest(h5, g // "/mu", digest_of(r%mu, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/positions", r%q, error); if (allocated(error)) return
      call put_digest(h5, g // "/positions", digest_of(r%q, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/velocities", r%u, error); if (allocated(error)) return
      call put_digest(h5, g // "/velocities", digest_of(r%u, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/desired", r%v, error); if (allocated(error)) return
      call put_digest(h5, g // "/desired", digest_of(r%v, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/kkt", r%kkt, error); if (allocated(error)) return
      call put_digest(h5, g // "/kkt", digest_of(r%kkt, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/min_gap", r%min_gap, error); if (allocated(error)) return
      call put_digest(h5, g // "/min_gap", digest_of(r%min_gap, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/iterations", r%iterations, error); if (allocated(error)) return
      call put_digest(h5, g // "/iterations", digest_of(r%iterations, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/converged", r%converged, error); if (allocated(error)) return
      call put_digest(h5, g // "/converged", digest_of(r%converged, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/n_active", r%n_active, error); if (allocated(error)) return
      call put_digest(h5, g // "/n_active", digest_of(r%n_active, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/lambda_offset", r%offset, error); if (allocated(error)) return
      call put_digest(h5, g // "/lambda_offset", digest_of(r%offset, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/lambda_key", r%key, error); if (allocated(error)) return
      call put_digest(h5, g // "/lambda_key", digest_of(r%key, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/lambda_ia", r%ia, error); if (allocated(error)) return
      call put_digest(h5, g // "/lambda_ia", digest_of(r%ia, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/lambda_ib", r%ib, error); if (allocated(error)) return
      call put_digest(h5, g // "/lambda_ib", digest_of(r%ib, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/lambda_ob", r%ob, error); if (allocated(error)) return
      call put_digest(h5, g // "/lambda_ob", digest_of(r%ob, 0_i8), error); if (allocated(error)) return
      call h5%write(g // "/lambda_value", r%value, error); if (allocated(error)) return
      call put_digest(h5, g // "/lambda_value", digest_of(r%value, 0_i8), error)
    end subroutine write_sample
  end subroutine write_piece

  !> Header of a piece: configuration hash and the (set, index) of each of its samples.
  !> An error if it is not a complete piece of this schema version.
  subroutine piece_header(path, hash, sets, idx, error)
    character(len=*), intent(in) :: path
    character(len=:), allocatable, intent(out) :: hash
    !> set name and index of each sample [n_samples]
    character(len=8), allocatable, intent(out) :: sets(:)
    integer, allocatable, intent(out) :: idx(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    character(len=:), allocatable :: schema, s
    integer :: version, n, complete, j
    type(error_t), allocatable :: e2
    hash = ""
    allocate(sets(0), idx(0))
    call h5%open(path, error)
    if (allocated(error)) return
    ops: block
      call h5%read_attr("/", "schema", schema, error); if (allocated(error)) exit ops
      if (schema /= PIECE_SCHEMA) then
        call set_error(error, "schema '" // schema // "' is not " // PIECE_SCHEMA); exit ops
      end if
      call h5%read_attr("/", "schema_version", version, error); if (allocated(error)) exit ops
      if (version /= PIECE_SCHEMA_VERSION) then
        call set_error(error, "piece schema version " // str(version) // " is not " // str(PIECE_SCHEMA_VERSION))
        exit ops
      end if
      call h5%read_attr("/", "complete", complete, error); if (allocated(error)) exit ops
      if (complete /= 1) then
        call set_error(error, "not marked complete"); exit ops
      end if
      call h5%read_attr("/", "config_hash", hash, error); if (allocated(error)) exit ops
      call h5%read_attr("/", "n_samples", n, error); if (allocated(error)) exit ops
      if (n < 1) then
        call set_error(error, "n_samples = " // str(n) // " (must be >= 1)"); exit ops
      end if
      deallocate(sets, idx)
      allocate(sets(n), idx(n))
      do j = 1, n
        call h5%read_attr("sample_" // str(j), "set", s, error); if (allocated(error)) exit ops
        sets(j) = s
        call h5%read_attr("sample_" // str(j), "index", idx(j), error); if (allocated(error)) exit ops
      end do
    end block ops
    call h5%close(e2)
    if (allocated(error)) call prefix_error(error, "piece '" // path // "'")
  end subroutine piece_header

  !> Read every sample of a piece, verifying each dataset's checksum and the internal
  !> consistency of each sample (shapes, finite values, multiplier layout). Identity against the
  !> study is check_sample's job. Errors start with "piece '<path>'".
  subroutine read_piece(path, res, error)
    character(len=*), intent(in) :: path
    type(sample_result_t), allocatable, intent(out) :: res(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: set, what
    integer :: n, j
    what = "piece '" // path // "'"
    allocate(res(0))
    call h5%open(path, error)
    if (allocated(error)) then
      call prefix_error(error, what); return
    end if
    ops: block
      call h5%read_attr("/", "n_samples", n, error); if (allocated(error)) exit ops
      if (n < 1) then
        call set_error(error, "n_samples = " // str(n)); exit ops
      end if
      deallocate(res); allocate(res(n))
      do j = 1, n
        call read_sample("sample_" // str(j), res(j), error); if (allocated(error)) exit ops
      end do
    end block ops
    call h5%close(e2)
    if (allocated(error)) then
      if (index(error%message, what) /= 1) call prefix_error(error, what)
    end if

  contains

    subroutine read_sample(g, r, error)
      character(len=*), intent(in) :: g
      type(sample_result_t), intent(inout) :: r
      type(error_t), allocatable, intent(out) :: error
      character(len=:), allocatable :: w
      integer :: nd, ns
      w = what // ", " // g
      call h5%read_attr(g, "set", set, error); if (allocated(error)) return
      r%set = set
      call h5%read_attr(g, "index", r%index, error); if (allocated(error)) return
      call h5%read_attr(g, "rank", r%rank, error); if (allocated(error)) return
      call h5%read_attr(g, "time", r%time, error); if (allocated(error)) return
      call h5%read_attr(g, "start", r%start, error); if (allocated(error)) return
      w = what // " (" // trim(r%set) // " sample " // str(r%index) // ")"
      call h5%read(g // "/mu", r%mu, error); if (allocated(error)) return
      call check_digest(h5, g // "/mu", digest_of(r%mu, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/positions", r%q, error); if (allocated(error)) return
      call check_digest(h5, g // "/positions", digest_of(r%q, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/velocities", r%u, error); if (allocated(error)) return
      call check_digest(h5, g // "/velocities", digest_of(r%u, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/desired", r%v, error); if (allocated(error)) return
      call check_digest(h5, g // "/desired", digest_of(r%v, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/kkt", r%kkt, error); if (allocated(error)) return
      call check_digest(h5, g // "/kkt", digest_of(r%kkt, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/min_gap", r%min_gap, error); if (allocated(error)) return
      call check_digest(h5, g // "/min_gap", digest_of(r%min_gap, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/iterations", r%iterations, error); if (allocated(error)) return
      call check_digest(h5, g // "/iterations", digest_of(r%iterations, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/converged", r%converged, error); if (allocated(error)) return
      call check_digest(h5, g // "/converged", digest_of(r%converged, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/n_active", r%n_active, error); if (allocated(error)) return
      call check_digest(h5, g // "/n_active", digest_of(r%n_active, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/lambda_offset", r%offset, error); if (allocated(error)) return
      call check_digest(h5, g // "/lambda_offset", digest_of(r%offset, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/lambda_key", r%key, error); if (allocated(error)) return
      call check_digest(h5, g // "/lambda_key", digest_of(r%key, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/lambda_ia", r%ia, error); if (allocated(error)) return
      call check_digest(h5, g // "/lambda_ia", digest_of(r%ia, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/lambda_ib", r%ib, error); if (allocated(error)) return
      call check_digest(h5, g // "/lambda_ib", digest_of(r%ib, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/lambda_ob", r%ob, error); if (allocated(error)) return
      call check_digest(h5, g // "/lambda_ob", digest_of(r%ob, 0_i8), w, error); if (allocated(error)) return
      call h5%read(g // "/lambda_value", r%value, error); if (allocated(error)) return
      call check_digest(h5, g // "/lambda_value", digest_of(r%value, 0_i8), w, error); if (allocated(error)) return
      ! internal consistency
      nd = size(r%q, 1); ns = size(r%q, 2) - 1
      if (ns < 1 .or. any(shape(r%u) /= [nd, ns]) .or. any(shape(r%v) /= [nd, ns]) .or. size(r%kkt) /= ns .or. &
          size(r%min_gap) /= ns .or. size(r%iterations) /= ns .or. size(r%converged) /= ns .or. &
          size(r%n_active) /= ns .or. size(r%offset) /= ns + 1) then
        call set_error(error, w // ": inconsistent dataset shapes"); return
      end if
      if (size(r%ia) /= size(r%key) .or. size(r%ib) /= size(r%key) .or. size(r%ob) /= size(r%key) .or. &
          size(r%value) /= size(r%key)) then
        call set_error(error, w // ": multiplier arrays of different lengths"); return
      end if
      if (r%offset(1) /= 0 .or. any(r%offset(2:) < r%offset(:ns)) .or. r%offset(ns + 1) /= size(r%value)) then
        call set_error(error, w // ": lambda_offset is not a CSR layout of the " // str(size(r%value)) // " values")
        return
      end if
      call need_finite(r%mu, "mu", w, error); if (allocated(error)) return
      call need_finite(reshape(r%q, [size(r%q)]), "positions", w, error); if (allocated(error)) return
      call need_finite(reshape(r%u, [size(r%u)]), "velocities", w, error); if (allocated(error)) return
      call need_finite(reshape(r%v, [size(r%v)]), "desired", w, error); if (allocated(error)) return
      call need_finite(r%kkt, "kkt", w, error); if (allocated(error)) return
      call need_finite(r%value, "lambda_value", w, error); if (allocated(error)) return
      call need_finite([r%time, r%start], "time", w, error); if (allocated(error)) return
      if (any(r%value <= 0)) then
        call set_error(error, w // ": lambda_value holds multipliers <= 0 (only lambda > 0 are stored)"); return
      end if
      if (any(r%converged /= 0 .and. r%converged /= 1)) then
        call set_error(error, w // ": converged holds values other than 0 and 1"); return
      end if
    end subroutine read_sample

    subroutine need_finite(x, name, w, error)
      real(wp), intent(in) :: x(:)
      character(len=*), intent(in) :: name, w
      type(error_t), allocatable, intent(out) :: error
      integer :: i
      if (all(ieee_is_finite(x))) return
      do i = 1, size(x)
        if (.not. ieee_is_finite(x(i))) exit
      end do
      call set_error(error, w // ": dataset '" // name // "' holds a non-finite value (NaN or Inf) at element " // &
        str(i))
    end subroutine need_finite
  end subroutine read_piece

  !> Check that sample r is sample k of set `set` of the study: its recorded set and index, its
  !> parameters (bitwise: both come from the same sampling) and its sizes.
  subroutine check_sample(r, set, k, mu, n_dof, n_steps, what, error)
    type(sample_result_t), intent(in) :: r
    character(len=*), intent(in) :: set
    integer, intent(in) :: k
    !> the study's parameters of that sample [n_expanded]
    real(wp), intent(in) :: mu(:)
    integer, intent(in) :: n_dof, n_steps
    !> the piece, for the message
    character(len=*), intent(in) :: what
    type(error_t), allocatable, intent(out) :: error
    if (trim(r%set) /= trim(set) .or. r%index /= k) then
      call set_error(error, what // " holds " // trim(r%set) // " sample " // str(r%index) // " where " // &
        trim(set) // " sample " // str(k) // " belongs (renamed or copied piece)")
    else if (size(r%mu) /= size(mu)) then
      call set_error(error, what // ": " // trim(set) // " sample " // str(k) // " has " // str(size(r%mu)) // &
        " parameters, the study " // str(size(mu)))
    else if (any(transfer(r%mu, 0_i8, size(mu)) /= transfer(mu, 0_i8, size(mu)))) then
      call set_error(error, what // ": the parameters of " // trim(set) // " sample " // str(k) // &
        " are not those of the study's sampling")
    else if (size(r%q, 1) /= n_dof .or. size(r%q, 2) /= n_steps + 1) then
      call set_error(error, what // ": " // trim(set) // " sample " // str(k) // " has positions of shape " // &
        str(size(r%q, 1)) // " x " // str(size(r%q, 2)) // ", the study " // str(n_dof) // " x " // str(n_steps + 1))
    end if
  end subroutine check_sample
end module cr_snapshot_piece
