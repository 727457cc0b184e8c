!> crowd_offline: reduced bases from a snapshot database.
!>
!>   mpirun -np P crowd_offline input.nml [--summary FILE]
!>
!> Stages: read the training snapshots (each rank its block of samples), velocity POD
!> (&pod method), multiplier cone (gIS or mCPG, optionally both for comparison),
!> supremizer enrichment (PGA), reduced inf-sup table, ROM file (&offline rom_file).
program crowd_offline
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_cli, only: cli_t
  use cr_program, only: program_start, program_finish, log_level_of
  use cr_config, only: config_t, read_config, config_echo
  use cr_inputs, only: check_input_groups
  use cr_config_check, only: check_config
  use cr_namelist_text, only: namelist_text_t
  use cr_study_match, only: check_database_matches
  use cr_offline_config, only: offline_cfg_t, read_offline, check_offline, offline_echo, check_offline_paths
  use cr_offline_data, only: offline_data_t, load_training
  use cr_pod, only: pod_result_t, pod_compute, rsvd_opts_t, pod_rsvd, pod_snapshots
  use cr_cone, only: cone_result_t, gis_build, mcpg_build
  use cr_sparse_cone, only: sparse_cone_t
  use cr_supremizer, only: pga_result_t, pga_enrich
  use cr_infsup_table, only: infsup_table
  use cr_rom_file, only: rom_file_t, rom_tables_t, write_rom_file
  use cr_rom_pairs, only: rom_pair_t, build_pair, hyper_summary
  use cr_json, only: json_writer_t
  implicit none
  type(env_t) :: env
  type(logger_t) :: log
  type(cli_t) :: cli
  type(config_t) :: cfg
  type(offline_cfg_t) :: ocfg
  type(namelist_text_t) :: nml
  type(error_t), allocatable :: error
  integer :: code

  call program_start("crowd_offline", env, log, cli, error)
  if (.not. allocated(error) .and. cli%help) then
    if (env%is_root()) call print_help()
    code = program_finish(env, log, error)
    stop
  end if
  if (.not. allocated(error)) call read_config(cli%input, env, cfg, error, nml, &
    program='crowd_offline', needed=[character(len=8) :: 'scene', 'agents', 'offline'])
  if (.not. allocated(error)) call check_input_groups(nml, error)
  if (.not. allocated(error)) call check_config(cfg, error)
  if (.not. allocated(error)) call read_offline(nml, ocfg, error)
  if (.not. allocated(error)) call check_offline(cli%input, ocfg, error)
  if (.not. allocated(error)) call check_offline_paths(cli%input, cli%summary, ocfg, error)
  if (.not. allocated(error)) call check_database_matches(env, cli%input // ": &offline", trim(ocfg%database), &
    cfg, nml, error)
  if (.not. allocated(error)) then
    log%level = log_level_of(cfg%output%log_level)
    call run(error)
  end if
  code = program_finish(env, log, error)
  ! a plain (quiet) stop: the error line was printed; no runtime backtrace on bad input
  if (code /= 0) stop code, quiet=.true.

