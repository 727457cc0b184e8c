!> Assembly of the snapshot database of a parameter study (schema, metadata type and the
!> validating readers: src/products/cr_snapshot_file; layout in the README, "Snapshot database").
!>
!> assemble_database gathers the per-sample pieces (cr_snapshot_piece) into one file with
!> parallel HDF5: the samples of each set are split into contiguous blocks over the ranks
!> (block_range), each rank reads the pieces of its block and writes its columns with
!> collective hyperslab writes. The global contact dictionary is the sorted union of the keys
!> of every stored multiplier, merged across ranks. The file is written under a temporary
!> name, gets `complete = 1` last, and is renamed only then.
module cr_snapshot_db
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_sort, only: argsort_i8, bsearch_i8
  use cr_fom, only: fom_t
  use cr_fom_file, only: write_scene
  use cr_config, only: config_t
  use cr_scene, only: scene_t
  use cr_sampling, only: param_space_t
  use cr_snapshot_file, only: SNAP_SCHEMA, SNAP_SCHEMA_VERSION, SNAP_UNITS, db_meta_t
  use cr_h5file, only: h5file_t, cr_h5_real, cr_h5_int, cr_h5_int64
  use cr_snapshot_piece, only: sample_result_t, read_piece, check_sample
  use cr_sampling, only: sample_set_t
  use cr_piece_store, only: piece_index_t, global_sample, set_of_sample
  use cr_digest, only: digest_t, digest_of, digest_of_ranges, digest_add, digest_allreduce, put_digest, &
    DIGEST_ALGORITHM
  use cr_fsys, only: rename_file, remove_file
  implicit none
  private
  public :: db_totals_t, probe_database, assemble_database, block_range, collective_error

  !> Totals over the whole database (every rank receives them).
  type :: db_totals_t
    integer :: n_dict = 0, nonconverged_steps = 0, nonconverged_samples = 0
    integer(i8) :: nnz = 0
    real(wp) :: kkt_max = 0, time_sum = 0, time_max = 0
    !> wall time of the assembly's phases on rank 0 (s): reading and checking this rank's pieces,
    !> contact dictionary, parallel data writes (create, write, close), serial header/checksums
    real(wp) :: t_read = 0, t_dict = 0, t_write = 0, t_seal = 0
    !> bytes of piece data read by all ranks
    real(wp) :: bytes_read = 0
  end type db_totals_t

  !> The samples of one set held by this rank (a contiguous block).
  type :: set_block_t
    character(len=8) :: name = ''
    integer :: n = 0, nloc = 0
    !> indices in the set of this rank's samples, increasing [nloc]
    integer, allocatable :: k(:)
    type(sample_result_t), allocatable :: s(:)
  end type set_block_t

