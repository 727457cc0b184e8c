!> The snapshot database of a parameter study (schema "crowdrom-snapshots", version 1; layout in
!> the README, "Snapshot database"): written by crowd_snapshots (cr_snapshot_db assembles the
!> pieces), read by crowd_offline (a block of training samples per rank), crowd_rom (the study
!> and its full-order trajectories) and the Python scripts.
!>
!> This module owns the schema's name, version, units and metadata type (the writer,
!> cr_snapshot_db, assembles the pieces with them) and the readers `read_snap_header` and
!> `read_snap_block`. Readers accept the versions in SNAP_VERSIONS_READ and validate what they
!> read: dataset shapes against the root attributes, dictionary identities and multiplier indices
!> in range, CSR offsets monotone, positions, velocities, desired velocities, parameters and
!> multipliers finite, and the checksums of what they read (cr_digest; the ranks' blocks of a
!> parallel read add up to the whole datasets).
module cr_snapshot_file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_h5file, only: h5file_t
  use cr_digest, only: digest_t, digest_of, digest_add, check_digest, check_digest_parts
  use cr_product_check, only: check_schema, need_finite, need_range, need_dims, product_error
  implicit none
  private
  public :: SNAP_SCHEMA, SNAP_SCHEMA_VERSION, SNAP_VERSIONS_READ, SNAP_UNITS, db_meta_t, snap_header_t, &
    snap_block_t, read_snap_header, read_snap_block

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
  end type snap_block_t

contains

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
    type(h5file_t), intent(inout) :: h5
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
    call need_range(path, "contacts/ob", hdr%dict_ob, 0, huge(1), error); if (allocated(error)) return
    call check_digest(h5, "initial_positions", digest_of(hdr%q0, 0_i8), "'" // path // "'", error)
    if (allocated(error)) return
    call check_digest(h5, "contacts/ia", digest_of(hdr%dict_ia, 0_i8), "'" // path // "'", error)
    if (allocated(error)) return
    call check_digest(h5, "contacts/ib", digest_of(hdr%dict_ib, 0_i8), "'" // path // "'", error)
    if (allocated(error)) return
    call check_digest(h5, "contacts/ob", digest_of(hdr%dict_ob, 0_i8), "'" // path // "'", error)
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
    ! ... then this rank's checks (made collective before the collective checksums)
    checks: block
    if (len(bad) > 0) then
      call product_error(path, "dataset '" // g // "lambda_offset': " // bad, error); exit checks
    end if
    call need_finite(path, g // "params", blk%mu, error); if (allocated(error)) exit checks
    call need_finite(path, g // "positions", blk%q, error); if (allocated(error)) exit checks
    call need_finite(path, g // "velocities", blk%u, error); if (allocated(error)) exit checks
    if (desired) then
      call need_finite(path, g // "desired", blk%v, error); if (allocated(error)) exit checks
    end if
    if (multipliers) then
      call need_range(path, g // "lambda_index", blk%lam_idx, 1, hdr%n_dict, error); if (allocated(error)) exit checks
      call need_finite(path, g // "lambda_value", blk%lam_val, error); if (allocated(error)) exit checks
    end if
    end block checks
    if (present(env)) then
      if (env%any_true(allocated(error)) .and. .not. allocated(error)) call set_error(error, "'" // path // &
        "': another rank found a corrupt block of set " // name, 2)
    end if
    if (allocated(error)) goto 9
    ! checksums: in parallel every rank's block is a part of the whole; serially only a whole set
    if (present(env) .and. n > 0) then
      call verify(.true., error); if (allocated(error)) goto 9
    else if (k0 == 1 .and. nloc == n .and. n > 0) then
      call verify(.false., error); if (allocated(error)) goto 9
    end if
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= 2) call prefix_error(error, "database '" // path // "', set " // name)
      error%code = 2
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)

  contains

    !> Compare the checksums of the datasets read (parts: this rank's block is one part).
    subroutine verify(parts, error)
      logical, intent(in) :: parts
      type(error_t), allocatable, intent(out) :: error
      character(len=:), allocatable :: w
      type(digest_t) :: d
      integer(i8) :: o
      w = "'" // path // "'"
      o = int(k0 - 1, i8)
      call one(g // "params", digest_of(blk%mu, o * hdr%n_params), parts, error); if (allocated(error)) return
      call one(g // "positions", digest_of(blk%q, o * (nt + 1) * nd), parts, error); if (allocated(error)) return
      call one(g // "velocities", digest_of(blk%u, o * nt * nd), parts, error); if (allocated(error)) return
      if (desired) then
        call one(g // "desired", digest_of(blk%v, o * nt * nd), parts, error); if (allocated(error)) return
      end if
      if (multipliers) then
        d = digest_of(off(1:nt * nloc), o * nt)
        if (nloc > 0 .and. k0 - 1 + nloc == n) d = digest_add(d, digest_of(off(nt * nloc + 1:), int(nt, i8) * n))
        call one(g // "lambda_offset", d, parts, error); if (allocated(error)) return
        call one(g // "lambda_index", digest_of(blk%lam_idx, base), parts, error); if (allocated(error)) return
        call one(g // "lambda_value", digest_of(blk%lam_val, base), parts, error); if (allocated(error)) return
      end if
    end subroutine verify

    subroutine one(name, d, parts, error)
      character(len=*), intent(in) :: name
      type(digest_t), intent(in) :: d
      logical, intent(in) :: parts
      type(error_t), allocatable, intent(out) :: error
      if (parts) then
        call check_digest_parts(h5, env, name, d, "'" // path // "'", error)
      else
        call check_digest(h5, name, d, "'" // path // "'", error)
      end if
    end subroutine one
  end subroutine read_snap_block
end module cr_snapshot_file
