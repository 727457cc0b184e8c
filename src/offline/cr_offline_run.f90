!> The offline stage (what crowd_offline runs): from the snapshot database to the ROM file.
!>
!> One object holds the stage's settings and everything it builds; one call per step:
!> `read_training` (each rank its block of training samples, cr_offline_data), `build_pod`
!> (velocity POD, &pod, and the optional POD / randomized POD comparison), `build_cone`
!> (multiplier cone, &cone: gIS or mCPG, optionally both), `enrich` (supremizers, &pga),
!> `infsup` (reduced inf-sup table, &infsup), `build_pairs` (the reduced models of &pairs with
!> their hyper-reduction, cr_rom_pairs) and `write_rom` (the ROM file, cr_rom_file). Every step
!> is collective, times itself into `tab` and returns the same error on every rank.
module cr_offline_run
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_logger, only: logger_t
  use cr_config, only: config_t, config_echo
  use cr_json, only: json_writer_t
  use cr_offline_config, only: offline_cfg_t, offline_echo
  use cr_offline_data, only: offline_data_t, load_training
  use cr_pod, only: pod_result_t, pod_compute, rsvd_opts_t, pod_rsvd, pod_snapshots
  use cr_cone, only: cone_result_t, gis_build, mcpg_build
  use cr_sparse_cone, only: sparse_cone_t
  use cr_supremizer, only: pga_result_t, pga_enrich
  use cr_infsup_table, only: infsup_table
  use cr_pga_cache, only: pga_cache_t
  use cr_rom_file, only: rom_file_t, rom_tables_t, write_rom_file
  use cr_rom_pairs, only: rom_pair_t, build_pair, hyper_summary, cone_prefix
  use cr_hyper_method, only: points_cap
  use cr_eim, only: eim_t, eim_build
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: offline_run_t

  !> The offline stage: settings, training data and every product of the stage.
  type :: offline_run_t
    !> the input file (starts messages), the model configuration and the offline settings
    character(len=:), allocatable :: input
    type(config_t) :: cfg
    type(offline_cfg_t) :: ocfg
    !> this rank's block of training samples
    type(offline_data_t) :: data
    type(pod_result_t) :: pod
    !> POD modes kept
    integer :: n_pod = 0
    !> velocity basis, POD modes then supremizers (replicated): [n_dof, n_pod + n_added]
    real(wp), allocatable :: v(:,:)
    !> the cone the ROM uses and the comparison cone (&cone compare)
    type(cone_result_t) :: cone, other
    type(sparse_cone_t) :: scone
    type(pga_result_t) :: pga
    !> every enrichment (N, R) computed so far: the main one, the inf-sup table's, the pairs'
    type(pga_cache_t) :: pga_cache
    !> timings and tables stored in the ROM file
    type(rom_tables_t) :: tab
    !> the prepared reduced models (&pairs)
    type(rom_pair_t), allocatable :: pairs(:)
  contains
    procedure :: init
    procedure :: read_training
    procedure :: build_pod
    procedure :: build_cone
    procedure :: enrich
    procedure :: infsup
    procedure :: build_pairs
    procedure :: write_rom
    procedure :: summary_line
    procedure :: add_summary
    procedure :: free
  end type offline_run_t

