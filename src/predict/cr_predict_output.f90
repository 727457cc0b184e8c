!> What crowd_predict keeps of one query (its record) and the product it writes (the QoI
!> product of cr_qoi_file with the prediction's own datasets).
!>
!> A record is computed on the rank that ran the query and travels to rank 0 packed into one
!> real vector of fixed length (record_size): the per-query CPU seconds, the flags, the
!> quantities of interest of the trajectory and, on request, its positions.
module cr_predict_output
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_h5file, only: h5file_t
  use cr_fsys, only: rename_file, remove_file
  use cr_qoi_file, only: qoi_product_t, write_qoi_product
  use cr_digest, only: digest_of, put_digest
  use cr_scene, only: scene_t
  use cr_qoi, only: qoi_t, compute_qoi, QOI_PCT
  implicit none
  private
  public :: query_record_t, record_size, pack_record, unpack_record, predict_product_t, write_predict_product, &
    MAX_EXITS

  !> exits of a scene at most (the top wall's, the right wall's)
  integer, parameter :: MAX_EXITS = 2
  !> scalar slots of a packed record: the query's (5), the QoIs' (n_exits, t_evac, censored,
  !> overlaps, n_through, displacement), per exit width, flow rate, flow, defined
  integer, parameter :: N_SCALARS = 5 + 1 + 2 * size(QOI_PCT) + 4 + 4 * MAX_EXITS

  !> One query's result.
  type :: query_record_t
    !> CPU seconds of the query (setup, trajectory and QoIs)
    real(wp) :: cpu = 0
    logical :: out_of_box = .false.
    !> reduced: first diverged step (0: none), infeasible and capped steps; exact: steps whose
    !> projection did not converge (n_capped)
    integer :: diverged_step = 0, n_infeasible = 0, n_capped = 0
    !> the quantities of interest of the trajectory (cr_qoi)
    type(qoi_t) :: qoi
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

  !> The quantities of interest of trajectory q [n_dof, n_steps + 1] on `scene` (cr_qoi).
  subroutine measure(this, scene, radius, h, q, error)
    class(query_record_t), intent(inout) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: radius, h, q(:,:)
    type(error_t), allocatable, intent(out) :: error
    call compute_qoi(scene, radius, h, q, this%qoi, error)
  end subroutine measure

  !> Length of a packed record (with_q: positions and n_basis coefficients per step).
  pure integer function record_size(n_steps, n_dof, n_basis, with_q) result(n)
    integer, intent(in) :: n_steps, n_dof, n_basis
    logical, intent(in) :: with_q
    n = N_SCALARS + MAX_EXITS * (n_steps + 1)
    if (with_q) n = n + n_dof * (n_steps + 1) + n_basis * n_steps
  end function record_size

  !> r into x [record_size] (positions and coefficients only when allocated).
  subroutine pack_record(r, x)
    type(query_record_t), intent(in) :: r
    real(wp), intent(out) :: x(:)
    integer :: m, nc, e, i
    m = size(QOI_PCT)
    x = 0
    associate (qo => r%qoi)
      nc = qo%n_steps + 1
      x(1:6) = [r%cpu, b2r(r%out_of_box), real(r%diverged_step, wp), real(r%n_infeasible, wp), real(r%n_capped, wp), &
        real(qo%n_exits, wp)]
      x(7:6 + m) = qo%t_evac
      x(7 + m:6 + 2 * m) = merge(1.0_wp, 0.0_wp, qo%censored)
      i = 6 + 2 * m
      x(i + 1:i + 4) = [qo%overlap_aa, qo%overlap_aw, real(qo%n_through, wp), qo%displacement]
      i = i + 4
      do e = 1, qo%n_exits
        x(i + 4 * e - 3:i + 4 * e) = [qo%width(e), qo%flow_rate(e), qo%flow(e), b2r(qo%flow_defined(e))]
        x(N_SCALARS + (e - 1) * nc + 1:N_SCALARS + e * nc) = real(qo%curve(:, e), wp)
      end do
      i = N_SCALARS + MAX_EXITS * nc
    end associate
    if (allocated(r%q)) x(i + 1:i + size(r%q)) = reshape(r%q, [size(r%q)])
    if (allocated(r%alpha)) x(i + size(r%q) + 1:i + size(r%q) + size(r%alpha)) = reshape(r%alpha, [size(r%alpha)])

  contains

    pure real(wp) function b2r(l)
      logical, intent(in) :: l
      b2r = merge(1.0_wp, 0.0_wp, l)
    end function b2r
  end subroutine pack_record

  !> The record of x (n_steps, n_dof, n_basis, with_q as for record_size; h the time step,
  !> n_agents the agents).
  subroutine unpack_record(x, n_steps, n_dof, n_basis, with_q, h, r)
    real(wp), intent(in) :: x(:)
    integer, intent(in) :: n_steps, n_dof, n_basis
    logical, intent(in) :: with_q
    real(wp), intent(in) :: h
    type(query_record_t), intent(out) :: r
    integer :: m, nc, e, i, ne
    m = size(QOI_PCT)
    nc = n_steps + 1
    r%cpu = x(1); r%out_of_box = x(2) > 0
    r%diverged_step = nint(x(3)); r%n_infeasible = nint(x(4)); r%n_capped = nint(x(5))
    ne = nint(x(6))
    associate (qo => r%qoi)
      qo%n_agents = n_dof / 2; qo%n_steps = n_steps; qo%n_exits = ne; qo%h = h
      qo%t_evac = x(7:6 + m)
      qo%censored = x(7 + m:6 + 2 * m) > 0
      i = 6 + 2 * m
      qo%overlap_aa = x(i + 1); qo%overlap_aw = x(i + 2); qo%n_through = nint(x(i + 3)); qo%displacement = x(i + 4)
      i = i + 4
      allocate(qo%width(ne), qo%flow_rate(ne), qo%flow(ne), qo%flow_defined(ne), qo%curve(0:n_steps, ne))
      do e = 1, ne
        qo%width(e) = x(i + 4 * e - 3); qo%flow_rate(e) = x(i + 4 * e - 2); qo%flow(e) = x(i + 4 * e - 1)
        qo%flow_defined(e) = x(i + 4 * e) > 0
        qo%curve(:, e) = nint(x(N_SCALARS + (e - 1) * nc + 1:N_SCALARS + e * nc))
      end do
      qo%curve_total = sum(qo%curve, dim=2)
    end associate
    if (.not. with_q) return
    i = N_SCALARS + MAX_EXITS * nc
    r%q = reshape(x(i + 1:i + n_dof * nc), [n_dof, nc])
    if (n_basis > 0) r%alpha = reshape(x(i + n_dof * nc + 1:i + n_dof * nc + n_basis * n_steps), [n_basis, n_steps])
  end subroutine unpack_record

  !> The product at `path`: the QoI product (cr_qoi_file, schema crowdrom-qoi: parameters mu
  !> [n_expanded, n_queries], outside-box flags, CPU seconds, model, configuration and the QoI
  !> group of the records rec [n_queries], in query order) with the prediction's own datasets
  !> added (per query: diverged_step, n_infeasible, n_capped; the ROM file, the pair, the list's
  !> origin, the training box, the wall time; positions and coefficients when the records hold
  !> them). Written complete under `<path>.qoi` and renamed to `path` at the end; on failure
  !> nothing is left.
  subroutine write_predict_product(path, p, mu, rec, error)
    character(len=*), intent(in) :: path
    type(predict_product_t), intent(in) :: p
    real(wp), intent(in) :: mu(:,:)
    type(query_record_t), intent(in) :: rec(:)
    type(error_t), allocatable, intent(out) :: error
    type(qoi_product_t) :: qp
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: tmp
    integer :: k, nq
    nq = size(rec)
    qp%program = "crowd_predict"; qp%model = p%model; qp%config = p%config; qp%param_names = p%param_names
    qp%radius = p%radius; qp%dt = p%dt; qp%params = mu
    allocate(qp%outside_box(nq), qp%cpu_seconds(nq), qp%qoi(nq))
    do k = 1, nq
      qp%outside_box(k) = rec(k)%out_of_box
      qp%cpu_seconds(k) = rec(k)%cpu
      qp%qoi(k) = rec(k)%qoi
    end do
    tmp = path // ".qoi"
    call write_qoi_product(tmp, qp, error)
    if (allocated(error)) return
    call h5%open(tmp, error, readwrite=.true.)
    if (.not. allocated(error)) call add_prediction(h5, p, rec, error)
    call h5%close(e2)
    if (allocated(e2) .and. .not. allocated(error)) call move_alloc(e2, error)
    if (.not. allocated(error)) then
      if (rename_file(tmp, path) /= 0) call set_error(error, "cannot rename '" // tmp // "' to '" // path // "'")
    end if
    if (allocated(error)) then
      call prefix_error(error, "prediction product '" // path // "'")
      k = remove_file(tmp)
    end if
  end subroutine write_predict_product

  !> The prediction's own attributes and datasets (write_predict_product), each with its digest.
  subroutine add_prediction(h5, p, rec, error)
    type(h5file_t), intent(inout) :: h5
    type(predict_product_t), intent(in) :: p
    type(query_record_t), intent(in) :: rec(:)
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: pos(:,:)
    integer :: k, nq, nc
    nq = size(rec)
    nc = p%n_steps + 1
    call h5%write_attr("/", "rom_file", p%rom_file, error); if (allocated(error)) return
    call h5%write_attr("/", "queries_from", p%source, error); if (allocated(error)) return
    call h5%write_attr("/", "param_min", p%param_min, error); if (allocated(error)) return
    call h5%write_attr("/", "param_max", p%param_max, error); if (allocated(error)) return
    call h5%write_attr("/", "n_agents", p%n_agents, error); if (allocated(error)) return
    call h5%write_attr("/", "n_steps", p%n_steps, error); if (allocated(error)) return
    call h5%write_attr("/", "n_ranks", p%n_ranks, error); if (allocated(error)) return
    call h5%write_attr("/", "wall_seconds", p%t_wall, error); if (allocated(error)) return
    call h5%write_attr("/", "pair", p%pair, error); if (allocated(error)) return
    call h5%write_attr("/", "pair_n", p%pair_n, error); if (allocated(error)) return
    call h5%write_attr("/", "pair_r", p%pair_r, error); if (allocated(error)) return
    call h5%write_attr("/", "n_basis", p%n_basis, error); if (allocated(error)) return
    call put_int("diverged_step", rec%diverged_step); if (allocated(error)) return
    call put_int("n_infeasible", rec%n_infeasible); if (allocated(error)) return
    call put_int("n_capped", rec%n_capped); if (allocated(error)) return
    if (nq == 0) return
    if (allocated(rec(1)%q)) then
      allocate(pos(size(rec(1)%q, 1), nc * nq))
      do k = 1, nq
        pos(:, (k - 1) * nc + 1:k * nc) = rec(k)%q
      end do
      call put_real("positions", pos); if (allocated(error)) return
      deallocate(pos)
    end if
    if (allocated(rec(1)%alpha)) then
      allocate(pos(size(rec(1)%alpha, 1), p%n_steps * nq))
      do k = 1, nq
        pos(:, (k - 1) * p%n_steps + 1:k * p%n_steps) = rec(k)%alpha
      end do
      call put_real("alpha", pos)
    end if

  contains

    subroutine put_real(name, x)
      character(len=*), intent(in) :: name
      real(wp), intent(in) :: x(:,:)
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine put_real

    subroutine put_int(name, x)
      character(len=*), intent(in) :: name
      integer, intent(in) :: x(:)
      call h5%write(name, x, error); if (allocated(error)) return
      call put_digest(h5, name, digest_of(x, 0_i8), error)
    end subroutine put_int
  end subroutine add_prediction
end module cr_predict_output
