!> A reproducible 62-bit text fingerprint (two polynomial hashes modulo 31-bit primes), shown as
!> 16 hexadecimal digits. Used to tie data files to the configuration that produced them; it is
!> not a cryptographic hash. All arithmetic stays below 2^62 (no integer overflow).
module cr_hash
  use cr_kinds, only: i8
  use cr_strings, only: to_lower
  implicit none
  private
  public :: hash_text

  integer(i8), parameter :: P1 = 2147483647_i8, P2 = 2147483629_i8
  integer(i8), parameter :: B1 = 1000003_i8, B2 = 916387_i8

contains

  !> Fingerprint of `s` as 16 lower-case hex digits.
  pure function hash_text(s) result(h)
    character(len=*), intent(in) :: s
    character(len=16) :: h
    integer(i8) :: h1, h2
    integer :: k
    h1 = 7_i8; h2 = 11_i8
    do k = 1, len(s)
      h1 = modulo(h1 * B1 + int(iachar(s(k:k)), i8) + 1_i8, P1)
      h2 = modulo(h2 * B2 + int(iachar(s(k:k)), i8) + 3_i8, P2)
    end do
    h1 = modulo(h1 * B1 + int(len(s), i8), P1)
    write(h, '(z8.8, z8.8)') h1, h2
    h = to_lower(h)
  end function hash_text

end module cr_hash
