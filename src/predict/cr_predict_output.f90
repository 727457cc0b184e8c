!> What crowd_predict keeps of one query (its record) and the product it writes.
!>
!> A record is computed on the rank that ran the query and travels to rank 0 packed into one
!> real vector of fixed length (record_size): the per-query CPU seconds, the flags, the
!> quantities of interest of the trajectory and, on request, its positions.
module cr_predict_output
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, prefix_error
  use cr_h5file, only: h5file_t
  use cr_digest, only: digest_of, put_digest
  use cr_scene, only: scene_t
  use cr_rom_metrics, only: evacuation_curve, evacuation_time, max_overlaps
  implicit none
  private
  public :: query_record_t, record_size, pack_record, unpack_record, predict_product_t, write_predict_product, &
    PREDICT_PCT

  !> the evacuation percentages of t50, t90, t100
  integer, parameter :: PREDICT_PCT(3) = [50, 90, 100]
  !> scalar slots of a packed record (before the curve)
  integer, parameter :: N_SCALARS = 5 + 2 * size(PREDICT_PCT) + 2

  !> One query's result.
  type :: query_record_t
    !> CPU seconds of the query (setup, trajectory and measures)
    real(wp) :: cpu = 0
    logical :: out_of_box = .false.
    !> reduced: first diverged step (0: none), infeasible and capped steps; exact: steps whose
    !> projection did not converge (n_capped)
    integer :: diverged_step = 0, n_infeasible = 0, n_capped = 0
    !> agents out at each frame [n_steps + 1]
    integer, allocatable :: curve(:)
    !> t50, t90, t100 [s]; censored: not reached within the horizon (value = the horizon)
    real(wp) :: t_pct(size(PREDICT_PCT)) = 0
    logical :: censored(size(PREDICT_PCT)) = .false.
    !> deepest agent-agent and agent-obstacle overlaps over the frames [m]
    real(wp) :: overlap_aa = 0, overlap_aw = 0
    !> positions [n_dof, n_steps + 1] and, reduced model, the velocity coefficients
    !> [n_basis, n_steps] (trajectories = .true. only)
    real(wp), allocatable :: q(:,:), alpha(:,:)
  contains
    procedure :: measure
  end type query_record_t

  !> The run's description for the product.
  type :: predict_product_t
    character(len=:), allocatable :: config, model, rom_file, source, param_names
    real(wp), allocatable :: param_min(:), param_max(:)
    integer :: n_agents = 0, n_steps = 0, n_ranks = 1
    !> reduced model: the pair of the ROM file (index, N, R, basis size; 0 for the exact model)
    integer :: pair = 0, pair_n = 0, pair_r = 0, n_basis = 0
    real(wp) :: dt = 0, radius = 0, t_wall = 0
  end type predict_product_t

