!> Assembly of the snapshot database of a parameter study (the product and its schema are
!> src/products/cr_snapshot_file).
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
  use cr_config, only: config_t
  use cr_scene, only: scene_t
  use cr_sampling, only: param_space_t
  use cr_h5file, only: h5file_t
  use cr_snapshot_file, only: SNAP_SCHEMA, db_meta_t, snap_block_t, write_snap_header, write_snap_set
  use cr_snapshot_piece, only: sample_result_t, read_piece, piece_path
  implicit none
  private
  public :: db_totals_t, probe_database, assemble_database, block_range, collective_error

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
  subroutine assemble_database(env, path, pieces_dir, meta, fom_ref, cfg, space, q0, n_train, n_valid, totals, error)
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: path, pieces_dir
    type(db_meta_t), intent(in) :: meta
    !> the reference model (for the scene group)
    type(fom_t), intent(in) :: fom_ref
    !> the reference configuration and the parameter space (each sample's mapped scene)
    type(config_t), intent(in) :: cfg
    type(param_space_t), intent(in) :: space
    !> common initial positions [2*n_agents]
    real(wp), intent(in), contiguous :: q0(:)
    integer, intent(in) :: n_train, n_valid
    type(db_totals_t), intent(out) :: totals
    type(error_t), allocatable, intent(out) :: error
    type(set_block_t) :: sets(2)
    integer(i8), allocatable :: dkey(:)
    integer, allocatable :: dia(:), dib(:), dob(:)
    type(h5file_t) :: h5
    type(snap_block_t) :: blk
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
      call write_snap_header(h5, meta, n_train, n_valid, q0, fom_ref%scene, dkey, dia, dib, dob, error)
      if (allocated(error)) exit ops
      do is = 1, 2
        blk = block_of(sets(is))
        call env_collective(msg, error); if (allocated(error)) exit ops
        call write_snap_set(env, h5, meta, blk, error); if (allocated(error)) exit ops
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

    !> The samples of a set block as the product's block (multipliers mapped to the dictionary).
    function block_of(b) result(o)
      type(set_block_t), intent(in) :: b
      type(snap_block_t) :: o
      type(scene_t) :: sc
      type(error_t), allocatable :: e3
      integer :: nd, ns, ne, k, j, c0, nnz, nv
      nd = 2 * meta%n_agents; ns = meta%n_steps; ne = meta%n_expanded
      o%name = b%name; o%n = b%n; o%k0 = b%k0; o%nloc = b%nloc
      allocate(o%mu(ne, b%nloc), o%q(nd, (ns + 1) * b%nloc), o%u(nd, ns * b%nloc), o%v(nd, ns * b%nloc), &
        o%kkt(ns, b%nloc), o%min_gap(ns, b%nloc), o%iterations(ns, b%nloc), o%converged(ns, b%nloc), &
        o%n_active(ns, b%nloc), o%time(b%nloc), o%rank(b%nloc), o%lam_ptr(ns * b%nloc + 1))
      nnz = 0
      o%lam_ptr(1) = 0
      do k = 1, b%nloc
        associate (s => b%s(k))
          o%mu(:, k) = s%mu
          o%q(:, (k - 1) * (ns + 1) + 1:k * (ns + 1)) = s%q
          o%u(:, (k - 1) * ns + 1:k * ns) = s%u
          o%v(:, (k - 1) * ns + 1:k * ns) = s%v
          o%kkt(:, k) = s%kkt; o%min_gap(:, k) = s%min_gap
          o%iterations(:, k) = s%iterations; o%converged(:, k) = s%converged; o%n_active(:, k) = s%n_active
          o%time(k) = s%time; o%rank(k) = s%rank
          o%lam_ptr((k - 1) * ns + 2:k * ns + 1) = nnz + s%offset(2:ns + 1)
          nnz = nnz + size(s%value)
        end associate
      end do
      ! each sample's mapped scene (reference vertex layout)
      nv = size(ref_vertices(fom_ref%scene))
      allocate(o%scene_vertices(nv, b%nloc), o%scene_exit(4, b%nloc))
      msg = ""
      do k = 1, b%nloc
        call space%scene_of(b%s(k)%mu, cfg, sc, e3)
        if (allocated(e3)) then
          msg = "scene of " // trim(b%name) // " sample " // str(b%k0 + k - 1) // ": " // e3%message; exit
        end if
        if (size(ref_vertices(sc)) /= nv) then
          msg = "scene of " // trim(b%name) // " sample " // str(b%k0 + k - 1) // " has another vertex layout"; exit
        end if
        o%scene_vertices(:, k) = ref_vertices(sc)
        o%scene_exit(:, k) = [sc%x_lo, sc%width, sc%x_hi, sc%width]
      end do
      allocate(o%lam_idx(nnz), o%lam_val(nnz))
      c0 = 0
      do k = 1, b%nloc
        do j = 1, size(b%s(k)%value)
          c0 = c0 + 1
          o%lam_val(c0) = b%s(k)%value(j)
          o%lam_idx(c0) = bsearch_i8(dkey, b%s(k)%key(j))
        end do
      end do
    end function block_of

    !> Vertices of every obstacle of a scene, in order [2 * total vertices].
    function ref_vertices(sc) result(v)
      type(scene_t), intent(in) :: sc
      real(wp), allocatable :: v(:)
      integer :: k
      allocate(v(0))
      do k = 1, sc%n_obstacles()
        v = [v, reshape(sc%obstacles(k)%vertices, [size(sc%obstacles(k)%vertices)])]
      end do
    end function ref_vertices

    !> Make this rank's message collective.
    subroutine env_collective(m, error)
      character(len=:), allocatable, intent(inout) :: m
      type(error_t), allocatable, intent(out) :: error
      call collective_error(env, m, error)
    end subroutine env_collective
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

  !> Make a per-rank error message collective (the lowest failing rank's message wins).
  subroutine collective_error(env, msg, error)
    type(env_t), intent(in) :: env
    character(len=:), allocatable, intent(inout) :: msg
    type(error_t), allocatable, intent(out) :: error
    integer :: who, ierr, n
    who = huge(1)
    if (len(msg) > 0) who = env%rank
    call MPI_Allreduce(MPI_IN_PLACE, who, 1, MPI_INTEGER, MPI_MIN, env%comm, ierr)
    if (who == huge(1)) return
    n = len(msg)
    call MPI_Bcast(n, 1, MPI_INTEGER, who, env%comm, ierr)
    if (env%rank /= who) then
      deallocate(msg); allocate(character(len=n) :: msg)
    end if
    call MPI_Bcast(msg, n, MPI_CHARACTER, who, env%comm, ierr)
    call set_error(error, msg)
  end subroutine collective_error
end module cr_snapshot_db
