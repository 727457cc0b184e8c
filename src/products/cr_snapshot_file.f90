!> The snapshot database of a parameter study (schema "crowdrom-snapshots", version 1; layout in
!> the README, "Snapshot database"): written by crowd_snapshots (cr_snapshot_db assembles the
!> pieces), read by crowd_offline (a block of training samples per rank), crowd_rom (the study
!> and its full-order trajectories) and the Python scripts.
!>
!> This module owns the schema: the root attributes and dictionary (`write_snap_header`), one
!> set's datasets written from per-rank blocks of samples (`write_snap_set`, collective), and
!> the readers `read_snap_header` and `read_snap_block`. Readers accept the versions in
!> SNAP_VERSIONS_READ and validate what they read: dataset shapes against the root attributes,
!> dictionary identities and multiplier indices in range, CSR offsets monotone, positions,
!> velocities, desired velocities, parameters and multipliers finite.
module cr_snapshot_file
  use mpi_f08, only: MPI_Exscan, MPI_Allreduce, MPI_IN_PLACE, MPI_INTEGER8, MPI_SUM
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_scene, only: scene_t
  use cr_h5file, only: h5file_t, cr_h5_real, cr_h5_int, cr_h5_int64
  use cr_fom_file, only: write_scene
  use cr_product_check, only: check_schema, need_finite, need_range, need_dims, product_error
  implicit none
  private
  public :: SNAP_SCHEMA, SNAP_SCHEMA_VERSION, SNAP_VERSIONS_READ, SNAP_UNITS, db_meta_t, snap_header_t, &
    snap_block_t, write_snap_header, write_snap_set, read_snap_header, read_snap_block

  character(len=*), parameter :: SNAP_SCHEMA = "crowdrom-snapshots"
  integer, parameter :: SNAP_SCHEMA_VERSION = 1
  !> versions the readers accept
  integer, parameter :: SNAP_VERSIONS_READ(1) = [1]
  character(len=*), parameter :: SNAP_UNITS = "length: m, time: s, velocity: m/s, l_exit: m, " // &
    "speed: m/s, multiplier: m/s^2 (lambda scales B = -h G: u = v - B^T lambda)"

  !> Root metadata of a database (what the writer is given).
  type :: db_meta_t
    !> effective configuration (config_echo + study_echo) and the input file text
    character(len=:), allocatable :: config_text, input_text
    character(len=16) :: hash = ''
    !> comma-separated component names of mu
    character(len=:), allocatable :: param_names
    !> program, HDF5, MPI and compiler versions
    character(len=:), allocatable :: version, hdf5_version, mpi_version, compiler
    integer :: n_agents = 0, n_steps = 0, n_expanded = 0
    real(wp) :: radius = 0, dt = 0
  end type db_meta_t

  !> What a reader learns from the root of a complete database.
  type :: snap_header_t
    character(len=:), allocatable :: path
    character(len=:), allocatable :: config_text, hash, param_names
    integer :: version = 0, n_agents = 0, n_dof = 0, n_steps = 0, n_params = 0, n_train = 0, n_valid = 0
    integer :: n_dict = 0
    real(wp) :: radius = 0, dt = 0
    !> common initial positions [n_dof]
    real(wp), allocatable :: q0(:)
    !> contact dictionary [n_dict]
    integer, allocatable :: dict_ia(:), dict_ib(:), dict_ob(:)
  end type snap_header_t

  !> A contiguous block of samples k0..k0+nloc-1 of one set (n samples in all).
  type :: snap_block_t
    character(len=8) :: name = ''
    integer :: n = 0, k0 = 1, nloc = 0
    !> parameters [n_params, nloc]
    real(wp), allocatable :: mu(:,:)
    !> positions [n_dof, (n_steps + 1) nloc]; velocities, desired velocities [n_dof, n_steps nloc]
    real(wp), allocatable :: q(:,:), u(:,:), v(:,:)
    !> per-step KKT residual and smallest gap [n_steps, nloc]
    real(wp), allocatable :: kkt(:,:), min_gap(:,:)
    !> per-step iterations, converged (1/0), active contacts [n_steps, nloc]
    integer, allocatable :: iterations(:,:), converged(:,:), n_active(:,:)
    !> wall time and computing rank per sample [nloc]
    real(wp), allocatable :: time(:)
    integer, allocatable :: rank(:)
    !> multipliers, CSR over the block's velocity columns: column c holds entries
    !> lam_ptr(c)+1..lam_ptr(c+1) (0-based, local) [n_steps nloc + 1]; dictionary indices
    !> (1-based) and values [nnz]
    integer(i8), allocatable :: lam_ptr(:)
    integer, allocatable :: lam_idx(:)
    real(wp), allocatable :: lam_val(:)
    !> each sample's mapped scene: the obstacle vertices in the layout of /scene/obstacle_vertices
    !> [2 * n_vertices, nloc] and the exit segment (x_lo, y, x_hi, y) [4, nloc] (written; the
    !> Fortran readers do not need them, the Python figures do)
    real(wp), allocatable :: scene_vertices(:,:), scene_exit(:,:)
  end type snap_block_t

