!> The reduced inf-sup table of crowd_offline: gamma(N, R) brackets (see cr_infsup) for a
!> grid of (N, R) at training configurations spread over the training columns (each rank
!> evaluates the sampled columns it holds), without and with supremizer enrichment (PGA of
!> the first N POD modes for the first R cone vectors; an enrichment already in the run's
!> cache, cr_pga_cache, is reused, and each new one is added to it).
module cr_infsup_table
  use cr_kinds, only: wp
  use cr_error, only: error_t, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_offline_config, only: offline_cfg_t
  use cr_offline_data, only: offline_data_t
  use cr_pod, only: pod_result_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_supremizer, only: pga_result_t, pga_enrich
  use cr_pga_cache, only: pga_cache_t
  use cr_infsup, only: infsup_t, reduced_infsup
  use cr_rom_file, only: rom_tables_t
  implicit none
  private
  public :: infsup_table

contains

  !> Reduced inf-sup constants for the (N, R) grid of &offline at infsup_samples training
  !> configurations (spread over the training columns), without and with supremizers.
  !> cache: the enrichments computed so far (used, and completed with the grid's).
  subroutine infsup_table(env, log, ocfg, data, pod, scone, cache, tab, error)
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(offline_cfg_t), intent(in) :: ocfg
    type(offline_data_t), intent(in) :: data
    type(pod_result_t), intent(in) :: pod
    type(sparse_cone_t), intent(in) :: scone
    type(pga_cache_t), intent(inout) :: cache
    type(rom_tables_t), intent(inout) :: tab
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: ns(:), rs(:)
    type(sparse_cone_t) :: sub
    type(pga_result_t) :: pres
    real(wp), allocatable :: vv(:,:), acc(:)
    integer :: a, b, m, npair, ncols, stride, hit
    real(wp) :: lo(4), hi(4)
    ns = pack(ocfg%infsup_n, ocfg%infsup_n > 0)
    rs = pack(ocfg%infsup_r, ocfg%infsup_r > 0)
    if (size(ns) == 0) ns = pack([5, 10, 20, 40], [5, 10, 20, 40] <= pod%n_modes)
    if (size(rs) == 0) rs = pack([5, 10, 20, 40, 80], [5, 10, 20, 40, 80] <= scone%r)
    ns = pack(ns, ns <= pod%n_modes)
    rs = pack(rs, rs <= scone%r)
    npair = size(ns) * size(rs)
    allocate(tab%is_n(npair), tab%is_r(npair), tab%is_low_min(npair), tab%is_up_min(npair), tab%is_up_mean(npair))
    allocate(tab%is_low_min_pga(npair), tab%is_up_min_pga(npair), tab%is_up_mean_pga(npair), tab%is_n_pga(npair))
    if (npair == 0 .or. ocfg%infsup_samples == 0) then
      deallocate(tab%is_n); allocate(tab%is_n(0)); return
    end if
    ncols = data%n_train * data%n_steps
    stride = max(1, ncols / ocfg%infsup_samples)
    m = 0
    do a = 1, size(ns)
      do b = 1, size(rs)
        m = m + 1
        tab%is_n(m) = ns(a); tab%is_r(m) = rs(b)
        call take_cone(scone, rs(b), sub)
        ! acc: [low_min, up_min, up_sum, count] without, then with supremizers
        allocate(acc(8)); acc = [huge(1.0_wp), huge(1.0_wp), 0.0_wp, 0.0_wp, huge(1.0_wp), huge(1.0_wp), 0.0_wp, 0.0_wp]
        vv = pod%phi(:, 1:ns(a))
        call sweep(ocfg, data, sub, vv, stride, ncols, acc(1:4), error)
        if (allocated(error)) return
        hit = cache%find(ns(a), rs(b))
        if (hit > 0) then
          vv = cache%entries(hit)%v
        else
          vv = pod%phi(:, 1:ns(a))
          call pga_enrich(env, data%scenes, data%scene_of, data%radius, data%dt, data%dict_ia, data%dict_ib, &
            data%dict_ob, sub, data%q, data%lam%col_offset, vv, ocfg%pga_delta, ocfg%pga_max_add, pres, error)
          if (allocated(error)) return
          call cache%add(ns(a), rs(b), vv, pres)
        end if
        tab%is_n_pga(m) = size(vv, 2)
        call sweep(ocfg, data, sub, vv, stride, ncols, acc(5:8), error)
        if (allocated(error)) return
        lo = acc([1, 2, 5, 6]); hi = acc([3, 4, 7, 8])
        call env%allreduce(lo, 'min', error)
        if (.not. allocated(error)) call env%allreduce(hi, 'sum', error)
        if (allocated(error)) then
          call prefix_error(error, "infsup_table"); return
        end if
        acc([1, 2, 5, 6]) = lo; acc([3, 4, 7, 8]) = hi
        tab%is_low_min(m) = acc(1); tab%is_up_min(m) = acc(2); tab%is_up_mean(m) = acc(3) / max(acc(4), 1.0_wp)
        tab%is_low_min_pga(m) = acc(5); tab%is_up_min_pga(m) = acc(6)
        tab%is_up_mean_pga(m) = acc(7) / max(acc(8), 1.0_wp)
        call log%info("   N = " // str(ns(a)) // ", R = " // str(rs(b)) // ": gamma in [" // str(acc(1)) // ", " // &
          str(acc(2)) // "]; with supremizers (N = " // str(tab%is_n_pga(m)) // ") [" // str(acc(5)) // ", " // &
          str(acc(6)) // "]")
        deallocate(acc)
      end do
    end do

  end subroutine infsup_table

  !> acc = [min gamma_low, min gamma_up, sum gamma_up, count] over the local sampled columns.
  subroutine sweep(ocfg, data, sub, basis, stride, ncols, acc, error)
    type(offline_cfg_t), intent(in) :: ocfg
    type(offline_data_t), intent(in) :: data
    type(sparse_cone_t), intent(in) :: sub
    real(wp), intent(in) :: basis(:,:)
    integer, intent(in) :: stride, ncols
    real(wp), intent(inout) :: acc(4)
    type(error_t), allocatable, intent(out) :: error
    type(infsup_t) :: g
    integer :: k, jcol, loc
    do k = 1, ocfg%infsup_samples
      jcol = 1 + (k - 1) * stride
      if (jcol > ncols) exit
      loc = jcol - int(data%lam%col_offset)
      if (loc < 1 .or. loc > data%lam%n_cols) cycle
      call reduced_infsup(data%scenes(data%scene_of(loc)), data%radius, data%dt, data%dict_ia, data%dict_ib, &
        data%dict_ob, sub, basis, data%q(:, loc), g, error)
      if (allocated(error)) return
      acc(1) = min(acc(1), g%low)
      acc(2) = min(acc(2), g%up)
      acc(3) = acc(3) + g%up
      acc(4) = acc(4) + 1
    end do
  end subroutine sweep

  !> The first r vectors of a cone.
  subroutine take_cone(c, r, sub)
    type(sparse_cone_t), intent(in) :: c
    integer, intent(in) :: r
    type(sparse_cone_t), intent(inout) :: sub
    sub%r = r; sub%n_dict = c%n_dict
    sub%ptr = c%ptr(1:r + 1)
    sub%idx = c%idx(1:c%ptr(r + 1))
    sub%val = c%val(1:c%ptr(r + 1))
  end subroutine take_cone
end module cr_infsup_table
