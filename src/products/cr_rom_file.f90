!> The ROM file (schema "crowdrom-rom", version 3; layout in docs/file-formats.md): written by
!> crowd_offline, read by crowd_rom, crowd_predict and the Python scripts. It holds the offline results (POD
!> spectrum, velocity basis, multiplier cones, PGA history, contact dictionary, inf-sup table,
!> timings) and the prepared reduced models: one `rom_pair_t` per pair (N, R) with its basis,
!> cone candidates and stored hyper-reduction: one group per stored method
!> (`pairs/<k>/<group>`, written and read by the method itself through `hyper_method_t`,
!> cr_hyper_method; the methods are those of the factory, cr_hyper_factory).
!>
!> The offline side builds `rom_pair_t` (cr_rom_pairs), the online side reads the same type:
!> `read_rom_file` (header, offline results, pair list) then `read_rom_pair` per pair. Version 3
!> adds the group `study`: the study's effective configuration (attribute `config`, the snapshot
!> database's, with &study), its parameter component names and the initial positions (dataset
!> `study/q0`), so that prediction for new parameters needs no database (cr_rom_study,
!> open_rom_study). Readers accept versions 2 and 3 (a version-2 file has no `study`: version
!> tells) and validate what they read (shapes against attributes,
!> dictionary and EIM/EQ indices in range, finite bases and weights).
module cr_rom_file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_h5file, only: h5file_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_hyper_terms, only: hyper_terms_t
  use cr_hyper_method, only: hyper_slot_t, TERM_NAMES
  use cr_hyper_factory, only: stored_hypers
  use cr_product_check, only: check_schema, need_finite, need_range, need_size, product_error
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: rom_file_t, rom_pair_t, rom_cone_t, rom_tables_t, write_rom_file, read_rom_file, read_rom_pair, &
    find_pair, ROM_SCHEMA, ROM_SCHEMA_VERSION, ROM_VERSIONS_READ, TERM_NAMES

  character(len=*), parameter :: ROM_SCHEMA = "crowdrom-rom"
  !> 2: prepared pairs (/pairs/<k>) with their hyper-reduction; 3: the study (group `study`)
  integer, parameter :: ROM_SCHEMA_VERSION = 3
  !> versions the reader accepts
  integer, parameter :: ROM_VERSIONS_READ(2) = [2, 3]

  !> A multiplier cone as built offline (gIS or mCPG) and stored.
  type :: rom_cone_t
    character(len=8) :: method = ''
    !> number of cone vectors R
    integer :: r = 0
    !> gIS: selected dictionary indices i_1..i_R (psi_r = e_{i_r}) [R]
    integer, allocatable :: indices(:)
    !> mCPG: cone vectors psi_1..psi_R [n_dict, R]
    real(wp), allocatable :: psi(:,:)
    !> global snapshot column selected at each iteration [R]
    integer(i8), allocatable :: sigma(:)
    !> maximum relative projection error e_r after r vectors, r = 0..R [R + 1]
    real(wp), allocatable :: err_max(:)
    !> mean relative projection error over the snapshots, r = 0..R [R + 1]
    real(wp), allocatable :: err_mean(:)
    !> mCPG only: accuracy a_r of the relative errors after r vectors, r = 0..R [R + 1]: every
    !> computed relative error of a snapshot not yet selected is within a_r of the exact one
    !> (see mcpg_build); not allocated for gIS, whose errors are exact sums of squares
    real(wp), allocatable :: err_acc(:)
    !> wall time of the construction (s)
    real(wp) :: time = 0
    character(len=:), allocatable :: note
  end type rom_cone_t

  !> Inf-sup table, POD comparison and timings of crowd_offline.
  type :: rom_tables_t
    integer, allocatable :: is_n(:), is_r(:)
    real(wp), allocatable :: is_low_min(:), is_up_min(:), is_up_mean(:)
    real(wp), allocatable :: is_low_min_pga(:), is_up_min_pga(:), is_up_mean_pga(:)
    integer, allocatable :: is_n_pga(:)
    !> POD vs rPOD: requested ranks, times (s), spectra (exact: all; rPOD: the largest run)
    integer, allocatable :: pc_n(:)
    real(wp), allocatable :: pc_t_rpod(:), pc_sigma_exact(:), pc_sigma_rpod(:)
    real(wp) :: pc_t_exact = 0
    real(wp) :: t_read = 0, t_pod = 0, t_cone = 0, t_mcpg = 0, t_pga = 0, t_infsup = 0, t_pairs = 0
  end type rom_tables_t

  !> One prepared reduced model (pair N, R).
  type :: rom_pair_t
    !> position in the file (1-based), POD modes N, cone vectors R, supremizers, basis size
    integer :: index = 0, n = 0, r = 0, n_pga = 0, nb = 0
    !> velocity basis [n_dof, nb] (POD modes first)
    real(wp), allocatable :: v(:,:)
    !> PGA history: largest relative projection error before each addition and at the end
    real(wp), allocatable :: pga_err(:)
    !> the cone's candidate entries of s1, s2, s3
    type(hyper_terms_t) :: terms
    !> hyper-reduction stored
    logical :: hyper = .false.
    !> the stored hyper-reduction methods (when hyper), each with its data and build time
    type(hyper_slot_t), allocatable :: methods(:)
    real(wp) :: t_pga = 0, t_snap = 0
  end type rom_pair_t

  !> Everything in a ROM file except the pairs' contents.
  type :: rom_file_t
    !> file read from and its schema version (set by read_rom_file)
    character(len=:), allocatable :: path
    integer :: version = 0
    !> the study (version 3): the snapshot database's effective configuration (with &study),
    !> its parameter component names ("l_exit,speed_1,...") and the initial positions [n_dof]
    character(len=:), allocatable :: study_config, param_names
    real(wp), allocatable :: q0(:)
    !> effective configuration, database path and its config hash
    character(len=:), allocatable :: config, database, db_hash
    integer :: n_agents = 0, n_dof = 0, n_steps = 0, n_dict = 0
    real(wp) :: radius = 0, dt = 0
    !> POD: method, numerical rank, total energy, every singular value
    character(len=:), allocatable :: pod_method
    integer :: pod_rank = 0
    real(wp) :: pod_total_energy = 0
    real(wp), allocatable :: pod_sigma(:)
    !> velocity basis of the largest model: POD modes then supremizers [n_dof, n_pod + n_pga]
    real(wp), allocatable :: v(:,:)
    integer :: n_pod = 0
    !> the cone used and the comparison cone (method '' when not built)
    type(rom_cone_t) :: cone, cone_other
    !> PGA history of the largest model
    real(wp), allocatable :: pga_err(:)
    !> contact dictionary [n_dict]
    integer, allocatable :: dict_ia(:), dict_ib(:), dict_ob(:)
    type(rom_tables_t) :: tables
    !> (N, R, basis size, hyper stored 1/0) of every pair [n_pairs]
    integer :: n_pairs = 0
    integer, allocatable :: pair_n(:), pair_r(:), pair_nb(:), pair_hyper(:)
  end type rom_file_t

