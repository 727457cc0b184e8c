!> Supremizer enrichment (PGA) and reduced inf-sup constants on a small synthetic scene,
!> distributed over 1, 2 or 4 ranks; the distributed enrichment must equal the one computed
!> by each rank alone on all the data.
program test_enrichment
  use mpi_f08
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_assert, only: check, check_close, test_summary
  use cr_config, only: scene_cfg_t, obstacles_cfg_t
  use cr_scene, only: scene_t
  use cr_random, only: rng_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_supremizer, only: pga_result_t, pga_enrich, supremizer
  use cr_infsup, only: infsup_t, reduced_infsup
  implicit none
  integer, parameter :: na = 6, nd = 2 * na, nsnap = 13, n0 = 3
  real(wp), parameter :: rad = 0.05_wp, h = 0.05_wp
  type(env_t) :: env, solo
  type(error_t), allocatable :: error
  type(scene_t) :: scene
  type(sparse_cone_t) :: cone
  real(wp) :: q(nd, nsnap), v0(nd, n0)
  integer :: dia(9), dib(9), dob(9), ierr
  type(MPI_Comm) :: self
  call MPI_Init(ierr)
  call env%init(MPI_COMM_WORLD, error)
  call MPI_Comm_split(MPI_COMM_WORLD, env%rank, 0, self, ierr)
  call solo%init(self, error)
  call scene%init(scene_cfg_t(), obstacles_cfg_t(), error)
  call make_data()
  call test_pga()
  call test_pga_graded()
  call test_infsup()
  call solo%free(); call env%free()
  call MPI_Comm_free(self, ierr)
  call MPI_Finalize(ierr)
  call test_summary(env%rank)