contains

  !> The quantities of interest of trajectory q [n_dof, n_steps + 1] on `scene`.
  subroutine measure(this, scene, radius, h, q)
    class(query_record_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h, q(:,:)
    integer :: j, na
    na = size(q, 1) / 2
    this%curve = evacuation_curve(scene, radius, q)
    do j = 1, size(PREDICT_PCT)
      this%t_pct(j) = evacuation_time(this%curve, na, PREDICT_PCT(j), h)
      this%censored(j) = this%t_pct(j) < 0
      if (this%censored(j)) this%t_pct(j) = (size(q, 2) - 1) * h
    end do
    call max_overlaps(scene, radius, q, this%overlap_aa, this%overlap_aw)
  end subroutine measure

  !> Length of a packed record (with_q: positions and n_basis coefficients per step).
  pure integer function record_size(n_steps, n_dof, n_basis, with_q) result(n)
    integer, intent(in) :: n_steps, n_dof, n_basis
    logical, intent(in) :: with_q
    n = N_SCALARS + (n_steps + 1)
    if (with_q) n = n + n_dof * (n_steps + 1) + n_basis * n_steps
  end function record_size

  !> r into x [record_size] (positions only when allocated).
  subroutine pack_record(r, x)
    type(query_record_t), intent(in) :: r
    real(wp), intent(out) :: x(:)
    integer :: m, nc
    m = size(PREDICT_PCT)
    nc = size(r%curve)
    x(1:5) = [r%cpu, merge(1.0_wp, 0.0_wp, r%out_of_box), real(r%diverged_step, wp), real(r%n_infeasible, wp), &
      real(r%n_capped, wp)]
    x(6:5 + m) = r%t_pct
    x(6 + m:5 + 2 * m) = merge(1.0_wp, 0.0_wp, r%censored)
    x(6 + 2 * m:7 + 2 * m) = [r%overlap_aa, r%overlap_aw]
    x(N_SCALARS + 1:N_SCALARS + nc) = real(r%curve, wp)
    if (allocated(r%q)) x(N_SCALARS + nc + 1:N_SCALARS + nc + size(r%q)) = reshape(r%q, [size(r%q)])
    if (allocated(r%alpha)) x(N_SCALARS + nc + size(r%q) + 1:) = reshape(r%alpha, [size(r%alpha)])
  end subroutine pack_record

  !> The record of x (n_steps, n_dof, n_basis, with_q as for record_size).
  subroutine unpack_record(x, n_steps, n_dof, n_basis, with_q, r)
    real(wp), intent(in) :: x(:)
    integer, intent(in) :: n_steps, n_dof, n_basis
    logical, intent(in) :: with_q
    type(query_record_t), intent(out) :: r
    integer :: m, nc
    m = size(PREDICT_PCT)
    nc = n_steps + 1
    r%cpu = x(1); r%out_of_box = x(2) > 0
    r%diverged_step = nint(x(3)); r%n_infeasible = nint(x(4)); r%n_capped = nint(x(5))
    r%t_pct = x(6:5 + m)
    r%censored = x(6 + m:5 + 2 * m) > 0
    r%overlap_aa = x(6 + 2 * m); r%overlap_aw = x(7 + 2 * m)
    r%curve = nint(x(N_SCALARS + 1:N_SCALARS + nc))
    if (.not. with_q) return
    r%q = reshape(x(N_SCALARS + nc + 1:N_SCALARS + nc + n_dof * nc), [n_dof, nc])
    if (n_basis > 0) r%alpha = reshape(x(N_SCALARS + nc + n_dof * nc + 1:N_SCALARS + nc + n_dof * nc + &
      n_basis * n_steps), [n_basis, n_steps])
  end subroutine unpack_record

  !> The product at `path` (temporary + rename): parameters mu [n_expanded, n_queries] and
  !> the records rec [n_queries] in query order.
  subroutine write_predict_product(path, p, mu, rec, error)
    character(len=*), intent(in) :: path
    type(predict_product_t), intent(in) :: p
    real(wp), intent(in) :: mu(:,:)
    type(query_record_t), intent(in) :: rec(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    integer :: k, nq, nc, j
    integer, allocatable :: curve(:,:)
    real(wp), allocatable :: t(:,:), pos(:,:)
    nq = size(rec)
    nc = p%n_steps + 1
    call h5%create(path, error)
    if (allocated(error)) return
    call h5%write_attr("/", "schema", "crowdrom-prediction", error); if (allocated(error)) goto 9
    call h5%write_attr("/", "schema_version", 1, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "program", "crowd_predict", error); if (allocated(error)) goto 9
    call h5%write_attr("/", "model", p%model, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "config", p%config, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "rom_file", p%rom_file, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "queries_from", p%source, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "param_names", p%param_names, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "param_min", p%param_min, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "param_max", p%param_max, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_queries", nq, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_agents", p%n_agents, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_steps", p%n_steps, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "dt", p%dt, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "agent_radius", p%radius, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_ranks", p%n_ranks, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "wall_seconds", p%t_wall, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "pair", p%pair, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "pair_n", p%pair_n, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "pair_r", p%pair_r, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_basis", p%n_basis, error); if (allocated(error)) goto 9
    call put_real("params", mu); if (allocated(error)) goto 9
    call put_int("out_of_box", merge(1, 0, rec%out_of_box)); if (allocated(error)) goto 9
    call put_real1("cpu_seconds", rec%cpu); if (allocated(error)) goto 9
    call put_int("diverged_step", rec%diverged_step); if (allocated(error)) goto 9
    call put_int("n_infeasible", rec%n_infeasible); if (allocated(error)) goto 9
    call put_int("n_capped", rec%n_capped); if (allocated(error)) goto 9
    allocate(curve(nc, nq), t(size(PREDICT_PCT), nq))
    do k = 1, nq
      curve(:, k) = rec(k)%curve
      t(:, k) = rec(k)%t_pct
    end do
    call put_int2("curve_total", curve); if (allocated(error)) goto 9
    do j = 1, size(PREDICT_PCT)
      call put_real1("t" // trim(num(PREDICT_PCT(j))), t(j, :)); if (allocated(error)) goto 9
      call put_int("t" // trim(num(PREDICT_PCT(j))) // "_censored", merge(1, 0, rec%censored(j)))
      if (allocated(error)) goto 9
    end do
    call put_real1("max_overlap_agents", rec%overlap_aa); if (allocated(error)) goto 9
    call put_real1("max_overlap_walls", rec%overlap_aw); if (allocated(error)) goto 9
    if (nq > 0) then
      if (allocated(rec(1)%q)) then
        allocate(pos(size(rec(1)%q, 1), nc * nq))
        do k = 1, nq
          pos(:, (k - 1) * nc + 1:k * nc) = rec(k)%q
        end do
        call put_real("positions", pos); if (allocated(error)) goto 9
        deallocate(pos)
      end if
      if (allocated(rec(1)%alpha)) then
        allocate(pos(size(rec(1)%alpha, 1), p%n_steps * nq))
        do k = 1, nq
          pos(:, (k - 1) * p%n_steps + 1:k * p%n_steps) = rec(k)%alpha
        end do
        call put_real("alpha", pos); if (allocated(error)) goto 9
      end if
    end if
    call h5%commit(error)
9   if (allocated(error)) then
      call prefix_error(error, "prediction product '" // path // "'")
      call h5%abort()
    end if

  contains

    subroutine put_real(name, x)
      character(len=*), intent(in) :: name
      real(wp), intent(in) :: x(:,:)
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine put_real

    subroutine put_real1(name, x)
      character(len=*), intent(in) :: name
      real(wp), intent(in) :: x(:)
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine put_real1

    subroutine put_int(name, x)
      character(len=*), intent(in) :: name
      integer, intent(in) :: x(:)
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine put_int

    subroutine put_int2(name, x)
      character(len=*), intent(in) :: name
      integer, intent(in) :: x(:,:)
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine put_int2

    function num(i) result(s)
      integer, intent(in) :: i
      character(len=8) :: s
      write(s, '(i0)') i
    end function num
  end subroutine write_predict_product
end module cr_predict_output