contains

  !> Keep the input's name and its (validated) configuration.
  subroutine init(this, input, cfg, ocfg)
    class(offline_run_t), intent(inout) :: this
    character(len=*), intent(in) :: input
    type(config_t), intent(in) :: cfg
    type(offline_cfg_t), intent(in) :: ocfg
    call this%free()
    this%input = input
    this%cfg = cfg
    this%ocfg = ocfg
  end subroutine init

  !> Read this rank's block of training samples from the database of &offline.
  subroutine read_training(this, env, log, error)
    class(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: t0
    call log%stage_begin("crowd_offline: read training snapshots")
    t0 = env%wtime()
    call load_training(env, trim(this%ocfg%database), this%cfg, this%data, error)
    call env%agree_error(error)
    if (allocated(error)) return
    this%tab%t_read = env%wtime() - t0
    call log%info("   " // str(this%data%n_train) // " training samples x " // str(this%data%n_steps) // &
      " steps, " // str(this%data%n_dof) // " velocity dofs, " // str(this%data%n_dict) // &
      " contacts in the dictionary, " // str(env%size) // " rank(s)")
    call log%stage_end()
  end subroutine read_training

  !> Velocity POD (&pod method, n or energy); then, if &pod compare_n asks, the timing and
  !> spectra of the exact POD against the randomized POD.
  subroutine build_pod(this, env, log, error)
    class(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    type(rsvd_opts_t) :: rsvd
    real(wp) :: t0, eps
    integer :: nmodes
    associate(ocfg => this%ocfg, data => this%data, pod => this%pod)
      call log%stage_begin("crowd_offline: velocity POD (" // trim(ocfg%pod_method) // ")")
      t0 = env%wtime()
      eps = ocfg%pod_energy
      nmodes = ocfg%pod_n
      if (nmodes > 0 .and. nmodes > data%n_dof) then
        call set_error(error, "&pod: n = " // str(nmodes) // " is larger than the number of velocity " // &
          "dofs (" // str(data%n_dof) // ")", EXIT_BAD_INPUT)
      end if
      call env%agree_error(error)
      if (allocated(error)) return
      rsvd = rsvd_opts_t(ocfg%rsvd_rank, ocfg%rsvd_oversampling, ocfg%rsvd_power, ocfg%rsvd_seed, ocfg%rsvd_sketch)
      if (nmodes > 0) then
        call pod_compute(env, trim(ocfg%pod_method), data%u, pod, error, n_modes=nmodes, rsvd=rsvd)
      else
        call pod_compute(env, trim(ocfg%pod_method), data%u, pod, error, eps=eps, rsvd=rsvd)
      end if
      call env%agree_error(error)
      if (allocated(error)) return
      if (nmodes > 0 .and. pod%n_modes < nmodes) call log%warn("&pod n = " // str(nmodes) // &
        " exceeds the numerical rank of the snapshots: " // str(pod%n_modes) // " modes kept")
      this%tab%t_pod = env%wtime() - t0
      this%n_pod = pod%n_modes
      this%v = pod%phi(:, 1:this%n_pod)
      call log%info("   N = " // str(this%n_pod) // " modes (numerical rank " // str(pod%rank) // &
        ", retained energy " // str(pod%energy) // ")")
      if (this%n_pod == 0) then
        if (.not. (pod%total_energy > 0)) then
          call log%warn("POD: the velocity snapshots are all zero (a crowd at rest): no POD mode")
        else
          call log%warn("POD: &pod energy = " // str(eps) // " keeps no POD mode (1 - retained energy <= " // &
            "energy already with N = 0)")
        end if
      end if
      call log%stage_end()
    end associate
    if (any(this%ocfg%pod_compare_n > 0)) then
      call log%stage_begin("crowd_offline: POD (method of snapshots) vs randomized POD")
      call pod_compare(this, env, log, error)
      call env%agree_error(error)
      if (allocated(error)) return
      call log%stage_end()
    end if
  end subroutine build_pod

  !> Time the exact POD (method of snapshots, all modes) and pod_rsvd for each requested rank.
  subroutine pod_compare(this, env, log, error)
    type(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    type(pod_result_t) :: ex, rs
    real(wp) :: t0
    integer :: k
    associate(ocfg => this%ocfg, tab => this%tab, data => this%data)
      tab%pc_n = pack(ocfg%pod_compare_n, ocfg%pod_compare_n > 0)
      allocate(tab%pc_t_rpod(size(tab%pc_n)))
      t0 = env%wtime()
      call pod_snapshots(env, data%u, ex, error, eps=0.0_wp)
      if (allocated(error)) return
      tab%pc_t_exact = env%wtime() - t0
      tab%pc_sigma_exact = ex%sigma_all
      do k = 1, size(tab%pc_n)
        t0 = env%wtime()
        call pod_rsvd(env, data%u, tab%pc_n(k), ocfg%rsvd_oversampling, ocfg%rsvd_power, &
          trim(ocfg%rsvd_sketch), ocfg%rsvd_seed, rs, error, n_modes=min(tab%pc_n(k), data%n_dof))
        if (allocated(error)) return
        tab%pc_t_rpod(k) = env%wtime() - t0
        if (k == size(tab%pc_n)) tab%pc_sigma_rpod = rs%sigma_all
        call log%info("   rPOD rank " // str(tab%pc_n(k)) // ": " // str(tab%pc_t_rpod(k), "es9.2") // &
          " s (exact POD " // str(tab%pc_t_exact, "es9.2") // " s), sigma_k " // &
          str(rs%sigma_all(min(tab%pc_n(k), size(rs%sigma_all))), "es10.3") // " vs " // &
          str(ex%sigma_all(min(tab%pc_n(k), size(ex%sigma_all))), "es10.3"))
      end do
    end associate
  end subroutine pod_compare

  !> Multiplier cone of &cone method (and the other method too with &cone compare).
  subroutine build_cone(this, env, log, error)
    class(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: t0
    associate(ocfg => this%ocfg, data => this%data, cone => this%cone, other => this%other)
      call log%stage_begin("crowd_offline: multiplier cone (" // trim(ocfg%cone_method) // ")")
      t0 = env%wtime()
      if (ocfg%cone_method == 'gis') then
        call gis_build(env, data%lam, ocfg%cone_delta, ocfg%cone_r_max, cone, error)
      else
        call mcpg_build(env, data%lam, ocfg%cone_delta, ocfg%mcpg_r_max, cone, error)
      end if
      call env%agree_error(error)
      if (allocated(error)) return
      this%tab%t_cone = env%wtime() - t0
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
        call env%agree_error(error)
        if (allocated(error)) return
        this%tab%t_mcpg = env%wtime() - t0
        call log%info("   comparison " // trim(other%method) // ": R = " // str(other%r) // ", e_R = " // &
          str(other%err_max(other%r + 1)) // ", " // str(other%time) // " s")
        if (allocated(other%note)) call log%warn("cone (comparison " // trim(other%method) // "): " // other%note)
      end if
      if (cone%method == 'gis') then
        call this%scone%from_indices(data%n_dict, cone%indices)
      else
        call this%scone%from_dense(cone%psi)
      end if
      call log%stage_end()
    end associate
  end subroutine build_cone

  !> Supremizer enrichment (&pga) of the POD basis for the whole cone; skipped (with a
  !> warning) when the cone is empty.
  subroutine enrich(this, env, log, error)
    class(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: t0
    associate(ocfg => this%ocfg, data => this%data, pga => this%pga)
      if (ocfg%pga .and. this%scone%r > 0) then
        call log%stage_begin("crowd_offline: supremizer enrichment (PGA, delta = " // str(ocfg%pga_delta) // ")")
        t0 = env%wtime()
        call pga_enrich(env, data%scenes, data%scene_of, data%radius, data%dt, data%dict_ia, data%dict_ib, &
          data%dict_ob, this%scone, data%q, data%lam%col_offset, this%v, ocfg%pga_delta, ocfg%pga_max_add, pga, error)
        call env%agree_error(error)
        if (allocated(error)) return
        this%tab%t_pga = env%wtime() - t0
        call this%pga_cache%add(this%n_pod, this%scone%r, this%v, pga)
        call log%info("   added " // str(pga%n_added) // " supremizers; largest projection error " // &
          str(pga%err(1)) // " -> " // str(pga%err(pga%n_added + 1)))
        if (allocated(pga%note)) call log%warn("PGA: " // pga%note)
        call log%stage_end()
      else
        allocate(pga%err(1), pga%chosen(0)); pga%err = 0
        if (ocfg%pga) call log%warn("PGA skipped: the cone is empty, there is no supremizer to add")
      end if
    end associate
    if (size(this%v, 2) == 0) call log%warn("the reduced velocity basis is empty (N = 0): the reduced model " // &
      "can only predict a zero velocity")
  end subroutine enrich

  !> Reduced inf-sup table (&infsup grid).
  subroutine infsup(this, env, log, error)
    class(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: t0
    call log%stage_begin("crowd_offline: reduced inf-sup table")
    t0 = env%wtime()
    call infsup_table(env, log, this%ocfg, this%data, this%pod, this%scone, this%pga_cache, this%tab, error)
    call env%agree_error(error)
    if (allocated(error)) return
    this%tab%t_infsup = env%wtime() - t0
    call log%stage_end()
  end subroutine infsup

  !> Build the pairs of &pairs n / r (default: one pair, all POD modes and the whole cone,
  !> which reuses the enrichment already computed) with their hyper-reduction.
  subroutine build_pairs(this, env, log, error)
    class(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: t0
    call log%stage_begin("crowd_offline: reduced models (pairs N, R; hyper-reduction)")
    t0 = env%wtime()
    call prepare_pairs(this, env, log, this%pod%phi(:, 1:this%n_pod), error)
    call env%agree_error(error)
    if (allocated(error)) return
    this%tab%t_pairs = env%wtime() - t0
    call log%stage_end()
  end subroutine build_pairs

  subroutine prepare_pairs(this, env, log, phi, error)
    type(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    !> the POD modes kept [n_dof, n_pod]
    real(wp), intent(in) :: phi(:,:)
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: nn(:), rr(:), nb(:), hit(:)
    real(wp), allocatable :: t_pga(:), vk(:,:)
    type(eim_t), target :: s1_shared
    type(error_t), allocatable :: s1_error
    type(pga_result_t) :: res
    integer :: k, m_s1
    real(wp) :: t0
    character(len=:), allocatable :: line
    associate(ocfg => this%ocfg, scone => this%scone, pairs => this%pairs)
      call log%progress_start()
      nn = pack(ocfg%rom_n, ocfg%rom_n > 0)
      rr = pack(ocfg%rom_r, ocfg%rom_n > 0)
      if (size(nn) == 0) then
        nn = [size(phi, 2)]; rr = [scone%r]
      end if
      if (allocated(this%pairs)) deallocate(this%pairs)
      allocate(this%pairs(size(nn)), nb(size(nn)), hit(size(nn)), t_pga(size(nn)))
      ! the bases first: every enrichment not yet computed (the main one's and the inf-sup
      ! table's are reused), so that the EIM of s1 can be built once for the largest basis
      t_pga = 0
      do k = 1, size(nn)
        if (nn(k) > size(phi, 2)) then
          call set_error(error, this%input // ": &pairs: n(" // str(k) // ") = " // str(nn(k)) // &
            " exceeds the " // str(size(phi, 2)) // " POD modes kept (&pod n / energy)", EXIT_BAD_INPUT); return
        end if
        if (rr(k) > scone%r) then
          call set_error(error, this%input // ": &pairs: r(" // str(k) // ") = " // str(rr(k)) // &
            " exceeds the " // str(scone%r) // " cone vectors built (&cone r_max / delta)", EXIT_BAD_INPUT); return
        end if
        hit(k) = 0
        nb(k) = nn(k)
        if (ocfg%pga .and. rr(k) > 0) then
          hit(k) = this%pga_cache%find(nn(k), rr(k))
          if (hit(k) == 0) then
            t0 = env%wtime()
            vk = phi(:, 1:nn(k))
            call pga_enrich(env, this%data%scenes, this%data%scene_of, this%data%radius, this%data%dt, &
              this%data%dict_ia, this%data%dict_ib, this%data%dict_ob, cone_prefix(scone, rr(k)), this%data%q, &
              this%data%lam%col_offset, vk, ocfg%pga_delta, ocfg%pga_max_add, res, error)
            if (allocated(error)) then
              call prefix_error(error, "PGA of pair (" // str(nn(k)) // ", " // str(rr(k)) // ")"); return
            end if
            call this%pga_cache%add(nn(k), rr(k), vk, res)
            hit(k) = this%pga_cache%find(nn(k), rr(k))
            t_pga(k) = env%wtime() - t0
          end if
          nb(k) = size(this%pga_cache%entries(hit(k))%v, 2)
        end if
      end do
      ! s1 = v(q) does not depend on the pair: one EIM for the most points any pair keeps,
      ! each pair takes its prefix (bitwise the EIM it would build); if that build fails, each
      ! pair builds its own (and reports its own error)
      m_s1 = 0
      if (ocfg%hyper .and. this%data%n_dof > 0) then
        do k = 1, size(nn)
          m_s1 = max(m_s1, points_cap(nb(k), rr(k), ocfg%hyper_m_factor, 1, this%data%n_dof))
        end do
        call eim_build(env, this%data%v, m_s1, s1_shared, s1_error)
        if (allocated(s1_error)) m_s1 = 0
      end if
      do k = 1, size(nn)
        call log%progress("pair", k, size(nn))
        if (hit(k) > 0) then
          associate(e => this%pga_cache%entries(hit(k)))
            call build_pair(env, this%data, phi, nn(k), scone, rr(k), .false., ocfg%pga_delta, ocfg%pga_max_add, &
              ocfg%hyper, ocfg%hyper_m_factor, ocfg%eq_tol, this%pairs(k), error, v_given=e%v, &
              s1_shared=s1_shared, s1_shared_m=m_s1)
            if (allocated(error)) return
            this%pairs(k)%n_pga = e%res%n_added
            this%pairs(k)%pga_err = e%res%err
          end associate
        else if (nn(k) == size(phi, 2) .and. rr(k) == scone%r) then
          ! no PGA here (off, or an empty cone): the main basis, the POD modes alone
          call build_pair(env, this%data, phi, nn(k), scone, rr(k), .false., ocfg%pga_delta, ocfg%pga_max_add, &
            ocfg%hyper, ocfg%hyper_m_factor, ocfg%eq_tol, this%pairs(k), error, v_given=this%v, &
            s1_shared=s1_shared, s1_shared_m=m_s1)
          if (allocated(error)) return
          this%pairs(k)%n_pga = size(this%v, 2) - size(phi, 2)
          this%pairs(k)%pga_err = this%pga%err
        else
          call build_pair(env, this%data, phi, nn(k), scone, rr(k), .false., ocfg%pga_delta, ocfg%pga_max_add, &
            ocfg%hyper, ocfg%hyper_m_factor, ocfg%eq_tol, this%pairs(k), error, &
            s1_shared=s1_shared, s1_shared_m=m_s1)
          if (allocated(error)) return
        end if
        this%pairs(k)%t_pga = t_pga(k)
        line = "   pair " // str(k) // ": N = " // str(nn(k)) // ", R = " // str(rr(k)) // ", supremizers " // &
          str(this%pairs(k)%n_pga) // " (basis " // str(size(this%pairs(k)%v, 2)) // ")"
        call log%info(line // hyper_summary(this%pairs(k)))
      end do
    end associate
  end subroutine prepare_pairs

  !> Write the ROM file of &offline (rank 0), with the effective configuration.
  subroutine write_rom(this, env, log, error)
    class(offline_run_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(logger_t), intent(inout) :: log
    type(error_t), allocatable, intent(out) :: error
    type(rom_file_t) :: rom
    call log%stage_begin("crowd_offline: write " // trim(this%ocfg%rom_file))
    if (env%is_root()) then
      rom%config = config_echo(this%cfg) // offline_echo(this%ocfg)
      rom%database = trim(this%ocfg%database); rom%db_hash = this%data%config_hash
      rom%n_agents = this%data%n_agents; rom%n_steps = this%data%n_steps
      rom%radius = this%data%radius; rom%dt = this%data%dt
      rom%study_config = this%data%config_text; rom%param_names = this%data%param_names
      rom%q0 = this%data%q0
      rom%pod_method = this%pod%method; rom%pod_rank = this%pod%rank
      rom%pod_total_energy = this%pod%total_energy
      rom%pod_sigma = this%pod%sigma_all
      rom%v = this%v; rom%n_pod = this%n_pod
      rom%cone = this%cone; rom%cone_other = this%other
      rom%pga_err = this%pga%err
      rom%dict_ia = this%data%dict_ia; rom%dict_ib = this%data%dict_ib; rom%dict_ob = this%data%dict_ob
      rom%tables = this%tab
      call write_rom_file(trim(this%ocfg%rom_file), rom, this%pairs, error)
    end if
    call env%agree_error(error)
    if (allocated(error)) return
    call log%stage_end()
  end subroutine write_rom

  !> One line: basis sizes and the stages' times.
  function summary_line(this) result(s)
    class(offline_run_t), intent(in) :: this
    character(len=:), allocatable :: s
    s = "summary: N_pod = " // str(this%n_pod) // ", N (with supremizers) = " // str(size(this%v, 2)) // &
      ", R = " // str(this%cone%r) // ", times: read " // str(this%tab%t_read) // " s, POD " // &
      str(this%tab%t_pod) // " s, cone " // str(this%tab%t_cone) // " s, PGA " // str(this%tab%t_pga) // &
      " s, inf-sup " // str(this%tab%t_infsup) // " s"
  end function summary_line

  !> Add the stage's figures (ROM file, ranks, bases, cone, PGA, notes, times) to a JSON summary.
  subroutine add_summary(this, env, js)
    class(offline_run_t), intent(in) :: this
    type(env_t), intent(in) :: env
    type(json_writer_t), intent(inout) :: js
    call js%add("rom_file", trim(this%ocfg%rom_file))
    call js%add("ranks", env%size)
    call js%add("n_pod", this%n_pod)
    call js%add("pod_numerical_rank", this%pod%rank)
    call js%add("pod_energy_retained", this%pod%energy)
    call js%add("n_total", size(this%v, 2))
    call js%add("r", this%cone%r)
    call js%add("cone_method", trim(this%cone%method))
    call js%add("cone_error", this%cone%err_max(this%cone%r + 1))
    call js%add("pga_added", this%pga%n_added)
    call js%add("pga_error", this%pga%err(this%pga%n_added + 1))
    call js%add("cone_note", note_of(this%cone%note))
    ! the comparison cone's note (e.g. mCPG stopped at the accuracy of its projections); "" if none
    call js%add("cone_comparison_note", note_of(this%other%note))
    call js%add("pga_note", note_of(this%pga%note))
    call js%add("time_read", this%tab%t_read)
    call js%add("time_pod", this%tab%t_pod)
    call js%add("time_cone", this%tab%t_cone)
    call js%add("time_cone_comparison", this%tab%t_mcpg)
    call js%add("time_pga", this%tab%t_pga)
    call js%add("time_infsup", this%tab%t_infsup)
  end subroutine add_summary

  !> Release everything built.
  subroutine free(this)
    class(offline_run_t), intent(inout) :: this
    type(offline_data_t) :: d0
    type(pod_result_t) :: p0
    type(cone_result_t) :: c0
    type(sparse_cone_t) :: s0
    type(pga_result_t) :: g0
    type(rom_tables_t) :: t0
    this%data = d0; this%pod = p0; this%cone = c0; this%other = c0; this%scone = s0; this%pga = g0
    this%tab = t0
    call this%pga_cache%free()
    this%n_pod = 0
    if (allocated(this%v)) deallocate(this%v)
    if (allocated(this%pairs)) deallocate(this%pairs)
  end subroutine free

  !> The note, or an empty string when there is none.
  function note_of(note) result(s)
    character(len=:), allocatable, intent(in) :: note
    character(len=:), allocatable :: s
    s = ""
    if (allocated(note)) s = note
  end function note_of
end module cr_offline_run
