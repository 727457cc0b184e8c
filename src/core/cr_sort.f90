!> Sorting and searching helpers: contact identities, and the largest entry with ties broken
!> by index (near_max_index).
module cr_sort
  use cr_kinds, only: wp, i8
  implicit none
  private
  public :: argsort_i8, bsearch_i8, lower_bound, near_max_index

contains

  !> Stable ascending argsort of int64 keys (merge sort, O(n log n)): keys(idx) is sorted.
  subroutine argsort_i8(keys, idx)
    integer(i8), intent(in) :: keys(:)
    integer, intent(out) :: idx(:)
    integer, allocatable :: tmp(:)
    integer :: n, width, lo, mid, hi, i, j, k
    n = size(keys)
    do k = 1, n
      idx(k) = k
    end do
    if (n < 2) return
    allocate(tmp(n))
    width = 1
    do while (width < n)
      lo = 1
      do while (lo <= n)
        mid = min(lo + width - 1, n)
        hi = min(lo + 2 * width - 1, n)
        i = lo; j = mid + 1; k = lo
        do while (i <= mid .and. j <= hi)
          if (keys(idx(j)) < keys(idx(i))) then
            tmp(k) = idx(j); j = j + 1
          else
            tmp(k) = idx(i); i = i + 1
          end if
          k = k + 1
        end do
        do while (i <= mid)
          tmp(k) = idx(i); i = i + 1; k = k + 1
        end do
        do while (j <= hi)
          tmp(k) = idx(j); j = j + 1; k = k + 1
        end do
        lo = lo + 2 * width
      end do
      idx(1:n) = tmp(1:n)
      width = 2 * width
    end do
  end subroutine argsort_i8

  !> Position of `key` in the ascending array `sorted`, or 0 if absent.
  pure integer function bsearch_i8(sorted, key) result(pos)
    integer(i8), intent(in) :: sorted(:)
    integer(i8), intent(in) :: key
    integer :: lo, hi, mid
    pos = 0
    lo = 1; hi = size(sorted)
    do while (lo <= hi)
      mid = (lo + hi) / 2
      if (sorted(mid) == key) then
        pos = mid; return
      else if (sorted(mid) < key) then
        lo = mid + 1
      else
        hi = mid - 1
      end if
    end do
  end function bsearch_i8

  !> First position of the ascending array `sorted` whose value is >= `key` (size + 1 if none).
  pure integer function lower_bound(sorted, key) result(lo)
    integer, intent(in) :: sorted(:)
    integer, intent(in) :: key
    integer :: hi, mid
    lo = 1; hi = size(sorted) + 1
    do while (lo < hi)
      mid = (lo + hi) / 2
      if (sorted(mid) < key) then
        lo = mid + 1
      else
        hi = mid
      end if
    end do
  end function lower_bound

  !> The lowest index i (with mask(i), if given) whose x(i) is within a relative sqrt(eps) of
  !> the largest such x: values that tie in exact arithmetic but come out a few eps apart, in
  !> an order set by the CPU's BLAS kernels or the number of ranks, give the same choice on
  !> every machine (sqrt(eps) ~ 1.5e-8 is far above that rounding and far below genuine
  !> differences). 0 when no entry is selected by mask.
  pure integer function near_max_index(x, mask) result(i)
    real(wp), intent(in) :: x(:)
    logical, intent(in), optional :: mask(:)
    real(wp) :: big
    integer :: k
    i = 0
    if (present(mask)) then
      if (.not. any(mask)) return
      big = maxval(x, mask=mask)
    else
      if (size(x) == 0) return
      big = maxval(x)
    end if
    do k = 1, size(x)
      if (present(mask)) then
        if (.not. mask(k)) cycle
      end if
      if (x(k) >= big - sqrt(epsilon(1.0_wp)) * abs(big)) then
        i = k
        return
      end if
    end do
  end function near_max_index
end module cr_sort
