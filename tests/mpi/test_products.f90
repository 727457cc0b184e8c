!> The inter-stage products (src/products): round trips (write, read back, compare exactly) of
!> the snapshot database (written and read in parallel, each rank its block), the ROM file,
!> the full-order output and the ROM-run file; and families of corrupt files every reader must
!> refuse with an input error naming the file and the dataset: NaN / +Inf / -Inf in each float
!> dataset that must be finite, indices out of range, attributes contradicting the shapes, and
!> schema versions the reader does not know. Run at 1 and 2 ranks (the corrupt families on
!> rank 0, serially).
program test_products
  use mpi_f08, only: MPI_Init, MPI_Finalize, MPI_COMM_WORLD, MPI_COMM_SELF
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_positive_inf, ieee_negative_inf
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_assert, only: check, test_summary
  use cr_distribution, only: block_range
  use cr_fsys, only: remove_file
  use cr_h5file, only: h5file_t
  use cr_config, only: config_t, read_config
  use cr_scene, only: scene_t
  use cr_fom, only: fom_t, step_record_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_fom_file, only: fom_writer_t, fom_file_t, read_fom_file
  use cr_snapshot_file, only: SNAP_SCHEMA, SNAP_SCHEMA_VERSION, snap_header_t, snap_block_t, read_snap_header, &
    read_snap_block, snap_sample_t, move_sample
  use cr_digest, only: digest_t, digest_of, digest_add, digest_pack, put_digest
  use cr_rom_file, only: rom_file_t, rom_pair_t, write_rom_file, read_rom_file, read_rom_pair
  use cr_hyper_factory, only: stored_hypers
  use cr_hyper_eim, only: hyper_eim_t
  use cr_hyper_eq, only: hyper_eq_t
  use cr_eim, only: eim_t
  use cr_romrun_file, only: romrun_header_t, romrun_row_t, romrun_set_t, romrun_t, romrun_writer_t, read_romrun
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  integer, parameter :: NA = 3, NT = 2, NE = 2, NDICT = 4
  integer, parameter :: DICT_IA(NDICT) = [1, 1, 2, 3], DICT_IB(NDICT) = [2, 0, 3, 0], DICT_OB(NDICT) = [0, 1, 0, 2]
  type(env_t) :: env, self
  type(error_t), allocatable :: error
  real(wp) :: bad(3)
  character(len=4), parameter :: BAD_NAMES(3) = ['NaN ', '+Inf', '-Inf']
  integer :: ierr

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call check(.not. allocated(error), "env init")
  call self%init(MPI_COMM_SELF, error)
  bad = [ieee_value(1.0_wp, ieee_quiet_nan), ieee_value(1.0_wp, ieee_positive_inf), &
    ieee_value(1.0_wp, ieee_negative_inf)]

  call snapshot_roundtrip()
  if (env%rank == 0) then
    call sample_move()
    call snapshot_corrupt()
    call rom_roundtrip()
    call rom_corrupt()
    call fom_roundtrip_and_corrupt()
    call romrun_roundtrip()
    call romrun_corrupt()
  end if
  call test_summary(env%rank)
  call MPI_Finalize(ierr)

