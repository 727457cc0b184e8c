!> gIS and mCPG on hand-made sparse multiplier snapshots with known answers, distributed
!> over 1, 2 or 4 ranks (contiguous column blocks): the result must not depend on the
!> number of ranks.
program test_cone
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_strings, only: str
  use cr_assert, only: check, check_close, test_summary
  use cr_cone, only: sparse_columns_t, cone_result_t, gis_build, mcpg_build
  use cr_test_columns, only: distribute
  implicit none
  type(env_t) :: env
  type(error_t), allocatable :: error
  integer :: ierr
  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call test_gis_canonical()
  call test_gis_known()
  call test_mcpg_generators()
  call test_empty()
  call test_mcpg_accuracy()
  call env%free()
  call MPI_Finalize(ierr)
  call test_summary(env%rank)

contains

  !> Scaled canonical vectors: gIS picks them by decreasing magnitude, error 0 at the end.
  subroutine test_gis_canonical()
    real(wp) :: x(6, 7)
    type(sparse_columns_t) :: lam
    type(cone_result_t) :: res
    type(error_t), allocatable :: err
    x = 0
    x(3, 1) = 2; x(1, 2) = 5; x(6, 3) = 1; x(3, 4) = 4; x(2, 5) = 3; x(1, 6) = 0.5_wp
    call distribute(env, x, lam)
    call gis_build(env, lam, 0.0_wp, 10, res, err)
    call check(.not. allocated(err), "gis canonical runs")
    call check(res%r == 4, "gis canonical: 4 indices")
    if (res%r == 4) then
      call check(all(res%indices == [1, 3, 2, 6]), "gis canonical: order by magnitude")
      call check(all(res%sigma == [2_i8, 4_i8, 5_i8, 3_i8]), "gis canonical: snapshots")
    end if
    call check_close(res%err_max(size(res%err_max)), 0.0_wp, 0.0_wp, "gis canonical: zero error")
    call check_close(res%err_max(2), 4.0_wp / 5.0_wp, 1e-15_wp, "gis canonical: e_1 = 4/5")
  end subroutine test_gis_canonical

  !> A small case worked by hand.
  subroutine test_gis_known()
    real(wp) :: x(4, 3)
    type(sparse_columns_t) :: lam
    type(cone_result_t) :: res
    type(error_t), allocatable :: err
    ! |col1| = sqrt(10), |col2| = sqrt(13), |col3| = sqrt(8)
    x(:, 1) = [3, 1, 0, 0]; x(:, 2) = [0, 2, 3, 0]; x(:, 3) = [2, 0, 0, 2]
    call distribute(env, x, lam)
    call gis_build(env, lam, 0.0_wp, 2, res, err)
    call check(.not. allocated(err) .and. res%r == 2, "gis known: 2 steps")
    ! step 1: sigma = 2, i = 3 -> residuals^2: 10, 4, 8 -> sigma = 1, i = 1 -> 1, 4, 4
    call check(all(res%indices == [3, 1]), "gis known: indices 3 then 1")
    call check(all(res%sigma == [2_i8, 1_i8]), "gis known: snapshots 2 then 1")
    call check_close(res%err_max(2), sqrt(10.0_wp / 13.0_wp), 1e-15_wp, "gis known: e_1")
    call check_close(res%err_max(3), sqrt(4.0_wp / 13.0_wp), 1e-15_wp, "gis known: e_2 (tie 4 = 4)")
    call check_close(res%err_mean(3), 5.0_wp / 3.0_wp / sqrt(13.0_wp), 1e-15_wp, "gis known: mean error")
  end subroutine test_gis_known

  !> Snapshots in the cone of two generators g1 = (1,1,0,0), g2 = (0,0,1,1): mCPG picks the
  !> largest (3,3,3,3), then (its LSI keeps residuals >= 0) g1 and g2: error 0 at r = 3.
  subroutine test_mcpg_generators()
    real(wp) :: x(4, 6)
    type(sparse_columns_t) :: lam
    type(cone_result_t) :: res
    type(error_t), allocatable :: err
    x(:, 1) = [1, 1, 0, 0]; x(:, 2) = [0, 0, 1, 1]; x(:, 3) = [3, 3, 3, 3]
    x(:, 4) = [2, 2, 1, 1]; x(:, 5) = [0.5_wp, 0.5_wp, 0.0_wp, 0.0_wp]; x(:, 6) = [1, 1, 2, 2]
    call distribute(env, x, lam)
    call mcpg_build(env, lam, 1.0e-12_wp, 10, res, err)
    call check(.not. allocated(err), "mcpg runs")
    if (allocated(err)) print '(a)', err%message
    call check(res%r == 3, "mcpg: 3 vectors")
    if (res%r /= 3) print *, "mcpg r =", res%r, " err =", res%err_max, " sigma =", res%sigma, " note ", res%note
    if (res%r >= 1) call check(res%sigma(1) == 3, "mcpg: starts from the largest snapshot")
    if (res%r == 3) then
      call check_close(minval(res%psi), 0.0_wp, 0.0_wp, "mcpg: cone vectors are non-negative")
      call check(res%err_max(4) <= 1e-12_wp, "mcpg: zero error with 3 vectors")
    end if
  end subroutine test_mcpg_generators

  subroutine test_empty()
    real(wp) :: x(5, 4)
    type(sparse_columns_t) :: lam
    type(cone_result_t) :: res
    type(error_t), allocatable :: err
    x = 0
    call distribute(env, x, lam)
    call gis_build(env, lam, 1e-4_wp, 10, res, err)
    call check(.not. allocated(err) .and. res%r == 0 .and. allocated(res%note), "gis: empty cone, no error")
    call mcpg_build(env, lam, 1e-4_wp, 10, res, err)
    call check(.not. allocated(err) .and. res%r == 0 .and. allocated(res%note), "mcpg: empty cone, no error")
    if (allocated(res%note)) call check(index(res%note, "empty cone") > 0, "says the cone is empty")
  end subroutine test_empty
  !> mCPG at delta = 0 on snapshots lying in the cone of a few sparse non-negative generators
  !> in exact arithmetic the error reaches 0; in floating point it reaches the
  !> accuracy of the Gram-form projections. Checks cr_cone's stated guarantees: the accuracy
  !> history a_r has R + 1 entries and obeys its bound a_r <= sqrt(reg + (64 r + 2 n_rows) eps
  !> (1 + sqrt(r))^2) (|k| <= |x| <= n1 since the psi are non-negative); the computed history
  !> satisfies e_{r+1} <= e_r + a_r + a_{r+1}; the construction stops before r_max with a note,
  !> and when the note says the accuracy was reached, e_R <= a_R.
  subroutine test_mcpg_accuracy()
    integer, parameter :: nrow = 40, ngen = 5, nsnap = 60
    real(wp) :: g(nrow, ngen), x(nrow, nsnap), w(ngen), bound
    type(sparse_columns_t) :: lam
    type(cone_result_t) :: res
    type(error_t), allocatable :: err
    integer :: i, j, k, trial, seed
    character(len=:), allocatable :: name
    do trial = 1, 4
      name = "mcpg accuracy " // str(trial)
      ! deterministic pseudo-random data (identical on every rank)
      seed = 12345 + 7919 * trial
      g = 0
      do j = 1, ngen
        do i = 1, nrow
          if (mod(lcg(seed), 3) == 0) g(i, j) = 0.1_wp + real(mod(lcg(seed), 1000), wp) / 1000.0_wp
        end do
        g(j, j) = 1.0_wp
      end do
      do k = 1, nsnap
        do j = 1, ngen
          w(j) = real(mod(lcg(seed), 1000), wp) / 1000.0_wp
          if (mod(lcg(seed), 4) == 0) w(j) = 0
        end do
        x(:, k) = matmul(g, w)
      end do
      x(:, 1:ngen) = g
      call distribute(env, x, lam)
      call mcpg_build(env, lam, 0.0_wp, 30, res, err)
      call check(.not. allocated(err), name // ": runs")
      if (allocated(err)) cycle
      call check(allocated(res%err_acc), name // ": accuracy history recorded")
      if (.not. allocated(res%err_acc)) cycle
      call check(size(res%err_acc) == res%r + 1 .and. size(res%err_max) == res%r + 1, name // ": R + 1 entries")
      do k = 1, res%r + 1
        bound = sqrt(1.0e-12_wp + real(64 * (k - 1) + 2 * nrow, wp) * epsilon(1.0_wp) * (1 + sqrt(real(k - 1, wp)))**2)
        call check(res%err_acc(k) >= 0 .and. res%err_acc(k) <= bound, name // ": a_" // str(k - 1) // " = " // &
          str(res%err_acc(k)) // " within its bound " // str(bound))
      end do
      do k = 1, res%r
        call check(res%err_max(k + 1) <= res%err_max(k) + res%err_acc(k) + res%err_acc(k + 1), &
          name // ": e_" // str(k) // " <= e_" // str(k - 1) // " + a_" // str(k - 1) // " + a_" // str(k))
      end do
      call check(res%r < 30 .and. allocated(res%note), name // ": stops before r_max with a note (R = " // &
        str(res%r) // ")")
      if (allocated(res%note)) then
        if (index(res%note, "accuracy of the inner cone projections") > 0) &
          call check(res%err_max(res%r + 1) <= res%err_acc(res%r + 1), name // ": e_R <= a_R at the accuracy stop")
      end if
    end do
  end subroutine test_mcpg_accuracy

  !> next value of a small linear congruential generator (non-negative)
  integer function lcg(state)
    integer, intent(inout) :: state
    state = int(mod(1103515245_i8 * state + 12345_i8, 2147483648_i8))
    lcg = state / 65536
  end function lcg
end program test_cone
