!> Slots and analysis reuse of the sparse dual active-set projection. The analysed matrix (M
!> restricted to the set W of rows that can become active) is indexed by slots, one per row
!> analysed, named by the row's contact identity in a hash table. M's pattern between two rows
!> depends only on their identities (they share an agent), so a later solve whose rows that may
!> become active all have a slot factorises on the same analysis (reuse_slots); a violated row
!> without a slot takes an empty tail slot (tail_slot) or enlarges W (enlarge_w, a fresh
!> analysis).
module cr_sparse_as_slots
  use cr_kinds, only: wp, i8
  use cr_grow, only: igrow => grow_int, rgrow => grow_real, grow_kept_int, grow_kept_real
  use cr_error, only: error_t
  use cr_contact_set, only: contact_set_t
  use cr_sparse_as_settings, only: sparse_as_settings_t
  use cr_sparse_as_state, only: sparse_as_state_t
  use cr_sparse_as_rows, only: slacks
  implicit none
  private
  public :: order_and_analyze, enlarge_w

contains

  !> Analyse M restricted to the rows of W (AMD ordering), in slot space: slot k is the k-th row
  !> of W, the other rows have no slot (they never enter the factor). Without fresh and with
  !> reuse_analysis, the previous analysis is kept when every row that may become active has a
  !> slot in it (reuse_slots); a fresh analysis widens W to the a_margin rows first (unless fresh:
  !> the enlargement of a solve, which sets W itself). Reusing the previous call's ordering by
  !> contact identity with a fresh symbolic analysis (CHOLMOD_GIVEN) was measured and is not
  !> cheaper: the symbolic analysis costs about as much as AMD on these graphs.
  subroutine order_and_analyze(st, kn, cs, fresh, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(contact_set_t), intent(in) :: cs
    logical, intent(in) :: fresh
    type(error_t), allocatable, intent(inout) :: error
    integer :: jj, k
    logical :: ok
    if (.not. fresh .and. kn%reuse_analysis) then
      call reuse_slots(st, kn, cs, ok, error)
      if (ok) return
      if (allocated(error)) return
    end if
    if (.not. fresh .and. kn%a_margin > kn%w_margin .and. kn%w_margin >= 0.0_wp) then
      do jj = 1, st%m
        if (st%cc(jj) > -kn%a_margin * st%sv) st%inw(jj) = .true.
      end do
    end if
    call igrow(st%rslot, st%m)
    k = 0
    do jj = 1, st%m
      st%rslot(jj) = 0
      if (st%inw(jj)) then
        k = k + 1; st%rslot(jj) = k
      end if
    end do
    ! and the tail slots k + 1 .. ns (empty columns)
    st%ns = k + max(kn%tail_slots, 0)
    ! no reuse of this analysis until it is complete
    st%keys_ok = .false.
    call analyze_w(st, k, error); if (allocated(error)) return
    call st%chol%set_rows(st%rslot(1:st%m), error)
    if (allocated(error)) return
    st%n_analyse = st%n_analyse + 1
    call name_slots(st, cs)
  end subroutine order_and_analyze

  !> The upper triangle of M on W in slot space (wptr, wi, wv; k slots with a row, then the
  !> empty tail slots up to ns) handed to the analysis.
  subroutine analyze_w(st, k, error)
    type(sparse_as_state_t), intent(inout) :: st
    integer, intent(in) :: k
    type(error_t), allocatable, intent(inout) :: error
    integer :: jj, q, nzw
    ! slot numbers grow with the row number: sorted columns stay sorted
    call igrow(st%wptr, st%ns + 1); call igrow(st%wi, max(st%nzu, 1))
    call rgrow(st%wv, max(st%nzu, 1))
    nzw = 0
    do jj = 1, st%m
      if (.not. st%inw(jj)) cycle
      st%wptr(st%rslot(jj)) = nzw + 1
      do q = st%fp(jj), st%fd(jj)
        if (st%inw(st%fi(q))) then
          nzw = nzw + 1
          st%wi(nzw) = st%rslot(st%fi(q)); st%wv(nzw) = st%fv(q)
        end if
      end do
    end do
    st%wptr(k + 1:st%ns + 1) = nzw + 1
    call st%chol%analyze(st%ns, st%wptr, st%wi, st%wv, error, ntail=st%ns - k)
  end subroutine analyze_w

  !> The slots' identities in a hash table (at most half full), for the next solves.
  subroutine name_slots(st, cs)
    type(sparse_as_state_t), intent(inout) :: st
    type(contact_set_t), intent(in) :: cs
    integer :: q, jj
    q = 16
    do while (q < 2 * st%ns)
      q = 2 * q
    end do
    if (allocated(st%hkey)) then
      if (size(st%hkey) < q) deallocate(st%hkey, st%hslot)
    end if
    if (.not. allocated(st%hkey)) allocate(st%hkey(0:q - 1), st%hslot(0:q - 1))
    st%hmask = q - 1
    st%hslot(0:q - 1) = 0
    st%keys_ok = .true.
    do jj = 1, st%m
      if (st%inw(jj)) call slot_insert(st, cs%key(jj), st%rslot(jj))
    end do
  end subroutine name_slots

  !> Name slot k by contact identity key in the slot table (two rows with one identity: no
  !> reuse of this analysis, never expected of a contact set).
  subroutine slot_insert(st, key, k)
    type(sparse_as_state_t), intent(inout) :: st
    integer(i8), intent(in) :: key
    integer, intent(in) :: k
    integer :: q
    q = key_hash(key, st%hmask)
    do while (st%hslot(q) /= 0)
      if (st%hkey(q) == key) st%keys_ok = .false.
      q = iand(q + 1, st%hmask)
    end do
    st%hkey(q) = key; st%hslot(q) = k
  end subroutine slot_insert

  !> The previous analysis serves this solve when every row that may become active (warm start,
  !> slack at u = v below r_margin velocity scales) has a slot (found by its contact identity), no
  !> two rows share one, and at least reuse_fill of the slots hold a row. Then W becomes every row
  !> with a slot, M is handed over in slot space (same pattern as analysed or a part of it) and ok
  !> is true.
  subroutine reuse_slots(st, kn, cs, ok, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(contact_set_t), intent(in) :: cs
    logical, intent(out) :: ok
    type(error_t), allocatable, intent(inout) :: error
    integer :: jj, k, nzs, nin, nneed, m
    ok = .false.
    if (.not. st%keys_ok .or. st%ns == 0) return
    m = st%m
    call igrow(st%rslot, m); call igrow(st%smark, st%ns)
    st%smark(1:st%ns) = 0
    nin = 0; nneed = 0
    do jj = 1, m
      k = find_slot(st, cs%key(jj))
      if (k > 0) then
        if (st%smark(k) /= 0) return
        st%smark(k) = jj; nin = nin + 1
      else if (st%lam(jj) > 0.0_wp .or. st%cc(jj) > -kn%r_margin * st%sv) then
        ! may become active without a slot: a tail slot below, while they last
        nneed = nneed + 1
        if (nneed > st%chol%tail_free()) return
        st%rem(nneed) = jj
      end if
      st%rslot(jj) = k
    end do
    if (real(nin, wp) < kn%reuse_fill * real(st%ns - st%chol%tail_free(), wp)) return
    ! the values of M on the analysed pattern (slot_values; M is assembled exactly
    ! symmetric, so the values are those of the row-space upper triangle); an entry outside
    ! the pattern (never expected: the same slots keep the same neighbours) means no reuse
    nzs = st%wptr(st%ns + 1) - 1
    call igrow(st%spos, st%ns); call igrow(st%scol, st%ns)
    call slot_values(m, st%ns, st%rslot, st%fp, st%fi, st%fv, st%wptr, st%wi, &
      st%wv, st%spos, st%scol, ok)
    if (.not. ok) then
      st%keys_ok = .false.; return
    end if
    ok = .false.
    call st%chol%set_analysed_values(st%wv(1:nzs), error)
    if (allocated(error)) then
      ! the analysis does not match (never expected): analyse afresh
      deallocate(error); st%keys_ok = .false.; return
    end if
    call st%chol%set_rows(st%rslot(1:m), error)
    if (allocated(error)) return
    do jj = 1, m
      st%inw(jj) = st%rslot(jj) > 0
    end do
    do k = 1, nneed
      call tail_slot(st, cs, st%rem(k), error); if (allocated(error)) return
    end do
    st%n_reuse = st%n_reuse + 1
    ok = .true.
  end subroutine reuse_slots

  !> Slot of the analysis named by contact identity key (0: none).
  integer function find_slot(st, key) result(k)
    type(sparse_as_state_t), intent(in) :: st
    integer(i8), intent(in) :: key
    integer :: q
    q = key_hash(key, st%hmask)
    k = 0
    do while (st%hslot(q) /= 0)
      if (st%hkey(q) == key) then
        k = st%hslot(q); return
      end if
      q = iand(q + 1, st%hmask)
    end do
  end function find_slot

  !> Rows viol(1:n) must be able to enter: those outside W take tail slots while enough are
  !> left (tail_slot: the analysis grows, the factor stays); otherwise W takes them and every
  !> row whose current slack is below the margin, M is analysed again and P refactorised. The
  !> margin doubles at each enlargement of a solve, so that a solve re-analyses a few times
  !> at most (W soon holds every row).
  subroutine enlarge_w(st, kn, cs, v, n, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(sparse_as_settings_t), intent(in) :: kn
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    integer, intent(in) :: n
    type(error_t), allocatable, intent(inout) :: error
    integer :: q
    if (all(st%inw(st%viol(1:n)))) return
    if (count(.not. st%inw(st%viol(1:n))) <= st%chol%tail_free()) then
      ! tail slots for the rows without one: the analysis grows, the factor stays
      do q = 1, n
        if (.not. st%inw(st%viol(q))) then
          call tail_slot(st, cs, st%viol(q), error); if (allocated(error)) return
        end if
      end do
      return
    end if
    st%inw(st%viol(1:n)) = .true.
    st%wmarg = 2.0_wp * st%wmarg
    call slacks(st, v)
    do q = 1, st%m
      if (st%slack(q) < st%wmarg * st%sv) st%inw(q) = .true.
    end do
    st%n_reanalyse = st%n_reanalyse + 1
    call order_and_analyze(st, kn, cs, .true., error); if (allocated(error)) return
    call st%chol%factor(st%act(1:st%m), error)
  end subroutine enlarge_w

  !> Give row jr (no slot) the next tail slot: its column of the slot-space upper triangle
  !> (the rows of its agents that have a slot, then its diagonal) joins the analysed
  !> pattern (wptr, wi: the next solves put their values there) and the analysis in the shim;
  !> its identity joins the slot table.
  subroutine tail_slot(st, cs, jr, error)
    type(sparse_as_state_t), intent(inout) :: st
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: jr
    type(error_t), allocatable, intent(inout) :: error
    integer :: q, e, sl, cnt, kk, p
    real(wp) :: x
    sl = st%ns - st%chol%tail_free() + 1
    e = st%wptr(sl)
    q = e - 1 + st%fp(jr + 1) - st%fp(jr)
    if (size(st%wi) < q) call grow_kept_int(st%wi, 2 * q, e - 1)
    if (size(st%wv) < q) call grow_kept_real(st%wv, 2 * q, e - 1)
    cnt = 0
    do q = st%fp(jr), st%fp(jr + 1) - 1
      kk = st%fi(q)
      if (kk == jr .or. st%rslot(kk) == 0) cycle
      ! by increasing slot (insertion: a few entries)
      kk = st%rslot(kk); x = st%fv(q)
      p = e + cnt
      do while (p > e)
        if (st%wi(p - 1) < kk) exit
        st%wi(p) = st%wi(p - 1); st%wv(p) = st%wv(p - 1)
        p = p - 1
      end do
      st%wi(p) = kk; st%wv(p) = x
      cnt = cnt + 1
    end do
    cnt = cnt + 1
    st%wi(e + cnt - 1) = sl; st%wv(e + cnt - 1) = st%fv(st%fd(jr))
    call st%chol%add_slot(sl, st%wi(e:e + cnt - 1), st%wv(e:e + cnt - 1), jr, error)
    if (allocated(error)) return
    st%wptr(sl + 1:st%ns + 1) = e + cnt
    st%rslot(jr) = sl; st%inw(jr) = .true.
    call slot_insert(st, cs%key(jr), sl)
    st%n_tail = st%n_tail + 1
  end subroutine tail_slot

  !> reuse_slots: the values of M on the analysed pattern (wptr, wi: upper triangle in slot
  !> space, rows increasing in each column): slot column b = rslot(jj) takes the entries of
  !> the whole column jj of M whose row has a slot a <= b, each found through the positions
  !> of column b's rows scattered first (spos, scol [ns]: work). ok is false when an entry
  !> lies outside the pattern.
  pure subroutine slot_values(m, ns, rslot, fp, fi, fv, wptr, wi, wv, spos, scol, ok)
    integer, intent(in) :: m, ns, rslot(m), fp(m + 1), fi(*), wptr(ns + 1), wi(*)
    real(wp), intent(in) :: fv(*)
    real(wp), intent(inout) :: wv(*)
    integer, intent(inout) :: spos(ns), scol(ns)
    logical, intent(out) :: ok
    integer :: jj, a, b, p, q
    ok = .false.
    wv(1:wptr(ns + 1) - 1) = 0.0_wp
    scol = 0
    do jj = 1, m
      b = rslot(jj)
      if (b == 0) cycle
      do p = wptr(b), wptr(b + 1) - 1
        spos(wi(p)) = p; scol(wi(p)) = b
      end do
      do q = fp(jj), fp(jj + 1) - 1
        a = rslot(fi(q))
        if (a == 0 .or. a > b) cycle
        if (scol(a) /= b) return
        wv(spos(a)) = fv(q)
      end do
    end do
    ok = .true.
  end subroutine slot_values

  !> Position of a contact identity (agent pair or agent-obstacle pair: two 31-bit halves) in
  !> a hash table of mask + 1 (a power of two) entries; no integer overflow.
  pure integer function key_hash(key, mask) result(q)
    integer(i8), intent(in) :: key
    integer, intent(in) :: mask
    integer(i8) :: hi, lo, h
    hi = ishft(key, -32); lo = iand(key, 4294967295_i8)
    h = ieor(lo * 1000003_i8, hi * 2750159_i8)
    h = ieor(h, ishft(h, -17))
    q = int(iand(h, int(mask, i8)))
  end function key_hash
end module cr_sparse_as_slots
