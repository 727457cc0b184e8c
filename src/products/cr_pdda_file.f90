!> Trajectories in the Pedestrian Dynamics Data Archive HDF5 layout (the layout of the
!> Juelich pedestrian data archive, read by PedPy's load_trajectory_from_ped_data_archive_hdf5
!> and load_walkable_area_from_ped_data_archive_hdf5 in one call each):
!> - dataset `trajectory`: one row per agent and frame, a compound of id (int32, agents
!>   numbered from 1), frame (int32, from 0), x, y, z (float64, m; z = 0), with the attribute
!>   `fps` (frames per second, 1 / (h every));
!> - root attribute `wkt_geometry`: the walkable area as WKT, a POLYGON whose outer ring is the
!>   hall with, at every exit, the doorway through the wall and a strip outside it (2 m deep,
!>   up to 1 m wider than the opening on each side), and whose holes are the interior
!>   obstacles (a disk as the 32-gon inscribed in it, a segment capsule as the rectangle
!>   around its axis, a polygon as itself);
!> - root attributes `n_exits`, `exits` [4, n_exits] (x0, y0, x1, y1 of each opening) and
!>   `agent_radius`.
!> An agent is written from frame 0 up to one frame after the first frame at which it is out
!> of the hall (scene%is_out with the body radius), then removed: a measurement line at the
!> "has left" line sees every crossing (PedPy counts a crossing at frame f from the movement
!> f-1 -> f and takes no movement at an agent's last frame). The file is written under a temporary name and
!> renamed when complete (cr_h5file).
module cr_pdda_file
  use, intrinsic :: iso_c_binding, only: c_int, c_double, c_char, c_ptr, c_loc, c_null_char
  use hdf5, only: hid_t, hsize_t, size_t, H5T_COMPOUND_F, H5T_NATIVE_INTEGER, H5T_NATIVE_DOUBLE, &
    H5S_UNLIMITED_F, H5P_DATASET_CREATE_F, H5S_SELECT_SET_F, h5tcreate_f, h5tinsert_f, h5tclose_f, &
    h5screate_simple_f, h5sclose_f, h5pcreate_f, h5pset_chunk_f, h5pclose_f, h5dcreate_f, h5dclose_f, &
    h5dset_extent_f, h5dget_space_f, h5sselect_hyperslab_f, h5dwrite_f, H5T_C_S1, &
    H5S_SCALAR_F, h5tcopy_f, h5tset_size_f, h5screate_f, h5acreate_f, h5awrite_f, h5aclose_f
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_shapes, only: OBST_DISK, OBST_SEGMENT
  use cr_h5file, only: h5file_t
  implicit none
  private
  public :: pdda_writer_t, walkable_wkt, exit_segments

  !> one row of the `trajectory` dataset (C layout: 32 bytes)
  type, bind(c) :: pdda_row_t
    integer(c_int) :: id, frame
    real(c_double) :: x, y, z
  end type pdda_row_t

  !> the C library's H5T_VARIABLE (size of a variable-length string type), which the Fortran
  !> interface of HDF5 1.10 does not export
  integer(size_t), parameter :: H5T_VARIABLE = -1_size_t

  !> rows buffered before they are appended to the dataset
  integer, parameter :: BLOCK_ROWS = 65536

  !> Streaming writer: open, write_frame per frame, close (or abort).
  type :: pdda_writer_t
    type(h5file_t) :: h5
    integer(hid_t) :: dset = -1, rtype = -1
    integer(hsize_t) :: n_rows = 0
    integer :: nbuf = 0
    real(wp) :: radius = 0
    type(pdda_row_t), allocatable :: buf(:)
    !> frames each agent is still written after its first frame out (2 while inside) [n_agents]
    integer, allocatable :: left(:)
  contains
    procedure :: open => pdda_open
    procedure :: write_frame
    procedure :: close => pdda_close
    procedure :: abort => pdda_abort
  end type pdda_writer_t

contains

  !> Create `path` (temporary name) for n_agents agents of body radius `radius` in `scene`,
  !> frames every `frame_dt` seconds.
  subroutine pdda_open(this, path, scene, radius, n_agents, frame_dt, error)
    class(pdda_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: path
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, frame_dt
    integer, intent(in) :: n_agents
    type(error_t), allocatable, intent(out) :: error
    integer(hid_t) :: space, dcpl
    integer :: e(6)
    real(wp), allocatable :: ex(:,:)
    this%radius = radius
    this%n_rows = 0; this%nbuf = 0
    if (allocated(this%buf)) deallocate(this%buf)
    if (allocated(this%left)) deallocate(this%left)
    allocate(this%buf(BLOCK_ROWS), this%left(n_agents))
    this%left = 2
    call this%h5%create(path, error)
    if (allocated(error)) return
    call h5tcreate_f(H5T_COMPOUND_F, 32_size_t, this%rtype, e(1))
    if (e(1) == 0) then
      call h5tinsert_f(this%rtype, "id", 0_size_t, H5T_NATIVE_INTEGER, e(2))
      call h5tinsert_f(this%rtype, "frame", 4_size_t, H5T_NATIVE_INTEGER, e(3))
      call h5tinsert_f(this%rtype, "x", 8_size_t, H5T_NATIVE_DOUBLE, e(4))
      call h5tinsert_f(this%rtype, "y", 16_size_t, H5T_NATIVE_DOUBLE, e(5))
      call h5tinsert_f(this%rtype, "z", 24_size_t, H5T_NATIVE_DOUBLE, e(6))
    end if
    if (any(e /= 0)) then
      call fail("creating the compound type"); return
    end if
    call h5screate_simple_f(1, [0_hsize_t], space, e(1), maxdims=[H5S_UNLIMITED_F])
    call h5pcreate_f(H5P_DATASET_CREATE_F, dcpl, e(2))
    call h5pset_chunk_f(dcpl, 1, [int(BLOCK_ROWS, hsize_t)], e(3))
    call h5dcreate_f(this%h5%file_id(), "trajectory", this%rtype, space, this%dset, e(4), dcpl_id=dcpl)
    call h5pclose_f(dcpl, e(5))
    call h5sclose_f(space, e(6))
    if (any(e /= 0)) then
      call fail("creating dataset 'trajectory'"); return
    end if
    call this%h5%write_attr("trajectory", "fps", 1 / frame_dt, error); if (allocated(error)) goto 9
    ! a variable-length string, as the archive's files have it (readers get a str, not bytes)
    call write_vlen_attr(this%h5%file_id(), "wkt_geometry", walkable_wkt(scene), e(1))
    if (e(1) /= 0) then
      call fail("writing attribute 'wkt_geometry'"); return
    end if
    call exit_segments(scene, ex)
    call this%h5%write_attr("/", "n_exits", size(ex, 2), error); if (allocated(error)) goto 9
    call this%h5%write_attr("/", "exits", reshape(ex, [size(ex)]), error); if (allocated(error)) goto 9
    call this%h5%write_attr("/", "agent_radius", radius, error); if (allocated(error)) goto 9
    return
9   call prefix_error(error, "trajectory file (&output pdda_file)")
    call this%abort()
  contains
    subroutine fail(what)
      character(len=*), intent(in) :: what
      call set_error(error, "trajectory file (&output pdda_file) '" // path // "': " // what // " failed")
      call this%abort()
    end subroutine fail
  end subroutine pdda_open

  !> Root attribute `name` of `loc` holding `text` as a variable-length string; status in e.
  subroutine write_vlen_attr(loc, name, text, e)
    integer(hid_t), intent(in) :: loc
    character(len=*), intent(in) :: name, text
    integer, intent(out) :: e
    character(kind=c_char), allocatable, target :: buf(:)
    type(c_ptr), target :: ptr(1)
    integer(hid_t) :: atype, space, attr
    integer :: k, s(6)
    allocate(buf(len(text) + 1))
    do k = 1, len(text)
      buf(k) = text(k:k)
    end do
    buf(len(text) + 1) = c_null_char
    ptr(1) = c_loc(buf(1))
    s = 0
    call h5tcopy_f(H5T_C_S1, atype, s(1))
    call h5tset_size_f(atype, H5T_VARIABLE, s(2))
    call h5screate_f(H5S_SCALAR_F, space, s(3))
    call h5acreate_f(loc, name, atype, space, attr, s(4))
    if (all(s(1:4) == 0)) call h5awrite_f(attr, atype, c_loc(ptr), s(5))
    call h5aclose_f(attr, k); s(6) = k
    call h5sclose_f(space, k)
    call h5tclose_f(atype, k)
    e = maxval(abs(s))
  end subroutine write_vlen_attr

  !> Rows of frame `frame` at positions q [2*n_agents]: every agent inside, or out since this
  !> frame or the one before (see the module header).
  subroutine write_frame(this, scene, frame, q, error)
    class(pdda_writer_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    integer, intent(in) :: frame
    real(wp), intent(in) :: q(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: i
    do i = 1, size(this%left)
      if (this%left(i) == 2) then
        if (scene%is_out(q(2*i-1:2*i), this%radius)) this%left(i) = 1
      else
        this%left(i) = max(this%left(i) - 1, -1)
      end if
      if (this%left(i) < 0) cycle
      if (this%nbuf == size(this%buf)) then
        call flush_rows(this, error)
        if (allocated(error)) return
      end if
      this%nbuf = this%nbuf + 1
      this%buf(this%nbuf) = pdda_row_t(int(i, c_int), int(frame, c_int), q(2*i-1), q(2*i), 0.0_c_double)
    end do
  end subroutine write_frame

  !> Append the buffered rows to the dataset.
  subroutine flush_rows(this, error)
    type(pdda_writer_t), intent(inout), target :: this
    type(error_t), allocatable, intent(out) :: error
    integer(hid_t) :: fspace, mspace
    integer :: e(5)
    integer(hsize_t) :: n
    if (this%nbuf == 0) return
    n = int(this%nbuf, hsize_t)
    e = 0
    call h5dset_extent_f(this%dset, [this%n_rows + n], e(1))
    call h5dget_space_f(this%dset, fspace, e(2))
    call h5sselect_hyperslab_f(fspace, H5S_SELECT_SET_F, [this%n_rows], [n], e(3))
    call h5screate_simple_f(1, [n], mspace, e(4))
    call h5dwrite_f(this%dset, this%rtype, c_loc(this%buf(1)), e(5), mem_space_id=mspace, file_space_id=fspace)
    call h5sclose_f(mspace, e(4))
    call h5sclose_f(fspace, e(2))
    if (any(e /= 0)) then
      call set_error(error, "trajectory file (&output pdda_file): appending " // str(this%nbuf) // &
        " rows to 'trajectory' failed"); return
    end if
    this%n_rows = this%n_rows + n
    this%nbuf = 0
  end subroutine flush_rows

  !> Write the remaining rows and commit (rename to the final name).
  subroutine pdda_close(this, error)
    class(pdda_writer_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    integer :: e(2)
    call flush_rows(this, error)
    if (allocated(error)) then
      call this%abort(); return
    end if
    call h5dclose_f(this%dset, e(1)); this%dset = -1
    call h5tclose_f(this%rtype, e(2)); this%rtype = -1
    if (any(e /= 0)) then
      call set_error(error, "trajectory file (&output pdda_file): closing 'trajectory' failed")
      call this%abort(); return
    end if
    call this%h5%commit(error)
  end subroutine pdda_close

  !> Close and delete the temporary (a previous final file is untouched).
  subroutine pdda_abort(this)
    class(pdda_writer_t), intent(inout) :: this
    integer :: e
    if (this%dset >= 0) call h5dclose_f(this%dset, e)
    if (this%rtype >= 0) call h5tclose_f(this%rtype, e)
    this%dset = -1; this%rtype = -1
    call this%h5%abort()
  end subroutine pdda_abort

  !> Every exit opening of the scene as x0, y0, x1, y1 on the inner face of its wall [4, n_exits]:
  !> exit 1 in the top wall, exit 2 in the right wall when the scene has one.
  subroutine exit_segments(scene, ex)
    type(scene_t), intent(in) :: scene
    real(wp), allocatable, intent(out) :: ex(:,:)
    allocate(ex(4, merge(2, 1, scene%has_exit2())))
    ex(:, 1) = [scene%x_lo, scene%width, scene%x_hi, scene%width]
    if (scene%has_exit2()) ex(:, 2) = [scene%length, scene%y_lo2, scene%length, scene%y_hi2]
  end subroutine exit_segments

  !> The walkable area of `scene` as WKT (see the module header).
  function walkable_wkt(scene) result(wkt)
    type(scene_t), intent(in) :: scene
    character(len=:), allocatable :: wkt
    real(wp), parameter :: DEPTH = 2.0_wp, SIDE = 1.0_wp
    real(wp) :: L, H, t, wd, yo, xo
    integer :: k
    L = scene%length; H = scene%width; t = scene%wall
    wkt = "POLYGON ((" // pt(0.0_wp, 0.0_wp) // ", " // pt(L, 0.0_wp)
    if (scene%has_exit2()) then
      xo = L + t
      wd = max(0.0_wp, min(SIDE, scene%y_lo2 + t, H + t - scene%y_hi2))
      wkt = wkt // ", " // pt(L, scene%y_lo2) // ", " // pt(xo, scene%y_lo2) // ", " // &
        pt(xo, scene%y_lo2 - wd) // ", " // pt(xo + DEPTH, scene%y_lo2 - wd) // ", " // &
        pt(xo + DEPTH, scene%y_hi2 + wd) // ", " // pt(xo, scene%y_hi2 + wd) // ", " // &
        pt(xo, scene%y_hi2) // ", " // pt(L, scene%y_hi2)
    end if
    yo = H + t
    wd = max(0.0_wp, min(SIDE, scene%x_lo + t, L + t - scene%x_hi))
    wkt = wkt // ", " // pt(L, H) // ", " // pt(scene%x_hi, H) // ", " // pt(scene%x_hi, yo) // ", " // &
      pt(scene%x_hi + wd, yo) // ", " // pt(scene%x_hi + wd, yo + DEPTH) // ", " // &
      pt(scene%x_lo - wd, yo + DEPTH) // ", " // pt(scene%x_lo - wd, yo) // ", " // pt(scene%x_lo, yo) // &
      ", " // pt(scene%x_lo, H) // ", " // pt(0.0_wp, H) // ", " // pt(0.0_wp, 0.0_wp) // ")"
    do k = scene%n_walls + 1, scene%n_obstacles()
      wkt = wkt // ", (" // hole(k) // ")"
    end do
    wkt = wkt // ")"
  contains
    function hole(k) result(s)
      integer, intent(in) :: k
      character(len=:), allocatable :: s
      integer, parameter :: NGON = 32
      real(wp) :: c(2), a, b(2), d(2), n(2), r
      integer :: j, nv
      associate (o => scene%obstacles(k))
        select case (o%kind)
        case (OBST_DISK)
          c = o%vertices(:, 1)
          s = ""
          do j = 0, NGON
            a = 2 * acos(-1.0_wp) * mod(j, NGON) / NGON
            if (j > 0) s = s // ", "
            s = s // pt(c(1) + o%radius * cos(a), c(2) + o%radius * sin(a))
          end do
        case (OBST_SEGMENT)
          b = o%vertices(:, 1); d = o%vertices(:, 2)
          n = [b(2) - d(2), d(1) - b(1)]
          n = n / max(norm2(n), tiny(1.0_wp))
          r = max(o%radius, 1.0e-6_wp)
          s = pt2(b + r * n) // ", " // pt2(d + r * n) // ", " // pt2(d - r * n) // ", " // pt2(b - r * n) // &
            ", " // pt2(b + r * n)
        case default
          nv = size(o%vertices, 2)
          s = ""
          do j = 0, nv
            if (j > 0) s = s // ", "
            s = s // pt2(o%vertices(:, mod(j, nv) + 1))
          end do
        end select
      end associate
    end function hole
    function pt2(p) result(s)
      real(wp), intent(in) :: p(2)
      character(len=:), allocatable :: s
      s = pt(p(1), p(2))
    end function pt2
  end function walkable_wkt

  !> "x y" with 17 significant digits.
  function pt(x, y) result(s)
    real(wp), intent(in) :: x, y
    character(len=:), allocatable :: s
    character(len=64) :: b1, b2
    write(b1, '(es24.16e3)') x
    write(b2, '(es24.16e3)') y
    s = trim(adjustl(b1)) // " " // trim(adjustl(b2))
  end function pt
end module cr_pdda_file
