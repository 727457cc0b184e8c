!> Reproducible random numbers: L'Ecuyer's MRG32k3a combined multiple-recursive generator.
!>
!> The stream depends only on (seed, stream id), never on the compiler, the number of MPI
!> ranks or the order in which other streams are used, so that sampling is reproducible.
!> All arithmetic stays below 2^53 in 64-bit integers (no overflow).
module cr_random
  use cr_kinds, only: wp, i8
  implicit none
  private
  public :: rng_t

  integer(i8), parameter :: M1 = 4294967087_i8, M2 = 4294944443_i8
  integer(i8), parameter :: A12 = 1403580_i8, A13N = 810728_i8
  integer(i8), parameter :: A21 = 527612_i8, A23N = 1370589_i8
  real(wp), parameter :: NORM = 1.0_wp / (real(M1, wp) + 1.0_wp)

  !> Generator state (six 32-bit components).
  type :: rng_t
    integer(i8) :: s(6) = [12345_i8, 12345_i8, 12345_i8, 12345_i8, 12345_i8, 12345_i8]
  contains
    procedure :: seed
    procedure :: uniform
    procedure :: uniform_array
    procedure :: normal
  end type rng_t

contains

  !> Seed from an integer seed and an optional stream id (e.g. the sample index).
  subroutine seed(this, seed_value, stream)
    class(rng_t), intent(inout) :: this
    integer, intent(in) :: seed_value
    integer, intent(in), optional :: stream
    integer(i8) :: z
    integer :: k, st
    st = 0
    if (present(stream)) st = stream
    z = mix(int(seed_value, i8) * 7919_i8 + int(st, i8) * 104729_i8 + 1_i8)
    do k = 1, 6
      z = mix(z + int(k, i8) * 2654435_i8)
      if (k <= 3) then
        this%s(k) = 1_i8 + modulo(z, M1 - 2_i8)
      else
        this%s(k) = 1_i8 + modulo(z, M2 - 2_i8)
      end if
    end do
    do k = 1, 10   ! discard a few outputs
      z = int(this%uniform() * 1000.0_wp, i8)
    end do
  end subroutine seed

  !> A 31-bit integer hash (no overflow: products stay below 2^62).
  pure integer(i8) function mix(x) result(z)
    integer(i8), intent(in) :: x
    z = modulo(x, 2147483647_i8)
    z = modulo(z * 48271_i8, 2147483647_i8)
    z = modulo(ieor(z, ishft(z, -13)) * 69621_i8, 2147483647_i8)
    z = modulo(ieor(z, ishft(z, -7)) * 48271_i8 + 11_i8, 2147483647_i8)
  end function mix

  !> Uniform deviate in (0, 1).
  real(wp) function uniform(this)
    class(rng_t), intent(inout) :: this
    integer(i8) :: p1, p2
    p1 = modulo(A12 * this%s(2) - A13N * this%s(1), M1)
    this%s(1) = this%s(2); this%s(2) = this%s(3); this%s(3) = p1
    p2 = modulo(A21 * this%s(6) - A23N * this%s(4), M2)
    this%s(4) = this%s(5); this%s(5) = this%s(6); this%s(6) = p2
    if (p1 > p2) then
      uniform = real(p1 - p2, wp) * NORM
    else
      uniform = real(p1 - p2 + M1, wp) * NORM
    end if
  end function uniform

  !> Fill an array with uniform deviates in (0, 1).
  subroutine uniform_array(this, x)
    class(rng_t), intent(inout) :: this
    real(wp), intent(out) :: x(:)
    integer :: k
    do k = 1, size(x)
      x(k) = this%uniform()
    end do
  end subroutine uniform_array

  !> Standard normal deviate (Box-Muller, one value per call).
  real(wp) function normal(this)
    class(rng_t), intent(inout) :: this
    real(wp) :: u1, u2
    u1 = this%uniform()
    u2 = this%uniform()
    normal = sqrt(-2.0_wp * log(u1)) * cos(2.0_wp * acos(-1.0_wp) * u2)
  end function normal
end module cr_random
