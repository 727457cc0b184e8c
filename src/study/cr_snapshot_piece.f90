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
!> Layout (schema "crowdrom-snapshot-piece" v2; n samples, each dataset holds them one after
!> the other, every dataset with a `checksum` attribute): root attributes schema,
!> schema_version, config_hash, n_samples, set_names ("train,valid"), checksum_algorithm,
!> complete; datasets set_id / index / rank [n], time / start [n] (s; start since the start of
!> the run), mu [n_expanded, n], positions [2*n_agents, (n_steps+1) n], velocities / desired
!> [2*n_agents, n_steps n], kkt / min_gap / iterations / converged / n_active [n_steps, n],
!> lambda_offset int64 [(n_steps+1) n] (each sample's CSR over its steps), lambda_key int64 /
!> lambda_ia / lambda_ib / lambda_ob / lambda_value [total nnz] (only lambda > 0).
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
  use cr_contact_set, only: contact_key
  use cr_snapshot_file, only: sample_result_t => snap_sample_t, SET_NAMES => SNAP_SET_NAMES, move_sample
  implicit none
  private
  public :: sample_result_t, move_sample, compute_sample, write_piece, read_piece, piece_header, check_sample, &
    piece_path, PIECE_SCHEMA, PIECE_SCHEMA_VERSION

  character(len=*), parameter :: PIECE_SCHEMA = "crowdrom-snapshot-piece"
  integer, parameter :: PIECE_SCHEMA_VERSION = 2

  !> The datasets of a piece as read (n samples of ns steps, nd degrees of freedom, nnz
  !> multipliers) and the names of the piece for messages (what; w: with its samples).
  type :: piece_data_t
    character(len=:), allocatable :: what, w
    integer :: n = 0, ns = 0, nd = 0
    integer(i8) :: nnz = 0
    integer, allocatable :: setid(:), idx(:), rk(:), iters(:,:), conv(:,:), nact(:,:), ia(:), ib(:), ob(:)
    real(wp), allocatable :: tm(:), st(:), mu(:,:), q(:,:), u(:,:), v(:,:), kkt(:,:), gap(:,:), val(:)
    integer(i8), allocatable :: off(:), key(:)
  end type piece_data_t

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

  !> Write the samples res(1:n) as one piece (serial HDF5, temporary name renamed when complete):
  !> every dataset holds the n samples one after the other (a fixed number of HDF5 objects
  !> whatever n), each with its checksum.
  subroutine write_piece(path, hash, res, error)
    character(len=*), intent(in) :: path, hash
    !> the samples, in the order they were computed [n >= 1], all of the same shapes
    type(sample_result_t), intent(in) :: res(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    integer :: n, nd, ns, ne, j, c
    integer(i8) :: nnz
    integer, allocatable :: setid(:), idx(:), rk(:), ibuf(:,:), i1(:)
    real(wp), allocatable :: r1(:), rbuf(:,:)
    integer(i8), allocatable :: l1(:)
    n = size(res)
    nd = size(res(1)%q, 1); ns = size(res(1)%q, 2) - 1; ne = size(res(1)%mu)
    allocate(setid(n), idx(n), rk(n))
    do j = 1, n
      setid(j) = merge(1, 2, trim(res(j)%set) == SET_NAMES(1))
      idx(j) = res(j)%index
      rk(j) = res(j)%rank
    end do
    call h5%create(path, error)
    if (allocated(error)) return
    ops: block
      call h5%write_attr("/", "schema", PIECE_SCHEMA, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "schema_version", PIECE_SCHEMA_VERSION, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "config_hash", hash, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "n_samples", n, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "set_names", SET_NAMES(1) // "," // SET_NAMES(2), error); if (allocated(error)) exit ops
      call h5%write_attr("/", "checksum_algorithm", DIGEST_ALGORITHM, error); if (allocated(error)) exit ops
      call wi1("set_id", setid, error); if (allocated(error)) exit ops
      call wi1("index", idx, error); if (allocated(error)) exit ops
      call wi1("rank", rk, error); if (allocated(error)) exit ops
      call wr1("time", [(res(j)%time, j = 1, n)], error); if (allocated(error)) exit ops
      call wr1("start", [(res(j)%start, j = 1, n)], error); if (allocated(error)) exit ops
      allocate(rbuf(ne, n))
      do j = 1, n
        rbuf(:, j) = res(j)%mu
      end do
      call wr2("mu", rbuf, error); if (allocated(error)) exit ops
      deallocate(rbuf); allocate(rbuf(nd, (ns + 1) * n))
      do j = 1, n
        rbuf(:, (j - 1) * (ns + 1) + 1:j * (ns + 1)) = res(j)%q
      end do
      call wr2("positions", rbuf, error); if (allocated(error)) exit ops
      deallocate(rbuf); allocate(rbuf(nd, ns * n))
      do j = 1, n
        rbuf(:, (j - 1) * ns + 1:j * ns) = res(j)%u
      end do
      call wr2("velocities", rbuf, error); if (allocated(error)) exit ops
      do j = 1, n
        rbuf(:, (j - 1) * ns + 1:j * ns) = res(j)%v
      end do
      call wr2("desired", rbuf, error); if (allocated(error)) exit ops
      deallocate(rbuf); allocate(rbuf(ns, n), ibuf(ns, n))
      do j = 1, n
        rbuf(:, j) = res(j)%kkt
      end do
      call wr2("kkt", rbuf, error); if (allocated(error)) exit ops
      do j = 1, n
        rbuf(:, j) = res(j)%min_gap
      end do
      call wr2("min_gap", rbuf, error); if (allocated(error)) exit ops
      do j = 1, n
        ibuf(:, j) = res(j)%iterations
      end do
      call wi2("iterations", ibuf, error); if (allocated(error)) exit ops
      do j = 1, n
        ibuf(:, j) = res(j)%converged
      end do
      call wi2("converged", ibuf, error); if (allocated(error)) exit ops
      do j = 1, n
        ibuf(:, j) = res(j)%n_active
      end do
      call wi2("n_active", ibuf, error); if (allocated(error)) exit ops
      ! multipliers: per-sample CSR offsets [(ns+1) n], entries concatenated [sum of nnz]
      allocate(l1((ns + 1) * n))
      nnz = 0
      do j = 1, n
        l1((j - 1) * (ns + 1) + 1:j * (ns + 1)) = res(j)%offset
        nnz = nnz + size(res(j)%value)
      end do
      call wl1("lambda_offset", l1, error); if (allocated(error)) exit ops
      deallocate(l1); allocate(l1(nnz), i1(nnz), r1(nnz))
      c = 0
      do j = 1, n
        l1(c + 1:c + size(res(j)%key)) = res(j)%key
        c = c + size(res(j)%key)
      end do
      call wl1("lambda_key", l1, error); if (allocated(error)) exit ops
      call cat_int(1); call wi1("lambda_ia", i1, error); if (allocated(error)) exit ops
      call cat_int(2); call wi1("lambda_ib", i1, error); if (allocated(error)) exit ops
      call cat_int(3); call wi1("lambda_ob", i1, error); if (allocated(error)) exit ops
      c = 0
      do j = 1, n
        r1(c + 1:c + size(res(j)%value)) = res(j)%value
        c = c + size(res(j)%value)
      end do
      call wr1("lambda_value", r1, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "complete", 1, error); if (allocated(error)) exit ops
      call h5%commit(error)
    end block ops
    if (allocated(error)) then
      call h5%abort()
      call prefix_error(error, "piece '" // path // "'")
    end if

  contains

    subroutine cat_int(which)
      integer, intent(in) :: which
      integer :: q, cc, m
      cc = 0
      do q = 1, n
        m = size(res(q)%ia)
        select case (which)
        case (1); i1(cc + 1:cc + m) = res(q)%ia
        case (2); i1(cc + 1:cc + m) = res(q)%ib
        case default; i1(cc + 1:cc + m) = res(q)%ob
        end select
        cc = cc + m
      end do
    end subroutine cat_int

    subroutine wr1(name, x, error)
      character(len=*), intent(in) :: name
      real(wp), intent(in) :: x(:)
      type(error_t), allocatable, intent(out) :: error
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine wr1

    subroutine wr2(name, x, error)
      character(len=*), intent(in) :: name
      real(wp), intent(in) :: x(:,:)
      type(error_t), allocatable, intent(out) :: error
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine wr2

    subroutine wi1(name, x, error)
      character(len=*), intent(in) :: name
      integer, intent(in) :: x(:)
      type(error_t), allocatable, intent(out) :: error
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine wi1

    subroutine wi2(name, x, error)
      character(len=*), intent(in) :: name
      integer, intent(in) :: x(:,:)
      type(error_t), allocatable, intent(out) :: error
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine wi2

    subroutine wl1(name, x, error)
      character(len=*), intent(in) :: name
      integer(i8), intent(in) :: x(:)
      type(error_t), allocatable, intent(out) :: error
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine wl1
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
    character(len=:), allocatable :: schema
    integer :: version, n, complete, j
    integer, allocatable :: setid(:)
    type(error_t), allocatable :: e2
    hash = ""
    allocate(sets(0), idx(0))
    call h5%open(path, error)
    if (allocated(error)) then
      call prefix_error(error, "piece '" // path // "'"); return
    end if
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
      call h5%read("set_id", setid, error); if (allocated(error)) exit ops
      call h5%read("index", idx, error); if (allocated(error)) exit ops
      if (n < 1 .or. size(setid) /= n .or. size(idx) /= n) then
        call set_error(error, "n_samples = " // str(n) // " does not match set_id / index"); exit ops
      end if
      if (any(setid < 1 .or. setid > 2)) then
        call set_error(error, "set_id holds values other than 1 (train) and 2 (valid)"); exit ops
      end if
      deallocate(sets)
      allocate(sets(n))
      do j = 1, n
        sets(j) = SET_NAMES(setid(j))
      end do
    end block ops
    call h5%close(e2)
    if (allocated(error)) call prefix_error(error, "piece '" // path // "'")
  end subroutine piece_header

  !> Read every sample of a piece, verifying each dataset's checksum and the internal
  !> consistency of each sample (shapes, finite values, multiplier layout). Identity against the
  !> study is check_sample's job. Errors start with "piece '<path>'". Steps: the datasets
  !> (read_piece_data), their shapes and CSR layout (check_piece_shapes), the contact indices
  !> (check_piece_indices), the values (check_piece_values), the split into samples (split_piece).
  subroutine read_piece(path, res, error)
    character(len=*), intent(in) :: path
    type(sample_result_t), allocatable, intent(out) :: res(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    type(piece_data_t) :: pd
    pd%what = "piece '" // path // "'"
    allocate(res(0))
    call h5%open(path, error)
    if (allocated(error)) then
      call prefix_error(error, pd%what); return
    end if
    ops: block
      call read_piece_data(h5, pd, error); if (allocated(error)) exit ops
      call check_piece_shapes(pd, error); if (allocated(error)) exit ops
      ! indices in range (a piece whose checksums were re-stamped over edited indices)
      call check_piece_indices(pd, error); if (allocated(error)) exit ops
      call check_piece_values(pd, error); if (allocated(error)) exit ops
      deallocate(res)
      call split_piece(pd, res)
    end block ops
    call h5%close(e2)
    if (allocated(error)) then
      if (size(res) > 0) deallocate(res)
      if (.not. allocated(res)) allocate(res(0))
      if (index(error%message, pd%what) /= 1) call prefix_error(error, pd%what)
    end if
  end subroutine read_piece

  !> Every dataset of a piece, each against its checksum (messages name the piece and, once
  !> known, its samples: pd%w).
  subroutine read_piece_data(h5, pd, error)
    type(h5file_t), intent(inout) :: h5
    type(piece_data_t), intent(inout) :: pd
    type(error_t), allocatable, intent(out) :: error
    integer :: n
    call h5%read_attr("/", "n_samples", pd%n, error); if (allocated(error)) return
    n = pd%n
    call read_checked(h5, "set_id", pd%what, error, i1=pd%setid); if (allocated(error)) return
    call read_checked(h5, "index", pd%what, error, i1=pd%idx); if (allocated(error)) return
    if (n < 1 .or. size(pd%setid) /= n .or. size(pd%idx) /= n .or. any(pd%setid < 1 .or. pd%setid > 2)) then
      call set_error(error, pd%what // ": n_samples, set_id and index disagree"); return
    end if
    pd%w = pd%what // " (" // samples_text(pd%setid, pd%idx) // ")"
    associate (w => pd%w)
    call read_checked(h5, "rank", w, error, i1=pd%rk); if (allocated(error)) return
    call read_checked(h5, "time", w, error, r1=pd%tm); if (allocated(error)) return
    call read_checked(h5, "start", w, error, r1=pd%st); if (allocated(error)) return
    call read_checked(h5, "mu", w, error, r2=pd%mu); if (allocated(error)) return
    call read_checked(h5, "positions", w, error, r2=pd%q); if (allocated(error)) return
    call read_checked(h5, "velocities", w, error, r2=pd%u); if (allocated(error)) return
    call read_checked(h5, "desired", w, error, r2=pd%v); if (allocated(error)) return
    call read_checked(h5, "kkt", w, error, r2=pd%kkt); if (allocated(error)) return
    call read_checked(h5, "min_gap", w, error, r2=pd%gap); if (allocated(error)) return
    call read_checked(h5, "iterations", w, error, i2=pd%iters); if (allocated(error)) return
    call read_checked(h5, "converged", w, error, i2=pd%conv); if (allocated(error)) return
    call read_checked(h5, "n_active", w, error, i2=pd%nact); if (allocated(error)) return
    call read_checked(h5, "lambda_offset", w, error, l1=pd%off); if (allocated(error)) return
    call read_checked(h5, "lambda_key", w, error, l1=pd%key); if (allocated(error)) return
    call read_checked(h5, "lambda_ia", w, error, i1=pd%ia); if (allocated(error)) return
    call read_checked(h5, "lambda_ib", w, error, i1=pd%ib); if (allocated(error)) return
    call read_checked(h5, "lambda_ob", w, error, i1=pd%ob); if (allocated(error)) return
    call read_checked(h5, "lambda_value", w, error, r1=pd%val); if (allocated(error)) return
    end associate
  end subroutine read_piece_data

  !> Dataset `name` into the one array given (i1, i2, l1, r1 or r2), against its checksum;
  !> desc names the piece in messages.
  subroutine read_checked(h5, name, desc, error, i1, i2, l1, r1, r2)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: name, desc
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable, intent(inout), optional :: i1(:), i2(:,:)
    integer(i8), allocatable, intent(inout), optional :: l1(:)
    real(wp), allocatable, intent(inout), optional :: r1(:), r2(:,:)
    if (present(i1)) then
      call h5%read(name, i1, error); if (allocated(error)) return
      call check_digest(h5, name, digest_of(i1, 0_i8), desc, error)
    else if (present(i2)) then
      call h5%read(name, i2, error); if (allocated(error)) return
      call check_digest(h5, name, digest_of(i2, 0_i8), desc, error)
    else if (present(l1)) then
      call h5%read(name, l1, error); if (allocated(error)) return
      call check_digest(h5, name, digest_of(l1, 0_i8), desc, error)
    else if (present(r1)) then
      call h5%read(name, r1, error); if (allocated(error)) return
      call check_digest(h5, name, digest_of(r1, 0_i8), desc, error)
    else if (present(r2)) then
      call h5%read(name, r2, error); if (allocated(error)) return
      call check_digest(h5, name, digest_of(r2, 0_i8), desc, error)
    end if
  end subroutine read_checked

  !> The datasets' shapes agree (n samples of ns steps, nd degrees of freedom), the multiplier
  !> arrays have one length and lambda_offset is a CSR layout of that many multipliers.
  subroutine check_piece_shapes(pd, error)
    type(piece_data_t), intent(inout) :: pd
    type(error_t), allocatable, intent(out) :: error
    integer :: j, n, ns, nd
    integer(i8) :: m, nnz
    n = pd%n
    pd%ns = size(pd%kkt, 1); pd%nd = size(pd%q, 1)
    ns = pd%ns; nd = pd%nd
    associate (w => pd%w)
    if (ns < 1 .or. size(pd%rk) /= n .or. size(pd%tm) /= n .or. size(pd%st) /= n .or. size(pd%mu, 2) /= n .or. &
        size(pd%q, 2) /= (ns + 1) * n .or. any(shape(pd%u) /= [nd, ns * n]) .or. &
        any(shape(pd%v) /= [nd, ns * n]) .or. any(shape(pd%kkt) /= [ns, n]) .or. &
        any(shape(pd%gap) /= [ns, n]) .or. any(shape(pd%iters) /= [ns, n]) .or. &
        any(shape(pd%conv) /= [ns, n]) .or. any(shape(pd%nact) /= [ns, n]) .or. size(pd%off) /= (ns + 1) * n) then
      call set_error(error, w // ": inconsistent dataset shapes"); return
    end if
    nnz = size(pd%val, kind=i8)
    pd%nnz = nnz
    if (size(pd%key, kind=i8) /= nnz .or. size(pd%ia, kind=i8) /= nnz .or. size(pd%ib, kind=i8) /= nnz .or. &
        size(pd%ob, kind=i8) /= nnz) then
      call set_error(error, w // ": multiplier arrays of different lengths"); return
    end if
    m = 0
    do j = 1, n
      associate (o => pd%off((j - 1) * (ns + 1) + 1:j * (ns + 1)))
        if (o(1) /= 0 .or. any(o(2:) < o(:ns))) then
          call set_error(error, w // ": lambda_offset is not a CSR layout"); return
        end if
        m = m + o(ns + 1)
      end associate
    end do
    if (m /= nnz) then
      call set_error(error, w // ": lambda_offset counts " // str(m) // " multipliers, lambda_value holds " // &
        str(nnz)); return
    end if
    end associate
  end subroutine check_piece_shapes

  !> Contact indices of the multipliers: ia in 1..n_agents, ib in 0..n_agents (0: an obstacle
  !> contact) and not ia, ob > 0 exactly when ib = 0, lambda_key the key of (ia, ib, ob);
  !> solver counts and ranks >= 0.
  subroutine check_piece_indices(pd, error)
    type(piece_data_t), intent(in) :: pd
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: bad
    integer :: na
    integer(i8) :: l
    na = pd%nd / 2
    bad = ""
    associate (ia => pd%ia, ib => pd%ib, ob => pd%ob, key => pd%key)
    do l = 1, pd%nnz
      if (ia(l) < 1 .or. ia(l) > na) then
        bad = "dataset 'lambda_ia': index " // str(ia(l)) // " outside 1.." // str(na)
      else if (ib(l) < 0 .or. ib(l) > na .or. ib(l) == ia(l)) then
        bad = "dataset 'lambda_ib': index " // str(ib(l)) // " outside 0.." // str(na) // " or equal to lambda_ia"
      else if (ob(l) < 0 .or. (ob(l) > 0 .neqv. ib(l) == 0)) then
        bad = "dataset 'lambda_ob': index " // str(ob(l)) // " negative, or not > 0 exactly where lambda_ib = 0"
      else if (key(l) /= contact_key(ia(l), ib(l), ob(l))) then
        bad = "dataset 'lambda_key': not the key of (lambda_ia, lambda_ib, lambda_ob)"
      end if
      if (len(bad) > 0) then
        call set_error(error, pd%w // ": " // bad // " at entry " // str(int(l))); return
      end if
    end do
    end associate
    if (any(pd%rk < 0)) then
      call set_error(error, pd%w // ": dataset 'rank' holds a negative rank"); return
    end if
    if (any(pd%iters < 0) .or. any(pd%nact < 0)) then
      call set_error(error, pd%w // ": dataset 'iterations' or 'n_active' holds a negative count"); return
    end if
  end subroutine check_piece_indices

  !> Finite values, positive multipliers, converged flags 0 or 1.
  subroutine check_piece_values(pd, error)
    type(piece_data_t), intent(in) :: pd
    type(error_t), allocatable, intent(out) :: error
    associate (w => pd%w)
    call need_finite_in(w, reshape(pd%mu, [size(pd%mu)]), "mu", error); if (allocated(error)) return
    call need_finite_in(w, reshape(pd%q, [size(pd%q)]), "positions", error); if (allocated(error)) return
    call need_finite_in(w, reshape(pd%u, [size(pd%u)]), "velocities", error); if (allocated(error)) return
    call need_finite_in(w, reshape(pd%v, [size(pd%v)]), "desired", error); if (allocated(error)) return
    call need_finite_in(w, reshape(pd%kkt, [size(pd%kkt)]), "kkt", error); if (allocated(error)) return
    call need_finite_in(w, pd%val, "lambda_value", error); if (allocated(error)) return
    call need_finite_in(w, [pd%tm, pd%st], "time", error); if (allocated(error)) return
    if (any(pd%val <= 0)) then
      call set_error(error, w // ": lambda_value holds multipliers <= 0 (only lambda > 0 are stored)"); return
    end if
    if (any(pd%conv /= 0 .and. pd%conv /= 1)) then
      call set_error(error, w // ": converged holds values other than 0 and 1"); return
    end if
    end associate
  end subroutine check_piece_values

  !> Record an error unless every element of x is finite (w names the piece).
  subroutine need_finite_in(w, x, name, error)
    character(len=*), intent(in) :: w
    real(wp), intent(in) :: x(:)
    character(len=*), intent(in) :: name
    type(error_t), allocatable, intent(out) :: error
    integer :: i
    if (all(ieee_is_finite(x))) return
    do i = 1, size(x)
      if (.not. ieee_is_finite(x(i))) exit
    end do
    call set_error(error, w // ": dataset '" // name // "' holds a non-finite value (NaN or Inf) at element " // &
      str(i))
  end subroutine need_finite_in

  !> The checked datasets of a piece split into its samples.
  subroutine split_piece(pd, res)
    type(piece_data_t), intent(in) :: pd
    type(sample_result_t), allocatable, intent(out) :: res(:)
    integer :: j, c, ns
    integer(i8) :: m
    ns = pd%ns
    allocate(res(pd%n))
    c = 0
    do j = 1, pd%n
      res(j)%set = SET_NAMES(pd%setid(j)); res(j)%index = pd%idx(j); res(j)%rank = pd%rk(j)
      res(j)%time = pd%tm(j); res(j)%start = pd%st(j)
      res(j)%mu = pd%mu(:, j)
      res(j)%q = pd%q(:, (j - 1) * (ns + 1) + 1:j * (ns + 1))
      res(j)%u = pd%u(:, (j - 1) * ns + 1:j * ns)
      res(j)%v = pd%v(:, (j - 1) * ns + 1:j * ns)
      res(j)%kkt = pd%kkt(:, j); res(j)%min_gap = pd%gap(:, j)
      res(j)%iterations = pd%iters(:, j); res(j)%converged = pd%conv(:, j); res(j)%n_active = pd%nact(:, j)
      res(j)%offset = pd%off((j - 1) * (ns + 1) + 1:j * (ns + 1))
      m = res(j)%offset(ns + 1)
      res(j)%key = pd%key(c + 1:c + m); res(j)%ia = pd%ia(c + 1:c + m); res(j)%ib = pd%ib(c + 1:c + m)
      res(j)%ob = pd%ob(c + 1:c + m); res(j)%value = pd%val(c + 1:c + m)
      c = c + int(m)
    end do
  end subroutine split_piece

  !> "train sample 3" or "train samples 3, 7, valid sample 2" (at most 6 listed).
  function samples_text(setid, idx) result(t)
    integer, intent(in) :: setid(:), idx(:)
    character(len=:), allocatable :: t
    integer :: j
    if (size(idx) == 1) then
      t = trim(SET_NAMES(setid(1))) // " sample " // str(idx(1)); return
    end if
    t = ""
    do j = 1, min(size(idx), 6)
      if (j > 1) t = t // ", "
      t = t // trim(SET_NAMES(setid(j))) // " " // str(idx(j))
    end do
    if (size(idx) > 6) t = t // ", ..."
    t = str(size(idx)) // " samples: " // t
  end function samples_text

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
