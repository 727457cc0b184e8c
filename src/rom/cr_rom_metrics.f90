!> Accuracy figures of a reduced trajectory (the paper's section 4) and the failure modes we
!> measure rather than hide: overlaps between agents (contacts outside the enforced set)
!> and agents that never leave (locking).
!>
!> Per sample (`measure_sample`, docs/model.md#accuracy-measures): the paper's E_mu;
!> the displacement error E_disp = sqrt(sum_nu |qr^nu - q^nu|^2) / sqrt(sum_nu |q^nu - q^0|^2)
!> (nu = 1..N_T); mobility |qr^N_T - q^0| / |q^N_T - q^0|; the deepest agent-agent and
!> agent-obstacle (walls and interior obstacles) overlaps; the evacuation curves (agents out
!> of the hall at t = nu h, nu = 0..N_T) of both models and the times at which EVAC_PCT % of
!> the agents are out (-1: not reached within the horizon). Per row of a sweep
!> (`aggregate_measures`): means and maxima over the samples that did not diverge, and for
!> each evacuation fraction the mean relative time error over the samples where both models
!> reach it, with the counts of samples where only one of them does.
module cr_rom_metrics
  use cr_kinds, only: wp
  use cr_scene, only: scene_t
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  !> the row aggregates and evacuation fractions are those the ROM-run file stores
  use cr_romrun_file, only: row_measures_t, EVAC_PCT
  implicit none
  private
  public :: position_errors, projection_error, max_overlap, agents_not_left
  public :: max_overlaps, evacuation_curve, evacuation_time, displacement_error
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
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    integer :: nu, l
    o = 0
    call cs%init(size(q, 1) / 2, 1.0_wp, 4 * size(q, 1))
    do nu = 1, size(q, 2)
      call build_contacts(scene, q(:, nu), radius, 1.0e-12_wp * radius, cells, cs)
      do l = 1, cs%n
        o = max(o, -cs%gap(l))
      end do
    end do
  end function max_overlap

  !> Deepest agent-agent (o_aa) and agent-obstacle (o_aw: walls and interior obstacles)
  !> overlaps over the configurations q [n_dof, n_conf]; 0 when nothing overlaps.
  subroutine max_overlaps(scene, radius, q, o_aa, o_aw)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:,:)
    real(wp), intent(out) :: o_aa, o_aw
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    integer :: nu, l
    o_aa = 0; o_aw = 0
    call cs%init(size(q, 1) / 2, 1.0_wp, 4 * size(q, 1))
    do nu = 1, size(q, 2)
      call build_contacts(scene, q(:, nu), radius, 1.0e-12_wp * radius, cells, cs)
      do l = 1, cs%n
        if (cs%ib(l) > 0) then
          o_aa = max(o_aa, -cs%gap(l))
        else
          o_aw = max(o_aw, -cs%gap(l))
        end if
      end do
    end do
  end subroutine max_overlaps

  !> Evacuation curve: agents out of the hall (scene%is_out: centre above scene%y_out(radius),
  !> or beyond the right wall when the scene has a second exit) in each
  !> configuration of q [n_dof, n_conf].
  function evacuation_curve(scene, radius, q) result(nout)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:,:)
    integer, allocatable :: nout(:)
    integer :: nu
    allocate(nout(size(q, 2)))
    do nu = 1, size(q, 2)
      nout(nu) = size(q, 1) / 2 - agents_not_left(scene, radius, q(:, nu))
    end do
  end function evacuation_curve

  !> First time t = (c - 1) h at which the curve nout(c) reaches pct % of n_agents (at least
  !> ceiling(pct n_agents / 100) agents out); -1 when not reached within the curve.
  pure real(wp) function evacuation_time(nout, n_agents, pct, h) result(t)
    integer, intent(in) :: nout(:), n_agents, pct
    real(wp), intent(in) :: h
    integer :: c, k
    k = (pct * n_agents + 99) / 100
    t = -1
    do c = 1, size(nout)
      if (nout(c) >= k) then
        t = (c - 1) * h; return
      end if
    end do
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
  !> the per-step relative position error.
  subroutine measure_sample(scene, radius, h, qr, m, q, err)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h, qr(:,:)
    type(sample_measures_t), intent(out) :: m
    real(wp), intent(in), optional :: q(:,:)
    real(wp), intent(out), optional :: err(:)
    real(wp), allocatable :: e(:)
    integer :: na, nc, j
    na = size(qr, 1) / 2
    nc = size(qr, 2)
    call max_overlaps(scene, radius, qr, m%overlap_aa, m%overlap_aw)
    m%evac_rom = evacuation_curve(scene, radius, qr)
    m%not_left = na - m%evac_rom(nc)
    do j = 1, size(EVAC_PCT)
      m%t_rom(j) = evacuation_time(m%evac_rom, na, EVAC_PCT(j), h)
    end do
    m%has_fom = present(q)
    if (.not. m%has_fom) then
      allocate(m%evac_fom(0))
      return
    end if
    allocate(e(nc))
    call position_errors(q, qr, e, m%e_mu)
    if (present(err)) err = e
    m%e_disp = displacement_error(q, qr, qr(:, 1))
    if (norm2(q(:, nc) - q(:, 1)) > 0) m%mobility = norm2(qr(:, nc) - qr(:, 1)) / norm2(q(:, nc) - q(:, 1))
    m%evac_fom = evacuation_curve(scene, radius, q)
    m%not_left_fom = na - m%evac_fom(nc)
    do j = 1, size(EVAC_PCT)
      m%t_fom(j) = evacuation_time(m%evac_fom, na, EVAC_PCT(j), h)
    end do
  end subroutine measure_sample

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

  !> Agents that have not left the hall at configuration q [n_dof].
  integer function agents_not_left(scene, radius, q) result(n)
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, q(:)
    integer :: i
    n = 0
    do i = 1, size(q) / 2
      if (.not. scene%is_out(q(2*i-1:2*i), radius)) n = n + 1
    end do
  end function agents_not_left
end module cr_rom_metrics
