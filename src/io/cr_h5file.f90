!> Thin HDF5 file handle: atomic create/commit, groups, whole datasets, extendible (streamed)
!> datasets, collective hyperslab blocks over the last dimension, attributes.
!>
!> Library code: never stops; every HDF5 status is translated into an `error_t` message naming
!> the operation, the object and the file on disk, e.g.
!> "h5file: write 'traj/positions' in 'out.h5.partial': h5dwrite_f failed (dims 40 x 12)".
!> HDF5's own error-stack printing is switched off (the message replaces it).
!>
!> Shapes are given in Fortran order (h5py shows them reversed).
!>
!> Atomic output: `create(path)` writes `path // '.partial'`; `commit` closes it and renames it to
!> `path` (rank 0, after all ranks closed), so a run that dies never leaves a file under the final
!> name and a previous `path` is replaced only by a complete new file. `abort` closes and deletes
!> the temporary. `create(..., in_place=.true.)` writes `path` directly (resumable databases);
!> `commit` then only closes, and `abort` closes without deleting.
!> A handle must end with `commit`, `close` or `abort` (there is no finaliser); `close` on a
!> temporary leaves `path.partial` behind, exactly like an interrupted run.
!>
!> Parallel use (create/open with an `env_t` of size > 1: MPI-IO driver on a duplicate of
!> env%comm). Every procedure is then collective: all ranks call it in the same order with the
!> same names and shapes.
!>  * `write` (whole dataset) and `append`: the dataset is created / extended collectively and
!>    rank 0 alone writes the raw data; the other ranks' data are ignored (pass the same shape).
!>  * `write_attr`: all ranks pass the same value (attributes are metadata).
!>  * `write_block` / `read_block`: collective MPI-IO transfer, each rank its own range of the
!>    last dimension; ranks with an empty range still call.
!>  * `read`, `read_attr`, `get_dims`, `exists`: every rank reads independently.
!>  * Failures of writing procedures are made collective: if one rank fails, all return an error.
module cr_h5file
  use, intrinsic :: iso_c_binding, only: c_ptr, c_null_ptr, c_loc, c_char, c_null_char, &
    c_associated, c_int, c_f_pointer, c_int64_t
  ! the MPI-IO driver of HDF5 takes the communicator itself; every other MPI call goes through env_t
  use mpi_f08, only: MPI_INFO_NULL
  use hdf5, only: hid_t, hsize_t, size_t, h5open_f, h5close_f, h5fflush_f, H5F_SCOPE_GLOBAL_F, &
    h5eset_auto_f, h5kind_to_type, &
    H5_REAL_KIND, H5_INTEGER_KIND, H5P_DEFAULT_F, H5P_FILE_ACCESS_F, H5P_LINK_CREATE_F, &
    H5P_DATASET_CREATE_F, H5P_DATASET_XFER_F, H5F_ACC_TRUNC_F, H5F_ACC_RDONLY_F, H5F_ACC_RDWR_F, &
    H5S_SCALAR_F, H5S_UNLIMITED_F, H5S_SELECT_SET_F, H5S_SELECT_OR_F, H5T_FLOAT_F, H5T_INTEGER_F, H5T_STRING_F, &
    H5T_FORTRAN_S1, H5T_STR_NULLPAD_F, H5FD_MPIO_COLLECTIVE_F, H5FD_MPIO_INDEPENDENT_F, &
    h5pcreate_f, h5pclose_f, h5pset_fapl_mpio_f, h5pset_dxpl_mpio_f, h5pset_chunk_f, &
    h5pset_create_inter_group_f, h5fcreate_f, h5fopen_f, h5fclose_f, h5fis_hdf5_f, &
    h5gcreate_f, h5gclose_f, h5lexists_f, h5ldelete_f, h5oopen_f, h5oclose_f, &
    h5dcreate_f, h5dopen_f, h5dclose_f, h5dwrite_f, h5dread_f, h5dget_space_f, h5dget_type_f, &
    h5dset_extent_f, h5screate_f, h5screate_simple_f, h5sclose_f, h5sselect_hyperslab_f, &
    h5sselect_none_f, h5sget_simple_extent_ndims_f, h5sget_simple_extent_dims_f, &
    h5tcopy_f, h5tclose_f, h5tset_size_f, h5tset_strpad_f, h5tget_class_f, h5tget_size_f, &
    h5tis_variable_str_f, h5aexists_f, h5adelete_f, h5acreate_f, h5aopen_f, h5aclose_f, &
    h5awrite_f, h5aread_f, h5aget_space_f, h5aget_type_f, &
    h5pset_alloc_time_f, h5pset_fill_time_f, h5dget_offset_f, H5D_ALLOC_TIME_EARLY_F, H5D_FILL_TIME_NEVER_F, &
    h5get_libversion_f
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_env, only: env_t, mpi_failed
  use cr_strings, only: str
  use cr_fsys, only: rename_file, remove_file, truncate_file, clear_errno, io_fault_text, discard_fd, errno_text, &
    reserve_space, errno_name, file_size, truncate_to
  implicit none
  private
  public :: h5file_t, cr_h5_real, cr_h5_int, cr_h5_int64, h5_library_close, h5_library_version

  !> element kinds for `create_extendible` / `create_dataset`: real(wp), integer, integer(int64)
  integer, parameter :: cr_h5_real = 1, cr_h5_int = 2, cr_h5_int64 = 3

  !> h5open_f has been called (once per process)
  logical, save :: h5_ready = .false.

  !> An open HDF5 file (see the module header for atomic and parallel semantics).
  type :: h5file_t
    private
    integer(hid_t) :: fid = -1
    integer(hid_t) :: lcpl = -1
    !> name the file gets on commit
    character(len=:), allocatable :: final_path
    !> name of the file actually open (final_path or final_path.partial)
    character(len=:), allocatable :: disk_path
    logical :: temporary = .false.
    logical :: writable = .false.
    logical :: parallel = .false.
    !> environment on a duplicate of the env communicator (owned while comm_held, parallel only)
    type(env_t) :: env
    logical :: comm_held = .false.
    !> bytes of the file on disk reserved by ensure_space (a writable temporary only);
    !> -1: the file system cannot reserve, writes go on unreserved
    integer(i8) :: reserved = 0
    integer :: rank = 0
  contains
    procedure :: create => h5_create
    procedure :: open => h5_open
    procedure :: close => h5_close
    procedure :: commit => h5_commit
    procedure :: abort => h5_abort
    procedure :: is_open => h5_is_open
    procedure :: path_on_disk => h5_path_on_disk
    procedure :: file_id => h5_file_id
    procedure :: make_group
    procedure :: exists
    procedure :: get_dims
    procedure :: create_extendible
    procedure :: create_dataset
    procedure :: create_placed
    procedure, private :: w_real, w_int, w_int64_1, w_string
    generic :: write => w_real, w_int, w_int64_1, w_string
    procedure, private :: r_real0, r_real1, r_real2, r_real3, r_int0, r_int1, r_int2, r_int3, &
      r_int64_1, r_string
    generic :: read => r_real0, r_real1, r_real2, r_real3, r_int0, r_int1, r_int2, r_int3, &
      r_int64_1, r_string
    procedure, private :: a_real0, a_real1, a_real2, a_int0, a_int1, a_int2, a_int64_0, a_int64_1
    generic :: append => a_real0, a_real1, a_real2, a_int0, a_int1, a_int2, a_int64_0, a_int64_1
    procedure, private :: wb_real, wb_int, wb_int64_1
    generic :: write_block => wb_real, wb_int, wb_int64_1
    procedure, private :: wr_real, wr_int, wr_int64_1
    generic :: write_ranges => wr_real, wr_int, wr_int64_1
    procedure, private :: rb_real, rb_int, rb_int64_1
    generic :: read_block => rb_real, rb_int, rb_int64_1
    procedure, private :: wa_string, wa_real, wa_int, wa_real1, wa_int1
    generic :: write_attr => wa_string, wa_real, wa_int, wa_real1, wa_int1
    procedure, private :: ra_string, ra_real, ra_int, ra_real1, ra_int1
    generic :: read_attr => ra_string, ra_real, ra_int, ra_real1, ra_int1
  end type h5file_t

  !> bytes reserved past the allocated address range before the final flush (superblock,
  !> free-space and cache entries the close may still allocate)
  integer(i8), parameter :: SPACE_MARGIN = 131072_i8
  integer, parameter :: ERRNO_ENOSPC = 28, ERRNO_EDQUOT = 122, ERRNO_EFBIG = 27

  interface
    !> C H5Fget_eoa: the end of the file's allocated address space (bytes).
    integer(c_int) function h5fget_eoa_c(file_id, eoa) bind(c, name="H5Fget_eoa")
      import :: c_int, c_int64_t
      integer(c_int64_t), value :: file_id
      integer(c_int64_t), intent(out) :: eoa
    end function h5fget_eoa_c
    !> C H5Fget_vfd_handle: the low-level handle of an open file (for the sec2 driver, a
    !> pointer to its file descriptor). No Fortran wrapper exists in HDF5 1.10.
    integer(c_int) function h5fget_vfd_handle_c(file_id, fapl_id, handle) bind(c, name="H5Fget_vfd_handle")
      import :: c_int, c_ptr, c_int64_t
      integer(c_int64_t), value :: file_id, fapl_id
      type(c_ptr), intent(out) :: handle
    end function h5fget_vfd_handle_c
  end interface

