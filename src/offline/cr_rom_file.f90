!> The ROM file written by crowd_offline (schema "crowdrom-rom", version 1; see README):
!> velocity bases, multiplier cone, contact dictionary, the data of the offline figures.
module cr_rom_file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, prefix_error
  use cr_h5file, only: h5file_t
  use cr_pod, only: pod_result_t
  use cr_cone, only: cone_result_t
  use cr_supremizer, only: pga_result_t
  use cr_rom_pairs, only: rom_pair_t, write_pair
  use cr_strings, only: str
  implicit none
  private
  public :: rom_tables_t, write_rom_file, ROM_SCHEMA, ROM_SCHEMA_VERSION

  character(len=*), parameter :: ROM_SCHEMA = "crowdrom-rom"
  !> 2: prepared pairs (/pairs/<k>) with their hyper-reduction
  integer, parameter :: ROM_SCHEMA_VERSION = 2

  !> Inf-sup table and timings gathered by the driver.
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

contains

  !> Write the ROM file (rank 0 only; temporary name + rename).
  subroutine write_rom_file(path, attrs_config, database, db_hash, n_agents, n_steps, radius, dt, &
      pod, v, n_pod, cone, cone_other, pga, dict_ia, dict_ib, dict_ob, tables, pairs, error)
    character(len=*), intent(in) :: path, attrs_config, database, db_hash
    integer, intent(in) :: n_agents, n_steps
    real(wp), intent(in) :: radius, dt
    type(pod_result_t), intent(in) :: pod
    real(wp), intent(in) :: v(:,:)
    integer, intent(in) :: n_pod
    type(cone_result_t), intent(in) :: cone, cone_other
    type(pga_result_t), intent(in) :: pga
    integer, intent(in) :: dict_ia(:), dict_ib(:), dict_ob(:)
    type(rom_tables_t), intent(in) :: tables
    !> the reduced models prepared for crowd_rom
    type(rom_pair_t), intent(in) :: pairs(:)
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    integer :: k
    call h5%create(path, error)
    if (allocated(error)) return
    call h5%write_attr("/", "schema", ROM_SCHEMA, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "schema_version", ROM_SCHEMA_VERSION, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "program", "crowd_offline", error); if (allocated(error)) goto 9
    call h5%write_attr("/", "config", attrs_config, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "database", database, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "database_config_hash", db_hash, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_agents", n_agents, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "n_steps", n_steps, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "agent_radius", radius, error); if (allocated(error)) goto 9
    call h5%write_attr("/", "dt", dt, error); if (allocated(error)) goto 9
    ! POD
    call h5%make_group("pod", error); if (allocated(error)) goto 9
    call h5%write_attr("pod", "method", pod%method, error); if (allocated(error)) goto 9
    call h5%write_attr("pod", "numerical_rank", pod%rank, error); if (allocated(error)) goto 9
    call h5%write_attr("pod", "total_energy", pod%total_energy, error); if (allocated(error)) goto 9
    call h5%write("pod/sigma", pod%sigma_all, error); if (allocated(error)) goto 9
    ! velocity basis: POD modes then supremizers
    call h5%make_group("basis", error); if (allocated(error)) goto 9
    call h5%write("basis/v", v, error); if (allocated(error)) goto 9
    call h5%write_attr("basis", "n_pod", n_pod, error); if (allocated(error)) goto 9
    call h5%write_attr("basis", "n_pga", size(v, 2) - n_pod, error); if (allocated(error)) goto 9
    ! cones
    call write_cone("cone", cone); if (allocated(error)) goto 9
    if (cone_other%method /= '') then
      call write_cone("cone_" // trim(cone_other%method), cone_other); if (allocated(error)) goto 9
    end if
    ! PGA history
    call h5%make_group("pga", error); if (allocated(error)) goto 9
    call h5%write("pga/err", pga%err, error); if (allocated(error)) goto 9
    ! dictionary
    call h5%make_group("contacts", error); if (allocated(error)) goto 9
    call h5%write("contacts/ia", dict_ia, error); if (allocated(error)) goto 9
    call h5%write("contacts/ib", dict_ib, error); if (allocated(error)) goto 9
    call h5%write("contacts/ob", dict_ob, error); if (allocated(error)) goto 9
    ! inf-sup table
    call h5%make_group("infsup", error); if (allocated(error)) goto 9
    if (size(tables%is_n) > 0) then
      call h5%write("infsup/n", tables%is_n, error); if (allocated(error)) goto 9
      call h5%write("infsup/r", tables%is_r, error); if (allocated(error)) goto 9
      call h5%write("infsup/gamma_low_min", tables%is_low_min, error); if (allocated(error)) goto 9
      call h5%write("infsup/gamma_up_min", tables%is_up_min, error); if (allocated(error)) goto 9
      call h5%write("infsup/gamma_up_mean", tables%is_up_mean, error); if (allocated(error)) goto 9
      call h5%write("infsup/gamma_low_min_pga", tables%is_low_min_pga, error); if (allocated(error)) goto 9
      call h5%write("infsup/gamma_up_min_pga", tables%is_up_min_pga, error); if (allocated(error)) goto 9
      call h5%write("infsup/gamma_up_mean_pga", tables%is_up_mean_pga, error); if (allocated(error)) goto 9
      call h5%write("infsup/n_pga", tables%is_n_pga, error); if (allocated(error)) goto 9
    end if
    call h5%make_group("timing", error); if (allocated(error)) goto 9
    call h5%write_attr("timing", "read", tables%t_read, error); if (allocated(error)) goto 9
    call h5%write_attr("timing", "pod", tables%t_pod, error); if (allocated(error)) goto 9
    call h5%write_attr("timing", "cone", tables%t_cone, error); if (allocated(error)) goto 9
    call h5%write_attr("timing", "cone_other", tables%t_mcpg, error); if (allocated(error)) goto 9
    call h5%write_attr("timing", "pga", tables%t_pga, error); if (allocated(error)) goto 9
    call h5%write_attr("timing", "infsup", tables%t_infsup, error); if (allocated(error)) goto 9
    call h5%write_attr("timing", "pairs", tables%t_pairs, error); if (allocated(error)) goto 9
    if (allocated(tables%pc_n)) then
      if (size(tables%pc_n) > 0) then
        call h5%make_group("pod_compare", error); if (allocated(error)) goto 9
        call h5%write("pod_compare/n", tables%pc_n, error); if (allocated(error)) goto 9
        call h5%write("pod_compare/t_rpod", tables%pc_t_rpod, error); if (allocated(error)) goto 9
        call h5%write("pod_compare/t_exact", [(tables%pc_t_exact, k = 1, size(tables%pc_n))], error)
        if (allocated(error)) goto 9
        call h5%write("pod_compare/sigma_exact", tables%pc_sigma_exact, error); if (allocated(error)) goto 9
        call h5%write("pod_compare/sigma_rpod", tables%pc_sigma_rpod, error); if (allocated(error)) goto 9
      end if
    end if
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

  contains

    subroutine write_cone(g, c)
      character(len=*), intent(in) :: g
      type(cone_result_t), intent(in) :: c
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
  end subroutine write_rom_file
end module cr_rom_file
