!> The QoI product (schema crowdrom-qoi, version 1) and the QoI group: write three queries' QoIs
!> (two exits, one query censored, one with an undefined flow), read them back and compare every
!> field exactly; rows that differ in size or a product whose columns disagree are refused and
!> leave no file; a product of another schema version and a file whose curve was edited after
!> writing (checksum) are refused with a message naming the file and the dataset.
program test_qoi_file
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_fsys, only: file_exists, remove_file
  use cr_h5file, only: h5file_t
  use cr_config, only: scene_cfg_t
  use cr_obstacles, only: obstacles_cfg_t
  use cr_scene, only: scene_t
  use cr_qoi, only: qoi_t, compute_qoi
  use cr_qoi_file, only: qoi_product_t, write_qoi_product, read_qoi_product, write_qoi_group, read_qoi_group, &
    QOI_SCHEMA_VERSION
    use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  integer, parameter :: nt = 30, na = 6
  real(wp), parameter :: h = 0.1_wp, radius = 0.04_wp
  type(scene_t) :: scene
  type(scene_cfg_t) :: sc
  type(error_t), allocatable :: error
  type(qoi_product_t) :: p, r
  integer :: k, status
  character(len=4096) :: dir

  status = remove_file("qoi_rt.h5"); status = remove_file("qoi_bad.h5"); status = remove_file("qoi_v.h5")
  sc%hall_length = 2.0_wp; sc%hall_width = 1.0_wp; sc%l_exit = 0.4_wp; sc%wall_thickness = 0.1_wp
  sc%l_exit2 = 0.3_wp
  call scene%init(sc, obstacles_cfg_t(), error)
  call check(.not. allocated(error), "scene")
  allocate(p%qoi(3))
  do k = 1, 3
    call compute_qoi(scene, radius, h, walkers(0.007_wp * k), p%qoi(k), error)
    call check(.not. allocated(error), "compute_qoi")
  end do
  call check(p%qoi(1)%censored(3) .and. .not. p%qoi(3)%censored(3) .and. p%qoi(3)%flow_defined(1), &
    "the rows cover a censored time and a defined flow")
  p%program = "test_qoi_file"; p%model = "rom setting 2"; p%config = "&rom n = 5 /"; p%param_names = "l_exit,speed"
  p%radius = radius; p%dt = h
  p%params = reshape([0.3_wp, 1.0_wp, 0.31_wp, 1.1_wp, 0.5_wp, 0.9_wp], [2, 3])
  p%outside_box = [.false., .false., .true.]
  p%cpu_seconds = [1.5e-3_wp, 2.5e-3_wp, acos(-1.0_wp)]
  call write_qoi_product("qoi_rt.h5", p, error)
  call check(.not. allocated(error), "write the product")
  call check(file_exists("qoi_rt.h5") .and. .not. file_exists("qoi_rt.h5.partial"), "committed, no temporary")
  call read_qoi_product("qoi_rt.h5", r, error)
  call check(.not. allocated(error), "read the product back")
  if (.not. allocated(error)) call compare()
  call test_refusals()
  status = remove_file("qoi_rt.h5"); status = remove_file("qoi_v.h5")
  ! with a directory argument: the product is left there as qoi_keep.h5 (read by scripts/tests/test_qoi.py)
  if (command_argument_count() > 0) then
    call get_command_argument(1, dir)
    call write_qoi_product(trim(dir) // "/qoi_keep.h5", p, error)
    call check(.not. allocated(error), "write the product to keep")
  end if
  call test_summary()

contains

  !> Agent i walks up through the top exit (odd i) or right through the right exit (even i) at
  !> speed s per step, from 0.25 i away from its line: [2 na, nt + 1].
  function walkers(s) result(q)
    real(wp), intent(in) :: s
    real(wp) :: q(2 * na, nt + 1)
    integer :: i, c
    do c = 0, nt
      do i = 1, na
        if (mod(i, 2) == 1) then
          q(2*i-1:2*i, c + 1) = [0.9_wp + 0.03_wp * i, scene%y_out(radius) - 0.05_wp * i + c * s]
        else
          q(2*i-1:2*i, c + 1) = [scene%length + scene%wall + radius - 0.05_wp * i + c * s, 0.42_wp + 0.01_wp * i]
        end if
      end do
    end do
  end function walkers

  subroutine compare()
    logical :: same
    integer :: j
    call check(r%program == p%program .and. r%model == p%model .and. r%config == p%config .and. &
      r%param_names == p%param_names .and. r%radius == p%radius .and. r%dt == p%dt, "root attributes")
    call check(all(r%params == p%params) .and. all(r%outside_box .eqv. p%outside_box) .and. &
      all(r%cpu_seconds == p%cpu_seconds), "parameters, flags, CPU seconds")
    same = size(r%qoi) == 3
    do j = 1, min(3, size(r%qoi))
      associate (a => p%qoi(j), b => r%qoi(j))
        same = same .and. a%n_agents == b%n_agents .and. a%n_steps == b%n_steps .and. a%n_exits == b%n_exits .and. &
          a%h == b%h .and. all(a%curve == b%curve) .and. lbound(b%curve, 1) == 0 .and. &
          all(a%curve_total == b%curve_total) .and. all(a%t_evac == b%t_evac) .and. &
          all(a%censored .eqv. b%censored) .and. all(a%width == b%width) .and. all(a%flow_rate == b%flow_rate) .and. &
          all(a%flow == b%flow) .and. all(a%flow_defined .eqv. b%flow_defined) .and. &
          a%overlap_aa == b%overlap_aa .and. a%overlap_aw == b%overlap_aw .and. a%n_through == b%n_through .and. &
          a%displacement == b%displacement
      end associate
    end do
    call check(same, "every QoI of every row equal bit for bit")
  end subroutine compare

  subroutine test_refusals()
    type(qoi_product_t) :: b
    type(qoi_t), allocatable :: rows(:)
    type(h5file_t) :: f
    real(wp) :: full(2 * na, nt + 1)
    ! rows of different lengths
    b = p
    full = walkers(0.1_wp)
    call compute_qoi(scene, radius, h, full(:, 1:5), b%qoi(2), error)
    call write_qoi_product("qoi_bad.h5", b, error)
    call check(allocated(error), "rows of different lengths refused")
    if (allocated(error)) call check(index(error%message, "row 2") > 0, "the message names the row")
    call check(.not. file_exists("qoi_bad.h5") .and. .not. file_exists("qoi_bad.h5.partial"), "and nothing written")
    ! columns that disagree
    b = p
    b%cpu_seconds = [1.0_wp]
    call write_qoi_product("qoi_bad.h5", b, error)
    call check(allocated(error) .and. .not. file_exists("qoi_bad.h5"), "3 rows with 1 CPU time refused, nothing written")
    ! another schema version
    call write_qoi_product("qoi_v.h5", p, error)
    call f%open("qoi_v.h5", error, readwrite=.true.)
    call check(.not. allocated(error), "reopen")
    call f%write_attr("/", "schema_version", QOI_SCHEMA_VERSION + 1, error)
    call f%close(error)
    call read_qoi_product("qoi_v.h5", b, error)
    call check(allocated(error), "another schema version refused")
    if (allocated(error)) call check(index(error%message, "qoi_v.h5") > 0 .and. error%code == EXIT_BAD_INPUT, &
      "input error naming the file")
    ! a QoI group whose curve was changed after its checksum: rewrite the group with other data
    ! under the old checksum
    call f%create("qoi_bad.h5", error)
    call write_qoi_group(f, "qoi", p%qoi, error)
    call check(.not. allocated(error), "write a group")
    call f%commit(error)
    call f%open("qoi_bad.h5", error, readwrite=.true.)
    call f%write_attr("qoi/curve_total", "checksum", "0000000000000000", error)
    call f%close(error)
    call f%open("qoi_bad.h5", error)
    call read_qoi_group(f, "qoi_bad.h5", "qoi", rows, error)
    call check(allocated(error), "a checksum mismatch refused")
    if (allocated(error)) call check(index(error%message, "curve_total") > 0, "the message names the dataset")
    call f%close(error)
    status = remove_file("qoi_bad.h5")
  end subroutine test_refusals
end program test_qoi_file
