!> The reduced models prepared for crowd_rom: for each pair (N, R) the velocity basis (first N
!> POD modes enriched by PGA supremizers of the first R cone vectors) and the hyper-reduction
!> of s1 = v(q), s2 = B(q), s3 = d(q) for that pair: EIM (POD + DEIM of the candidate
!> snapshots) and Empirical Quadrature (NNOMP on the Gramians summed over all ranks).
!> The pair type is the ROM file's (cr_rom_file).
!> Training snapshots of the terms are evaluated at the training configurations q^{nu-1}
!> each rank holds; nothing is gathered except p x p Gramians and the POD's small factors.
module cr_rom_pairs
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_offline_data, only: offline_data_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_supremizer, only: pga_result_t, pga_enrich
  use cr_eim, only: eim_build
  use cr_eq, only: eq_gramian, eq_build
  use cr_rom_file, only: rom_pair_t, TERM_NAMES
  implicit none
  private
  public :: rom_pair_t, build_pair, cone_prefix, TERM_NAMES

contains

  !> The first r vectors of a cone.
  function cone_prefix(cone, r) result(c)
    type(sparse_cone_t), intent(in) :: cone
    integer, intent(in) :: r
    type(sparse_cone_t) :: c
    c%r = r
    c%n_dict = cone%n_dict
    c%ptr = cone%ptr(1:r + 1)
    c%idx = cone%idx(1:cone%ptr(r + 1))
    c%val = cone%val(1:cone%ptr(r + 1))
  end function cone_prefix

  !> Build pair (n, r) from the POD modes phi [n_dof, >= n] and the cone (collective).
  !> pga: enrich with supremizers (delta, max_add); hyper: EIM and EQ with at most
  !> m_factor times the paper's default points, EQ tolerance eq_tol.
  subroutine build_pair(env, data, phi, n, cone, r, pga, pga_delta, pga_max_add, hyper, m_factor, eq_tol, &
      pair, error, v_given)
    type(env_t), intent(in) :: env
    type(offline_data_t), intent(in) :: data
    real(wp), intent(in) :: phi(:,:)
    integer, intent(in) :: n, r
    type(sparse_cone_t), intent(in) :: cone
    logical, intent(in) :: pga, hyper
    real(wp), intent(in) :: pga_delta, m_factor, eq_tol
    integer, intent(in) :: pga_max_add
    type(rom_pair_t), intent(out) :: pair
    type(error_t), allocatable, intent(out) :: error
    !> an already enriched basis [n_dof, >= n] for this pair (PGA is then skipped)
    real(wp), intent(in), optional :: v_given(:,:)
    type(sparse_cone_t) :: cr
    type(pga_result_t) :: res
    real(wp) :: t0
    if (n < 1 .or. n > size(phi, 2)) then
      call set_error(error, "&pairs: n = " // str(n) // " but the POD kept " // str(size(phi, 2)) // &
        " modes", 2); return
    end if
    if (r < 0 .or. r > cone%r) then
      call set_error(error, "&pairs: r = " // str(r) // " but the cone has " // str(cone%r) // &
        " vectors", 2); return
    end if
    pair%n = n; pair%r = r
    pair%v = phi(:, 1:n)
    if (present(v_given)) pair%v = v_given
    cr = cone_prefix(cone, r)
    t0 = env%wtime()
    if (pga .and. r > 0 .and. .not. present(v_given)) then
      call pga_enrich(env, data%scenes, data%scene_of, data%radius, data%dt, data%dict_ia, data%dict_ib, &
        data%dict_ob, cr, data%q, data%lam%col_offset, pair%v, pga_delta, pga_max_add, res, error)
      if (allocated(error)) then
        call prefix_error(error, "PGA of pair (" // str(n) // ", " // str(r) // ")"); return
      end if
      pair%n_pga = res%n_added
      pair%pga_err = res%err
    else
      pair%pga_err = [0.0_wp]
    end if
    pair%t_pga = env%wtime() - t0
    pair%nb = size(pair%v, 2)
    call pair%terms%init(cr, r, data%dict_ia, data%dict_ib, data%dict_ob, data%n_dof, error)
    if (allocated(error)) return
    pair%hyper = hyper
    if (hyper) call build_hyper(env, data, m_factor, eq_tol, pair, error)
  end subroutine build_pair

  !> EIM and EQ of the three terms of `pair` (collective).
  subroutine build_hyper(env, data, m_factor, eq_tol, pair, error)
    type(env_t), intent(in) :: env
    type(offline_data_t), intent(in) :: data
    real(wp), intent(in) :: m_factor, eq_tol
    type(rom_pair_t), intent(inout) :: pair
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: s1(:,:), s2(:,:), s3(:,:), kmat(:,:), h(:,:)
    integer :: c, k, nloc, nb, mdef(3), m_max
    real(wp) :: t0
    t0 = env%wtime()
    nloc = size(data%q, 2)
    allocate(s1(pair%terms%p(1), nloc), s2(pair%terms%p(2), nloc), s3(pair%terms%p(3), nloc))
    do c = 1, nloc
      call pair%terms%snapshot(data%scenes(data%scene_of(c)), data%q(:, c), data%v(:, c), data%radius, &
        data%dt, s1(:, c), s2(:, c), s3(:, c))
    end do
    pair%t_snap = env%wtime() - t0
    nb = size(pair%v, 2)
    mdef = [2 * nb, pair%r, 2 * pair%r]
    do k = 1, 3
      if (pair%terms%p(k) == 0) cycle
      ! EIM of the entries
      m_max = min(pair%terms%p(k), max(1, ceiling(m_factor * mdef(k))))
      t0 = env%wtime()
      select case (k)
      case (1)
        call eim_build(env, s1, m_max, pair%eim(k), error)
      case (2)
        call eim_build(env, s2, m_max, pair%eim(k), error)
      case (3)
        call eim_build(env, s3, m_max, pair%eim(k), error)
      end select
      if (allocated(error)) then
        call prefix_error(error, "EIM of " // TERM_NAMES(k)); return
      end if
      pair%t_eim = pair%t_eim + env%wtime() - t0
      ! EQ of the projected term (s2: candidates are the support rows)
      t0 = env%wtime()
      call pair%terms%kernel(k, pair%v, kmat)
      select case (k)
      case (1)
        call eq_gramian(env, s1, kmat, h, error)
      case (2)
        call row_gramian(h, error)
      case (3)
        call eq_gramian(env, s3, kmat, h, error)
      end select
      if (allocated(error)) then
        call prefix_error(error, "EQ Gramian of " // TERM_NAMES(k)); return
      end if
      m_max = min(size(h, 1), max(1, ceiling(m_factor * mdef(k))))
      call eq_build(h, k /= 2, m_max, eq_tol, pair%eq(k), error)
      if (allocated(error)) then
        call prefix_error(error, "EQ of " // TERM_NAMES(k)); return
      end if
      pair%t_eq = pair%t_eq + env%wtime() - t0
    end do

  contains

    !> H2 = (sum over all ranks' configurations of Y Y^T) o (W W^T), Y = row images [p3, Nb].
    subroutine row_gramian(h, error)
      real(wp), allocatable, intent(out) :: h(:,:)
      type(error_t), allocatable, intent(out) :: error
      real(wp), allocatable :: y(:,:), yy(:)
      integer :: p3
      p3 = pair%terms%p(3)
      allocate(y(p3, nb), yy(p3 * p3))
      yy = 0
      h = reshape(yy, [p3, p3])
      do c = 1, nloc
        call pair%terms%row_images(data%scenes(data%scene_of(c)), data%q(:, c), data%radius, data%dt, pair%v, y)
        h = h + matmul(y, transpose(y))
      end do
      yy = reshape(h, [p3 * p3])
      call env%sum_real_array(yy)
      h = reshape(yy, [p3, p3]) * kmat
      if (any(.not. abs(h) <= huge(1.0_wp))) call set_error(error, "the row Gramian is not finite")
    end subroutine row_gramian
  end subroutine build_hyper
end module cr_rom_pairs