contains

  subroutine print_help()
    print '(a)', "usage: [mpirun -np P] crowd_offline input.nml [--summary FILE]"
    print '(a)', ""
    print '(a)', "Builds the reduced bases from the snapshot database named in &offline: velocity POD"
    print '(a)', "(tsqr | rsvd | scalapack | snapshots), multiplier cone (gis | mcpg), supremizer"
    print '(a)', "enrichment (PGA), reduced inf-sup table; writes the ROM file (&offline rom_file)."
    print '(a)', "The input is the study's namelist file plus an &offline group (see README)."
    print '(a)', ""
    print '(a)', "Exit status: 0 success, 2 bad input, 1 other failure."
  end subroutine print_help

  !> All stages; errors are made collective before returning.
  subroutine run(error)
    type(error_t), allocatable, intent(out) :: error
    type(offline_data_t) :: data
    type(pod_result_t) :: pod
    type(rsvd_opts_t) :: rsvd
    type(cone_result_t) :: cone, other
    type(sparse_cone_t) :: scone
    type(pga_result_t) :: pga
    type(rom_tables_t) :: tab
    type(rom_pair_t), allocatable :: pairs(:)
    real(wp), allocatable :: v(:,:)
    real(wp) :: t0, eps
    integer :: n_pod, nmodes
    logical :: failed

    call log%stage_begin("crowd_offline: read training snapshots")
    t0 = env%wtime()
    call load_training(env, trim(ocfg%database), cfg, data, error)
    if (collective_fail()) return
    tab%t_read = env%wtime() - t0
    call log%info("   " // str(data%n_train) // " training samples x " // str(data%n_steps) // " steps, " // &
      str(data%n_dof) // " velocity dofs, " // str(data%n_dict) // " contacts in the dictionary, " // &
      str(env%size) // " rank(s)")
    call log%stage_end()

    ! ---- velocity POD
    call log%stage_begin("crowd_offline: velocity POD (" // trim(ocfg%pod_method) // ")")
    t0 = env%wtime()
    eps = ocfg%pod_energy
    nmodes = ocfg%pod_n
    if (nmodes > 0 .and. nmodes > data%n_dof) then
      call set_error(error, "&pod: n = " // str(nmodes) // " is larger than the number of velocity " // &
        "dofs (" // str(data%n_dof) // ")", 2)
    end if
    if (collective_fail()) return
    rsvd = rsvd_opts_t(ocfg%rsvd_rank, ocfg%rsvd_oversampling, ocfg%rsvd_power, ocfg%rsvd_seed, ocfg%rsvd_sketch)
    if (nmodes > 0) then
      call pod_compute(env, trim(ocfg%pod_method), data%u, pod, error, n_modes=nmodes, rsvd=rsvd)
    else
      call pod_compute(env, trim(ocfg%pod_method), data%u, pod, error, eps=eps, rsvd=rsvd)
    end if
    if (collective_fail()) return
    if (nmodes > 0 .and. pod%n_modes < nmodes) call log%warn("&pod n = " // str(nmodes) // &
      " exceeds the numerical rank of the snapshots: " // str(pod%n_modes) // " modes kept")
    tab%t_pod = env%wtime() - t0
    n_pod = pod%n_modes
    v = pod%phi(:, 1:n_pod)
    call log%info("   N = " // str(n_pod) // " modes (numerical rank " // str(pod%rank) // &
      ", retained energy " // str(pod%energy) // ")")
    if (n_pod == 0) then
      if (.not. (pod%total_energy > 0)) then
        call log%warn("POD: the velocity snapshots are all zero (a crowd at rest): no POD mode")
      else
        call log%warn("POD: &pod energy = " // str(eps) // " keeps no POD mode (1 - retained energy <= " // &
          "energy already with N = 0)")
      end if
    end if
    call log%stage_end()

    ! ---- POD vs randomized POD (timing and spectra)
    if (any(ocfg%pod_compare_n > 0)) then
      call log%stage_begin("crowd_offline: POD (method of snapshots) vs randomized POD")
      call pod_compare(data, tab, error)
      if (collective_fail()) return
      call log%stage_end()
    end if

    ! ---- multiplier cone
    call log%stage_begin("crowd_offline: multiplier cone (" // trim(ocfg%cone_method) // ")")
    t0 = env%wtime()
    if (ocfg%cone_method == 'gis') then
      call gis_build(env, data%lam, ocfg%cone_delta, ocfg%cone_r_max, cone, error)
    else
      call mcpg_build(env, data%lam, ocfg%cone_delta, ocfg%mcpg_r_max, cone, error)
    end if
    if (collective_fail()) return
    tab%t_cone = env%wtime() - t0
    call log%info("   R = " // str(cone%r) // ", e_R = " // str(cone%err_max(cone%r + 1)) // ", " // &
      str(cone%time) // " s")
    if (allocated(cone%note)) call log%warn("cone: " // cone%note)
    if (ocfg%cone_compare) then
      t0 = env%wtime()
      if (ocfg%cone_method == 'gis') then
        call mcpg_build(env, data%lam, ocfg%cone_delta, ocfg%mcpg_r_max, other, error)
      else
        call gis_build(env, data%lam, ocfg%cone_delta, ocfg%cone_r_max, other, error)
      end if
      if (collective_fail()) return
      tab%t_mcpg = env%wtime() - t0
      call log%info("   comparison " // trim(other%method) // ": R = " // str(other%r) // ", e_R = " // &
        str(other%err_max(other%r + 1)) // ", " // str(other%time) // " s")
      if (allocated(other%note)) call log%warn("cone (comparison " // trim(other%method) // "): " // other%note)
    end if
    if (cone%method == 'gis') then
      call scone%from_indices(data%n_dict, cone%indices)
    else
      call scone%from_dense(cone%psi)
    end if
    call log%stage_end()

    ! ---- supremizer enrichment
    if (ocfg%pga .and. scone%r > 0) then
      call log%stage_begin("crowd_offline: supremizer enrichment (PGA, delta = " // str(ocfg%pga_delta) // ")")
      t0 = env%wtime()
      call pga_enrich(env, data%scenes, data%scene_of, data%radius, data%dt, data%dict_ia, data%dict_ib, &
        data%dict_ob, scone, data%q, data%lam%col_offset, v, ocfg%pga_delta, ocfg%pga_max_add, pga, error)
      if (collective_fail()) return
      tab%t_pga = env%wtime() - t0
      call log%info("   added " // str(pga%n_added) // " supremizers; largest projection error " // &
        str(pga%err(1)) // " -> " // str(pga%err(pga%n_added + 1)))
      if (allocated(pga%note)) call log%warn("PGA: " // pga%note)
      call log%stage_end()
    else
      allocate(pga%err(1), pga%chosen(0)); pga%err = 0
      if (ocfg%pga) call log%warn("PGA skipped: the cone is empty, there is no supremizer to add")
    end if
    if (size(v, 2) == 0) call log%warn("the reduced velocity basis is empty (N = 0): the reduced model " // &
      "can only predict a zero velocity")

    ! ---- inf-sup table
    call log%stage_begin("crowd_offline: reduced inf-sup table")
    t0 = env%wtime()
    call infsup_table(env, log, ocfg, data, pod, scone, tab, error)
    if (collective_fail()) return
    tab%t_infsup = env%wtime() - t0
    call log%stage_end()

    ! ---- reduced models for crowd_rom (pairs (N, R), their supremizers and hyper-reduction)
    call log%stage_begin("crowd_offline: reduced models (pairs N, R; hyper-reduction)")
    t0 = env%wtime()
    call prepare_pairs(data, pod%phi(:, 1:n_pod), scone, v, pga, pairs, error)
    if (collective_fail()) return
    tab%t_pairs = env%wtime() - t0
    call log%stage_end()

    ! ---- ROM file
    call log%stage_begin("crowd_offline: write " // trim(ocfg%rom_file))
    if (env%is_root()) then
      block
        type(rom_file_t) :: rom
        rom%config = config_echo(cfg) // offline_echo(ocfg)
        rom%database = trim(ocfg%database); rom%db_hash = data%config_hash
        rom%n_agents = data%n_agents; rom%n_steps = data%n_steps; rom%radius = data%radius; rom%dt = data%dt
        rom%pod_method = pod%method; rom%pod_rank = pod%rank; rom%pod_total_energy = pod%total_energy
        rom%pod_sigma = pod%sigma_all
        rom%v = v; rom%n_pod = n_pod
        rom%cone = cone; rom%cone_other = other
        rom%pga_err = pga%err
        rom%dict_ia = data%dict_ia; rom%dict_ib = data%dict_ib; rom%dict_ob = data%dict_ob
        rom%tables = tab
        call write_rom_file(trim(ocfg%rom_file), rom, pairs, error)
      end block
    end if
    failed = collective_fail()
    if (failed) return
    call log%stage_end()
    call log%info("summary: N_pod = " // str(n_pod) // ", N (with supremizers) = " // str(size(v, 2)) // &
      ", R = " // str(cone%r) // ", times: read " // str(tab%t_read) // " s, POD " // str(tab%t_pod) // &
      " s, cone " // str(tab%t_cone) // " s, PGA " // str(tab%t_pga) // " s, inf-sup " // str(tab%t_infsup) // " s")
    if (len(cli%summary) > 0 .and. env%is_root()) then
      block
        type(json_writer_t) :: js
        call js%add("program", "crowd_offline")
        call js%add("rom_file", trim(ocfg%rom_file))
        call js%add("ranks", env%size)
        call js%add("n_pod", n_pod)
        call js%add("pod_numerical_rank", pod%rank)
        call js%add("pod_energy_retained", pod%energy)
        call js%add("n_total", size(v, 2))
        call js%add("r", cone%r)
        call js%add("cone_method", trim(cone%method))
        call js%add("cone_error", cone%err_max(cone%r + 1))
        call js%add("pga_added", pga%n_added)
        call js%add("pga_error", pga%err(pga%n_added + 1))
        call js%add("cone_note", note_of(cone%note))
        ! the comparison cone's note (e.g. mCPG stopped at the accuracy of its projections); "" if none
        call js%add("cone_comparison_note", note_of(other%note))
        call js%add("pga_note", note_of(pga%note))
        call js%add("time_read", tab%t_read)
        call js%add("time_pod", tab%t_pod)
        call js%add("time_cone", tab%t_cone)
        call js%add("time_cone_comparison", tab%t_mcpg)
        call js%add("time_pga", tab%t_pga)
        call js%add("time_infsup", tab%t_infsup)
        call js%write_file(cli%summary, error)
      end block
    end if
    if (collective_fail()) return
  end subroutine run

  !> Time the exact POD (method of snapshots, all modes) and pod_rsvd for each requested rank.
  subroutine pod_compare(data_ref, tab, error)
    type(offline_data_t), intent(in) :: data_ref
    type(rom_tables_t), intent(inout) :: tab
    type(error_t), allocatable, intent(out) :: error
    type(pod_result_t) :: ex, rs
    real(wp) :: t0
    integer :: k
    tab%pc_n = pack(ocfg%pod_compare_n, ocfg%pod_compare_n > 0)
    allocate(tab%pc_t_rpod(size(tab%pc_n)))
    t0 = env%wtime()
    call pod_snapshots(env, data_ref%u, ex, error, eps=0.0_wp)
    if (allocated(error)) return
    tab%pc_t_exact = env%wtime() - t0
    tab%pc_sigma_exact = ex%sigma_all
    do k = 1, size(tab%pc_n)
      t0 = env%wtime()
      call pod_rsvd(env, data_ref%u, tab%pc_n(k), ocfg%rsvd_oversampling, ocfg%rsvd_power, &
        trim(ocfg%rsvd_sketch), ocfg%rsvd_seed, rs, error, n_modes=min(tab%pc_n(k), data_ref%n_dof))
      if (allocated(error)) return
      tab%pc_t_rpod(k) = env%wtime() - t0
      if (k == size(tab%pc_n)) tab%pc_sigma_rpod = rs%sigma_all
      call log%info("   rPOD rank " // str(tab%pc_n(k)) // ": " // str(tab%pc_t_rpod(k), "es9.2") // " s (exact POD " // &
        str(tab%pc_t_exact, "es9.2") // " s), sigma_k " // str(rs%sigma_all(min(tab%pc_n(k), size(rs%sigma_all))), &
        "es10.3") // " vs " // str(ex%sigma_all(min(tab%pc_n(k), size(ex%sigma_all))), "es10.3"))
    end do
  end subroutine pod_compare

  !> Build the pairs of &pairs n / r (default: one pair, all POD modes and the
  !> whole cone, which reuses the enrichment v_full / pga_full already computed).
  subroutine prepare_pairs(data_ref, phi, scone, v_full, pga_full, pairs, error)
    type(offline_data_t), intent(in) :: data_ref
    real(wp), intent(in) :: phi(:,:)
    type(sparse_cone_t), intent(in) :: scone
    real(wp), intent(in) :: v_full(:,:)
    type(pga_result_t), intent(in) :: pga_full
    type(rom_pair_t), allocatable, intent(out) :: pairs(:)
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: nn(:), rr(:)
    integer :: k
    character(len=:), allocatable :: line
    call log%progress_start()
    nn = pack(ocfg%rom_n, ocfg%rom_n > 0)
    rr = pack(ocfg%rom_r, ocfg%rom_n > 0)
    if (size(nn) == 0) then
      nn = [size(phi, 2)]; rr = [scone%r]
    end if
    allocate(pairs(size(nn)))
    do k = 1, size(nn)
      if (nn(k) > size(phi, 2)) then
        call set_error(error, cli%input // ": &pairs: n(" // str(k) // ") = " // str(nn(k)) // &
          " exceeds the " // str(size(phi, 2)) // " POD modes kept (&pod n / energy)", 2); return
      end if
      if (rr(k) > scone%r) then
        call set_error(error, cli%input // ": &pairs: r(" // str(k) // ") = " // str(rr(k)) // &
          " exceeds the " // str(scone%r) // " cone vectors built (&cone r_max / delta)", 2); return
      end if
      call log%progress("pair", k, size(nn))
      if (nn(k) == size(phi, 2) .and. rr(k) == scone%r) then
        ! the full enrichment is already computed
        call build_pair(env, data_ref, phi, nn(k), scone, rr(k), .false., ocfg%pga_delta, ocfg%pga_max_add, &
          ocfg%hyper, ocfg%hyper_m_factor, ocfg%eq_tol, pairs(k), error, v_given=v_full)
        if (allocated(error)) return
        pairs(k)%n_pga = size(v_full, 2) - size(phi, 2)
        pairs(k)%pga_err = pga_full%err
      else
        call build_pair(env, data_ref, phi, nn(k), scone, rr(k), ocfg%pga, ocfg%pga_delta, ocfg%pga_max_add, &
          ocfg%hyper, ocfg%hyper_m_factor, ocfg%eq_tol, pairs(k), error)
        if (allocated(error)) return
      end if
      line = "   pair " // str(k) // ": N = " // str(nn(k)) // ", R = " // str(rr(k)) // ", supremizers " // &
        str(pairs(k)%n_pga) // " (basis " // str(size(pairs(k)%v, 2)) // ")"
      call log%info(line // hyper_summary(pairs(k)))
    end do
  end subroutine prepare_pairs

  !> The note, or an empty string when there is none.
  function note_of(note) result(s)
    character(len=:), allocatable, intent(in) :: note
    character(len=:), allocatable :: s
    s = ""
    if (allocated(note)) s = note
  end function note_of

  !> True on every rank if any rank has an error (the message is kept where it arose;
  !> ranks without one get a generic message so that all stop together).
  logical function collective_fail()
    call env%agree_error(error)
    collective_fail = allocated(error)
  end function collective_fail
end program crowd_offline
