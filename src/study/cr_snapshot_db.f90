!> The snapshot database of a parameter study (schema "crowdrom-snapshots", version 1; the
!> layout is documented in the README, "Snapshot database").
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
  use cr_fom_output, only: write_scene
  use cr_h5file, only: h5file_t, cr_h5_real, cr_h5_int, cr_h5_int64
  use cr_snapshot_piece, only: sample_result_t, read_piece, piece_path
  implicit none
  private
  public :: SNAP_SCHEMA, SNAP_SCHEMA_VERSION, SNAP_UNITS, db_meta_t, db_totals_t, probe_database, &
    assemble_database, block_range, collective_error

  character(len=*), parameter :: SNAP_SCHEMA = "crowdrom-snapshots"
  integer, parameter :: SNAP_SCHEMA_VERSION = 1
  character(len=*), parameter :: SNAP_UNITS = "length: m, time: s, velocity: m/s, l_exit: m, " // &
    "speed: m/s, multiplier: m/s^2 (lambda scales B = -h G: u = v - B^T lambda)"

  !> Root metadata of a database.
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

  !> Totals over the whole database (every rank receives them).
  type :: db_totals_t
    integer :: n_dict = 0, nonconverged_steps = 0, nonconverged_samples = 0
    integer(i8) :: nnz = 0
    real(wp) :: kkt_max = 0, time_sum = 0, time_max = 0
  end type db_totals_t

  !> The samples of one set held by this rank (a contiguous block).
  type :: set_block_t
    character(len=8) :: name = ''
    integer :: n = 0, k0 = 1, nloc = 0
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
  subroutine assemble_database(env, path, pieces_dir, meta, fom_ref, q0, n_train, n_valid, totals, error)
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: path, pieces_dir
    type(db_meta_t), intent(in) :: meta
    !> the reference model (for the scene group)
    type(fom_t), intent(in) :: fom_ref
    !> common initial positions [2*n_agents]
    real(wp), intent(in), contiguous :: q0(:)
    integer, intent(in) :: n_train, n_valid
    type(db_totals_t), intent(out) :: totals
    type(error_t), allocatable, intent(out) :: error
    type(set_block_t) :: sets(2)
    integer(i8), allocatable :: dkey(:)
    integer, allocatable :: dia(:), dib(:), dob(:)
    type(h5file_t) :: h5
    character(len=:), allocatable :: msg
    integer :: is, k, ierr, bad
    sets(1)%name = 'train'; sets(1)%n = n_train
    sets(2)%name = 'valid'; sets(2)%n = n_valid
    ! 1. read the pieces of this rank's blocks
    msg = ""
    do is = 1, 2
      call block_range(sets(is)%n, env%size, env%rank, sets(is)%k0, sets(is)%nloc)
      allocate(sets(is)%s(sets(is)%nloc))
      do k = 1, sets(is)%nloc
        if (len(msg) > 0) exit
        call read_piece(piece_path(pieces_dir, sets(is)%name, sets(is)%k0 + k - 1), sets(is)%s(k), error)
        if (allocated(error)) then
          msg = error%message; deallocate(error)
        end if
      end do
    end do
    call collective_error(env, msg, error)
    if (allocated(error)) return
    ! 2. the global contact dictionary
    call build_dictionary(env, sets, dkey, dia, dib, dob)
    totals%n_dict = size(dkey)
    ! 3. the file
    call h5%create(path, error, env=env)
    if (allocated(error)) return
    ops: block
      call write_header(error); if (allocated(error)) exit ops
      do is = 1, 2
        call write_set(sets(is), error); if (allocated(error)) exit ops
      end do
      call h5%write_attr("/", "complete", 1, error); if (allocated(error)) exit ops
      call h5%commit(error)
    end block ops
    if (allocated(error)) then
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

    subroutine write_header(error)
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
      call write_scene(h5, fom_ref, error); if (allocated(error)) return
      call h5%make_group("contacts", error); if (allocated(error)) return
      call h5%write("contacts/key", dkey, error); if (allocated(error)) return
      call h5%write("contacts/ia", dia, error); if (allocated(error)) return
      call h5%write("contacts/ib", dib, error); if (allocated(error)) return
      call h5%write("contacts/ob", dob, error); if (allocated(error)) return
      call h5%write_attr("contacts", "description", "global contact dictionary: every contact " // &
        "with lambda > 0 in some sample and step, sorted by key; ib = 0 for agent-obstacle " // &
        "contacts (ob = obstacle index), ob = 0 for agent pairs", error)
    end subroutine write_header

    subroutine write_set(b, error)
      type(set_block_t), intent(in) :: b
      type(error_t), allocatable, intent(out) :: error
      character(len=:), allocatable :: g
      real(wp), allocatable :: rbuf(:,:), r1(:)
      integer, allocatable :: ibuf(:,:), i1(:)
      integer(i8), allocatable :: off(:), cnt(:)
      integer(i8) :: base, base0, mine
      integer :: nd, ns, ne, k, c0, nnz_loc, j, n0, o, ierr
      g = trim(b%name)
      nd = 2 * meta%n_agents; ns = meta%n_steps; ne = meta%n_expanded
      call h5%make_group(g, error); if (allocated(error)) return
      call h5%make_group(g // "/stats", error); if (allocated(error)) return
      ! parameters
      call h5%create_dataset(g // "/params", [ne, b%n], cr_h5_real, error); if (allocated(error)) return
      allocate(rbuf(ne, b%nloc))
      do k = 1, b%nloc
        rbuf(:, k) = b%s(k)%mu
      end do
      call h5%write_block(g // "/params", rbuf, b%k0 - 1, error); if (allocated(error)) return
      deallocate(rbuf)
      ! positions
      call h5%create_dataset(g // "/positions", [nd, (ns + 1) * b%n], cr_h5_real, error); if (allocated(error)) return
      allocate(rbuf(nd, (ns + 1) * b%nloc))
      do k = 1, b%nloc
        rbuf(:, (k - 1) * (ns + 1) + 1:k * (ns + 1)) = b%s(k)%q
      end do
      call h5%write_block(g // "/positions", rbuf, (b%k0 - 1) * (ns + 1), error); if (allocated(error)) return
      deallocate(rbuf)
      ! velocities and desired velocities
      allocate(rbuf(nd, ns * b%nloc))
      call h5%create_dataset(g // "/velocities", [nd, ns * b%n], cr_h5_real, error); if (allocated(error)) return
      do k = 1, b%nloc
        rbuf(:, (k - 1) * ns + 1:k * ns) = b%s(k)%u
      end do
      call h5%write_block(g // "/velocities", rbuf, (b%k0 - 1) * ns, error); if (allocated(error)) return
      call h5%create_dataset(g // "/desired", [nd, ns * b%n], cr_h5_real, error); if (allocated(error)) return
      do k = 1, b%nloc
        rbuf(:, (k - 1) * ns + 1:k * ns) = b%s(k)%v
      end do
      call h5%write_block(g // "/desired", rbuf, (b%k0 - 1) * ns, error); if (allocated(error)) return
      deallocate(rbuf)
      ! per-step statistics [n_steps, n_S]
      allocate(rbuf(ns, b%nloc), ibuf(ns, b%nloc))
      call h5%create_dataset(g // "/stats/kkt", [ns, b%n], cr_h5_real, error); if (allocated(error)) return
      do k = 1, b%nloc
        rbuf(:, k) = b%s(k)%kkt
      end do
      call h5%write_block(g // "/stats/kkt", rbuf, b%k0 - 1, error); if (allocated(error)) return
      call h5%create_dataset(g // "/stats/min_gap", [ns, b%n], cr_h5_real, error); if (allocated(error)) return
      do k = 1, b%nloc
        rbuf(:, k) = b%s(k)%min_gap
      end do
      call h5%write_block(g // "/stats/min_gap", rbuf, b%k0 - 1, error); if (allocated(error)) return
      call h5%create_dataset(g // "/stats/iterations", [ns, b%n], cr_h5_int, error); if (allocated(error)) return
      do k = 1, b%nloc
        ibuf(:, k) = b%s(k)%iterations
      end do
      call h5%write_block(g // "/stats/iterations", ibuf, b%k0 - 1, error); if (allocated(error)) return
      call h5%create_dataset(g // "/stats/converged", [ns, b%n], cr_h5_int, error); if (allocated(error)) return
      do k = 1, b%nloc
        ibuf(:, k) = b%s(k)%converged
      end do
      call h5%write_block(g // "/stats/converged", ibuf, b%k0 - 1, error); if (allocated(error)) return
      call h5%create_dataset(g // "/stats/n_active", [ns, b%n], cr_h5_int, error); if (allocated(error)) return
      do k = 1, b%nloc
        ibuf(:, k) = b%s(k)%n_active
      end do
      call h5%write_block(g // "/stats/n_active", ibuf, b%k0 - 1, error); if (allocated(error)) return
      ! per-sample time and rank [n_S] (not part of the bitwise comparison)
      allocate(r1(b%nloc), i1(b%nloc))
      do k = 1, b%nloc
        r1(k) = b%s(k)%time; i1(k) = b%s(k)%rank
      end do
      call h5%create_dataset(g // "/stats/time", [b%n], cr_h5_real, error); if (allocated(error)) return
      call h5%write_block(g // "/stats/time", r1, b%k0 - 1, error); if (allocated(error)) return
      call h5%create_dataset(g // "/stats/rank", [b%n], cr_h5_int, error); if (allocated(error)) return
      call h5%write_block(g // "/stats/rank", i1, b%k0 - 1, error); if (allocated(error)) return
      ! sparse multipliers, CSR over the snapshot columns
      nnz_loc = 0
      do k = 1, b%nloc
        nnz_loc = nnz_loc + size(b%s(k)%value)
      end do
      mine = nnz_loc
      base = 0
      call MPI_Exscan(mine, base, 1, MPI_INTEGER8, MPI_SUM, env%comm, ierr)
      if (env%rank == 0) base = 0
      base0 = base
      allocate(cnt(1))
      cnt(1) = mine
      call MPI_Allreduce(MPI_IN_PLACE, cnt, 1, MPI_INTEGER8, MPI_SUM, env%comm, ierr)
      if (cnt(1) > huge(1)) then
        call set_error(error, g // ": " // str(cnt(1)) // " multipliers exceed the 32-bit block offsets"); return
      end if
      n0 = merge(1, 0, env%rank == 0)
      allocate(off(n0 + ns * b%nloc))
      if (n0 == 1) off(1) = 0
      c0 = n0
      do k = 1, b%nloc
        off(c0 + 1:c0 + ns) = base + b%s(k)%offset(2:ns + 1)
        base = base + b%s(k)%offset(ns + 1)
        c0 = c0 + ns
      end do
      o = 0
      if (env%rank > 0) o = (b%k0 - 1) * ns + 1
      call h5%create_dataset(g // "/lambda_offset", [ns * b%n + 1], cr_h5_int64, error); if (allocated(error)) return
      call h5%write_block(g // "/lambda_offset", off, o, error); if (allocated(error)) return
      deallocate(r1, i1)
      allocate(r1(nnz_loc), i1(nnz_loc))
      c0 = 0
      do k = 1, b%nloc
        do j = 1, size(b%s(k)%value)
          c0 = c0 + 1
          r1(c0) = b%s(k)%value(j)
          i1(c0) = bsearch_i8(dkey, b%s(k)%key(j))
        end do
      end do
      o = int(base0)
      call h5%create_dataset(g // "/lambda_index", [int(cnt(1))], cr_h5_int, error); if (allocated(error)) return
      call h5%write_block(g // "/lambda_index", i1, o, error); if (allocated(error)) return
      call h5%create_dataset(g // "/lambda_value", [int(cnt(1))], cr_h5_real, error); if (allocated(error)) return
      call h5%write_block(g // "/lambda_value", r1, o, error); if (allocated(error)) return
      call h5%write_attr(g, "n_samples", b%n, error)
    end subroutine write_set
  end subroutine assemble_database

  !> Sorted union over all ranks of the contact keys of this rank's samples (with identities).
  subroutine build_dictionary(env, sets, dkey, dia, dib, dob)
    type(env_t), intent(in) :: env
    type(set_block_t), intent(in) :: sets(:)
    integer(i8), allocatable, intent(out) :: dkey(:)
    integer, allocatable, intent(out) :: dia(:), dib(:), dob(:)
    integer(i8), allocatable :: keys(:), allk(:)
    integer, allocatable :: ids(:,:), allid(:,:), idx(:), counts(:), displs(:), c3(:), d3(:)
    integer :: n, is, k, j, m, ierr, r
    ! local unique
    n = 0
    do is = 1, size(sets)
      do k = 1, sets(is)%nloc
        n = n + size(sets(is)%s(k)%key)
      end do
    end do
    allocate(keys(n), ids(3, n))
    n = 0
    do is = 1, size(sets)
      do k = 1, sets(is)%nloc
        associate (s => sets(is)%s(k))
          do j = 1, size(s%key)
            n = n + 1
            keys(n) = s%key(j); ids(:, n) = [s%ia(j), s%ib(j), s%ob(j)]
          end do
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
