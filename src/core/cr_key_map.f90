!> A map from an integer(i8) identity to a real value: the previous multiplier of a contact,
!> looked up by the contact's identity (agent pair or agent-obstacle pair) to warm-start the
!> next solve. One concept used by the full model, the local projection and the reduced stepper.
!>
!> Open addressing with linear probing in a power-of-two table kept at most half full. Slots
!> carry the generation in which they were written, so `clear` is O(1) and a map refilled every
!> step allocates nothing once it has grown. Any integer(i8) is a valid key (no sentinel).
!> A key can be stored once per generation: `put` of a key already present leaves its first
!> value in place and reports it (added = .false.).
module cr_key_map
  use cr_kinds, only: wp, i8
  implicit none
  private
  public :: key_map_t

  !> Identity -> value map (see the module header).
  type :: key_map_t
    !> number of keys stored
    integer :: n = 0
    !> current generation: slot s is in use iff stamp(s) == gen
    integer :: gen = 1
    !> keys, values and generation stamps of the slots [capacity] (capacity a power of two)
    integer(i8), allocatable :: keys(:)
    real(wp), allocatable :: vals(:)
    integer, allocatable :: stamp(:)
  contains
    procedure :: init
    procedure :: free
    procedure :: clear
    procedure :: put
    procedure :: get
    procedure :: lookup
    procedure :: fill
  end type key_map_t

  !> odd multipliers < 2^30 for the two 32-bit halves of a key (products stay below 2^62)
  integer(i8), parameter :: MUL_LO = 945488131_i8, MUL_HI = 674506111_i8
  integer(i8), parameter :: MASK32 = 4294967295_i8

