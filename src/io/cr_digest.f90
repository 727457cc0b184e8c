!> Checksums of datasets that can be computed in pieces: the digest of a dataset is a sum, over
!> its elements, of a non-linear mix of the element's bits and its position (0-based linear
!> index in Fortran order), in two lanes with different constants, modulo the Mersenne prime
!> 2^31 - 1 (reduced by shifts, no division: about 20 integer operations per element). Any rank
!> can digest any part of a dataset (a block of columns at some offset) and the parts add up (`digest_add`, or
!> `digest_allreduce` over ranks) to the digest of the whole, whatever the distribution.
!> A changed, swapped or moved element changes the digest except with probability ~2^-62.
!> Not cryptographic: it detects corruption (bit rot, overwritten bytes, edited values), not
!> forgery. All arithmetic stays below 2^63 (no integer overflow).
!>
!> Stored as the attribute `checksum` (16 hex digits) of the dataset; `put_digest` writes it,
!> `check_digest` compares it with the digest of the data a reader actually read.
!>
!> Block digests, for readers of a part of a dataset: a product splits its datasets into blocks
!> (e.g. one sample's columns) and stores a table, an integer dataset [2 n_ds, n_blocks] whose
!> column b holds the two residues (`digest_pack`) of block b of each of n_ds datasets (block b
!> of a dataset being digested at its own linear offsets, the blocks add up to the whole). A
!> reader of blocks b0..b1 compares the digest of what it read with the sum of those columns
!> (`digest_table_sum`, `check_digest_blocks`); the table itself carries a `checksum`, and the
!> sum of all its columns equals each dataset's whole checksum.
module cr_digest
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_env, only: env_t
  use cr_strings, only: to_lower
  use cr_h5file, only: h5file_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: digest_t, digest_of, digest_of_ranges, digest_add, digest_allreduce, digest_hex, put_digest, &
    check_digest, check_digest_parts, DIGEST_ATTR, DIGEST_ALGORITHM, digest_pack, digest_table_sum, &
    check_digest_blocks

  !> name of the dataset attribute holding the digest
  character(len=*), parameter :: DIGEST_ATTR = "checksum"
  !> description stored with the files that use it
  character(len=*), parameter :: DIGEST_ALGORITHM = "crowdrom-digest-2: two sums over the elements " // &
    "of mix(bits, linear index) mod 2^31-1 (src/io/cr_digest.f90), 16 hex digits"

  integer(i8), parameter :: M = 2147483647_i8
  integer(i8), parameter :: LO32 = 4294967295_i8

  !> Partial or complete digest (two residues).
  type :: digest_t
    integer(i8) :: s1 = 0, s2 = 0
  end type digest_t

  !> Digest of an array whose first element has 0-based linear index `offset` in its dataset.
  interface digest_of
    module procedure dg_real1, dg_real2, dg_int1, dg_int2, dg_int64_1
  end interface digest_of

  !> Digest of a packed array whose elements lie in the ranges (0-based offset, count) of the
  !> dataset's linear index, one range after the other.
  interface digest_of_ranges
    module procedure dgr_real1, dgr_int1
  end interface digest_of_ranges

contains

  !> x mod M for 0 <= x < 2^63 (M = 2^31 - 1: two folds of the high bits, one subtraction).
  elemental integer(i8) function fold(x) result(y)
    integer(i8), intent(in) :: x
    y = iand(x, M) + shiftr(x, 31)
    y = iand(y, M) + shiftr(y, 31)
    if (y >= M) y = y - M
  end function fold

  !> Mix of one 64-bit word w at linear position g into the two residues (no division: the
  !> modulus is the Mersenne prime 2^31 - 1; products of a 32-bit and a 31-bit number < 2^63).
  pure subroutine mix_in(d, w, g)
    type(digest_t), intent(inout) :: d
    integer(i8), intent(in) :: w, g
    integer(i8) :: lo, hi, gm, x
    lo = iand(w, LO32)
    hi = iand(shiftr(w, 32), LO32)
    gm = fold(g)
    x = fold(fold(lo * 1103515245_i8) + fold(hi * 69069_i8) + fold(gm * 1664525_i8) + 12345_i8)
    x = fold(x * (x + 977_i8))
    d%s1 = d%s1 + x
    x = fold(fold(lo * 214013_i8) + fold(hi * 1812433253_i8) + fold(gm * 22695477_i8) + 2531011_i8)
    x = fold(x * (x + 1013_i8))
    d%s2 = d%s2 + x
  end subroutine mix_in

  pure function dg_real1(x, offset) result(d)
    !> values [n]
    real(wp), intent(in) :: x(:)
    !> 0-based linear index of x(1) in the dataset
    integer(i8), intent(in) :: offset
    type(digest_t) :: d
    integer(i8) :: k
    do k = 1, size(x, kind=i8)
      call mix_in(d, transfer(x(k), 0_i8), offset + k - 1)
    end do
    d%s1 = fold(d%s1); d%s2 = fold(d%s2)
  end function dg_real1

  pure function dg_real2(x, offset) result(d)
    !> columns [n_rows, n_cols] (linear index in Fortran order)
    real(wp), intent(in) :: x(:,:)
    integer(i8), intent(in) :: offset
    type(digest_t) :: d
    integer(i8) :: i, j, m
    m = size(x, 1, kind=i8)
    do j = 1, size(x, 2, kind=i8)
      do i = 1, m
        call mix_in(d, transfer(x(i, j), 0_i8), offset + (j - 1) * m + i - 1)
      end do
    end do
    d%s1 = fold(d%s1); d%s2 = fold(d%s2)
  end function dg_real2

  pure function dg_int1(x, offset) result(d)
    integer, intent(in) :: x(:)
    integer(i8), intent(in) :: offset
    type(digest_t) :: d
    integer(i8) :: k
    do k = 1, size(x, kind=i8)
      call mix_in(d, int(x(k), i8), offset + k - 1)
    end do
    d%s1 = fold(d%s1); d%s2 = fold(d%s2)
  end function dg_int1

  pure function dg_int2(x, offset) result(d)
    integer, intent(in) :: x(:,:)
    integer(i8), intent(in) :: offset
    type(digest_t) :: d
    integer(i8) :: i, j, m
    m = size(x, 1, kind=i8)
    do j = 1, size(x, 2, kind=i8)
      do i = 1, m
        call mix_in(d, int(x(i, j), i8), offset + (j - 1) * m + i - 1)
      end do
    end do
    d%s1 = fold(d%s1); d%s2 = fold(d%s2)
  end function dg_int2

  pure function dg_int64_1(x, offset) result(d)
    integer(i8), intent(in) :: x(:)
    integer(i8), intent(in) :: offset
    type(digest_t) :: d
    integer(i8) :: k
    do k = 1, size(x, kind=i8)
      call mix_in(d, x(k), offset + k - 1)
    end do
    d%s1 = fold(d%s1); d%s2 = fold(d%s2)
  end function dg_int64_1

  pure function dgr_real1(x, ranges) result(d)
    real(wp), intent(in) :: x(:)
    !> (offset, count) of each range [2, n_ranges]; the counts add up to size(x)
    integer, intent(in) :: ranges(:,:)
    type(digest_t) :: d
    integer :: q, c
    c = 0
    do q = 1, size(ranges, 2)
      d = digest_add(d, dg_real1(x(c + 1:c + ranges(2, q)), int(ranges(1, q), i8)))
      c = c + ranges(2, q)
    end do
  end function dgr_real1

  pure function dgr_int1(x, ranges) result(d)
    integer, intent(in) :: x(:)
    integer, intent(in) :: ranges(:,:)
    type(digest_t) :: d
    integer :: q, c
    c = 0
    do q = 1, size(ranges, 2)
      d = digest_add(d, dg_int1(x(c + 1:c + ranges(2, q)), int(ranges(1, q), i8)))
      c = c + ranges(2, q)
    end do
  end function dgr_int1

  !> The two residues of a digest as default integers (both below 2^31 - 1), for block tables.
  pure function digest_pack(d) result(r)
    type(digest_t), intent(in) :: d
    integer :: r(2)
    r = int([d%s1, d%s2])
  end function digest_pack

  !> Sum of the block digests of dataset q (1-based) over the columns of a block table
  !> [2 n_ds, n_blocks] (entries outside 0..2^31-2 make an impossible digest, -1).
  pure function digest_table_sum(table, q) result(d)
    integer, intent(in) :: table(:,:)
    integer, intent(in) :: q
    type(digest_t) :: d
    integer :: b
    do b = 1, size(table, 2)
      if (any(table(2 * q - 1:2 * q, b) < 0) .or. any(table(2 * q - 1:2 * q, b) >= M)) then
        d = digest_t(-1, -1); return
      end if
      d = digest_add(d, digest_t(int(table(2 * q - 1, b), i8), int(table(2 * q, b), i8)))
    end do
  end function digest_table_sum

  !> Compare the digest `d` of blocks read from dataset `name` with the sum of their entries in
  !> the block table (the table's columns of those blocks). `what` leads the message.
  subroutine check_digest_blocks(table, q, name, d, what, error)
    integer, intent(in) :: table(:,:)
    integer, intent(in) :: q
    character(len=*), intent(in) :: name, what
    type(digest_t), intent(in) :: d
    type(error_t), allocatable, intent(out) :: error
    type(digest_t) :: t
    t = digest_table_sum(table, q)
    if (t%s1 == d%s1 .and. t%s2 == d%s2) return
    call set_error(error, what // ": block checksum mismatch in dataset '" // name // "' (stored " // &
      digest_hex(t) // ", data " // digest_hex(d) // "): the file is corrupted", EXIT_BAD_INPUT)
  end subroutine check_digest_blocks

  !> Digest of the union of two disjoint parts.
  elemental function digest_add(a, b) result(d)
    type(digest_t), intent(in) :: a, b
    type(digest_t) :: d
    d%s1 = fold(a%s1 + b%s1)
    d%s2 = fold(a%s2 + b%s2)
  end function digest_add

  !> Collective: the sum of every rank's parts (each rank gets the digests of the wholes), for
  !> one digest or several at once (one MPI_Allreduce). If the sum fails, the error is
  !> returned (when asked for) and the digests are set to an impossible value (-1), so that
  !> no checksum can match them.
  subroutine digest_allreduce(env, d, error)
    type(env_t), intent(in) :: env
    type(digest_t), intent(inout) :: d(..)
    type(error_t), allocatable, intent(out), optional :: error
    integer(i8), allocatable :: s(:)
    type(error_t), allocatable :: e
    integer :: k, n
    if (env%size == 1) return
    select rank (d)
    rank (0)
      s = [d%s1, d%s2]
    rank (1)
      n = size(d)
      allocate(s(2 * n))
      do k = 1, n
        s(2 * k - 1) = d(k)%s1; s(2 * k) = d(k)%s2
      end do
    end select
    ! at most 2^31 ranks of residues < 2^31: no overflow
    call env%allreduce(s, 'sum', e)
    if (.not. allocated(e)) s = fold(s)
    if (allocated(e)) s = -1
    select rank (d)
    rank (0)
      d%s1 = s(1); d%s2 = s(2)
    rank (1)
      do k = 1, size(d)
        d(k)%s1 = s(2 * k - 1); d(k)%s2 = s(2 * k)
      end do
    end select
    if (allocated(e) .and. present(error)) call move_alloc(e, error)
  end subroutine digest_allreduce

  !> 16 lower-case hex digits.
  function digest_hex(d) result(h)
    type(digest_t), intent(in) :: d
    character(len=16) :: h
    write(h, '(z8.8, z8.8)') d%s1, d%s2
    h = to_lower(h)
  end function digest_hex

  !> Store the digest of dataset `name` as its `checksum` attribute (collective like write_attr).
  subroutine put_digest(h5, name, d, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: name
    type(digest_t), intent(in) :: d
    type(error_t), allocatable, intent(out) :: error
    call h5%write_attr(name, DIGEST_ATTR, digest_hex(d), error)
  end subroutine put_digest

  !> Compare the digest `d` of the data read from dataset `name` with its stored checksum.
  !> The error names the dataset and the file; `what` (e.g. "piece 'p.h5'") leads the message.
  subroutine check_digest(h5, name, d, what, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: name, what
    type(digest_t), intent(in) :: d
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: stored
    call h5%read_attr(name, DIGEST_ATTR, stored, error)
    if (allocated(error)) then
      deallocate(error)
      call set_error(error, what // ": dataset '" // name // "' has no checksum attribute (written by " // &
        "an older crowdrom, or damaged)")
      return
    end if
    if (stored /= digest_hex(d)) call set_error(error, what // ": checksum mismatch in dataset '" // name // &
      "' (stored " // stored // ", data " // digest_hex(d) // "): the file is corrupted")
  end subroutine check_digest

  !> Collective: `d` is this rank's part of dataset `name` (the ranks' parts together cover it
  !> exactly once, e.g. blocks of columns read with read_block); compare their sum with the
  !> stored checksum. Every rank gets the same result.
  subroutine check_digest_parts(h5, env, name, d, what, error)
    type(h5file_t), intent(inout) :: h5
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: name, what
    type(digest_t), intent(in) :: d
    type(error_t), allocatable, intent(out) :: error
    type(digest_t) :: total
    total = d
    call digest_allreduce(env, total, error)
    if (allocated(error)) return
    call check_digest(h5, name, total, what, error)
  end subroutine check_digest_parts
end module cr_digest