contains

  ! ------------------------------------------------------------------ write

  !> Root attributes (`complete` = 0), initial positions, reference scene and contact dictionary
  !> of a database being written (collective when h5 is parallel).
  subroutine write_snap_header(h5, meta, n_train, n_valid, q0, scene, dkey, dia, dib, dob, error)
    type(h5file_t), intent(inout) :: h5
    type(db_meta_t), intent(in) :: meta
    integer, intent(in) :: n_train, n_valid
    real(wp), intent(in) :: q0(:)
    type(scene_t), intent(in) :: scene
    integer(i8), intent(in) :: dkey(:)
    integer, intent(in) :: dia(:), dib(:), dob(:)
    type(error_t), allocatable, intent(out) :: error
    call h5%write_attr("/", "schema", SNAP_SCHEMA, error); if (allocated(error)) return
    call h5%write_attr("/", "schema_version", SNAP_SCHEMA_VERSION, error); if (allocated(error)) return
    call h5%write_attr("/", "program", "crowd_snapshots", error); if (allocated(error)) return
    call h5%write_attr("/", "version", meta%version, error); if (allocated(error)) return
    call h5%write_attr("/", "hdf5_version", meta%hdf5_version, error); if (allocated(error)) return
    call h5%write_attr("/", "mpi_version", meta%mpi_version, error); if (allocated(error)) return
    call h5%write_attr("/", "compiler", meta%compiler, error); if (allocated(error)) return
    call h5%write_attr("/", "config", meta%config_text, error); if (allocated(error)) return
    call h5%write_attr("/", "input_text", meta%input_text, error); if (allocated(error)) return
    call h5%write_attr("/", "config_hash", trim(meta%hash), error); if (allocated(error)) return
    call h5%write_attr("/", "units", SNAP_UNITS, error); if (allocated(error)) return
    call h5%write_attr("/", "n_agents", meta%n_agents, error); if (allocated(error)) return
    call h5%write_attr("/", "agent_radius", meta%radius, error); if (allocated(error)) return
    call h5%write_attr("/", "dt", meta%dt, error); if (allocated(error)) return
    call h5%write_attr("/", "n_steps", meta%n_steps, error); if (allocated(error)) return
    call h5%write_attr("/", "n_train", n_train, error); if (allocated(error)) return
    call h5%write_attr("/", "n_valid", n_valid, error); if (allocated(error)) return
    call h5%write_attr("/", "n_params", meta%n_expanded, error); if (allocated(error)) return
    call h5%write_attr("/", "param_names", meta%param_names, error); if (allocated(error)) return
    call h5%write_attr("/", "complete", 0, error); if (allocated(error)) return
    call h5%write("initial_positions", q0, error); if (allocated(error)) return
    call write_scene(h5, scene, error); if (allocated(error)) return
    call h5%make_group("contacts", error); if (allocated(error)) return
    call h5%write("contacts/key", dkey, error); if (allocated(error)) return
    call h5%write("contacts/ia", dia, error); if (allocated(error)) return
    call h5%write("contacts/ib", dib, error); if (allocated(error)) return
    call h5%write("contacts/ob", dob, error); if (allocated(error)) return
    call h5%write_attr("contacts", "description", "global contact dictionary: every contact " // &
      "with lambda > 0 in some sample and step, sorted by key; ib = 0 for agent-obstacle " // &
      "contacts (ob = obstacle index), ob = 0 for agent pairs", error)
  end subroutine write_snap_header

  !> Collective: the datasets of one set, each rank writing its block b (ranks' blocks are
  !> contiguous and ordered by rank; a rank may hold none).
  subroutine write_snap_set(env, h5, meta, b, error)
    type(env_t), intent(in) :: env
    type(h5file_t), intent(inout) :: h5
    type(db_meta_t), intent(in) :: meta
    type(snap_block_t), intent(in) :: b
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: g
    integer(i8), allocatable :: off(:), cnt(:)
    integer(i8) :: base, mine
    integer :: nd, ns, ne, n0, o, ierr
    g = trim(b%name)
    nd = 2 * meta%n_agents; ns = meta%n_steps; ne = meta%n_expanded
    call h5%make_group(g, error); if (allocated(error)) return
    call h5%make_group(g // "/stats", error); if (allocated(error)) return
    call h5%create_dataset(g // "/params", [ne, b%n], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/params", b%mu, b%k0 - 1, error); if (allocated(error)) return
    call h5%create_dataset(g // "/positions", [nd, (ns + 1) * b%n], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/positions", b%q, (b%k0 - 1) * (ns + 1), error); if (allocated(error)) return
    call h5%create_dataset(g // "/velocities", [nd, ns * b%n], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/velocities", b%u, (b%k0 - 1) * ns, error); if (allocated(error)) return
    call h5%create_dataset(g // "/desired", [nd, ns * b%n], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/desired", b%v, (b%k0 - 1) * ns, error); if (allocated(error)) return
    ! per-step statistics [n_steps, n_S]
    call h5%create_dataset(g // "/stats/kkt", [ns, b%n], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/stats/kkt", b%kkt, b%k0 - 1, error); if (allocated(error)) return
    call h5%create_dataset(g // "/stats/min_gap", [ns, b%n], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/stats/min_gap", b%min_gap, b%k0 - 1, error); if (allocated(error)) return
    call h5%create_dataset(g // "/stats/iterations", [ns, b%n], cr_h5_int, error); if (allocated(error)) return
    call h5%write_block(g // "/stats/iterations", b%iterations, b%k0 - 1, error); if (allocated(error)) return
    call h5%create_dataset(g // "/stats/converged", [ns, b%n], cr_h5_int, error); if (allocated(error)) return
    call h5%write_block(g // "/stats/converged", b%converged, b%k0 - 1, error); if (allocated(error)) return
    call h5%create_dataset(g // "/stats/n_active", [ns, b%n], cr_h5_int, error); if (allocated(error)) return
    call h5%write_block(g // "/stats/n_active", b%n_active, b%k0 - 1, error); if (allocated(error)) return
    ! per-sample time and rank [n_S] (not part of the bitwise comparison)
    call h5%create_dataset(g // "/stats/time", [b%n], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/stats/time", b%time, b%k0 - 1, error); if (allocated(error)) return
    call h5%create_dataset(g // "/stats/rank", [b%n], cr_h5_int, error); if (allocated(error)) return
    call h5%write_block(g // "/stats/rank", b%rank, b%k0 - 1, error); if (allocated(error)) return
    ! sparse multipliers, CSR over the snapshot columns
    mine = b%lam_ptr(size(b%lam_ptr))
    base = 0
    call MPI_Exscan(mine, base, 1, MPI_INTEGER8, MPI_SUM, env%comm, ierr)
    if (env%rank == 0) base = 0
    allocate(cnt(1))
    cnt(1) = mine
    call MPI_Allreduce(MPI_IN_PLACE, cnt, 1, MPI_INTEGER8, MPI_SUM, env%comm, ierr)
    if (cnt(1) > huge(1)) then
      call set_error(error, g // ": " // str(cnt(1)) // " multipliers exceed the 32-bit block offsets"); return
    end if
    ! rank 0 writes the leading 0, every rank the ends of its columns
    n0 = merge(1, 0, env%rank == 0)
    allocate(off(n0 + ns * b%nloc))
    if (n0 == 1) off(1) = 0
    off(n0 + 1:) = base + b%lam_ptr(2:)
    o = 0
    if (env%rank > 0) o = (b%k0 - 1) * ns + 1
    call h5%create_dataset(g // "/lambda_offset", [ns * b%n + 1], cr_h5_int64, error); if (allocated(error)) return
    call h5%write_block(g // "/lambda_offset", off, o, error); if (allocated(error)) return
    call h5%create_dataset(g // "/lambda_index", [int(cnt(1))], cr_h5_int, error); if (allocated(error)) return
    call h5%write_block(g // "/lambda_index", b%lam_idx, int(base), error); if (allocated(error)) return
    call h5%create_dataset(g // "/lambda_value", [int(cnt(1))], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/lambda_value", b%lam_val, int(base), error); if (allocated(error)) return
    ! each sample's mapped scene
    call h5%create_dataset(g // "/scene_vertices", [size(b%scene_vertices, 1), b%n], cr_h5_real, error)
    if (allocated(error)) return
    call h5%write_block(g // "/scene_vertices", b%scene_vertices, b%k0 - 1, error); if (allocated(error)) return
    call h5%create_dataset(g // "/scene_exit", [4, b%n], cr_h5_real, error); if (allocated(error)) return
    call h5%write_block(g // "/scene_exit", b%scene_exit, b%k0 - 1, error); if (allocated(error)) return
    call h5%write_attr(g, "n_samples", b%n, error)
  end subroutine write_snap_set

  ! ------------------------------------------------------------------ read

  !> Open `path` read-only (in parallel when env is given), check schema, version and
  !> completeness, read and validate the root attributes, initial positions and dictionary.
  !> Messages start with `where` (e.g. "input.nml: &offline: database").
  subroutine read_snap_header(path, where, hdr, error, env)
    character(len=*), intent(in) :: path, where
    type(snap_header_t), intent(out) :: hdr
    type(error_t), allocatable, intent(out) :: error
    type(env_t), intent(in), optional :: env
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    call h5%open(path, error, env=env)
    if (allocated(error)) then
      error%message = where // ": '" // path // "': cannot open the snapshot database (" // error%message // ")"
      error%code = 2; return
    end if
    call header_of(h5, path, hdr, error)
    call h5%close(e2)
    if (allocated(error)) then
      if (index(error%message, where) /= 1) error%message = where // ": " // error%message
      error%code = 2
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_snap_header

  subroutine header_of(h5, path, hdr, error)
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path
    type(snap_header_t), intent(out) :: hdr
    type(error_t), allocatable, intent(out) :: error
    integer :: complete
    hdr%path = path
    call check_schema(h5, path, SNAP_SCHEMA, SNAP_VERSIONS_READ, "snapshot database", hdr%version, error)
    if (allocated(error)) return
    call h5%read_attr("/", "complete", complete, error); if (allocated(error)) return
    if (complete /= 1) then
      call product_error(path, "the snapshot database is not complete (attribute complete = " // str(complete) // &
        ")", error); return
    end if
    call h5%read_attr("/", "n_agents", hdr%n_agents, error); if (allocated(error)) return
    call h5%read_attr("/", "n_steps", hdr%n_steps, error); if (allocated(error)) return
    call h5%read_attr("/", "n_train", hdr%n_train, error); if (allocated(error)) return
    call h5%read_attr("/", "n_valid", hdr%n_valid, error); if (allocated(error)) return
    call h5%read_attr("/", "n_params", hdr%n_params, error); if (allocated(error)) return
    call h5%read_attr("/", "agent_radius", hdr%radius, error); if (allocated(error)) return
    call h5%read_attr("/", "dt", hdr%dt, error); if (allocated(error)) return
    call h5%read_attr("/", "config_hash", hdr%hash, error); if (allocated(error)) return
    call h5%read_attr("/", "param_names", hdr%param_names, error); if (allocated(error)) return
    call h5%read_attr("/", "config", hdr%config_text, error); if (allocated(error)) return
    if (hdr%n_agents < 1 .or. hdr%n_steps < 1 .or. hdr%n_train < 0 .or. hdr%n_valid < 0 .or. hdr%n_params < 0 &
        .or. .not. (hdr%radius > 0 .and. hdr%radius <= huge(1.0_wp)) .or. &
        .not. (hdr%dt > 0 .and. hdr%dt <= huge(1.0_wp))) then
      call product_error(path, "root attributes out of range (n_agents " // str(hdr%n_agents) // ", n_steps " // &
        str(hdr%n_steps) // ", n_train " // str(hdr%n_train) // ", n_valid " // str(hdr%n_valid) // &
        ", n_params " // str(hdr%n_params) // ", agent_radius " // str(hdr%radius) // ", dt " // str(hdr%dt) // ")", &
        error); return
    end if
    hdr%n_dof = 2 * hdr%n_agents
    call need_dims(h5, path, "initial_positions", [int(hdr%n_dof, i8)], "2 n_agents", error); if (allocated(error)) return
    call h5%read("initial_positions", hdr%q0, error); if (allocated(error)) return
    call need_finite(path, "initial_positions", hdr%q0, error); if (allocated(error)) return
    call h5%read("contacts/ia", hdr%dict_ia, error); if (allocated(error)) return
    hdr%n_dict = size(hdr%dict_ia)
    call need_dims(h5, path, "contacts/ib", [int(hdr%n_dict, i8)], "contacts/ia", error); if (allocated(error)) return
    call need_dims(h5, path, "contacts/ob", [int(hdr%n_dict, i8)], "contacts/ia", error); if (allocated(error)) return
    call h5%read("contacts/ib", hdr%dict_ib, error); if (allocated(error)) return
    call h5%read("contacts/ob", hdr%dict_ob, error); if (allocated(error)) return
    call need_range(path, "contacts/ia", hdr%dict_ia, 1, hdr%n_agents, error); if (allocated(error)) return
    call need_range(path, "contacts/ib", hdr%dict_ib, 0, hdr%n_agents, error); if (allocated(error)) return
    call need_range(path, "contacts/ob", hdr%dict_ob, 0, huge(1), error)
  end subroutine header_of

  !> Read samples k0..k0+nloc-1 of set `name` ('train' or 'valid') and validate them. With env
  !> the file is opened in parallel and every rank of env calls with its own block (nloc may be
  !> 0). desired / multipliers: also read the desired velocities / the multipliers.
  subroutine read_snap_block(hdr, name, k0, nloc, desired, multipliers, blk, error, env)
    type(snap_header_t), intent(in) :: hdr
    character(len=*), intent(in) :: name
    integer, intent(in) :: k0, nloc
    logical, intent(in) :: desired, multipliers
    type(snap_block_t), intent(out) :: blk
    type(error_t), allocatable, intent(out) :: error
    type(env_t), intent(in), optional :: env
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: path, g, bad
    integer(i8), allocatable :: off(:), d(:)
    integer(i8) :: ns8, nt8, base, nnz_all
    integer :: nt, nd, c, n
    nnz_all = 0
    path = hdr%path
    nt = hdr%n_steps; nd = hdr%n_dof
    n = merge(hdr%n_train, hdr%n_valid, name == 'train')
    if (k0 < 1 .or. nloc < 0 .or. k0 - 1 + nloc > n) then
      call set_error(error, "'" // path // "': samples " // str(k0) // ".." // str(k0 + nloc - 1) // " of set " // &
        name // " requested, the set has " // str(n)); return
    end if
    call h5%open(path, error, env=env)
    if (allocated(error)) return
    g = name // "/"
    blk%name = name; blk%n = n; blk%k0 = k0; blk%nloc = nloc
    ns8 = n; nt8 = nt
    ! shapes against the root attributes (before anything is allocated from them)
    call need_dims(h5, path, g // "params", [int(hdr%n_params, i8), ns8], "n_params x n_" // name, error)
    if (allocated(error)) goto 9
    call need_dims(h5, path, g // "positions", [int(nd, i8), (nt8 + 1) * ns8], "2 n_agents x (n_steps + 1) n_" // &
      name, error); if (allocated(error)) goto 9
    call need_dims(h5, path, g // "velocities", [int(nd, i8), nt8 * ns8], "2 n_agents x n_steps n_" // name, error)
    if (allocated(error)) goto 9
    if (desired) then
      call need_dims(h5, path, g // "desired", [int(nd, i8), nt8 * ns8], "2 n_agents x n_steps n_" // name, error)
      if (allocated(error)) goto 9
    end if
    if (multipliers) then
      call need_dims(h5, path, g // "lambda_offset", [nt8 * ns8 + 1], "n_steps n_" // name // " + 1", error)
      if (allocated(error)) goto 9
      call h5%get_dims(g // "lambda_index", d, error); if (allocated(error)) goto 9
      nnz_all = d(1)
      call need_dims(h5, path, g // "lambda_value", [nnz_all], "lambda_index", error); if (allocated(error)) goto 9
    end if
    ! collective reads (every rank makes the same calls, whatever its block holds) ...
    allocate(blk%mu(hdr%n_params, nloc), blk%q(nd, (nt + 1) * nloc), blk%u(nd, nt * nloc))
    call h5%read_block(g // "params", blk%mu, k0 - 1, error); if (allocated(error)) goto 9
    call h5%read_block(g // "positions", blk%q, (k0 - 1) * (nt + 1), error); if (allocated(error)) goto 9
    call h5%read_block(g // "velocities", blk%u, (k0 - 1) * nt, error); if (allocated(error)) goto 9
    if (desired) then
      allocate(blk%v(nd, nt * nloc))
      call h5%read_block(g // "desired", blk%v, (k0 - 1) * nt, error); if (allocated(error)) goto 9
    end if
    bad = ""
    if (multipliers) then
      allocate(off(nt * nloc + 1))
      call h5%read_block(g // "lambda_offset", off, (k0 - 1) * nt, error); if (allocated(error)) goto 9
      if (k0 == 1 .and. off(1) /= 0) bad = "first offset " // str(off(1)) // ", expected 0"
      do c = 1, nt * nloc
        if (len(bad) > 0) exit
        if (off(c + 1) < off(c)) bad = "offsets decrease at column " // str(int((k0 - 1) * nt8 + c))
      end do
      if (len(bad) == 0 .and. (off(1) < 0 .or. off(nt * nloc + 1) > nnz_all)) bad = "offsets " // str(off(1)) // &
        ".." // str(off(nt * nloc + 1)) // " outside 0.." // str(nnz_all) // " (size of lambda_index)"
      base = 0
      if (len(bad) == 0) then
        base = off(1)
        blk%lam_ptr = off - base
      else
        allocate(blk%lam_ptr(1)); blk%lam_ptr = 0
      end if
      allocate(blk%lam_idx(int(blk%lam_ptr(size(blk%lam_ptr)))), blk%lam_val(int(blk%lam_ptr(size(blk%lam_ptr)))))
      call h5%read_block(g // "lambda_index", blk%lam_idx, int(base), error); if (allocated(error)) goto 9
      call h5%read_block(g // "lambda_value", blk%lam_val, int(base), error); if (allocated(error)) goto 9
    end if
    ! ... then this rank's checks
    if (len(bad) > 0) then
      call product_error(path, "dataset '" // g // "lambda_offset': " // bad, error); goto 9
    end if
    call need_finite(path, g // "params", blk%mu, error); if (allocated(error)) goto 9
    call need_finite(path, g // "positions", blk%q, error); if (allocated(error)) goto 9
    call need_finite(path, g // "velocities", blk%u, error); if (allocated(error)) goto 9
    if (desired) then
      call need_finite(path, g // "desired", blk%v, error); if (allocated(error)) goto 9
    end if
    if (multipliers) then
      call need_range(path, g // "lambda_index", blk%lam_idx, 1, hdr%n_dict, error); if (allocated(error)) goto 9
      call need_finite(path, g // "lambda_value", blk%lam_val, error); if (allocated(error)) goto 9
    end if
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= 2) call prefix_error(error, "database '" // path // "', set " // name)
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_snap_block
end module cr_snapshot_file