contains

  !> Empty map with room for `capacity` keys before it grows (default 16).
  subroutine init(this, capacity)
    class(key_map_t), intent(inout) :: this
    integer, intent(in), optional :: capacity
    integer :: want
    want = 16
    if (present(capacity)) want = max(capacity, 1)
    call this%free()
    call allocate_slots(this, table_size(want))
  end subroutine init

  subroutine free(this)
    class(key_map_t), intent(inout) :: this
    if (allocated(this%keys)) deallocate(this%keys, this%vals, this%stamp)
    this%n = 0
    this%gen = 1
  end subroutine free

  !> Remove every key, keeping the storage (O(1)).
  subroutine clear(this)
    class(key_map_t), intent(inout) :: this
    this%n = 0
    if (.not. allocated(this%keys)) return
    if (this%gen == huge(this%gen)) then
      this%stamp = 0
      this%gen = 1
    else
      this%gen = this%gen + 1
    end if
  end subroutine clear

  !> Store value `val` under `key`. A key already present keeps its value: added = .false.
  subroutine put(this, key, val, added)
    class(key_map_t), intent(inout) :: this
    integer(i8), intent(in) :: key
    real(wp), intent(in) :: val
    logical, intent(out), optional :: added
    integer :: s
    if (.not. allocated(this%keys)) call this%init()
    if (2 * (this%n + 1) > size(this%keys)) call rehash(this, 2 * size(this%keys))
    s = find_slot(this, key)
    if (this%stamp(s) == this%gen) then
      if (present(added)) added = .false.
      return
    end if
    call store(this, s, key, val)
    if (present(added)) added = .true.
  end subroutine put

  !> Value stored under `key`, or `default` when the key is absent (found = .false.).
  function get(this, key, default, found) result(val)
    class(key_map_t), intent(in) :: this
    integer(i8), intent(in) :: key
    real(wp), intent(in) :: default
    logical, intent(out), optional :: found
    real(wp) :: val
    integer :: s
    val = default
    if (present(found)) found = .false.
    if (this%n == 0) return
    s = find_slot(this, key)
    if (this%stamp(s) == this%gen) then
      val = this%vals(s)
      if (present(found)) found = .true.
    end if
  end function get

  !> vals(k) = value stored under keys(k), or `default` when absent [size(keys)].
  subroutine lookup(this, keys, vals, default)
    class(key_map_t), intent(in) :: this
    integer(i8), intent(in) :: keys(:)
    real(wp), intent(out) :: vals(:)
    real(wp), intent(in) :: default
    integer :: k, s
    if (this%n == 0) then
      vals(1:size(keys)) = default
      return
    end if
    do k = 1, size(keys)
      s = find_slot(this, keys(k))
      if (this%stamp(s) == this%gen) then
        vals(k) = this%vals(s)
      else
        vals(k) = default
      end if
    end do
  end subroutine lookup

  !> Replace the content by keys(k) -> vals(k) for every k with keep(k) (all k when keep is
  !> absent) [size(keys)]; n_refused: keys given more than once (their first value is kept).
  subroutine fill(this, keys, vals, keep, n_refused)
    class(key_map_t), intent(inout) :: this
    integer(i8), intent(in) :: keys(:)
    real(wp), intent(in) :: vals(:)
    logical, intent(in), optional :: keep(:)
    integer, intent(out), optional :: n_refused
    integer :: k, nref, s
    call this%clear()
    if (.not. allocated(this%keys)) call this%init(size(keys))
    if (2 * size(keys) > size(this%keys)) then
      deallocate(this%keys, this%vals, this%stamp)
      call allocate_slots(this, table_size(size(keys)))
    end if
    ! the table holds 2 size(keys) slots or more: no growth below
    nref = 0
    do k = 1, size(keys)
      if (present(keep)) then
        if (.not. keep(k)) cycle
      end if
      s = find_slot(this, keys(k))
      if (this%stamp(s) == this%gen) then
        nref = nref + 1
        cycle
      end if
      call store(this, s, keys(k), vals(k))
    end do
    if (present(n_refused)) n_refused = nref
  end subroutine fill

  !> Smallest power of two >= 2 * want (at least 16).
  pure integer function table_size(want) result(cap)
    integer, intent(in) :: want
    cap = 16
    do while (cap < 2 * want)
      cap = 2 * cap
    end do
  end function table_size

  subroutine allocate_slots(this, cap)
    type(key_map_t), intent(inout) :: this
    integer, intent(in) :: cap
    allocate(this%keys(cap), this%vals(cap), this%stamp(cap))
    this%stamp = 0
    this%gen = 1
    this%n = 0
  end subroutine allocate_slots

  !> Move the current keys into a table of `cap` slots.
  subroutine rehash(this, cap)
    type(key_map_t), intent(inout) :: this
    integer, intent(in) :: cap
    integer(i8), allocatable :: k0(:)
    real(wp), allocatable :: v0(:)
    integer, allocatable :: s0(:)
    integer :: s, g0, t
    call move_alloc(this%keys, k0)
    call move_alloc(this%vals, v0)
    call move_alloc(this%stamp, s0)
    g0 = this%gen
    call allocate_slots(this, cap)
    do s = 1, size(k0)
      if (s0(s) /= g0) cycle
      t = find_slot(this, k0(s))
      call store(this, t, k0(s), v0(s))
    end do
  end subroutine rehash

  !> Write key -> val into the free slot s (from find_slot) of the current generation.
  pure subroutine store(this, s, key, val)
    type(key_map_t), intent(inout) :: this
    integer, intent(in) :: s
    integer(i8), intent(in) :: key
    real(wp), intent(in) :: val
    this%stamp(s) = this%gen
    this%keys(s) = key
    this%vals(s) = val
    this%n = this%n + 1
  end subroutine store

  !> The slot holding `key`, or the free slot where it would go (the table is never full).
  pure integer function find_slot(this, key) result(s)
    type(key_map_t), intent(in) :: this
    integer(i8), intent(in) :: key
    integer :: mask
    mask = size(this%keys) - 1
    s = iand(int(mix(key), kind(s)), mask)
    do
      if (this%stamp(s + 1) /= this%gen) exit
      if (this%keys(s + 1) == key) exit
      s = iand(s + 1, mask)
    end do
    s = s + 1
  end function find_slot

  !> Scatter of a key over 31 bits without integer overflow: the two 32-bit halves times odd
  !> constants below 2^30, summed (< 2^63), folded.
  elemental integer(i8) function mix(key) result(h)
    integer(i8), intent(in) :: key
    integer(i8) :: lo, hi
    lo = iand(key, MASK32)
    hi = iand(ishft(key, -32), MASK32)
    h = lo * MUL_LO + hi * MUL_HI
    h = iand(ieor(h, ishft(h, -29)), int(huge(1), i8))
  end function mix
end module cr_key_map
