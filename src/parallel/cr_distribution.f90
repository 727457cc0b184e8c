!> How data is distributed over the ranks: the one module that owns it.
!>
!> * Contiguous balanced blocks (`block_range`): snapshot columns, rows of S^T, rows of a
!>   sketch. Part p (0-based) of n items holds items offset+1 .. offset+count; the first
!>   mod(n, nparts) parts hold one item more. Parts may be empty.
!> * BLACS process grids and ScaLAPACK descriptors (`blacs_grid_t`), built on the env_t
!>   communicator (never MPI_COMM_WORLD), and the 2D block-cyclic index maps.
module cr_distribution
  use mpi_f08, only: MPI_Comm
  use cr_env, only: env_t
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  implicit none
  private
  public :: block_range, block_owner, blacs_grid_t, grid_shape, cyclic_owner, cyclic_local_index

  !> Length of a ScaLAPACK array descriptor.
  integer, parameter, public :: DLEN = 9

  !> A BLACS process grid on a duplicate of env%comm (row-major process numbering).
  type :: blacs_grid_t
    integer :: context = -1
    integer :: system_handle = -1
    !> the duplicate given to BLACS, with MPI_ERRORS_ARE_FATAL: BLACS (and ScaLAPACK over it)
    !> does not check MPI statuses, and its communicators inherit the handler of this one, so
    !> env%comm's MPI_ERRORS_RETURN would let a failed MPI call inside it pass unseen
    type(env_t), private :: blacs_env
    integer :: nprow = 0, npcol = 0
    integer :: myrow = -1, mycol = -1
  contains
    procedure :: init => grid_init
    procedure :: free => grid_free
    procedure :: local_rows, local_cols
    procedure :: descriptor
    procedure :: pnum
  end type blacs_grid_t

  interface
    integer function sys2blacs_handle(comm)
      integer, intent(in) :: comm
    end function sys2blacs_handle
    subroutine free_blacs_system_handle(handle)
      integer, intent(in) :: handle
    end subroutine free_blacs_system_handle
    subroutine blacs_gridinit(ctxt, order, nprow, npcol)
      integer, intent(inout) :: ctxt
      character, intent(in) :: order
      integer, intent(in) :: nprow, npcol
    end subroutine blacs_gridinit
    subroutine blacs_gridinfo(ctxt, nprow, npcol, myrow, mycol)
      integer, intent(in) :: ctxt
      integer, intent(out) :: nprow, npcol, myrow, mycol
    end subroutine blacs_gridinfo
    subroutine blacs_gridexit(ctxt)
      integer, intent(in) :: ctxt
    end subroutine blacs_gridexit
    integer function blacs_pnum(ctxt, prow, pcol)
      integer, intent(in) :: ctxt, prow, pcol
    end function blacs_pnum
    integer function numroc(n, nb, iproc, isrcproc, nprocs)
      integer, intent(in) :: n, nb, iproc, isrcproc, nprocs
    end function numroc
    subroutine descinit(desc, m, n, mb, nb, irsrc, icsrc, ictxt, lld, info)
      import :: DLEN
      integer, intent(out) :: desc(DLEN)
      integer, intent(in) :: m, n, mb, nb, irsrc, icsrc, ictxt, lld
      integer, intent(out) :: info
    end subroutine descinit
  end interface

