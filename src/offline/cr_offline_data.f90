!> The training data of crowd_offline, read from a snapshot database (schema
!> crowdrom-snapshots): each rank reads a contiguous block of training samples (cr_distribution)
!> and holds their velocity snapshots, the configurations q^{nu-1} at which each velocity was
!> computed, the multipliers (sparse, in the dictionary index space) and one scene per sample
!> (the exit width may be a parameter).
module cr_offline_data
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_config, only: config_t
  use cr_scene, only: scene_t
  use cr_h5file, only: h5file_t
  use cr_digest, only: digest_of, check_digest, check_digest_parts
  use cr_distribution, only: block_range
  use cr_cone, only: sparse_columns_t
  implicit none
  private
  public :: offline_data_t, load_training

  !> Local share of the training set.
  type :: offline_data_t
    integer :: n_agents = 0, n_dof = 0, n_steps = 0, n_train = 0, n_dict = 0
    real(wp) :: radius = 0, dt = 0
    character(len=:), allocatable :: config_hash, param_names
    !> first local sample minus 1, number of local samples
    integer :: s0 = 0, ns = 0
    !> velocity snapshots u^nu, configurations q^{nu-1} and desired velocities v(q^{nu-1})
    !> [n_dof, ns * n_steps]
    real(wp), allocatable :: u(:,:), q(:,:), v(:,:)
    !> multipliers of the local snapshot columns
    type(sparse_columns_t) :: lam
    !> contact dictionary [n_dict]
    integer, allocatable :: dict_ia(:), dict_ib(:), dict_ob(:)
    !> one scene per local sample, and the scene of every local column [ns * n_steps]
    type(scene_t), allocatable :: scenes(:)
    integer, allocatable :: scene_of(:)
  end type offline_data_t

