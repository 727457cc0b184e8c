!> What crowd_rom needs from the snapshot database a ROM file was built from: the effective
!> configuration (scene, agents, time, solver and &study, parsed from the database's `config`
!> attribute, so the reduced model runs exactly the study's scene), the parameter space
!> (training box), the initial positions, and the full-order trajectories of the sets run.
!> open_rom_study builds the same study from a version-3 ROM file alone (no database: what
!> prediction for new parameters needs).
module cr_rom_study
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_snapshot_file, only: snap_header_t, snap_block_t, read_snap_header, read_snap_block
  use cr_config, only: config_t, parse_config
  use cr_namelist_text, only: namelist_text_t
  use cr_study_config, only: study_cfg_t, read_study
  use cr_sampling, only: param_space_t
  use cr_rom_file, only: rom_file_t
  use cr_h5file, only: h5file_t
  use cr_qoi, only: qoi_t
  use cr_qoi_file, only: read_qoi_group
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: rom_study_t, sample_block_t, open_study, open_rom_study, read_block_set

  !> Samples of one set and, for database sets, their full-order trajectories.
  type :: sample_block_t
    character(len=8) :: name = ''
    integer :: n = 0
    !> parameters [n_mu, n]
    real(wp), allocatable :: mu(:,:)
    !> full-order positions [n_dof, (N_T + 1) n] and velocities [n_dof, N_T n] (database sets)
    real(wp), allocatable :: q(:,:), u(:,:)
    logical :: has_fom = .false.
    !> the full-order trajectories' QoIs as crowd_snapshots stored them [n] (not allocated:
    !> a database written before they were stored)
    type(qoi_t), allocatable :: qoi(:)
  end type sample_block_t

  !> The study behind a ROM file.
  type :: rom_study_t
    character(len=:), allocatable :: database, hash, param_names
    !> the database's header (read and validated)
    type(snap_header_t) :: db
    type(config_t) :: cfg
    type(study_cfg_t) :: study
    type(param_space_t) :: space
    integer :: n_agents = 0, n_dof = 0, n_steps = 0, n_train = 0, n_valid = 0
    !> contact radius r + d_s / 2 (the database's agent_radius: the gaps of every stage) and
    !> body radius r (&agents radius: the QoIs' "has left" lines and overlaps, as crowd_fom
    !> and crowd_snapshots measure them)
    real(wp) :: radius = 0, body_radius = 0, dt = 0
    !> initial positions of every sample [n_dof]
    real(wp), allocatable :: q0(:)
    !> reference speeds (before parameters are applied) [n_agents]
    real(wp), allocatable :: speeds(:)
  end type rom_study_t

contains

  !> Open the database at `path` (checked against the ROM header) and read its configuration.
  subroutine open_study(path, where, hdr, st, error)
    character(len=*), intent(in) :: path, where
    type(rom_file_t), intent(in) :: hdr
    type(rom_study_t), intent(out) :: st
    type(error_t), allocatable, intent(out) :: error
    call read_snap_header(path, where, st%db, error)
    if (allocated(error)) return
    st%database = path
    st%hash = st%db%hash
    if (st%hash /= hdr%db_hash) then
      call set_error(error, where // ": ROM file '" // hdr%path // "' was built from another study (database " // &
        "config_hash " // hdr%db_hash // ", but '" // path // "' has " // st%hash // ")", EXIT_BAD_INPUT); return
    end if
    st%n_agents = st%db%n_agents; st%n_steps = st%db%n_steps
    st%n_train = st%db%n_train; st%n_valid = st%db%n_valid
    st%radius = st%db%radius; st%dt = st%db%dt
    st%param_names = st%db%param_names
    st%q0 = st%db%q0
    st%n_dof = st%db%n_dof
    if (st%n_agents /= hdr%n_agents .or. st%n_steps /= hdr%n_steps) then
      call set_error(error, where // ": ROM file '" // hdr%path // "' and database '" // path // &
        "' disagree on n_agents / n_steps", EXIT_BAD_INPUT); return
    end if
    call parse_study(path // " (attribute config)", st%db%config_text, st, error)
    if (allocated(error)) return
    if (st%space%n_expanded /= st%db%n_params) then
      call set_error(error, where // " '" // path // "': attribute 'n_params' = " // str(st%db%n_params) // &
        ", but its configuration has " // str(st%space%n_expanded) // " parameter components", EXIT_BAD_INPUT); return
    end if
  end subroutine open_study

  !> The study stored in a ROM file (version 3; read by read_rom_file): configuration,
  !> parameter space and initial positions, without the database (st%database is '').
  subroutine open_rom_study(hdr, where, st, error)
    type(rom_file_t), intent(in) :: hdr
    character(len=*), intent(in) :: where
    type(rom_study_t), intent(out) :: st
    type(error_t), allocatable, intent(out) :: error
    if (hdr%version < 3 .or. .not. allocated(hdr%study_config)) then
      call set_error(error, where // " '" // hdr%path // "': ROM file version " // str(hdr%version) // " holds no " // &
        "study (configuration, initial positions), which prediction needs: rebuild it with this crowd_offline " // &
        "(version 3)", EXIT_BAD_INPUT); return
    end if
    st%database = ''
    st%hash = hdr%db_hash
    st%n_agents = hdr%n_agents; st%n_steps = hdr%n_steps; st%n_dof = hdr%n_dof
    st%radius = hdr%radius; st%dt = hdr%dt
    st%param_names = hdr%param_names
    st%q0 = hdr%q0
    call parse_study(hdr%path // " (attribute study/config)", hdr%study_config, st, error)
    if (allocated(error)) return
    if (st%space%component_names() /= st%param_names) then
      call set_error(error, where // " '" // hdr%path // "': attribute study/param_names '" // st%param_names // &
        "' does not match its configuration ('" // st%space%component_names() // "')", EXIT_BAD_INPUT); return
    end if
    if (st%cfg%agents%n_agents /= st%n_agents) then
      call set_error(error, where // " '" // hdr%path // "': its study configuration has " // &
        str(st%cfg%agents%n_agents) // " agents, the file " // str(st%n_agents), EXIT_BAD_INPUT); return
    end if
  end subroutine open_rom_study

  !> Configuration, &study, parameter space and reference speeds of st from the study's
  !> configuration text (`what` names it in messages); st%n_agents must be set.
  subroutine parse_study(what, text, st, error)
    character(len=*), intent(in) :: what, text
    type(rom_study_t), intent(inout) :: st
    type(error_t), allocatable, intent(out) :: error
    type(namelist_text_t) :: t
    call t%set_text(what, text)
    call parse_config(t, st%cfg, error)
    if (allocated(error)) return
    call read_study(t, st%study, error)
    if (allocated(error)) return
    call st%space%init(st%study, st%n_agents)
    allocate(st%speeds(st%n_agents))
    st%speeds = st%cfg%agents%speed
    st%body_radius = st%cfg%agents%radius
  end subroutine parse_study

  !> Read the first n (0: all) samples of database set `name` ('train' or 'valid').
  subroutine read_block_set(st, name, n, blk, error)
    type(rom_study_t), intent(in) :: st
    character(len=*), intent(in) :: name
    integer, intent(in) :: n
    type(sample_block_t), intent(out) :: blk
    type(error_t), allocatable, intent(out) :: error
    type(snap_block_t) :: b
    integer :: ns
    ns = merge(st%n_train, st%n_valid, name == 'train')
    if (n > 0) ns = min(n, ns)
    call read_snap_block(st%db, name, 1, ns, .false., .false., b, error)
    if (allocated(error)) return
    blk%name = name
    blk%n = ns
    call move_alloc(b%mu, blk%mu)
    call move_alloc(b%q, blk%q)
    call move_alloc(b%u, blk%u)
    blk%has_fom = .true.
    call read_block_qoi(st, name, ns, blk, error)
  end subroutine read_block_set

  !> The stored QoIs of the first ns samples of set `name`, when the database has them.
  subroutine read_block_qoi(st, name, ns, blk, error)
    type(rom_study_t), intent(in) :: st
    character(len=*), intent(in) :: name
    integer, intent(in) :: ns
    type(sample_block_t), intent(inout) :: blk
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    type(qoi_t), allocatable :: all(:)
    call h5%open(st%database, error)
    if (allocated(error)) return
    if (h5%exists(name // "/qoi")) then
      call read_qoi_group(h5, st%database, name // "/qoi", all, error)
      if (.not. allocated(error)) then
        if (size(all) < ns) then
          call set_error(error, "'" // st%database // "': group '" // name // "/qoi' has " // str(size(all)) // &
            " rows for " // str(ns) // " samples")
        else
          blk%qoi = all(1:ns)
        end if
      end if
    end if
    call h5%close(e2)
    if (.not. allocated(error) .and. allocated(e2)) call move_alloc(e2, error)
  end subroutine read_block_qoi

end module cr_rom_study
