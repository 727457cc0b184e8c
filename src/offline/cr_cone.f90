!> The reduced cone of the multipliers (the paper's section 3.1.2): greedy index selection
!> (gIS, Algorithm 2) and the modified cone projected greedy (mCPG, Algorithm 1), distributed
!> over the ranks that hold the multiplier snapshots.
!>
!> Snapshots are sparse vectors of R^{n_dict} (n_dict = size of the global contact
!> dictionary), stored per rank as compressed columns (sparse_columns_t) of a contiguous block
!> of global snapshot columns. Every selection follows the project's near-tie rule
!> (cr_sort::near_max_index: values within a relative sqrt(eps) of the largest count as tied,
!> the lowest index wins), the snapshot choice as a global reduction (env_t's
!> allreduce_near_maxloc), so the result does not depend on the number of ranks or on the
!> last bits of the residuals.
module cr_cone
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_sort, only: near_max_index
  !> the result of a cone construction is the cone record of the ROM file
  use cr_rom_file, only: cone_result_t => rom_cone_t
  use cr_nnls, only: nnls_solve, nnls_stats_t, ldp_solve, ldp_stats_t, nnls_work_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: sparse_columns_t, cone_result_t, gis_build, mcpg_build, cone_project_gram

  !> Tikhonov term of the Gram-form cone projections: G + reg I (the psi are unit vectors)
  real(wp), parameter :: reg = 1.0e-12_wp

  !> Local block of sparse snapshot columns.
  type :: sparse_columns_t
    !> dimension of each column (size of the contact dictionary)
    integer :: n_rows = 0
    !> number of local columns and global index of the first one minus 1
    integer :: n_cols = 0
    integer(i8) :: col_offset = 0
    !> column pointers, 0-based offsets into idx/val [n_cols + 1]
    integer(i8), allocatable :: ptr(:)
    !> 1-based row indices and values of the non-zeros [nnz]
    integer, allocatable :: idx(:)
    real(wp), allocatable :: val(:)
  end type sparse_columns_t

  !> What the steps of mcpg_build share: the cone vectors psi [n_rows, r_max] with their Gram
  !> matrix gm and the Cholesky factor rg of gm + reg I [r_max, r_max]; per local snapshot its
  !> squared norm, residual and accuracy, its coefficients c and kk [r_max, n_cols] and whether
  !> it was selected; the selected snapshots (sig), the history (worst error, mean, accuracy
  !> [r_max + 1]); the current worst snapshot
  !> (gcol, worst), n1 the norm of the first, r the vectors so far, t0 the start.
  type :: mcpg_state_t
    real(wp), allocatable :: psi(:,:), gm(:,:), rg(:,:), c(:,:), kk(:,:)
    real(wp), allocatable :: x2(:), res2(:), acc2(:)
    real(wp), allocatable :: tmp_err(:), tmp_mean(:), tmp_acc(:)
    logical, allocatable :: used(:)
    integer(i8), allocatable :: sig(:)
    integer(i8) :: gcol = 0
    real(wp) :: worst = 0, n1 = 0, t0 = 0
    integer :: r = 0
  end type mcpg_state_t

contains

  ! ------------------------------------------------------------------ helpers

  !> Global argmax of `val` [n_cols] over the local columns, near ties (relative sqrt(eps)) to
  !> the lowest global column; vmax = -huge and gcol = 0 when no rank has a column.
  subroutine global_argmax(env, lam, val, vmax, gcol, error)
    type(env_t), intent(in) :: env
    type(sparse_columns_t), intent(in) :: lam
    real(wp), intent(in) :: val(:)
    real(wp), intent(out) :: vmax
    integer(i8), intent(out) :: gcol
    type(error_t), allocatable, intent(out) :: error
    call env%allreduce_near_maxloc(val(1:lam%n_cols), lam%col_offset, vmax, gcol, error)
    if (allocated(error)) call prefix_error(error, "cone")
  end subroutine global_argmax

  !> The dense copy [n_rows] of global column `gcol`, on every rank.
  subroutine fetch_column(env, lam, gcol, x, error)
    type(env_t), intent(in) :: env
    type(sparse_columns_t), intent(in) :: lam
    integer(i8), intent(in) :: gcol
    real(wp), contiguous, intent(out) :: x(:)
    type(error_t), allocatable, intent(out) :: error
    integer :: owner, k
    integer(i8) :: p
    owner = 0
    if (gcol > lam%col_offset .and. gcol <= lam%col_offset + lam%n_cols) owner = env%rank
    call env%allreduce(owner, 'max', error)
    if (allocated(error)) then
      call prefix_error(error, "cone: owner of a snapshot"); return
    end if
    x = 0
    if (env%rank == owner) then
      k = int(gcol - lam%col_offset)
      do p = lam%ptr(k) + 1, lam%ptr(k + 1)
        x(lam%idx(p)) = lam%val(p)
      end do
    end if
    call env%bcast(x, error, root=owner)
    if (allocated(error)) call prefix_error(error, "cone: a snapshot")
  end subroutine fetch_column

  !> Squared norms of the local columns [n_cols].
  subroutine column_norms2(lam, nrm2)
    type(sparse_columns_t), intent(in) :: lam
    real(wp), intent(out) :: nrm2(:)
    integer :: k
    do k = 1, lam%n_cols
      nrm2(k) = sum(lam%val(lam%ptr(k) + 1:lam%ptr(k + 1))**2)
    end do
  end subroutine column_norms2

  subroutine check_columns(lam, error)
    type(sparse_columns_t), intent(in) :: lam
    type(error_t), allocatable, intent(out) :: error
    if (lam%n_cols < 0 .or. lam%n_rows < 0) then
      call set_error(error, "cone: negative sizes"); return
    end if
    if (.not. allocated(lam%ptr)) then
      call set_error(error, "cone: snapshot columns not set"); return
    end if
    if (size(lam%ptr) /= lam%n_cols + 1) then
      call set_error(error, "cone: ptr has " // str(size(lam%ptr)) // " entries, expected n_cols + 1 = " // &
        str(lam%n_cols + 1)); return
    end if
    if (lam%n_cols > 0) then
      if (any(lam%idx(1:lam%ptr(lam%n_cols + 1)) < 1) .or. any(lam%idx(1:lam%ptr(lam%n_cols + 1)) > lam%n_rows)) then
        call set_error(error, "cone: a row index is outside 1.." // str(lam%n_rows)); return
      end if
    end if
  end subroutine check_columns

  !> Mean over all snapshots of the relative projection error sqrt(res2) / n1.
  subroutine mean_relative(env, lam, res2, n1, mean, error)
    type(env_t), intent(in) :: env
    type(sparse_columns_t), intent(in) :: lam
    real(wp), intent(in) :: res2(:), n1
    real(wp), intent(out) :: mean
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: s(2)
    s(1) = sum(sqrt(max(res2(1:lam%n_cols), 0.0_wp))) / n1
    s(2) = lam%n_cols
    mean = 0
    call env%allreduce(s, 'sum', error)
    if (allocated(error)) then
      call prefix_error(error, "cone: the mean projection error"); return
    end if
    mean = s(1) / max(s(2), 1.0_wp)
  end subroutine mean_relative

  !> Store R, the selected snapshots, the error history and the time in `res`.
  subroutine record_history(res, r, sig, err, mean, n1, time)
    type(cone_result_t), intent(inout) :: res
    integer, intent(in) :: r
    integer(i8), intent(in) :: sig(:)
    real(wp), intent(in) :: err(:), mean(:), n1, time
    res%r = r
    res%sigma = sig(1:r)
    if (n1 > 0) then
      res%err_max = err(1:r + 1)
      res%err_mean = mean(1:r + 1)
    else
      res%err_max = [0.0_wp]
      res%err_mean = [0.0_wp]
    end if
    res%time = time
  end subroutine record_history

  ! ------------------------------------------------------------------ gIS

  !> Greedy index selection (Algorithm 2): psi_r = e_{i_r}, i_r the largest coordinate of
  !> the worst-approximated snapshot not yet selected (both choices by the near-tie rule: the
  !> lowest snapshot, the lowest coordinate, within a relative sqrt(eps) of the largest). The projection onto the cone of
  !> selected canonical vectors keeps the selected coordinates (they are >= 0), so the
  !> squared residual of each snapshot is updated by subtracting the new coordinate squared.
  !> Stops when e_r <= delta, r = r_max, or the worst snapshot has no uncovered coordinate.
  !> A residual that the subtraction has reduced below 1e-6 of the snapshot's squared norm
  !> (where it has lost about six digits to cancellation) is recomputed exactly from the
  !> uncovered coordinates, so that small errors, and e_R = 0 once everything is covered,
  !> are exact (delta = 0 is a valid request).
  subroutine gis_build(env, lam, delta, r_max, res, error)
    type(env_t), intent(in) :: env
    type(sparse_columns_t), intent(in) :: lam
    real(wp), intent(in) :: delta
    integer, intent(in) :: r_max
    type(cone_result_t), intent(out) :: res
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: res2(:), x2(:), col(:), tmp_err(:), tmp_mean(:)
    integer, allocatable :: sel(:), tptr(:), tcol(:)
    integer(i8), allocatable :: sig(:)
    logical, allocatable :: chosen(:)
    real(wp), allocatable :: tval(:)
    real(wp) :: n1, worst, t0
    integer(i8) :: gcol
    integer :: r, i, k, nnz, p
    t0 = env%wtime()
    res%method = 'gis'
    call check_columns(lam, error); if (allocated(error)) return
    if (delta < 0 .or. r_max < 0) then
      call set_error(error, "gis: delta must be >= 0 and r_max >= 0", EXIT_BAD_INPUT); return
    end if
    allocate(res2(max(lam%n_cols, 1)), col(max(lam%n_rows, 1)), chosen(max(lam%n_rows, 1)))
    allocate(sel(r_max), sig(r_max), tmp_err(r_max + 1), tmp_mean(r_max + 1))
    chosen = .false.
    call column_norms2(lam, res2)
    x2 = res2
    ! transposed structure: for each dictionary index, its (local column, value) pairs
    nnz = 0
    if (lam%n_cols > 0) nnz = int(lam%ptr(lam%n_cols + 1))
    allocate(tptr(lam%n_rows + 1), tcol(max(nnz, 1)), tval(max(nnz, 1)))
    tptr = 0
    do k = 1, nnz
      tptr(lam%idx(k) + 1) = tptr(lam%idx(k) + 1) + 1
    end do
    do i = 1, lam%n_rows
      tptr(i + 1) = tptr(i + 1) + tptr(i)
    end do
    block
      integer, allocatable :: fill(:)
      allocate(fill(lam%n_rows))
      fill = tptr(1:lam%n_rows)
      do k = 1, lam%n_cols
        do p = int(lam%ptr(k)) + 1, int(lam%ptr(k + 1))
          i = lam%idx(p)
          fill(i) = fill(i) + 1
          tcol(fill(i)) = k; tval(fill(i)) = lam%val(p)
        end do
      end do
    end block
    ! sigma_1 = argmax |lambda(sigma)|
    call global_argmax(env, lam, res2, worst, gcol, error); if (allocated(error)) return
    n1 = sqrt(max(worst, 0.0_wp))
    r = 0
    if (.not. (n1 > 0)) then
      res%note = "empty cone: no contact is ever active in the snapshots (all multipliers are zero)"
      call finish(); return
    end if
    tmp_err(1) = 1.0_wp
    call mean_relative(env, lam, res2, n1, tmp_mean(1), error); if (allocated(error)) return
    do while (r < r_max)
      if (sqrt(max(worst, 0.0_wp)) / n1 <= delta .and. r > 0) exit
      call fetch_column(env, lam, gcol, col, error); if (allocated(error)) return
      ! largest positive coordinate not yet selected (near ties: lowest index)
      i = near_max_index(col(1:lam%n_rows), mask=.not. chosen(1:lam%n_rows) .and. col(1:lam%n_rows) > 0)
      if (i == 0) then
        res%note = "the worst-approximated snapshot has no uncovered positive coordinate"
        exit
      end if
      r = r + 1
      sel(r) = i; sig(r) = gcol; chosen(i) = .true.
      do p = tptr(i) + 1, tptr(i + 1)
        k = tcol(p)
        res2(k) = max(res2(k) - tval(p)**2, 0.0_wp)
        if (res2(k) <= 1.0e-6_wp * x2(k)) res2(k) = uncovered2(k)
      end do
      call global_argmax(env, lam, res2, worst, gcol, error); if (allocated(error)) return
      tmp_err(r + 1) = sqrt(max(worst, 0.0_wp)) / n1
      call mean_relative(env, lam, res2, n1, tmp_mean(r + 1), error); if (allocated(error)) return
    end do
    call finish()

  contains

    !> Exact squared residual of local column kk: its uncovered coordinates squared.
    real(wp) function uncovered2(kk)
      integer, intent(in) :: kk
      integer :: q
      uncovered2 = 0
      do q = int(lam%ptr(kk)) + 1, int(lam%ptr(kk + 1))
        if (.not. chosen(lam%idx(q))) uncovered2 = uncovered2 + lam%val(q)**2
      end do
    end function uncovered2

    subroutine finish()
      res%indices = sel(1:r)
      call record_history(res, r, sig, tmp_err, tmp_mean, n1, env%wtime() - t0)
    end subroutine finish
  end subroutine gis_build

  ! ------------------------------------------------------------------ mCPG

  !> Projection onto cone(psi_1..psi_r) in Gram form: k = argmin_{k >= 0} |x - Psi k|^2,
  !> given G = Psi^T Psi [r, r], the upper Cholesky factor rg of G + eps I (eps = 1e-12 times
  !> the largest diagonal of G: cone generators may be linearly dependent, e.g. psi_1 =
  !> (psi_2 + psi_3) / sqrt(2) while the cone still grows), c = Psi^T x and |x|^2.
  !> Returns k [r] and the squared residual |x - Psi k|^2 (from the unregularised G), and
  !> optionally acc2, a bound on |res2 - exact squared distance to the cone| (see mcpg_build):
  !>   acc2 = reg |k|^2 + (64 r + 2 n_rows) eps (|x| + |k|_1)^2
  !> (n_rows: length of the dot products that formed G and c; default 0).
  subroutine cone_project_gram(rg, g, c, x2, k, res2, error, passive0, work, acc2, n_rows)
    real(wp), intent(in) :: rg(:,:), g(:,:)
    real(wp), intent(in) :: c(:)
    real(wp), intent(in) :: x2
    real(wp), intent(out) :: k(:)
    real(wp), intent(out) :: res2
    type(error_t), allocatable, intent(out) :: error
    logical, intent(in), optional :: passive0(:)
    type(nnls_work_t), intent(inout), optional :: work
    real(wp), intent(out), optional :: acc2
    integer, intent(in), optional :: n_rows
    real(wp), allocatable :: b(:)
    type(nnls_stats_t) :: st
    integer :: r, i, nr
    r = size(c)
    ! |x - Psi k|^2 + eps |k|^2 = |R k - R^{-T} c|^2 + const
    allocate(b(r))
    do i = 1, r
      b(i) = (c(i) - dot_product(rg(1:i-1, i), b(1:i-1))) / rg(i, i)
    end do
    call nnls_solve(rg, b, k, st, error, passive0=passive0, work=work)
    if (allocated(error)) return
    res2 = max(x2 - 2 * dot_product(k, c) + dot_product(k, matmul(g, k)), 0.0_wp)
    if (present(acc2)) then
      nr = 0
      if (present(n_rows)) nr = n_rows
      acc2 = reg * sum(k**2) + real(64 * r + 2 * nr, wp) * epsilon(1.0_wp) * (sqrt(max(x2, 0.0_wp)) + sum(abs(k)))**2
    end if
  end subroutine cone_project_gram

  !> Modified cone projected greedy (Algorithm 1). psi_r is the normalised residual of the
  !> worst-approximated snapshot after its projection onto the current cone subject to the
  !> residual staying non-negative (a least-squares problem with inequality constraints,
  !> reduced to least-distance programming and solved by our LDP/NNLS). All other
  !> projections are cone projections in Gram form (nnls), warm started from the previous
  !> iteration's support.
  !>
  !> Accuracy and stopping rule. Each snapshot's squared error res2 = |x - Psi k|^2 comes from a
  !> Gram-form projection: nnls_solve on (R, R^{-T} c) with R^T R = G + reg I, then the expansion
  !> |x|^2 - 2 k.c + k.G k. Its distance to the exact squared distance to the cone is bounded by
  !> acc2 = reg |k|^2 (the Tikhonov term: res2 + reg |k|^2 is the regularised objective)
  !>      + 64 r eps (|x| + |k|_1)^2 (nnls_solve's stated accuracy, |r| <= |r*| + 32 r eps
  !>        sum_j |R_j| k_j with |R_j| ~ 1 and |r| <= |x|, and the rounding of the expansion,
  !>        |G_ij| <= 1, |c_j| <= |x|)
  !>      + 2 n_rows eps (|x| + |k|_1)^2 (the dot products of length n_rows forming G and c).
  !> The history records e_r = max over the snapshots not yet selected of sqrt(res2) / n1 and
  !> a_r = max over the same snapshots of sqrt(acc2) / n1. The exact worst error cannot grow
  !> with the cone; the computed one satisfies e_{r+1} <= e_r + a_r + a_{r+1} (the regularised
  !> objective of each snapshot does not grow, so res2 grows by at most reg |k_r|^2 plus the
  !> rounding at r and r + 1). The construction stops when e_r <= delta, at r_max, when the
  !> worst snapshot's LSI residual vanishes (note), or when e_r <= a_r: the worst error is at
  !> the accuracy of the projections themselves and further vectors would be fitted to
  !> rounding (note, also written to the ROM file and the summary).
  subroutine mcpg_build(env, lam, delta, r_max, res, error)
    type(env_t), intent(in) :: env
    type(sparse_columns_t), intent(in) :: lam
    real(wp), intent(in) :: delta
    integer, intent(in) :: r_max
    type(cone_result_t), intent(out) :: res
    type(error_t), allocatable, intent(out) :: error
    type(mcpg_state_t) :: st
    type(nnls_work_t) :: work
    real(wp), allocatable :: col(:), resid(:)
    real(wp) :: nrm, e, acc_max
    st%t0 = env%wtime()
    res%method = 'mcpg'
    call check_columns(lam, error); if (allocated(error)) return
    if (delta < 0 .or. r_max < 0) then
      call set_error(error, "mcpg: delta must be >= 0 and r_max >= 0", EXIT_BAD_INPUT); return
    end if
    call mcpg_init(env, lam, r_max, st, error); if (allocated(error)) return
    allocate(col(max(lam%n_rows, 1)), resid(max(lam%n_rows, 1)))
    if (.not. (st%n1 > 0)) then
      res%note = "empty cone: no contact is ever active in the snapshots (all multipliers are zero)"
      call mcpg_finish(env, lam, st, res); return
    end if
    st%tmp_err(1) = 1.0_wp
    call mean_relative(env, lam, st%res2, st%n1, st%tmp_mean(1), error); if (allocated(error)) return
    call mcpg_accuracy(env, lam, st, acc_max, error); if (allocated(error)) return
    st%tmp_acc(1) = acc_max
    do while (st%r < r_max)
      e = sqrt(max(st%worst, 0.0_wp)) / st%n1
      if (st%r > 0 .and. e <= delta) exit
      if (st%r > 0 .and. e <= st%tmp_acc(st%r + 1)) then
        res%note = "the worst projection error e_R = " // str(e) // &
          " reached the accuracy of the inner cone projections (" // str(st%tmp_acc(st%r + 1)) // &
          "): further cone vectors would be fitted to rounding"
        exit
      end if
      call fetch_column(env, lam, st%gcol, col, error); if (allocated(error)) return
      if (st%gcol > lam%col_offset .and. st%gcol <= lam%col_offset + lam%n_cols) &
        st%used(int(st%gcol - lam%col_offset)) = .true.
      ! gamma = Psi k*, k* = argmin |col - Psi k| s.t. k >= 0, col - Psi k >= 0
      call lsi_residual(lam, st, col, resid, error); if (allocated(error)) return
      nrm = norm2(resid(1:lam%n_rows))
      if (.not. (nrm > 1.0e-14_wp * st%n1)) then
        res%note = "the worst-approximated snapshot already lies in the cone"
        exit
      end if
      call mcpg_add(lam, st, resid, nrm)
      call mcpg_project(lam, st, work, error); if (allocated(error)) return
      ! selected snapshots are excluded from the next selection (line 12)
      call global_argmax(env, lam, merge(-1.0_wp, st%res2(1:max(lam%n_cols, 1)), st%used(1:max(lam%n_cols, 1))), &
        st%worst, st%gcol, error); if (allocated(error)) return
      st%worst = max(st%worst, 0.0_wp)
      st%tmp_err(st%r + 1) = sqrt(st%worst) / st%n1
      call mean_relative(env, lam, st%res2, st%n1, st%tmp_mean(st%r + 1), error); if (allocated(error)) return
      call mcpg_accuracy(env, lam, st, acc_max, error); if (allocated(error)) return
      st%tmp_acc(st%r + 1) = acc_max
    end do
    call mcpg_finish(env, lam, st, res)
  end subroutine mcpg_build

  !> The state of mcpg_build before its first vector: every array sized for r_max, the squared
  !> norms of the snapshots (the residuals of the empty cone) with their accuracy (a sum of at
  !> most n_rows squares), and the worst snapshot over the ranks (n1 its norm).
  subroutine mcpg_init(env, lam, r_max, st, error)
    type(env_t), intent(in) :: env
    type(sparse_columns_t), intent(in) :: lam
    integer, intent(in) :: r_max
    type(mcpg_state_t), intent(inout) :: st
    type(error_t), allocatable, intent(out) :: error
    allocate(st%x2(max(lam%n_cols, 1)), st%res2(max(lam%n_cols, 1)), st%used(max(lam%n_cols, 1)))
    allocate(st%c(max(r_max, 1), max(lam%n_cols, 1)), st%kk(max(r_max, 1), max(lam%n_cols, 1)))
    allocate(st%psi(max(lam%n_rows, 1), max(r_max, 1)))
    allocate(st%rg(max(r_max, 1), max(r_max, 1)), st%gm(max(r_max, 1), max(r_max, 1)), st%sig(r_max))
    allocate(st%tmp_err(r_max + 1), st%tmp_mean(r_max + 1), st%tmp_acc(r_max + 1), st%acc2(max(lam%n_cols, 1)))
    st%used = .false.; st%kk = 0; st%rg = 0; st%gm = 0
    call column_norms2(lam, st%x2)
    st%res2 = st%x2
    ! r = 0: res2 = |x|^2 is a sum of at most n_rows squares
    st%acc2 = 2 * real(lam%n_rows, wp) * epsilon(1.0_wp) * st%x2
    call global_argmax(env, lam, st%res2, st%worst, st%gcol, error); if (allocated(error)) return
    st%n1 = sqrt(max(st%worst, 0.0_wp))
    st%r = 0
  end subroutine mcpg_init

  !> The new cone vector psi_r = resid / nrm (from snapshot gcol), its Gram column and the
  !> Cholesky column r of G + reg I (the psi are unit vectors).
  subroutine mcpg_add(lam, st, resid, nrm)
    type(sparse_columns_t), intent(in) :: lam
    type(mcpg_state_t), intent(inout) :: st
    real(wp), intent(in) :: resid(:), nrm
    integer :: j, r
    st%r = st%r + 1
    r = st%r
    associate (psi => st%psi, gm => st%gm, rg => st%rg)
    psi(1:lam%n_rows, r) = resid(1:lam%n_rows) / nrm
    st%sig(r) = st%gcol
    do j = 1, r
      gm(j, r) = dot_product(psi(1:lam%n_rows, j), psi(1:lam%n_rows, r))
      gm(r, j) = gm(j, r)
    end do
    rg(1:r, r) = gm(1:r, r)
    rg(r, r) = rg(r, r) + reg
    do j = 1, r - 1
      rg(j, r) = (rg(j, r) - dot_product(rg(1:j-1, j), rg(1:j-1, r))) / rg(j, j)
    end do
    rg(r, r) = sqrt(max(rg(r, r) - sum(rg(1:r-1, r)**2), reg))
    end associate
  end subroutine mcpg_add

  !> Every local snapshot projected onto the cone of the r vectors (warm started from its
  !> previous coefficients): its residual, coefficients and accuracy.
  subroutine mcpg_project(lam, st, work, error)
    type(sparse_columns_t), intent(in) :: lam
    type(mcpg_state_t), intent(inout) :: st
    type(nnls_work_t), intent(inout) :: work
    type(error_t), allocatable, intent(out) :: error
    integer :: k, p, r
    r = st%r
    do k = 1, lam%n_cols
      st%c(r, k) = 0
      do p = int(lam%ptr(k)) + 1, int(lam%ptr(k + 1))
        st%c(r, k) = st%c(r, k) + st%psi(lam%idx(p), r) * lam%val(p)
      end do
      call cone_project_gram(st%rg(1:r, 1:r), st%gm(1:r, 1:r), st%c(1:r, k), st%x2(k), st%kk(1:r, k), st%res2(k), &
        error, passive0=st%kk(1:r, k) > 0, work=work, acc2=st%acc2(k), n_rows=lam%n_rows)
      if (allocated(error)) then
        call prefix_error(error, "mcpg: projection of snapshot " // str(lam%col_offset + k)); return
      end if
    end do
  end subroutine mcpg_project

  !> amax = max over all ranks' snapshots not yet selected of sqrt(acc2) / n1
  subroutine mcpg_accuracy(env, lam, st, amax, error)
    type(env_t), intent(in) :: env
    type(sparse_columns_t), intent(in) :: lam
    type(mcpg_state_t), intent(in) :: st
    real(wp), intent(out) :: amax
    type(error_t), allocatable, intent(out) :: error
    integer :: kk2
    amax = 0
    do kk2 = 1, lam%n_cols
      if (.not. st%used(kk2)) amax = max(amax, sqrt(max(st%acc2(kk2), 0.0_wp)) / st%n1)
    end do
    call env%allreduce(amax, 'max', error)
    if (allocated(error)) call prefix_error(error, "mcpg: the accuracy")
  end subroutine mcpg_accuracy

  !> resid = x - Psi k*,  k* = argmin |x - Psi k|, k >= 0, Psi k <= x   (LSI -> LDP), over the
  !> st%r vectors of the cone.
  subroutine lsi_residual(lam, st, x, resid, error)
    type(sparse_columns_t), intent(in) :: lam
    type(mcpg_state_t), intent(in) :: st
    real(wp), intent(in) :: x(:)
    real(wp), intent(out) :: resid(:)
    type(error_t), allocatable, intent(out) :: error
    ! Regularised (eps |k|^2, eps = 1e-12, as in the Gram projections) so that dependent
    ! generators are allowed: [Psi; sqrt(eps) I] = [Q; Q2] R with R = rg, Q = Psi R^{-1}.
    ! With z = R k - Q^T x:
    ! min |z|^2 s.t. k = R^{-1}(z + Q^T x) >= 0 and Psi k <= x, an LDP in z:
    !   -R^{-1} z <= R^{-1} Q^T x          (k >= 0)
    !   Q z <= x - Q Q^T x                 (Psi k = Q (z + Q^T x) <= x)
    real(wp), allocatable :: q(:,:), qtx(:), rinv(:,:), bm(:,:), d(:), z(:), lz(:), v0(:), kvec(:)
    type(ldp_stats_t) :: lst
    integer :: n, i, jj, r
    n = lam%n_rows
    r = st%r
    if (r == 0) then
      resid(1:n) = x(1:n); return
    end if
    associate (psi => st%psi, rg => st%rg)
    allocate(q(n, r), qtx(r), rinv(r, r), bm(r + n, r), d(r + n), z(r), lz(r + n), v0(r), kvec(r))
    ! Q = Psi R^{-1}  (R upper triangular: column j of Q solves R^T)
    do jj = 1, r
      q(:, jj) = psi(1:n, jj)
      do i = 1, jj - 1
        q(:, jj) = q(:, jj) - rg(i, jj) * q(:, i)
      end do
      q(:, jj) = q(:, jj) / rg(jj, jj)
    end do
    qtx = matmul(x(1:n), q)
    ! R^{-1}
    rinv = 0
    do jj = 1, r
      rinv(jj, jj) = 1 / rg(jj, jj)
      do i = jj - 1, 1, -1
        rinv(i, jj) = -dot_product(rg(i, i+1:jj), rinv(i+1:jj, jj)) / rg(i, i)
      end do
    end do
    bm(1:r, :) = -rinv
    d(1:r) = matmul(rinv, qtx)
    bm(r+1:r+n, :) = q
    d(r+1:r+n) = x(1:n) - matmul(q, qtx)
    v0 = 0; lz = 0
    call ldp_solve(bm, d, v0, z, lz, lst, error)
    if (allocated(error)) return
    kvec = matmul(rinv, z + qtx)
    kvec = max(kvec, 0.0_wp)
    resid(1:n) = x(1:n) - matmul(psi(1:n, 1:r), kvec)
    resid(1:n) = max(resid(1:n), 0.0_wp)
    end associate
  end subroutine lsi_residual

  !> The result of mcpg_build: the r vectors, the history and the accuracy of each step.
  subroutine mcpg_finish(env, lam, st, res)
    type(env_t), intent(in) :: env
    type(sparse_columns_t), intent(in) :: lam
    type(mcpg_state_t), intent(in) :: st
    type(cone_result_t), intent(inout) :: res
    res%psi = st%psi(1:lam%n_rows, 1:st%r)
    call record_history(res, st%r, st%sig, st%tmp_err, st%tmp_mean, st%n1, env%wtime() - st%t0)
    if (st%n1 > 0) then
      res%err_acc = st%tmp_acc(1:st%r + 1)
    else
      res%err_acc = [0.0_wp]
    end if
  end subroutine mcpg_finish
end module cr_cone