contains

  ! ------------------------------------------------------------------ write

  !> Write the ROM file (rank 0 only; temporary name + rename).
  subroutine write_rom_file(path, rom, pairs, error)
    character(len=*), intent(in) :: path
    type(rom_file_t), intent(in) :: rom
    type(rom_pair_t), intent(in) :: pairs(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    integer :: k
    call h5%create(path, error)
    if (allocated(error)) return
    call h5%write_attr("/", "schema", ROM_SCHEMA, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "schema_version", ROM_SCHEMA_VERSION, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "program", "crowd_offline", error); if (allocated(error)) goto 9
    call h5%write_attr("/", "config", rom%config, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "database", rom%database, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "database_config_hash", rom%db_hash, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_agents", rom%n_agents, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_steps", rom%n_steps, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "agent_radius", rom%radius, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "dt", rom%dt, error); if (allocated(error)) goto 9
    call write_study(h5, rom, error); if (allocated(error)) goto 9
    ! POD
    call h5%make_group("pod", error); if (allocated(error)) goto 9
    call h5%write_attr("pod", "method", rom%pod_method, error); if (allocated(error)) goto 9
    call h5%write_attr("pod", "numerical_rank", rom%pod_rank, error); if (allocated(error)) goto 9
    call h5%write_attr("pod", "total_energy", rom%pod_total_energy, error); if (allocated(error)) goto 9
    call h5%write("pod/sigma", rom%pod_sigma, error); if (allocated(error)) goto 9
    ! velocity basis: POD modes then supremizers
    call h5%make_group("basis", error); if (allocated(error)) goto 9
    call h5%write("basis/v", rom%v, error); if (allocated(error)) goto 9
    call h5%write_attr("basis", "n_pod", rom%n_pod, error); if (allocated(error)) goto 9
    call h5%write_attr("basis", "n_pga", size(rom%v, 2) - rom%n_pod, error); if (allocated(error)) goto 9
    ! cones
    call write_cone(h5, "cone", rom%cone, error); if (allocated(error)) goto 9
    if (rom%cone_other%method /= '') then
      call write_cone(h5, "cone_" // trim(rom%cone_other%method), rom%cone_other, error); if (allocated(error)) goto 9
    end if
    ! PGA history
    call h5%make_group("pga", error); if (allocated(error)) goto 9
    call h5%write("pga/err", rom%pga_err, error); if (allocated(error)) goto 9
    ! dictionary
    call h5%make_group("contacts", error); if (allocated(error)) goto 9
    call h5%write("contacts/ia", rom%dict_ia, error); if (allocated(error)) goto 9
    call h5%write("contacts/ib", rom%dict_ib, error); if (allocated(error)) goto 9
    call h5%write("contacts/ob", rom%dict_ob, error); if (allocated(error)) goto 9
    call write_tables(h5, rom%tables, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_pairs", size(pairs), error); if (allocated(error)) goto 9
    call h5%make_group("pairs", error); if (allocated(error)) goto 9
    do k = 1, size(pairs)
      call write_pair(h5, "pairs/" // str(k), pairs(k), error)
      if (allocated(error)) goto 9
    end do
    call h5%commit(error)
9   if (allocated(error)) then
      call prefix_error(error, "ROM file")
      call h5%abort()
    end if
  end subroutine write_rom_file

  !> The study of a version-3 file (everything prediction needs besides the pairs).
  subroutine write_study(h5, rom, error)
    type(h5file_t), intent(inout) :: h5
    type(rom_file_t), intent(in) :: rom
    type(error_t), allocatable, intent(out) :: error
    if (.not. allocated(rom%study_config) .or. .not. allocated(rom%param_names) .or. .not. allocated(rom%q0)) then
      call set_error(error, "the study (configuration, parameter names, initial positions) is not set"); return
    end if
    call h5%make_group("study", error); if (allocated(error)) return
    call h5%write_attr("study", "config", rom%study_config, error); if (allocated(error)) return
    call h5%write_attr("study", "param_names", rom%param_names, error); if (allocated(error)) return
    call h5%write("study/q0", rom%q0, error)
  end subroutine write_study

  subroutine write_cone(h5, g, c, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: g
    type(rom_cone_t), intent(in) :: c
    type(error_t), allocatable, intent(out) :: error
    call h5%make_group(g, error); if (allocated(error)) return
    call h5%write_attr(g, "method", trim(c%method), error); if (allocated(error)) return
    call h5%write_attr(g, "r", c%r, error); if (allocated(error)) return
    call h5%write_attr(g, "time", c%time, error); if (allocated(error)) return
    if (allocated(c%note)) then
      call h5%write_attr(g, "note", c%note, error); if (allocated(error)) return
    end if
    call h5%write(g // "/err_max", c%err_max, error); if (allocated(error)) return
    call h5%write(g // "/err_mean", c%err_mean, error); if (allocated(error)) return
    ! mCPG: accuracy of each err_max entry (see mcpg_build)
    if (allocated(c%err_acc)) then
      call h5%write(g // "/err_acc", c%err_acc, error); if (allocated(error)) return
    end if
    ! written also when R = 0 (empty datasets): a reader finds the same objects in every file
    if (allocated(c%sigma)) then
      call h5%write(g // "/sigma", c%sigma, error); if (allocated(error)) return
    end if
    if (allocated(c%indices)) then
      call h5%write(g // "/indices", c%indices, error); if (allocated(error)) return
    end if
    if (allocated(c%psi)) then
      call h5%write(g // "/psi", c%psi, error); if (allocated(error)) return
    end if
  end subroutine write_cone

  subroutine write_tables(h5, t, error)
    type(h5file_t), intent(inout) :: h5
    type(rom_tables_t), intent(in) :: t
    type(error_t), allocatable, intent(out) :: error
    integer :: k
    call h5%make_group("infsup", error); if (allocated(error)) return
    if (allocated(t%is_n)) then
      if (size(t%is_n) > 0) then
        call h5%write("infsup/n", t%is_n, error); if (allocated(error)) return
        call h5%write("infsup/r", t%is_r, error); if (allocated(error)) return
        call h5%write("infsup/gamma_low_min", t%is_low_min, error); if (allocated(error)) return
        call h5%write("infsup/gamma_up_min", t%is_up_min, error); if (allocated(error)) return
        call h5%write("infsup/gamma_up_mean", t%is_up_mean, error); if (allocated(error)) return
        call h5%write("infsup/gamma_low_min_pga", t%is_low_min_pga, error); if (allocated(error)) return
        call h5%write("infsup/gamma_up_min_pga", t%is_up_min_pga, error); if (allocated(error)) return
        call h5%write("infsup/gamma_up_mean_pga", t%is_up_mean_pga, error); if (allocated(error)) return
        call h5%write("infsup/n_pga", t%is_n_pga, error); if (allocated(error)) return
      end if
    end if
    call h5%make_group("timing", error); if (allocated(error)) return
    call h5%write_attr("timing", "read", t%t_read, error); if (allocated(error)) return
    call h5%write_attr("timing", "pod", t%t_pod, error); if (allocated(error)) return
    call h5%write_attr("timing", "cone", t%t_cone, error); if (allocated(error)) return
    call h5%write_attr("timing", "cone_other", t%t_mcpg, error); if (allocated(error)) return
    call h5%write_attr("timing", "pga", t%t_pga, error); if (allocated(error)) return
    call h5%write_attr("timing", "infsup", t%t_infsup, error); if (allocated(error)) return
    call h5%write_attr("timing", "pairs", t%t_pairs, error); if (allocated(error)) return
    if (allocated(t%pc_n)) then
      if (size(t%pc_n) > 0) then
        call h5%make_group("pod_compare", error); if (allocated(error)) return
        call h5%write("pod_compare/n", t%pc_n, error); if (allocated(error)) return
        call h5%write("pod_compare/t_rpod", t%pc_t_rpod, error); if (allocated(error)) return
        call h5%write("pod_compare/t_exact", [(t%pc_t_exact, k = 1, size(t%pc_n))], error)
        if (allocated(error)) return
        call h5%write("pod_compare/sigma_exact", t%pc_sigma_exact, error); if (allocated(error)) return
        call h5%write("pod_compare/sigma_rpod", t%pc_sigma_rpod, error); if (allocated(error)) return
      end if
    end if
  end subroutine write_tables

  !> Write `pair` into group `g` of an open ROM file.
  subroutine write_pair(h5, g, pair, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: g
    type(rom_pair_t), intent(in) :: pair
    type(error_t), allocatable, intent(out) :: error
    integer :: k
    call h5%make_group(g, error); if (allocated(error)) return
    call h5%write_attr(g, "n", pair%n, error); if (allocated(error)) return
    call h5%write_attr(g, "r", pair%r, error); if (allocated(error)) return
    call h5%write_attr(g, "n_pga", pair%n_pga, error); if (allocated(error)) return
    call h5%write_attr(g, "n_basis", size(pair%v, 2), error); if (allocated(error)) return
    call h5%write_attr(g, "hyper", merge(1, 0, pair%hyper), error); if (allocated(error)) return
    call h5%write_attr(g, "time_pga", pair%t_pga, error); if (allocated(error)) return
    call h5%write_attr(g, "time_snapshots", pair%t_snap, error); if (allocated(error)) return
    call h5%write(g // "/v", pair%v, error); if (allocated(error)) return
    call h5%write(g // "/pga_err", pair%pga_err, error); if (allocated(error)) return
    call h5%make_group(g // "/cand", error); if (allocated(error)) return
    call h5%write(g // "/cand/rows", pair%terms%rows, error); if (allocated(error)) return
    call h5%write(g // "/cand/w", pair%terms%w, error); if (allocated(error)) return
    call h5%write(g // "/cand/s2_row", pair%terms%s2_row, error); if (allocated(error)) return
    call h5%write(g // "/cand/s2_dof", pair%terms%s2_dof, error); if (allocated(error)) return
    if (.not. pair%hyper) return
    do k = 1, size(pair%methods)
      associate (m => pair%methods(k)%m)
        call h5%write_attr(g, "time_" // m%storage(), m%time, error); if (allocated(error)) return
        call m%write(h5, g, error); if (allocated(error)) return
      end associate
    end do
  end subroutine write_pair

  ! ------------------------------------------------------------------ read

  !> Read the header, offline results, dictionary and pair list of ROM file `path`; `where`
  !> prefixes messages (e.g. "input.nml: &rom: rom_file"). Errors are input errors (code 2).
  subroutine read_rom_file(path, where, rom, error)
    character(len=*), intent(in) :: path, where
    type(rom_file_t), intent(out) :: rom
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    integer :: version, k, nb
    character(len=:), allocatable :: g
    call h5%open(path, error)
    if (allocated(error)) then
      error%message = where // " '" // path // "': cannot open (" // error%message // ")"
      error%code = EXIT_BAD_INPUT; return
    end if
    rom%path = path
    call check_schema(h5, path, ROM_SCHEMA, ROM_VERSIONS_READ, "ROM file", version, error); if (allocated(error)) goto 9
    rom%version = version
    call h5%read_attr("/", "database", rom%database, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "database_config_hash", rom%db_hash, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "config", rom%config, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_agents", rom%n_agents, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_steps", rom%n_steps, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "agent_radius", rom%radius, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "dt", rom%dt, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_pairs", rom%n_pairs, error); if (allocated(error)) goto 9
    if (rom%n_agents < 1 .or. rom%n_steps < 1 .or. rom%n_pairs < 0 .or. .not. (rom%radius > 0) .or. &
        .not. (rom%dt > 0) .or. rom%radius > huge(1.0_wp) .or. rom%dt > huge(1.0_wp)) then
      call product_error(path, "root attributes out of range (n_agents " // str(rom%n_agents) // ", n_steps " // &
        str(rom%n_steps) // ", n_pairs " // str(rom%n_pairs) // ", agent_radius " // str(rom%radius) // ", dt " // &
        str(rom%dt) // ")", error); goto 9
    end if
    rom%n_dof = 2 * rom%n_agents
    ! offline results
    call h5%read_attr("pod", "method", rom%pod_method, error); if (allocated(error)) goto 9
    call h5%read_attr("pod", "numerical_rank", rom%pod_rank, error); if (allocated(error)) goto 9
    call h5%read_attr("pod", "total_energy", rom%pod_total_energy, error); if (allocated(error)) goto 9
    call h5%read("pod/sigma", rom%pod_sigma, error); if (allocated(error)) goto 9
    call need_finite(path, "pod/sigma", rom%pod_sigma, error); if (allocated(error)) goto 9
    call h5%read("basis/v", rom%v, error); if (allocated(error)) goto 9
    call h5%read_attr("basis", "n_pod", rom%n_pod, error); if (allocated(error)) goto 9
    call need_size(path, "basis/v (rows)", size(rom%v, 1), rom%n_dof, "2 n_agents", error); if (allocated(error)) goto 9
    call need_finite(path, "basis/v", rom%v, error); if (allocated(error)) goto 9
    if (version >= 3) then
      call h5%read_attr("study", "config", rom%study_config, error); if (allocated(error)) goto 9
      call h5%read_attr("study", "param_names", rom%param_names, error); if (allocated(error)) goto 9
      call h5%read("study/q0", rom%q0, error); if (allocated(error)) goto 9
      call need_size(path, "study/q0", size(rom%q0), rom%n_dof, "2 n_agents", error); if (allocated(error)) goto 9
      call need_finite(path, "study/q0", rom%q0, error); if (allocated(error)) goto 9
    end if
    call read_cone(h5, path, "cone", rom%cone, error); if (allocated(error)) goto 9
    do k = 1, 2
      g = "cone_" // trim(merge('gis ', 'mcpg', k == 1))
      if (h5%exists(g)) then
        call read_cone(h5, path, g, rom%cone_other, error); if (allocated(error)) goto 9
      end if
    end do
    call h5%read("pga/err", rom%pga_err, error); if (allocated(error)) goto 9
    call h5%read("contacts/ia", rom%dict_ia, error); if (allocated(error)) goto 9
    call h5%read("contacts/ib", rom%dict_ib, error); if (allocated(error)) goto 9
    call h5%read("contacts/ob", rom%dict_ob, error); if (allocated(error)) goto 9
    rom%n_dict = size(rom%dict_ia)
    call check_dictionary(path, rom%n_agents, rom%dict_ia, rom%dict_ib, rom%dict_ob, error); if (allocated(error)) goto 9
    call read_tables(h5, rom%tables, error); if (allocated(error)) goto 9
    ! the pair list
    allocate(rom%pair_n(rom%n_pairs), rom%pair_r(rom%n_pairs), rom%pair_nb(rom%n_pairs), rom%pair_hyper(rom%n_pairs))
    do k = 1, rom%n_pairs
      g = "pairs/" // str(k)
      call h5%read_attr(g, "n", rom%pair_n(k), error); if (allocated(error)) goto 9
      call h5%read_attr(g, "r", rom%pair_r(k), error); if (allocated(error)) goto 9
      call h5%read_attr(g, "n_basis", rom%pair_nb(k), error); if (allocated(error)) goto 9
      call h5%read_attr(g, "hyper", rom%pair_hyper(k), error); if (allocated(error)) goto 9
      nb = rom%pair_nb(k)
      if (rom%pair_n(k) < 0 .or. rom%pair_r(k) < 0 .or. nb < rom%pair_n(k) .or. nb > rom%n_dof .or. &
          rom%pair_hyper(k) < 0 .or. rom%pair_hyper(k) > 1) then
        call product_error(path, "group '" // g // "': attributes out of range (n " // str(rom%pair_n(k)) // &
          ", r " // str(rom%pair_r(k)) // ", n_basis " // str(nb) // ", hyper " // str(rom%pair_hyper(k)) // &
          "; n_dof " // str(rom%n_dof) // ")", error); goto 9
      end if
    end do
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= EXIT_BAD_INPUT) call prefix_error(error, where // " '" // path // "'")
      if (error%code == EXIT_BAD_INPUT .and. index(error%message, where) /= 1) error%message = where // ": " // error%message
      error%code = EXIT_BAD_INPUT
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_rom_file

  !> Dictionary identities: ia in 1..n_agents, ib in 0..n_agents (0: obstacle contact), ob >= 0.
  subroutine check_dictionary(path, n_agents, ia, ib, ob, error)
    character(len=*), intent(in) :: path
    integer, intent(in) :: n_agents, ia(:), ib(:), ob(:)
    type(error_t), allocatable, intent(out) :: error
    call need_size(path, "contacts/ib", size(ib), size(ia), "contacts/ia", error); if (allocated(error)) return
    call need_size(path, "contacts/ob", size(ob), size(ia), "contacts/ia", error); if (allocated(error)) return
    call need_range(path, "contacts/ia", ia, 1, n_agents, error); if (allocated(error)) return
    call need_range(path, "contacts/ib", ib, 0, n_agents, error); if (allocated(error)) return
    call need_range(path, "contacts/ob", ob, 0, huge(1), error)
  end subroutine check_dictionary

  subroutine read_cone(h5, path, g, c, error)
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path, g
    type(rom_cone_t), intent(out) :: c
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: m
    call h5%read_attr(g, "method", m, error); if (allocated(error)) return
    c%method = m
    call h5%read_attr(g, "r", c%r, error); if (allocated(error)) return
    call h5%read_attr(g, "time", c%time, error); if (allocated(error)) return
    call h5%read_attr(g, "note", m, error)
    if (allocated(error)) then
      deallocate(error)
    else
      c%note = m
    end if
    call h5%read(g // "/err_max", c%err_max, error); if (allocated(error)) return
    call h5%read(g // "/err_mean", c%err_mean, error); if (allocated(error)) return
    if (h5%exists(g // "/err_acc")) then
      call h5%read(g // "/err_acc", c%err_acc, error); if (allocated(error)) return
    end if
    if (h5%exists(g // "/sigma")) then
      call h5%read(g // "/sigma", c%sigma, error); if (allocated(error)) return
    end if
    if (h5%exists(g // "/indices")) then
      call h5%read(g // "/indices", c%indices, error); if (allocated(error)) return
    end if
    if (h5%exists(g // "/psi")) then
      call h5%read(g // "/psi", c%psi, error); if (allocated(error)) return
      call need_finite(path, g // "/psi", c%psi, error); if (allocated(error)) return
    end if
    call need_size(path, g // "/err_max", size(c%err_max), c%r + 1, "attribute r + 1", error)
  end subroutine read_cone

  subroutine read_tables(h5, t, error)
    type(h5file_t), intent(in) :: h5
    type(rom_tables_t), intent(out) :: t
    type(error_t), allocatable, intent(out) :: error
    real(wp), allocatable :: te(:)
    if (h5%exists("infsup/n")) then
      call h5%read("infsup/n", t%is_n, error); if (allocated(error)) return
      call h5%read("infsup/r", t%is_r, error); if (allocated(error)) return
      call h5%read("infsup/gamma_low_min", t%is_low_min, error); if (allocated(error)) return
      call h5%read("infsup/gamma_up_min", t%is_up_min, error); if (allocated(error)) return
      call h5%read("infsup/gamma_up_mean", t%is_up_mean, error); if (allocated(error)) return
      call h5%read("infsup/gamma_low_min_pga", t%is_low_min_pga, error); if (allocated(error)) return
      call h5%read("infsup/gamma_up_min_pga", t%is_up_min_pga, error); if (allocated(error)) return
      call h5%read("infsup/gamma_up_mean_pga", t%is_up_mean_pga, error); if (allocated(error)) return
      call h5%read("infsup/n_pga", t%is_n_pga, error); if (allocated(error)) return
    else
      allocate(t%is_n(0))
    end if
    call h5%read_attr("timing", "read", t%t_read, error); if (allocated(error)) return
    call h5%read_attr("timing", "pod", t%t_pod, error); if (allocated(error)) return
    call h5%read_attr("timing", "cone", t%t_cone, error); if (allocated(error)) return
    call h5%read_attr("timing", "cone_other", t%t_mcpg, error); if (allocated(error)) return
    call h5%read_attr("timing", "pga", t%t_pga, error); if (allocated(error)) return
    call h5%read_attr("timing", "infsup", t%t_infsup, error); if (allocated(error)) return
    call h5%read_attr("timing", "pairs", t%t_pairs, error); if (allocated(error)) return
    if (h5%exists("pod_compare")) then
      call h5%read("pod_compare/n", t%pc_n, error); if (allocated(error)) return
      call h5%read("pod_compare/t_rpod", t%pc_t_rpod, error); if (allocated(error)) return
      call h5%read("pod_compare/t_exact", te, error); if (allocated(error)) return
      if (size(te) > 0) t%pc_t_exact = te(1)
      call h5%read("pod_compare/sigma_exact", t%pc_sigma_exact, error); if (allocated(error)) return
      call h5%read("pod_compare/sigma_rpod", t%pc_sigma_rpod, error); if (allocated(error)) return
    end if
  end subroutine read_tables

  !> Index of the pair (n, r) in the file, or an error listing the stored pairs.
  subroutine find_pair(rom, n, r, where, k, error)
    type(rom_file_t), intent(in) :: rom
    integer, intent(in) :: n, r
    character(len=*), intent(in) :: where
    integer, intent(out) :: k
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: list
    integer :: j
    do k = 1, rom%n_pairs
      if (rom%pair_n(k) == n .and. rom%pair_r(k) == r) return
    end do
    list = ""
    do j = 1, rom%n_pairs
      list = list // " (" // str(rom%pair_n(j)) // ", " // str(rom%pair_r(j)) // ")"
    end do
    k = 0
    call set_error(error, where // ": (N, R) = (" // str(n) // ", " // str(r) // ") is not prepared in ROM file '" // &
      rom%path // "' (stored pairs (N, R):" // list // "; add it to &pairs n / r and rerun crowd_offline)", EXIT_BAD_INPUT)
  end subroutine find_pair

  !> Read pair k of the ROM file and validate it (sizes, finite values, indices in range).
  subroutine read_rom_pair(rom, k, pair, error)
    type(rom_file_t), intent(in) :: rom
    integer, intent(in) :: k
    type(rom_pair_t), intent(out) :: pair
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    type(sparse_cone_t) :: cone
    character(len=:), allocatable :: g, path
    integer, allocatable :: rows(:), s2_row(:), s2_dof(:)
    real(wp), allocatable :: w(:,:)
    integer :: j, l, nz
    path = rom%path
    call h5%open(path, error)
    if (allocated(error)) return
    g = "pairs/" // str(k)
    pair%index = k
    pair%n = rom%pair_n(k); pair%r = rom%pair_r(k); pair%nb = rom%pair_nb(k)
    pair%hyper = rom%pair_hyper(k) == 1
    call h5%read_attr(g, "n_pga", pair%n_pga, error); if (allocated(error)) goto 9
    call h5%read_attr(g, "time_pga", pair%t_pga, error); if (allocated(error)) goto 9
    call h5%read_attr(g, "time_snapshots", pair%t_snap, error); if (allocated(error)) goto 9
    call h5%read(g // "/v", pair%v, error); if (allocated(error)) goto 9
    call h5%read(g // "/pga_err", pair%pga_err, error); if (allocated(error)) goto 9
    call h5%read(g // "/cand/rows", rows, error); if (allocated(error)) goto 9
    call h5%read(g // "/cand/w", w, error); if (allocated(error)) goto 9
    call h5%read(g // "/cand/s2_row", s2_row, error); if (allocated(error)) goto 9
    call h5%read(g // "/cand/s2_dof", s2_dof, error); if (allocated(error)) goto 9
    if (size(pair%v, 1) /= rom%n_dof .or. size(pair%v, 2) /= pair%nb) then
      call product_error(path, "dataset '" // g // "/v' has " // str(size(pair%v, 1)) // " x " // &
        str(size(pair%v, 2)) // " entries, but n_agents and n_basis say " // str(rom%n_dof) // " x " // &
        str(pair%nb), error); goto 9
    end if
    call need_finite(path, g // "/v", pair%v, error); if (allocated(error)) goto 9
    if (size(w, 2) /= pair%r .or. size(w, 1) /= size(rows)) then
      call product_error(path, "dataset '" // g // "/cand/w' has " // str(size(w, 1)) // " x " // str(size(w, 2)) // &
        " entries, but cand/rows and r say " // str(size(rows)) // " x " // str(pair%r), error); goto 9
    end if
    call need_finite(path, g // "/cand/w", w, error); if (allocated(error)) goto 9
    call need_range(path, g // "/cand/rows", rows, 1, rom%n_dict, error); if (allocated(error)) goto 9
    ! the cone over the dictionary, from its support rows
    cone%r = pair%r; cone%n_dict = rom%n_dict
    nz = count(w /= 0)
    allocate(cone%ptr(pair%r + 1), cone%idx(nz), cone%val(nz))
    nz = 0
    cone%ptr(1) = 0
    do j = 1, pair%r
      do l = 1, size(rows)
        if (w(l, j) /= 0) then
          nz = nz + 1
          cone%idx(nz) = rows(l); cone%val(nz) = w(l, j)
        end if
      end do
      cone%ptr(j + 1) = nz
    end do
    call pair%terms%init(cone, pair%r, rom%dict_ia, rom%dict_ib, rom%dict_ob, rom%n_dof, error)
    if (allocated(error)) goto 9
    if (size(pair%terms%rows) /= size(rows) .or. size(pair%terms%s2_row) /= size(s2_row) .or. &
        size(pair%terms%s2_dof) /= size(s2_dof)) then
      call product_error(path, "group '" // g // "/cand': candidate lists do not match its cone", error); goto 9
    end if
    if (any(pair%terms%rows /= rows) .or. any(pair%terms%s2_row /= s2_row) .or. any(pair%terms%s2_dof /= s2_dof)) then
      call product_error(path, "group '" // g // "/cand': candidate lists do not match its cone", error); goto 9
    end if
    if (pair%hyper) then
      call stored_hypers(pair%methods)
      do j = 1, size(pair%methods)
        associate (m => pair%methods(j)%m)
          call h5%read_attr(g, "time_" // m%storage(), m%time, error); if (allocated(error)) goto 9
          call m%read(h5, path, g, pair%terms, error); if (allocated(error)) goto 9
        end associate
      end do
    end if
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= EXIT_BAD_INPUT) call prefix_error(error, "ROM file '" // path // "', pair " // str(k))
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)

  end subroutine read_rom_pair
end module cr_rom_file
