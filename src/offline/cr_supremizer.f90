!> Supremizer enrichment of the velocity basis (the paper's PGA, after Niakh et al.):
!> the candidates are the supremizers s_{sigma,r} = B(q_sigma)^T psi_r for every training
!> configuration q_sigma (distributed over the ranks) and cone vector psi_r; the candidate
!> with the largest relative projection error |(I - V V^T) s| / |s| onto the current basis V
!> is orthonormalised into V, until that error is <= delta (or max_add vectors were added).
!>
!> Cost: each candidate has at most 4 nnz(psi_r) non-zeros (2 per obstacle row), so its
!> projections onto the basis are updated in O(nnz(psi_r)) per added vector (no dense
!> n_dof x n_candidates matrix is formed). The squared residuals are tracked as
!> |s|^2 - |V^T s|^2, which loses relative accuracy below ~1e-6; below that level every
!> candidate's residual is recomputed explicitly (s - V (V^T s), orthogonalised twice), so
!> small thresholds such as delta = 1e-8 are decided on exact residuals.
!>
!> The exact residuals are formed per support row, not per candidate: a candidate is
!> s = sum_l (-h psi_{r,l}) M_l g_l(q), where M_l [n_dof, 2] puts a normal g on the dofs of
!> the row's agents (+g on agent a, -g on agent b), so (I - V V^T) s is the same combination
!> of W_l = (I - V V^T) M_l. W_l is projected (twice Gram-Schmidt) once per support row and
!> basis, and each candidate costs O(nnz(psi_r) n_dof) instead of O(n_dof N): for a gIS cone
!> (one row per cone vector) about 2 N times less. The result differs from the per-candidate
!> projection only by rounding (both are accurate to a few eps |s|). When the rows would
!> cost more than the candidates (dense mCPG vectors), or W would not fit in
!> PGA_ROWS_MAX_BYTES, the candidates are projected one by one as before.
!>
!> Stops also, with a note, when the basis spans the whole velocity space (N = n_dof) or
!> when the largest exact relative residual is at the round-off level (<= ROUNDOFF_FLOOR):
!> such a candidate lies in the span, and orthonormalising it would add a direction made of
!> rounding errors (a delta below that level is unreachable, not a reason to add noise).
module cr_supremizer
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_scene, only: scene_t
  use cr_contact_eval, only: eval_contact
  use cr_sparse_cone, only: sparse_cone_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: pga_result_t, pga_enrich, supremizer, ROUNDOFF_FLOOR

  !> relative residual below which a candidate counts as lying in the span of the basis
  real(wp), parameter :: ROUNDOFF_FLOOR = 1.0e-12_wp
  !> largest memory of the projected rows W [n_dof, 2, n_support] of the exact phase (bytes)
  real(wp), parameter :: PGA_ROWS_MAX_BYTES = 512.0_wp * 2.0_wp**20

  !> History of an enrichment.
  type :: pga_result_t
    integer :: n_added = 0
    !> largest relative projection error before addition k (k = 1..n_added) and at the end
    real(wp), allocatable :: err(:)
    !> global candidate id of each addition: (sigma - 1) * R + r (sigma global, 1-based)
    integer(i8), allocatable :: chosen(:)
    !> why the enrichment stopped before reaching delta (empty when it reached delta)
    character(len=:), allocatable :: note
  end type pga_result_t

  !> What the steps of pga_enrich share: the cone's support rows and each one's place among
  !> them, the normals of the support rows at every local configuration [2, ns, nl], each
  !> candidate's squared norm and squared residual [R, nl], scratch [ns], the candidate
  !> supremizer [nd], the sizes and the exact phase's route.
  type :: pga_state_t
    integer, allocatable :: sup(:), pos(:)
    real(wp), allocatable :: gq(:,:,:), nrm2(:,:), res2(:,:), t(:), s(:)
    integer :: nd = 0, nl = 0, ns = 0
    character(len=16) :: route = 'auto'
  end type pga_state_t

contains

  !> s = B(q)^T psi_r as a dense vector [2*n_agents] (B = -h G over the dictionary rows).
  subroutine supremizer(scene, radius, h, dict_ia, dict_ib, dict_ob, cone, r, q, s)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h
    integer, intent(in) :: dict_ia(:), dict_ib(:), dict_ob(:)
    type(sparse_cone_t), intent(in) :: cone
    integer, intent(in) :: r
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: s(:)
    integer :: p, l, a, b
    real(wp) :: gap, g(2), w
    s = 0
    do p = cone%ptr(r) + 1, cone%ptr(r + 1)
      l = cone%idx(p); w = -h * cone%val(p)
      call eval_contact(scene, q, radius, dict_ia(l), dict_ib(l), dict_ob(l), gap, g)
      a = dict_ia(l); b = dict_ib(l)
      s(2*a-1:2*a) = s(2*a-1:2*a) + w * g
      if (b > 0) s(2*b-1:2*b) = s(2*b-1:2*b) - w * g
    end do
  end subroutine supremizer

  !> Enrich the orthonormal basis v [n_dof, N] (replicated) with supremizers of the local
  !> configurations q_local [n_dof, n_local] (global columns col_offset+1..col_offset+n_local).
  !> scenes(scene_of(k)) is the scene of local configuration k (studies that vary the exit
  !> width have one scene per sample). The greedy loop: the largest relative residual over
  !> every rank's candidates (pga_argmax), the stops, and the chosen supremizer formed by its
  !> owner and orthonormalised into v by every rank (pga_add); the residuals are updated
  !> (pga_subtract) or, once their relative accuracy is exhausted, recomputed (pga_recompute).
  subroutine pga_enrich(env, scenes, scene_of, radius, h, dict_ia, dict_ib, dict_ob, cone, q_local, col_offset, &
      v, delta, max_add, res, error, exact_route)
    type(env_t), intent(in) :: env
    type(scene_t), intent(in) :: scenes(:)
    integer, intent(in) :: scene_of(:)
    real(wp), intent(in) :: radius, h
    integer, intent(in) :: dict_ia(:), dict_ib(:), dict_ob(:)
    type(sparse_cone_t), intent(in) :: cone
    real(wp), intent(in) :: q_local(:,:)
    integer(i8), intent(in) :: col_offset
    real(wp), allocatable, intent(inout) :: v(:,:)
    real(wp), intent(in) :: delta
    integer, intent(in) :: max_add
    type(pga_result_t), intent(out) :: res
    type(error_t), allocatable, intent(out) :: error
    !> how the exact phase projects: 'auto' (default: the cheaper), 'rows' (through the
    !> projected support rows W_l) or 'candidates' (one candidate at a time); for tests
    character(len=*), intent(in), optional :: exact_route
    type(pga_state_t) :: st
    real(wp), allocatable :: hist(:)
    integer(i8), allocatable :: chosen(:)
    logical :: exact
    integer :: j, added
    integer(i8) :: gid
    real(wp) :: best(2), err
    character(len=:), allocatable :: why
    call pga_check(scene_of, q_local, v, delta, max_add, error, exact_route)
    if (allocated(error)) return
    st%route = 'auto'
    if (present(exact_route)) st%route = exact_route
    allocate(hist(max_add + 1), chosen(max_add))
    res%n_added = 0
    if (cone%r == 0) then
      res%err = [0.0_wp]; allocate(res%chosen(0)); return
    end if
    call pga_normals(scenes, scene_of, radius, h, dict_ia, dict_ib, dict_ob, cone, q_local, st)
    do j = 1, size(v, 2)
      call pga_subtract(st, h, dict_ia, dict_ib, cone, v(:, j))
    end do
    exact = .false.
    added = 0
    do
      call pga_argmax(env, st, cone, col_offset, best, error)
      if (allocated(error)) return
      err = sqrt(max(best(1), 0.0_wp))
      if (.not. exact .and. err < 1.0e-5_wp) then
        ! relative accuracy of |s|^2 - |V^T s|^2 is exhausted: recompute exactly
        exact = .true.
        call pga_recompute(st, scenes, scene_of, radius, h, dict_ia, dict_ib, dict_ob, cone, q_local, v)
        cycle
      end if
      hist(added + 1) = err
      if (err <= delta .or. best(1) < 0) exit
      if (added == max_add) then
        res%note = "stopped at pga_max_add = " // str(max_add) // " before reaching delta"
        exit
      end if
      if (size(v, 2) >= st%nd) then
        res%note = "the basis spans the whole velocity space (N = " // str(st%nd) // ")"
        exit
      end if
      if (exact .and. err <= ROUNDOFF_FLOOR) then
        res%note = "every remaining supremizer lies in the span up to round-off (relative residual " // &
          str(err) // " <= " // str(ROUNDOFF_FLOOR) // "): delta is below the round-off level"
        exit
      end if
      gid = nint(best(2), i8)
      call pga_add(env, st, scenes, scene_of, radius, h, dict_ia, dict_ib, dict_ob, cone, q_local, col_offset, &
        gid, v, why, error)
      if (allocated(error)) return
      if (len(why) > 0) then
        res%note = why
        exit
      end if
      added = added + 1
      chosen(added) = gid
      if (exact) then
        call pga_recompute(st, scenes, scene_of, radius, h, dict_ia, dict_ib, dict_ob, cone, q_local, v)
      else
        call pga_subtract(st, h, dict_ia, dict_ib, cone, st%s)
      end if
    end do
    res%n_added = added
    res%err = hist(1:added + 1)
    res%chosen = chosen(1:added)
  end subroutine pga_enrich

  !> The arguments of pga_enrich checked (sizes, exact_route, delta and max_add).
  subroutine pga_check(scene_of, q_local, v, delta, max_add, error, exact_route)
    integer, intent(in) :: scene_of(:)
    real(wp), intent(in) :: q_local(:,:), v(:,:), delta
    integer, intent(in) :: max_add
    type(error_t), allocatable, intent(out) :: error
    character(len=*), intent(in), optional :: exact_route
    integer :: nd, nl
    nd = size(v, 1); nl = size(q_local, 2)
    if (size(scene_of) /= nl) then
      call set_error(error, "pga: scene_of has " // str(size(scene_of)) // " entries, expected " // str(nl)); return
    end if
    if (size(q_local, 1) /= nd) then
      call set_error(error, "pga: positions have " // str(size(q_local, 1)) // " rows, basis has " // str(nd)); return
    end if
    if (present(exact_route)) then
      if (exact_route /= 'auto' .and. exact_route /= 'rows' .and. exact_route /= 'candidates') then
        call set_error(error, "pga: exact_route = '" // exact_route // "' (known: auto, rows, candidates)", EXIT_BAD_INPUT); return
      end if
    end if
    if (delta < 0 .or. max_add < 0) then
      call set_error(error, "pga: delta must be >= 0 and max_add >= 0", EXIT_BAD_INPUT); return
    end if
  end subroutine pga_check

  !> The support rows of the cone and the normals of each at every local configuration (st%gq),
  !> with every candidate's squared norm (st%nrm2, the first residuals st%res2).
  subroutine pga_normals(scenes, scene_of, radius, h, dict_ia, dict_ib, dict_ob, cone, q_local, st)
    type(scene_t), intent(in) :: scenes(:)
    integer, intent(in) :: scene_of(:)
    real(wp), intent(in) :: radius, h
    integer, intent(in) :: dict_ia(:), dict_ib(:), dict_ob(:)
    type(sparse_cone_t), intent(in) :: cone
    real(wp), intent(in) :: q_local(:,:)
    type(pga_state_t), intent(inout) :: st
    integer :: j, k, r
    real(wp) :: gap
    st%nd = size(q_local, 1); st%nl = size(q_local, 2)
    st%sup = cone%support(); st%ns = size(st%sup)
    allocate(st%pos(cone%n_dict)); st%pos = 0
    do j = 1, st%ns
      st%pos(st%sup(j)) = j
    end do
    allocate(st%gq(2, st%ns, max(st%nl, 1)), st%nrm2(cone%r, max(st%nl, 1)), st%res2(cone%r, max(st%nl, 1)), &
      st%t(st%ns), st%s(st%nd))
    do k = 1, st%nl
      do j = 1, st%ns
        call eval_contact(scenes(scene_of(k)), q_local(:, k), radius, dict_ia(st%sup(j)), dict_ib(st%sup(j)), &
          dict_ob(st%sup(j)), gap, st%gq(:, j, k))
      end do
      do r = 1, cone%r
        call supremizer(scenes(scene_of(k)), radius, h, dict_ia, dict_ib, dict_ob, cone, r, q_local(:, k), st%s)
        st%nrm2(r, k) = sum(st%s**2)
      end do
    end do
    st%res2 = st%nrm2
  end subroutine pga_normals

  !> Candidate gid (a global id of pga_argmax): formed by the rank that owns it, broadcast, and
  !> orthonormalised into v by every rank (twice Gram-Schmidt; st%s holds it). note: why it was
  !> not added ('' when it was).
  subroutine pga_add(env, st, scenes, scene_of, radius, h, dict_ia, dict_ib, dict_ob, cone, q_local, col_offset, &
      gid, v, note, error)
    type(env_t), intent(in) :: env
    type(pga_state_t), intent(inout) :: st
    type(scene_t), intent(in) :: scenes(:)
    integer, intent(in) :: scene_of(:)
    real(wp), intent(in) :: radius, h
    integer, intent(in) :: dict_ia(:), dict_ib(:), dict_ob(:)
    type(sparse_cone_t), intent(in) :: cone
    real(wp), intent(in) :: q_local(:,:)
    integer(i8), intent(in) :: col_offset, gid
    real(wp), allocatable, intent(inout) :: v(:,:)
    character(len=:), allocatable, intent(out) :: note
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: vn(:,:)
    integer :: k, rr, owner, j
    note = ""
    k = int((gid - 1) / cone%r - col_offset) + 1
    rr = int(mod(gid - 1, int(cone%r, i8))) + 1
    owner = -1
    if (k >= 1 .and. k <= st%nl) owner = env%rank
    call env%allreduce(owner, 'max', error)
    if (allocated(error)) then
      call prefix_error(error, "pga: owner of a supremizer"); return
    end if
    if (env%rank == owner) call supremizer(scenes(scene_of(k)), radius, h, dict_ia, dict_ib, dict_ob, cone, rr, &
      q_local(:, k), st%s)
    call env%bcast(st%s, error, root=owner)
    if (allocated(error)) then
      call prefix_error(error, "pga: a supremizer"); return
    end if
    do j = 1, 2
      st%s = st%s - matmul(v, matmul(st%s, v))
    end do
    if (.not. (norm2(st%s) > 0)) then
      note = "the selected supremizer lies in the span of the basis"
      return
    end if
    st%s = st%s / norm2(st%s)
    allocate(vn(st%nd, size(v, 2) + 1))
    vn(:, 1:size(v, 2)) = v
    vn(:, size(v, 2) + 1) = st%s
    call move_alloc(vn, v)
  end subroutine pga_add

  !> st%res2 -= (phi^T s)^2 for every local candidate (O(nnz) each).
  subroutine pga_subtract(st, h, dict_ia, dict_ib, cone, phi)
    type(pga_state_t), intent(inout) :: st
    real(wp), intent(in) :: h
    integer, intent(in) :: dict_ia(:), dict_ib(:)
    type(sparse_cone_t), intent(in) :: cone
    real(wp), intent(in) :: phi(:)
    integer :: kk, jj, p, a, b, r2
    real(wp) :: pr
    associate (t => st%t, gq => st%gq, sup => st%sup, pos => st%pos)
    do kk = 1, st%nl
      do jj = 1, st%ns
        a = dict_ia(sup(jj)); b = dict_ib(sup(jj))
        t(jj) = gq(1, jj, kk) * phi(2*a-1) + gq(2, jj, kk) * phi(2*a)
        if (b > 0) t(jj) = t(jj) - gq(1, jj, kk) * phi(2*b-1) - gq(2, jj, kk) * phi(2*b)
        t(jj) = -h * t(jj)
      end do
      do r2 = 1, cone%r
        pr = 0
        do p = cone%ptr(r2) + 1, cone%ptr(r2 + 1)
          pr = pr + cone%val(p) * t(pos(cone%idx(p)))
        end do
        st%res2(r2, kk) = st%res2(r2, kk) - pr * pr
      end do
    end do
    end associate
  end subroutine pga_subtract

  !> Exact squared residuals of every local candidate: through the projected rows W_l when
  !> that is cheaper (see the module's header) or st%route = 'rows', else candidate by candidate.
  subroutine pga_recompute(st, scenes, scene_of, radius, h, dict_ia, dict_ib, dict_ob, cone, q_local, v)
    type(pga_state_t), intent(inout) :: st
    type(scene_t), intent(in) :: scenes(:)
    integer, intent(in) :: scene_of(:)
    real(wp), intent(in) :: radius, h
    integer, intent(in) :: dict_ia(:), dict_ib(:), dict_ob(:)
    type(sparse_cone_t), intent(in) :: cone
    real(wp), intent(in) :: q_local(:,:), v(:,:)
    integer :: kk, r2, m, nd, nl, ns, nb
    real(wp), allocatable :: w(:)
    real(wp) :: cost_rows, cost_cand
    logical :: use_rows
    nd = st%nd; nl = st%nl; ns = st%ns
    allocate(w(nd))
    nb = size(v, 2)
    ! multiply-adds: rows: 2 ns projections of 4 nd nb + per candidate 2 nd per non-zero;
    ! candidates: 4 nd nb each
    cost_rows = 8.0_wp * ns * nd * nb + 2.0_wp * nd * real(nl, wp) * size(cone%idx)
    cost_cand = 4.0_wp * nd * nb * real(nl, wp) * cone%r
    use_rows = cost_rows < cost_cand .and. 16.0_wp * nd * ns <= PGA_ROWS_MAX_BYTES
    if (st%route == 'rows') use_rows = .true.
    if (st%route == 'candidates') use_rows = .false.
    if (use_rows) then
      call pga_recompute_rows(st, h, dict_ia, dict_ib, cone, v)
    else
      do kk = 1, nl
        do r2 = 1, cone%r
          call supremizer(scenes(scene_of(kk)), radius, h, dict_ia, dict_ib, dict_ob, cone, r2, q_local(:, kk), w)
          do m = 1, 2
            w = w - matmul(v, matmul(w, v))
          end do
          st%res2(r2, kk) = sum(w**2)
        end do
      end do
    end if
  end subroutine pga_recompute

  !> pga_recompute through the projected rows: W_l = (I - V V^T) M_l for every support row,
  !> twice Gram-Schmidt, then each candidate's residual from the W_l of its rows.
  subroutine pga_recompute_rows(st, h, dict_ia, dict_ib, cone, v)
    type(pga_state_t), intent(inout) :: st
    real(wp), intent(in) :: h
    integer, intent(in) :: dict_ia(:), dict_ib(:)
    type(sparse_cone_t), intent(in) :: cone
    real(wp), intent(in) :: v(:,:)
    integer :: kk, r2, m, jj, p, a, b
    real(wp), allocatable :: w(:), wl(:,:,:)
    real(wp) :: c
    allocate(w(st%nd))
    allocate(wl(st%nd, 2, st%ns))
    wl = 0
    do jj = 1, st%ns
      a = dict_ia(st%sup(jj)); b = dict_ib(st%sup(jj))
      wl(2*a-1, 1, jj) = 1; wl(2*a, 2, jj) = 1
      if (b > 0) then
        wl(2*b-1, 1, jj) = -1; wl(2*b, 2, jj) = -1
      end if
      do m = 1, 2
        wl(:, :, jj) = wl(:, :, jj) - matmul(v, matmul(transpose(v), wl(:, :, jj)))
      end do
    end do
    do r2 = 1, cone%r
      do kk = 1, st%nl
        w = 0
        do p = cone%ptr(r2) + 1, cone%ptr(r2 + 1)
          jj = st%pos(cone%idx(p))
          c = -h * cone%val(p)
          w = w + (c * st%gq(1, jj, kk)) * wl(:, 1, jj) + (c * st%gq(2, jj, kk)) * wl(:, 2, jj)
        end do
        st%res2(r2, kk) = sum(w**2)
      end do
    end do
  end subroutine pga_recompute_rows

  !> Global (max relative squared residual, candidate id) over the candidates with a non-zero
  !> supremizer; near ties (relative sqrt(eps), the rule of cr_sort::near_max_index) go to the
  !> lowest id, so the choice does not depend on the number of ranks. (-huge, 0) when no rank
  !> has a candidate. Candidate (r2, kk) has the id (col_offset + kk - 1) * cone%r + r2.
  subroutine pga_argmax(env, st, cone, col_offset, out, error)
    type(env_t), intent(in) :: env
    type(pga_state_t), intent(in) :: st
    type(sparse_cone_t), intent(in) :: cone
    integer(i8), intent(in) :: col_offset
    real(wp), intent(out) :: out(2)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: rel(:)
    logical, allocatable :: has(:)
    integer(i8) :: gid_best
    integer :: kk, r2, j
    ! candidate (r2, kk) at position (kk - 1) R + r2: its local id
    allocate(rel(cone%r * st%nl), has(cone%r * st%nl))
    j = 0
    do kk = 1, st%nl
      do r2 = 1, cone%r
        j = j + 1
        has(j) = st%nrm2(r2, kk) > 0
        rel(j) = 0
        if (has(j)) rel(j) = max(st%res2(r2, kk), 0.0_wp) / st%nrm2(r2, kk)
      end do
    end do
    call env%allreduce_near_maxloc(rel, col_offset * cone%r, out(1), gid_best, error, mask=has)
    if (allocated(error)) call prefix_error(error, "pga: the largest projection error")
    out(2) = real(gid_best, wp)
  end subroutine pga_argmax
end module cr_supremizer
