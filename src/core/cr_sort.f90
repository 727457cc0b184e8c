!> Sorting and searching helpers for contact identities.
module cr_sort
  use cr_kinds, only: i8
  implicit none
  private
  public :: argsort_i8, bsearch_i8, lower_bound

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
end module cr_sort
