!> The full-order writer's buffer of output states (cr_fom_file): one run of a small crowd
!> with contacts is written by several writers at once, holding 1 state (every state goes to
!> the file at once, as before the buffer), 3 and 5 states (12 output states: a multiple of 3,
!> so close finds the buffer empty, but not of 5, so the last flush is a partial one at close),
!> more states than the run has, and the default budget; with and without multipliers. Each file must hold exactly the states
!> recorded in memory during the run (steps, times, positions, velocities, desired velocities,
!> inside flags, active multipliers and their offsets), and the files must be equal.
!> Then the atomic-output guarantees with states still in the buffer: abort leaves neither the
!> final name nor a temporary and keeps a previous file; write_step on a closed writer fails.
program test_fom_buffer
  use mpi_f08, only: MPI_Init, MPI_Finalize, MPI_COMM_SELF
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_assert, only: check, test_summary
  use cr_fsys, only: file_exists, remove_file
  use cr_config, only: config_t, read_config
  use cr_fom, only: fom_t, step_record_t
  use cr_fom_file, only: fom_writer_t, fom_file_t, read_fom_file
  implicit none
  !> steps of the run (n_steps + 1 = 12 output states)
  integer, parameter :: NT = 11
  !> writers: buffer sizes (0: the default budget) and whether they store multipliers
  integer, parameter :: NW = 6
  integer, parameter :: BUF(NW) = [1, 3, 5, 1000, 0, 5]
  logical, parameter :: MULT(NW) = [.true., .true., .true., .true., .true., .false.]
  type(env_t) :: self
  type(error_t), allocatable :: error
  type(config_t) :: cfg, cfg_nomult
  type(fom_t) :: fom
  type(fom_writer_t) :: w(NW)
  type(step_record_t) :: recs(NT)
  type(fom_file_t) :: f
  !> the states as they were written [2 n_agents, NT + 1], [n_agents, NT + 1], [NT + 1]
  real(wp), allocatable :: q(:,:), u(:,:), v(:,:)
  integer, allocatable :: inside(:,:), steps(:)
  !> active multipliers in output order and their offsets [NT + 2]
  integer, allocatable :: ia(:), ib(:), ob(:)
  real(wp), allocatable :: lam(:)
  integer(i8), allocatable :: off(:)
  integer :: ierr, k, j, status
  character(len=:), allocatable :: path

  call MPI_Init(ierr)
  call self%init(MPI_COMM_SELF, error)
  call write_input("fom_buffer.nml", .true.)
  call read_config("fom_buffer.nml", self, cfg, error); call check(.not. allocated(error), "config")
  call write_input("fom_buffer_nomult.nml", .false.)
  call read_config("fom_buffer_nomult.nml", self, cfg_nomult, error); call check(.not. allocated(error), "config")
  call fom%init(cfg, error); call check(.not. allocated(error), "fom init")
  if (allocated(error)) call test_summary()

  allocate(q(2 * fom%n_agents, NT + 1), u(2 * fom%n_agents, NT + 1), v(2 * fom%n_agents, NT + 1), &
    inside(fom%n_agents, NT + 1), steps(NT + 1), off(NT + 2), ia(0), ib(0), ob(0), lam(0))
  off(1) = 0
  do j = 1, NW
    path = "fom_buffer_" // str(j) // ".h5"
    status = remove_file(path)
    if (MULT(j)) then
      call open_writer(w(j), path, cfg)
    else
      call open_writer(w(j), path, cfg_nomult)
    end if
    call check(.not. allocated(error), "writer " // str(j) // " (buffer " // str(BUF(j)) // "): open")
  end do
  call record(1)
  do k = 1, NT
    call fom%advance(recs(k), error); call check(.not. allocated(error), "advance " // str(k))
    do j = 1, NW
      call w(j)%write_step(fom, error)
      call check(.not. allocated(error), "writer " // str(j) // ": write_step " // str(k))
    end do
    call record(k + 1)
    if (k == 5) then
      ! states still buffered are not in any file yet, and nothing is under a final name
      call check(.not. file_exists("fom_buffer_5.h5") .and. file_exists("fom_buffer_5.h5.partial"), &
        "before close: only the temporary exists")
    end if
  end do
  call check(size(lam) > 20, "the run has active multipliers (" // str(size(lam)) // ")")
  do j = 1, NW
    call w(j)%close(recs, error)
    call check(.not. allocated(error), "writer " // str(j) // ": close")
  end do

  do j = 1, NW
    path = "fom_buffer_" // str(j) // ".h5"
    call check(.not. file_exists(path // ".partial"), "writer " // str(j) // ": no temporary after close")
    call read_fom_file(path, f, error)
    call check(.not. allocated(error), "writer " // str(j) // ": read back")
    if (allocated(error)) then
      print '(a)', "   " // error%message; cycle
    end if
    call compare(f, j)
    status = remove_file(path)
  end do

  call abort_cases()
  status = remove_file("fom_buffer.nml"); status = remove_file("fom_buffer_nomult.nml")
  call self%free()
  call MPI_Finalize(ierr)
  call test_summary()

contains

  !> A congested little room: 24 agents of radius 0.05 in 0.8 x 0.6, so contacts are active.
  subroutine write_input(file, store)
    character(len=*), intent(in) :: file
    logical, intent(in) :: store
    integer :: un
    open(newunit=un, file=file, status='replace', action='write')
    write(un, '(a)') "&scene hall_length = 0.8, hall_width = 0.6, l_exit = 0.15, wall_thickness = 0.05 /"
    write(un, '(a)') "&agents n_agents = 24, radius = 0.05, speed = 2.0, seed = 7 /"
    write(un, '(a)') "&time dt = 0.01, n_steps = " // str(NT) // " /"
    write(un, '(a)') "&solver name = 'sparse_active_set', tol = 1.0e-10 /"
    write(un, '(a)') "&output store_multipliers = " // merge(".true. ", ".false.", store) // " /"
    close(un)
  end subroutine write_input

  subroutine open_writer(wr, path, c)
    type(fom_writer_t), intent(inout) :: wr
    character(len=*), intent(in) :: path
    type(config_t), intent(in) :: c
    if (BUF(j) > 0) then
      call wr%open(path, c, fom, error, buffer_steps=BUF(j))
    else
      call wr%open(path, c, fom, error)
    end if
  end subroutine open_writer

  !> Keep output state c (the fom's current state) as the writers must have stored it.
  subroutine record(c)
    integer, intent(in) :: c
    integer :: l
    steps(c) = fom%step
    q(:, c) = fom%q; u(:, c) = fom%u; v(:, c) = fom%v
    inside(:, c) = merge(1, 0, fom%inside)
    if (fom%step > 0) then
      do l = 1, fom%cs%n
        if (fom%lambda(l) > 0) then
          ia = [ia, fom%cs%ia(l)]; ib = [ib, fom%cs%ib(l)]; ob = [ob, fom%cs%ob(l)]; lam = [lam, fom%lambda(l)]
        end if
      end do
    end if
    off(c + 1) = size(lam)
  end subroutine record

  !> File of writer jw against the recorded states (exact equality: the same bits).
  subroutine compare(ff, jw)
    type(fom_file_t), intent(in) :: ff
    integer, intent(in) :: jw
    character(len=:), allocatable :: name
    name = "writer " // str(jw) // " (buffer " // str(BUF(jw)) // "): "
    call check(ff%n_out == NT + 1, name // "output count " // str(ff%n_out))
    if (ff%n_out /= NT + 1) return
    call check(all(ff%step == steps), name // "steps")
    call check(all(ff%time == steps * fom%dt), name // "times")
    call check(all(ff%q == q), name // "positions")
    call check(all(ff%u == u), name // "velocities")
    call check(all(ff%v == v), name // "desired velocities")
    call check(all(ff%inside == inside), name // "inside flags")
    call check(size(ff%iterations) == NT .and. size(ff%kkt) == NT, name // "statistics")
    if (MULT(jw)) then
      call check(all(ff%offset == off), name // "multiplier offsets")
      call check(size(ff%lambda) == size(lam), name // "multiplier count " // str(size(ff%lambda)))
      if (size(ff%lambda) /= size(lam)) return
      call check(all(ff%ia == ia) .and. all(ff%ib == ib) .and. all(ff%ob == ob), name // "multiplier identities")
      call check(all(ff%lambda == lam), name // "multiplier values")
    else
      call check(all(ff%offset == 0) .and. size(ff%lambda) == 0, name // "no multipliers")
    end if
  end subroutine compare

  !> Abort with states in the buffer (and after a flush): no file under the final name, no
  !> temporary, a previous file untouched; write_step after the abort is an error.
  subroutine abort_cases()
    type(fom_writer_t) :: wa
    type(fom_t) :: g, g2
    integer :: un, ios, kk
    character(len=32) :: line
    call g%init(cfg, error); call check(.not. allocated(error), "abort: fom init")
    status = remove_file("fom_buffer_abort.h5")
    call wa%open("fom_buffer_abort.h5", cfg, g, error, buffer_steps=2)
    call check(.not. allocated(error), "abort: open")
    do kk = 1, 4
      call g%advance(recs(kk), error)
      call wa%write_step(g, error)
    end do
    call check(.not. allocated(error), "abort: write_step (flushes after 2 states)")
    call wa%abort()
    call check(.not. file_exists("fom_buffer_abort.h5") .and. .not. file_exists("fom_buffer_abort.h5.partial"), &
      "abort: neither the final name nor a temporary")
    call wa%write_step(g, error)
    call check(allocated(error), "abort: write_step after abort is an error")
    ! a previous result survives an aborted run
    open(newunit=un, file="fom_buffer_abort.h5", status='replace', action='write')
    write(un, '(a)') "precious"
    close(un)
    call g2%init(cfg, error)
    call wa%open("fom_buffer_abort.h5", cfg, g2, error)
    call g2%advance(recs(1), error)
    call wa%write_step(g2, error)
    call wa%abort()
    open(newunit=un, file="fom_buffer_abort.h5", status='old', action='read', iostat=ios)
    line = ""
    if (ios == 0) then
      read(un, '(a)', iostat=ios) line
      close(un)
    end if
    call check(ios == 0 .and. line == "precious" .and. .not. file_exists("fom_buffer_abort.h5.partial"), &
      "abort: the previous file is untouched and no temporary is left")
    status = remove_file("fom_buffer_abort.h5")
  end subroutine abort_cases
end program test_fom_buffer