contains

  !> Read the local block of training samples of `path` (collective over env).
  subroutine load_training(env, path, cfg, data, error)
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: path
    type(config_t), intent(in) :: cfg
    type(offline_data_t), intent(out) :: data
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: schema, w
    integer(i8), allocatable :: off(:)
    integer, allocatable :: idx(:)
    real(wp), allocatable :: val(:), pos(:,:), params(:,:)
    integer :: complete, nt, k, nu, c, il, j
    integer(i8) :: p, base
    call h5%open(path, error, env=env)
    if (allocated(error)) then
      error%message = "&offline: database: " // error%message; error%code = 2; return
    end if
    call h5%read_attr("/", "schema", schema, error)
    if (allocated(error)) goto 9
    if (schema /= "crowdrom-snapshots") then
      call set_error(error, "&offline: database '" // path // "' is not a snapshot database (schema '" // &
        schema // "')", 2); goto 9
    end if
    call h5%read_attr("/", "complete", complete, error); if (allocated(error)) goto 9
    if (complete /= 1) then
      call set_error(error, "&offline: database '" // path // "' is not complete", 2); goto 9
    end if
    call h5%read_attr("/", "n_agents", data%n_agents, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_steps", data%n_steps, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_train", data%n_train, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "agent_radius", data%radius, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "dt", data%dt, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "config_hash", data%config_hash, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "param_names", data%param_names, error); if (allocated(error)) goto 9
    if (data%n_agents /= cfg%agents%n_agents .or. abs(data%radius - cfg%agents%radius) > 0 .or. &
        abs(data%dt - cfg%time%dt) > 0) then
      call set_error(error, "&offline: database '" // path // "' is from another scene (n_agents " // &
        str(data%n_agents) // ", radius " // str(data%radius) // ", dt " // str(data%dt) // &
        ") than the input (n_agents " // str(cfg%agents%n_agents) // ", radius " // str(cfg%agents%radius) // &
        ", dt " // str(cfg%time%dt) // ")", 2); goto 9
    end if
    data%n_dof = 2 * data%n_agents
    nt = data%n_steps
    call block_range(data%n_train, env%size, env%rank, data%s0, data%ns)
    ! velocities and the configurations before each step
    allocate(data%u(data%n_dof, data%ns * nt), pos(data%n_dof, data%ns * (nt + 1)))
    call h5%read_block("train/velocities", data%u, data%s0 * nt, error); if (allocated(error)) goto 9
    call h5%read_block("train/positions", pos, data%s0 * (nt + 1), error); if (allocated(error)) goto 9
    allocate(data%v(data%n_dof, data%ns * nt))
    call h5%read_block("train/desired", data%v, data%s0 * nt, error); if (allocated(error)) goto 9
    ! checksums of what was read (each rank its blocks; together the whole datasets)
    w = "&offline: database '" // path // "'"
    call check_digest_parts(h5, env, "train/velocities", digest_of(data%u, int(data%s0, i8) * nt * data%n_dof), &
      w, error); if (allocated(error)) goto 9
    call check_digest_parts(h5, env, "train/positions", digest_of(pos, int(data%s0, i8) * (nt + 1) * data%n_dof), &
      w, error); if (allocated(error)) goto 9
    call check_digest_parts(h5, env, "train/desired", digest_of(data%v, int(data%s0, i8) * nt * data%n_dof), &
      w, error); if (allocated(error)) goto 9
    allocate(data%q(data%n_dof, data%ns * nt))
    do k = 1, data%ns
      do nu = 1, nt
        data%q(:, (k - 1) * nt + nu) = pos(:, (k - 1) * (nt + 1) + nu)
      end do
    end do
    ! dictionary and multipliers (CSR over the snapshot columns)
    call h5%read("contacts/ia", data%dict_ia, error); if (allocated(error)) goto 9
    call h5%read("contacts/ib", data%dict_ib, error); if (allocated(error)) goto 9
    call h5%read("contacts/ob", data%dict_ob, error); if (allocated(error)) goto 9
    data%n_dict = size(data%dict_ia)
    call h5%read("train/lambda_offset", off, error); if (allocated(error)) goto 9
    call h5%read("train/lambda_index", idx, error); if (allocated(error)) goto 9
    call h5%read("train/lambda_value", val, error); if (allocated(error)) goto 9
    call check_digest(h5, "contacts/ia", digest_of(data%dict_ia, 0_i8), w, error); if (allocated(error)) goto 9
    call check_digest(h5, "contacts/ib", digest_of(data%dict_ib, 0_i8), w, error); if (allocated(error)) goto 9
    call check_digest(h5, "contacts/ob", digest_of(data%dict_ob, 0_i8), w, error); if (allocated(error)) goto 9
    call check_digest(h5, "train/lambda_offset", digest_of(off, 0_i8), w, error); if (allocated(error)) goto 9
    call check_digest(h5, "train/lambda_index", digest_of(idx, 0_i8), w, error); if (allocated(error)) goto 9
    call check_digest(h5, "train/lambda_value", digest_of(val, 0_i8), w, error); if (allocated(error)) goto 9
    data%lam%n_rows = data%n_dict
    data%lam%n_cols = data%ns * nt
    data%lam%col_offset = int(data%s0, i8) * nt
    base = off(data%s0 * nt + 1)
    allocate(data%lam%ptr(data%lam%n_cols + 1))
    do c = 1, data%lam%n_cols + 1
      data%lam%ptr(c) = off(data%s0 * nt + c) - base
    end do
    allocate(data%lam%idx(int(data%lam%ptr(data%lam%n_cols + 1))), data%lam%val(int(data%lam%ptr(data%lam%n_cols + 1))))
    do p = 1, data%lam%ptr(data%lam%n_cols + 1)
      data%lam%idx(p) = idx(base + p)
      data%lam%val(p) = val(base + p)
    end do
    ! one scene per local sample (l_exit may be a parameter)
    call h5%read("train/params", params, error); if (allocated(error)) goto 9
    call check_digest(h5, "train/params", digest_of(params, 0_i8), w, error); if (allocated(error)) goto 9
    il = index("," // data%param_names // ",", ",l_exit,")
    allocate(data%scenes(max(data%ns, 1)), data%scene_of(data%ns * nt))
    do k = 1, data%ns
      block
        type(config_t) :: c2
        c2 = cfg
        if (il > 0) then
          j = count_commas(data%param_names(1:il - 1)) + 1
          c2%scene%l_exit = params(j, data%s0 + k)
        end if
        call data%scenes(k)%init(c2%scene, c2%obstacles, error)
        if (allocated(error)) then
          call prefix_error(error, "&offline: scene of training sample " // str(data%s0 + k)); goto 9
        end if
      end block
      data%scene_of((k - 1) * nt + 1:k * nt) = k
    end do
    if (data%ns == 0) call data%scenes(1)%init(cfg%scene, cfg%obstacles, error)
9   call h5%close(e2)
    if (allocated(error)) return
    if (allocated(e2)) call move_alloc(e2, error)

  contains

    pure integer function count_commas(s)
      character(len=*), intent(in) :: s
      integer :: i
      count_commas = 0
      do i = 1, len(s)
        if (s(i:i) == ',') count_commas = count_commas + 1
      end do
    end function count_commas
  end subroutine load_training
end module cr_offline_data
