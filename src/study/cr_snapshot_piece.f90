!> One sample of a study: its full-order trajectory (computed by compute_sample) and the
!> "piece" file that makes it durable before the database is assembled.
!>
!> A piece is a small serial HDF5 file `<database>.pieces/<set>_<k>.h5` written under a
!> temporary name and renamed when closed (cr_h5file), so a piece exists under its final name
!> only when all its data is on disk: a killed run leaves only complete pieces (and maybe a
!> `.partial`, ignored and overwritten). Piece layout (schema "crowdrom-snapshot-piece" v1):
!> attributes config_hash, set, index, rank, time; datasets mu [n_expanded], positions
!> [2*n_agents, n_steps+1], velocities / desired [2*n_agents, n_steps], kkt / min_gap /
!> iterations / converged / n_active [n_steps], lambda_offset int64 [n_steps+1], lambda_key
!> int64 / lambda_ia / lambda_ib / lambda_ob / lambda_value [nnz] (only lambda > 0).
module cr_snapshot_piece
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_config, only: config_t
  use cr_fom, only: fom_t, step_record_t
  use cr_sampling, only: param_space_t
  use cr_h5file, only: h5file_t
  implicit none
  private
  public :: sample_result_t, compute_sample, write_piece, read_piece, piece_hash, piece_path, &
    PIECE_SCHEMA

  character(len=*), parameter :: PIECE_SCHEMA = "crowdrom-snapshot-piece"

  !> Trajectory and statistics of one sample.
  type :: sample_result_t
    !> 'train' or 'valid', and the sample's index in its set
    character(len=8) :: set = ''
    integer :: index = 0
    !> parameter values [n_expanded]
    real(wp), allocatable :: mu(:)
    !> positions q^0..q^{n_steps} [2*n_agents, n_steps+1]
    real(wp), allocatable :: q(:,:)
    !> velocities u^nu and desired velocities v(q^{nu-1}), nu = 1..n_steps [2*n_agents, n_steps]
    real(wp), allocatable :: u(:,:), v(:,:)
    !> per-step KKT residual and smallest gap [n_steps]
    real(wp), allocatable :: kkt(:), min_gap(:)
    !> per-step solver iterations, converged flag (1/0), active contacts [n_steps]
    integer, allocatable :: iterations(:), converged(:), n_active(:)
    !> sparse multipliers, CSR over the steps: step nu holds entries offset(nu)+1..offset(nu+1)
    integer(i8), allocatable :: offset(:)
    integer(i8), allocatable :: key(:)
    integer, allocatable :: ia(:), ib(:), ob(:)
    real(wp), allocatable :: value(:)
    !> wall time of the sample (s) and the rank that computed it
    real(wp) :: time = 0
    integer :: rank = -1
  end type sample_result_t

