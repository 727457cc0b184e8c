!> What crowd_rom needs from the snapshot database a ROM file was built from: the effective
!> configuration (scene, agents, time, solver and &study, parsed from the database's `config`
!> attribute, so the reduced model runs exactly the study's scene), the parameter space
!> (training box), the initial positions, and the full-order trajectories of the sets run.
module cr_rom_study
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_h5file, only: h5file_t
  use cr_config, only: config_t, parse_config
  use cr_namelist_text, only: namelist_text_t
  use cr_study_config, only: study_cfg_t, read_study
  use cr_sampling, only: param_space_t
  use cr_rom_file, only: rom_file_t
  implicit none
  private
  public :: rom_study_t, sample_block_t, open_study, read_block_set

  !> Samples of one set and, for database sets, their full-order trajectories.
  type :: sample_block_t
    character(len=8) :: name = ''
    integer :: n = 0
    !> parameters [n_mu, n]
    real(wp), allocatable :: mu(:,:)
    !> full-order positions [n_dof, (N_T + 1) n] and velocities [n_dof, N_T n] (database sets)
    real(wp), allocatable :: q(:,:), u(:,:)
    logical :: has_fom = .false.
  end type sample_block_t

  !> The study behind a ROM file.
  type :: rom_study_t
    character(len=:), allocatable :: database, hash, param_names
    type(config_t) :: cfg
    type(study_cfg_t) :: study
    type(param_space_t) :: space
    integer :: n_agents = 0, n_dof = 0, n_steps = 0, n_train = 0, n_valid = 0
    real(wp) :: radius = 0, dt = 0
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
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    type(namelist_text_t) :: t
    character(len=:), allocatable :: schema, text
    integer :: complete
    call h5%open(path, error)
    if (allocated(error)) then
      error%message = where // " '" // path // "': cannot open the snapshot database (" // error%message // ")"
      error%code = 2; return
    end if
    st%database = path
    call h5%read_attr("/", "schema", schema, error)
    if (.not. allocated(error)) then
      if (schema /= "crowdrom-snapshots") call set_error(error, where // " '" // path // &
        "' is not a snapshot database (schema '" // schema // "')", 2)
    else
      call set_error(error, where // " '" // path // "' is not a snapshot database (no schema attribute)", 2)
    end if
    if (allocated(error)) goto 9
    call h5%read_attr("/", "complete", complete, error); if (allocated(error)) goto 9
    if (complete /= 1) then
      call set_error(error, where // " '" // path // "' is not complete", 2); goto 9
    end if
    call h5%read_attr("/", "config_hash", st%hash, error); if (allocated(error)) goto 9
    if (st%hash /= hdr%db_hash) then
      call set_error(error, where // ": ROM file '" // hdr%path // "' was built from another study (database " // &
        "config_hash " // hdr%db_hash // ", but '" // path // "' has " // st%hash // ")", 2); goto 9
    end if
    call h5%read_attr("/", "n_agents", st%n_agents, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_steps", st%n_steps, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_train", st%n_train, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_valid", st%n_valid, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "agent_radius", st%radius, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "dt", st%dt, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "param_names", st%param_names, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "config", text, error); if (allocated(error)) goto 9
    call h5%read("initial_positions", st%q0, error); if (allocated(error)) goto 9
    st%n_dof = 2 * st%n_agents
    if (st%n_agents /= hdr%n_agents .or. st%n_steps /= hdr%n_steps) then
      call set_error(error, where // ": ROM file '" // hdr%path // "' and database '" // path // &
        "' disagree on n_agents / n_steps", 2); goto 9
    end if
    call t%set_text(path // " (attribute config)", text)
    call parse_config(t, st%cfg, error)
    if (allocated(error)) goto 9
    call read_study(t, st%study, error)
    if (allocated(error)) goto 9
    call st%space%init(st%study, st%n_agents)
    allocate(st%speeds(st%n_agents))
    st%speeds = st%cfg%agents%speed
9   call h5%close(e2)
    if (allocated(error)) return
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine open_study

  !> Read the first n (0: all) samples of database set `name` ('train' or 'valid').
  subroutine read_block_set(st, name, n, blk, error)
    type(rom_study_t), intent(in) :: st
    character(len=*), intent(in) :: name
    integer, intent(in) :: n
    type(sample_block_t), intent(out) :: blk
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    real(wp), allocatable :: mu(:,:)
    integer :: ns, nt
    call h5%open(st%database, error)
    if (allocated(error)) return
    call h5%read(name // "/params", mu, error); if (allocated(error)) goto 9
    ns = size(mu, 2)
    if (n > 0) ns = min(n, ns)
    nt = st%n_steps
    blk%name = name
    blk%n = ns
    blk%mu = mu(:, 1:ns)
    allocate(blk%q(st%n_dof, (nt + 1) * ns), blk%u(st%n_dof, nt * ns))
    if (ns > 0) then
      call h5%read_block(name // "/positions", blk%q, 0, error); if (allocated(error)) goto 9
      call h5%read_block(name // "/velocities", blk%u, 0, error); if (allocated(error)) goto 9
    end if
    blk%has_fom = .true.
9   call h5%close(e2)
    if (allocated(error)) then
      call prefix_error(error, "database '" // st%database // "', set " // name); return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_block_set

end module cr_rom_study
