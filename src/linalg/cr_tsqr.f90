!> Tall-skinny QR of a matrix distributed by contiguous blocks of rows (TSQR).
!>
!> Each rank reduces its block A_r [n_r, n] to an upper-trapezoidal factor (Householder QR
!> when n_r > n, the block itself otherwise); the factors are merged up a binary tree
!> (rank r receives from r + step at step = 1, 2, 4, ...) by QR of the stacked pair whenever
!> the stack has more than n rows. The R factor ends on rank 0. If asked, the orthonormal
!> factor is formed by pushing the top-level identity back down the tree, so that
!> A = Q R with Q distributed like A. R is unique up to the signs of its rows, so the
!> singular values and right singular vectors of R do not depend on the number of ranks.
module cr_tsqr
  use cr_kinds, only: wp
  use cr_env, only: env_t
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_lapack, only: la_geqrf, la_orgqr, la_gemm
  implicit none
  private
  public :: tsqr

  !> One merge done by this rank on the way up.
  type :: merge_t
    integer :: partner = -1, m_a = 0, m_b = 0, m_out = 0, level = 0
    logical :: has_q = .false.
    real(wp), allocatable :: q(:, :)   ! [m_a + m_b, m_out] when has_q
  end type merge_t

contains

  !> QR of A [n_total, n] whose rows are distributed: a_local [n_r, n] on each rank.
  !> r [m, n] (m = min(n_total, n), upper trapezoidal up to row signs) is returned on
  !> rank 0 (zero-sized elsewhere); if present, q_local [n_r, m] receives this rank's rows
  !> of the orthonormal factor Q. Collective; the error is the same on all ranks.
  subroutine tsqr(env, a_local, r, error, q_local)
    type(env_t), intent(in) :: env
    real(wp), contiguous, intent(in) :: a_local(:, :)
    real(wp), allocatable, intent(out) :: r(:, :)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable, intent(out), optional :: q_local(:, :)
    integer :: n, n_r, m, step, partner, m_b, nmerge, i, lvl
    logical :: want_q, leaf_q, failed
    real(wp), allocatable :: leaf(:, :), tau(:), rb(:, :), stacked(:, :), c(:, :), cab(:, :)
    type(merge_t) :: merges(32)
    integer :: parent, m_up, nn(2)
    type(error_t), allocatable :: e_mpi

    n = size(a_local, 2)
    n_r = size(a_local, 1)
    want_q = present(q_local)
    failed = .false.
    nn = [n, -n]
    call env%allreduce(nn, 'max', error)
    if (allocated(error)) return
    if (nn(1) /= -nn(2)) then
      call set_error(error, "tsqr: the number of columns differs between ranks")
      return
    end if

    ! leaf: reduce the local block
    leaf_q = n_r > n
    if (leaf_q) then
      allocate(leaf, source=a_local)
      allocate(tau(n))
      call la_geqrf(leaf, tau, error)
      if (allocated(error)) failed = .true.
      r = upper(leaf(1:n, :))
      if (want_q .and. .not. failed) then
        call la_orgqr(leaf, tau, error)
        if (allocated(error)) failed = .true.
      end if
      deallocate(tau)
    else
      allocate(r, source=a_local)
    end if

    ! up the tree
    nmerge = 0
    parent = -1
    step = 1
    lvl = 0
    do while (step < env%size)
      lvl = lvl + 1
      if (mod(env%rank, 2 * step) == 0) then
        partner = env%rank + step
        if (partner < env%size) then
          m_b = 0
          call env%recv(m_b, partner, 100 + lvl, e_mpi)
          call keep(e_mpi)
          allocate(rb(m_b, n))
          if (m_b * n > 0) call env%recv(rb, partner, 100 + lvl, e_mpi)
          call keep(e_mpi)
          nmerge = nmerge + 1
          merges(nmerge)%partner = partner
          merges(nmerge)%level = lvl
          merges(nmerge)%m_a = size(r, 1)
          merges(nmerge)%m_b = m_b
          allocate(stacked(size(r, 1) + m_b, n))
          stacked(1:size(r, 1), :) = r
          stacked(size(r, 1) + 1:, :) = rb
          deallocate(rb, r)
          if (size(stacked, 1) > n) then
            allocate(tau(n))
            call la_geqrf(stacked, tau, error)
            if (allocated(error)) failed = .true.
            r = upper(stacked(1:n, :))
            merges(nmerge)%m_out = n
            if (want_q .and. .not. failed) then
              call la_orgqr(stacked, tau, error)
              if (allocated(error)) failed = .true.
              merges(nmerge)%has_q = .true.
              call move_alloc(stacked, merges(nmerge)%q)
            end if
            deallocate(tau)
            if (allocated(stacked)) deallocate(stacked)
          else
            merges(nmerge)%m_out = size(stacked, 1)
            call move_alloc(stacked, r)
          end if
        end if
      else if (mod(env%rank, 2 * step) == step) then
        parent = env%rank - step
        m_up = size(r, 1)
        call env%send(m_up, parent, 100 + lvl, e_mpi)
        call keep(e_mpi)
        if (m_up * n > 0) call env%send(r, parent, 100 + lvl, e_mpi)
        call keep(e_mpi)
        exit
      end if
      step = 2 * step
    end do

    call env%agree_error(error)
    if (allocated(error)) return

    ! size of the final R, known to all
    m = 0
    if (env%rank == 0) m = size(r, 1)
    call env%bcast(m, error, root=0)
    if (allocated(error)) return
    if (env%rank /= 0) then
      deallocate(r)
      allocate(r(0, n))
    end if
    if (.not. want_q) return

    ! down the tree: c holds this node's rows of the top-level identity, transformed
    if (env%rank == 0) then
      allocate(c(m, m))
      c = 0.0_wp
      do i = 1, m
        c(i, i) = 1.0_wp
      end do
    else
      allocate(c(m_up, m))
      if (m_up * m > 0) call env%recv(c, parent, 200 + lvl, error)
      if (allocated(error)) return
    end if
    do i = nmerge, 1, -1
      associate (mg => merges(i))
        allocate(cab(mg%m_a + mg%m_b, m))
        if (mg%has_q) then
          call la_gemm('N', 'N', 1.0_wp, mg%q, c, 0.0_wp, cab, error)
          if (allocated(error)) return
        else
          cab = c
        end if
        if (mg%m_b * m > 0) then
          rb = cab(mg%m_a + 1:, :)
          call env%send(rb, mg%partner, 200 + mg%level, error)
          if (allocated(error)) return
        end if
        c = cab(1:mg%m_a, :)
        deallocate(cab)
      end associate
    end do
    allocate(q_local(n_r, m))
    if (leaf_q) then
      call la_gemm('N', 'N', 1.0_wp, leaf, c, 0.0_wp, q_local, error)
    else
      q_local = c
    end if
    call env%agree_error(error)

  contains

    !> Keep the first error of the way up (the tree goes on so that no rank waits forever).
    subroutine keep(e)
      type(error_t), allocatable, intent(inout) :: e
      if (.not. allocated(e)) return
      failed = .true.
      if (.not. allocated(error)) call move_alloc(e, error)
      if (allocated(e)) deallocate(e)
    end subroutine keep
  end subroutine tsqr

  !> Upper-trapezoidal part of a [m, n].
  pure function upper(a) result(u)
    real(wp), intent(in) :: a(:, :)
    real(wp), allocatable :: u(:, :)
    integer :: j
    allocate(u(size(a, 1), size(a, 2)))
    u = 0.0_wp
    do j = 1, size(a, 2)
      u(1:min(j, size(a, 1)), j) = a(1:min(j, size(a, 1)), j)
    end do
  end function upper
end module cr_tsqr
