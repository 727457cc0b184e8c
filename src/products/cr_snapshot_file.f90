!> The snapshot database of a parameter study (schema "crowdrom-snapshots", version 2; layout in
!> docs/file-formats.md; version 2 adds each set's block table `sample_checksums`, the
!> per-sample digests of every dataset of the set, so that a reader of some samples verifies
!> them: docs/robustness.md): written by crowd_snapshots, read by crowd_offline (a block
!> of training samples per rank), crowd_rom (the study and its full-order trajectories) and the
!> Python scripts.
!>
!> This module owns the schema's name, version, units, the sample and metadata types, the
!> writer `snap_writer_t` (begin: rank 0 lays the file out serially, every fixed-size dataset's
!> storage placed; put: a rank writes one of its samples' blocks at their byte offsets with
!> its own block writes (cr_fsys's block_file_t, nothing collective) as soon as it has the
!> sample; finish: the contact dictionary, the multipliers, the
!> checksums and complete = 1; a fixed, small number of collectives whatever the number of
!> samples and datasets), `probe_snap_database` (is a file under the name a complete database
!> of this configuration?) and the readers `read_snap_header` and `read_snap_block`. Readers
!> accept the versions in SNAP_VERSIONS_READ and validate what they read: dataset shapes against the root attributes, dictionary identities and multiplier indices
!> in range, CSR offsets monotone, positions, velocities, desired velocities, parameters and
!> multipliers finite, and the checksums of what they read (cr_digest; the ranks' blocks of a
!> parallel read add up to the whole datasets).
module cr_snapshot_file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t, pending_bcast_t
  use cr_h5file, only: h5file_t, cr_h5_real, cr_h5_int, cr_h5_int64
  use cr_digest, only: digest_t, digest_of, digest_add, check_digest, check_digest_parts, digest_allreduce, &
    put_digest, DIGEST_ALGORITHM, digest_pack, digest_table_sum, check_digest_blocks, digest_hex
  use cr_product_check, only: check_schema, need_finite, need_range, need_dims, product_error
  use cr_sort, only: argsort_i8, bsearch_i8
  use cr_scene, only: scene_t
  use cr_fom_file, only: write_scene
  use cr_fsys, only: rename_file, remove_file, block_file_t
  use cr_qoi, only: qoi_t
  use cr_qoi_file, only: write_qoi_group
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: SNAP_SCHEMA, SNAP_SCHEMA_VERSION, SNAP_VERSIONS_READ, SNAP_UNITS, db_meta_t, snap_header_t, &
    snap_block_t, read_snap_header, read_snap_block, snap_sample_t, snap_write_stats_t, snap_writer_t, &
    probe_snap_database, scene_vertex_list, SNAP_SET_NAMES, move_sample

  character(len=*), parameter :: SNAP_SCHEMA = "crowdrom-snapshots"
  !> 2: with the per-sample block checksums <set>/sample_checksums (partial reads verified)
  integer, parameter :: SNAP_SCHEMA_VERSION = 2
  !> versions the readers accept (version 1: whole sets only, see read_snap_block)
  integer, parameter :: SNAP_VERSIONS_READ(2) = [1, 2]
  !> block table of each set: per sample, the digests of the 17 datasets DS of that sample
  character(len=*), parameter :: SAMPLE_CHECKSUMS = "sample_checksums"
  character(len=*), parameter :: SNAP_UNITS = "length: m, time: s, velocity: m/s, l_exit: m, " // &
    "speed: m/s, multiplier: m/s^2 (lambda scales B = -h G: u = v - B^T lambda)"

  !> the sets of a study, in database order
  character(len=8), parameter :: SNAP_SET_NAMES(2) = [character(len=8) :: 'train', 'valid']

  !> One sample of a study as the database stores it: its trajectory, statistics, multipliers
  !> and mapped scene (the study computes it; the writer places it by set and index).
  type :: snap_sample_t
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
    !> the sample's scene as the parameter mapping builds it (set before writing the database):
    !> obstacle vertices in the layout of /scene [2 n_v] and exit segment (x_lo, y, x_hi, y)
    real(wp), allocatable :: scene_v(:)
    real(wp) :: scene_exit(4) = 0
  end type snap_sample_t

  !> What the writer measured (s; rank 0's clock unless said) and wrote.
  type :: snap_write_stats_t
    !> this rank's time in put (checksum parts and block writes of its samples); in finish: global
    !> counts, contact dictionary and checksum sums; serial layout by rank 0 (begin and finish);
    !> the ranks' multiplier block writes; completion (complete = 1, rename)
    real(wp) :: t_put = 0, t_dict = 0, t_layout = 0, t_write = 0, t_seal = 0
    !> this rank's time in finish on its own samples' multipliers (their unique contacts for the
    !> dictionary, CSR places and dictionary indices, checksum parts, block writes), no waiting
    !> in it
    real(wp) :: t_blocks = 0
    !> this rank's serial work on the database that no other rank does (rank 0: the HDF5 layout
    !> of begin; in finish the multiplier datasets, dictionary, checksums, complete = 1, the
    !> close and the rename; 0 on the other ranks), and its time writing the samples it held while
    !> the places were in transit (outside put: in poll and finish)
    real(wp) :: t_serial = 0, t_held = 0
    !> when this rank passed the steps of finish (env%wtime): places settled, end reduction,
    !> dictionary shared, own blocks (and rank 0's HDF5 work) done, agreement, renamed
    real(wp) :: marks(6) = 0
    !> contacts in the dictionary, stored multipliers, data bytes written by all ranks
    integer :: n_dict = 0
    integer(i8) :: nnz = 0, bytes = 0
  end type snap_write_stats_t

  !> datasets of one set, in this order (stats/... in the stats group), their element sizes
  !> (bytes), kinds and ranks; the multiplier datasets are placed only when finish knows their sizes
  character(len=*), parameter :: DS(17) = [character(len=16) :: 'params', 'positions', 'velocities', &
    'desired', 'lambda_offset', 'lambda_index', 'lambda_value', 'stats/kkt', 'stats/min_gap', &
    'stats/iterations', 'stats/converged', 'stats/n_active', 'stats/time', 'stats/rank', 'stats/start', &
    'scene_vertices', 'scene_exit']
  integer, parameter :: ESZ(17) = [8, 8, 8, 8, 8, 4, 8, 8, 8, 4, 4, 4, 8, 4, 8, 8, 8]
  integer, parameter :: KIND_OF(17) = [cr_h5_real, cr_h5_real, cr_h5_real, cr_h5_real, cr_h5_int64, cr_h5_int, &
    cr_h5_real, cr_h5_real, cr_h5_real, cr_h5_int, cr_h5_int, cr_h5_int, cr_h5_real, cr_h5_int, cr_h5_real, &
    cr_h5_real, cr_h5_real]
  integer, parameter :: DRANK(17) = [2, 2, 2, 2, 1, 1, 1, 2, 2, 2, 2, 2, 1, 1, 1, 2, 2]
  !> the multiplier datasets (their checksums need every sample's place in the CSR arrays) and
  !> those of them placed only in finish (their sizes are the numbers of multipliers)
  integer, parameter :: LAMBDA_DS(3) = [5, 6, 7]
  !> the datasets of the run itself (stats/time, stats/rank, stats/start): 0 in the block table
  integer, parameter :: RUN_DS(3) = [13, 14, 15]
  integer, parameter :: LATE_DS(2) = [6, 7]

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
    !> samples of the two sets
    integer :: n_train = 0, n_valid = 0
    real(wp) :: radius = 0, dt = 0
  end type db_meta_t

  !> Writer of a database (collective begin and finish; put by each rank for the samples it
  !> holds, as soon as it has them): see writer_begin, writer_put, writer_finish.
  type :: snap_writer_t
    type(snap_write_stats_t) :: stats
    type(env_t), private :: env
    character(len=:), allocatable, private :: path
    type(db_meta_t), private :: meta
    integer, private :: nset(2) = 0, nd = 0, ns = 0, ne = 0, nv = 0
    !> byte offset of each dataset of each set in the file (-1: empty or not placed yet) [17, 2]
    integer(i8), private :: place(17, 2) = -1
    !> this rank's checksum parts [17, 2]
    type(digest_t), private :: dg(17, 2)
    type(block_file_t), private :: pf
    !> rank 0: the file's HDF5 handle, open from begin to finish (metadata only: the data go by
    !> block writes)
    type(h5file_t), private :: h5
    !> the places and rank 0's layout status in transit (nonblocking broadcast: [status, place])
    type(pending_bcast_t), private :: pend
    !> this rank has the places (rank 0 from its layout, the others once pend has arrived)
    logical, private :: placed = .false.
    !> samples put before the places arrived, written when they do [nq]
    integer, private :: nq = 0
    type(snap_sample_t), allocatable, private :: queue(:)
    !> why this rank cannot write (its file did not open, or a failure before begin): its puts
    !> fail with it
    character(len=:), allocatable, private :: fault
    logical, private :: active = .false.
    !> the multipliers of the samples put by this rank, their global numbers and their block
    !> digests (one per dataset DS; the multipliers' filled in finish) [nl]
    integer, private :: nl = 0
    type(snap_sample_t), allocatable, private :: lam(:)
    integer, allocatable, private :: gl(:)
    type(digest_t), allocatable, private :: sdg(:,:)
    !> this rank's contacts [4, n] (end_local) and whether end_local has run
    integer(i8), allocatable, private :: pack4(:,:)
    logical, private :: local_done = .false.
    !> multipliers per set and each sample's position in its set's CSR arrays (finish)
    integer(i8), private :: total(2) = 0
    integer(i8), allocatable, private :: base(:)
  contains
    procedure :: begin => writer_begin
    procedure :: put => writer_put
    procedure :: poll => writer_poll
    procedure :: wait_places => writer_wait_places
    procedure :: end_local => writer_end_local
    procedure :: finish => writer_finish
    procedure :: discard => writer_discard
  end type snap_writer_t

  !> One sample's multipliers in the set's CSR arrays: offsets [ns], dictionary indices [nnz].
  type :: csr_t
    integer(i8), allocatable :: off8(:)
    integer, allocatable :: li(:)
  end type csr_t

  !> What the steps of the writer's finish pass on: this rank's contacts [4, n] and CSR arrays
  !> [nl], the contact dictionary (keys and ids), every rank's contact entries [P], the report
  !> to rank 0 (checksum parts, failed flag, block digests), rank 0's places of the multiplier
  !> datasets [2, 2] and its status (m: '' or its message); ended: rank 0's failure shared.
  type :: finish_state_t
    integer(i8), allocatable :: pack4(:,:), dkey(:)
    type(csr_t), allocatable :: csr(:)
    integer, allocatable :: dia(:), dib(:), dob(:), counts(:)
    real(wp), allocatable :: dl(:)
    integer(i8) :: lplace(2, 2) = -1
    character(len=:), allocatable :: m
    integer :: ntot = 0
    real(wp) :: t0 = 0
    logical :: ended = .false.
  end type finish_state_t

  !> What the steps of read_snap_block share: the request (set, first sample, count, what to
  !> read), the set's size, the file and group, the sizes (steps, degrees of freedom, all the
  !> set's multipliers), whether the file has per-sample checksums (version 2) and this block's
  !> columns of the block table [34, nloc], the multiplier offsets read [nt nloc + 1], their
  !> first (base) and a fault found in them (bad: '' if none).
  type :: block_read_t
    character(len=:), allocatable :: name, path, g, bad
    integer :: k0 = 1, nloc = 0, n = 0, nt = 0, nd = 0
    logical :: desired = .false., multipliers = .false., blocks = .false.
    integer(i8) :: nnz_all = 0, base = 0
    integer, allocatable :: tab(:,:)
    integer(i8), allocatable :: off(:)
  end type block_read_t

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

  ! ------------------------------------------------------------------ write

  !> Vertices of every obstacle of a scene, in order [2 * total vertices] (the layout of
  !> /scene/obstacle_vertices and of <set>/scene_vertices).
  function scene_vertex_list(sc) result(v)
    type(scene_t), intent(in) :: sc
    real(wp), allocatable :: v(:)
    integer :: k, n, m
    n = 0
    do k = 1, sc%n_obstacles()
      n = n + size(sc%obstacles(k)%vertices)
    end do
    allocate(v(n))
    n = 0
    do k = 1, sc%n_obstacles()
      m = size(sc%obstacles(k)%vertices)
      v(n + 1:n + m) = reshape(sc%obstacles(k)%vertices, [m])
      n = n + m
    end do
  end function scene_vertex_list

  !> Serial check of an existing file under the database's name: status 0 = no file, 1 =
  !> complete database of this configuration (config_hash), 2 = anything else (message says why;
  !> it must not be overwritten).
  subroutine probe_snap_database(path, hash, status, message)
    character(len=*), intent(in) :: path, hash
    integer, intent(out) :: status
    character(len=:), allocatable, intent(out) :: message
    type(h5file_t) :: h5
    type(error_t), allocatable :: error, e2
    character(len=:), allocatable :: schema, h
    integer :: complete
    logical :: ex
    message = ""
    inquire(file=path, exist=ex)
    if (.not. ex) then
      status = 0; return
    end if
    status = 2
    call h5%open(path, error)
    if (allocated(error)) then
      message = "database '" // path // "' exists and is not a crowdrom snapshot database (" // &
        error%message // "): refusing to overwrite it; remove it or change &study database"
      return
    end if
    call h5%read_attr("/", "schema", schema, error)
    if (.not. allocated(error)) call h5%read_attr("/", "config_hash", h, error)
    if (.not. allocated(error)) call h5%read_attr("/", "complete", complete, error)
    call h5%close(e2)
    if (allocated(error)) then
      message = "database '" // path // "' exists and is not a crowdrom snapshot database: " // &
        "refusing to overwrite it; remove it or change &study database"
    else if (schema /= SNAP_SCHEMA) then
      message = "database '" // path // "' has schema '" // schema // "', not " // SNAP_SCHEMA // &
        ": refusing to overwrite it"
    else if (h /= hash) then
      message = "database '" // path // "' was written for a different configuration (config_hash " // &
        h // ", this input " // trim(hash) // "): refusing to overwrite or mix it; remove it or " // &
        "change &study database"
    else if (complete /= 1) then
      message = "database '" // path // "' is marked incomplete: refusing to overwrite it"
    else
      status = 1
    end if
  end subroutine probe_snap_database

  ! ---- the writer: begin (collective), put (each rank, any number of samples), finish (collective)

  !> Collective: create `<path>.partial`. Rank 0 lays it out serially: root attributes, initial
  !> positions, scene, and every dataset whose size the study fixes (all but the contact
  !> dictionary, lambda_index and lambda_value) with its storage placed, and keeps the file open
  !> for finish. The byte offsets go out by a nonblocking broadcast: begin returns at once on
  !> the other ranks, which compute samples meanwhile; their puts keep the samples until the
  !> places have arrived (put, poll), then each rank opens the file for its own block writes
  !> (block_file_t: POSIX pwrite, not collective). A failed layout is not returned here: every
  !> rank's puts and finish fail with it (rank 0's message, agreed in finish). `prior`: a
  !> failure of this rank just before begin (e.g. rank 0 zeroing a counter): its puts fail with
  !> it likewise.
  subroutine writer_begin(this, env, path, meta, q0, scene, error, prior)
    class(snap_writer_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: path
    type(db_meta_t), intent(in) :: meta
    !> common initial positions [2*n_agents]
    real(wp), intent(in), contiguous :: q0(:)
    !> the reference scene (group /scene; its vertex layout is that of every sample's scene)
    type(scene_t), intent(in) :: scene
    type(error_t), allocatable, intent(out) :: error
    type(error_t), allocatable, intent(inout), optional :: prior
    character(len=:), allocatable :: m
    logical :: failed
    real(wp) :: t0
    t0 = env%wtime()
    this%env = env
    this%path = path
    this%meta = meta
    this%nset = [meta%n_train, meta%n_valid]
    this%nd = 2 * meta%n_agents; this%ns = meta%n_steps; this%ne = meta%n_expanded
    this%nv = size(scene_vertex_list(scene))
    this%place = -1
    this%nl = 0
    this%nq = 0
    this%placed = .false.
    this%local_done = .false.
    allocate(this%lam(16), this%gl(16), this%sdg(17, 16), this%queue(4))
    if (allocated(this%fault)) deallocate(this%fault)
    m = ""
    failed = .false.
    if (present(prior)) failed = allocated(prior)
    if (failed) this%fault = prior%message
    if (env%is_root()) then
      if (.not. failed) call lay_out(m)
      if (len(m) > 0) this%fault = m
      if (allocated(this%fault)) then
        if (index(this%fault, "database '") /= 1) this%fault = "database '" // path // "': " // this%fault
      end if
      this%stats%t_serial = env%wtime() - t0
    end if
    ! [status, places]: status 0, or rank 0 has no database to offer
    allocate(this%pend%x(35))
    this%pend%x = 0
    if (env%is_root()) then
      this%pend%x(1) = merge(1, 0, allocated(this%fault))
      this%pend%x(2:) = reshape(this%place, [34])
    end if
    call this%pend%start(env, error)
    if (allocated(error)) then
      if (env%is_root()) call this%h5%abort()
      return
    end if
    this%active = .true.
    if (env%is_root()) call take_places(this)
    this%stats%t_layout = env%wtime() - t0

  contains

    !> Rank 0: create the file and lay it out (this%h5 stays open).
    subroutine lay_out(m)
      character(len=:), allocatable, intent(inout) :: m
      type(error_t), allocatable :: e
      integer :: iss, q2, n
      integer :: dims(2, 17)
      character(len=:), allocatable :: g
      call this%h5%create(path, e)
      if (allocated(e)) then
        m = e%message; return
      end if
      associate (h5 => this%h5)
      ops: block
        call write_root(h5, e); if (allocated(e)) exit ops
        call h5%write("initial_positions", q0, e); if (allocated(e)) exit ops
        call put_digest(h5, "initial_positions", digest_of(q0, 0_i8), e); if (allocated(e)) exit ops
        call write_scene(h5, scene, e); if (allocated(e)) exit ops
        do iss = 1, 2
          n = this%nset(iss)
          g = trim(SNAP_SET_NAMES(iss))
          call h5%make_group(g, e); if (allocated(e)) exit ops
          call h5%make_group(g // "/stats", e); if (allocated(e)) exit ops
          call h5%write_attr(g, "n_samples", n, e); if (allocated(e)) exit ops
          call set_dims(this, iss, dims)
          do q2 = 1, 17
            if (any(q2 == LATE_DS)) cycle
            call h5%create_placed(g // "/" // trim(DS(q2)), dims(1:DRANK(q2), q2), KIND_OF(q2), this%place(q2, iss), e)
            if (allocated(e)) exit ops
          end do
        end do
      end block ops
      end associate
      if (allocated(e)) then
        m = e%message
        call this%h5%abort()
      end if
    end subroutine lay_out

    !> Root attributes (complete = 1 comes last, in finish).
    subroutine write_root(hh, e)
      type(h5file_t), intent(inout) :: hh
      type(error_t), allocatable, intent(out) :: e
      call hh%write_attr("/", "schema", SNAP_SCHEMA, e); if (allocated(e)) return
      call hh%write_attr("/", "schema_version", SNAP_SCHEMA_VERSION, e); if (allocated(e)) return
      call hh%write_attr("/", "program", "crowd_snapshots", e); if (allocated(e)) return
      call hh%write_attr("/", "version", meta%version, e); if (allocated(e)) return
      call hh%write_attr("/", "hdf5_version", meta%hdf5_version, e); if (allocated(e)) return
      call hh%write_attr("/", "mpi_version", meta%mpi_version, e); if (allocated(e)) return
      call hh%write_attr("/", "compiler", meta%compiler, e); if (allocated(e)) return
      call hh%write_attr("/", "config", meta%config_text, e); if (allocated(e)) return
      call hh%write_attr("/", "input_text", meta%input_text, e); if (allocated(e)) return
      call hh%write_attr("/", "config_hash", trim(meta%hash), e); if (allocated(e)) return
      call hh%write_attr("/", "units", SNAP_UNITS, e); if (allocated(e)) return
      call hh%write_attr("/", "n_agents", meta%n_agents, e); if (allocated(e)) return
      call hh%write_attr("/", "agent_radius", meta%radius, e); if (allocated(e)) return
      call hh%write_attr("/", "dt", meta%dt, e); if (allocated(e)) return
      call hh%write_attr("/", "n_steps", meta%n_steps, e); if (allocated(e)) return
      call hh%write_attr("/", "n_train", meta%n_train, e); if (allocated(e)) return
      call hh%write_attr("/", "n_valid", meta%n_valid, e); if (allocated(e)) return
      call hh%write_attr("/", "n_params", meta%n_expanded, e); if (allocated(e)) return
      call hh%write_attr("/", "param_names", meta%param_names, e); if (allocated(e)) return
      call hh%write_attr("/", "checksum_algorithm", DIGEST_ALGORITHM, e)
    end subroutine write_root
  end subroutine writer_begin

  !> Collective: rank 0's status (m: '' or its message), one broadcast (the message follows
  !> only on failure); every rank returns the failure.
  subroutine share_status(this, m, error)
    type(snap_writer_t), intent(inout) :: this
    character(len=:), allocatable, intent(inout) :: m
    type(error_t), allocatable, intent(out) :: error
    integer :: n(1)
    n = len(m)
    call this%env%bcast(n, error)
    if (allocated(error)) return
    if (n(1) == 0) return
    call this%env%bcast(m, error)
    if (allocated(error)) return
    if (index(m, "database '") /= 1) m = "database '" // this%path // "': " // m
    call set_error(error, m)
  end subroutine share_status

  !> The places have arrived on this rank (rank 0: its own): take them, open the file for this
  !> rank's block writes (a rank that cannot open it keeps the reason as its fault).
  subroutine take_places(this)
    type(snap_writer_t), intent(inout) :: this
    type(error_t), allocatable :: e
    this%placed = .true.
    if (.not. this%env%is_root()) then
      this%place = reshape(this%pend%x(2:), [17, 2])
      if (this%pend%x(1) /= 0 .and. .not. allocated(this%fault)) &
        this%fault = "database '" // this%path // "': rank 0 could not lay it out"
    end if
    if (allocated(this%fault)) return
    call this%pf%open(this%path // ".partial", e)
    ! (rank 0: the first offset of each set's CSR arrays, always 0, written now rather than at
    ! the end)
    if (.not. allocated(e) .and. this%env%is_root()) then
      if (this%place(5, 1) >= 0) call this%pf%write_at(this%place(5, 1), [0_i8], 8_i8, e)
      if (.not. allocated(e) .and. this%place(5, 2) >= 0) call this%pf%write_at(this%place(5, 2), [0_i8], 8_i8, e)
    end if
    if (allocated(e)) this%fault = "database '" // this%path // "': " // e%message
  end subroutine take_places

  !> Not collective: once the places have arrived (wait: until they do), write the samples put
  !> before (t_written: the time writing them, s) and complete this rank's part of the broadcast.
  !> Returns this rank's fault (rank 0's failed layout, or a file this rank could not open).
  subroutine settle(this, wait, error, t_written)
    type(snap_writer_t), intent(inout) :: this
    logical, intent(in) :: wait
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(out) :: t_written
    logical :: done
    integer :: j
    real(wp) :: t0
    t_written = 0
    if (this%pend%active) then
      if (wait) then
        call this%pend%wait(error)
        done = .true.
      else
        call this%pend%test(done, error)
      end if
      if (allocated(error)) then
        if (.not. allocated(this%fault)) this%fault = "database '" // this%path // "': " // error%message
        return
      end if
      if (done .and. .not. this%placed) call take_places(this)
    end if
    if (allocated(this%fault)) then
      call set_error(error, this%fault); return
    end if
    if (.not. this%placed .or. this%nq == 0) return
    t0 = this%env%wtime()
    do j = 1, this%nq
      call write_sample(this, this%queue(j), error)
      if (allocated(error)) exit
    end do
    deallocate(this%queue)
    allocate(this%queue(4))
    this%nq = 0
    t_written = this%env%wtime() - t0
  end subroutine settle

  !> Not collective, cheap: if the places have arrived, write the samples this rank put before
  !> (their time counts in stats%t_held); returns this rank's fault, e.g. rank 0's failed
  !> layout, so that a sample loop can stop before its next sample.
  subroutine writer_poll(this, error)
    class(snap_writer_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    call settle_held(this, .false., error)
  end subroutine writer_poll

  !> Not collective: wait for the places (e.g. before putting the samples of earlier pieces).
  subroutine writer_wait_places(this, error)
    class(snap_writer_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    call settle_held(this, .true., error)
  end subroutine writer_wait_places

  !> settle outside put (poll, wait_places): the time writing held samples counts in t_held.
  subroutine settle_held(this, wait, error)
    type(snap_writer_t), intent(inout) :: this
    logical, intent(in) :: wait
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: tw
    if (.not. this%active) return
    call settle(this, wait, error, tw)
    this%stats%t_held = this%stats%t_held + tw
    this%stats%t_put = this%stats%t_put + tw
  end subroutine settle_held

  !> Global dims of the datasets of set is [2, 17] (second entry unused for 1D datasets).
  subroutine set_dims(this, is, dims)
    type(snap_writer_t), intent(in) :: this
    integer, intent(in) :: is
    integer, intent(out) :: dims(2, 17)
    integer :: n, q
    n = this%nset(is)
    dims(:, 1) = [this%ne, n]; dims(:, 2) = [this%nd, (this%ns + 1) * n]; dims(:, 3) = [this%nd, this%ns * n]
    dims(:, 4) = [this%nd, this%ns * n]; dims(:, 5) = [this%ns * n + 1, 0]
    dims(:, 6) = [int(this%total(is)), 0]; dims(:, 7) = [int(this%total(is)), 0]
    do q = 8, 12
      dims(:, q) = [this%ns, n]
    end do
    dims(:, 13) = [n, 0]; dims(:, 14) = [n, 0]; dims(:, 15) = [n, 0]
    dims(:, 16) = [this%nv, n]; dims(:, 17) = [4, n]
  end subroutine set_dims

  !> Write one sample (this rank's; not collective): its blocks of every dataset but the
  !> multipliers go to their places, their checksum parts are added; the multipliers are kept
  !> (compact) until finish places them. Before the places have arrived from rank 0 the sample
  !> is kept whole and written when they do (a later put, poll or finish). The sample's
  !> scene_v / scene_exit must be set.
  subroutine writer_put(this, s, error)
    class(snap_writer_t), intent(inout) :: this
    type(snap_sample_t), intent(in) :: s
    type(error_t), allocatable, intent(out) :: error
    type(snap_sample_t), allocatable :: q2(:)
    character(len=:), allocatable :: m
    real(wp) :: t0, tw
    integer :: j
    t0 = this%env%wtime()
    if (.not. this%active) then
      call set_error(error, "database '" // this%path // "': put before begin or after finish"); return
    end if
    m = ""
    call check_shapes(this, s, m)
    if (len(m) > 0) then
      call set_error(error, "database '" // this%path // "': " // m); return
    end if
    call settle(this, .false., error, tw)
    if (allocated(error)) return
    if (this%placed) then
      call write_sample(this, s, error)
    else
      if (this%nq == size(this%queue)) then
        allocate(q2(2 * this%nq))
        do j = 1, this%nq
          call move_sample(this%queue(j), q2(j))
        end do
        call move_alloc(q2, this%queue)
      end if
      this%nq = this%nq + 1
      this%queue(this%nq) = s
    end if
    this%stats%t_put = this%stats%t_put + (this%env%wtime() - t0)
  end subroutine writer_put

  !> Move sample a into b; a is left empty (every allocatable component deallocated, the
  !> scalars at their defaults). Intrinsic assignment copies every component of the type,
  !> including components added later, so this never needs extending by hand; the price is one
  !> copy of the sample's arrays per move (queues and held lists grow by doubling: about one
  !> copy per sample, against seconds to compute it), and only one sample is held twice at a
  !> time.
  subroutine move_sample(a, b)
    type(snap_sample_t), intent(inout) :: a
    type(snap_sample_t), intent(out) :: b
    b = a
    a = snap_sample_t()
  end subroutine move_sample

  !> The blocks of one checked sample at their places, its checksum parts, its multipliers kept.
  subroutine write_sample(this, s, error)
    type(snap_writer_t), intent(inout) :: this
    type(snap_sample_t), intent(in) :: s
    type(error_t), allocatable, intent(out) :: error
    type(snap_sample_t), allocatable :: l2(:)
    integer, allocatable :: g2(:)
    type(digest_t), allocatable :: sd2(:,:)
    type(digest_t) :: dd(17)
    integer(i8) :: o(17), at(17)
    integer :: is, q, nd, ns, ne, nv
    nd = this%nd; ns = this%ns; ne = this%ne; nv = this%nv
    is = findloc(SNAP_SET_NAMES, s%set, dim=1)
    o = elem_offsets(this, s, 0_i8)
    at = this%place(:, is) + o * ESZ
    ! the sample's block digests (the multipliers' in finish), added to the checksum parts
    dd(1) = digest_of(s%mu, o(1)); dd(2) = digest_of(s%q, o(2))
    dd(3) = digest_of(s%u, o(3)); dd(4) = digest_of(s%v, o(4))
    dd(8) = digest_of(s%kkt, o(8)); dd(9) = digest_of(s%min_gap, o(9))
    dd(10) = digest_of(s%iterations, o(10)); dd(11) = digest_of(s%converged, o(11))
    dd(12) = digest_of(s%n_active, o(12)); dd(13) = digest_of([s%time], o(13))
    dd(14) = digest_of([s%rank], o(14)); dd(15) = digest_of([s%start], o(15))
    dd(16) = digest_of(s%scene_v, o(16)); dd(17) = digest_of(s%scene_exit, o(17))
    this%dg(:, is) = digest_add(this%dg(:, is), dd)
    w: block
      call this%pf%write_at(at(1), s%mu, 8_i8 * ne, error); if (allocated(error)) exit w
      call this%pf%write_at(at(2), s%q, 8_i8 * nd * (ns + 1), error); if (allocated(error)) exit w
      call this%pf%write_at(at(3), s%u, 8_i8 * nd * ns, error); if (allocated(error)) exit w
      call this%pf%write_at(at(4), s%v, 8_i8 * nd * ns, error); if (allocated(error)) exit w
      call this%pf%write_at(at(8), s%kkt, 8_i8 * ns, error); if (allocated(error)) exit w
      call this%pf%write_at(at(9), s%min_gap, 8_i8 * ns, error); if (allocated(error)) exit w
      call this%pf%write_at(at(10), s%iterations, 4_i8 * ns, error); if (allocated(error)) exit w
      call this%pf%write_at(at(11), s%converged, 4_i8 * ns, error); if (allocated(error)) exit w
      call this%pf%write_at(at(12), s%n_active, 4_i8 * ns, error); if (allocated(error)) exit w
      call this%pf%write_at(at(13), [s%time], 8_i8, error); if (allocated(error)) exit w
      call this%pf%write_at(at(14), [s%rank], 4_i8, error); if (allocated(error)) exit w
      call this%pf%write_at(at(15), [s%start], 8_i8, error); if (allocated(error)) exit w
      if (nv > 0) then
        call this%pf%write_at(at(16), s%scene_v, 8_i8 * nv, error); if (allocated(error)) exit w
      end if
      call this%pf%write_at(at(17), s%scene_exit, 32_i8, error)
    end block w
    if (allocated(error)) return
    ! the multipliers, kept for finish
    if (this%nl == size(this%lam)) then
      allocate(l2(2 * this%nl), g2(2 * this%nl), sd2(17, 2 * this%nl))
      g2(1:this%nl) = this%gl(1:this%nl)
      sd2(:, 1:this%nl) = this%sdg(:, 1:this%nl)
      call move_alloc(sd2, this%sdg)
      do q = 1, this%nl
        call move_alloc(this%lam(q)%offset, l2(q)%offset); call move_alloc(this%lam(q)%key, l2(q)%key)
        call move_alloc(this%lam(q)%ia, l2(q)%ia); call move_alloc(this%lam(q)%ib, l2(q)%ib)
        call move_alloc(this%lam(q)%ob, l2(q)%ob); call move_alloc(this%lam(q)%value, l2(q)%value)
        l2(q)%set = this%lam(q)%set; l2(q)%index = this%lam(q)%index
      end do
      call move_alloc(l2, this%lam); call move_alloc(g2, this%gl)
    end if
    this%nl = this%nl + 1
    associate (l => this%lam(this%nl))
      l%set = s%set; l%index = s%index
      l%offset = s%offset; l%key = s%key; l%ia = s%ia; l%ib = s%ib; l%ob = s%ob; l%value = s%value
    end associate
    this%gl(this%nl) = gnum(this, s)
    this%sdg(:, this%nl) = dd
    this%stats%bytes = this%stats%bytes + sample_bytes(this, s)
  end subroutine write_sample

  !> Not collective, the first part of finish (a caller may run it before some synchronisation
  !> of its own, e.g. while other ranks still compute): wait for the places, write the samples
  !> held meanwhile, and find this rank's contacts for the dictionary. `error` on entry: this
  !> rank's failure before (then only the broadcast of the places is completed); on return:
  !> that failure or a new one, which finish then shares.
  subroutine writer_end_local(this, error)
    class(snap_writer_t), intent(inout) :: this
    type(error_t), allocatable, intent(inout) :: error
    type(error_t), allocatable :: e2
    real(wp) :: t1, tw
    this%local_done = .true.
    if (allocated(this%pack4)) deallocate(this%pack4)
    if (allocated(error)) then
      call this%pend%wait(e2)
    else
      call settle(this, .true., error, tw)
      this%stats%t_held = this%stats%t_held + tw
      this%stats%t_put = this%stats%t_put + tw
      if (.not. allocated(error) .and. .not. this%placed) call set_error(error, "places not received")
    end if
    this%stats%marks(1) = this%env%wtime()
    ! this rank's contacts (unique keys and identities) for the dictionary
    t1 = this%env%wtime()
    if (allocated(error)) then
      allocate(this%pack4(4, 0))
    else
      call local_contacts(this%lam(1:this%nl), this%pack4)
    end if
    this%stats%t_blocks = this%env%wtime() - t1
  end subroutine writer_end_local

  !> Collective: every sample of the study must have been put by exactly one rank. `error` on
  !> entry: this rank's failure before finish (e.g. in its sample loop); if any rank has one,
  !> every rank returns the lowest failing rank's (agreed) and the database is discarded.
  !> `extra`: the caller's figures, summed over the ranks in finish's first reduction.
  !>
  !> Steps (collectives in brackets): the places are awaited and the samples held meanwhile
  !> written; this rank's contacts; [one MPI_Allreduce: failures, each sample's holder and
  !> number of multipliers, every rank's number of contacts, the checksum parts of the datasets
  !> the study sizes, extra] (end_reduction); rank 0 places lambda_index and lambda_value (HDF5)
  !> while the others compute their CSR offsets and checksum parts (csr_offsets); [one
  !> MPI_Allgatherv: the contacts, and rank 0's status and places first]: the dictionary, the
  !> sorted union of the contacts (share_dictionary); each rank's dictionary indices, the
  !> multipliers' checksum parts (dictionary_indices) and its multiplier blocks; [one MPI_Reduce
  !> to rank 0: every rank's blocks are in (or it failed), with the checksum parts]
  !> (write_multipliers); rank 0 then adds the dictionary, every checksum and complete = 1,
  !> closes the file and renames it (the commit) [one broadcast of its status; on failure an
  !> agreement on the failing rank's message] (seal). On failure the temporary is removed.
  subroutine writer_finish(this, error, extra, qois)
    class(snap_writer_t), intent(inout) :: this
    type(error_t), allocatable, intent(inout) :: error
    real(wp), intent(inout), optional :: extra(:)
    !> rank 0: the quantities of interest of every sample, train then valid [n_train + n_valid],
    !> written as the QoI group <set>/qoi (cr_qoi_file)
    type(qoi_t), intent(in), optional :: qois(:)
    type(finish_state_t) :: fs
    fs%t0 = this%env%wtime()
    this%stats%marks(2:) = fs%t0
    fs%ntot = sum(this%nset)
    ! the places, the samples held meanwhile and this rank's contacts (if the caller has not
    ! asked for them before)
    if (.not. this%local_done) call this%end_local(error)
    call move_alloc(this%pack4, fs%pack4)
    call end_reduction(this, fs, error, extra)
    if (.not. allocated(error)) then
      call csr_offsets(this, fs)
      call share_dictionary(this, fs, error)
    end if
    if (.not. (allocated(error) .or. fs%ended)) then
      call dictionary_indices(this, fs)
      this%stats%t_dict = this%env%wtime() - fs%t0
      call write_multipliers(this, fs, error)
      call seal(this, fs, error, qois)
    end if
    this%active = .false.
    if (allocated(error)) then
      call this%discard()
      if (index(error%message, "database '") /= 1) error%message = "database '" // this%path // "': " // &
        error%message
    end if
  end subroutine writer_finish

  !> finish, the end reduction: [failed, (held, multipliers) per sample, data bytes, contact
  !> entries per rank [P], checksum parts [2, 17, 2] (those of the multipliers are still 0),
  !> extra]; every value is an integer below 2^53 (exact in real(wp)) but extra's. Then each
  !> sample's place in its set's CSR arrays, the contact counts and the summed checksums.
  subroutine end_reduction(this, fs, error, extra)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    type(error_t), allocatable, intent(inout) :: error
    real(wp), intent(inout), optional :: extra(:)
    real(wp), allocatable :: red(:)
    type(error_t), allocatable :: e2
    integer :: ntot, p, ne, j, k, is, q, g
    logical :: failed
    associate (env => this%env)
    ntot = fs%ntot
    p = env%size
    ne = 0
    if (present(extra)) ne = size(extra)
    failed = allocated(error)
    allocate(red(1 + 2 * ntot + 1 + p + 68 + ne))
    red = 0
    red(1) = merge(1, 0, failed)
    do j = 1, this%nl
      red(1 + 2 * this%gl(j) - 1) = 1
      red(1 + 2 * this%gl(j)) = size(this%lam(j)%value)
    end do
    red(2 + 2 * ntot) = real(this%stats%bytes, wp)
    red(3 + 2 * ntot + env%rank) = size(fs%pack4)
    k = 2 + 2 * ntot + p
    do is = 1, 2
      do q = 1, 17
        red(k + 1) = real(this%dg(q, is)%s1, wp); red(k + 2) = real(this%dg(q, is)%s2, wp)
        k = k + 2
      end do
    end do
    if (ne > 0) red(k + 1:) = extra
    call env%allreduce(red, 'sum', e2)
    this%stats%marks(2) = env%wtime()
    if (allocated(e2)) then
      if (allocated(error)) deallocate(error)
      call move_alloc(e2, error)
      return
    end if
    if (ne > 0) extra = red(k + 1:)
    if (red(1) > 0) then
      call env%agree_error(error); return
    end if
    this%stats%bytes = nint(red(2 + 2 * ntot), i8)
    do g = 1, ntot
      if (nint(red(2 * g)) /= 1) then
        call set_error(error, "sample " // str(g) // " of the study was written by " // str(nint(red(2 * g))) // &
          " ranks (expected exactly one)"); return
      end if
    end do
    allocate(this%base(ntot))
    this%total = 0
    do g = 1, ntot
      is = merge(1, 2, g <= this%nset(1))
      this%base(g) = this%total(is)
      this%total(is) = this%total(is) + nint(red(1 + 2 * g), i8)
    end do
    if (any(this%total > huge(1))) then
      call set_error(error, str(maxval(this%total)) // " multipliers in one set exceed the 32-bit dataset sizes")
      return
    end if
    fs%counts = nint(red(3 + 2 * ntot:2 + 2 * ntot + p))
    if (sum(real(fs%counts, wp)) + 5 > huge(1)) then
      call set_error(error, str(sum(int(fs%counts, i8)) / 4) // " contact entries exceed the 32-bit MPI counts")
      return
    end if
    this%stats%nnz = sum(this%total)
    k = 2 + 2 * ntot + p
    do is = 1, 2
      do q = 1, 17
        this%dg(q, is) = digest_add(digest_t(nint(red(k + 1), i8), nint(red(k + 2), i8)), digest_t())
        k = k + 2
      end do
      this%dg(LAMBDA_DS, is) = digest_t()
    end do
    end associate
  end subroutine end_reduction

  !> finish: rank 0 places the multiplier datasets; every rank meanwhile computes the global
  !> CSR offsets of its samples and the checksum parts of the offsets and values.
  subroutine csr_offsets(this, fs)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    integer :: j, is
    integer(i8) :: o(17)
    real(wp) :: t1
    associate (env => this%env)
    fs%m = ""
    fs%lplace = -1
    if (env%is_root()) then
      t1 = env%wtime()
      call place_multipliers(this, fs)
      this%stats%t_serial = this%stats%t_serial + (env%wtime() - t1)
    end if
    t1 = env%wtime()
    allocate(fs%csr(this%nl))
    do j = 1, this%nl
      is = findloc(SNAP_SET_NAMES, this%lam(j)%set, dim=1)
      fs%csr(j)%off8 = this%base(this%gl(j)) + this%lam(j)%offset(2:this%ns + 1)
      o = elem_offsets(this, this%lam(j), this%base(this%gl(j)))
      this%sdg(5, j) = digest_of(fs%csr(j)%off8, o(5))
      this%sdg(7, j) = digest_of(this%lam(j)%value, o(7))
      this%dg(5, is) = digest_add(this%dg(5, is), this%sdg(5, j))
      this%dg(7, is) = digest_add(this%dg(7, is), this%sdg(7, j))
      ! the leading 0 of lambda_offset belongs to the block of the set's first sample
      if (this%lam(j)%index == 1) this%sdg(5, j) = digest_add(this%sdg(5, j), digest_of([0_i8], 0_i8))
    end do
    if (env%is_root()) then
      do is = 1, 2
        this%dg(5, is) = digest_add(this%dg(5, is), digest_of([0_i8], 0_i8))
      end do
    end if
    this%stats%t_blocks = this%stats%t_blocks + (env%wtime() - t1)
    end associate
  end subroutine csr_offsets

  !> finish: the contacts of every rank, rank 0's status and places first ([len(m), places
  !> [2, 2]], one MPI_Allgatherv); the contact dictionary, their sorted union. fs%ended: rank
  !> 0 failed (error holds its message).
  subroutine share_dictionary(this, fs, error)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    type(error_t), allocatable, intent(inout) :: error
    integer(i8), allocatable :: sendb(:), allk(:), all4(:, :)
    integer, allocatable :: displs(:), ids(:, :)
    integer :: head, q, p, nc, mm, is
    associate (env => this%env)
    p = env%size
    head = 5
    fs%counts(1) = fs%counts(1) + head
    allocate(displs(p))
    displs(1) = 0
    do q = 2, p
      displs(q) = displs(q - 1) + fs%counts(q - 1)
    end do
    nc = size(fs%pack4)
    if (env%is_root()) then
      sendb = [int(len(fs%m), i8), reshape(fs%lplace, [4]), reshape(fs%pack4, [nc])]
    else
      sendb = reshape(fs%pack4, [nc])
    end if
    allocate(allk(sum(fs%counts)))
    call env%allgatherv(sendb, allk, fs%counts, displs, error)
    this%stats%marks(3) = env%wtime()
    if (allocated(error)) return
    if (allk(1) /= 0) then
      call share_status(this, fs%m, error)
      fs%ended = .true.; return
    end if
    do is = 1, 2
      this%place(LATE_DS, is) = allk(2 + 2 * (is - 1):3 + 2 * (is - 1))
    end do
    mm = (size(allk) - head) / 4
    all4 = reshape(allk(head + 1:), [4, mm])
    fs%dkey = all4(1, :)
    ids = int(all4(2:4, :))
    deallocate(all4, allk)
    call unique_contacts(fs%dkey, ids, mm)
    fs%dkey = fs%dkey(1:mm)
    fs%dia = ids(1, 1:mm); fs%dib = ids(2, 1:mm); fs%dob = ids(3, 1:mm)
    this%stats%n_dict = mm
    end associate
  end subroutine share_dictionary

  !> finish: each rank's dictionary indices and their checksum parts; the report to rank 0
  !> packed (fs%dl: [multipliers' checksum parts [2, 3, 2], failed, block digests [34, ntot]]).
  subroutine dictionary_indices(this, fs)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    integer :: j, k, is, q
    integer(i8) :: o(17)
    real(wp) :: t1
    t1 = this%env%wtime()
    do j = 1, this%nl
      is = findloc(SNAP_SET_NAMES, this%lam(j)%set, dim=1)
      allocate(fs%csr(j)%li(size(this%lam(j)%key)))
      do k = 1, size(this%lam(j)%key)
        fs%csr(j)%li(k) = bsearch_i8(fs%dkey, this%lam(j)%key(k))
      end do
      o = elem_offsets(this, this%lam(j), this%base(this%gl(j)))
      this%sdg(6, j) = digest_of(fs%csr(j)%li, o(6))
      this%dg(6, is) = digest_add(this%dg(6, is), this%sdg(6, j))
    end do
    allocate(fs%dl(13 + 34 * fs%ntot))
    fs%dl = 0
    do j = 1, this%nl
      k = 13 + 34 * (this%gl(j) - 1)
      fs%dl(k + 1:k + 34) = real(reshape(digest_pack_all(this%sdg(:, j)), [34]), wp)
      ! the run's wall times and ranks (different in every run) have whole checksums only, so
      ! that the same study gives the same table
      do q = 1, size(RUN_DS)
        fs%dl(k + 2 * RUN_DS(q) - 1:k + 2 * RUN_DS(q)) = 0
      end do
    end do
    k = 0
    do is = 1, 2
      do q = 1, 3
        fs%dl(k + 1) = real(this%dg(LAMBDA_DS(q), is)%s1, wp); fs%dl(k + 2) = real(this%dg(LAMBDA_DS(q), is)%s2, wp)
        k = k + 2
      end do
    end do
    this%stats%t_blocks = this%stats%t_blocks + (this%env%wtime() - t1)
  end subroutine dictionary_indices

  !> finish: this rank's multiplier blocks, the file handle of begin closed, then every rank's
  !> report to rank 0 (MPI_Reduce: a rank other than 0 does not wait for it): its blocks are in,
  !> or it failed, with the multipliers' checksum parts [failed, 2, 3, 2].
  subroutine write_multipliers(this, fs, error)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    type(error_t), allocatable, intent(inout) :: error
    type(error_t), allocatable :: e2
    integer :: j, is
    integer(i8) :: o(17), at(17)
    real(wp) :: t1
    associate (env => this%env)
    t1 = env%wtime()
    do j = 1, this%nl
      if (allocated(error)) exit
      is = findloc(SNAP_SET_NAMES, this%lam(j)%set, dim=1)
      o = elem_offsets(this, this%lam(j), this%base(this%gl(j)))
      at = this%place(:, is) + o * ESZ
      call this%pf%write_at(at(5), fs%csr(j)%off8, 8_i8 * this%ns, error)
      if (.not. allocated(error) .and. size(fs%csr(j)%li) > 0) &
        call this%pf%write_at(at(6), fs%csr(j)%li, 4_i8 * size(fs%csr(j)%li), error)
      if (.not. allocated(error) .and. size(fs%csr(j)%li) > 0) &
        call this%pf%write_at(at(7), this%lam(j)%value, 8_i8 * size(fs%csr(j)%li), error)
    end do
    call this%pf%close(e2)
    if (allocated(e2) .and. .not. allocated(error)) call move_alloc(e2, error)
    this%stats%t_blocks = this%stats%t_blocks + (env%wtime() - t1)
    this%stats%t_write = env%wtime() - t1
    this%stats%marks(4) = env%wtime()
    fs%dl(13) = merge(1, 0, allocated(error))
    call env%reduce_sum_root(fs%dl, e2)
    if (allocated(e2) .and. .not. allocated(error)) call move_alloc(e2, error)
    this%stats%marks(5) = env%wtime()
    end associate
  end subroutine write_multipliers

  !> finish: rank 0, once every rank's blocks are in: dictionary, every checksum, complete = 1,
  !> the file closed and renamed (the commit); its status to every rank (one broadcast: 0
  !> committed, 1 some rank failed, whose message every rank then agrees on).
  subroutine seal(this, fs, error, qois)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    type(error_t), allocatable, intent(inout) :: error
    type(qoi_t), intent(in), optional :: qois(:)
    type(error_t), allocatable :: e2
    integer :: stat1(1), k, is, q
    real(wp) :: t1
    associate (env => this%env)
    t1 = env%wtime()
    stat1 = 0
    if (env%is_root()) then
      if (.not. allocated(error) .and. nint(fs%dl(13)) == 0) then
        k = 0
        do is = 1, 2
          do q = 1, 3
            this%dg(LAMBDA_DS(q), is) = digest_add(digest_t(nint(fs%dl(k + 1), i8), nint(fs%dl(k + 2), i8)), &
              digest_t())
            k = k + 2
          end do
        end do
        fs%m = ""
        call add_block_table(this, fs)
        if (len(fs%m) == 0) call add_rest(this, fs, qois)
        if (len(fs%m) == 0) then
          if (rename_file(this%path // ".partial", this%path) /= 0) &
            fs%m = "rename '" // this%path // ".partial' -> '" // this%path // "' failed"
        end if
        if (len(fs%m) > 0) call set_error(error, fs%m)
      end if
      this%stats%t_serial = this%stats%t_serial + (env%wtime() - t1)
      this%stats%t_layout = this%stats%t_layout + (env%wtime() - t1)
      stat1 = merge(1, 0, allocated(error) .or. nint(fs%dl(13)) > 0)
    end if
    call env%bcast(stat1, e2)
    if (allocated(e2)) then
      if (allocated(error)) deallocate(error)
      call move_alloc(e2, error)
    else if (stat1(1) /= 0) then
      call env%agree_error(error)
      if (.not. allocated(error)) call set_error(error, "a rank failed to finish the database")
    end if
    this%stats%t_seal = env%wtime() - t1
    this%stats%marks(6) = env%wtime()
    end associate
  end subroutine seal

  !> Rank 0 (before add_rest closes the file): each set's block table <set>/sample_checksums
  !> [34, n] from the reduced block digests, with its own checksum; each column's sum over the
  !> samples must give the dataset checksums (a slip in the bookkeeping fails here; fs%m).
  subroutine add_block_table(this, fs)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    type(error_t), allocatable :: e
    integer, allocatable :: tab(:,:)
    integer :: iss, q2, g0
    character(len=:), allocatable :: g, names
    names = ""
    do q2 = 1, 17
      if (q2 > 1) names = names // ","
      names = names // trim(DS(q2))
    end do
    g0 = 0
    do iss = 1, 2
      g = trim(SNAP_SET_NAMES(iss))
      tab = reshape(nint(fs%dl(13 + 34 * g0 + 1:13 + 34 * (g0 + this%nset(iss)))), [34, this%nset(iss)])
      g0 = g0 + this%nset(iss)
      if (this%nset(iss) == 0) cycle
      do q2 = 1, 17
        if (any(q2 == RUN_DS)) cycle
        if (digest_hex(digest_table_sum(tab, q2)) /= digest_hex(this%dg(q2, iss))) then
          fs%m = "block digests of " // g // "/" // trim(DS(q2)) // " do not add up to its checksum"; return
        end if
      end do
      call this%h5%write(g // "/" // SAMPLE_CHECKSUMS, tab, e); if (allocated(e)) exit
      call put_digest(this%h5, g // "/" // SAMPLE_CHECKSUMS, digest_of(tab, 0_i8), e); if (allocated(e)) exit
      call this%h5%write_attr(g // "/" // SAMPLE_CHECKSUMS, "datasets", names, e); if (allocated(e)) exit
      call this%h5%write_attr(g // "/" // SAMPLE_CHECKSUMS, "description", "per sample (column), the " // &
        "two residues of the digest of that sample's block of each dataset named in 'datasets' " // &
        "(src/io/cr_digest.f90); lambda_offset's block of the first sample includes the leading 0; " // &
        "0 for stats/time, stats/rank, stats/start (they differ from run to run: whole checksums only)", e)
      if (allocated(e)) exit
    end do
    if (allocated(e)) then
      fs%m = e%message; call this%h5%abort()
    end if
  end subroutine add_block_table

  !> Rank 0: create lambda_index and lambda_value of both sets (their places in fs%lplace
  !> [2, 2]; a failure in fs%m).
  subroutine place_multipliers(this, fs)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    type(error_t), allocatable :: e
    integer :: iss, q2, dims(2, 17)
    character(len=:), allocatable :: g
    if (.not. this%h5%is_open()) then
      fs%m = "the file is not open on rank 0"; return
    end if
    do iss = 1, 2
      g = trim(SNAP_SET_NAMES(iss))
      call set_dims(this, iss, dims)
      do q2 = 1, 2
        call this%h5%create_placed(g // "/" // trim(DS(LATE_DS(q2))), dims(1:1, LATE_DS(q2)), KIND_OF(LATE_DS(q2)), &
          fs%lplace(q2, iss), e)
        if (allocated(e)) then
          fs%m = e%message; return
        end if
      end do
    end do
  end subroutine place_multipliers

  !> Rank 0: contact dictionary, every checksum, the QoI groups and complete = 1, serially; the
  !> file closed (a failure in fs%m).
  subroutine add_rest(this, fs, qois)
    type(snap_writer_t), intent(inout) :: this
    type(finish_state_t), intent(inout) :: fs
    type(qoi_t), intent(in), optional :: qois(:)
    type(error_t), allocatable :: e, e3
    integer :: iss, q2
    character(len=:), allocatable :: g
    associate (h5 => this%h5)
    ops: block
      call h5%make_group("contacts", e); if (allocated(e)) exit ops
      call h5%write("contacts/key", fs%dkey, e); if (allocated(e)) exit ops
      call put_digest(h5, "contacts/key", digest_of(fs%dkey, 0_i8), e); if (allocated(e)) exit ops
      call h5%write("contacts/ia", fs%dia, e); if (allocated(e)) exit ops
      call put_digest(h5, "contacts/ia", digest_of(fs%dia, 0_i8), e); if (allocated(e)) exit ops
      call h5%write("contacts/ib", fs%dib, e); if (allocated(e)) exit ops
      call put_digest(h5, "contacts/ib", digest_of(fs%dib, 0_i8), e); if (allocated(e)) exit ops
      call h5%write("contacts/ob", fs%dob, e); if (allocated(e)) exit ops
      call put_digest(h5, "contacts/ob", digest_of(fs%dob, 0_i8), e); if (allocated(e)) exit ops
      call h5%write_attr("contacts", "description", "global contact dictionary: every contact " // &
        "with lambda > 0 in some sample and step, sorted by key; ib = 0 for agent-obstacle " // &
        "contacts (ob = obstacle index), ob = 0 for agent pairs", e); if (allocated(e)) exit ops
      do iss = 1, 2
        g = trim(SNAP_SET_NAMES(iss))
        do q2 = 1, 17
          call put_digest(h5, g // "/" // trim(DS(q2)), this%dg(q2, iss), e); if (allocated(e)) exit ops
        end do
      end do
      if (present(qois)) then
        call write_qoi_group(h5, "train/qoi", qois(1:this%nset(1)), e); if (allocated(e)) exit ops
        call write_qoi_group(h5, "valid/qoi", qois(this%nset(1) + 1:), e); if (allocated(e)) exit ops
      end if
      ! (the file keeps its temporary name until every rank's multiplier blocks are in)
      call h5%write_attr("/", "complete", 1, e)
    end block ops
    if (allocated(e)) then
      fs%m = e%message
      call h5%abort()
      return
    end if
    call h5%close(e3)
    if (allocated(e3)) fs%m = e3%message
    end associate
  end subroutine add_rest

  !> Collective: give up a database being written (after begin): each rank completes the
  !> broadcast of the places and closes its file, and rank 0 removes the temporary. Nothing
  !> under the final name is touched.
  subroutine writer_discard(this)
    class(snap_writer_t), intent(inout) :: this
    type(error_t), allocatable :: e
    integer :: st
    if (.not. allocated(this%path)) return
    call this%pend%wait(e)
    if (allocated(e)) deallocate(e)
    call this%pf%close(e)
    if (allocated(e)) deallocate(e)
    if (this%h5%is_open()) call this%h5%abort()
    this%active = .false.
    this%nq = 0
    ! every rank has closed the file before rank 0 removes it (a failed barrier is not reported:
    ! the run has failed already)
    call this%env%sync(e)
    if (this%env%is_root()) st = remove_file(this%path // ".partial")
  end subroutine writer_discard

  !> Block digests as a table column [2, n].
  pure function digest_pack_all(d) result(r)
    type(digest_t), intent(in) :: d(:)
    integer :: r(2, size(d))
    integer :: q
    do q = 1, size(d)
      r(:, q) = digest_pack(d(q))
    end do
  end function digest_pack_all

  !> Global number of a sample (train 1..n_train, then valid).
  integer function gnum(this, s)
    type(snap_writer_t), intent(in) :: this
    type(snap_sample_t), intent(in) :: s
    gnum = s%index
    if (s%set == SNAP_SET_NAMES(2)) gnum = this%nset(1) + s%index
  end function gnum

  !> Shapes of a sample against the metadata (m = '' if right).
  subroutine check_shapes(this, s, m)
    type(snap_writer_t), intent(in) :: this
    type(snap_sample_t), intent(in) :: s
    character(len=:), allocatable, intent(inout) :: m
    integer :: iss, nnz, nd, ns
    nd = this%nd; ns = this%ns
    iss = findloc(SNAP_SET_NAMES, s%set, dim=1)
    if (iss == 0) then
      m = "sample of unknown set '" // trim(s%set) // "'"; return
    end if
    if (s%index < 1 .or. s%index > this%nset(iss)) then
      m = trim(s%set) // " sample " // str(s%index) // " is outside 1.." // str(this%nset(iss)); return
    end if
    if (.not. (allocated(s%mu) .and. allocated(s%q) .and. allocated(s%u) .and. allocated(s%v) .and. &
        allocated(s%kkt) .and. allocated(s%min_gap) .and. allocated(s%iterations) .and. allocated(s%converged) &
        .and. allocated(s%n_active) .and. allocated(s%offset) .and. allocated(s%key) .and. allocated(s%ia) .and. &
        allocated(s%ib) .and. allocated(s%ob) .and. allocated(s%value) .and. allocated(s%scene_v))) then
      m = trim(s%set) // " sample " // str(s%index) // ": incomplete sample (unallocated data)"; return
    end if
    nnz = size(s%value)
    if (size(s%mu) /= this%ne .or. any(shape(s%q) /= [nd, ns + 1]) .or. any(shape(s%u) /= [nd, ns]) .or. &
        any(shape(s%v) /= [nd, ns]) .or. size(s%kkt) /= ns .or. size(s%min_gap) /= ns .or. &
        size(s%iterations) /= ns .or. size(s%converged) /= ns .or. size(s%n_active) /= ns .or. &
        size(s%offset) /= ns + 1 .or. size(s%key) /= nnz .or. size(s%ia) /= nnz .or. size(s%ib) /= nnz .or. &
        size(s%ob) /= nnz .or. size(s%scene_v) /= this%nv) then
      m = trim(s%set) // " sample " // str(s%index) // ": array shapes disagree with the study (" // &
        str(nd) // " dofs, " // str(ns) // " steps, " // str(this%ne) // " parameters, " // str(this%nv) // &
        " scene vertex coordinates)"; return
    end if
    if (s%offset(1) /= 0 .or. s%offset(ns + 1) /= nnz) m = trim(s%set) // " sample " // str(s%index) // &
      ": multiplier offsets do not span its " // str(nnz) // " entries"
  end subroutine check_shapes

  !> Element offset (0-based) of sample s in each dataset of its set [17]; `lbase`: position of
  !> its multipliers in the set's CSR arrays (only known in finish).
  function elem_offsets(this, s, lbase) result(o)
    type(snap_writer_t), intent(in) :: this
    type(snap_sample_t), intent(in) :: s
    integer(i8), intent(in) :: lbase
    integer(i8) :: o(17)
    integer(i8) :: k1, ne, nd, ns, nv
    k1 = s%index - 1
    ne = this%ne; nd = this%nd; ns = this%ns; nv = this%nv
    o = [k1 * ne, k1 * (ns + 1) * nd, k1 * ns * nd, k1 * ns * nd, k1 * ns + 1, lbase, lbase, &
      k1 * ns, k1 * ns, k1 * ns, k1 * ns, k1 * ns, k1, k1, k1, k1 * nv, k1 * 4]
  end function elem_offsets

  !> Data bytes of one sample in the database.
  integer(i8) function sample_bytes(this, s)
    type(snap_writer_t), intent(in) :: this
    type(snap_sample_t), intent(in) :: s
    integer(i8) :: ne, nd, ns, nv
    ne = this%ne; nd = this%nd; ns = this%ns; nv = this%nv
    sample_bytes = 8_i8 * (ne + nd * (3 * ns + 1) + 3 * ns + 2 + nv + 4 + size(s%value)) + &
      4_i8 * (3 * ns + 1 + size(s%value))
  end function sample_bytes

  !> This rank's contacts: the unique keys of its samples with each contact's identities,
  !> sorted by key, packed as [key, ia, ib, ob] per contact [4, n].
  subroutine local_contacts(samples, pack4)
    type(snap_sample_t), intent(in) :: samples(:)
    integer(i8), allocatable, intent(out) :: pack4(:,:)
    integer(i8), allocatable :: keys(:)
    integer, allocatable :: ids(:,:)
    integer :: n, j, m
    n = 0
    do j = 1, size(samples)
      n = n + size(samples(j)%key)
    end do
    allocate(keys(n), ids(3, n))
    ! each sample's keys made unique first (a contact lasts many steps): the sorts stay small
    n = 0
    do j = 1, size(samples)
      associate (s => samples(j))
        m = size(s%key)
        keys(n + 1:n + m) = s%key
        ids(1, n + 1:n + m) = s%ia; ids(2, n + 1:n + m) = s%ib; ids(3, n + 1:n + m) = s%ob
        call unique_contacts(keys(n + 1:n + m), ids(:, n + 1:n + m), m)
        n = n + m
      end associate
    end do
    call unique_contacts(keys, ids, n)
    allocate(pack4(4, n))
    pack4(1, :) = keys(1:n)
    pack4(2:4, :) = int(ids(:, 1:n), i8)
  end subroutine local_contacts

  !> Sort keys(1:n) ascending (ids [3, n] along), drop duplicates; n becomes the number of
  !> unique keys.
  subroutine unique_contacts(keys, ids, n)
    integer(i8), intent(inout) :: keys(:)
    integer, intent(inout) :: ids(:,:)
    integer, intent(inout) :: n
    integer, allocatable :: idx(:)
    integer :: a, u
    allocate(idx(n))
    call argsort_i8(keys(1:n), idx)
    keys(1:n) = keys(idx)
    ids(:, 1:n) = ids(:, idx)
    u = 0
    do a = 1, n
      if (u > 0) then
        if (keys(a) == keys(u)) cycle
      end if
      u = u + 1
      keys(u) = keys(a); ids(:, u) = ids(:, a)
    end do
    n = u
  end subroutine unique_contacts

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
      error%code = EXIT_BAD_INPUT; return
    end if
    call header_of(h5, path, hdr, error)
    call h5%close(e2)
    if (allocated(error)) then
      if (index(error%message, where) /= 1) error%message = where // ": " // error%message
      error%code = EXIT_BAD_INPUT
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
    integer(i8), allocatable :: d(:)
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
    call h5%get_dims("scene/obstacle_kind", d, error); if (allocated(error)) return
    call need_range(path, "contacts/ob", hdr%dict_ob, 0, int(product(d)), error); if (allocated(error)) return
    call pairing(error); if (allocated(error)) return
    call check_digest(h5, "initial_positions", digest_of(hdr%q0, 0_i8), "'" // path // "'", error)
    if (allocated(error)) return
    call check_digest(h5, "contacts/ia", digest_of(hdr%dict_ia, 0_i8), "'" // path // "'", error)
    if (allocated(error)) return
    call check_digest(h5, "contacts/ib", digest_of(hdr%dict_ib, 0_i8), "'" // path // "'", error)
    if (allocated(error)) return
    call check_digest(h5, "contacts/ob", digest_of(hdr%dict_ob, 0_i8), "'" // path // "'", error)

  contains

    !> Each contact of the dictionary is an agent pair (ib > 0, not ia, ob = 0) or an
    !> agent-obstacle contact (ib = 0, ob > 0).
    subroutine pairing(error)
      type(error_t), allocatable, intent(out) :: error
      integer :: k
      do k = 1, hdr%n_dict
        if (hdr%dict_ib(k) == hdr%dict_ia(k) .or. (hdr%dict_ob(k) > 0 .neqv. hdr%dict_ib(k) == 0)) then
          call product_error(path, "datasets 'contacts/ib' and 'contacts/ob': contact " // str(k) // " (ia, ib, ob = " // &
            str(hdr%dict_ia(k)) // ", " // str(hdr%dict_ib(k)) // ", " // str(hdr%dict_ob(k)) // ") is neither " // &
            "an agent pair nor an agent-obstacle contact", error); return
        end if
      end do
    end subroutine pairing
  end subroutine header_of

  !> Read samples k0..k0+nloc-1 of set `name` ('train' or 'valid') and validate them. With env
  !> the file is opened in parallel and every rank of env calls with its own block (nloc may be
  !> 0). desired / multipliers: also read the desired velocities / the multipliers. Steps: the
  !> request (block_request), the shapes and the block table (block_shapes), the collective
  !> reads (block_read), this rank's checks (block_checks), agreed over the ranks, then the
  !> whole-dataset checksums of version 1 (block_verify).
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
    type(block_read_t) :: rc
    rc%name = name; rc%k0 = k0; rc%nloc = nloc; rc%desired = desired; rc%multipliers = multipliers
    call block_request(hdr, rc, present(env), error)
    if (allocated(error)) return
    call h5%open(rc%path, error, env=env)
    if (allocated(error)) return
    blk%name = name; blk%n = rc%n; blk%k0 = k0; blk%nloc = nloc
    call block_shapes(h5, hdr, rc, error); if (allocated(error)) goto 9
    call block_read(h5, hdr, rc, blk, error); if (allocated(error)) goto 9
    call block_checks(hdr, rc, blk, error)
    ! every rank returns the lowest failing rank's message (the block checksums are checked by
    ! each rank on its own samples)
    if (present(env)) call env%agree_error(error)
    if (allocated(error)) goto 9
    ! version 1 checksums: in parallel every rank's block is a part of the whole; serially only a
    ! whole set (version 2: each block against its samples' block digests, in block_checks)
    if (rc%blocks) then
      continue
    else if (present(env) .and. rc%n > 0) then
      call block_verify(h5, hdr, rc, blk, .true., error, env); if (allocated(error)) goto 9
    else if (k0 == 1 .and. nloc == rc%n .and. rc%n > 0) then
      call block_verify(h5, hdr, rc, blk, .false., error); if (allocated(error)) goto 9
    end if
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= EXIT_BAD_INPUT) call prefix_error(error, "database '" // rc%path // "', set " // name)
      error%code = EXIT_BAD_INPUT
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_snap_block

  !> The request of read_snap_block checked: the samples exist, and a part of a set read
  !> serially can be verified (version 1 has only whole-dataset checksums).
  subroutine block_request(hdr, rc, parallel, error)
    type(snap_header_t), intent(in) :: hdr
    type(block_read_t), intent(inout) :: rc
    logical, intent(in) :: parallel
    type(error_t), allocatable, intent(out) :: error
    rc%path = hdr%path
    rc%nt = hdr%n_steps; rc%nd = hdr%n_dof
    rc%n = merge(hdr%n_train, hdr%n_valid, rc%name == 'train')
    rc%g = rc%name // "/"
    associate (k0 => rc%k0, nloc => rc%nloc, n => rc%n, path => rc%path, name => rc%name)
    if (k0 < 1 .or. nloc < 0 .or. k0 - 1 + nloc > n) then
      call set_error(error, "'" // path // "': samples " // str(k0) // ".." // str(k0 + nloc - 1) // " of set " // &
        name // " requested, the set has " // str(n)); return
    end if
    rc%blocks = hdr%version >= 2 .and. n > 0
    if (.not. rc%blocks .and. .not. parallel .and. n > 0 .and. (k0 /= 1 .or. nloc /= n)) then
      call set_error(error, "'" // path // "': snapshot database schema version " // str(hdr%version) // &
        " has no per-sample checksums: samples " // str(k0) // ".." // str(k0 + nloc - 1) // " of the " // &
        str(n) // " of set " // name // " cannot be verified (read the whole set, or rerun crowd_snapshots " // &
        "to write version " // str(SNAP_SCHEMA_VERSION) // ")", EXIT_BAD_INPUT); return
    end if
    end associate
  end subroutine block_request

  !> The shapes of the set's datasets against the root attributes (before anything is
  !> allocated from them); version 2: the set's block table (whole: it is small, 34 integers
  !> per sample), checked against its own checksum and shape, this block's columns kept.
  subroutine block_shapes(h5, hdr, rc, error)
    type(h5file_t), intent(inout) :: h5
    type(snap_header_t), intent(in) :: hdr
    type(block_read_t), intent(inout) :: rc
    type(error_t), allocatable, intent(out) :: error
    integer(i8), allocatable :: d(:)
    integer, allocatable :: all(:,:)
    integer(i8) :: ns8, nt8
    associate (path => rc%path, g => rc%g, name => rc%name, nd => rc%nd)
    ns8 = rc%n; nt8 = rc%nt
    call need_dims(h5, path, g // "params", [int(hdr%n_params, i8), ns8], "n_params x n_" // name, error)
    if (allocated(error)) return
    call need_dims(h5, path, g // "positions", [int(nd, i8), (nt8 + 1) * ns8], "2 n_agents x (n_steps + 1) n_" // &
      name, error); if (allocated(error)) return
    call need_dims(h5, path, g // "velocities", [int(nd, i8), nt8 * ns8], "2 n_agents x n_steps n_" // name, error)
    if (allocated(error)) return
    if (rc%desired) then
      call need_dims(h5, path, g // "desired", [int(nd, i8), nt8 * ns8], "2 n_agents x n_steps n_" // name, error)
      if (allocated(error)) return
    end if
    if (rc%multipliers) then
      call need_dims(h5, path, g // "lambda_offset", [nt8 * ns8 + 1], "n_steps n_" // name // " + 1", error)
      if (allocated(error)) return
      call h5%get_dims(g // "lambda_index", d, error); if (allocated(error)) return
      rc%nnz_all = d(1)
      call need_dims(h5, path, g // "lambda_value", [rc%nnz_all], "lambda_index", error); if (allocated(error)) return
    end if
    if (rc%blocks) then
      call need_dims(h5, path, g // SAMPLE_CHECKSUMS, [34_i8, ns8], "34 x n_" // name, error)
      if (allocated(error)) return
      call h5%read(g // SAMPLE_CHECKSUMS, all, error); if (allocated(error)) return
      call check_digest(h5, g // SAMPLE_CHECKSUMS, digest_of(all, 0_i8), "'" // path // "'", error)
      if (allocated(error)) return
      rc%tab = all(:, rc%k0:rc%k0 + rc%nloc - 1)
    end if
    end associate
  end subroutine block_shapes

  !> The collective reads (every rank makes the same calls, whatever its block holds); the
  !> multiplier offsets checked as they come (a fault kept in rc%bad, reported by block_checks).
  subroutine block_read(h5, hdr, rc, blk, error)
    type(h5file_t), intent(inout) :: h5
    type(snap_header_t), intent(in) :: hdr
    type(block_read_t), intent(inout) :: rc
    type(snap_block_t), intent(inout) :: blk
    type(error_t), allocatable, intent(out) :: error
    integer :: c
    associate (g => rc%g, nd => rc%nd, nt => rc%nt, k0 => rc%k0, nloc => rc%nloc)
    allocate(blk%mu(hdr%n_params, nloc), blk%q(nd, (nt + 1) * nloc), blk%u(nd, nt * nloc))
    call h5%read_block(g // "params", blk%mu, k0 - 1, error); if (allocated(error)) return
    call h5%read_block(g // "positions", blk%q, (k0 - 1) * (nt + 1), error); if (allocated(error)) return
    call h5%read_block(g // "velocities", blk%u, (k0 - 1) * nt, error); if (allocated(error)) return
    if (rc%desired) then
      allocate(blk%v(nd, nt * nloc))
      call h5%read_block(g // "desired", blk%v, (k0 - 1) * nt, error); if (allocated(error)) return
    end if
    rc%bad = ""
    if (rc%multipliers) then
      allocate(rc%off(nt * nloc + 1))
      call h5%read_block(g // "lambda_offset", rc%off, (k0 - 1) * nt, error); if (allocated(error)) return
      if (k0 == 1 .and. rc%off(1) /= 0) rc%bad = "first offset " // str(rc%off(1)) // ", expected 0"
      do c = 1, nt * nloc
        if (len(rc%bad) > 0) exit
        if (rc%off(c + 1) < rc%off(c)) rc%bad = "offsets decrease at column " // str(int((k0 - 1) * int(nt, i8) + c))
      end do
      if (len(rc%bad) == 0 .and. (rc%off(1) < 0 .or. rc%off(nt * nloc + 1) > rc%nnz_all)) &
        rc%bad = "offsets " // str(rc%off(1)) // ".." // str(rc%off(nt * nloc + 1)) // " outside 0.." // &
        str(rc%nnz_all) // " (size of lambda_index)"
      rc%base = 0
      if (len(rc%bad) == 0) then
        rc%base = rc%off(1)
        blk%lam_ptr = rc%off - rc%base
      else
        allocate(blk%lam_ptr(1)); blk%lam_ptr = 0
      end if
      allocate(blk%lam_idx(int(blk%lam_ptr(size(blk%lam_ptr)))), blk%lam_val(int(blk%lam_ptr(size(blk%lam_ptr)))))
      call h5%read_block(g // "lambda_index", blk%lam_idx, int(rc%base), error); if (allocated(error)) return
      call h5%read_block(g // "lambda_value", blk%lam_val, int(rc%base), error); if (allocated(error)) return
    end if
    end associate
  end subroutine block_read

  !> This rank's checks of its block (made collective by the caller before the collective
  !> checksums): the offsets, finite values, indices in range, and (version 2) the digest of
  !> each dataset read against the sum of its samples' block digests (no collective: every rank
  !> checks its own samples). DS order: 1 params, 2 positions, 3 velocities, 4 desired,
  !> 5 lambda_offset, 6 lambda_index, 7 lambda_value.
  subroutine block_checks(hdr, rc, blk, error)
    type(snap_header_t), intent(in) :: hdr
    type(block_read_t), intent(in) :: rc
    type(snap_block_t), intent(in) :: blk
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: w
    type(digest_t) :: d
    integer(i8) :: o
    associate (path => rc%path, g => rc%g, tab => rc%tab, nt => rc%nt, nd => rc%nd)
    if (len(rc%bad) > 0) then
      call product_error(path, "dataset '" // g // "lambda_offset': " // rc%bad, error); return
    end if
    call need_finite(path, g // "params", blk%mu, error); if (allocated(error)) return
    call need_finite(path, g // "positions", blk%q, error); if (allocated(error)) return
    call need_finite(path, g // "velocities", blk%u, error); if (allocated(error)) return
    if (rc%desired) then
      call need_finite(path, g // "desired", blk%v, error); if (allocated(error)) return
    end if
    if (rc%multipliers) then
      call need_range(path, g // "lambda_index", blk%lam_idx, 1, hdr%n_dict, error); if (allocated(error)) return
      call need_finite(path, g // "lambda_value", blk%lam_val, error); if (allocated(error)) return
    end if
    if (.not. (rc%blocks .and. rc%nloc > 0)) return
    w = "'" // path // "'"
    o = int(rc%k0 - 1, i8)
    call check_digest_blocks(tab, 1, g // "params", digest_of(blk%mu, o * hdr%n_params), w, error)
    if (allocated(error)) return
    call check_digest_blocks(tab, 2, g // "positions", digest_of(blk%q, o * (nt + 1) * nd), w, error)
    if (allocated(error)) return
    call check_digest_blocks(tab, 3, g // "velocities", digest_of(blk%u, o * nt * nd), w, error)
    if (allocated(error)) return
    if (rc%desired) then
      call check_digest_blocks(tab, 4, g // "desired", digest_of(blk%v, o * nt * nd), w, error)
      if (allocated(error)) return
    end if
    if (.not. rc%multipliers) return
    ! a sample's offsets block: the ends of its steps (and the leading 0 for the first sample)
    d = digest_of(rc%off(2:), o * nt + 1)
    if (rc%k0 == 1) d = digest_add(d, digest_of(rc%off(1:1), 0_i8))
    call check_digest_blocks(tab, 5, g // "lambda_offset", d, w, error); if (allocated(error)) return
    call check_digest_blocks(tab, 6, g // "lambda_index", digest_of(blk%lam_idx, rc%base), w, error)
    if (allocated(error)) return
    call check_digest_blocks(tab, 7, g // "lambda_value", digest_of(blk%lam_val, rc%base), w, error)
    end associate
  end subroutine block_checks

  !> Version 1: the checksums of the datasets read (parts: this rank's block is one part of
  !> the whole, compared collectively over env; else the whole set).
  subroutine block_verify(h5, hdr, rc, blk, parts, error, env)
    type(h5file_t), intent(inout) :: h5
    type(snap_header_t), intent(in) :: hdr
    type(block_read_t), intent(in) :: rc
    type(snap_block_t), intent(in) :: blk
    logical, intent(in) :: parts
    type(error_t), allocatable, intent(out) :: error
    type(env_t), intent(in), optional :: env
    type(digest_t) :: d
    integer(i8) :: o
    associate (g => rc%g, nt => rc%nt, nd => rc%nd, nloc => rc%nloc, off => rc%off)
    o = int(rc%k0 - 1, i8)
    call one(g // "params", digest_of(blk%mu, o * hdr%n_params), error); if (allocated(error)) return
    call one(g // "positions", digest_of(blk%q, o * (nt + 1) * nd), error); if (allocated(error)) return
    call one(g // "velocities", digest_of(blk%u, o * nt * nd), error); if (allocated(error)) return
    if (rc%desired) then
      call one(g // "desired", digest_of(blk%v, o * nt * nd), error); if (allocated(error)) return
    end if
    if (rc%multipliers) then
      d = digest_of(off(1:nt * nloc), o * nt)
      if (nloc > 0 .and. rc%k0 - 1 + nloc == rc%n) d = digest_add(d, digest_of(off(nt * nloc + 1:), int(nt, i8) * rc%n))
      call one(g // "lambda_offset", d, error); if (allocated(error)) return
      call one(g // "lambda_index", digest_of(blk%lam_idx, rc%base), error); if (allocated(error)) return
      call one(g // "lambda_value", digest_of(blk%lam_val, rc%base), error); if (allocated(error)) return
    end if
    end associate

  contains

    subroutine one(name, d, error)
      character(len=*), intent(in) :: name
      type(digest_t), intent(in) :: d
      type(error_t), allocatable, intent(out) :: error
      if (parts) then
        call check_digest_parts(h5, env, name, d, "'" // rc%path // "'", error)
      else
        call check_digest(h5, name, d, "'" // rc%path // "'", error)
      end if
    end subroutine one
  end subroutine block_verify
end module cr_snapshot_file
