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
  use cr_param_model, only: param_model_t
  use cr_snapshot_file, only: snap_header_t, snap_block_t, read_snap_header, read_snap_block
  use cr_distribution, only: block_range
  use cr_cone, only: sparse_columns_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: offline_data_t, load_training

  !> Local share of the training set.
  type :: offline_data_t
    integer :: n_agents = 0, n_dof = 0, n_steps = 0, n_train = 0, n_dict = 0
    real(wp) :: radius = 0, dt = 0
    character(len=:), allocatable :: config_hash, param_names
    !> the database's effective configuration (with &study) and initial positions [n_dof],
    !> stored in the ROM file so that prediction needs no database
    character(len=:), allocatable :: config_text
    real(wp), allocatable :: q0(:)
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
    type(snap_header_t) :: hdr
    type(snap_block_t) :: blk
    type(param_model_t) :: pm
    integer :: nt, k, nu
    call read_snap_header(path, "&offline: database", hdr, error, env=env)
    if (allocated(error)) return
    data%n_agents = hdr%n_agents; data%n_steps = hdr%n_steps; data%n_train = hdr%n_train
    data%radius = hdr%radius; data%dt = hdr%dt
    data%config_hash = hdr%hash; data%param_names = hdr%param_names
    data%config_text = hdr%config_text; data%q0 = hdr%q0
    ! the database holds the contact radius (body radius + social distance / 2)
    if (data%n_agents /= cfg%agents%n_agents .or. &
        abs(data%radius - (cfg%agents%radius + cfg%agents%social_distance / 2)) > 0 .or. &
        abs(data%dt - cfg%time%dt) > 0) then
      call set_error(error, "&offline: database '" // path // "' is from another scene (n_agents " // &
        str(data%n_agents) // ", radius " // str(data%radius) // ", dt " // str(data%dt) // &
        ") than the input (n_agents " // str(cfg%agents%n_agents) // ", radius " // &
        str(cfg%agents%radius + cfg%agents%social_distance / 2) // &
        ", dt " // str(cfg%time%dt) // ")", EXIT_BAD_INPUT); return
    end if
    data%n_dof = hdr%n_dof
    nt = data%n_steps
    call block_range(data%n_train, env%size, env%rank, data%s0, data%ns)
    call read_snap_block(hdr, 'train', data%s0 + 1, data%ns, .true., .true., blk, error, env=env)
    if (allocated(error)) then
      if (error%code == EXIT_BAD_INPUT) error%message = "&offline: database: " // error%message
      return
    end if
    ! velocities, desired velocities and the configurations before each step
    call move_alloc(blk%u, data%u)
    call move_alloc(blk%v, data%v)
    allocate(data%q(data%n_dof, data%ns * nt))
    do k = 1, data%ns
      do nu = 1, nt
        data%q(:, (k - 1) * nt + nu) = blk%q(:, (k - 1) * (nt + 1) + nu)
      end do
    end do
    ! dictionary and multipliers (CSR over the local snapshot columns)
    data%dict_ia = hdr%dict_ia; data%dict_ib = hdr%dict_ib; data%dict_ob = hdr%dict_ob
    data%n_dict = hdr%n_dict
    data%lam%n_rows = data%n_dict
    data%lam%n_cols = data%ns * nt
    data%lam%col_offset = int(data%s0, i8) * nt
    call move_alloc(blk%lam_ptr, data%lam%ptr)
    call move_alloc(blk%lam_idx, data%lam%idx)
    call move_alloc(blk%lam_val, data%lam%val)
    ! one scene per local sample (the parameters may change it)
    call pm%init_from_components(data%param_names, data%n_agents, error)
    if (allocated(error)) then
      call prefix_error(error, "&offline: database '" // path // "': attribute 'param_names'"); return
    end if
    allocate(data%scenes(max(data%ns, 1)), data%scene_of(data%ns * nt))
    do k = 1, data%ns
      call pm%scene_of(blk%mu(:, k), cfg, data%scenes(k), error)
      if (allocated(error)) then
        call prefix_error(error, "&offline: scene of training sample " // str(data%s0 + k)); return
      end if
      data%scene_of((k - 1) * nt + 1:k * nt) = k
    end do
    if (data%ns == 0) call data%scenes(1)%init(cfg%scene, cfg%obstacles, error)
    if (allocated(error)) return
    if (data%n_dict > 0) then
      if (maxval(data%dict_ob) > data%scenes(1)%n_obstacles()) call set_error(error, "&offline: database '" // &
        path // "': dataset 'contacts/ob': obstacle index " // str(maxval(data%dict_ob)) // " but the scene has " // &
        str(data%scenes(1)%n_obstacles()) // " obstacles", EXIT_BAD_INPUT)
    end if

  end subroutine load_training
end module cr_offline_data
