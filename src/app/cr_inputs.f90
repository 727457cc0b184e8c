!> The one place where an input file's groups are checked against every program's readers: a
!> file may hold the groups of every stage (full model, &study, crowd_offline's, crowd_rom's,
!> crowd_predict's), so each program reads them all with the readers that own them (cr_config,
!> cr_study_config, cr_offline_config, cr_rom_config, cr_predict_config). A group no program
!> reads, or a variable its group does not have (misspelt or misplaced), is refused with the one-line error naming the file, the
!> group and the variable, whichever program is run. Ranges are checked only by the program
!> that uses the group.
module cr_inputs
  use cr_error, only: error_t
  use cr_env, only: env_t
  use cr_namelist_text, only: namelist_text_t
  use cr_config, only: config_t, parse_config, read_config
  use cr_config_check, only: check_config
  use cr_study_config, only: study_cfg_t, read_study
  use cr_offline_config, only: offline_cfg_t, read_offline
  use cr_rom_config, only: rom_cfg_t, read_rom_groups
  use cr_predict_config, only: predict_cfg_t, read_predict
  implicit none
  private
  public :: check_input_groups, read_model_input

contains

  !> Read every group of `t` with its owner (&study and &predict only when present: the programs
  !> that need them report their absence themselves; crowd_rom's groups &rom, &sweep, &reduced,
  !> &fom_timing each when present, whether or not &rom is).
  subroutine check_input_groups(t, error)
    type(namelist_text_t), intent(in) :: t
    type(error_t), allocatable, intent(out) :: error
    type(config_t) :: cfg
    type(study_cfg_t) :: study
    type(offline_cfg_t) :: ocfg
    type(rom_cfg_t) :: rcfg
    type(predict_cfg_t) :: pcfg
    call parse_config(t, cfg, error); if (allocated(error)) return
    if (t%has_group('study')) call read_study(t, study, error)
    if (allocated(error)) return
    call read_offline(t, ocfg, error); if (allocated(error)) return
    call read_rom_groups(t, rcfg, error)
    if (allocated(error)) return
    if (t%has_group('predict')) call read_predict(t, pcfg, error)
  end subroutine check_input_groups

  !> A program's input: rank 0 reads `path` (broadcast to every rank of env), the groups
  !> `needed` must be present, every group is checked by its owner (check_input_groups) and the
  !> full model's configuration `cfg` by check_config. `nml` keeps the text for the program's
  !> own groups.
  subroutine read_model_input(path, env, program, needed, cfg, nml, error)
    character(len=*), intent(in) :: path, program
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: needed(:)
    type(config_t), intent(out) :: cfg
    type(namelist_text_t), intent(out) :: nml
    type(error_t), allocatable, intent(out) :: error
    call read_config(path, env, cfg, error, nml, program=program, needed=needed)
    if (allocated(error)) return
    call check_input_groups(nml, error)
    if (allocated(error)) return
    call check_config(cfg, error)
  end subroutine read_model_input
end module cr_inputs
