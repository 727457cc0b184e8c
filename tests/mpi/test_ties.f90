!> The near-tie rule (cr_sort::near_max_index: values within a relative sqrt(eps) of the largest
!> count as tied, the lowest index wins) in the distributed selections: env_t's
!> allreduce_near_maxloc (used by the cone's snapshot choice and the PGA's supremizer choice)
!> and gIS's coordinate choice. Exact ties, near ties inside the tolerance and differences just
!> outside it must give the same index at 1, 2 and 4 ranks, whatever the split of the indices.
program test_ties
  use mpi_f08, only: MPI_Init, MPI_Finalize, MPI_COMM_WORLD
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_sort, only: near_max_index
  use cr_strings, only: str
  use cr_assert, only: check, test_summary
  use cr_cone, only: sparse_columns_t, cone_result_t, gis_build, mcpg_build
  use cr_distribution, only: block_range
  use cr_test_columns, only: distribute
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  integer :: ierr
  real(wp), parameter :: tol = sqrt(epsilon(1.0_wp))

  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call check(.not. allocated(error), "env%init")
  call test_near_maxloc()
  call test_near_maxloc_errors()
  call test_gis_ties()
  call test_mcpg_tie()
  call env%free()
  call MPI_Finalize(ierr)
  call test_summary(env%rank)

