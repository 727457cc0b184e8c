!> The reduced models prepared for crowd_rom: for each pair (N, R) the velocity basis (first N
!> POD modes enriched by PGA supremizers of the first R cone vectors) and the hyper-reduction
!> of s1 = v(q), s2 = B(q), s3 = d(q) for that pair: every stored method of the factory
!> (cr_hyper_factory; each builds itself from the candidate snapshots, src/hyper).
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
  use cr_hyper_method, only: hyper_train_t
  use cr_hyper_factory, only: stored_hypers
  use cr_rom_file, only: rom_pair_t
  use cr_eim, only: eim_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: rom_pair_t, build_pair, cone_prefix, hyper_summary

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
      pair, error, v_given, s1_shared, s1_shared_m)
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
    !> the EIM of s1 shared by the pairs, built requesting s1_shared_m modes (0: none)
    type(eim_t), intent(in), target, optional :: s1_shared
    integer, intent(in), optional :: s1_shared_m
    type(sparse_cone_t) :: cr
    type(pga_result_t) :: res
    real(wp) :: t0
    if (n < 1 .or. n > size(phi, 2)) then
      call set_error(error, "&pairs: n = " // str(n) // " but the POD kept " // str(size(phi, 2)) // &
        " modes", EXIT_BAD_INPUT); return
    end if
    if (r < 0 .or. r > cone%r) then
      call set_error(error, "&pairs: r = " // str(r) // " but the cone has " // str(cone%r) // &
        " vectors", EXIT_BAD_INPUT); return
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
    if (hyper) then
      if (present(s1_shared) .and. present(s1_shared_m)) then
        call build_hyper(env, data, m_factor, eq_tol, pair, error, s1_shared, s1_shared_m)
      else
        call build_hyper(env, data, m_factor, eq_tol, pair, error)
      end if
    end if
  end subroutine build_pair

  !> Every stored hyper-reduction method of the factory for `pair` (collective): the
  !> candidate snapshots of s1, s2, s3 at this rank's training configurations, then each
  !> method's own build.
  subroutine build_hyper(env, data, m_factor, eq_tol, pair, error, s1_shared, s1_shared_m)
    type(env_t), intent(in) :: env
    type(offline_data_t), intent(in), target :: data
    real(wp), intent(in) :: m_factor, eq_tol
    type(rom_pair_t), intent(inout) :: pair
    type(error_t), allocatable, intent(out) :: error
    type(eim_t), intent(in), target, optional :: s1_shared
    integer, intent(in), optional :: s1_shared_m
    type(hyper_train_t) :: train
    integer :: c, k, nloc
    real(wp) :: t0
    t0 = env%wtime()
    nloc = size(data%q, 2)
    train%v = pair%v
    train%terms = pair%terms
    train%r = pair%r
    train%q => data%q
    train%scenes => data%scenes
    train%scene_of => data%scene_of
    train%radius = data%radius
    train%dt = data%dt
    train%m_factor = m_factor
    train%eq_tol = eq_tol
    if (present(s1_shared) .and. present(s1_shared_m)) then
      if (s1_shared_m > 0) then
        train%s1_shared => s1_shared
        train%s1_shared_m = s1_shared_m
      end if
    end if
    allocate(train%s1(pair%terms%p(1), nloc), train%s2(pair%terms%p(2), nloc), train%s3(pair%terms%p(3), nloc))
    do c = 1, nloc
      call pair%terms%snapshot(data%scenes(data%scene_of(c)), data%q(:, c), data%v(:, c), data%radius, &
        data%dt, train%s1(:, c), train%s2(:, c), train%s3(:, c))
    end do
    pair%t_snap = env%wtime() - t0
    call stored_hypers(pair%methods)
    do k = 1, size(pair%methods)
      call pair%methods(k)%m%build(env, train, error)
      if (allocated(error)) return
    end do
  end subroutine build_hyper

  !> "; <method summary>" for each stored method of `pair` (the log line of crowd_offline).
  function hyper_summary(pair) result(line)
    type(rom_pair_t), intent(in) :: pair
    character(len=:), allocatable :: line
    integer :: j
    line = ""
    if (.not. pair%hyper) return
    line = "; candidates p ="
    do j = 1, 3
      line = line // " " // str(pair%terms%p(j))
    end do
    do j = 1, size(pair%methods)
      line = line // "; " // pair%methods(j)%m%summary()
    end do
  end function hyper_summary
end module cr_rom_pairs