contains

  !> move_sample hands every component of a full sample to the target (equal to a copy made
  !> before) and leaves the source empty.
  subroutine sample_move()
    type(snap_sample_t) :: a, b, c
    integer :: k
    logical :: ok
    a%set = 'valid'; a%index = 7; a%time = 1.5_wp; a%start = 2.5_wp; a%rank = 3
    a%scene_exit = [1.0_wp, 2.0_wp, 3.0_wp, 4.0_wp]
    a%mu = [0.1_wp, 0.2_wp]
    a%q = reshape([(real(k, wp), k = 1, 12)], [4, 3])
    a%u = reshape([(real(-k, wp), k = 1, 8)], [4, 2]); a%v = 2 * a%u
    a%kkt = [1.0e-12_wp, 2.0e-12_wp]; a%min_gap = [0.0_wp, -1.0e-16_wp]
    a%iterations = [3, 4]; a%converged = [1, 0]; a%n_active = [1, 2]
    a%offset = [0_i8, 1_i8, 3_i8]; a%key = [11_i8, 12_i8, 13_i8]
    a%ia = [1, 1, 2]; a%ib = [2, 0, 0]; a%ob = [0, 1, 2]; a%value = [0.5_wp, 0.25_wp, 0.125_wp]
    a%scene_v = [0.0_wp, 1.0_wp, 2.0_wp, 3.0_wp]
    c = a
    call move_sample(a, b)
    call check(b%set == c%set .and. b%index == c%index .and. b%time == c%time .and. &
      b%start == c%start .and. b%rank == c%rank .and. all(b%scene_exit == c%scene_exit), &
      "move_sample: scalars")
    ok = allocated(b%mu) .and. allocated(b%q) .and. allocated(b%u) .and. allocated(b%v) .and. &
      allocated(b%kkt) .and. allocated(b%min_gap) .and. allocated(b%iterations) .and. &
      allocated(b%converged) .and. allocated(b%n_active) .and. allocated(b%offset) .and. &
      allocated(b%key) .and. allocated(b%ia) .and. allocated(b%ib) .and. allocated(b%ob) .and. &
      allocated(b%value) .and. allocated(b%scene_v)
    call check(ok, "move_sample: every array component handed over")
    if (.not. ok) return
    call check(all(b%mu == c%mu) .and. all(b%q == c%q) .and. all(b%u == c%u) .and. all(b%v == c%v) &
      .and. all(b%kkt == c%kkt) .and. all(b%min_gap == c%min_gap), "move_sample: real arrays")
    call check(all(b%iterations == c%iterations) .and. all(b%converged == c%converged) .and. &
      all(b%n_active == c%n_active) .and. all(b%offset == c%offset) .and. all(b%key == c%key) &
      .and. all(b%ia == c%ia) .and. all(b%ib == c%ib) .and. all(b%ob == c%ob), &
      "move_sample: integer arrays")
    call check(all(b%value == c%value) .and. all(b%scene_v == c%scene_v), "move_sample: multipliers, scene")
    call check(.not. (allocated(a%mu) .or. allocated(a%q) .or. allocated(a%u) .or. allocated(a%v) .or. &
      allocated(a%kkt) .or. allocated(a%min_gap) .or. allocated(a%iterations) .or. &
      allocated(a%converged) .or. allocated(a%n_active) .or. allocated(a%offset) .or. &
      allocated(a%key) .or. allocated(a%ia) .or. allocated(a%ib) .or. allocated(a%ob) .or. &
      allocated(a%value) .or. allocated(a%scene_v)) .and. a%index == 0 .and. a%rank == -1, &
      "move_sample: source left empty")
  end subroutine sample_move

  ! ------------------------------------------------------------------ helpers

  !> The reader refused with an input error naming the file and `what`.
  subroutine expect_refusal(error, path, what, name)
    type(error_t), allocatable, intent(in) :: error
    character(len=*), intent(in) :: path, what, name
    logical :: ok
    ok = allocated(error)
    if (ok) ok = error%code == EXIT_BAD_INPUT .and. index(error%message, path) > 0 .and. index(error%message, what) > 0
    if (.not. ok .and. allocated(error)) print '(a)', "   got: " // error%message
    call check(ok, name // ": refused with a message naming '" // path // "' and '" // what // "'")
  end subroutine expect_refusal

  !> Set entry `at` (column-major, 1-based) of real dataset `name` to x.
  subroutine poke_real(path, name, at, x)
    character(len=*), intent(in) :: path, name
    integer, intent(in) :: at
    real(wp), intent(in) :: x
    type(h5file_t) :: h5
    integer(i8), allocatable :: d(:)
    real(wp), allocatable :: a1(:), a2(:,:), flat(:)
    call h5%open(path, error, readwrite=.true.); call check(.not. allocated(error), "poke: open " // name)
    call h5%get_dims(name, d, error); call check(.not. allocated(error), "poke: dims " // name)
    if (size(d) == 1) then
      call h5%read(name, a1, error)
      a1(at) = x
      call h5%write(name, a1, error)
    else
      call h5%read(name, a2, error)
      flat = reshape(a2, [size(a2)])
      flat(at) = x
      a2 = reshape(flat, shape(a2))
      call h5%write(name, a2, error)
    end if
    call check(.not. allocated(error), "poke: write " // name)
    call h5%close(error)
  end subroutine poke_real

  !> Set entry `at` of integer dataset `name` (rank 1 or 2) to x.
  subroutine poke_int(path, name, at, x)
    character(len=*), intent(in) :: path, name
    integer, intent(in) :: at, x
    type(h5file_t) :: h5
    integer(i8), allocatable :: d(:)
    integer, allocatable :: a1(:), a2(:,:), flat(:)
    call h5%open(path, error, readwrite=.true.); call check(.not. allocated(error), "poke: open " // name)
    call h5%get_dims(name, d, error)
    if (size(d) == 1) then
      call h5%read(name, a1, error)
      a1(at) = x
      call h5%write(name, a1, error)
    else
      call h5%read(name, a2, error)
      flat = reshape(a2, [size(a2)])
      flat(at) = x
      a2 = reshape(flat, shape(a2))
      call h5%write(name, a2, error)
    end if
    call check(.not. allocated(error), "poke: write " // name)
    call h5%close(error)
  end subroutine poke_int

  subroutine poke_int64(path, name, at, x)
    character(len=*), intent(in) :: path, name
    integer, intent(in) :: at
    integer(i8), intent(in) :: x
    type(h5file_t) :: h5
    integer(i8), allocatable :: a1(:)
    call h5%open(path, error, readwrite=.true.)
    call h5%read(name, a1, error)
    a1(at) = x
    call h5%write(name, a1, error)
    call check(.not. allocated(error), "poke: write " // name)
    call h5%close(error)
  end subroutine poke_int64

  subroutine poke_attr(path, obj, name, x)
    character(len=*), intent(in) :: path, obj, name
    integer, intent(in) :: x
    type(h5file_t) :: h5
    call h5%open(path, error, readwrite=.true.)
    call h5%write_attr(obj, name, x, error)
    call check(.not. allocated(error), "poke: attribute " // name)
    call h5%close(error)
  end subroutine poke_attr

  ! ------------------------------------------------------------------ snapshot database

  pure real(wp) function sval(set, kg, i, j, what)
    integer, intent(in) :: set, kg, i, j, what
    sval = 1000.0_wp * what + 100.0_wp * set + 10.0_wp * kg + i + 0.01_wp * j
  end function sval

  !> Samples k0..k0+nloc-1 of set `set` (1 train, 2 valid) of the synthetic database.
  function make_block(set, n, k0, nloc) result(b)
    integer, intent(in) :: set, n, k0, nloc
    type(snap_block_t) :: b
    integer :: k, kg, i, j, c, e, nnz
    b%name = trim(merge('train', 'valid', set == 1)); b%n = n; b%k0 = k0; b%nloc = nloc
    allocate(b%mu(NE, nloc), b%q(2 * NA, (NT + 1) * nloc), b%u(2 * NA, NT * nloc), b%v(2 * NA, NT * nloc), &
      b%kkt(NT, nloc), b%min_gap(NT, nloc), b%iterations(NT, nloc), b%converged(NT, nloc), b%n_active(NT, nloc), &
      b%time(nloc), b%rank(nloc), b%lam_ptr(NT * nloc + 1))
    nnz = 0
    b%lam_ptr(1) = 0
    do k = 1, nloc
      kg = k0 + k - 1
      b%mu(:, k) = [real(kg, wp), 0.5_wp * kg + set]
      do j = 1, NT + 1
        do i = 1, 2 * NA
          b%q(i, (k - 1) * (NT + 1) + j) = sval(set, kg, i, j, 1)
        end do
      end do
      do j = 1, NT
        do i = 1, 2 * NA
          b%u(i, (k - 1) * NT + j) = sval(set, kg, i, j, 2)
          b%v(i, (k - 1) * NT + j) = sval(set, kg, i, j, 3)
        end do
        c = (k - 1) * NT + j
        nnz = nnz + mod(kg + j, 3)
        b%lam_ptr(c + 1) = nnz
      end do
      b%kkt(:, k) = 1.0e-9_wp * kg; b%min_gap(:, k) = 0.01_wp * kg
      b%iterations(:, k) = kg; b%converged(:, k) = 1; b%n_active(:, k) = kg + 1
      b%time(k) = 0.1_wp * kg; b%rank(k) = 0
    end do
    allocate(b%lam_idx(nnz), b%lam_val(nnz))
    nnz = 0
    do k = 1, nloc
      kg = k0 + k - 1
      do j = 1, NT
        do e = 1, mod(kg + j, 3)
          nnz = nnz + 1
          b%lam_idx(nnz) = 1 + mod(kg * j + e, NDICT)
          b%lam_val(nnz) = kg + 0.1_wp * j + e
        end do
      end do
    end do
  end function make_block

  !> Write the synthetic database (3 train, 2 valid samples; every dataset with its checksum and,
  !> from schema version 2 on, each set's per-sample block table) on the ranks of `e` (the file is
  !> opened in parallel; rank 0 writes the data). `version`: schema version (default the current).
  subroutine write_db(e, path, version)
    type(env_t), intent(in) :: e
    character(len=*), intent(in) :: path
    integer, intent(in), optional :: version
    type(h5file_t) :: h5
    type(snap_block_t) :: b
    real(wp), allocatable :: q0(:)
    integer :: set, n, v
    character(len=:), allocatable :: g
    integer, allocatable :: tab(:,:)
    v = SNAP_SCHEMA_VERSION
    if (present(version)) v = version
    q0 = [(0.1_wp * n, n = 1, 2 * NA)]
    call h5%create(path, error, env=e); call check(.not. allocated(error), "db: create")
    call h5%write_attr("/", "schema", SNAP_SCHEMA, error)
    call h5%write_attr("/", "schema_version", v, error)
    call h5%write_attr("/", "config", "&time n_steps = 2 /", error)
    call h5%write_attr("/", "config_hash", "0123456789abcdef", error)
    call h5%write_attr("/", "param_names", "l_exit,speed", error)
    call h5%write_attr("/", "n_agents", NA, error)
    call h5%write_attr("/", "n_steps", NT, error)
    call h5%write_attr("/", "n_train", 3, error)
    call h5%write_attr("/", "n_valid", 2, error)
    call h5%write_attr("/", "n_params", NE, error)
    call h5%write_attr("/", "agent_radius", 0.04_wp, error)
    call h5%write_attr("/", "dt", 0.02_wp, error)
    call h5%write_attr("/", "complete", 1, error)
    call h5%write("initial_positions", q0, error)
    call put_digest(h5, "initial_positions", digest_of(q0, 0_i8), error)
    call h5%make_group("scene", error)
    call h5%write("scene/obstacle_kind", [1, 1], error)
    call h5%make_group("contacts", error)
    call h5%write("contacts/ia", DICT_IA, error)
    call put_digest(h5, "contacts/ia", digest_of(DICT_IA, 0_i8), error)
    call h5%write("contacts/ib", DICT_IB, error)
    call put_digest(h5, "contacts/ib", digest_of(DICT_IB, 0_i8), error)
    call h5%write("contacts/ob", DICT_OB, error)
    call put_digest(h5, "contacts/ob", digest_of(DICT_OB, 0_i8), error)
    call check(.not. allocated(error), "db: header")
    do set = 1, 2
      n = merge(3, 2, set == 1)
      b = make_block(set, n, 1, n)
      g = trim(b%name) // "/"
      call h5%make_group(trim(b%name), error)
      call h5%write(g // "params", b%mu, error)
      call put_digest(h5, g // "params", digest_of(b%mu, 0_i8), error)
      call h5%write(g // "positions", b%q, error)
      call put_digest(h5, g // "positions", digest_of(b%q, 0_i8), error)
      call h5%write(g // "velocities", b%u, error)
      call put_digest(h5, g // "velocities", digest_of(b%u, 0_i8), error)
      call h5%write(g // "desired", b%v, error)
      call put_digest(h5, g // "desired", digest_of(b%v, 0_i8), error)
      call h5%write(g // "lambda_offset", b%lam_ptr, error)
      call put_digest(h5, g // "lambda_offset", digest_of(b%lam_ptr, 0_i8), error)
      call h5%write(g // "lambda_index", b%lam_idx, error)
      call put_digest(h5, g // "lambda_index", digest_of(b%lam_idx, 0_i8), error)
      call h5%write(g // "lambda_value", b%lam_val, error)
      call put_digest(h5, g // "lambda_value", digest_of(b%lam_val, 0_i8), error)
      if (v >= 2) then
        tab = block_table(b)
        call h5%write(g // "sample_checksums", tab, error)
        call put_digest(h5, g // "sample_checksums", digest_of(tab, 0_i8), error)
      end if
      call check(.not. allocated(error), "db: set " // str(set))
    end do
    call h5%commit(error); call check(.not. allocated(error), "db: commit")
  end subroutine write_db

  !> The block table of a whole set [34, n] as crowd_snapshots writes it: per sample, the digests of
  !> its blocks of the 17 datasets (params, positions, velocities, desired, lambda_offset,
  !> lambda_index, lambda_value, then stats and scenes, not in this file: 0).
  function block_table(b) result(tab)
    type(snap_block_t), intent(in) :: b
    integer, allocatable :: tab(:,:)
    type(digest_t) :: d(17)
    integer(i8) :: k1, lo, hi
    integer :: k, q
    allocate(tab(34, b%n))
    do k = 1, b%n
      k1 = k - 1
      d = digest_t()
      d(1) = digest_of(b%mu(:, k), k1 * NE)
      d(2) = digest_of(b%q(:, k1 * (NT + 1) + 1:k * (NT + 1)), k1 * (NT + 1) * 2 * NA)
      d(3) = digest_of(b%u(:, k1 * NT + 1:k * NT), k1 * NT * 2 * NA)
      d(4) = digest_of(b%v(:, k1 * NT + 1:k * NT), k1 * NT * 2 * NA)
      d(5) = digest_of(b%lam_ptr(k1 * NT + 2:k * NT + 1), k1 * NT + 1)
      if (k == 1) d(5) = digest_add(d(5), digest_of(b%lam_ptr(1:1), 0_i8))
      lo = b%lam_ptr(k1 * NT + 1); hi = b%lam_ptr(k * NT + 1)
      d(6) = digest_of(b%lam_idx(lo + 1:hi), lo)
      d(7) = digest_of(b%lam_val(lo + 1:hi), lo)
      do q = 1, 17
        tab(2 * q - 1:2 * q, k) = digest_pack(d(q))
      end do
    end do
  end function block_table

  !> Read the whole database (header, both sets with desired velocities and multipliers).
  subroutine read_db(path, error)
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    type(snap_header_t) :: hdr
    type(snap_block_t) :: b
    call read_snap_header(path, "test", hdr, error); if (allocated(error)) return
    call read_snap_block(hdr, 'train', 1, hdr%n_train, .true., .true., b, error); if (allocated(error)) return
    call read_snap_block(hdr, 'valid', 1, hdr%n_valid, .true., .true., b, error)
  end subroutine read_db

  subroutine compare_block(b, ref, name)
    type(snap_block_t), intent(in) :: b, ref
    character(len=*), intent(in) :: name
    call check(all(b%mu == ref%mu) .and. all(b%q == ref%q) .and. all(b%u == ref%u) .and. all(b%v == ref%v), &
      name // ": params, positions, velocities, desired equal")
    call check(all(b%lam_ptr == ref%lam_ptr) .and. all(b%lam_idx == ref%lam_idx) .and. all(b%lam_val == ref%lam_val), &
      name // ": multipliers equal")
  end subroutine compare_block

  subroutine snapshot_roundtrip()
    type(snap_header_t) :: hdr
    type(snap_block_t) :: b
    character(len=:), allocatable :: path
    integer :: set, n, off, nloc
    path = "products_db_np" // str(env%size) // ".h5"
    call write_db(env, path)
    call read_snap_header(path, "test", hdr, error, env=env)
    call check(.not. allocated(error), "db: parallel header read")
    call check(hdr%n_agents == NA .and. hdr%n_steps == NT .and. hdr%n_train == 3 .and. hdr%n_valid == 2 .and. &
      hdr%n_params == NE .and. hdr%hash == "0123456789abcdef" .and. hdr%param_names == "l_exit,speed", "db: header")
    call check(all(hdr%dict_ia == DICT_IA) .and. all(hdr%dict_ib == DICT_IB) .and. all(hdr%dict_ob == DICT_OB), &
      "db: dictionary")
    do set = 1, 2
      n = merge(3, 2, set == 1)
      call block_range(n, env%size, env%rank, off, nloc)
      call read_snap_block(hdr, trim(merge('train', 'valid', set == 1)), off + 1, nloc, .true., .true., b, error, env=env)
      call check(.not. allocated(error), "db: parallel block read, set " // str(set))
      call compare_block(b, make_block(set, n, off + 1, nloc), "db np" // str(env%size) // " rank " // &
        str(env%rank) // " set " // str(set))
    end do
    if (env%rank == 0) then
      ! the whole file serially: the blocks written by every rank
      do set = 1, 2
        n = merge(3, 2, set == 1)
        call read_snap_block(hdr, trim(merge('train', 'valid', set == 1)), 1, n, .true., .true., b, error)
        call check(.not. allocated(error), "db: serial read")
        call compare_block(b, make_block(set, n, 1, n), "db serial set " // str(set))
      end do
    end if
    call env%sync(error)
    call check(.not. allocated(error), "db: barrier")
  end subroutine snapshot_roundtrip

  subroutine snapshot_corrupt()
    character(len=*), parameter :: path = "products_db_bad.h5"
    character(len=20), parameter :: floats(11) = [character(len=20) :: "initial_positions", "train/params", &
      "train/positions", "train/velocities", "train/desired", "train/lambda_value", "valid/params", &
      "valid/positions", "valid/velocities", "valid/desired", "valid/lambda_value"]
    integer :: k, b
    ! NaN / Inf in every float dataset that must be finite
    do k = 1, size(floats)
      do b = 1, 3
        call write_db(self, path)
        call poke_real(path, trim(floats(k)), 2, bad(b))
        call read_db(path, error)
        call expect_refusal(error, path, trim(floats(k)), "db " // trim(BAD_NAMES(b)) // " in " // trim(floats(k)))
      end do
    end do
    ! a finite value changed: the checksum of the dataset no longer matches
    call write_db(self, path)
    call poke_real(path, "train/positions", 5, 123.0_wp)
    call read_db(path, error)
    call expect_refusal(error, path, "checksum mismatch in dataset 'train/positions'", "db value edited")
    ! indices out of range
    call db_int_case("contacts/ia", 2, 0)
    call db_int_case("contacts/ia", 3, NA + 1)
    call db_int_case("contacts/ib", 1, -1)
    call db_int_case("contacts/ib", 1, NA + 1)
    call db_int_case("contacts/ob", 4, -2)
    call db_int_case("train/lambda_index", 1, 0)
    call db_int_case("train/lambda_index", 2, NDICT + 1)
    call db_int_case("valid/lambda_index", 1, -5)
    call write_db(self, path)
    call poke_int64(path, "train/lambda_offset", 3, 0_i8)
    call read_db(path, error)
    call expect_refusal(error, path, "train/lambda_offset", "db offsets decreasing")
    call write_db(self, path)
    call poke_int64(path, "valid/lambda_offset", 5, 1000_i8)
    call read_db(path, error)
    call expect_refusal(error, path, "valid/lambda_offset", "db offsets beyond the multipliers")
    ! attributes contradicting the shapes
    call db_attr_case("n_agents", NA + 1, "initial_positions")
    call db_attr_case("n_steps", NT + 1, "train/positions")
    call db_attr_case("n_train", 4, "train/params")
    call db_attr_case("n_valid", 1, "valid/params")
    call db_attr_case("n_params", NE + 1, "train/params")
    ! versions and completeness
    call db_attr_case("schema_version", 0, "schema version 0 is not supported (supported: 1, 2)")
    call db_attr_case("schema_version", 3, "schema version 3 is not supported (supported: 1, 2)")
    call db_attr_case("complete", 0, "not complete")
    ! contacts that are neither an agent pair nor an agent-obstacle contact, an obstacle beyond
    ! the scene's
    call db_int_case("contacts/ob", 1, 1)
    call db_int_case("contacts/ib", 3, 2)
    call db_int_case("contacts/ob", 4, 3)
    call partial_reads()
    k = remove_file(path)
  end subroutine snapshot_corrupt

  !> A serial read of some samples verifies them against the block table: edits inside them
  !> refused (the whole-dataset checksum cannot tell), an edit outside them not read; a version 1
  !> file (no table) refused for such a read, accepted whole; the table edited refused.
  subroutine partial_reads()
    character(len=*), parameter :: path = "products_db_part.h5"
    type(snap_header_t) :: hdr
    type(snap_block_t) :: b
    integer :: k
    call write_db(self, path)
    call read_part(path, hdr, b, 2, 2)
    call check(.not. allocated(error), "db part: samples 2..3 of a clean file read")
    if (.not. allocated(error)) call compare_block(b, make_block(1, 3, 2, 2), "db part: samples 2..3")
    ! one position of train sample 1 scaled (the stale checksum is not read by this reader)
    call poke_real(path, "train/positions", 3, 1.001_wp * sval(1, 1, 3, 1, 1))
    call read_part(path, hdr, b, 1, 1)
    call expect_refusal(error, path, "block checksum mismatch in dataset 'train/positions'", "db part: positions")
    call read_part(path, hdr, b, 2, 2)
    call check(.not. allocated(error), "db part: samples 2..3 unaffected by an edit in sample 1")
    call write_db(self, path)
    call poke_real(path, "train/velocities", 2 * NA * NT + 1, 7.0_wp)
    call read_part(path, hdr, b, 2, 1)
    call expect_refusal(error, path, "block checksum mismatch in dataset 'train/velocities'", "db part: velocities")
    call write_db(self, path)
    call poke_real(path, "train/lambda_value", 1, 0.5_wp)
    call read_part(path, hdr, b, 1, 2)
    call expect_refusal(error, path, "block checksum mismatch in dataset 'train/lambda_value'", "db part: multipliers")
    call write_db(self, path)
    call poke_int(path, "train/sample_checksums", 4, 12345)
    call read_part(path, hdr, b, 2, 1)
    call expect_refusal(error, path, "checksum mismatch in dataset 'train/sample_checksums'", "db part: table edited")
    call write_db(self, path, version=1)
    call read_part(path, hdr, b, 1, 2)
    call expect_refusal(error, path, "schema version 1 has no per-sample checksums", "db part: version 1")
    call read_part(path, hdr, b, 1, 3)
    call check(.not. allocated(error), "db part: a whole set of a version 1 file read")
    k = remove_file(path)
  end subroutine partial_reads

  !> Samples k0..k0+nloc-1 of the training set, read serially.
  subroutine read_part(path, hdr, b, k0, nloc)
    character(len=*), intent(in) :: path
    type(snap_header_t), intent(out) :: hdr
    type(snap_block_t), intent(out) :: b
    integer, intent(in) :: k0, nloc
    call read_snap_header(path, "test", hdr, error)
    if (allocated(error)) return
    call read_snap_block(hdr, 'train', k0, nloc, .true., .true., b, error)
  end subroutine read_part

  subroutine db_int_case(name, at, x)
    character(len=*), intent(in) :: name
    integer, intent(in) :: at, x
    character(len=*), parameter :: path = "products_db_bad.h5"
    call write_db(self, path)
    call poke_int(path, name, at, x)
    call read_db(path, error)
    call expect_refusal(error, path, name, "db " // name // "(" // str(at) // ") = " // str(x))
  end subroutine db_int_case

  subroutine db_attr_case(name, x, what)
    character(len=*), intent(in) :: name, what
    integer, intent(in) :: x
    character(len=*), parameter :: path = "products_db_bad.h5"
    call write_db(self, path)
    call poke_attr(path, "/", name, x)
    call read_db(path, error)
    call expect_refusal(error, path, what, "db attribute " // name // " = " // str(x))
  end subroutine db_attr_case

  ! ------------------------------------------------------------------ ROM file

  subroutine make_rom(rom, pair)
    type(rom_file_t), intent(out) :: rom
    type(rom_pair_t), intent(out) :: pair
    type(sparse_cone_t) :: cone
    integer :: i, j, k, l, p, m
    rom%config = "&offline /"; rom%database = "db.h5"; rom%db_hash = "0123456789abcdef"
    rom%n_agents = NA; rom%n_steps = NT; rom%radius = 0.04_wp; rom%dt = 0.02_wp
    rom%study_config = "&scene /"; rom%param_names = "l_exit"
    rom%q0 = [(0.1_wp * i, i = 1, 2 * NA)]
    rom%pod_method = "tsqr"; rom%pod_rank = 2; rom%pod_total_energy = 1.5_wp; rom%pod_sigma = [2.0_wp, 1.0_wp]
    allocate(rom%v(2 * NA, 3))
    do j = 1, 3
      do i = 1, 2 * NA
        rom%v(i, j) = 1.0_wp / (i + j)
      end do
    end do
    rom%n_pod = 2
    rom%cone%method = 'gis'; rom%cone%r = 2; rom%cone%indices = [1, 3]; rom%cone%sigma = [4_i8, 7_i8]
    rom%cone%err_max = [1.0_wp, 0.5_wp, 0.1_wp]; rom%cone%err_mean = [0.5_wp, 0.2_wp, 0.05_wp]
    rom%cone%time = 0.25_wp; rom%cone%note = "stopped"
    rom%pga_err = [0.3_wp, 0.1_wp]
    rom%dict_ia = DICT_IA; rom%dict_ib = DICT_IB; rom%dict_ob = DICT_OB
    allocate(rom%tables%is_n(0))
    rom%tables%t_pod = 1.25_wp
    pair%n = 2; pair%r = 2; pair%n_pga = 1; pair%nb = 3; pair%v = rom%v; pair%pga_err = rom%pga_err
    call cone%from_indices(NDICT, [1, 3])
    call pair%terms%init(cone, 2, DICT_IA, DICT_IB, DICT_OB, 2 * NA, error)
    call check(.not. allocated(error), "rom: candidate terms")
    pair%hyper = .true.
    ! every stored method of the factory, with made-up data
    call stored_hypers(pair%methods)
    call check(size(pair%methods) == 2, "rom: the factory stores two methods (eim, eq)")
    do l = 1, size(pair%methods)
      pair%methods(l)%m%time = 0.5_wp * l
      select type (hm => pair%methods(l)%m)
      type is (hyper_eim_t)
        do k = 1, 3
          call fake_eim(pair%terms%p(k), k, hm%eim(k))
        end do
      type is (hyper_eq_t)
        do k = 1, 3
          p = pair%terms%p(merge(1, 3, k == 1)); m = min(2, p)
          hm%eq(k)%p = p; hm%eq(k)%m = m
          hm%eq(k)%idx = [(p + 1 - j, j = 1, m)]
          allocate(hm%eq(k)%w(m, m))
          hm%eq(k)%w = 0.5_wp * k
          hm%eq(k)%err = [(0.1_wp ** j, j = 1, m)]
        end do
        call fake_eim(pair%terms%p(1), 4, hm%vdeim)
      class default
        call check(.false., "rom: unexpected stored method " // pair%methods(l)%m%storage())
      end select
    end do

  end subroutine make_rom

  subroutine write_rom(path)
    character(len=*), intent(in) :: path
    type(rom_file_t) :: rom
    type(rom_pair_t) :: pair
    call make_rom(rom, pair)
    call write_rom_file(path, rom, [pair], error)
    call check(.not. allocated(error), "rom: write")
  end subroutine write_rom

  subroutine read_rom(path, error)
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    type(rom_file_t) :: rom
    type(rom_pair_t) :: pair
    call read_rom_file(path, "test", rom, error); if (allocated(error)) return
    call read_rom_pair(rom, 1, pair, error)
  end subroutine read_rom

  subroutine rom_roundtrip()
    character(len=*), parameter :: path = "products_rom.h5"
    type(rom_file_t) :: ref, rom
    type(rom_pair_t) :: rp, pair
    integer :: k, l
    logical :: ok
    call make_rom(ref, rp)
    call write_rom_file(path, ref, [rp], error)
    call check(.not. allocated(error), "rom: write")
    call read_rom_file(path, "test", rom, error)
    call check(.not. allocated(error), "rom: read header")
    if (allocated(error)) return
    call check(rom%n_agents == NA .and. rom%n_steps == NT .and. rom%radius == ref%radius .and. rom%dt == ref%dt .and. &
      rom%db_hash == ref%db_hash .and. rom%database == ref%database .and. rom%config == ref%config, "rom: header")
    call check(rom%version == 3 .and. rom%study_config == ref%study_config .and. rom%param_names == ref%param_names &
      .and. all(rom%q0 == ref%q0), "rom: study")
    call check(rom%pod_method == "tsqr" .and. rom%pod_rank == 2 .and. all(rom%pod_sigma == ref%pod_sigma) .and. &
      all(rom%v == ref%v) .and. rom%n_pod == 2 .and. all(rom%pga_err == ref%pga_err), "rom: POD, basis, PGA")
    call check(rom%cone%method == 'gis' .and. rom%cone%r == 2 .and. all(rom%cone%indices == [1, 3]) .and. &
      all(rom%cone%sigma == [4_i8, 7_i8]) .and. all(rom%cone%err_max == ref%cone%err_max) .and. &
      rom%cone%note == "stopped" .and. rom%cone_other%method == '', "rom: cone")
    call check(all(rom%dict_ia == DICT_IA) .and. all(rom%dict_ib == DICT_IB) .and. all(rom%dict_ob == DICT_OB), &
      "rom: dictionary")
    call check(rom%tables%t_pod == 1.25_wp .and. size(rom%tables%is_n) == 0, "rom: tables")
    call check(rom%n_pairs == 1 .and. rom%pair_n(1) == 2 .and. rom%pair_r(1) == 2 .and. rom%pair_nb(1) == 3 .and. &
      rom%pair_hyper(1) == 1, "rom: pair list")
    call read_rom_pair(rom, 1, pair, error)
    call check(.not. allocated(error), "rom: read pair")
    if (allocated(error)) return
    call check(pair%n == 2 .and. pair%r == 2 .and. pair%nb == 3 .and. pair%n_pga == 1 .and. pair%hyper .and. &
      all(pair%v == rp%v) .and. all(pair%pga_err == rp%pga_err), "rom: pair basis")
    call check(all(pair%terms%rows == rp%terms%rows) .and. all(pair%terms%w == rp%terms%w) .and. &
      all(pair%terms%s2_dof == rp%terms%s2_dof), "rom: pair candidates")
    ok = size(pair%methods) == size(rp%methods)
    if (ok) then
      do l = 1, size(pair%methods)
        ok = ok .and. pair%methods(l)%m%time == rp%methods(l)%m%time
        select type (a => pair%methods(l)%m)
        type is (hyper_eim_t)
          select type (b => rp%methods(l)%m)
          type is (hyper_eim_t)
            do k = 1, 3
              ok = ok .and. same_eim(a%eim(k), b%eim(k))
            end do
          class default
            ok = .false.
          end select
        type is (hyper_eq_t)
          select type (b => rp%methods(l)%m)
          type is (hyper_eq_t)
            do k = 1, 3
              ok = ok .and. a%eq(k)%m == b%eq(k)%m .and. a%eq(k)%p == b%eq(k)%p .and. all(a%eq(k)%idx == b%eq(k)%idx) &
                .and. all(a%eq(k)%w == b%eq(k)%w) .and. all(a%eq(k)%err == b%eq(k)%err)
            end do
            ok = ok .and. same_eim(a%vdeim, b%vdeim)
          class default
            ok = .false.
          end select
        class default
          ok = .false.
        end select
      end do
    end if
    call check(ok, "rom: pair EIM, EQ and the DEIM of v (stored methods)")
    k = remove_file(path)
  end subroutine rom_roundtrip

  !> Made-up EIM data of p candidates (seed k).
  subroutine fake_eim(p, k, e)
    integer, intent(in) :: p, k
    type(eim_t), intent(out) :: e
    integer :: i, j
    e%p = p; e%m = min(2, p)
    allocate(e%basis(p, e%m))
    do j = 1, e%m
      do i = 1, p
        e%basis(i, j) = k + 0.1_wp * i + 0.01_wp * j
      end do
    end do
    e%idx = [(j, j = 1, e%m)]; e%err = [(0.5_wp ** j, j = 1, e%m)]
    e%sigma = [3.0_wp, 2.0_wp, 1.0_wp]
  end subroutine fake_eim

  logical function same_eim(a, b)
    type(eim_t), intent(in) :: a, b
    same_eim = a%m == b%m .and. a%p == b%p .and. all(a%basis == b%basis) .and. all(a%idx == b%idx) .and. &
      all(a%err == b%err) .and. allocated(b%sigma)
    if (same_eim) same_eim = all(a%sigma == b%sigma)
  end function same_eim

  subroutine rom_corrupt()
    character(len=*), parameter :: path = "products_rom_bad.h5"
    character(len=24), parameter :: floats(8) = [character(len=24) :: "pod/sigma", "basis/v", "pairs/1/v", &
      "pairs/1/cand/w", "pairs/1/eim/s1/basis", "pairs/1/eim/s2/basis", "pairs/1/eq/s3/weights", "study/q0"]
    integer :: k, b
    do k = 1, size(floats)
      do b = 1, 3
        call write_rom(path)
        call poke_real(path, trim(floats(k)), 1, bad(b))
        call read_rom(path, error)
        call expect_refusal(error, path, trim(floats(k)), "rom " // trim(BAD_NAMES(b)) // " in " // trim(floats(k)))
      end do
    end do
    call rom_int_case("contacts/ia", 1, 0)
    call rom_int_case("contacts/ia", 4, NA + 1)
    call rom_int_case("contacts/ib", 2, -1)
    call rom_int_case("pairs/1/cand/rows", 1, 0)
    call rom_int_case("pairs/1/cand/rows", 2, NDICT + 1)
    call rom_int_case("pairs/1/eim/s1/indices", 1, 0)
    call rom_int_case("pairs/1/eim/s2/indices", 2, 1000)
    call rom_int_case("pairs/1/eim/s3/indices", 1, -1)
    call rom_int_case("pairs/1/eq/s1/indices", 1, 0)
    call rom_int_case("pairs/1/eq/s2/indices", 2, 1000)
    call rom_int_case("pairs/1/eq/s3/indices", 1, -7)
    ! attributes contradicting the shapes
    call rom_attr_case("/", "n_agents", NA + 1, "basis/v")
    call rom_attr_case("pairs/1", "n_basis", 2, "pairs/1/v")
    call rom_attr_case("pairs/1/eim/s1", "m", 1, "pairs/1/eim/s1/basis")
    call rom_attr_case("pairs/1/eim/s2", "m", 100, "pairs/1/eim/s2")
    call rom_attr_case("pairs/1/eq/s1", "m", 1, "pairs/1/eq/s1/indices")
    call rom_attr_case("pairs/1/eq/s3", "p", 1, "pairs/1/eq/s3")
    ! versions
    call rom_attr_case("/", "schema_version", 1, "schema version 1 is not supported (supported: 2, 3)")
    call rom_attr_case("/", "schema_version", 4, "schema version 4 is not supported (supported: 2, 3)")
    k = remove_file(path)
  end subroutine rom_corrupt

  subroutine rom_int_case(name, at, x)
    character(len=*), intent(in) :: name
    integer, intent(in) :: at, x
    character(len=*), parameter :: path = "products_rom_bad.h5"
    call write_rom(path)
    call poke_int(path, name, at, x)
    call read_rom(path, error)
    call expect_refusal(error, path, name, "rom " // name // "(" // str(at) // ") = " // str(x))
  end subroutine rom_int_case

  subroutine rom_attr_case(obj, name, x, what)
    character(len=*), intent(in) :: obj, name, what
    integer, intent(in) :: x
    character(len=*), parameter :: path = "products_rom_bad.h5"
    call write_rom(path)
    call poke_attr(path, obj, name, x)
    call read_rom(path, error)
    call expect_refusal(error, path, what, "rom attribute " // obj // ":" // name // " = " // str(x))
  end subroutine rom_attr_case

  ! ------------------------------------------------------------------ full-order output

  subroutine write_fom(path, qs)
    character(len=*), intent(in) :: path
    real(wp), allocatable, intent(out) :: qs(:,:)
    type(config_t) :: cfg
    type(fom_t) :: fom
    type(fom_writer_t) :: w
    type(step_record_t) :: recs(3)
    integer :: u, k
    open(newunit=u, file="products_fom.nml", status='replace', action='write')
    write(u, '(a)') "&scene hall_length = 0.6, hall_width = 0.5, l_exit = 0.2, wall_thickness = 0.05 /"
    write(u, '(a)') "&agents n_agents = 8, radius = 0.04, speed = 1.0, seed = 3 /"
    write(u, '(a)') "&time dt = 0.02, n_steps = 3 /"
    close(u)
    call read_config("products_fom.nml", self, cfg, error); call check(.not. allocated(error), "fom: config")
    call fom%init(cfg, error); call check(.not. allocated(error), "fom: init")
    allocate(qs(2 * fom%n_agents, 4))
    qs(:, 1) = fom%q
    call w%open(path, cfg, fom, error); call check(.not. allocated(error), "fom: writer open")
    do k = 1, 3
      call fom%advance(recs(k), error)
      call w%write_step(fom, error)
      qs(:, k + 1) = fom%q
    end do
    call w%close(recs, error); call check(.not. allocated(error), "fom: writer close")
  end subroutine write_fom

  subroutine fom_roundtrip_and_corrupt()
    character(len=*), parameter :: path = "products_fom.h5"
    character(len=16), parameter :: floats(4) = [character(len=16) :: "traj/positions", "traj/velocities", &
      "traj/desired", "agents/speed"]
    type(fom_file_t) :: f
    real(wp), allocatable :: qs(:,:)
    integer :: k, b
    call write_fom(path, qs)
    call read_fom_file(path, f, error)
    call check(.not. allocated(error), "fom: read")
    if (allocated(error)) return
    call check(f%n_agents == 8 .and. f%n_out == 4 .and. all(f%step == [0, 1, 2, 3]) .and. all(f%q == qs) .and. &
      f%dt == 0.02_wp .and. f%radius == 0.04_wp, "fom: round trip (positions, steps, attributes)")
    call check(f%offset(f%n_out + 1) == size(f%lambda) .and. size(f%kkt) == 3, "fom: multipliers and statistics")
    do k = 1, size(floats)
      do b = 1, 3
        call write_fom(path, qs)
        call poke_real(path, trim(floats(k)), 3, bad(b))
        call read_fom_file(path, f, error)
        call expect_refusal(error, path, trim(floats(k)), "fom " // trim(BAD_NAMES(b)) // " in " // trim(floats(k)))
      end do
    end do
    call write_fom(path, qs)
    call poke_int(path, "traj/inside", 2, 7)
    call read_fom_file(path, f, error)
    call expect_refusal(error, path, "traj/inside", "fom inside flag 7")
    call write_fom(path, qs)
    call poke_attr(path, "/", "n_agents", 9)
    call read_fom_file(path, f, error)
    call expect_refusal(error, path, "agents/speed", "fom n_agents contradicting the shapes")
    call write_fom(path, qs)
    call poke_attr(path, "/", "schema_version", 2)
    call read_fom_file(path, f, error)
    call expect_refusal(error, path, "schema version 2 is not supported (supported: 1)", "fom unknown version")
    k = remove_file(path)
    k = remove_file("products_fom.nml")
  end subroutine fom_roundtrip_and_corrupt

  ! ------------------------------------------------------------------ ROM-run file

  subroutine make_romrun(hdr, s, rows)
    type(romrun_header_t), intent(out) :: hdr
    type(romrun_set_t), intent(out) :: s
    type(romrun_row_t), intent(out) :: rows(1)
    integer :: i, j
    hdr%config = "&rom /"; hdr%rom_file = "rom.h5"; hdr%database = "db.h5"; hdr%db_hash = "0123456789abcdef"
    hdr%param_names = "l_exit,speed"; hdr%n_agents = NA; hdr%n_steps = NT; hdr%n_settings = 1
    hdr%dt = 0.02_wp; hdr%radius = 0.04_wp; hdr%param_min = [0.1_wp, 1.0_wp]; hdr%param_max = [0.2_wp, 2.0_wp]
    hdr%t_uz = 1.0e-3_wp; hdr%t_ex = 2.0e-4_wp; hdr%exact_solver = "gpcg"; hdr%uzawa_rows = "all"
    s%setting = 1; s%n = 2; s%r = 1; s%nb = 3; s%pair = 1; s%m = [4, 5, 6]; s%hyper = 'eq'; s%contacts = 'cone'
    s%solver = 'nnls'; s%name = 'valid'; s%summary = .true.; s%e_avg = 0.01_wp; s%t_step = 1.0e-5_wp
    s%speedup_uzawa = 100; s%speedup_exact = 20
    s%params = reshape([0.15_wp, 1.5_wp, 0.12_wp, 1.2_wp], [2, 2])
    allocate(s%alpha(3, NT * 2), s%beta(1, NT * 2), s%positions(2 * NA, (NT + 1) * 2), s%err_time(NT + 1, 2))
    do j = 1, NT * 2
      s%alpha(:, j) = [(i + 0.1_wp * j, i = 1, 3)]
    end do
    s%beta = 0.5_wp
    do j = 1, (NT + 1) * 2
      s%positions(:, j) = [(0.01_wp * i * j, i = 1, 2 * NA)]
    end do
    s%err_time = 1.0e-3_wp
    s%e_mu = [0.01_wp, 0.02_wp]; s%e_proj = [0.001_wp, 0.002_wp]; s%max_overlap = [0.0_wp, 1.0e-4_wp]
    s%mobility = [1.0_wp, 0.9_wp]; s%time = [0.1_wp, 0.2_wp]
    s%n_not_left = [0, 1]; s%n_not_left_fom = [0, 0]; s%n_infeasible = [0, 2]; s%n_capped = [1, 0]
    s%extrapolating = [0, 0]; s%diverged_step = [0, 2]; s%samples_diverged = 1
    s%e_disp = [0.05_wp, -1.0_wp]; s%overlap_aa = [0.0_wp, 1.0e-3_wp]; s%overlap_aw = [2.0e-4_wp, 0.0_wp]
    s%evac_rom = reshape([0, 1, 2, 0, 0, 1], [NT + 1, 2]); s%t_out_rom = reshape([0.02_wp, 0.04_wp, -1.0_wp, -1.0_wp], [2, 2])
    s%evac_fom = reshape([0, 1, 3, 0, 1, 2], [NT + 1, 2]); s%t_out_fom = reshape([0.02_wp, 0.04_wp, 0.04_wp, -1.0_wp], [2, 2])
    rows(1)%setting = 1; rows(1)%n = 2; rows(1)%r = 1; rows(1)%nb = 3; rows(1)%e_avg = 0.015_wp
    rows(1)%e_max = 0.02_wp; rows(1)%t_step = 1.0e-5_wp; rows(1)%not_left = 1; rows(1)%capped = 1
    rows(1)%diverged = 1; rows(1)%meas%e_disp = 0.05_wp; rows(1)%meas%t_err = [0.1_wp, -1.0_wp]
    ! the local exact correction and the 'fastest' exact reference
    hdr%exact_asked = "fastest"; hdr%exact_timings = "sparse_active_set 1.0e-4 2.0e-2; active_set 3.0e-4 5.0e-2"
    s%correction = 'local'; s%n_corrected = reshape([0, 1, 0, 2], [NT, 2])
    s%t_correct = [1.0e-3_wp, 2.0e-3_wp]
    rows(1)%correction = 'local'; rows(1)%corr_frac = 0.25_wp; rows(1)%corr_frac_max = 0.5_wp
    rows(1)%t_correct = 3.0e-6_wp
  end subroutine make_romrun

  subroutine write_romrun(path)
    character(len=*), intent(in) :: path
    type(romrun_header_t) :: hdr
    type(romrun_set_t) :: s
    type(romrun_row_t) :: rows(1)
    type(romrun_writer_t) :: w
    call make_romrun(hdr, s, rows)
    call w%open(path, hdr, error); call check(.not. allocated(error), "romrun: open")
    call w%write_set(s, error); call check(.not. allocated(error), "romrun: write set")
    call w%close(hdr, rows, error); call check(.not. allocated(error), "romrun: close")
  end subroutine write_romrun

  subroutine romrun_roundtrip()
    character(len=*), parameter :: path = "products_romrun.h5"
    type(romrun_header_t) :: hdr
    type(romrun_set_t) :: s
    type(romrun_row_t) :: rows(1)
    type(romrun_t) :: run
    integer :: k
    call make_romrun(hdr, s, rows)
    call write_romrun(path)
    call read_romrun(path, run, error)
    call check(.not. allocated(error), "romrun: read")
    if (allocated(error)) return
    call check(run%hdr%n_agents == NA .and. run%hdr%n_steps == NT .and. run%hdr%n_settings == 1 .and. &
      all(run%hdr%param_min == hdr%param_min) .and. run%hdr%t_uz == hdr%t_uz .and. run%hdr%exact_solver == "gpcg", &
      "romrun: header")
    call check(size(run%sets) == 1, "romrun: one set")
    if (size(run%sets) /= 1) return
    associate (r => run%sets(1))
      call check(r%name == 'valid' .and. r%hyper == 'eq' .and. all(r%m == s%m) .and. r%summary .and. &
        r%e_avg == s%e_avg .and. r%speedup_exact == s%speedup_exact, "romrun: setting attributes")
      call check(all(r%params == s%params) .and. all(r%alpha == s%alpha) .and. all(r%beta == s%beta) .and. &
        all(r%positions == s%positions) .and. all(r%err_time == s%err_time), "romrun: trajectories")
      call check(all(r%e_mu == s%e_mu) .and. all(r%mobility == s%mobility) .and. all(r%n_infeasible == s%n_infeasible) &
        .and. all(r%n_capped == s%n_capped) .and. all(r%time == s%time), "romrun: per-sample measures")
      call check(all(r%diverged_step == s%diverged_step) .and. r%samples_diverged == 1 .and. &
        all(r%e_disp == s%e_disp) .and. all(r%overlap_aw == s%overlap_aw) .and. all(r%evac_rom == s%evac_rom) .and. &
        all(r%evac_fom == s%evac_fom) .and. all(r%t_out_fom == s%t_out_fom), "romrun: divergence and evacuation")
      call check(r%correction == 'local' .and. allocated(r%n_corrected) .and. allocated(r%t_correct), &
        "romrun: local correction present")
      if (allocated(r%n_corrected) .and. allocated(r%t_correct)) call check(all(r%n_corrected == s%n_corrected) &
        .and. all(r%t_correct == s%t_correct), "romrun: local correction data")
    end associate
    call check(run%hdr%exact_asked == "fastest" .and. run%hdr%exact_timings == hdr%exact_timings, &
      "romrun: exact reference asked and timed")
    call check(run%rows(1)%corr_frac == 0.25_wp .and. run%rows(1)%corr_frac_max == 0.5_wp .and. &
      run%rows(1)%t_correct == 3.0e-6_wp, "romrun: correction columns")
    call check(size(run%rows) == 1 .and. run%rows(1)%e_avg == rows(1)%e_avg .and. run%rows(1)%not_left == 1 .and. &
      run%rows(1)%capped == 1 .and. run%rows(1)%diverged == 1 .and. run%rows(1)%meas%e_disp == 0.05_wp, &
      "romrun: table")
    k = remove_file(path)
  end subroutine romrun_roundtrip

  subroutine romrun_corrupt()
    character(len=*), parameter :: path = "products_romrun_bad.h5"
    type(romrun_t) :: run
    integer :: b, k
    do b = 1, 3
      call write_romrun(path)
      call poke_real(path, "setting_1/valid/params", 2, bad(b))
      call read_romrun(path, run, error)
      call expect_refusal(error, path, "setting_1/valid/params", "romrun " // trim(BAD_NAMES(b)) // " in params")
    end do
    call write_romrun(path)
    call poke_attr(path, "/", "n_steps", NT + 1)
    call read_romrun(path, run, error)
    call expect_refusal(error, path, "setting_1/valid/alpha", "romrun n_steps contradicting alpha")
    call write_romrun(path)
    call poke_attr(path, "/", "n_settings", 2)
    call read_romrun(path, run, error)
    call expect_refusal(error, path, "setting_2", "romrun n_settings beyond the groups")
    call write_romrun(path)
    call poke_int(path, "table/setting", 1, 5)
    call read_romrun(path, run, error)
    call expect_refusal(error, path, "table/setting", "romrun table setting out of range")
    call write_romrun(path)
    call poke_attr(path, "/", "schema_version", 7)
    call read_romrun(path, run, error)
    call expect_refusal(error, path, "schema version 7 is not supported (supported: 1)", "romrun unknown version")
    k = remove_file(path)
  end subroutine romrun_corrupt
end program test_products