contains

  !> This rank's share [c0 + 1, c0 + nc] of n indices: 'block' (contiguous blocks, the first
  !> ranks one larger), 'back' (rank 0 holds nothing, the last rank the remainder), 'front'
  !> (rank 0 holds all but one index per other rank).
  subroutine split(n, how, c0, nc)
    integer, intent(in) :: n
    character(len=*), intent(in) :: how
    integer, intent(out) :: c0, nc
    integer :: p, r, per
    p = env%size; r = env%rank
    select case (how)
    case ('block')
      call block_range(n, p, r, c0, nc)
    case ('back')
      if (p == 1) then
        c0 = 0; nc = n
      else if (r == 0) then
        c0 = 0; nc = 0
      else
        per = n / (p - 1)
        c0 = (r - 1) * per; nc = per
        if (r == p - 1) nc = n - c0
      end if
    case default
      if (r == 0) then
        c0 = 0; nc = n - (p - 1)
      else
        c0 = n - (p - 1) + (r - 1); nc = 1
      end if
    end select
  end subroutine split

  !> allreduce_near_maxloc on the global values x [n] (and mask) split three ways must give
  !> near_max_index(x, mask), and `expect` when given.
  subroutine check_case(name, x, expect, mask)
    character(len=*), intent(in) :: name
    real(wp), intent(in) :: x(:)
    integer, intent(in) :: expect
    logical, intent(in), optional :: mask(:)
    character(len=5), parameter :: hows(3) = [character(len=5) :: 'block', 'back', 'front']
    type(error_t), allocatable :: err
    integer :: h, c0, nc, ref
    integer(i8) :: g
    real(wp) :: v
    if (present(mask)) then
      ref = near_max_index(x, mask)
    else
      ref = near_max_index(x)
    end if
    call check(ref == expect, name // ": serial near_max_index gives " // str(expect) // " (got " // str(ref) // ")")
    do h = 1, size(hows)
      call split(size(x), trim(hows(h)), c0, nc)
      if (present(mask)) then
        call env%allreduce_near_maxloc(x(c0 + 1:c0 + nc), int(c0, i8), v, g, err, mask=mask(c0 + 1:c0 + nc))
      else
        call env%allreduce_near_maxloc(x(c0 + 1:c0 + nc), int(c0, i8), v, g, err)
      end if
      call check(.not. allocated(err), name // " (" // trim(hows(h)) // "): no error")
      call check(g == expect, name // " (" // trim(hows(h)) // " split, " // str(env%size) // " ranks): index " // &
        str(expect) // ", got " // str(g))
      if (expect > 0 .and. g == expect) then
        call check(v == x(expect), name // " (" // trim(hows(h)) // "): the value of the chosen entry")
      else if (expect == 0) then
        call check(v == -huge(1.0_wp), name // " (" // trim(hows(h)) // "): -huge when nothing is selected")
      end if
    end do
  end subroutine check_case

  subroutine test_near_maxloc()
    real(wp) :: x(9), big
    logical :: m(9)
    integer :: k
    big = 3.0_wp
    x = [(real(k, wp) / 10, k = 1, 9)]
    ! a clear maximum
    x(6) = big
    call check_case("clear maximum", x, 6)
    ! exact tie: the lowest index wins, wherever the tied entries sit
    x(2) = big; x(8) = big
    call check_case("exact tie", x, 2)
    ! near tie inside the tolerance: the lower index wins although its value is smaller ...
    x = [(real(k, wp) / 10, k = 1, 9)]
    x(3) = big * (1 - 0.25_wp * tol); x(8) = big
    call check_case("near tie below, inside the tolerance", x, 3)
    ! ... or larger
    x(3) = big * (1 + 0.25_wp * tol)
    call check_case("near tie above, inside the tolerance", x, 3)
    ! outside the tolerance: the larger value wins
    x(3) = big * (1 - 4 * tol)
    call check_case("difference outside the tolerance", x, 8)
    ! the threshold comes from the global maximum, not each rank's own: 1 is within the
    ! tolerance of 2 but not of 9 (the global maximum), so 2 wins, not 1 (a rank holding 1 and
    ! 2 but not 9 that applied the rule to its own values would offer 1)
    x = 0
    x(1) = big * (1 - 1.2_wp * tol); x(2) = big * (1 - 0.5_wp * tol); x(9) = big * (1 + 0.25_wp * tol)
    call check_case("threshold from the global maximum", x, 2)
    ! negative values: relative to |max|
    x = -5
    x(4) = -2 * (1 + 0.5_wp * tol); x(7) = -2
    call check_case("negative near tie", x, 4)
    x(4) = -2 * (1 + 4 * tol)
    call check_case("negative, outside the tolerance", x, 7)
    ! all zero: every entry ties
    x = 0
    call check_case("all zero", x, 1)
    ! mask: masked entries neither win nor set the maximum
    x = [(real(k, wp), k = 1, 9)]
    x(2) = 9 * (1 - 0.5_wp * tol)
    m = .true.; m(2) = .false.
    call check_case("masked near tie", x, 9, m)
    m(9) = .false.
    call check_case("masked maximum", x, 8, m)
    m(2) = .true.
    call check_case("unmasked near tie of a masked maximum", x, 2, m)
    m = .false.
    call check_case("nothing selected", x, 0, m)
    ! many near ties produced by different rounding: sums of the same terms in different
    ! orders, the kind of difference a different number of ranks makes
    do k = 1, 9
      x(k) = sum_in_order(k)
    end do
    call check(maxval(x) - minval(x) <= 16 * epsilon(1.0_wp) * maxval(x), "rounding only: the values agree to rounding")
    call check_case("sums in different orders", x, 1)
  end subroutine test_near_maxloc

  !> 0.1 + 0.2 + ... + 1.0 summed from a rotating start (the same sum, different rounding).
  real(wp) function sum_in_order(start)
    integer, intent(in) :: start
    integer :: j
    sum_in_order = 0
    do j = 0, 9
      sum_in_order = sum_in_order + real(mod(start + j, 10) + 1, wp) / 10
    end do
  end function sum_in_order

  !> A bad argument on one rank is an error on every rank (no rank hangs in a collective).
  subroutine test_near_maxloc_errors()
    type(error_t), allocatable :: err
    real(wp) :: x(3), v
    integer(i8) :: g
    logical :: m(3)
    x = [1, 2, 3]; m = .true.
    if (env%rank == env%size - 1) then
      call env%allreduce_near_maxloc(x, 3_i8 * env%rank, v, g, err, mask=m(1:2))
    else
      call env%allreduce_near_maxloc(x, 3_i8 * env%rank, v, g, err, mask=m)
    end if
    call check(allocated(err), "a mask of the wrong size on the last rank: an error on every rank")
    if (allocated(err)) call check(index(err%message, "near maxloc") > 0, "the error names the near maxloc")
    call check(g == 0, "no index on error")
    call env%allreduce_near_maxloc(x, -1_i8, v, g, err)
    call check(allocated(err), "a negative offset is an error")
  end subroutine test_near_maxloc_errors

  !> gIS with tied snapshots and tied coordinates. Snapshots 2 and 4 have norms within the
  !> tolerance (4 slightly larger): snapshot 2 is chosen first at every rank count. Its
  !> coordinates 5 and 2 tie within the tolerance (5 slightly larger): coordinate 2 is chosen.
  !> A coordinate larger by more than the tolerance wins over a lower index.
  subroutine test_gis_ties()
    real(wp) :: x(6, 5)
    type(sparse_columns_t) :: lam
    type(cone_result_t) :: res
    type(error_t), allocatable :: err
    real(wp) :: a
    a = 3 / sqrt(2.0_wp)
    x = 0
    x(:, 1) = [1, 0, 0, 0, 0, 0]
    x(2, 2) = a; x(5, 2) = a * (1 + 0.25_wp * tol)
    x(3, 3) = 1
    x(1, 4) = a * (1 + 0.5_wp * tol); x(6, 4) = a * (1 + 0.5_wp * tol)
    x(4, 5) = 2
    call distribute(env, x, lam)
    call gis_build(env, lam, 0.0_wp, 1, res, err)
    call check(.not. allocated(err) .and. res%r == 1, "gis near ties: one step")
    if (res%r == 1) then
      call check(res%sigma(1) == 2_i8, "gis near ties: snapshot 2 (lowest of the near-tied norms) at " // &
        str(env%size) // " ranks, got " // str(res%sigma(1)))
      call check(res%indices(1) == 2, "gis near ties: coordinate 2 (lowest of the near-tied coordinates), got " // &
        str(res%indices(1)))
    end if
    ! outside the tolerance: snapshot 4 is larger, and its coordinate 6 beats coordinate 1
    x(1, 4) = a * (1 + 4 * tol); x(6, 4) = a * (1 + 12 * tol)
    call distribute(env, x, lam)
    call gis_build(env, lam, 0.0_wp, 1, res, err)
    call check(.not. allocated(err) .and. res%r == 1, "gis separated: one step")
    if (res%r == 1) then
      call check(res%sigma(1) == 4_i8, "gis separated: snapshot 4 at " // str(env%size) // " ranks, got " // &
        str(res%sigma(1)))
      call check(res%indices(1) == 6, "gis separated: coordinate 6, got " // str(res%indices(1)))
    end if
    ! exact ties: the whole selection is the same at every rank count
    x = 0
    x(:, 1) = [2, 0, 0, 0, 0, 2]; x(:, 2) = [0, 2, 2, 0, 0, 0]; x(:, 3) = [0, 0, 0, 2, 2, 0]
    x(:, 4) = [0, 2, 2, 0, 0, 0]; x(:, 5) = [2, 0, 0, 0, 0, 2]
    call distribute(env, x, lam)
    call gis_build(env, lam, 0.0_wp, 6, res, err)
    call check(.not. allocated(err) .and. res%r == 6, "gis exact ties: six steps")
    if (res%r == 6) then
      ! norms^2 8 8 8 8 8 -> 1 (coord 1); 4 8 8 8 4 -> 2 (coord 2); 4 4 8 4 4 -> 3 (coord 4);
      ! 4 4 4 4 4 -> 1 (coord 6); 0 4 4 4 0 -> 2 (coord 3); 0 0 4 0 0 -> 3 (coord 5)
      call check(all(res%indices == [1, 2, 4, 6, 3, 5]), "gis exact ties: coordinates 1, 2, 4, 6, 3, 5")
      call check(all(res%sigma == [1_i8, 2_i8, 3_i8, 1_i8, 2_i8, 3_i8]), "gis exact ties: snapshots 1, 2, 3, 1, 2, 3")
    end if
  end subroutine test_gis_ties

  !> mCPG's first snapshot with two norms tied within the tolerance across the ranks' blocks:
  !> the lower column wins at every rank count.
  subroutine test_mcpg_tie()
    real(wp) :: x(3, 4)
    type(sparse_columns_t) :: lam
    type(cone_result_t) :: res
    type(error_t), allocatable :: err
    x(:, 1) = [1, 0, 0]; x(:, 2) = [0, 2, 0]
    x(:, 3) = [0, 0, 1]; x(:, 4) = [0.0_wp, 0.0_wp, 2 * (1 + 0.25_wp * tol)]
    call distribute(env, x, lam)
    call mcpg_build(env, lam, 0.0_wp, 1, res, err)
    call check(.not. allocated(err) .and. res%r == 1, "mcpg near tie: one vector")
    if (res%r == 1) call check(res%sigma(1) == 2_i8, "mcpg near tie: snapshot 2 at " // str(env%size) // &
      " ranks, got " // str(res%sigma(1)))
  end subroutine test_mcpg_tie
end program test_ties