contains

  !> Contiguous block of n items for rank r of p: items k0..k0+nloc-1 (nloc may be 0).
  pure subroutine block_range(n, p, r, k0, nloc)
    integer, intent(in) :: n, p, r
    integer, intent(out) :: k0, nloc
    k0 = int(int(r, i8) * n / p) + 1
    nloc = int(int(r + 1, i8) * n / p) - k0 + 1
  end subroutine block_range

  !> Serial check of an existing database: status 0 = no file, 1 = complete database of this
  !> configuration, 2 = anything else (message says why; it must not be overwritten).
  subroutine probe_database(path, hash, status, message)
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
  end subroutine probe_database

  !> Collective: assemble every piece in `pieces_dir` into the database `path`.
  subroutine assemble_database(env, path, pieces, meta, fom_ref, cfg, space, q0, samples, totals, error)
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: path
    !> where each sample is stored (every sample must be)
    type(piece_index_t), intent(in) :: pieces
    type(db_meta_t), intent(in) :: meta
    !> the reference model (for the scene group)
    type(fom_t), intent(in) :: fom_ref
    !> the reference configuration and the parameter space (each sample's mapped scene)
    type(config_t), intent(in) :: cfg
    type(param_space_t), intent(in) :: space
    !> common initial positions [2*n_agents]
    real(wp), intent(in), contiguous :: q0(:)
    !> the study's samples (train, valid): each piece's samples are checked against them
    type(sample_set_t), intent(in) :: samples(2)
    type(db_totals_t), intent(out) :: totals
    type(error_t), allocatable, intent(out) :: error
    type(set_block_t) :: sets(2)
    integer(i8), allocatable :: dkey(:)
    integer, allocatable :: dia(:), dib(:), dob(:)
    type(h5file_t) :: h5
    character(len=:), allocatable :: msg
    type(sample_result_t), allocatable :: res(:)
    logical, allocatable :: mine(:)
    !> digests of the datasets written, stored when the parallel file is closed
    character(len=64), allocatable :: dnames(:)
    type(digest_t), allocatable :: dvals(:)
    integer :: nd_noted
    logical :: closed
    real(wp) :: tph
    integer :: is, k, ierr, bad, n_train, n_valid, g, p, j, c, k0
    n_train = samples(1)%n; n_valid = samples(2)%n
    sets(1)%name = samples(1)%name; sets(1)%n = n_train
    sets(2)%name = samples(2)%name; sets(2)%n = n_valid
    ! 1. this rank's samples: those of the pieces it owns (the pieces it wrote, or was given
    !    among those of earlier runs); checksums, finiteness and identity verified again
    tph = MPI_Wtime()
    msg = ""
    nd_noted = 0
    closed = .false.
    allocate(dnames(64), dvals(64))
    allocate(mine(pieces%n_tot))
    mine = .false.
    do g = 1, pieces%n_tot
      p = pieces%piece_of(g)
      if (p == 0) then
        if (env%is_root()) msg = "sample " // str(g) // " of the study is in no piece"
      else
        mine(g) = pieces%owner(p) == env%rank
      end if
    end do
    do is = 1, 2
      k0 = 0
      if (is == 2) k0 = n_train
      sets(is)%k = pack([(k, k = 1, sets(is)%n)], mine(k0 + 1:k0 + sets(is)%n))
      sets(is)%nloc = size(sets(is)%k)
      allocate(sets(is)%s(sets(is)%nloc))
    end do
    do p = 1, pieces%n_pieces
      if (len(msg) > 0) exit
      if (pieces%owner(p) /= env%rank) cycle
      call read_piece(pieces%path_of(p), res, error)
      if (.not. allocated(error)) then
        do j = 1, size(res)
          g = global_sample(samples, res(j)%set, res(j)%index)
          if (g == 0) then
            call set_error(error, "piece '" // pieces%path_of(p) // "' holds " // trim(res(j)%set) // &
              " sample " // str(res(j)%index) // ", which this study does not have")
          else if (pieces%piece_of(g) /= p .or. pieces%slot_of(g) /= j) then
            call set_error(error, "piece '" // pieces%path_of(p) // "': sample " // str(j) // &
              " is not the one recorded for it")
          else
            call set_of_sample(samples, g, is, k)
            call check_sample(res(j), sets(is)%name, k, samples(is)%mu(:, k), 2 * meta%n_agents, meta%n_steps, &
              "piece '" // pieces%path_of(p) // "'", error)
          end if
          if (allocated(error)) exit
          ! position of k among this rank's samples of the set
          c = findloc(sets(is)%k, k, dim=1)
          call move_sample(res(j), sets(is)%s(c))
        end do
      end if
      if (allocated(error)) then
        msg = error%message // " (run again with --quarantine-bad-pieces to move it aside and recompute it)"
        deallocate(error)
      end if
    end do
    call collective_error(env, msg, error)
    if (allocated(error)) return
    do is = 1, 2
      do k = 1, sets(is)%nloc
        totals%bytes_read = totals%bytes_read + 8.0_wp * (size(sets(is)%s(k)%q) + size(sets(is)%s(k)%u) + &
          size(sets(is)%s(k)%v) + 2 * size(sets(is)%s(k)%value))
      end do
    end do
    totals%bytes_read = env%sum_real(totals%bytes_read)
    totals%t_read = MPI_Wtime() - tph
    ! 2. the global contact dictionary
    call build_dictionary(env, sets, dkey, dia, dib, dob)
    totals%n_dict = size(dkey)
    totals%t_dict = MPI_Wtime() - tph - totals%t_read
    ! 3. the file
    call h5%create(path, error, env=env)
    if (allocated(error)) return
    ops: block
      do is = 1, 2
        call write_set(sets(is), error); if (allocated(error)) exit ops
      end do
      ! parallel metadata writes cost a collective each: the header, the attributes, the
      ! checksums and complete = 1 (last) are added by rank 0 alone, serially, before the rename
      closed = .true.
      call h5%close(error); if (allocated(error)) exit ops
      call digest_allreduce(env, dvals(1:nd_noted))
      totals%t_write = MPI_Wtime() - tph - totals%t_read - totals%t_dict
      call seal_file(error)
      totals%t_seal = MPI_Wtime() - tph - totals%t_read - totals%t_dict - totals%t_write
    end block ops
    if (allocated(error) .and. closed) then
      call MPI_Barrier(env%comm, ierr)
      if (env%is_root()) ierr = remove_file(path // ".partial")
      call prefix_error(error, "database '" // path // "'")
      return
    else if (allocated(error)) then
      call h5%abort()
      call prefix_error(error, "database '" // path // "'")
      return
    end if
    ! totals
    bad = 0
    do is = 1, 2
      do k = 1, sets(is)%nloc
        associate (s => sets(is)%s(k))
          totals%nonconverged_steps = totals%nonconverged_steps + count(s%converged == 0)
          if (any(s%converged == 0)) bad = bad + 1
          if (size(s%kkt) > 0) totals%kkt_max = max(totals%kkt_max, maxval(s%kkt))
          totals%time_sum = totals%time_sum + s%time
          totals%time_max = max(totals%time_max, s%time)
          totals%nnz = totals%nnz + size(s%value)
        end associate
      end do
    end do
    totals%nonconverged_samples = bad
    call MPI_Allreduce(MPI_IN_PLACE, totals%nonconverged_steps, 1, MPI_INTEGER, MPI_SUM, env%comm, ierr)
    call MPI_Allreduce(MPI_IN_PLACE, totals%nonconverged_samples, 1, MPI_INTEGER, MPI_SUM, env%comm, ierr)
    call MPI_Allreduce(MPI_IN_PLACE, totals%nnz, 1, MPI_INTEGER8, MPI_SUM, env%comm, ierr)
    totals%kkt_max = env%max_real(totals%kkt_max)
    totals%time_max = env%max_real(totals%time_max)
    totals%time_sum = env%sum_real(totals%time_sum)

  contains

    !> Remember the digest of a dataset (every rank holds the same list).
    subroutine note(name, d)
      character(len=*), intent(in) :: name
      type(digest_t), intent(in) :: d
      character(len=64), allocatable :: n2(:)
      type(digest_t), allocatable :: v2(:)
      if (nd_noted == size(dnames)) then
        allocate(n2(2 * nd_noted), v2(2 * nd_noted))
        n2(1:nd_noted) = dnames; v2(1:nd_noted) = dvals
        call move_alloc(n2, dnames); call move_alloc(v2, dvals)
      end if
      nd_noted = nd_noted + 1
      dnames(nd_noted) = name
      dvals(nd_noted) = d
    end subroutine note

    !> Collective: rank 0 writes the checksums and complete = 1 into the closed temporary file
    !> (serial HDF5) and renames it; every rank gets the status.
    subroutine seal_file(error)
      type(error_t), allocatable, intent(out) :: error
      type(h5file_t) :: hs
      character(len=:), allocatable :: m
      integer :: q, ie
      m = ""
      if (env%is_root()) then
        call hs%open(path // ".partial", error, readwrite=.true.)
        if (.not. allocated(error)) call write_header(hs, error)
        if (.not. allocated(error)) call hs%write_attr(trim(sets(1)%name), "n_samples", sets(1)%n, error)
        if (.not. allocated(error)) call hs%write_attr(trim(sets(2)%name), "n_samples", sets(2)%n, error)
        do q = 1, nd_noted
          if (allocated(error)) exit
          call put_digest(hs, trim(dnames(q)), dvals(q), error)
        end do
        if (.not. allocated(error)) call hs%write_attr("/", "complete", 1, error)
        if (allocated(error)) then
          m = error%message; deallocate(error)
          call hs%close(error)
          if (allocated(error)) deallocate(error)
        else
          call hs%close(error)
          if (allocated(error)) then
            m = error%message; deallocate(error)
          else if (rename_file(path // ".partial", path) /= 0) then
            m = "rename '" // path // ".partial' -> '" // path // "' failed"
          end if
        end if
      end if
      call env%bcast_string(m)
      call MPI_Barrier(env%comm, ie)
      if (len(m) > 0) call set_error(error, m)
    end subroutine seal_file

    !> Root attributes, initial positions, scene and contact dictionary (serial, rank 0).
    subroutine write_header(hh, error)
      type(h5file_t), intent(inout) :: hh
      type(error_t), allocatable, intent(out) :: error
      call hh%write_attr("/", "schema", SNAP_SCHEMA, error); if (allocated(error)) return
      call hh%write_attr("/", "schema_version", SNAP_SCHEMA_VERSION, error); if (allocated(error)) return
      call hh%write_attr("/", "program", "crowd_snapshots", error); if (allocated(error)) return
      call hh%write_attr("/", "version", meta%version, error); if (allocated(error)) return
      call hh%write_attr("/", "hdf5_version", meta%hdf5_version, error); if (allocated(error)) return
      call hh%write_attr("/", "mpi_version", meta%mpi_version, error); if (allocated(error)) return
      call hh%write_attr("/", "compiler", meta%compiler, error); if (allocated(error)) return
      call hh%write_attr("/", "config", meta%config_text, error); if (allocated(error)) return
      call hh%write_attr("/", "input_text", meta%input_text, error); if (allocated(error)) return
      call hh%write_attr("/", "config_hash", trim(meta%hash), error); if (allocated(error)) return
      call hh%write_attr("/", "units", SNAP_UNITS, error); if (allocated(error)) return
      call hh%write_attr("/", "n_agents", meta%n_agents, error); if (allocated(error)) return
      call hh%write_attr("/", "agent_radius", meta%radius, error); if (allocated(error)) return
      call hh%write_attr("/", "dt", meta%dt, error); if (allocated(error)) return
      call hh%write_attr("/", "n_steps", meta%n_steps, error); if (allocated(error)) return
      call hh%write_attr("/", "n_train", n_train, error); if (allocated(error)) return
      call hh%write_attr("/", "n_valid", n_valid, error); if (allocated(error)) return
      call hh%write_attr("/", "n_params", meta%n_expanded, error); if (allocated(error)) return
      call hh%write_attr("/", "param_names", meta%param_names, error); if (allocated(error)) return
      call hh%write_attr("/", "checksum_algorithm", DIGEST_ALGORITHM, error); if (allocated(error)) return
      call hh%write("initial_positions", q0, error); if (allocated(error)) return
      call note("initial_positions", digest_of(q0, 0_i8)); if (allocated(error)) return
      call write_scene(hh, fom_ref%scene, error); if (allocated(error)) return
      call hh%make_group("contacts", error); if (allocated(error)) return
      call hh%write("contacts/key", dkey, error); if (allocated(error)) return
      call note("contacts/key", digest_of(dkey, 0_i8)); if (allocated(error)) return
      call hh%write("contacts/ia", dia, error); if (allocated(error)) return
      call note("contacts/ia", digest_of(dia, 0_i8)); if (allocated(error)) return
      call hh%write("contacts/ib", dib, error); if (allocated(error)) return
      call note("contacts/ib", digest_of(dib, 0_i8)); if (allocated(error)) return
      call hh%write("contacts/ob", dob, error); if (allocated(error)) return
      call note("contacts/ob", digest_of(dob, 0_i8)); if (allocated(error)) return
      call hh%write_attr("contacts", "description", "global contact dictionary: every contact " // &
        "with lambda > 0 in some sample and step, sorted by key; ib = 0 for agent-obstacle " // &
        "contacts (ob = obstacle index), ob = 0 for agent pairs", error)
    end subroutine write_header

    !> Collective: set b; each rank writes the columns of its own samples (any subset of the
    !> set: runs of consecutive samples become one hyperslab each).
    subroutine write_set(b, error)
      type(set_block_t), intent(in) :: b
      type(error_t), allocatable, intent(out) :: error
      character(len=:), allocatable :: g
      real(wp), allocatable :: rbuf(:,:), r1(:)
      integer, allocatable :: ibuf(:,:), i1(:), rg(:,:)
      integer(i8), allocatable :: nnz(:), base(:), off(:)
      integer(i8) :: total
      integer :: nd, ns, ne, k, j, c0, n0, ierr
      type(digest_t) :: d
      g = trim(b%name)
      nd = 2 * meta%n_agents; ns = meta%n_steps; ne = meta%n_expanded
      call h5%make_group(g, error); if (allocated(error)) return
      call h5%make_group(g // "/stats", error); if (allocated(error)) return
      ! parameters [ne, n]
      allocate(rbuf(ne, b%nloc))
      d = digest_t()
      do j = 1, b%nloc
        rbuf(:, j) = b%s(j)%mu
        d = digest_add(d, digest_of(rbuf(:, j), int(b%k(j) - 1, i8) * ne))
      end do
      call h5%create_dataset(g // "/params", [ne, b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/params", rbuf, runs(b, 1), error); if (allocated(error)) return
      call seal(g // "/params", d, error); if (allocated(error)) return
      deallocate(rbuf)
      ! positions [nd, (ns + 1) n]
      allocate(rbuf(nd, (ns + 1) * b%nloc))
      d = digest_t()
      do j = 1, b%nloc
        rbuf(:, (j - 1) * (ns + 1) + 1:j * (ns + 1)) = b%s(j)%q
        d = digest_add(d, digest_of(b%s(j)%q, int(b%k(j) - 1, i8) * (ns + 1) * nd))
      end do
      call h5%create_dataset(g // "/positions", [nd, (ns + 1) * b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/positions", rbuf, runs(b, ns + 1), error); if (allocated(error)) return
      call seal(g // "/positions", d, error); if (allocated(error)) return
      deallocate(rbuf)
      ! velocities and desired velocities [nd, ns n]
      allocate(rbuf(nd, ns * b%nloc))
      d = digest_t()
      do j = 1, b%nloc
        rbuf(:, (j - 1) * ns + 1:j * ns) = b%s(j)%u
        d = digest_add(d, digest_of(b%s(j)%u, int(b%k(j) - 1, i8) * ns * nd))
      end do
      call h5%create_dataset(g // "/velocities", [nd, ns * b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/velocities", rbuf, runs(b, ns), error); if (allocated(error)) return
      call seal(g // "/velocities", d, error); if (allocated(error)) return
      d = digest_t()
      do j = 1, b%nloc
        rbuf(:, (j - 1) * ns + 1:j * ns) = b%s(j)%v
        d = digest_add(d, digest_of(b%s(j)%v, int(b%k(j) - 1, i8) * ns * nd))
      end do
      call h5%create_dataset(g // "/desired", [nd, ns * b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/desired", rbuf, runs(b, ns), error); if (allocated(error)) return
      call seal(g // "/desired", d, error); if (allocated(error)) return
      deallocate(rbuf)
      ! per-step statistics [ns, n]
      allocate(rbuf(ns, b%nloc), ibuf(ns, b%nloc))
      do j = 1, b%nloc
        rbuf(:, j) = b%s(j)%kkt
      end do
      call stat_real(b, "kkt", rbuf, error); if (allocated(error)) return
      do j = 1, b%nloc
        rbuf(:, j) = b%s(j)%min_gap
      end do
      call stat_real(b, "min_gap", rbuf, error); if (allocated(error)) return
      do j = 1, b%nloc
        ibuf(:, j) = b%s(j)%iterations
      end do
      call stat_int(b, "iterations", ibuf, error); if (allocated(error)) return
      do j = 1, b%nloc
        ibuf(:, j) = b%s(j)%converged
      end do
      call stat_int(b, "converged", ibuf, error); if (allocated(error)) return
      do j = 1, b%nloc
        ibuf(:, j) = b%s(j)%n_active
      end do
      call stat_int(b, "n_active", ibuf, error); if (allocated(error)) return
      ! per-sample time, start and rank [n] (not part of the bitwise comparison)
      allocate(r1(b%nloc), i1(b%nloc))
      do j = 1, b%nloc
        r1(j) = b%s(j)%time; i1(j) = b%s(j)%rank
      end do
      call h5%create_dataset(g // "/stats/time", [b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/stats/time", r1, runs(b, 1), error); if (allocated(error)) return
      call seal(g // "/stats/time", sample_digest_r1(b, r1), error); if (allocated(error)) return
      call h5%create_dataset(g // "/stats/rank", [b%n], cr_h5_int, error); if (allocated(error)) return
      call h5%write_ranges(g // "/stats/rank", i1, runs(b, 1), error); if (allocated(error)) return
      call seal(g // "/stats/rank", sample_digest_i1(b, i1), error); if (allocated(error)) return
      do j = 1, b%nloc
        r1(j) = b%s(j)%start
      end do
      call h5%create_dataset(g // "/stats/start", [b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/stats/start", r1, runs(b, 1), error); if (allocated(error)) return
      call seal(g // "/stats/start", sample_digest_r1(b, r1), error); if (allocated(error)) return
      deallocate(r1, i1)
      ! each sample's scene as the parameter mapping builds it [2 n_v, n], [4, n]
      call write_scenes(b, error); if (allocated(error)) return
      ! sparse multipliers, CSR over the snapshot columns: the global position of each sample's
      ! entries from every sample's count
      allocate(nnz(b%n), base(b%n + 1))
      nnz = 0
      do j = 1, b%nloc
        nnz(b%k(j)) = size(b%s(j)%value)
      end do
      call MPI_Allreduce(MPI_IN_PLACE, nnz, b%n, MPI_INTEGER8, MPI_SUM, env%comm, ierr)
      base(1) = 0
      do k = 1, b%n
        base(k + 1) = base(k) + nnz(k)
      end do
      total = base(b%n + 1)
      if (total > huge(1)) then
        call set_error(error, g // ": " // str(total) // " multipliers exceed the 32-bit block offsets"); return
      end if
      ! lambda_offset [ns n + 1]: entry 1 (= 0) by rank 0, then ns entries per sample
      n0 = merge(1, 0, env%rank == 0)
      allocate(off(n0 + ns * b%nloc))
      d = digest_t()
      if (n0 == 1) then
        off(1) = 0
        d = digest_of(off(1:1), 0_i8)
      end if
      do j = 1, b%nloc
        c0 = n0 + (j - 1) * ns
        off(c0 + 1:c0 + ns) = base(b%k(j)) + b%s(j)%offset(2:ns + 1)
        d = digest_add(d, digest_of(off(c0 + 1:c0 + ns), int(b%k(j) - 1, i8) * ns + 1))
      end do
      rg = runs(b, ns)
      rg(1, :) = rg(1, :) + 1
      if (n0 == 1) rg = reshape([[0, 1], reshape(rg, [size(rg)])], [2, size(rg, 2) + 1])
      call h5%create_dataset(g // "/lambda_offset", [ns * b%n + 1], cr_h5_int64, error); if (allocated(error)) return
      call h5%write_ranges(g // "/lambda_offset", off, rg, error); if (allocated(error)) return
      call seal(g // "/lambda_offset", d, error); if (allocated(error)) return
      ! lambda_index, lambda_value [nnz]: each sample's entries at its base
      allocate(r1(sum(nnz(b%k))), i1(sum(nnz(b%k))))
      deallocate(rg); allocate(rg(2, b%nloc))
      c0 = 0
      do j = 1, b%nloc
        rg(:, j) = [int(base(b%k(j))), int(nnz(b%k(j)))]
        do k = 1, size(b%s(j)%value)
          r1(c0 + k) = b%s(j)%value(k)
          i1(c0 + k) = bsearch_i8(dkey, b%s(j)%key(k))
        end do
        c0 = c0 + size(b%s(j)%value)
      end do
      call h5%create_dataset(g // "/lambda_index", [int(total)], cr_h5_int, error); if (allocated(error)) return
      call h5%write_ranges(g // "/lambda_index", i1, rg, error); if (allocated(error)) return
      call seal(g // "/lambda_index", digest_of_ranges(i1, rg), error); if (allocated(error)) return
      call h5%create_dataset(g // "/lambda_value", [int(total)], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/lambda_value", r1, rg, error); if (allocated(error)) return
      call seal(g // "/lambda_value", digest_of_ranges(r1, rg), error); if (allocated(error)) return
    end subroutine write_set

    !> Ranges (0-based offset, count) of the samples of b on this rank when each takes w entries
    !> of the last dimension; consecutive samples merged [2, n_runs].
    function runs(b, w) result(r)
      type(set_block_t), intent(in) :: b
      integer, intent(in) :: w
      integer, allocatable :: r(:,:)
      integer :: q, m
      allocate(r(2, b%nloc))
      m = 0
      do q = 1, b%nloc
        if (m > 0) then
          if (b%k(q) == b%k(q - 1) + 1) then
            r(2, m) = r(2, m) + w; cycle
          end if
        end if
        m = m + 1
        r(:, m) = [(b%k(q) - 1) * w, w]
      end do
      r = r(:, 1:m)
    end function runs

    !> Collective: per-step statistic `name` of set b from x [n_steps, nloc].
    subroutine stat_real(b, name, x, error)
      type(set_block_t), intent(in) :: b
      character(len=*), intent(in) :: name
      real(wp), intent(in), contiguous :: x(:,:)
      type(error_t), allocatable, intent(out) :: error
      type(digest_t) :: dd
      integer :: q
      character(len=:), allocatable :: ds
      ds = trim(b%name) // "/stats/" // name
      do q = 1, b%nloc
        dd = digest_add(dd, digest_of(x(:, q), int(b%k(q) - 1, i8) * size(x, 1)))
      end do
      call h5%create_dataset(ds, [meta%n_steps, b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(ds, x, runs(b, 1), error); if (allocated(error)) return
      call seal(ds, dd, error)
    end subroutine stat_real

    !> Collective: integer version of stat_real.
    subroutine stat_int(b, name, x, error)
      type(set_block_t), intent(in) :: b
      character(len=*), intent(in) :: name
      integer, intent(in), contiguous :: x(:,:)
      type(error_t), allocatable, intent(out) :: error
      type(digest_t) :: dd
      integer :: q
      character(len=:), allocatable :: ds
      ds = trim(b%name) // "/stats/" // name
      do q = 1, b%nloc
        dd = digest_add(dd, digest_of(x(:, q), int(b%k(q) - 1, i8) * size(x, 1)))
      end do
      call h5%create_dataset(ds, [meta%n_steps, b%n], cr_h5_int, error); if (allocated(error)) return
      call h5%write_ranges(ds, x, runs(b, 1), error); if (allocated(error)) return
      call seal(ds, dd, error)
    end subroutine stat_int

    !> Digest of one value per sample of b [nloc].
    function sample_digest_r1(b, x) result(dd)
      type(set_block_t), intent(in) :: b
      real(wp), intent(in) :: x(:)
      type(digest_t) :: dd
      integer :: q
      do q = 1, b%nloc
        dd = digest_add(dd, digest_of(x(q:q), int(b%k(q) - 1, i8)))
      end do
    end function sample_digest_r1

    function sample_digest_i1(b, x) result(dd)
      type(set_block_t), intent(in) :: b
      integer, intent(in) :: x(:)
      type(digest_t) :: dd
      integer :: q
      do q = 1, b%nloc
        dd = digest_add(dd, digest_of(x(q:q), int(b%k(q) - 1, i8)))
      end do
    end function sample_digest_i1

    !> Collective: `<set>/scene_vertices` [2 n_v, n] and `<set>/scene_exit` [4, n], each sample's
    !> scene mapped from its parameters (cr_param_model), vertices in the layout of /scene.
    subroutine write_scenes(b, error)
      type(set_block_t), intent(in) :: b
      type(error_t), allocatable, intent(out) :: error
      type(scene_t) :: sc
      type(error_t), allocatable :: e3
      real(wp), allocatable :: sv(:,:), se(:,:)
      character(len=:), allocatable :: m, g
      integer :: nv, j
      g = trim(b%name)
      nv = size(scene_vertices(fom_ref%scene))
      allocate(sv(nv, b%nloc), se(4, b%nloc))
      m = ""
      do j = 1, b%nloc
        call space%scene_of(b%s(j)%mu, cfg, sc, e3)
        if (allocated(e3)) then
          m = "scene of " // g // " sample " // str(b%k(j)) // ": " // e3%message; exit
        end if
        if (size(scene_vertices(sc)) /= nv) then
          m = "scene of " // g // " sample " // str(b%k(j)) // " has another vertex layout"; exit
        end if
        sv(:, j) = scene_vertices(sc)
        se(:, j) = [sc%x_lo, sc%width, sc%x_hi, sc%width]
      end do
      call collective_error(env, m, error); if (allocated(error)) return
      call h5%create_dataset(g // "/scene_vertices", [nv, b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/scene_vertices", sv, runs(b, 1), error); if (allocated(error)) return
      call seal(g // "/scene_vertices", sample_digest_r2(b, sv), error); if (allocated(error)) return
      call h5%create_dataset(g // "/scene_exit", [4, b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_ranges(g // "/scene_exit", se, runs(b, 1), error); if (allocated(error)) return
      call seal(g // "/scene_exit", sample_digest_r2(b, se), error)
    end subroutine write_scenes

    !> This rank's part of the digest of [m, n] dataset from its columns x [m, nloc].
    function sample_digest_r2(b, x) result(dd)
      type(set_block_t), intent(in) :: b
      real(wp), intent(in) :: x(:,:)
      type(digest_t) :: dd
      integer :: j
      dd = digest_t()
      do j = 1, b%nloc
        dd = digest_add(dd, digest_of(x(:, j), int(b%k(j) - 1, i8) * size(x, 1)))
      end do
    end function sample_digest_r2

    !> Vertices of every obstacle of a scene, in order [2 * total vertices].
    function scene_vertices(sc) result(v)
      type(scene_t), intent(in) :: sc
      real(wp), allocatable :: v(:)
      integer :: k
      allocate(v(0))
      do k = 1, sc%n_obstacles()
        v = [v, reshape(sc%obstacles(k)%vertices, [size(sc%obstacles(k)%vertices)])]
      end do
    end function scene_vertices

    !> This rank's part of the digest of a dataset, noted for its checksum (the parts are summed
    !> over the ranks in one MPI_Allreduce and written by seal_file; `error` keeps the call
    !> pattern of the writes).
    subroutine seal(name, d, error)
      character(len=*), intent(in) :: name
      type(digest_t), intent(in) :: d
      type(error_t), allocatable, intent(out) :: error
      call note(name, d)
    end subroutine seal
  end subroutine assemble_database

  !> Sorted union over all ranks of the contact keys of this rank's samples (with identities).
  subroutine build_dictionary(env, sets, dkey, dia, dib, dob)
    type(env_t), intent(in) :: env
    type(set_block_t), intent(in) :: sets(:)
    integer(i8), allocatable, intent(out) :: dkey(:)
    integer, allocatable, intent(out) :: dia(:), dib(:), dob(:)
    integer(i8), allocatable :: keys(:), allk(:)
    integer, allocatable :: ids(:,:), allid(:,:), idx(:), counts(:), displs(:), c3(:), d3(:)
    integer :: n, is, k, m, ierr, r
    ! local unique
    n = 0
    do is = 1, size(sets)
      do k = 1, sets(is)%nloc
        n = n + size(sets(is)%s(k)%key)
      end do
    end do
    allocate(keys(n), ids(3, n))
    ! each sample's keys made unique first (a contact lasts many steps): the sorts stay small
    n = 0
    do is = 1, size(sets)
      do k = 1, sets(is)%nloc
        associate (s => sets(is)%s(k))
          m = size(s%key)
          keys(n + 1:n + m) = s%key
          ids(1, n + 1:n + m) = s%ia; ids(2, n + 1:n + m) = s%ib; ids(3, n + 1:n + m) = s%ob
          call unique(keys(n + 1:n + m), ids(:, n + 1:n + m), m)
          n = n + m
        end associate
      end do
    end do
    call unique(keys, ids, n)
    ! gather
    allocate(counts(env%size), displs(env%size), c3(env%size), d3(env%size))
    call MPI_Allgather(n, 1, MPI_INTEGER, counts, 1, MPI_INTEGER, env%comm, ierr)
    displs(1) = 0
    do r = 2, env%size
      displs(r) = displs(r - 1) + counts(r - 1)
    end do
    m = sum(counts)
    allocate(allk(m), allid(3, m))
    call MPI_Allgatherv(keys, n, MPI_INTEGER8, allk, counts, displs, MPI_INTEGER8, env%comm, ierr)
    c3 = 3 * counts; d3 = 3 * displs
    call MPI_Allgatherv(ids, 3 * n, MPI_INTEGER, allid, c3, d3, MPI_INTEGER, env%comm, ierr)
    call unique(allk, allid, m)
    dkey = allk(1:m)
    dia = allid(1, 1:m); dib = allid(2, 1:m); dob = allid(3, 1:m)

  contains

    !> Sort keys(1:n) ascending, drop duplicates; n becomes the number of unique keys.
    subroutine unique(keys, ids, n)
      integer(i8), intent(inout) :: keys(:)
      integer, intent(inout) :: ids(:,:)
      integer, intent(inout) :: n
      integer :: a, u
      if (allocated(idx)) deallocate(idx)
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
    end subroutine unique
  end subroutine build_dictionary

  !> Move sample a into b (allocations moved, no copies).
  subroutine move_sample(a, b)
    type(sample_result_t), intent(inout) :: a
    type(sample_result_t), intent(inout) :: b
    b%set = a%set; b%index = a%index; b%time = a%time; b%start = a%start; b%rank = a%rank
    call move_alloc(a%mu, b%mu); call move_alloc(a%q, b%q); call move_alloc(a%u, b%u)
    call move_alloc(a%v, b%v); call move_alloc(a%kkt, b%kkt); call move_alloc(a%min_gap, b%min_gap)
    call move_alloc(a%iterations, b%iterations); call move_alloc(a%converged, b%converged)
    call move_alloc(a%n_active, b%n_active); call move_alloc(a%offset, b%offset)
    call move_alloc(a%key, b%key); call move_alloc(a%ia, b%ia); call move_alloc(a%ib, b%ib)
    call move_alloc(a%ob, b%ob); call move_alloc(a%value, b%value)
  end subroutine move_sample

  !> Make a per-rank error message (empty: no error) collective: env%agree_error, the lowest
  !> failing rank's message wins and every rank returns it.
  subroutine collective_error(env, msg, error)
    type(env_t), intent(in) :: env
    character(len=:), allocatable, intent(inout) :: msg
    type(error_t), allocatable, intent(out) :: error
    if (len(msg) > 0) call set_error(error, msg)
    call env%agree_error(error)
    if (allocated(error)) msg = error%message
  end subroutine collective_error
end module cr_snapshot_db