contains

  !> `<dir>/<set>_<k>.h5` with k zero-padded to 6 digits.
  function piece_path(dir, set, k) result(p)
    character(len=*), intent(in) :: dir, set
    integer, intent(in) :: k
    character(len=:), allocatable :: p
    character(len=16) :: b
    write(b, '(i6.6)') k
    p = dir // "/" // trim(set) // "_" // trim(b) // ".h5"
  end function piece_path

  !> Run the full-order model for parameters mu from the common initial positions q0.
  subroutine compute_sample(cfg_ref, space, mu, q0, ref_speeds, res, error)
    type(config_t), intent(in) :: cfg_ref
    type(param_space_t), intent(in) :: space
    !> parameters [n_expanded]
    real(wp), intent(in) :: mu(:)
    !> initial positions [2*n_agents]
    real(wp), intent(in) :: q0(:)
    !> reference speeds [n_agents] (for parameters that do not set them)
    real(wp), intent(in) :: ref_speeds(:)
    type(sample_result_t), intent(inout) :: res
    type(error_t), allocatable, intent(out) :: error
    type(config_t) :: cfg
    type(fom_t) :: fom
    type(step_record_t) :: rec
    real(wp), allocatable :: speeds(:)
    integer :: ns, nd, nu, l, nnz
    cfg = cfg_ref
    speeds = ref_speeds
    call space%apply(mu, cfg, speeds)
    call fom%init(cfg, error, q0=q0, speeds=speeds)
    if (allocated(error)) return
    ns = cfg%time%n_steps
    nd = 2 * fom%n_agents
    res%mu = mu
    if (allocated(res%q)) deallocate(res%q, res%u, res%v, res%kkt, res%min_gap, res%iterations, &
      res%converged, res%n_active, res%offset, res%key, res%ia, res%ib, res%ob, res%value)
    allocate(res%q(nd, ns + 1), res%u(nd, ns), res%v(nd, ns), res%kkt(ns), res%min_gap(ns), &
      res%iterations(ns), res%converged(ns), res%n_active(ns), res%offset(ns + 1))
    allocate(res%key(16 * fom%n_agents), res%ia(16 * fom%n_agents), res%ib(16 * fom%n_agents), &
      res%ob(16 * fom%n_agents), res%value(16 * fom%n_agents))
    res%q(:, 1) = fom%q
    res%offset(1) = 0
    nnz = 0
    do nu = 1, ns
      call fom%advance(rec, error)
      if (allocated(error)) return
      res%q(:, nu + 1) = fom%q
      res%u(:, nu) = fom%u
      res%v(:, nu) = fom%v
      res%kkt(nu) = rec%kkt
      res%min_gap(nu) = rec%min_gap
      res%iterations(nu) = rec%iterations
      res%converged(nu) = merge(1, 0, rec%converged)
      res%n_active(nu) = rec%n_active
      do l = 1, fom%cs%n
        if (fom%lambda(l) > 0) then
          if (nnz == size(res%key)) call grow()
          nnz = nnz + 1
          res%key(nnz) = fom%cs%key(l)
          res%ia(nnz) = fom%cs%ia(l); res%ib(nnz) = fom%cs%ib(l); res%ob(nnz) = fom%cs%ob(l)
          res%value(nnz) = fom%lambda(l)
        end if
      end do
      res%offset(nu + 1) = nnz
    end do
    res%key = res%key(1:nnz); res%ia = res%ia(1:nnz); res%ib = res%ib(1:nnz)
    res%ob = res%ob(1:nnz); res%value = res%value(1:nnz)

  contains

    subroutine grow()
      integer :: n
      integer(i8), allocatable :: k2(:)
      integer, allocatable :: i2(:)
      real(wp), allocatable :: r2(:)
      n = 2 * size(res%key)
      allocate(k2(n)); k2(1:nnz) = res%key(1:nnz); call move_alloc(k2, res%key)
      allocate(i2(n)); i2(1:nnz) = res%ia(1:nnz); call move_alloc(i2, res%ia)
      allocate(i2(n)); i2(1:nnz) = res%ib(1:nnz); call move_alloc(i2, res%ib)
      allocate(i2(n)); i2(1:nnz) = res%ob(1:nnz); call move_alloc(i2, res%ob)
      allocate(r2(n)); r2(1:nnz) = res%value(1:nnz); call move_alloc(r2, res%value)
    end subroutine grow
  end subroutine compute_sample

  !> Write a piece (serial HDF5, temporary name renamed when complete).
  subroutine write_piece(path, hash, res, error)
    character(len=*), intent(in) :: path, hash
    type(sample_result_t), intent(in) :: res
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    call h5%create(path, error)
    if (allocated(error)) return
    ops: block
      call h5%write_attr("/", "schema", PIECE_SCHEMA, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "config_hash", hash, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "set", trim(res%set), error); if (allocated(error)) exit ops
      call h5%write_attr("/", "index", res%index, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "rank", res%rank, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "time", res%time, error); if (allocated(error)) exit ops
      call h5%write("mu", res%mu, error); if (allocated(error)) exit ops
      call h5%write("positions", res%q, error); if (allocated(error)) exit ops
      call h5%write("velocities", res%u, error); if (allocated(error)) exit ops
      call h5%write("desired", res%v, error); if (allocated(error)) exit ops
      call h5%write("kkt", res%kkt, error); if (allocated(error)) exit ops
      call h5%write("min_gap", res%min_gap, error); if (allocated(error)) exit ops
      call h5%write("iterations", res%iterations, error); if (allocated(error)) exit ops
      call h5%write("converged", res%converged, error); if (allocated(error)) exit ops
      call h5%write("n_active", res%n_active, error); if (allocated(error)) exit ops
      call h5%write("lambda_offset", res%offset, error); if (allocated(error)) exit ops
      call h5%write("lambda_key", res%key, error); if (allocated(error)) exit ops
      call h5%write("lambda_ia", res%ia, error); if (allocated(error)) exit ops
      call h5%write("lambda_ib", res%ib, error); if (allocated(error)) exit ops
      call h5%write("lambda_ob", res%ob, error); if (allocated(error)) exit ops
      call h5%write("lambda_value", res%value, error); if (allocated(error)) exit ops
      call h5%write_attr("/", "complete", 1, error); if (allocated(error)) exit ops
      call h5%commit(error)
    end block ops
    if (allocated(error)) then
      call h5%abort()
      call prefix_error(error, "piece '" // path // "'")
    end if
  end subroutine write_piece

  !> The config_hash attribute of a piece ('' with an error if it is not a piece).
  subroutine piece_hash(path, hash, error)
    character(len=*), intent(in) :: path
    character(len=:), allocatable, intent(out) :: hash
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    character(len=:), allocatable :: schema
    type(error_t), allocatable :: e2
    hash = ""
    call h5%open(path, error)
    if (allocated(error)) return
    call h5%read_attr("/", "schema", schema, error)
    if (.not. allocated(error)) then
      if (schema /= PIECE_SCHEMA) call set_error(error, "piece '" // path // "': schema '" // schema // &
        "' is not " // PIECE_SCHEMA)
    end if
    if (.not. allocated(error)) call h5%read_attr("/", "config_hash", hash, error)
    call h5%close(e2)
  end subroutine piece_hash

  !> Read a piece written by write_piece.
  subroutine read_piece(path, res, error)
    character(len=*), intent(in) :: path
    type(sample_result_t), intent(inout) :: res
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: set
    call h5%open(path, error)
    if (allocated(error)) return
    ops: block
      call h5%read_attr("/", "set", set, error); if (allocated(error)) exit ops
      res%set = set
      call h5%read_attr("/", "index", res%index, error); if (allocated(error)) exit ops
      call h5%read_attr("/", "rank", res%rank, error); if (allocated(error)) exit ops
      call h5%read_attr("/", "time", res%time, error); if (allocated(error)) exit ops
      call h5%read("mu", res%mu, error); if (allocated(error)) exit ops
      call h5%read("positions", res%q, error); if (allocated(error)) exit ops
      call h5%read("velocities", res%u, error); if (allocated(error)) exit ops
      call h5%read("desired", res%v, error); if (allocated(error)) exit ops
      call h5%read("kkt", res%kkt, error); if (allocated(error)) exit ops
      call h5%read("min_gap", res%min_gap, error); if (allocated(error)) exit ops
      call h5%read("iterations", res%iterations, error); if (allocated(error)) exit ops
      call h5%read("converged", res%converged, error); if (allocated(error)) exit ops
      call h5%read("n_active", res%n_active, error); if (allocated(error)) exit ops
      call h5%read("lambda_offset", res%offset, error); if (allocated(error)) exit ops
      call h5%read("lambda_key", res%key, error); if (allocated(error)) exit ops
      call h5%read("lambda_ia", res%ia, error); if (allocated(error)) exit ops
      call h5%read("lambda_ib", res%ib, error); if (allocated(error)) exit ops
      call h5%read("lambda_ob", res%ob, error); if (allocated(error)) exit ops
      call h5%read("lambda_value", res%value, error); if (allocated(error)) exit ops
    end block ops
    call h5%close(e2)
    if (allocated(error)) call prefix_error(error, "piece '" // path // "'")
    if (.not. allocated(error) .and. size(res%offset) > 0) then
      if (res%offset(size(res%offset)) /= size(res%value)) call set_error(error, "piece '" // path // &
        "': lambda_offset ends at " // str(res%offset(size(res%offset))) // " but there are " // &
        str(size(res%value)) // " values")
    end if
  end subroutine read_piece
end module cr_snapshot_piece