contains

  ! ------------------------------------------------------------------ helpers

  !> "40 x 12" (or "scalar")
  pure function dims_str(d) result(s)
    integer(hsize_t), intent(in) :: d(:)
    character(len=:), allocatable :: s
    integer :: k
    if (size(d) == 0) then
      s = "scalar"; return
    end if
    s = str(int(d(1), i8))
    do k = 2, size(d)
      s = s // " x " // str(int(d(k), i8))
    end do
  end function dims_str

  function where_str(this) result(s)
    class(h5file_t), intent(in) :: this
    character(len=:), allocatable :: s
    if (allocated(this%disk_path)) then
      s = this%disk_path
    else
      s = "(no file)"
    end if
  end function where_str

  !> Set an error "h5file: <op> '<name>' in '<file>': <what> [(dims ...)]".
  subroutine fail(this, error, op, name, what, d)
    class(h5file_t), intent(in) :: this
    type(error_t), allocatable, intent(out) :: error
    character(len=*), intent(in) :: op, name, what
    integer(hsize_t), intent(in), optional :: d(:)
    character(len=:), allocatable :: msg
    msg = "h5file: " // op // " '" // name // "' in '" // where_str(this) // "': " // what
    if (present(d)) msg = msg // " (dims " // dims_str(d) // ")"
    call set_error(error, msg)
  end subroutine fail

  !> If hdferr < 0, set an error naming the failed HDF5 routine.
  subroutine check_h5(hdferr, this, error, op, name, routine, d)
    integer, intent(in) :: hdferr
    class(h5file_t), intent(in) :: this
    type(error_t), allocatable, intent(inout) :: error
    character(len=*), intent(in) :: op, name, routine
    integer(hsize_t), intent(in), optional :: d(:)
    character(len=:), allocatable :: why
    if (hdferr >= 0 .or. allocated(error)) then
      call clear_errno(); return
    end if
    ! the system's reason (disk full, read-only, ...) when the failure was a storage fault
    why = io_fault_text()
    if (len(why) > 0) then
      call fail(this, error, op, name, routine // " failed: " // why, d)
    else
      call fail(this, error, op, name, routine // " failed", d)
    end if
    call clear_errno()
  end subroutine check_h5

  !> In parallel, make an error collective: if any rank failed, every rank returns an error.
  subroutine sync_error(this, error)
    class(h5file_t), intent(in) :: this
    type(error_t), allocatable, intent(inout) :: error
    if (.not. this%parallel .or. .not. this%comm_held) return
    call this%env%agree_error(error)
  end subroutine sync_error

  subroutine init_hdf5(error)
    type(error_t), allocatable, intent(out) :: error
    integer :: hdferr
    if (h5_ready) return
    call h5open_f(hdferr)
    if (hdferr < 0) then
      call set_error(error, "h5file: h5open_f failed"); return
    end if
    call h5eset_auto_f(0, hdferr)
    h5_ready = .true.
  end subroutine init_hdf5

  !> Close the HDF5 library if this module opened it (every object still open is closed by
  !> HDF5). Programs call it before MPI_Finalize, also on error paths, so that HDF5 never
  !> shuts down inside MPI_Finalize with a file whose close failed (full disk).
  subroutine h5_library_close()
    integer :: hdferr
    if (.not. h5_ready) return
    call h5close_f(hdferr)
    h5_ready = .false.
  end subroutine h5_library_close

  !> The version of the HDF5 library ("1.10.8"), "unknown" when the library does not say.
  function h5_library_version() result(v)
    character(len=:), allocatable :: v
    integer :: maj, mnr, rel, ierr
    call h5get_libversion_f(maj, mnr, rel, ierr)
    v = "unknown"
    if (ierr == 0) v = str(maj) // "." // str(mnr) // "." // str(rel)
  end function h5_library_version

  !> HDF5 memory type of a crowdrom element kind code
  integer(hid_t) function type_of(kind_code)
    integer, intent(in) :: kind_code
    select case (kind_code)
    case (cr_h5_real)
      type_of = h5kind_to_type(wp, H5_REAL_KIND)
    case (cr_h5_int)
      type_of = h5kind_to_type(kind(0), H5_INTEGER_KIND)
    case (cr_h5_int64)
      type_of = h5kind_to_type(i8, H5_INTEGER_KIND)
    case default
      type_of = -1
    end select
  end function type_of

  integer function class_of(kind_code)
    integer, intent(in) :: kind_code
    if (kind_code == cr_h5_real) then
      class_of = H5T_FLOAT_F
    else
      class_of = H5T_INTEGER_F
    end if
  end function class_of

  function class_name(tclass) result(s)
    integer, intent(in) :: tclass
    character(len=:), allocatable :: s
    if (tclass == H5T_FLOAT_F) then
      s = "float"
    else if (tclass == H5T_INTEGER_F) then
      s = "integer"
    else if (tclass == H5T_STRING_F) then
      s = "string"
    else
      s = "class " // str(tclass)
    end if
  end function class_name

  !> Fixed-length, null-padded string type of n bytes (caller closes it).
  subroutine string_type(n, stype, hdferr)
    integer, intent(in) :: n
    integer(hid_t), intent(out) :: stype
    integer, intent(out) :: hdferr
    call h5tcopy_f(H5T_FORTRAN_S1, stype, hdferr)
    if (hdferr < 0) return
    call h5tset_size_f(stype, int(n, size_t), hdferr)
    if (hdferr < 0) return
    call h5tset_strpad_f(stype, H5T_STR_NULLPAD_F, hdferr)
  end subroutine string_type

  !> C string buffer of a Fortran string (at least one byte, null-padded)
  subroutine to_cbuf(s, buf)
    character(len=*), intent(in) :: s
    character(kind=c_char), allocatable, intent(out) :: buf(:)
    integer :: k
    allocate(buf(max(1, len(s))))
    buf = c_null_char
    do k = 1, len(s)
      buf(k) = s(k:k)
    end do
  end subroutine to_cbuf

  !> Fortran string of a C buffer, trailing NULs removed
  function from_cbuf(buf) result(s)
    character(kind=c_char), intent(in) :: buf(:)
    character(len=:), allocatable :: s
    integer :: n, k
    n = size(buf)
    do while (n > 0)
      if (buf(n) /= c_null_char) exit
      n = n - 1
    end do
    allocate(character(len=n) :: s)
    do k = 1, n
      s(k:k) = buf(k)
    end do
  end function from_cbuf

  subroutine close_ids(dset, space, mspace, ptype, dtype)
    integer(hid_t), intent(inout), optional :: dset, space, mspace, ptype, dtype
    integer :: e
    if (present(dset)) then
      if (dset >= 0) call h5dclose_f(dset, e)
      dset = -1
    end if
    if (present(space)) then
      if (space >= 0) call h5sclose_f(space, e)
      space = -1
    end if
    if (present(mspace)) then
      if (mspace >= 0) call h5sclose_f(mspace, e)
      mspace = -1
    end if
    if (present(ptype)) then
      if (ptype >= 0) call h5pclose_f(ptype, e)
      ptype = -1
    end if
    if (present(dtype)) then
      if (dtype >= 0) call h5tclose_f(dtype, e)
      dtype = -1
    end if
  end subroutine close_ids

  subroutine need_open(this, error, op, name, write_access)
    class(h5file_t), intent(in) :: this
    type(error_t), allocatable, intent(out) :: error
    character(len=*), intent(in) :: op, name
    logical, intent(in) :: write_access
    if (this%fid < 0) then
      call fail(this, error, op, name, "file is not open")
    else if (write_access .and. .not. this%writable) then
      call fail(this, error, op, name, "file is open read-only")
    end if
  end subroutine need_open

  !> Before a write of about `nbytes` (summed over the ranks in parallel): reserve disk
  !> blocks up to the end of the allocated address range plus the write and a margin, so
  !> that HDF5 itself never meets a full disk. HDF5 1.10 cannot close a file after a failed
  !> metadata flush, and the file left registered crashes the library shutdown inside
  !> MPI_Finalize; a reservation that fails instead gives a clean error ("No space left on
  !> device") and h5_abort can still close and delete the temporary. Collective in parallel.
  subroutine ensure_space(this, nbytes, op, name, error)
    class(h5file_t), intent(inout) :: this
    integer(i8), intent(in) :: nbytes
    character(len=*), intent(in) :: op, name
    type(error_t), allocatable, intent(inout) :: error
    integer(i8) :: total, need, want
    integer(c_int64_t) :: eoa
    integer :: status
    integer(i8) :: shared(2)
    type(error_t), allocatable :: e
    if (this%fid < 0 .or. .not. this%writable) return
    if (this%reserved < 0) return
    total = max(nbytes, 0_i8)
    if (this%parallel) then
      call this%env%allreduce(total, 'sum', e)
      if (allocated(e)) then
        if (.not. allocated(error)) call fail(this, error, op, name, e%message)
        return
      end if
    end if
    status = 0
    if (this%rank == 0) then
      eoa = 0
      if (h5fget_eoa_c(this%fid, eoa) < 0) eoa = int(max(file_size(this%disk_path), 0_i8), c_int64_t)
      need = int(eoa, i8) + total + SPACE_MARGIN
      if (need > this%reserved) then
        ! grow in steps (1/16 of what is reserved, at least the margin, at most 64 MiB)
        want = need + min(max(this%reserved / 16, SPACE_MARGIN), 67108864_i8)
        status = reserve_space(this%disk_path, want)
        if (status == 0) then
          this%reserved = want
        else if (status /= ERRNO_ENOSPC .and. status /= ERRNO_EDQUOT .and. status /= ERRNO_EFBIG) then
          ! no fallocate on this file system: go on without reservations
          this%reserved = -1
          status = 0
        end if
      end if
    end if
    if (this%parallel) then
      shared = [int(status, i8), this%reserved]
      call this%env%bcast(shared, e, root=0)
      if (allocated(e)) then
        if (.not. allocated(error)) call fail(this, error, op, name, e%message)
        return
      end if
      status = int(shared(1)); this%reserved = shared(2)
    end if
    if (status /= 0 .and. .not. allocated(error)) &
      call fail(this, error, op, name, errno_name(status) // " (" // str(total) // " more bytes to write)")
  end subroutine ensure_space

  ! ------------------------------------------------------------------ life cycle

  !> Take parallel settings from env (MPI-IO when env%size > 1).
  subroutine setup(this, path, env, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: path
    type(env_t), intent(in), optional :: env
    type(error_t), allocatable, intent(out) :: error
    this%parallel = .false.
    this%rank = 0
    if (present(env)) then
      if (env%size > 1) then
        this%parallel = .true.
        this%rank = env%rank
        call this%env%init(env%comm, error)
        if (allocated(error)) then
          error%message = "h5file: '" // path // "': " // error%message
          this%parallel = .false.
        else
          this%comm_held = .true.
        end if
      end if
    end if
  end subroutine setup

  subroutine release_comm(this)
    class(h5file_t), intent(inout) :: this
    if (this%comm_held) call this%env%free()
    this%comm_held = .false.
  end subroutine release_comm

  !> File access property list (MPI-IO in parallel); H5P_DEFAULT_F otherwise.
  subroutine make_fapl(this, fapl, hdferr)
    class(h5file_t), intent(in) :: this
    integer(hid_t), intent(out) :: fapl
    integer, intent(out) :: hdferr
    fapl = H5P_DEFAULT_F
    hdferr = 0
    if (.not. this%parallel) return
    call h5pcreate_f(H5P_FILE_ACCESS_F, fapl, hdferr)
    if (hdferr < 0) return
    call h5pset_fapl_mpio_f(fapl, this%env%comm%MPI_VAL, MPI_INFO_NULL%MPI_VAL, hdferr)
  end subroutine make_fapl

  subroutine make_lcpl(this, hdferr)
    class(h5file_t), intent(inout) :: this
    integer, intent(out) :: hdferr
    call h5pcreate_f(H5P_LINK_CREATE_F, this%lcpl, hdferr)
    if (hdferr < 0) return
    call h5pset_create_inter_group_f(this%lcpl, 1, hdferr)
  end subroutine make_lcpl

  !> Create `path.partial` (or `path` with in_place) for writing, truncating any old one.
  !> Collective over env%comm when env%size > 1 (MPI-IO driver).
  subroutine h5_create(this, path, error, env, in_place)
    class(h5file_t), intent(inout) :: this
    !> final file name
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    !> parallel environment (MPI-IO if env%size > 1)
    type(env_t), intent(in), optional :: env
    !> write `path` directly instead of a temporary (default .false.)
    logical, intent(in), optional :: in_place
    integer(hid_t) :: fapl
    integer :: hdferr, e
    character(len=:), allocatable :: why
    character(len=*), parameter :: op = "create"
    if (this%fid >= 0) then
      call fail(this, error, op, path, "handle is already open"); return
    end if
    call init_hdf5(error)
    if (allocated(error)) return
    call setup(this, path, env, error)
    if (allocated(error)) return
    this%temporary = .true.
    if (present(in_place)) this%temporary = .not. in_place
    this%final_path = path
    if (this%temporary) then
      this%disk_path = path // ".partial"
    else
      this%disk_path = path
    end if
    this%writable = .true.
    this%reserved = 0
    call make_fapl(this, fapl, hdferr)
    call check_h5(hdferr, this, error, op, "/", "h5pset_fapl_mpio_f")
    if (.not. allocated(error)) then
      call clear_errno()
      call h5fcreate_f(this%disk_path, H5F_ACC_TRUNC_F, this%fid, hdferr, access_prp=fapl)
      if (hdferr < 0) then
        this%fid = -1
        ! not ours to remove: a temporary of that name may be another run's, still being
        ! written (HDF5's file lock refused it)
        this%temporary = .false.
        ! any system reason is the one that matters here (missing directory, permission, ...)
        why = errno_text()
        if (len(why) == 0) why = "h5fcreate_f failed"
        call fail(this, error, op, "/", "cannot create the file: " // why)
      end if
    end if
    if (fapl /= H5P_DEFAULT_F .and. fapl >= 0) call h5pclose_f(fapl, e)
    if (.not. allocated(error)) then
      call make_lcpl(this, hdferr)
      call check_h5(hdferr, this, error, op, "/", "h5pset_create_inter_group_f")
    end if
    call sync_error(this, error)
    if (allocated(error)) call h5_abort(this)
  end subroutine h5_create

  !> Open an existing file (read-only unless readwrite). Collective when env%size > 1.
  subroutine h5_open(this, path, error, env, readwrite)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: path
    type(error_t), allocatable, intent(out) :: error
    type(env_t), intent(in), optional :: env
    !> open for reading and writing (default .false.)
    logical, intent(in), optional :: readwrite
    integer(hid_t) :: fapl
    integer :: hdferr, e, flag
    logical :: ex, is_h5
    character(len=*), parameter :: op = "open"
    if (this%fid >= 0) then
      call fail(this, error, op, path, "handle is already open"); return
    end if
    inquire(file=path, exist=ex)
    if (.not. ex) then
      call set_error(error, "h5file: open '" // path // "': file does not exist"); return
    end if
    call init_hdf5(error)
    if (allocated(error)) return
    call h5fis_hdf5_f(path, is_h5, hdferr)
    if (hdferr < 0 .or. .not. is_h5) then
      call set_error(error, "h5file: open '" // path // "': not an HDF5 file"); return
    end if
    call setup(this, path, env, error)
    if (allocated(error)) return
    this%final_path = path
    this%disk_path = path
    this%temporary = .false.
    this%writable = .false.
    if (present(readwrite)) this%writable = readwrite
    this%reserved = 0
    flag = H5F_ACC_RDONLY_F
    if (this%writable) flag = H5F_ACC_RDWR_F
    call make_fapl(this, fapl, hdferr)
    call check_h5(hdferr, this, error, op, "/", "h5pset_fapl_mpio_f")
    if (.not. allocated(error)) then
      call h5fopen_f(path, flag, this%fid, hdferr, access_prp=fapl)
      if (hdferr < 0) this%fid = -1
      call check_h5(hdferr, this, error, op, "/", "h5fopen_f")
    end if
    if (fapl /= H5P_DEFAULT_F .and. fapl >= 0) call h5pclose_f(fapl, e)
    if (.not. allocated(error)) then
      call make_lcpl(this, hdferr)
      call check_h5(hdferr, this, error, op, "/", "h5pset_create_inter_group_f")
    end if
    call sync_error(this, error)
    if (allocated(error)) then
      if (this%lcpl >= 0) call h5pclose_f(this%lcpl, e)
      this%lcpl = -1
      if (this%fid >= 0) call h5fclose_f(this%fid, e)
      this%fid = -1
      call release_comm(this)
    end if
  end subroutine h5_open

  !> True while a file is open.
  pure logical function h5_is_open(this)
    class(h5file_t), intent(in) :: this
    h5_is_open = this%fid >= 0
  end function h5_is_open

  !> Name of the file on disk (the temporary until commit).
  function h5_path_on_disk(this) result(s)
    class(h5file_t), intent(in) :: this
    character(len=:), allocatable :: s
    s = where_str(this)
  end function h5_path_on_disk

  !> The HDF5 identifier of the open file (-1 when closed), for writers of layouts the
  !> handle does not offer (e.g. compound datasets); they check their own return codes.
  integer(hid_t) function h5_file_id(this) result(fid)
    class(h5file_t), intent(in) :: this
    fid = this%fid
  end function h5_file_id

  !> Close the HDF5 file (no rename); hdferr of h5fclose_f.
  subroutine close_file(this, hdferr)
    class(h5file_t), intent(inout) :: this
    integer, intent(out) :: hdferr
    integer :: e
    hdferr = 0
    if (this%lcpl >= 0) call h5pclose_f(this%lcpl, e)
    this%lcpl = -1
    ! closing a parallel file is collective: not after a failed MPI call on this rank (the
    ! file is left open, the job ends by MPI_Abort; see cr_env's mpi_failed)
    if (this%fid >= 0 .and. .not. (this%parallel .and. mpi_failed())) call h5fclose_f(this%fid, hdferr)
    this%fid = -1
  end subroutine close_file

  !> Close the file. On a temporary (from `create`) this leaves `path.partial` (see commit).
  subroutine h5_close(this, error)
    class(h5file_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    integer :: hdferr, status
    logical :: trim_reserve
    if (this%fid < 0) return
    trim_reserve = this%writable .and. this%reserved > 0 .and. this%rank == 0
    call close_file(this, hdferr)
    call check_h5(hdferr, this, error, "close", "/", "h5fclose_f")
    ! give back the blocks reserved past the end of the file
    if (trim_reserve .and. hdferr >= 0) status = truncate_to(this%disk_path, file_size(this%disk_path))
    call sync_error(this, error)
    call release_comm(this)
  end subroutine h5_close

  !> Close and atomically rename `path.partial` to `path` (replacing an old `path` only now).
  !> In parallel: all ranks close (collective), then rank 0 renames; all ranks get its status.
  !> For a file created in place or opened, commit only closes.
  subroutine h5_commit(this, error)
    class(h5file_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    integer :: hdferr, status
    integer :: shared(1)
    character(len=*), parameter :: op = "commit"
    if (this%fid < 0) then
      call fail(this, error, op, "/", "file is not open"); return
    end if
    if (.not. this%temporary) then
      call h5_close(this, error); return
    end if
    ! A metadata flush that fails (full disk) leaves HDF5 1.10 unable to close the file, and
    ! the freed file still registered crashes the library shutdown inside MPI_Finalize. So
    ! the space the last writes need is reserved first (the whole allocated address range
    ! plus a margin, without changing the size): if it cannot be, the file is abandoned
    ! before any flush (h5_abort sends the pending writes to memory) and the error says why.
    call ensure_space(this, 0_i8, op, "/", error)
    if (allocated(error)) then
      call h5_abort(this); return
    end if
    call clear_errno()
    call h5fflush_f(this%fid, H5F_SCOPE_GLOBAL_F, hdferr)
    call check_h5(hdferr, this, error, op, "/", "h5fflush_f")
    call sync_error(this, error)
    if (allocated(error)) then
      call h5_abort(this); return
    end if
    call close_file(this, hdferr)
    call check_h5(hdferr, this, error, op, "/", "h5fclose_f")
    call sync_error(this, error)
    if (allocated(error)) then
      call release_comm(this); return
    end if
    if (this%parallel) call this%env%sync(error)
    if (allocated(error)) then
      call release_comm(this); return
    end if
    status = 0
    if (this%rank == 0) then
      ! give back the reserved blocks past the end of the file
      status = truncate_to(this%disk_path, file_size(this%disk_path))
      status = rename_file(this%disk_path, this%final_path)
    end if
    if (this%parallel) then
      shared = status
      call this%env%bcast(shared, error, root=0)
      status = shared(1)
    end if
    call release_comm(this)
    if (allocated(error)) return
    if (status /= 0) then
      call set_error(error, "h5file: commit: rename '" // this%disk_path // "' -> '" // &
        this%final_path // "' failed"); return
    end if
    this%disk_path = this%final_path
    this%temporary = .false.
  end subroutine h5_commit

  !> Close (ignoring errors) and delete the temporary; a previous final file is untouched.
  !> A file created in place or opened is only closed. Collective in parallel.
  subroutine h5_abort(this)
    class(h5file_t), intent(inout) :: this
    integer :: hdferr, status
    integer(c_int), pointer :: fd
    type(error_t), allocatable :: e
    type(c_ptr) :: handle
    ! An abandoned temporary must close even when its pending writes cannot succeed (full
    ! disk): a failed h5fclose leaves HDF5 1.10 with a freed file still registered, which
    ! crashes at library shutdown (inside MPI_Finalize). Serial files: the remaining writes
    ! go to an in-memory file. Parallel (MPI-IO) files: the temporary is emptied, which frees
    ! its blocks for the last metadata writes.
    if (this%temporary .and. this%writable .and. this%fid >= 0 .and. allocated(this%disk_path)) then
      if (.not. this%parallel) then
        handle = c_null_ptr
        if (h5fget_vfd_handle_c(this%fid, H5P_DEFAULT_F, handle) >= 0) then
          if (c_associated(handle)) then
            call c_f_pointer(handle, fd)
            status = discard_fd(fd)
          end if
        end if
      else
        ! errors are ignored here as everywhere in abort
        if (this%comm_held) call this%env%sync(e)
        if (this%rank == 0) status = truncate_file(this%disk_path)
        if (this%comm_held) call this%env%sync(e)
      end if
    end if
    call close_file(this, hdferr)
    if (this%temporary .and. allocated(this%disk_path)) then
      if (this%parallel .and. this%comm_held) call this%env%sync(e)
      if (this%rank == 0) status = remove_file(this%disk_path)
      if (this%parallel .and. this%comm_held) call this%env%sync(e)
    end if
    this%temporary = .false.
    call release_comm(this)
  end subroutine h5_abort

  ! ------------------------------------------------------------------ groups and queries

  !> True if the object (group or dataset; nested path "a/b/c") exists. False if not open.
  logical function exists(this, name)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    integer :: k, hdferr, n
    logical :: ex
    exists = .false.
    if (this%fid < 0) return
    n = len_trim(name)
    do while (n > 0)
      if (name(n:n) /= "/") exit
      n = n - 1
    end do
    if (n == 0) then
      exists = .true.; return
    end if
    do k = 2, n + 1
      if (k <= n) then
        if (name(k:k) /= "/") cycle
      end if
      if (name(k-1:k-1) == "/") cycle
      call h5lexists_f(this%fid, name(1:k-1), ex, hdferr)
      if (hdferr < 0 .or. .not. ex) return
    end do
    exists = .true.
  end function exists

  !> Create a group and any missing parents ("traj/contacts"); existing groups are fine.
  subroutine make_group(this, name, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    type(error_t), allocatable, intent(out) :: error
    integer(hid_t) :: gid
    integer :: hdferr, e
    character(len=*), parameter :: op = "make_group"
    call need_open(this, error, op, name, .true.)
    if (allocated(error)) return
    call ensure_space(this, 0_i8, op, name, error)
    if (allocated(error)) return
    if (.not. this%exists(name)) then
      call h5gcreate_f(this%fid, name, gid, hdferr, lcpl_id=this%lcpl)
      call check_h5(hdferr, this, error, op, name, "h5gcreate_f")
      if (hdferr >= 0) call h5gclose_f(gid, e)
    end if
    call sync_error(this, error)
  end subroutine make_group

  !> Dataset dims, class and element size (dataset closed again).
  subroutine inspect(this, name, op, d, tclass, tsize, error, varstr)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name, op
    integer(hsize_t), allocatable, intent(out) :: d(:)
    integer, intent(out) :: tclass
    integer(size_t), intent(out) :: tsize
    type(error_t), allocatable, intent(out) :: error
    logical, intent(out), optional :: varstr
    integer(hid_t) :: dset, space, dtype
    integer :: hdferr
    logical :: isvar
    dset = -1; space = -1; dtype = -1
    tclass = -1; tsize = 0
    allocate(d(0))
    if (present(varstr)) varstr = .false.
    call need_open(this, error, op, name, .false.)
    if (allocated(error)) return
    if (.not. this%exists(name)) then
      call fail(this, error, op, name, "no such dataset"); return
    end if
    ops: block
      call h5dopen_f(this%fid, name, dset, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5dopen_f (not a dataset?)")
      if (allocated(error)) exit ops
      call h5dget_space_f(dset, space, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5dget_space_f")
      if (allocated(error)) exit ops
      call h5dget_type_f(dset, dtype, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5dget_type_f")
      if (allocated(error)) exit ops
      call shape_and_class(this, space, dtype, op, name, d, tclass, error)
      if (allocated(error)) exit ops
      call h5tget_size_f(dtype, tsize, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5tget_size_f")
      if (allocated(error)) exit ops
      if (tclass == H5T_STRING_F .and. present(varstr)) then
        call h5tis_variable_str_f(dtype, isvar, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5tis_variable_str_f")
        varstr = isvar
      end if
    end block ops
    call close_ids(dset=dset, space=space, dtype=dtype)
  end subroutine inspect

  !> Dimensions of dataspace `space` [rank] and class of datatype `dtype` of the dataset or
  !> attribute `label` (shared by datasets and attributes).
  subroutine shape_and_class(this, space, dtype, op, label, d, tclass, error)
    class(h5file_t), intent(in) :: this
    integer(hid_t), intent(in) :: space, dtype
    character(len=*), intent(in) :: op, label
    integer(hsize_t), allocatable, intent(inout) :: d(:)
    integer, intent(out) :: tclass
    type(error_t), allocatable, intent(inout) :: error
    integer(hsize_t), allocatable :: maxd(:)
    integer :: hdferr, r
    tclass = -1
    call h5sget_simple_extent_ndims_f(space, r, hdferr)
    call check_h5(hdferr, this, error, op, label, "h5sget_simple_extent_ndims_f")
    if (allocated(error)) return
    if (allocated(d)) deallocate(d)
    allocate(d(r), maxd(r))
    if (r > 0) then
      call h5sget_simple_extent_dims_f(space, d, maxd, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5sget_simple_extent_dims_f")
      if (allocated(error)) return
    end if
    call h5tget_class_f(dtype, tclass, hdferr)
    call check_h5(hdferr, this, error, op, label, "h5tget_class_f")
  end subroutine shape_and_class

  !> inspect + check rank (-1: scalar or one element) and type class
  subroutine query(this, name, op, rank_expected, class_expected, d, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name, op
    integer, intent(in) :: rank_expected, class_expected
    integer(hsize_t), allocatable, intent(out) :: d(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: tclass
    integer(size_t) :: tsize
    call inspect(this, name, op, d, tclass, tsize, error)
    if (allocated(error)) return
    if (tclass /= class_expected) then
      call fail(this, error, op, name, "expected a " // class_name(class_expected) // &
        " dataset, found " // class_name(tclass), d); return
    end if
    if (rank_expected < 0) then
      if (product(d) /= 1) call fail(this, error, op, name, "expected a scalar", d)
    else if (size(d) /= rank_expected) then
      call fail(this, error, op, name, "expected rank " // str(rank_expected) // ", found rank " &
        // str(size(d)), d)
    end if
  end subroutine query

  !> Dimensions of a dataset, Fortran order (h5py shows them reversed). Empty for a scalar.
  subroutine get_dims(this, name, dims, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    integer(i8), allocatable, intent(out) :: dims(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    integer :: tclass
    integer(size_t) :: tsize
    call inspect(this, name, "get_dims", d, tclass, tsize, error)
    dims = int(d, i8)
  end subroutine get_dims

  ! ------------------------------------------------------------------ dataset creation

  !> Create a dataset with dims d (may replace/reuse an existing one), optional chunking.
  !> Returns the open dataset id.
  subroutine create_raw(this, name, op, ftype, tclass, d, dset, error, maxd, chunk)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name, op
    integer(hid_t), intent(in) :: ftype
    integer, intent(in) :: tclass
    integer(hsize_t), intent(in) :: d(:)
    integer(hid_t), intent(out) :: dset
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), intent(in), optional :: maxd(:), chunk(:)
    integer(hsize_t), allocatable :: old(:)
    integer(hid_t) :: space, dcpl
    integer(size_t) :: tsize, fsize
    integer :: hdferr, oclass
    logical :: reuse
    dset = -1; space = -1; dcpl = -1
    reuse = .false.
    ops: block
      if (this%exists(name)) then
        call inspect(this, name, op, old, oclass, tsize, error)
        if (allocated(error)) exit ops
        call h5tget_size_f(ftype, fsize, hdferr)
        reuse = .not. present(maxd) .and. oclass == tclass .and. tsize == fsize
        if (reuse) reuse = size(old) == size(d)
        if (reuse) reuse = all(old == d)
        if (.not. reuse) then
          call h5ldelete_f(this%fid, name, hdferr)
          call check_h5(hdferr, this, error, op, name, "h5ldelete_f (replacing)", d)
          if (allocated(error)) exit ops
        end if
      end if
      if (reuse) then
        call h5dopen_f(this%fid, name, dset, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5dopen_f", d)
        exit ops
      end if
      if (size(d) == 0) then
        call h5screate_f(H5S_SCALAR_F, space, hdferr)
      else if (present(maxd)) then
        call h5screate_simple_f(size(d), d, space, hdferr, maxd)
      else
        call h5screate_simple_f(size(d), d, space, hdferr)
      end if
      call check_h5(hdferr, this, error, op, name, "h5screate_simple_f", d)
      if (allocated(error)) exit ops
      if (present(chunk)) then
        call h5pcreate_f(H5P_DATASET_CREATE_F, dcpl, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5pcreate_f", d)
        if (allocated(error)) exit ops
        call h5pset_chunk_f(dcpl, size(chunk), chunk, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5pset_chunk_f (chunk " // &
          dims_str(chunk) // ")", d)
        if (allocated(error)) exit ops
        call h5dcreate_f(this%fid, name, ftype, space, dset, hdferr, dcpl_id=dcpl, &
          lcpl_id=this%lcpl)
      else
        call h5dcreate_f(this%fid, name, ftype, space, dset, hdferr, lcpl_id=this%lcpl)
      end if
      call check_h5(hdferr, this, error, op, name, "h5dcreate_f", d)
    end block ops
    call close_ids(space=space, ptype=dcpl)
    if (allocated(error) .and. dset >= 0) call close_ids(dset=dset)
  end subroutine create_raw

  !> Create (collectively) a fixed-size dataset to be filled with write_block.
  subroutine create_dataset(this, name, global_dims, kind, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    !> global dims, Fortran order, e.g. [n_rows, n_cols_global]
    integer, intent(in) :: global_dims(:)
    !> cr_h5_real, cr_h5_int or cr_h5_int64
    integer, intent(in) :: kind
    type(error_t), allocatable, intent(out) :: error
    integer(hid_t) :: dset
    character(len=*), parameter :: op = "create_dataset"
    call need_open(this, error, op, name, .true.)
    if (.not. allocated(error)) call ensure_space(this, 8_i8 * product(int(global_dims, i8)), op, name, error)
    if (.not. allocated(error)) then
      if (type_of(kind) < 0) then
        call fail(this, error, op, name, "unknown kind code " // str(kind))
      else
        call create_raw(this, name, op, type_of(kind), class_of(kind), &
          int(global_dims, hsize_t), dset, error)
        if (.not. allocated(error)) call close_ids(dset=dset)
      end if
    end if
    call sync_error(this, error)
  end subroutine create_dataset

  !> Serial handle only: create a contiguous dataset whose storage is allocated now (no fill
  !> values written) and return the byte offset of its first element in the file, so that the
  !> ranks of a parallel writer can fill their blocks with plain block writes (cr_fsys's
  !> block_file_t): elements in Fortran order, native byte order.
  subroutine create_placed(this, name, global_dims, kind, offset, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    !> global dims, Fortran order
    integer, intent(in) :: global_dims(:)
    !> cr_h5_real, cr_h5_int or cr_h5_int64
    integer, intent(in) :: kind
    !> byte offset of the data in the file (-1 for an empty dataset: nothing to write)
    integer(i8), intent(out) :: offset
    type(error_t), allocatable, intent(out) :: error
    integer(hid_t) :: dset, space, dcpl
    integer(hsize_t) :: d(size(global_dims)), off
    integer :: hdferr
    character(len=*), parameter :: op = "create_placed"
    offset = -1
    dset = -1; space = -1; dcpl = -1
    call need_open(this, error, op, name, .true.)
    if (allocated(error)) return
    if (this%parallel) then
      call fail(this, error, op, name, "needs a serial handle"); return
    end if
    if (type_of(kind) < 0) then
      call fail(this, error, op, name, "unknown kind code " // str(kind)); return
    end if
    d = int(global_dims, hsize_t)
    call ensure_space(this, 8_i8 * product(int(global_dims, i8)), op, name, error)
    if (allocated(error)) return
    ops: block
      call h5screate_simple_f(size(d), d, space, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5screate_simple_f", d)
      if (allocated(error)) exit ops
      call h5pcreate_f(H5P_DATASET_CREATE_F, dcpl, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5pcreate_f", d)
      if (allocated(error)) exit ops
      call h5pset_alloc_time_f(dcpl, H5D_ALLOC_TIME_EARLY_F, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5pset_alloc_time_f", d)
      if (allocated(error)) exit ops
      call h5pset_fill_time_f(dcpl, H5D_FILL_TIME_NEVER_F, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5pset_fill_time_f", d)
      if (allocated(error)) exit ops
      call h5dcreate_f(this%fid, name, type_of(kind), space, dset, hdferr, dcpl_id=dcpl, lcpl_id=this%lcpl)
      call check_h5(hdferr, this, error, op, name, "h5dcreate_f", d)
      if (allocated(error)) exit ops
      if (product(d) > 0) then
        call h5dget_offset_f(dset, off, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5dget_offset_f", d)
        if (allocated(error)) exit ops
        offset = int(off, i8)
      end if
    end block ops
    call close_ids(dset=dset, space=space, ptype=dcpl)
  end subroutine create_placed

  !> Create (collectively) a chunked dataset [row_shape..., 0] with an unlimited last dimension,
  !> grown by `append`. row_shape may be empty (1D stream, e.g. contact lists).
  subroutine create_extendible(this, name, row_shape, kind, error, chunk)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer, intent(in) :: row_shape(:)
    !> cr_h5_real, cr_h5_int or cr_h5_int64
    integer, intent(in) :: kind
    type(error_t), allocatable, intent(out) :: error
    !> chunk length along the last dimension (default: about 8192 elements per chunk)
    integer, intent(in), optional :: chunk
    integer(hsize_t) :: d(size(row_shape) + 1), maxd(size(row_shape) + 1), ch(size(row_shape) + 1)
    integer(hid_t) :: dset
    integer :: r, nrow
    character(len=*), parameter :: op = "create_extendible"
    call need_open(this, error, op, name, .true.)
    if (.not. allocated(error)) call ensure_space(this, 0_i8, op, name, error)
    if (.not. allocated(error)) then
      r = size(row_shape) + 1
      nrow = max(1, product(row_shape))
      d(1:r-1) = int(row_shape, hsize_t)
      d(r) = 0
      maxd = d
      maxd(r) = H5S_UNLIMITED_F
      ch = max(1_hsize_t, d)
      ch(r) = int(max(1, 8192 / nrow), hsize_t)
      if (present(chunk)) ch(r) = int(max(1, chunk), hsize_t)
      if (type_of(kind) < 0) then
        call fail(this, error, op, name, "unknown kind code " // str(kind))
      else if (any(row_shape < 1)) then
        call fail(this, error, op, name, "row_shape must be positive", d)
      else
        call create_raw(this, name, op, type_of(kind), class_of(kind), d, dset, error, &
          maxd=maxd, chunk=ch)
        if (.not. allocated(error)) call close_ids(dset=dset)
      end if
    end if
    call sync_error(this, error)
  end subroutine create_extendible

  ! ------------------------------------------------------------------ whole datasets

  !> Create/overwrite dataset `name` with dims d and write it (rank 0 only in parallel).
  subroutine write_raw(this, name, p, mtype, tclass, d, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    type(c_ptr), intent(in) :: p
    integer(hid_t), intent(in) :: mtype
    integer, intent(in) :: tclass
    integer(hsize_t), intent(in) :: d(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hid_t) :: dset
    integer :: hdferr
    character(len=*), parameter :: op = "write"
    dset = -1
    call need_open(this, error, op, name, .true.)
    if (.not. allocated(error)) call ensure_space(this, 8_i8 * product(int(d, i8)), op, name, error)
    if (.not. allocated(error)) then
      call create_raw(this, name, op, mtype, tclass, d, dset, error)
      if (.not. allocated(error) .and. (.not. this%parallel .or. this%rank == 0) &
        .and. c_associated(p)) then
        call h5dwrite_f(dset, mtype, p, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5dwrite_f", d)
      end if
    end if
    call close_ids(dset=dset)
    call sync_error(this, error)
  end subroutine write_raw

  !> Read a whole dataset into p (memory type mtype); caller has checked dims.
  subroutine read_raw(this, name, p, mtype, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    type(c_ptr), intent(in) :: p
    integer(hid_t), intent(in) :: mtype
    type(error_t), allocatable, intent(out) :: error
    integer(hid_t) :: dset
    integer :: hdferr
    type(c_ptr) :: pp
    pp = p
    call h5dopen_f(this%fid, name, dset, hdferr)
    call check_h5(hdferr, this, error, "read", name, "h5dopen_f")
    if (allocated(error)) return
    call h5dread_f(dset, mtype, pp, hdferr)
    call check_h5(hdferr, this, error, "read", name, "h5dread_f")
    call close_ids(dset=dset)
  end subroutine read_raw

  !> p, or a null pointer for an empty buffer. (The assumed-rank wrappers pass the extents as
  !> max(shape(x), 0): gfortran 12 reports -1 for a zero-size assumed-shape actual copied into a
  !> contiguous assumed-rank dummy.)
  function cptr_of_size(p, n) result(q)
    type(c_ptr), intent(in) :: p
    integer, intent(in) :: n
    type(c_ptr) :: q
    q = c_null_ptr
    if (n > 0) q = p
  end function cptr_of_size

  !> Write a real(wp) dataset of any rank (a scalar: a scalar dataset).
  subroutine w_real(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    real(wp), intent(in), target, contiguous :: x(..)
    type(error_t), allocatable, intent(out) :: error
    call write_raw(this, name, cptr_of_size(c_loc(x), product(max(shape(x), 0))), type_of(cr_h5_real), H5T_FLOAT_F, &
      int(max(shape(x), 0), hsize_t), error)
  end subroutine w_real

  !> Write an integer dataset of any rank (a scalar: a scalar dataset).
  subroutine w_int(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer, intent(in), target, contiguous :: x(..)
    type(error_t), allocatable, intent(out) :: error
    call write_raw(this, name, cptr_of_size(c_loc(x), product(max(shape(x), 0))), type_of(cr_h5_int), H5T_INTEGER_F, &
      int(max(shape(x), 0), hsize_t), error)
  end subroutine w_int

  !> Write an integer(int64) dataset [n].
  subroutine w_int64_1(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer(i8), intent(in), target, contiguous :: x(:)
    type(error_t), allocatable, intent(out) :: error
    type(c_ptr) :: p
    p = c_null_ptr
    if (size(x) > 0) p = c_loc(x)
    call write_raw(this, name, p, type_of(cr_h5_int64), H5T_INTEGER_F, &
      int(shape(x), hsize_t), error)
  end subroutine w_int64_1

  !> Write a scalar fixed-length string dataset (e.g. the config echo).
  subroutine w_string(this, name, s, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    character(len=*), intent(in) :: s
    type(error_t), allocatable, intent(out) :: error
    character(kind=c_char), allocatable, target :: buf(:)
    integer(hid_t) :: stype
    integer :: hdferr
    call to_cbuf(s, buf)
    call string_type(size(buf), stype, hdferr)
    if (hdferr < 0) then
      call fail(this, error, "write", name, "string type creation failed")
    else
      call write_raw(this, name, c_loc(buf), stype, H5T_STRING_F, [integer(hsize_t) ::], error)
    end if
    call close_ids(dtype=stype)
  end subroutine w_string

  !> Read a real(wp) scalar dataset.
  subroutine r_real0(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    real(wp), intent(out), target :: x
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", -1, H5T_FLOAT_F, d, error)
    if (allocated(error)) return
    call read_raw(this, name, c_loc(x), type_of(cr_h5_real), error)
  end subroutine r_real0

  !> Read a real(wp) dataset [n] (allocated here).
  subroutine r_real1(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    real(wp), allocatable, intent(out), target :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", 1, H5T_FLOAT_F, d, error)
    if (allocated(error)) return
    allocate(x(d(1)))
    if (size(x) > 0) call read_raw(this, name, c_loc(x), type_of(cr_h5_real), error)
  end subroutine r_real1

  !> Read a real(wp) dataset [n1, n2] (allocated here).
  subroutine r_real2(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    real(wp), allocatable, intent(out), target :: x(:,:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", 2, H5T_FLOAT_F, d, error)
    if (allocated(error)) return
    allocate(x(d(1), d(2)))
    if (size(x) > 0) call read_raw(this, name, c_loc(x), type_of(cr_h5_real), error)
  end subroutine r_real2

  !> Read a real(wp) dataset [n1, n2, n3] (allocated here).
  subroutine r_real3(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    real(wp), allocatable, intent(out), target :: x(:,:,:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", 3, H5T_FLOAT_F, d, error)
    if (allocated(error)) return
    allocate(x(d(1), d(2), d(3)))
    if (size(x) > 0) call read_raw(this, name, c_loc(x), type_of(cr_h5_real), error)
  end subroutine r_real3

  !> Read an integer scalar dataset.
  subroutine r_int0(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    integer, intent(out), target :: x
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", -1, H5T_INTEGER_F, d, error)
    if (allocated(error)) return
    call read_raw(this, name, c_loc(x), type_of(cr_h5_int), error)
  end subroutine r_int0

  !> Read an integer dataset [n] (allocated here).
  subroutine r_int1(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    integer, allocatable, intent(out), target :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", 1, H5T_INTEGER_F, d, error)
    if (allocated(error)) return
    allocate(x(d(1)))
    if (size(x) > 0) call read_raw(this, name, c_loc(x), type_of(cr_h5_int), error)
  end subroutine r_int1

  !> Read an integer dataset [n1, n2] (allocated here).
  subroutine r_int2(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    integer, allocatable, intent(out), target :: x(:,:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", 2, H5T_INTEGER_F, d, error)
    if (allocated(error)) return
    allocate(x(d(1), d(2)))
    if (size(x) > 0) call read_raw(this, name, c_loc(x), type_of(cr_h5_int), error)
  end subroutine r_int2

  !> Read an integer dataset [n1, n2, n3] (allocated here).
  subroutine r_int3(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    integer, allocatable, intent(out), target :: x(:,:,:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", 3, H5T_INTEGER_F, d, error)
    if (allocated(error)) return
    allocate(x(d(1), d(2), d(3)))
    if (size(x) > 0) call read_raw(this, name, c_loc(x), type_of(cr_h5_int), error)
  end subroutine r_int3

  !> Read an integer(int64) dataset [n] (allocated here).
  subroutine r_int64_1(this, name, x, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    integer(i8), allocatable, intent(out), target :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call query(this, name, "read", 1, H5T_INTEGER_F, d, error)
    if (allocated(error)) return
    allocate(x(d(1)))
    if (size(x) > 0) call read_raw(this, name, c_loc(x), type_of(cr_h5_int64), error)
  end subroutine r_int64_1

  !> Read a scalar fixed-length string dataset (trailing NULs removed).
  subroutine r_string(this, name, s, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: name
    character(len=:), allocatable, intent(out) :: s
    type(error_t), allocatable, intent(out) :: error
    character(kind=c_char), allocatable, target :: buf(:)
    integer(hsize_t), allocatable :: d(:)
    integer(hid_t) :: stype
    integer(size_t) :: tsize
    integer :: tclass, hdferr
    logical :: isvar
    call inspect(this, name, "read", d, tclass, tsize, error, varstr=isvar)
    if (allocated(error)) return
    if (tclass /= H5T_STRING_F .or. isvar .or. size(d) /= 0) then
      call fail(this, error, "read", name, "expected a scalar fixed-length string, found " // &
        class_name(tclass), d); return
    end if
    allocate(buf(tsize))
    call string_type(int(tsize), stype, hdferr)
    call check_h5(hdferr, this, error, "read", name, "h5tcopy_f")
    if (.not. allocated(error)) call read_raw(this, name, c_loc(buf), stype, error)
    call close_ids(dtype=stype)
    if (.not. allocated(error)) s = from_cbuf(buf)
  end subroutine r_string

  ! ------------------------------------------------------------------ extendible datasets

  !> Append a block with dims dd along the last dimension of an extendible dataset.
  !> dd of the dataset's rank: a block; one less: a single new element/column.
  subroutine append_raw(this, name, p, mtype, tclass, dd, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    type(c_ptr), intent(in) :: p
    integer(hid_t), intent(in) :: mtype
    integer, intent(in) :: tclass
    integer(hsize_t), intent(in) :: dd(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:), md(:), newd(:), start(:)
    integer(hid_t) :: dset, fspace, mspace
    integer :: hdferr, r
    character(len=*), parameter :: op = "append"
    dset = -1; fspace = -1; mspace = -1
    ops: block
      call need_open(this, error, op, name, .true.)
      if (allocated(error)) exit ops
      call ensure_space(this, 8_i8 * product(int(dd, i8)), op, name, error)
      if (allocated(error)) exit ops
      call query(this, name, op, size(dd), tclass, d, error)
      if (allocated(error)) then
        if (size(d) /= size(dd) + 1) exit ops
        deallocate(error)
        call query(this, name, op, size(dd) + 1, tclass, d, error)
        if (allocated(error)) exit ops
      end if
      r = size(d)
      if (size(dd) == r) then
        md = dd
      else
        md = [dd, 1_hsize_t]
      end if
      if (r > 1) then
        if (any(md(1:r-1) /= d(1:r-1))) then
          call fail(this, error, op, name, "row shape mismatch: data dims " // dims_str(md), d)
          exit ops
        end if
      end if
      if (md(r) == 0) exit ops
      newd = d
      newd(r) = d(r) + md(r)
      call h5dopen_f(this%fid, name, dset, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5dopen_f", d)
      if (allocated(error)) exit ops
      call h5dset_extent_f(dset, newd, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5dset_extent_f (not extendible?)", newd)
      if (allocated(error)) exit ops
      call h5dget_space_f(dset, fspace, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5dget_space_f", newd)
      if (allocated(error)) exit ops
      allocate(start(r))
      start = 0
      start(r) = d(r)
      call h5sselect_hyperslab_f(fspace, H5S_SELECT_SET_F, start, md, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5sselect_hyperslab_f", md)
      if (allocated(error)) exit ops
      call h5screate_simple_f(r, md, mspace, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5screate_simple_f", md)
      if (allocated(error)) exit ops
      if (.not. this%parallel .or. this%rank == 0) then
        call h5dwrite_f(dset, mtype, p, hdferr, mem_space_id=mspace, file_space_id=fspace)
        call check_h5(hdferr, this, error, op, name, "h5dwrite_f", md)
      end if
    end block ops
    call close_ids(dset=dset, space=fspace, mspace=mspace)
    call sync_error(this, error)
  end subroutine append_raw

  !> Append one real(wp) element to a 1D extendible dataset.
  subroutine a_real0(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    real(wp), intent(in), target :: x
    type(error_t), allocatable, intent(out) :: error
    call append_raw(this, name, c_loc(x), type_of(cr_h5_real), H5T_FLOAT_F, &
      [integer(hsize_t) ::], error)
  end subroutine a_real0

  !> Append x [k]: one column of a [k, *] dataset, or k elements of a 1D dataset.
  subroutine a_real1(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    real(wp), intent(in), target, contiguous :: x(:)
    type(error_t), allocatable, intent(out) :: error
    call append_raw(this, name, cptr_of_size(c_loc(x), size(x)), type_of(cr_h5_real), &
      H5T_FLOAT_F, int(shape(x), hsize_t), error)
  end subroutine a_real1

  !> Append x [k, m]: m columns of a [k, *] dataset.
  subroutine a_real2(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    real(wp), intent(in), target, contiguous :: x(:,:)
    type(error_t), allocatable, intent(out) :: error
    call append_raw(this, name, cptr_of_size(c_loc(x), size(x)), type_of(cr_h5_real), &
      H5T_FLOAT_F, int(shape(x), hsize_t), error)
  end subroutine a_real2

  !> Append one integer element to a 1D extendible dataset.
  subroutine a_int0(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer, intent(in), target :: x
    type(error_t), allocatable, intent(out) :: error
    call append_raw(this, name, c_loc(x), type_of(cr_h5_int), H5T_INTEGER_F, &
      [integer(hsize_t) ::], error)
  end subroutine a_int0

  !> Append integer x [k]: one column of a [k, *] dataset, or k elements of a 1D dataset.
  subroutine a_int1(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer, intent(in), target, contiguous :: x(:)
    type(error_t), allocatable, intent(out) :: error
    call append_raw(this, name, cptr_of_size(c_loc(x), size(x)), type_of(cr_h5_int), &
      H5T_INTEGER_F, int(shape(x), hsize_t), error)
  end subroutine a_int1

  !> Append integer x [k, m]: m columns of a [k, *] dataset.
  subroutine a_int2(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer, intent(in), target, contiguous :: x(:,:)
    type(error_t), allocatable, intent(out) :: error
    call append_raw(this, name, cptr_of_size(c_loc(x), size(x)), type_of(cr_h5_int), &
      H5T_INTEGER_F, int(shape(x), hsize_t), error)
  end subroutine a_int2

  !> Append one integer(int64) element to a 1D extendible dataset (e.g. contact offsets).
  subroutine a_int64_0(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer(i8), intent(in), target :: x
    type(error_t), allocatable, intent(out) :: error
    call append_raw(this, name, c_loc(x), type_of(cr_h5_int64), H5T_INTEGER_F, &
      [integer(hsize_t) ::], error)
  end subroutine a_int64_0

  !> Append integer(int64) x [k] (column of [k, *] or k elements of a 1D dataset).
  subroutine a_int64_1(this, name, x, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer(i8), intent(in), target, contiguous :: x(:)
    type(error_t), allocatable, intent(out) :: error
    call append_raw(this, name, cptr_of_size(c_loc(x), size(x)), type_of(cr_h5_int64), &
      H5T_INTEGER_F, int(shape(x), hsize_t), error)
  end subroutine a_int64_1

  ! ------------------------------------------------------------------ hyperslab blocks

  !> Collective write/read of the block dd at offset (0-based) along the last dimension.
  subroutine block_raw(this, name, p, mtype, tclass, dd, offset, is_write, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    type(c_ptr), intent(in) :: p
    integer(hid_t), intent(in) :: mtype
    integer, intent(in) :: tclass
    integer(hsize_t), intent(in) :: dd(:)
    integer, intent(in) :: offset
    logical, intent(in) :: is_write
    type(error_t), allocatable, intent(out) :: error
    integer :: rg(2, 1)
    rg(1, 1) = offset
    rg(2, 1) = int(dd(size(dd)))
    call ranges_raw(this, name, p, mtype, tclass, dd, rg, is_write, error)
  end subroutine block_raw

  !> Collective write/read of the block dd whose last dimension is the concatenation of the
  !> ranges (0-based offset, count) of the file's last dimension, in increasing order.
  subroutine ranges_raw(this, name, p, mtype, tclass, dd, ranges, is_write, error, independent)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    type(c_ptr), intent(in) :: p
    integer(hid_t), intent(in) :: mtype
    integer, intent(in) :: tclass
    integer(hsize_t), intent(in) :: dd(:)
    !> (offset, count) of each range along the last dimension [2, n_ranges]
    integer, intent(in) :: ranges(:,:)
    logical, intent(in) :: is_write
    type(error_t), allocatable, intent(out) :: error
    !> independent MPI-IO transfer instead of collective (the call stays collective)
    logical, intent(in), optional :: independent
    integer(hsize_t), allocatable :: d(:), start(:), cnt(:)
    integer(hid_t) :: dset, fspace, mspace, xfer
    integer(i8), target :: dummy(1)
    type(c_ptr) :: pp
    integer :: hdferr, r, q, sel
    integer(i8) :: total, last
    character(len=:), allocatable :: op
    dset = -1; fspace = -1; mspace = -1; xfer = -1
    op = "read_block"
    if (is_write) op = "write_block"
    ! validation, made collective before any collective transfer
    call need_open(this, error, op, name, is_write)
    if (.not. allocated(error)) call query(this, name, op, size(dd), tclass, d, error)
    if (.not. allocated(error)) then
      r = size(d)
      total = 0; last = 0
      do q = 1, size(ranges, 2)
        if (ranges(1, q) < last .or. ranges(2, q) < 0 .or. int(ranges(1, q), hsize_t) + ranges(2, q) > d(r)) then
          call fail(this, error, op, name, "range " // str(ranges(1, q) + 1) // ".." // &
            str(ranges(1, q) + ranges(2, q)) // " of the last dimension is out of bounds or out of order", d)
          exit
        end if
        total = total + ranges(2, q)
        last = int(ranges(1, q), i8) + ranges(2, q)
      end do
      if (allocated(error)) then
        continue
      else if (total /= int(dd(r), i8)) then
        call fail(this, error, op, name, "the ranges hold " // str(total) // " entries of the last dimension, " // &
          "the data " // str(int(dd(r), i8)), d)
      else if (dd(r) > 0 .and. r > 1) then
        if (any(dd(1:r-1) /= d(1:r-1))) call fail(this, error, op, name, &
          "leading dims mismatch: data dims " // dims_str(dd), d)
      end if
    end if
    call sync_error(this, error)
    if (allocated(error)) return
    ! an empty dataset (the same dims on every rank: file metadata) has nothing to transfer, and
    ! a collective MPI-IO transfer on it fails (e.g. a study without contacts at 2 ranks)
    if (product(d) == 0) return
    if (is_write) then
      call ensure_space(this, 8_i8 * product(int(dd, i8)), op, name, error)
      if (allocated(error)) return
    end if
    ops: block
      call h5dopen_f(this%fid, name, dset, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5dopen_f", d)
      if (allocated(error)) exit ops
      call h5dget_space_f(dset, fspace, hdferr)
      call check_h5(hdferr, this, error, op, name, "h5dget_space_f", d)
      if (allocated(error)) exit ops
      if (product(dd) > 0) then
        allocate(start(r), cnt(r))
        start = 0
        cnt = dd
        sel = H5S_SELECT_SET_F
        do q = 1, size(ranges, 2)
          if (ranges(2, q) == 0) cycle
          start(r) = int(ranges(1, q), hsize_t)
          cnt(r) = int(ranges(2, q), hsize_t)
          call h5sselect_hyperslab_f(fspace, sel, start, cnt, hdferr)
          call check_h5(hdferr, this, error, op, name, "h5sselect_hyperslab_f", cnt)
          if (allocated(error)) exit ops
          sel = H5S_SELECT_OR_F
        end do
        call h5screate_simple_f(r, dd, mspace, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5screate_simple_f", dd)
        if (allocated(error)) exit ops
        pp = p
      else
        call h5sselect_none_f(fspace, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5sselect_none_f", d)
        if (allocated(error)) exit ops
        call h5screate_simple_f(1, [1_hsize_t], mspace, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5screate_simple_f", d)
        if (allocated(error)) exit ops
        call h5sselect_none_f(mspace, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5sselect_none_f", d)
        if (allocated(error)) exit ops
        pp = c_loc(dummy)
      end if
      xfer = H5P_DEFAULT_F
      if (this%parallel) then
        call h5pcreate_f(H5P_DATASET_XFER_F, xfer, hdferr)
        call check_h5(hdferr, this, error, op, name, "h5pcreate_f", d)
        if (allocated(error)) exit ops
        if (present(independent)) then
          if (independent) then
            call h5pset_dxpl_mpio_f(xfer, H5FD_MPIO_INDEPENDENT_F, hdferr)
          else
            call h5pset_dxpl_mpio_f(xfer, H5FD_MPIO_COLLECTIVE_F, hdferr)
          end if
        else
          call h5pset_dxpl_mpio_f(xfer, H5FD_MPIO_COLLECTIVE_F, hdferr)
        end if
        call check_h5(hdferr, this, error, op, name, "h5pset_dxpl_mpio_f", d)
        if (allocated(error)) exit ops
      end if
      if (is_write) then
        call h5dwrite_f(dset, mtype, pp, hdferr, mem_space_id=mspace, file_space_id=fspace, &
          xfer_prp=xfer)
        call check_h5(hdferr, this, error, op, name, "h5dwrite_f", dd)
      else
        call h5dread_f(dset, mtype, pp, hdferr, mem_space_id=mspace, file_space_id=fspace, &
          xfer_prp=xfer)
        call check_h5(hdferr, this, error, op, name, "h5dread_f", dd)
      end if
    end block ops
    if (xfer == H5P_DEFAULT_F) xfer = -1
    call close_ids(dset=dset, space=fspace, mspace=mspace, ptype=xfer)
    call sync_error(this, error)
  end subroutine ranges_raw

  !> Collective: write this rank's elements offset+1..offset+size(x) of a 1D dataset.
  subroutine wb_real(this, name, x, offset, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    !> local part, distributed over ranks: [n_local] of a 1D dataset, or columns
    !> [n_rows, n_cols_local] of a [n_rows, n_cols] dataset (n_cols_local may be 0)
    real(wp), intent(in), target, contiguous :: x(..)
    !> number of elements (1D) or columns (2D) before this rank's part (0-based offset)
    integer, intent(in) :: offset
    type(error_t), allocatable, intent(out) :: error
    call block_raw(this, name, cptr_of_size(c_loc(x), product(max(shape(x), 0))), type_of(cr_h5_real), &
      H5T_FLOAT_F, int(max(shape(x), 0), hsize_t), offset, .true., error)
  end subroutine wb_real

  !> Collective: integer version of wb_real.
  subroutine wb_int(this, name, x, offset, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer, intent(in), target, contiguous :: x(..)
    integer, intent(in) :: offset
    type(error_t), allocatable, intent(out) :: error
    call block_raw(this, name, cptr_of_size(c_loc(x), product(max(shape(x), 0))), type_of(cr_h5_int), &
      H5T_INTEGER_F, int(max(shape(x), 0), hsize_t), offset, .true., error)
  end subroutine wb_int

  !> Collective: read elements offset+1..offset+size(x) of a 1D dataset into x (caller-sized).
  subroutine rb_real(this, name, x, offset, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    !> [n_local] of a 1D dataset, or columns [n_rows, n_cols_local] (caller-sized)
    real(wp), intent(inout), target, contiguous :: x(..)
    integer, intent(in) :: offset
    type(error_t), allocatable, intent(out) :: error
    call block_raw(this, name, cptr_of_size(c_loc(x), product(max(shape(x), 0))), type_of(cr_h5_real), &
      H5T_FLOAT_F, int(max(shape(x), 0), hsize_t), offset, .false., error)
  end subroutine rb_real

  !> Collective: integer version of rb_real.
  subroutine rb_int(this, name, x, offset, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer, intent(inout), target, contiguous :: x(..)
    integer, intent(in) :: offset
    type(error_t), allocatable, intent(out) :: error
    call block_raw(this, name, cptr_of_size(c_loc(x), product(max(shape(x), 0))), type_of(cr_h5_int), &
      H5T_INTEGER_F, int(max(shape(x), 0), hsize_t), offset, .false., error)
  end subroutine rb_int

  !> Collective: int64 version of wb_real (1D).
  subroutine wb_int64_1(this, name, x, offset, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer(i8), intent(in), target, contiguous :: x(:)
    integer, intent(in) :: offset
    type(error_t), allocatable, intent(out) :: error
    call block_raw(this, name, cptr_of_size(c_loc(x), size(x)), type_of(cr_h5_int64), &
      H5T_INTEGER_F, int(shape(x), hsize_t), offset, .true., error)
  end subroutine wb_int64_1

  !> Collective: write this rank's ranges of the last dimension (ranges(:, q) = 0-based offset,
  !> count; increasing, disjoint), packed one after the other in x [n_local]. Ranks may own any
  !> set of ranges (the ranks' ranges must not overlap); a rank with none passes size(x) = 0.
  subroutine wr_real(this, name, x, ranges, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    !> [n_local] of a 1D dataset, or columns [n_rows, n_local] of a [n_rows, n_cols] dataset
    real(wp), intent(in), target, contiguous :: x(..)
    integer, intent(in) :: ranges(:,:)
    type(error_t), allocatable, intent(out) :: error
    call ranges_raw(this, name, cptr_of_size(c_loc(x), product(max(shape(x), 0))), type_of(cr_h5_real), &
      H5T_FLOAT_F, int(max(shape(x), 0), hsize_t), ranges, .true., error, independent=.true.)
  end subroutine wr_real

  !> Collective: integer version of wr_real.
  subroutine wr_int(this, name, x, ranges, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer, intent(in), target, contiguous :: x(..)
    integer, intent(in) :: ranges(:,:)
    type(error_t), allocatable, intent(out) :: error
    call ranges_raw(this, name, cptr_of_size(c_loc(x), product(max(shape(x), 0))), type_of(cr_h5_int), &
      H5T_INTEGER_F, int(max(shape(x), 0), hsize_t), ranges, .true., error, independent=.true.)
  end subroutine wr_int

  !> Collective: int64 version of wr_real (1D).
  subroutine wr_int64_1(this, name, x, ranges, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer(i8), intent(in), target, contiguous :: x(:)
    integer, intent(in) :: ranges(:,:)
    type(error_t), allocatable, intent(out) :: error
    call ranges_raw(this, name, cptr_of_size(c_loc(x), size(x)), type_of(cr_h5_int64), &
      H5T_INTEGER_F, int(shape(x), hsize_t), ranges, .true., error, independent=.true.)
  end subroutine wr_int64_1

  !> Collective: int64 version of rb_real (1D).
  subroutine rb_int64_1(this, name, x, offset, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: name
    integer(i8), intent(inout), target, contiguous :: x(:)
    integer, intent(in) :: offset
    type(error_t), allocatable, intent(out) :: error
    call block_raw(this, name, cptr_of_size(c_loc(x), size(x)), type_of(cr_h5_int64), &
      H5T_INTEGER_F, int(shape(x), hsize_t), offset, .false., error)
  end subroutine rb_int64_1

  ! ------------------------------------------------------------------ attributes

  function obj_path(obj) result(s)
    character(len=*), intent(in) :: obj
    character(len=:), allocatable :: s
    if (len_trim(obj) == 0) then
      s = "/"
    else
      s = trim(obj)
    end if
  end function obj_path

  !> Write (replace) attribute `name` on object `obj` ("" or "/" for the root group).
  subroutine attr_write_raw(this, obj, name, p, mtype, d, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: obj, name
    type(c_ptr), intent(in) :: p
    integer(hid_t), intent(in) :: mtype
    integer(hsize_t), intent(in) :: d(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hid_t) :: oid, aid, space
    integer :: hdferr, e
    logical :: ex
    character(len=:), allocatable :: label
    character(len=*), parameter :: op = "write_attr"
    oid = -1; aid = -1; space = -1
    label = obj_path(obj) // "@" // name
    ops: block
      call need_open(this, error, op, label, .true.)
      if (allocated(error)) exit ops
      call ensure_space(this, 8_i8 * product(int(d, i8)), op, label, error)
      if (allocated(error)) exit ops
      call h5oopen_f(this%fid, obj_path(obj), oid, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5oopen_f (no such object?)")
      if (allocated(error)) exit ops
      call h5aexists_f(oid, name, ex, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5aexists_f")
      if (allocated(error)) exit ops
      if (ex) then
        call h5adelete_f(oid, name, hdferr)
        call check_h5(hdferr, this, error, op, label, "h5adelete_f")
        if (allocated(error)) exit ops
      end if
      if (size(d) == 0) then
        call h5screate_f(H5S_SCALAR_F, space, hdferr)
      else
        call h5screate_simple_f(size(d), d, space, hdferr)
      end if
      call check_h5(hdferr, this, error, op, label, "h5screate_f", d)
      if (allocated(error)) exit ops
      call h5acreate_f(oid, name, mtype, space, aid, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5acreate_f", d)
      if (allocated(error)) exit ops
      if (c_associated(p)) then
        call h5awrite_f(aid, mtype, p, hdferr)
        call check_h5(hdferr, this, error, op, label, "h5awrite_f", d)
      end if
    end block ops
    if (aid >= 0) call h5aclose_f(aid, e)
    call close_ids(space=space)
    if (oid >= 0) call h5oclose_f(oid, e)
    call sync_error(this, error)
  end subroutine attr_write_raw

  !> Read attribute `name` of `obj` into p after checking class and dims (expected_rank -1:
  !> scalar). For strings (mtype < 0) a fixed-length buffer of the stored size is read into
  !> sbuf. On success d holds the dims.
  subroutine attr_read_raw(this, obj, name, tclass_expected, rank_expected, d, error, p, &
      mtype, sbuf)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: obj, name
    integer, intent(in) :: tclass_expected, rank_expected
    integer(hsize_t), allocatable, intent(out) :: d(:)
    type(error_t), allocatable, intent(out) :: error
    type(c_ptr), intent(in), optional :: p
    integer(hid_t), intent(in), optional :: mtype
    character(kind=c_char), allocatable, target, intent(out), optional :: sbuf(:)
    integer(hid_t) :: oid, aid, space, atype, stype
    type(c_ptr) :: pp
    integer(size_t) :: tsize
    integer :: hdferr, e, r, tclass
    logical :: ex, isvar
    character(len=:), allocatable :: label
    character(len=*), parameter :: op = "read_attr"
    oid = -1; aid = -1; space = -1; atype = -1; stype = -1
    label = obj_path(obj) // "@" // name
    allocate(d(0))
    ops: block
      call need_open(this, error, op, label, .false.)
      if (allocated(error)) exit ops
      if (.not. this%exists(obj)) then
        call fail(this, error, op, label, "no such object"); exit ops
      end if
      call h5oopen_f(this%fid, obj_path(obj), oid, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5oopen_f")
      if (allocated(error)) exit ops
      call h5aexists_f(oid, name, ex, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5aexists_f")
      if (allocated(error)) exit ops
      if (.not. ex) then
        call fail(this, error, op, label, "no such attribute"); exit ops
      end if
      call h5aopen_f(oid, name, aid, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5aopen_f")
      if (allocated(error)) exit ops
      call h5aget_space_f(aid, space, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5aget_space_f")
      if (allocated(error)) exit ops
      call h5aget_type_f(aid, atype, hdferr)
      call check_h5(hdferr, this, error, op, label, "h5aget_type_f")
      if (allocated(error)) exit ops
      call shape_and_class(this, space, atype, op, label, d, tclass, error)
      if (allocated(error)) exit ops
      r = size(d)
      if (tclass /= tclass_expected) then
        call fail(this, error, op, label, "expected a " // class_name(tclass_expected) // &
          " attribute, found " // class_name(tclass), d); exit ops
      end if
      if (rank_expected < 0) then
        if (product(d) /= 1) then
          call fail(this, error, op, label, "expected a scalar", d); exit ops
        end if
      else if (r /= rank_expected) then
        call fail(this, error, op, label, "expected rank " // str(rank_expected), d); exit ops
      end if
      if (present(sbuf)) then
        call h5tis_variable_str_f(atype, isvar, hdferr)
        call check_h5(hdferr, this, error, op, label, "h5tis_variable_str_f")
        if (allocated(error)) exit ops
        if (isvar) then
          call fail(this, error, op, label, "variable-length strings are not supported")
          exit ops
        end if
        call h5tget_size_f(atype, tsize, hdferr)
        call check_h5(hdferr, this, error, op, label, "h5tget_size_f")
        if (allocated(error)) exit ops
        allocate(sbuf(tsize))
        call string_type(int(tsize), stype, hdferr)
        call check_h5(hdferr, this, error, op, label, "h5tcopy_f")
        if (allocated(error)) exit ops
        pp = c_loc(sbuf)
        call h5aread_f(aid, stype, pp, hdferr)
        call check_h5(hdferr, this, error, op, label, "h5aread_f")
      else if (present(p) .and. present(mtype)) then
        if (c_associated(p)) then
          pp = p
          call h5aread_f(aid, mtype, pp, hdferr)
          call check_h5(hdferr, this, error, op, label, "h5aread_f", d)
        end if
      end if
    end block ops
    call close_ids(dtype=atype)
    call close_ids(dtype=stype)
    if (aid >= 0) call h5aclose_f(aid, e)
    call close_ids(space=space)
    if (oid >= 0) call h5oclose_f(oid, e)
  end subroutine attr_read_raw

  !> Write a string attribute on obj ("" or "/" = root group).
  subroutine wa_string(this, obj, name, value, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: obj, name, value
    type(error_t), allocatable, intent(out) :: error
    character(kind=c_char), allocatable, target :: buf(:)
    integer(hid_t) :: stype
    integer :: hdferr
    call to_cbuf(value, buf)
    call string_type(size(buf), stype, hdferr)
    if (hdferr < 0) then
      call fail(this, error, "write_attr", name, "string type creation failed")
    else
      call attr_write_raw(this, obj, name, c_loc(buf), stype, [integer(hsize_t) ::], error)
    end if
    call close_ids(dtype=stype)
  end subroutine wa_string

  !> Write a real(wp) scalar attribute.
  subroutine wa_real(this, obj, name, value, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: obj, name
    real(wp), intent(in), target :: value
    type(error_t), allocatable, intent(out) :: error
    call attr_write_raw(this, obj, name, c_loc(value), type_of(cr_h5_real), &
      [integer(hsize_t) ::], error)
  end subroutine wa_real

  !> Write an integer scalar attribute.
  subroutine wa_int(this, obj, name, value, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: obj, name
    integer, intent(in), target :: value
    type(error_t), allocatable, intent(out) :: error
    call attr_write_raw(this, obj, name, c_loc(value), type_of(cr_h5_int), &
      [integer(hsize_t) ::], error)
  end subroutine wa_int

  !> Write a real(wp) array attribute [n] (n >= 1).
  subroutine wa_real1(this, obj, name, value, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: obj, name
    real(wp), intent(in), target, contiguous :: value(:)
    type(error_t), allocatable, intent(out) :: error
    if (size(value) == 0) then
      call fail(this, error, "write_attr", obj_path(obj) // "@" // name, &
        "empty array attributes are not supported")
      call sync_error(this, error)
      return
    end if
    call attr_write_raw(this, obj, name, c_loc(value), type_of(cr_h5_real), &
      int(shape(value), hsize_t), error)
  end subroutine wa_real1

  !> Write an integer array attribute [n] (n >= 1).
  subroutine wa_int1(this, obj, name, value, error)
    class(h5file_t), intent(inout) :: this
    character(len=*), intent(in) :: obj, name
    integer, intent(in), target, contiguous :: value(:)
    type(error_t), allocatable, intent(out) :: error
    if (size(value) == 0) then
      call fail(this, error, "write_attr", obj_path(obj) // "@" // name, &
        "empty array attributes are not supported")
      call sync_error(this, error)
      return
    end if
    call attr_write_raw(this, obj, name, c_loc(value), type_of(cr_h5_int), &
      int(shape(value), hsize_t), error)
  end subroutine wa_int1

  !> Read a fixed-length string attribute.
  subroutine ra_string(this, obj, name, value, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: obj, name
    character(len=:), allocatable, intent(out) :: value
    type(error_t), allocatable, intent(out) :: error
    character(kind=c_char), allocatable, target :: buf(:)
    integer(hsize_t), allocatable :: d(:)
    call attr_read_raw(this, obj, name, H5T_STRING_F, -1, d, error, sbuf=buf)
    if (allocated(error)) return
    value = from_cbuf(buf)
  end subroutine ra_string

  !> Read a real(wp) scalar attribute.
  subroutine ra_real(this, obj, name, value, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: obj, name
    real(wp), intent(out), target :: value
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call attr_read_raw(this, obj, name, H5T_FLOAT_F, -1, d, error, p=c_loc(value), &
      mtype=type_of(cr_h5_real))
  end subroutine ra_real

  !> Read an integer scalar attribute.
  subroutine ra_int(this, obj, name, value, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: obj, name
    integer, intent(out), target :: value
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call attr_read_raw(this, obj, name, H5T_INTEGER_F, -1, d, error, p=c_loc(value), &
      mtype=type_of(cr_h5_int))
  end subroutine ra_int

  !> Read a real(wp) array attribute [n] (allocated here).
  subroutine ra_real1(this, obj, name, value, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: obj, name
    real(wp), allocatable, intent(out), target :: value(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call attr_read_raw(this, obj, name, H5T_FLOAT_F, 1, d, error)
    if (allocated(error)) return
    allocate(value(d(1)))
    if (size(value) == 0) return
    call attr_read_raw(this, obj, name, H5T_FLOAT_F, 1, d, error, p=c_loc(value), &
      mtype=type_of(cr_h5_real))
  end subroutine ra_real1

  !> Read an integer array attribute [n] (allocated here).
  subroutine ra_int1(this, obj, name, value, error)
    class(h5file_t), intent(in) :: this
    character(len=*), intent(in) :: obj, name
    integer, allocatable, intent(out), target :: value(:)
    type(error_t), allocatable, intent(out) :: error
    integer(hsize_t), allocatable :: d(:)
    call attr_read_raw(this, obj, name, H5T_INTEGER_F, 1, d, error)
    if (allocated(error)) return
    allocate(value(d(1)))
    if (size(value) == 0) return
    call attr_read_raw(this, obj, name, H5T_INTEGER_F, 1, d, error, p=c_loc(value), &
      mtype=type_of(cr_h5_int))
  end subroutine ra_int1
end module cr_h5file