contains

  subroutine make_data()
    type(rng_t) :: rng
    integer :: k, i
    real(wp) :: a(nd, n0), x
    call rng%seed(42)
    do k = 1, nsnap
      do i = 1, na   ! agents in a row, jittered, near the bottom wall
        q(2*i-1, k) = 0.2_wp + 0.12_wp * i + 0.01_wp * (rng%uniform() - 0.5_wp)
        q(2*i, k) = 0.06_wp + 0.02_wp * rng%uniform()
      end do
    end do
    ! dictionary: 5 neighbour pairs, 3 bottom-wall contacts (obstacle 3), one left wall
    dia = [1, 2, 3, 4, 5, 1, 3, 6, 1]; dib = [2, 3, 4, 5, 6, 0, 0, 0, 0]; dob = [0, 0, 0, 0, 0, 3, 3, 3, 1]
    call cone%from_indices(9, [2, 7, 4, 1, 8])
    ! a random orthonormal start basis
    do k = 1, n0
      do i = 1, nd
        x = rng%normal(); a(i, k) = x
      end do
    end do
    do k = 1, n0
      do i = 1, 2
        a(:, k) = a(:, k) - matmul(a(:, 1:k-1), matmul(a(:, k), a(:, 1:k-1)))
      end do
      a(:, k) = a(:, k) / norm2(a(:, k))
    end do
    v0 = a
  end subroutine make_data

  subroutine test_pga()
    real(wp), allocatable :: v(:,:), vs(:,:)
    type(pga_result_t) :: res, ress
    type(error_t), allocatable :: err
    integer :: per, rem, c0, nc, k, r, j
    real(wp) :: s(nd), worst, rel
    per = nsnap / env%size; rem = mod(nsnap, env%size)
    nc = per; if (env%rank < rem) nc = nc + 1
    c0 = env%rank * per + min(env%rank, rem)
    v = v0
    call pga_enrich(env, [scene], [(1, k = 1, nc)], rad, h, dia, dib, dob, cone, q(:, c0 + 1:c0 + nc), &
      int(c0, i8), v, 1.0e-8_wp, 100, res, err)
    call check(.not. allocated(err), "pga runs")
    call check(res%n_added > 0, "pga adds supremizers")
    call check(res%err(res%n_added + 1) <= 1.0e-8_wp, "pga: final error <= delta")
    call check(maxval(abs(matmul(transpose(v), v) - eye(size(v, 2)))) < 1e-12_wp, "enriched basis orthonormal")
    ! every candidate of every snapshot is now represented to delta
    worst = 0
    do k = 1, nsnap
      do r = 1, cone%r
        call supremizer(scene, rad, h, dia, dib, dob, cone, r, q(:, k), s)
        rel = norm2(s - matmul(v, matmul(s, v))) / norm2(s)
        worst = max(worst, rel)
      end do
    end do
    call check(worst <= 1.0e-8_wp, "pga: every supremizer represented to 1e-8")
    ! the same on one rank with all the data
    vs = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, cone, q, 0_i8, vs, &
      1.0e-8_wp, 100, ress, err)
    call check(ress%n_added == res%n_added, "distributed = serial: same number of additions")
    if (ress%n_added == res%n_added) then
      call check(all(ress%chosen == res%chosen), "distributed = serial: same candidates")
      j = size(v, 2)
      call check(maxval(abs(vs - v)) < 1e-12_wp, "distributed = serial: same basis")
    end if
    call check_choices(vs, ress, q, "delta 1e-8")
    ! a small budget stops early and says so through the error history
    vs = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, cone, q, 0_i8, vs, &
      1.0e-8_wp, 1, ress, err)
    call check(ress%n_added == 1 .and. ress%err(2) > 1.0e-8_wp, "max_add caps the enrichment")
    call check(allocated(ress%note), "max_add: the note says why PGA stopped")
    ! a delta below the round-off level: PGA stops at the whole space or at round-off, with a
    ! note, and never adds directions made of rounding errors
    vs = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, cone, q, 0_i8, vs, &
      1.0e-300_wp, 10 * nd, ress, err)
    call check(.not. allocated(err), "tiny delta: not an error")
    call check(size(vs, 2) <= nd, "tiny delta: no more basis vectors than dofs")
    call check(allocated(ress%note), "tiny delta: the note says why PGA stopped")
    call check(maxval(abs(matmul(transpose(vs), vs) - eye(size(vs, 2)))) < 1e-12_wp, "tiny delta: basis orthonormal")
    call check(all(ress%err == ress%err) .and. ress%err(ress%n_added + 1) <= 1.0e-12_wp, &
      "tiny delta: every supremizer represented to round-off")
    call check_choices(vs, ress, q, "tiny delta")
  end subroutine test_pga

  !> Snapshots that differ from the first by 1e-5 ... 1e-10: the residuals of their supremizers
  !> decay gradually through the exact phase (relative residual < 1e-5), where the residuals
  !> are recomputed (through the projected support rows, or candidate by candidate); every
  !> choice is checked against an eager recomputation, and the two routes against each other.
  subroutine test_pga_graded()
    real(wp) :: qg(nd, nsnap), dq(nd)
    real(wp), allocatable :: v(:,:), vr(:,:), vc(:,:)
    type(pga_result_t) :: res, resr, resc
    type(error_t), allocatable :: err
    type(rng_t) :: rng
    type(sparse_cone_t) :: dense
    integer :: k, i
    call rng%seed(7)
    do k = 1, nsnap
      do i = 1, nd
        dq(i) = rng%normal()
      end do
      qg(:, k) = q(:, 1) + 10.0_wp**(-5 - 5 * real(k - 1, wp) / (nsnap - 1)) * rad * dq / norm2(dq)
    end do
    v = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, cone, qg, 0_i8, v, &
      1.0e-11_wp, 100, res, err)
    call check(.not. allocated(err), "graded pga runs")
    call check(count(res%err(1:res%n_added) < 1.0e-5_wp) >= 2, "graded pga: several additions in the exact phase")
    call check_choices(v, res, qg, "graded")
    ! the exact phase through the projected support rows and candidate by candidate: the same
    ! choices, residuals equal to rounding (both are accurate to a few eps |s|)
    vr = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, cone, qg, 0_i8, vr, &
      1.0e-11_wp, 100, resr, err, exact_route='rows')
    vc = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, cone, qg, 0_i8, vc, &
      1.0e-11_wp, 100, resc, err, exact_route='candidates')
    call check(.not. allocated(err), "graded pga, candidate route runs")
    call check(resr%n_added == resc%n_added, "exact routes: same number of additions")
    if (resr%n_added == resc%n_added) then
      call check(all(resr%chosen == resc%chosen), "exact routes: same choices")
      call check(maxval(abs(resr%err - resc%err)) <= 1.0e3_wp * epsilon(1.0_wp), &
        "exact routes: relative residuals equal to rounding")
      call check(maxval(abs(vr - vc)) <= 1.0e-6_wp, "exact routes: same basis")
    end if
    ! dense cone vectors (mCPG-like, several rows each): both routes agree too
    call dense%from_dense(reshape([(0.1_wp + mod(7 * i, 5), i = 1, 9 * 3)], [9, 3]))
    vr = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, dense, qg, 0_i8, vr, &
      1.0e-11_wp, 100, resr, err, exact_route='rows')
    vc = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, dense, qg, 0_i8, vc, &
      1.0e-11_wp, 100, resc, err, exact_route='candidates')
    call check(resr%n_added == resc%n_added .and. resr%n_added > 0, "dense cone, exact routes: same number of additions")
    if (resr%n_added == resc%n_added) then
      call check(all(resr%chosen == resc%chosen), "dense cone, exact routes: same choices")
      call check(maxval(abs(resr%err - resc%err)) <= 1.0e3_wp * epsilon(1.0_wp), &
        "dense cone, exact routes: relative residuals equal to rounding")
    end if
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, dense, qg, 0_i8, vc, &
      1.0e-11_wp, 100, resc, err, exact_route='fastest')
    call check(allocated(err), "an unknown exact route is refused")
    if (allocated(err)) call check(index(err%message, "rows") > 0, "the refusal lists the known routes")
  end subroutine test_pga_graded

  !> Every choice of a PGA run (basis v = v0 followed by the added vectors) is the candidate
  !> with the largest exact relative residual against the basis before it: an eager
  !> recomputation of every candidate at every step (the choice of the exact phase must
  !> agree), checked while that maximum is above the round-off level.
  subroutine check_choices(v, res, qq, tag)
    real(wp), intent(in) :: v(:,:), qq(:,:)
    type(pga_result_t), intent(in) :: res
    character(len=*), intent(in) :: tag
    integer :: j, k, r, n_checked
    real(wp) :: worst, rel
    n_checked = 0
    do j = 1, res%n_added
      worst = 0
      do k = 1, size(qq, 2)
        do r = 1, cone%r
          worst = max(worst, exact_rel(v(:, 1:n0 + j - 1), qq(:, k), r))
        end do
      end do
      if (worst <= 1.0e-10_wp) exit
      k = int((res%chosen(j) - 1) / cone%r) + 1
      r = int(mod(res%chosen(j) - 1, int(cone%r, i8))) + 1
      rel = exact_rel(v(:, 1:n0 + j - 1), qq(:, k), r)
      call check(rel >= worst * (1 - 1.0e-9_wp), tag // ": choice " // str(j) // " has the largest exact residual")
      n_checked = n_checked + 1
    end do
    call check(n_checked >= min(res%n_added, 3), tag // ": choices checked")
  end subroutine check_choices

  !> Exact relative residual |(I - V V^T) s| / |s| of the supremizer of cone vector r at
  !> snapshot k (orthogonalised twice).
  real(wp) function exact_rel(v, qk, r) result(rel)
    real(wp), intent(in) :: v(:,:), qk(:)
    integer, intent(in) :: r
    real(wp) :: s(nd), w(nd)
    integer :: m
    call supremizer(scene, rad, h, dia, dib, dob, cone, r, qk, s)
    w = s
    do m = 1, 2
      w = w - matmul(v, matmul(w, v))
    end do
    rel = 0
    if (norm2(s) > 0) rel = norm2(w) / norm2(s)
  end function exact_rel

  subroutine test_infsup()
    type(infsup_t) :: g0, g1, g2
    type(sparse_cone_t) :: one
    type(error_t), allocatable :: err
    real(wp), allocatable :: v(:,:), vz(:,:)
    type(pga_result_t) :: res
    real(wp) :: s(nd)
    integer :: k
    ! enriched basis: positive constant at every training configuration
    v = v0
    call pga_enrich(solo, [scene], [(1, k = 1, nsnap)], rad, h, dia, dib, dob, cone, q, 0_i8, v, &
      1.0e-10_wp, 100, res, err)
    do k = 1, nsnap
      call reduced_infsup(scene, rad, h, dia, dib, dob, cone, v, q(:, k), g1, err)
      call check(.not. allocated(err), "infsup runs")
      call check(g1%low <= g1%up * (1 + 1e-12_wp), "bracket low <= up")
      call check(g1%up > 1e-3_wp * h, "enriched: gamma > 0 at training configuration")
    end do
    ! a basis orthogonal to every supremizer: gamma = 0 exactly
    allocate(vz(nd, 1)); vz = 0
    vz(1, 1) = 1   ! x of agent 1 ...
    call supremizer(scene, rad, h, dia, dib, dob, cone, 1, q(:, 1), s)
    vz(:, 1) = [(0.0_wp, k = 1, nd)]
    vz(nd, 1) = 1  ! y of agent 6: only rows 8 (agent 6 - wall) touch it
    call one%from_indices(9, [2, 4])   ! pairs 2-3 and 4-5 do not involve agent 6
    call reduced_infsup(scene, rad, h, dia, dib, dob, one, vz, q(:, 1), g0, err)
    call check(g0%exact .and. g0%up == 0, "orthogonal basis: gamma = 0 (exact)")
    ! R = 1: gamma = |Bh^T e| exactly
    call one%from_indices(9, [8])
    call reduced_infsup(scene, rad, h, dia, dib, dob, one, vz, q(:, 1), g2, err)
    call supremizer(scene, rad, h, dia, dib, dob, one, 1, q(:, 1), s)
    call check(g2%exact, "R = 1 is exact")
    call check_close(g2%up, abs(s(nd)), 1e-14_wp, "R = 1: gamma = |V^T B^T psi|")
  end subroutine test_infsup

  function eye(n) result(e)
    integer, intent(in) :: n
    real(wp) :: e(n, n)
    integer :: i
    e = 0
    do i = 1, n
      e(i, i) = 1
    end do
  end function eye
end program test_enrichment
