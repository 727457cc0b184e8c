!> Accuracy figures of a reduced trajectory (the paper's section 4) and the failure modes we
!> measure rather than hide: overlaps between agents (contacts outside the enforced set)
!> and agents that never leave (locking).
!>
!> Per sample (`measure_sample`, docs/model.md#accuracy-measures): the paper's E_mu;
!> the displacement error E_disp = sqrt(sum_nu |qr^nu - q^nu|^2) / sqrt(sum_nu |q^nu - q^0|^2)
!> (nu = 1..N_T); mobility |qr^N_T - q^0| / |q^N_T - q^0|; the deepest agent-agent and
!> agent-obstacle (walls and interior obstacles) overlaps; the quantities of interest of both
!> models (cr_qoi: evacuation curves, times, flows, trust indicators), and from them the times at
!> which EVAC_PCT % of the agents are out (-1: not reached within the horizon). Per row of a sweep
!> (`aggregate_measures`): means and maxima over the samples that did not diverge, and for
!> each evacuation fraction the mean relative time error over the samples where both models
!> reach it, with the counts of samples where only one of them does.
module cr_rom_metrics
  use cr_kinds, only: wp
  use cr_error, only: error_t, prefix_error
  use cr_scene, only: scene_t
  use cr_qoi, only: qoi_t, compute_qoi, max_overlaps, mobility_ratio
  !> the row aggregates and evacuation fractions are those the ROM-run file stores
  use cr_romrun_file, only: row_measures_t, EVAC_PCT
  implicit none
  private
  public :: position_errors, projection_error, max_overlap, evacuation_time, displacement_error
  public :: sample_measures_t, row_measures_t, measure_sample, aggregate_measures, EVAC_PCT

  !> Measures of one reduced trajectory (-1: not available, e.g. no full-order reference).
  type :: sample_measures_t
    real(wp) :: e_mu = -1, e_disp = -1, mobility = -1
    !> deepest agent-agent and agent-obstacle overlap (0: none)
    real(wp) :: overlap_aa = 0, overlap_aw = 0
    !> times at which EVAC_PCT % of the agents are out, reduced and full (-1: not reached)
    real(wp) :: t_rom(2) = -1, t_fom(2) = -1
    integer :: not_left = 0, not_left_fom = -1
    logical :: has_fom = .false.
    !> the trajectory diverged (stopped by the guard): excluded from the aggregates
    logical :: diverged = .false.
    !> agents out at nu = 0..N_T, reduced and full (empty without reference)
    integer, allocatable :: evac_rom(:), evac_fom(:)
    !> quantities of interest of the reduced and (with a reference) the full trajectory
    type(qoi_t) :: qoi_rom, qoi_fom
  end type sample_measures_t


contains

  !> Relative position error per step err(nu) = |q - qr| / |q| (nu = 0..N_T) and the
  !> paper's time-integrated E_mu = sqrt(sum_nu h |q - qr|^2) / sqrt(sum_nu h |q|^2) over
  !> nu = 1..N_T (uniform h cancels). q, qr [n_dof, N_T + 1].
  subroutine position_errors(q, qr, err, e_mu)
    real(wp), intent(in) :: q(:,:), qr(:,:)
    real(wp), intent(out) :: err(:), e_mu
    real(wp) :: num, den, d2, n2
    integer :: nu
    num = 0; den = 0
    do nu = 1, size(q, 2)
      d2 = sum((q(:, nu) - qr(:, nu))**2)
      n2 = sum(q(:, nu)**2)
      err(nu) = sqrt(d2) / max(sqrt(n2), tiny(1.0_wp))
      if (nu > 1) then
        num = num + d2; den = den + n2
      end if
    end do
    e_mu = sqrt(num) / max(sqrt(den), tiny(1.0_wp))
  end subroutine position_errors

  !> Best-approximation error of the velocities u [n_dof, N_T] in the orthonormal basis
  !> v [n_dof, nb]: sqrt(sum |u - V V^T u|^2) / sqrt(sum |u|^2) (0 when u = 0).
  real(wp) function projection_error(u, v) result(e)
    real(wp), intent(in) :: u(:,:), v(:,:)
    real(wp) :: num, den
    integer :: nu
    num = 0; den = 0
    do nu = 1, size(u, 2)
      num = num + sum((u(:, nu) - matmul(v, matmul(u(:, nu), v)))**2)
      den = den + sum(u(:, nu)**2)
    end do
    e = 0
    if (den > 0) e = sqrt(num / den)
  end function projection_error

  !> Deepest overlap (largest -gap, agent-agent or agent-obstacle) over the configurations
  !> q [n_dof, n_conf]; 0 when nothing overlaps.
  real(wp) function max_overlap(scene, radius, q) result(o)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:,:)
    real(wp) :: o_aa, o_aw
    call max_overlaps(scene, radius, q, o_aa, o_aw)
    o = max(o_aa, o_aw)
  end function max_overlap

  !> cr_qoi's time at which pct % of n_agents are out of the curve nout [n_conf] (time step h),
  !> -1 where censored (not reached within the curve).
  pure real(wp) function evacuation_time(nout, n_agents, pct, h) result(t)
    use cr_qoi, only: qoi_time => evacuation_time
    integer, intent(in) :: nout(:), n_agents, pct
    real(wp), intent(in) :: h
    logical :: censored
    call qoi_time(nout, n_agents, pct, h, t, censored)
    if (censored) t = -1
  end function evacuation_time

  !> Displacement error sqrt(sum_nu |qr - q|^2) / sqrt(sum_nu |q - q0|^2) over the
  !> configurations nu = 2..n_conf of q, qr [n_dof, n_conf] (the first is q0); -1 when the
  !> full model does not move.
  real(wp) function displacement_error(q, qr, q0) result(e)
    real(wp), intent(in) :: q(:,:), qr(:,:), q0(:)
    real(wp) :: num, den
    integer :: nu
    num = 0; den = 0
    do nu = 2, size(q, 2)
      num = num + sum((qr(:, nu) - q(:, nu))**2)
      den = den + sum((q(:, nu) - q0)**2)
    end do
    e = -1
    if (den > 0) e = sqrt(num) / sqrt(den)
  end function displacement_error

  !> Every measure of one reduced trajectory qr [n_dof, N_T + 1] (time step h), against
  !> the full-order one q [n_dof, N_T + 1] when present; err [N_T + 1] (optional) receives
  !> the per-step relative position error; qoi_fom (optional) are the full-order trajectory's
  !> QoIs as stored (otherwise computed from q). The QoIs use the body radius `radius`; the
  !> overlaps m%overlap_aa / aw measure the model's constraints, at contact_radius (default
  !> radius; r + d_s / 2 with a social distance: a reduced agent inside another's ring counts).
  subroutine measure_sample(scene, radius, h, qr, m, error, q, err, qoi_fom, contact_radius)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h, qr(:,:)
    type(sample_measures_t), intent(out) :: m
    type(error_t), allocatable, intent(out) :: error
    real(wp), intent(in), optional :: q(:,:)
    real(wp), intent(out), optional :: err(:)
    type(qoi_t), intent(in), optional :: qoi_fom
    real(wp), intent(in), optional :: contact_radius
    real(wp), allocatable :: e(:)
    call compute_qoi(scene, radius, h, qr, m%qoi_rom, error)
    if (allocated(error)) then
      call prefix_error(error, "reduced trajectory"); return
    end if
    m%overlap_aa = m%qoi_rom%overlap_aa; m%overlap_aw = m%qoi_rom%overlap_aw
    if (present(contact_radius)) then
      if (contact_radius /= radius) call max_overlaps(scene, contact_radius, qr, m%overlap_aa, m%overlap_aw)
    end if
    call evac_times(m%qoi_rom, m%evac_rom, m%not_left, m%t_rom)
    m%has_fom = present(q)
    if (.not. m%has_fom) then
      allocate(m%evac_fom(0))
      return
    end if
    if (present(qoi_fom)) then
      m%qoi_fom = qoi_fom
    else
      call compute_qoi(scene, radius, h, q, m%qoi_fom, error)
      if (allocated(error)) then
        call prefix_error(error, "full-order trajectory"); return
      end if
    end if
    allocate(e(size(qr, 2)))
    call position_errors(q, qr, e, m%e_mu)
    if (present(err)) err = e
    m%e_disp = displacement_error(q, qr, qr(:, 1))
    m%mobility = mobility_ratio(m%qoi_rom%displacement, m%qoi_fom%displacement)
    call evac_times(m%qoi_fom, m%evac_fom, m%not_left_fom, m%t_fom)
  end subroutine measure_sample

  !> The sweep's evacuation figures from the QoIs: curve, agents not out at the end, times of
  !> EVAC_PCT % out (-1: censored).
  subroutine evac_times(qoi, evac, not_left, t)
    type(qoi_t), intent(in) :: qoi
    integer, allocatable, intent(out) :: evac(:)
    integer, intent(out) :: not_left
    real(wp), intent(out) :: t(:)
    integer :: j
    allocate(evac(size(qoi%curve_total)))
    evac = qoi%curve_total
    not_left = qoi%n_agents - evac(size(evac))
    do j = 1, size(EVAC_PCT)
      t(j) = evacuation_time(evac, qoi%n_agents, EVAC_PCT(j), qoi%h)
    end do
  end subroutine evac_times

  !> Aggregate the measures ms of the samples of one row (time step h): every figure over
  !> the samples that did not diverge.
  subroutine aggregate_measures(ms, h, agg)
    type(sample_measures_t), intent(in) :: ms(:)
    real(wp), intent(in) :: h
    type(row_measures_t), intent(out) :: agg
    logical :: ok(size(ms)), ref(size(ms))
    real(wp) :: s
    integer :: k, j, n
    agg%n_samples = size(ms)
    ok = .not. ms%diverged
    agg%n_diverged = count(.not. ok)
    if (.not. any(ok)) return
    agg%overlap_aa = maxval(ms%overlap_aa, mask=ok)
    agg%overlap_aw = maxval(ms%overlap_aw, mask=ok)
    agg%not_left = sum(ms%not_left, mask=ok)
    ref = ok .and. ms%has_fom
    if (.not. any(ref)) return
    n = count(ref)
    agg%e_avg = sum(ms%e_mu, mask=ref) / n
    agg%e_max = maxval(ms%e_mu, mask=ref)
    agg%not_left_fom = sum(ms%not_left_fom, mask=ref)
    if (all(ms%e_disp >= 0 .or. .not. ref)) agg%e_disp = sum(ms%e_disp, mask=ref) / n
    if (all(ms%mobility >= 0 .or. .not. ref)) agg%mobility = sum(ms%mobility, mask=ref) / n
    do j = 1, size(EVAC_PCT)
      s = 0
      do k = 1, size(ms)
        if (.not. ref(k)) cycle
        if (ms(k)%t_fom(j) < 0) then
          agg%t_fom_missed(j) = agg%t_fom_missed(j) + 1
        else if (ms(k)%t_rom(j) < 0) then
          agg%t_rom_missed(j) = agg%t_rom_missed(j) + 1
        else
          agg%t_n(j) = agg%t_n(j) + 1
          s = s + abs(ms(k)%t_rom(j) - ms(k)%t_fom(j)) / max(ms(k)%t_fom(j), h)
        end if
      end do
      if (agg%t_n(j) > 0) agg%t_err(j) = s / agg%t_n(j)
    end do
  end subroutine aggregate_measures

end module cr_rom_metrics