contains

  !> Balanced contiguous block of `n` items for part `part` (0-based) of `nparts`:
  !> items offset+1 .. offset+count.
  pure subroutine block_range(n, nparts, part, offset, count)
    integer, intent(in) :: n, nparts, part
    integer, intent(out) :: offset, count
    integer :: base, extra
    base = n / nparts
    extra = mod(n, nparts)
    count = base
    if (part < extra) count = base + 1
    offset = part * base + min(part, extra)
  end subroutine block_range

  !> Part (0-based) that holds item `i` (1-based) in `block_range(n, nparts, ...)`.
  pure integer function block_owner(n, nparts, i) result(part)
    integer, intent(in) :: n, nparts, i
    integer :: base, extra
    base = n / nparts
    extra = mod(n, nparts)
    if (i <= extra * (base + 1)) then
      part = (i - 1) / (base + 1)
    else
      part = extra + (i - 1 - extra * (base + 1)) / base
    end if
  end function block_owner

  !> Near-square process grid nprow x npcol = nprocs with nprow <= npcol.
  pure subroutine grid_shape(nprocs, nprow, npcol)
    integer, intent(in) :: nprocs
    integer, intent(out) :: nprow, npcol
    integer :: p
    nprow = 1
    do p = 1, nprocs
      if (p * p > nprocs) exit
      if (mod(nprocs, p) == 0) nprow = p
    end do
    npcol = nprocs / nprow
  end subroutine grid_shape

  !> Process coordinate owning global index `i` (1-based) in a block-cyclic layout
  !> with block size `nb` over `nprocs` processes (first block on process 0).
  pure integer function cyclic_owner(i, nb, nprocs)
    integer, intent(in) :: i, nb, nprocs
    cyclic_owner = mod((i - 1) / nb, nprocs)
  end function cyclic_owner

  !> Local index (1-based) of global index `i` on its owner in a block-cyclic layout.
  pure integer function cyclic_local_index(i, nb, nprocs)
    integer, intent(in) :: i, nb, nprocs
    cyclic_local_index = ((i - 1) / (nb * nprocs)) * nb + mod(i - 1, nb) + 1
  end function cyclic_local_index

  !> Create a near-square BLACS grid over all ranks of env%comm (or nprow x npcol if given).
  subroutine grid_init(this, env, error, nprow, npcol)
    class(blacs_grid_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(error_t), allocatable, intent(out) :: error
    integer, intent(in), optional :: nprow, npcol
    integer :: pr, pc
    call grid_shape(env%size, pr, pc)
    if (present(nprow) .and. present(npcol)) then
      pr = nprow; pc = npcol
    end if
    if (pr * pc /= env%size .or. pr < 1 .or. pc < 1) then
      call set_error(error, "blacs grid: " // str(pr) // " x " // str(pc) // &
        & " does not match the " // str(env%size) // " ranks of the communicator")
      return
    end if
    call this%blacs_env%init(env%comm, error, errors_fatal=.true.)
    if (allocated(error)) then
      call grid_free(this); return
    end if
    this%system_handle = sys2blacs_handle(this%blacs_env%comm%MPI_VAL)
    this%context = this%system_handle
    call blacs_gridinit(this%context, 'R', pr, pc)
    call blacs_gridinfo(this%context, this%nprow, this%npcol, this%myrow, this%mycol)
    if (this%nprow /= pr .or. this%npcol /= pc .or. this%myrow < 0) then
      call set_error(error, "blacs grid: blacs_gridinit failed for a " // str(pr) // " x " // &
        & str(pc) // " grid")
      ! nothing of a failed grid is kept (the caller need not free it)
      call grid_free(this)
    end if
  end subroutine grid_init

  !> Release the grid.
  subroutine grid_free(this)
    class(blacs_grid_t), intent(inout) :: this
    if (this%context >= 0) call blacs_gridexit(this%context)
    if (this%system_handle >= 0) call free_blacs_system_handle(this%system_handle)
    call this%blacs_env%free()
    this%context = -1
    this%system_handle = -1
    this%nprow = 0; this%npcol = 0; this%myrow = -1; this%mycol = -1
  end subroutine grid_free

  !> Local number of rows of an m-row matrix with row block mb (numroc).
  integer function local_rows(this, m, mb)
    class(blacs_grid_t), intent(in) :: this
    integer, intent(in) :: m, mb
    local_rows = numroc(m, mb, this%myrow, 0, this%nprow)
  end function local_rows

  !> Local number of columns of an n-column matrix with column block nb (numroc).
  integer function local_cols(this, n, nb)
    class(blacs_grid_t), intent(in) :: this
    integer, intent(in) :: n, nb
    local_cols = numroc(n, nb, this%mycol, 0, this%npcol)
  end function local_cols

  !> Rank in env%comm of grid process (prow, pcol).
  integer function pnum(this, prow, pcol)
    class(blacs_grid_t), intent(in) :: this
    integer, intent(in) :: prow, pcol
    pnum = blacs_pnum(this%context, prow, pcol)
  end function pnum

  !> Descriptor of an m x n matrix with mb x nb blocks, first block on process (0, 0).
  subroutine descriptor(this, m, n, mb, nb, desc, error)
    class(blacs_grid_t), intent(in) :: this
    integer, intent(in) :: m, n, mb, nb
    integer, intent(out) :: desc(DLEN)
    type(error_t), allocatable, intent(out) :: error
    integer :: info
    call descinit(desc, m, n, mb, nb, 0, 0, this%context, max(1, this%local_rows(m, mb)), info)
    if (info /= 0) call set_error(error, "descinit: argument " // str(-info) // &
      & " is illegal for a " // str(m) // " x " // str(n) // " matrix with " // str(mb) // &
      & " x " // str(nb) // " blocks")
  end subroutine descriptor
end module cr_distribution
