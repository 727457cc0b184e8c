!> The passive set P of the sparse dual active-set projection as a list of rows in increasing
!> order, st%alist(1:st%nact), kept equal to the mask st%act, with the right-hand side of the
!> solves on P (st%bp: B v - d on P, zero elsewhere).
module cr_sparse_as_lists
  use cr_kinds, only: wp
  use cr_sort, only: lower_bound
  use cr_sparse_as_state, only: sparse_as_state_t
  implicit none
  private
  public :: list_from_mask, list_prune, list_merge, list_delete, list_insert, lam_from_z, &
    nonpositive_on_p, copy_on_list

contains

  !> The list of P (alist, nact) and the right-hand side bp from the mask act.
  subroutine list_from_mask(st)
    type(sparse_as_state_t), intent(inout) :: st
    integer :: jj
    st%nact = 0
    do jj = 1, st%m
      if (st%act(jj)) then
        st%nact = st%nact + 1; st%alist(st%nact) = jj
        st%bp(jj) = st%cc(jj)
      else
        st%bp(jj) = 0.0_wp
      end if
    end do
  end subroutine list_from_mask

  !> Rows whose mask went off (removals, dependent rows) leave the list of P.
  subroutine list_prune(st)
    type(sparse_as_state_t), intent(inout) :: st
    integer :: q, n, jj
    n = 0
    do q = 1, st%nact
      jj = st%alist(q)
      if (st%act(jj)) then
        n = n + 1; st%alist(n) = jj
      else
        st%bp(jj) = 0.0_wp
      end if
    end do
    st%nact = n
  end subroutine list_prune

  !> Rows rows(1:n) entered P (masks on): into the list, in order (a few one by one, more
  !> by one merge from the back when rows is increasing).
  subroutine list_merge(st, n, rows)
    type(sparse_as_state_t), intent(inout) :: st
    integer, intent(in) :: n, rows(:)
    integer :: q, i, k
    logical :: one_by_one
    one_by_one = n <= 8
    do q = 2, n
      if (rows(q) <= rows(q - 1)) one_by_one = .true.
    end do
    if (one_by_one) then
      do k = 1, n
        call list_insert(st, rows(k))
      end do
      return
    end if
    i = st%nact; k = n
    do q = st%nact + n, 1, -1
      if (k == 0) exit
      if (i > 0) then
        if (st%alist(i) > rows(k)) then
          st%alist(q) = st%alist(i); i = i - 1
          cycle
        end if
      end if
      st%alist(q) = rows(k); st%bp(rows(k)) = st%cc(rows(k)); k = k - 1
    end do
    st%nact = st%nact + n
  end subroutine list_merge

  !> Row tt left P (mask off): out of the list.
  subroutine list_delete(st, tt)
    type(sparse_as_state_t), intent(inout) :: st
    integer, intent(in) :: tt
    integer :: lo, n
    st%bp(tt) = 0.0_wp
    n = st%nact
    lo = lower_bound(st%alist(1:n), tt)
    if (lo > n) return
    if (st%alist(lo) /= tt) return
    st%alist(lo:n - 1) = st%alist(lo + 1:n)
    st%nact = n - 1
  end subroutine list_delete

  !> Row tt entered P (mask on): into the list, in order.
  subroutine list_insert(st, tt)
    type(sparse_as_state_t), intent(inout) :: st
    integer, intent(in) :: tt
    integer :: lo, n
    st%bp(tt) = st%cc(tt)
    ! the first position whose row exceeds tt (binary search), then shift the tail
    n = st%nact
    lo = lower_bound(st%alist(1:n), tt)
    if (lo <= n) st%alist(lo + 1:n + 1) = st%alist(lo:n)
    st%alist(lo) = tt
    st%nact = n + 1
  end subroutine list_insert

  !> lambda = z on P, zero elsewhere.
  subroutine lam_from_z(st)
    type(sparse_as_state_t), intent(inout) :: st
    integer :: q, jj
    st%lam(1:st%m) = 0.0_wp
    do q = 1, st%nact
      jj = st%alist(q); st%lam(jj) = st%z(jj)
    end do
  end subroutine lam_from_z

  !> The rows of P (in list order) where x <= 0: viol(1:nv).
  subroutine nonpositive_on_p(st, x)
    type(sparse_as_state_t), intent(inout) :: st
    real(wp), intent(in) :: x(:)
    integer :: q, jj
    st%nv = 0
    do q = 1, st%nact
      jj = st%alist(q)
      if (x(jj) <= 0.0_wp) then
        st%nv = st%nv + 1; st%viol(st%nv) = jj
      end if
    end do
  end subroutine nonpositive_on_p

  !> dst = src on the list of P.
  pure subroutine copy_on_list(nact, alist, src, dst)
    integer, intent(in) :: nact, alist(nact)
    real(wp), intent(in) :: src(*)
    real(wp), intent(inout) :: dst(*)
    integer :: q
    do q = 1, nact
      dst(alist(q)) = src(alist(q))
    end do
  end subroutine copy_on_list
end module cr_sparse_as_lists
