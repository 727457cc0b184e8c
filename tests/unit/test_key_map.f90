!> Unit tests of cr_key_map: hits, misses, an empty (or never initialised) map, duplicate keys
!> (refused, first value kept), growth past the initial capacity, clear / refill across many
!> generations, and agreement with the sorted-keys binary search it replaces on contact keys.
program test_key_map
  use cr_kinds, only: wp, i8
  use cr_assert, only: check, test_summary
  use cr_key_map, only: key_map_t
  use cr_contact_set, only: contact_key
  use cr_sort, only: argsort_i8, bsearch_i8
  implicit none
  type(key_map_t) :: m, fresh
  integer(i8), allocatable :: keys(:), sorted(:)
  real(wp), allocatable :: vals(:)
  integer, allocatable :: idx(:)
  integer :: k, nref, pos, nbad, gen
  logical :: found, added
  real(wp) :: x

  ! -- a map never initialised, and an empty one: every lookup misses
  x = fresh%get(7_i8, -1.0_wp, found)
  call check(.not. found .and. x == -1.0_wp, "uninitialised map: miss, default returned")
  call m%init()
  x = m%get(0_i8, 2.5_wp, found)
  call check(.not. found .and. x == 2.5_wp, "empty map: miss")
  call m%fill([integer(i8) ::], [real(wp) ::])
  call check(m%n == 0, "fill with no keys: empty")
  x = m%get(contact_key(1, 2, 0), 0.0_wp, found)
  call check(.not. found .and. x == 0.0_wp, "empty previous set: miss")

  ! -- hits and misses, extreme keys (no sentinel value)
  call m%put(contact_key(1, 2, 0), 1.5_wp)
  call m%put(contact_key(1, 0, 3), 2.5_wp)
  call m%put(-huge(1_i8) - 1_i8, 3.5_wp)
  call m%put(huge(1_i8), 4.5_wp)
  call m%put(0_i8, 5.5_wp)
  call check(m%n == 5, "five keys stored")
  call check(m%get(contact_key(2, 1, 0), 0.0_wp) == 1.5_wp, "hit: pair key (either order)")
  call check(m%get(contact_key(1, 0, 3), 0.0_wp) == 2.5_wp, "hit: obstacle key")
  call check(m%get(-huge(1_i8) - 1_i8, 0.0_wp) == 3.5_wp, "hit: most negative key")
  call check(m%get(huge(1_i8), 0.0_wp) == 4.5_wp, "hit: largest key")
  call check(m%get(0_i8, 0.0_wp) == 5.5_wp, "hit: key 0")
  x = m%get(contact_key(1, 3, 0), -2.0_wp, found)
  call check(.not. found .and. x == -2.0_wp, "miss: other pair")
  x = m%get(contact_key(1, 0, 2), -2.0_wp, found)
  call check(.not. found .and. x == -2.0_wp, "miss: other obstacle of the same agent")

  ! -- duplicates are refused: the first value stays
  call m%put(contact_key(1, 2, 0), 9.0_wp, added)
  call check(.not. added, "duplicate put refused")
  call check(m%get(contact_key(1, 2, 0), 0.0_wp) == 1.5_wp .and. m%n == 5, "duplicate: first value kept")
  call m%fill([10_i8, 11_i8, 10_i8, 12_i8, 11_i8], [1.0_wp, 2.0_wp, 3.0_wp, 4.0_wp, 5.0_wp], n_refused=nref)
  call check(nref == 2 .and. m%n == 3, "fill: two duplicates counted, three keys stored")
  call check(m%get(10_i8, 0.0_wp) == 1.0_wp .and. m%get(11_i8, 0.0_wp) == 2.0_wp, "fill: first values kept")
  call check(m%get(contact_key(1, 0, 3), -1.0_wp) == -1.0_wp, "fill replaces the previous content")

  ! -- fill with a mask (the reduced stepper keeps positive multipliers only)
  call m%fill([1_i8, 2_i8, 3_i8], [0.5_wp, 0.0_wp, 2.0_wp], keep=[.true., .false., .true.])
  x = m%get(2_i8, -1.0_wp, found)
  call check(m%n == 2 .and. .not. found .and. m%get(3_i8, 0.0_wp) == 2.0_wp, "fill with keep mask")

  ! -- growth from a small table, and agreement with argsort + binary search
  call m%init(4)
  allocate(keys(5000), vals(5000), idx(5000))
  do k = 1, 5000
    if (mod(k, 3) == 0) then
      keys(k) = contact_key(k, 0, mod(k, 7) + 1)
    else
      keys(k) = contact_key(k, k + 1 + mod(7 * k, 40), 0)
    end if
    vals(k) = real(k, wp) * 0.25_wp
    call m%put(keys(k), vals(k))
  end do
  call check(m%n == 5000, "growth: 5000 keys stored from capacity 4")
  call argsort_i8(keys, idx)
  sorted = keys(idx)
  nbad = 0
  do k = 1, 5000
    ! queries: the stored keys, and neighbours of them (mostly misses)
    pos = bsearch_i8(sorted, keys(k))
    if (m%get(keys(k), -1.0_wp) /= vals(idx(pos))) nbad = nbad + 1
    pos = bsearch_i8(sorted, keys(k) + 1_i8)
    x = m%get(keys(k) + 1_i8, -1.0_wp, found)
    if ((pos > 0) .neqv. found) nbad = nbad + 1
    if (pos > 0) then
      if (x /= vals(idx(pos))) nbad = nbad + 1
    end if
  end do
  call check(nbad == 0, "same matches as argsort + binary search")

  ! -- clear is O(1) and forgets everything; refilled over many generations
  call m%clear()
  x = m%get(keys(1), -1.0_wp, found)
  call check(m%n == 0 .and. .not. found, "clear forgets every key")
  nbad = 0
  do gen = 1, 200
    call m%fill(keys(gen:gen + 99), vals(gen:gen + 99))
    if (m%n /= 100) nbad = nbad + 1
    if (gen > 1) then
      x = m%get(keys(gen - 1), -1.0_wp, found)
      if (found) nbad = nbad + 1
    end if
    if (m%get(keys(gen + 50), -1.0_wp) /= vals(gen + 50)) nbad = nbad + 1
  end do
  call check(nbad == 0, "200 refills: only the current keys are found")
  call m%free()
  x = m%get(keys(1), -1.0_wp, found)
  call check(.not. found .and. m%n == 0, "free: empty")
  call test_summary()
end program test_key_map
