!> HDF5 output of a full-order run (schema "crowdrom-fom", version 1; docs/file-formats.md), written
!> by crowd_fom (`fom_writer_t`) and read back by `read_fom_file` (tests, tools), which accepts the
!> versions in FOM_VERSIONS_READ and validates shapes, contact identities and finiteness. The scene
!> group (`write_scene`) is shared with the snapshot database.
!>
!> The file is written under a temporary name and renamed when complete (cr_h5file), so an
!> interrupted or failed run never leaves a file that looks finished and never destroys a
!> previous result. Trajectories are streamed (extendible datasets); per-step statistics
!> are written at the end. Multipliers are stored sparse: identity (ia, ib, ob) + value
!> of every row with lambda > 0, with offsets per output step.
!>
!> Output states are buffered: `write_step` copies the state into memory, and the buffer goes
!> to the file as one hyperslab per dataset when it holds `buffer_steps` states (default: as
!> many as fit BUFFER_BYTES, at most the run's output count), when its multipliers bring it
!> past BUFFER_BYTES, and at `close` (before the statistics and the commit). Appending one
!> state per dataset and step cost about as much as the solver (HDF5 opens, extends, selects
!> and writes a tiny hyperslab each time); the file is the same. A failure (a flush that
!> fails, a run that stops) ends with `abort`: the temporary, with whatever was flushed, is
!> deleted and the final name is untouched, exactly as without the buffer.
module cr_fom_file
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, prefix_error, set_error
  use cr_config, only: config_t, config_echo
  use cr_fom_state, only: fom_state_t, step_record_t
  use cr_scene, only: scene_t
  use cr_pdda_file, only: exit_segments
  use cr_h5file, only: h5file_t, cr_h5_real, cr_h5_int, cr_h5_int64
  use cr_strings, only: str
  use cr_grow, only: grow_kept_int, grow_kept_real
  use cr_product_check, only: check_schema, need_finite, need_range, need_dims, product_error
  use cr_qoi, only: qoi_t
  use cr_qoi_file, only: write_qoi_group
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: fom_writer_t, fom_file_t, read_fom_file, write_scene, FOM_SCHEMA, FOM_SCHEMA_VERSION, FOM_VERSIONS_READ

  character(len=*), parameter :: FOM_SCHEMA = "crowdrom-fom"
  integer, parameter :: FOM_SCHEMA_VERSION = 1
  !> versions the reader accepts
  integer, parameter :: FOM_VERSIONS_READ(1) = [1]
  !> memory budget of the writer's buffer of output states (bytes)
  integer(i8), parameter :: BUFFER_BYTES = 4194304_i8
  !> bytes of one buffered multiplier (ia, ib, ob, lambda)
  integer(i8), parameter :: CONTACT_BYTES = 3 * 4 + 8

  !> A full-order run as read back (n_out output states, nnz stored multipliers).
  type :: fom_file_t
    character(len=:), allocatable :: path, solver, config
    integer :: n_agents = 0, n_out = 0
    real(wp) :: radius = 0, dt = 0
    !> reference speeds and initial positions [n_agents], [2 n_agents]
    real(wp), allocatable :: speed(:), q0(:)
    !> output steps and times [n_out]
    integer, allocatable :: step(:)
    real(wp), allocatable :: time(:)
    !> positions, velocities, desired velocities [2 n_agents, n_out]; inside flags [n_agents, n_out]
    real(wp), allocatable :: q(:,:), u(:,:), v(:,:)
    integer, allocatable :: inside(:,:)
    !> multipliers, CSR over the output states: offset [n_out + 1]; identities, values [nnz]
    integer(i8), allocatable :: offset(:)
    integer, allocatable :: ia(:), ib(:), ob(:)
    real(wp), allocatable :: lambda(:)
    !> per-step statistics [n_steps]
    integer, allocatable :: iterations(:), converged(:)
    real(wp), allocatable :: kkt(:), min_gap(:)
  end type fom_file_t

  !> Streaming writer of one run (open, write_step per output state, close or abort), with a
  !> buffer of output states in memory (see the module header).
  type :: fom_writer_t
    type(h5file_t) :: h5
    logical :: store_multipliers = .true.
    !> multipliers and output states written so far (buffered ones included)
    integer(i8) :: nnz = 0
    integer :: n_out = 0
    !> capacity of the buffer (output states), states in it, offsets in it (the initial 0 of
    !> traj/contacts/offset waits in it too), multipliers in it
    integer :: kcap = 0, nbuf = 0, noff = 0, nc = 0
    !> bytes of one buffered state without its multipliers
    integer(i8) :: state_bytes = 0
    !> buffered steps and times [kcap]; offsets [kcap + 1]
    integer, allocatable :: b_step(:)
    real(wp), allocatable :: b_time(:)
    integer(i8), allocatable :: b_off(:)
    !> buffered positions, velocities, desired velocities [2 n_agents, kcap]; inside flags [n_agents, kcap]
    real(wp), allocatable :: b_q(:,:), b_u(:,:), b_v(:,:)
    integer, allocatable :: b_inside(:,:)
    !> buffered multipliers: identities and values [>= nc]
    integer, allocatable :: b_ia(:), b_ib(:), b_ob(:)
    real(wp), allocatable :: b_lam(:)
  contains
    procedure :: open => writer_open
    procedure :: write_step
    procedure :: flush => writer_flush
    procedure :: close => writer_close
    procedure :: abort => writer_abort
  end type fom_writer_t

contains

  !> Create the file (temporary name), write metadata and scene, buffer the initial state.
  subroutine writer_open(this, path, cfg, fom, error, buffer_steps)
    class(fom_writer_t), intent(inout) :: this
    character(len=*), intent(in) :: path
    type(config_t), intent(in) :: cfg
    class(fom_state_t), intent(in) :: fom
    type(error_t), allocatable, intent(out) :: error
    !> output states held in memory before they go to the file (>= 1; default: as many as
    !> fit BUFFER_BYTES, at most the number of steps + 1)
    integer, intent(in), optional :: buffer_steps
    integer :: na, n_target
    na = fom%n_agents
    this%store_multipliers = cfg%output%store_multipliers
    this%state_bytes = 4 + 8 + 8 + int(na, i8) * (3 * 2 * 8 + 4)
    if (present(buffer_steps)) then
      this%kcap = max(1, buffer_steps)
    else
      n_target = cfg%time%n_steps
      if (cfg%time%until_empty) n_target = cfg%time%max_steps
      this%kcap = int(max(1_i8, min(BUFFER_BYTES / this%state_bytes, int(n_target, i8) + 1)))
    end if
    call free_buffer(this)
    call this%h5%create(path, error)
    if (allocated(error)) return
    allocate(this%b_step(this%kcap), this%b_time(this%kcap), this%b_off(this%kcap + 1), &
      this%b_q(2 * na, this%kcap), this%b_u(2 * na, this%kcap), this%b_v(2 * na, this%kcap), &
      this%b_inside(na, this%kcap))
    call attrs(error); if (allocated(error)) goto 9
    call write_scene(this%h5, fom%scene, error); if (allocated(error)) goto 9
    call this%h5%make_group("agents", error); if (allocated(error)) goto 9
    call this%h5%write("agents/speed", fom%speeds, error); if (allocated(error)) goto 9
    call this%h5%write("agents/initial_positions", fom%q, error); if (allocated(error)) goto 9
    call this%h5%make_group("traj/contacts", error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/step", [integer ::], cr_h5_int, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/time", [integer ::], cr_h5_real, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/positions", [2 * na], cr_h5_real, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/velocities", [2 * na], cr_h5_real, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/desired", [2 * na], cr_h5_real, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/inside", [na], cr_h5_int, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/contacts/offset", [integer ::], cr_h5_int64, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/contacts/ia", [integer ::], cr_h5_int, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/contacts/ib", [integer ::], cr_h5_int, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/contacts/ob", [integer ::], cr_h5_int, error); if (allocated(error)) goto 9
    call this%h5%create_extendible("traj/contacts/lambda", [integer ::], cr_h5_real, error); if (allocated(error)) goto 9
    this%nnz = 0
    this%n_out = 0
    this%noff = 1
    this%b_off(1) = 0
    call this%write_step(fom, error)
9   if (allocated(error)) then
      call prefix_error(error, "output")
      call this%abort()
    end if

  contains

    subroutine attrs(error)
      type(error_t), allocatable, intent(out) :: error
      call this%h5%write_attr("/", "schema", FOM_SCHEMA, error); if (allocated(error)) return
      call this%h5%write_attr("/", "schema_version", FOM_SCHEMA_VERSION, error); if (allocated(error)) return
      call this%h5%write_attr("/", "program", "crowd_fom", error); if (allocated(error)) return
      call this%h5%write_attr("/", "units", "length: m, time: s, velocity: m/s, multiplier: m/s^2 " // &
        "(lambda scales B = -h G: u = v - B^T lambda)", error); if (allocated(error)) return
      call this%h5%write_attr("/", "agent_radius", fom%radius, error); if (allocated(error)) return
      call this%h5%write_attr("/", "n_agents", fom%n_agents, error); if (allocated(error)) return
      call this%h5%write_attr("/", "dt", fom%dt, error); if (allocated(error)) return
      call this%h5%write_attr("/", "solver", trim(cfg%solver%name), error); if (allocated(error)) return
      call this%h5%write_attr("/", "config", config_echo(cfg), error); if (allocated(error)) return
      call this%h5%write_attr("/", "input_text", cfg%text, error); if (allocated(error)) return
    end subroutine attrs
  end subroutine writer_open

  !> Append the current state (positions, velocities, inside flags, active multipliers): copy
  !> it into the buffer, which goes to the file when full. On an error the caller aborts.
  subroutine write_step(this, fom, error)
    class(fom_writer_t), intent(inout) :: this
    class(fom_state_t), intent(in) :: fom
    type(error_t), allocatable, intent(out) :: error
    integer :: n, l, k, j
    if (.not. this%h5%is_open() .or. .not. allocated(this%b_q)) then
      call set_error(error, "output: write_step: the writer is not open"); return
    end if
    if (size(fom%q) /= size(this%b_q, 1) .or. size(fom%u) /= size(this%b_u, 1) .or. &
        size(fom%v) /= size(this%b_v, 1) .or. size(fom%inside) /= size(this%b_inside, 1)) then
      call set_error(error, "output: write_step: state of " // str(size(fom%inside)) // &
        " agents in a file of " // str(size(this%b_inside, 1))); return
    end if
    if (this%nbuf >= this%kcap) then
      ! only after a failed flush (the caller should have aborted): try again
      call this%flush(error); if (allocated(error)) return
    end if
    j = this%nbuf + 1
    this%b_step(j) = fom%step
    this%b_time(j) = fom%step * fom%dt
    this%b_q(:, j) = fom%q
    this%b_u(:, j) = fom%u
    this%b_v(:, j) = fom%v
    this%b_inside(:, j) = merge(1, 0, fom%inside)
    n = 0
    if (this%store_multipliers .and. fom%step > 0) n = count(fom%lambda(1:fom%cs%n) > 0)
    if (n > 0) then
      call reserve_contacts(this, this%nc + n)
      k = this%nc
      do l = 1, fom%cs%n
        if (fom%lambda(l) > 0) then
          k = k + 1
          this%b_ia(k) = fom%cs%ia(l); this%b_ib(k) = fom%cs%ib(l); this%b_ob(k) = fom%cs%ob(l)
          this%b_lam(k) = fom%lambda(l)
        end if
      end do
      this%nc = k
    end if
    this%nnz = this%nnz + n
    this%noff = this%noff + 1
    this%b_off(this%noff) = this%nnz
    this%nbuf = j
    this%n_out = this%n_out + 1
    if (this%nbuf >= this%kcap .or. this%nbuf * this%state_bytes + this%nc * CONTACT_BYTES >= BUFFER_BYTES) &
      call this%flush(error)
  end subroutine write_step

  !> Write the buffered output states to the file (one hyperslab per dataset) and empty the
  !> buffer. On an error the file holds part of them: the caller aborts.
  subroutine writer_flush(this, error)
    class(fom_writer_t), intent(inout) :: this
    type(error_t), allocatable, intent(out) :: error
    integer :: m
    m = this%nbuf
    if (m > 0) then
      call this%h5%append("traj/step", this%b_step(1:m), error); if (allocated(error)) return
      call this%h5%append("traj/time", this%b_time(1:m), error); if (allocated(error)) return
      call this%h5%append("traj/positions", this%b_q(:, 1:m), error); if (allocated(error)) return
      call this%h5%append("traj/velocities", this%b_u(:, 1:m), error); if (allocated(error)) return
      call this%h5%append("traj/desired", this%b_v(:, 1:m), error); if (allocated(error)) return
      call this%h5%append("traj/inside", this%b_inside(:, 1:m), error); if (allocated(error)) return
    end if
    if (this%nc > 0) then
      call this%h5%append("traj/contacts/ia", this%b_ia(1:this%nc), error); if (allocated(error)) return
      call this%h5%append("traj/contacts/ib", this%b_ib(1:this%nc), error); if (allocated(error)) return
      call this%h5%append("traj/contacts/ob", this%b_ob(1:this%nc), error); if (allocated(error)) return
      call this%h5%append("traj/contacts/lambda", this%b_lam(1:this%nc), error); if (allocated(error)) return
    end if
    if (this%noff > 0) then
      call this%h5%append("traj/contacts/offset", this%b_off(1:this%noff), error); if (allocated(error)) return
    end if
    this%nbuf = 0; this%nc = 0; this%noff = 0
  end subroutine writer_flush

  !> Room for n buffered multipliers (contents kept; grows by half at least).
  subroutine reserve_contacts(this, n)
    class(fom_writer_t), intent(inout) :: this
    integer, intent(in) :: n
    integer :: cap
    if (allocated(this%b_ia)) then
      if (size(this%b_ia) >= n) return
    end if
    cap = max(n, 1024)
    if (allocated(this%b_ia)) cap = max(n, size(this%b_ia) + size(this%b_ia) / 2)
    call grow_kept_int(this%b_ia, cap, this%nc)
    call grow_kept_int(this%b_ib, cap, this%nc)
    call grow_kept_int(this%b_ob, cap, this%nc)
    call grow_kept_real(this%b_lam, cap, this%nc)
  end subroutine reserve_contacts

  !> Release the buffer.
  subroutine free_buffer(this)
    class(fom_writer_t), intent(inout) :: this
    if (allocated(this%b_step)) deallocate(this%b_step)
    if (allocated(this%b_time)) deallocate(this%b_time)
    if (allocated(this%b_off)) deallocate(this%b_off)
    if (allocated(this%b_q)) deallocate(this%b_q)
    if (allocated(this%b_u)) deallocate(this%b_u)
    if (allocated(this%b_v)) deallocate(this%b_v)
    if (allocated(this%b_inside)) deallocate(this%b_inside)
    if (allocated(this%b_ia)) deallocate(this%b_ia)
    if (allocated(this%b_ib)) deallocate(this%b_ib)
    if (allocated(this%b_ob)) deallocate(this%b_ob)
    if (allocated(this%b_lam)) deallocate(this%b_lam)
    this%nbuf = 0; this%noff = 0; this%nc = 0
  end subroutine free_buffer

  !> Write the buffered states and the per-step statistics and commit the file under its
  !> final name (on an error: abort). With qoi: the run's quantities of interest as the QoI
  !> group `qoi` (one row; cr_qoi_file).
  subroutine writer_close(this, recs, error, qoi)
    class(fom_writer_t), intent(inout) :: this
    type(step_record_t), intent(in) :: recs(:)
    type(error_t), allocatable, intent(out) :: error
    type(qoi_t), intent(in), optional :: qoi
    integer, allocatable :: iv(:)
    real(wp), allocatable :: rv(:)
    if (.not. this%h5%is_open()) then
      call set_error(error, "output: close: the writer is not open"); return
    end if
    call this%flush(error); if (allocated(error)) goto 9
    call free_buffer(this)
    call this%h5%make_group("stats", error); if (allocated(error)) goto 9
    iv = recs%step
    call this%h5%write("stats/step", iv, error); if (allocated(error)) goto 9
    iv = recs%iterations
    call this%h5%write("stats/iterations", iv, error); if (allocated(error)) goto 9
    iv = merge(1, 0, recs%converged)
    call this%h5%write("stats/converged", iv, error); if (allocated(error)) goto 9
    rv = recs%kkt
    call this%h5%write("stats/kkt", rv, error); if (allocated(error)) goto 9
    rv = recs%primal
    call this%h5%write("stats/kkt_primal", rv, error); if (allocated(error)) goto 9
    rv = recs%dual
    call this%h5%write("stats/kkt_dual", rv, error); if (allocated(error)) goto 9
    rv = recs%compl
    call this%h5%write("stats/kkt_complementarity", rv, error); if (allocated(error)) goto 9
    rv = recs%stat
    call this%h5%write("stats/kkt_stationarity", rv, error); if (allocated(error)) goto 9
    iv = recs%n_rows
    call this%h5%write("stats/n_rows", iv, error); if (allocated(error)) goto 9
    iv = recs%n_active
    call this%h5%write("stats/n_active", iv, error); if (allocated(error)) goto 9
    iv = recs%resolves
    call this%h5%write("stats/resolves", iv, error); if (allocated(error)) goto 9
    iv = recs%n_inside
    call this%h5%write("stats/n_inside", iv, error); if (allocated(error)) goto 9
    rv = recs%min_gap
    call this%h5%write("stats/min_gap", rv, error); if (allocated(error)) goto 9
    rv = recs%t_solve
    call this%h5%write("stats/time_solve", rv, error); if (allocated(error)) goto 9
    rv = recs%t_step
    call this%h5%write("stats/time_step", rv, error); if (allocated(error)) goto 9
    if (present(qoi)) then
      call write_qoi_group(this%h5, "qoi", [qoi], error); if (allocated(error)) goto 9
    end if
    call this%h5%commit(error)
9   if (allocated(error)) then
      call prefix_error(error, "output")
      call this%abort()
    end if
  end subroutine writer_close

  !> Drop the buffer, close and delete the temporary file (the final name is untouched).
  subroutine writer_abort(this)
    class(fom_writer_t), intent(inout) :: this
    call free_buffer(this)
    call this%h5%abort()
  end subroutine writer_abort

  !> Read and validate a full-order output file (serial).
  subroutine read_fom_file(path, f, error)
    character(len=*), intent(in) :: path
    type(fom_file_t), intent(out) :: f
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    integer(i8), allocatable :: d(:)
    integer :: version, nd, c
    call h5%open(path, error)
    if (allocated(error)) then
      error%code = EXIT_BAD_INPUT; return
    end if
    f%path = path
    call check_schema(h5, path, FOM_SCHEMA, FOM_VERSIONS_READ, "full-order output", version, error)
    if (allocated(error)) goto 9
    call h5%read_attr("/", "n_agents", f%n_agents, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "agent_radius", f%radius, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "dt", f%dt, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "solver", f%solver, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "config", f%config, error); if (allocated(error)) goto 9
    if (f%n_agents < 0 .or. .not. (f%radius > 0 .and. f%radius <= huge(1.0_wp)) .or. &
        .not. (f%dt > 0 .and. f%dt <= huge(1.0_wp))) then
      call product_error(path, "root attributes out of range (n_agents " // str(f%n_agents) // ", agent_radius " // &
        str(f%radius) // ", dt " // str(f%dt) // ")", error); goto 9
    end if
    nd = 2 * f%n_agents
    call h5%get_dims("traj/step", d, error); if (allocated(error)) goto 9
    f%n_out = int(d(1))
    call need_dims(h5, path, "agents/speed", [int(f%n_agents, i8)], "n_agents", error); if (allocated(error)) goto 9
    call need_dims(h5, path, "agents/initial_positions", [int(nd, i8)], "2 n_agents", error); if (allocated(error)) goto 9
    call need_dims(h5, path, "traj/time", [int(f%n_out, i8)], "traj/step", error); if (allocated(error)) goto 9
    call need_dims(h5, path, "traj/positions", [int(nd, i8), int(f%n_out, i8)], "2 n_agents x traj/step", error)
    if (allocated(error)) goto 9
    call need_dims(h5, path, "traj/velocities", [int(nd, i8), int(f%n_out, i8)], "2 n_agents x traj/step", error)
    if (allocated(error)) goto 9
    call need_dims(h5, path, "traj/desired", [int(nd, i8), int(f%n_out, i8)], "2 n_agents x traj/step", error)
    if (allocated(error)) goto 9
    call need_dims(h5, path, "traj/inside", [int(f%n_agents, i8), int(f%n_out, i8)], "n_agents x traj/step", error)
    if (allocated(error)) goto 9
    call need_dims(h5, path, "traj/contacts/offset", [int(f%n_out + 1, i8)], "traj/step + 1", error)
    if (allocated(error)) goto 9
    call h5%read("agents/speed", f%speed, error); if (allocated(error)) goto 9
    call h5%read("agents/initial_positions", f%q0, error); if (allocated(error)) goto 9
    call h5%read("traj/step", f%step, error); if (allocated(error)) goto 9
    call h5%read("traj/time", f%time, error); if (allocated(error)) goto 9
    call h5%read("traj/positions", f%q, error); if (allocated(error)) goto 9
    call h5%read("traj/velocities", f%u, error); if (allocated(error)) goto 9
    call h5%read("traj/desired", f%v, error); if (allocated(error)) goto 9
    call h5%read("traj/inside", f%inside, error); if (allocated(error)) goto 9
    call h5%read("traj/contacts/offset", f%offset, error); if (allocated(error)) goto 9
    call h5%read("traj/contacts/ia", f%ia, error); if (allocated(error)) goto 9
    call h5%read("traj/contacts/ib", f%ib, error); if (allocated(error)) goto 9
    call h5%read("traj/contacts/ob", f%ob, error); if (allocated(error)) goto 9
    call h5%read("traj/contacts/lambda", f%lambda, error); if (allocated(error)) goto 9
    call h5%read("stats/iterations", f%iterations, error); if (allocated(error)) goto 9
    call h5%read("stats/converged", f%converged, error); if (allocated(error)) goto 9
    call h5%read("stats/kkt", f%kkt, error); if (allocated(error)) goto 9
    call h5%read("stats/min_gap", f%min_gap, error); if (allocated(error)) goto 9
    call need_finite(path, "agents/speed", f%speed, error); if (allocated(error)) goto 9
    call need_finite(path, "agents/initial_positions", f%q0, error); if (allocated(error)) goto 9
    call need_finite(path, "traj/positions", f%q, error); if (allocated(error)) goto 9
    call need_finite(path, "traj/velocities", f%u, error); if (allocated(error)) goto 9
    call need_finite(path, "traj/desired", f%v, error); if (allocated(error)) goto 9
    call need_finite(path, "traj/contacts/lambda", f%lambda, error); if (allocated(error)) goto 9
    call need_range(path, "traj/inside", reshape(f%inside, [size(f%inside)]), 0, 1, error); if (allocated(error)) goto 9
    call need_range(path, "traj/contacts/ia", f%ia, 1, f%n_agents, error); if (allocated(error)) goto 9
    call need_range(path, "traj/contacts/ib", f%ib, 0, f%n_agents, error); if (allocated(error)) goto 9
    call need_range(path, "traj/contacts/ob", f%ob, 0, huge(1), error); if (allocated(error)) goto 9
    if (size(f%ib) /= size(f%ia) .or. size(f%ob) /= size(f%ia) .or. size(f%lambda) /= size(f%ia)) then
      call product_error(path, "datasets 'traj/contacts/ia, ib, ob, lambda' have different sizes", error); goto 9
    end if
    if (f%offset(1) /= 0 .or. f%offset(f%n_out + 1) /= size(f%ia)) then
      call product_error(path, "dataset 'traj/contacts/offset': ends " // str(f%offset(1)) // ".." // &
        str(f%offset(f%n_out + 1)) // ", expected 0.." // str(size(f%ia)), error); goto 9
    end if
    do c = 1, f%n_out
      if (f%offset(c + 1) < f%offset(c)) then
        call product_error(path, "dataset 'traj/contacts/offset': offsets decrease at output " // str(c), error); goto 9
      end if
    end do
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= EXIT_BAD_INPUT) call prefix_error(error, "full-order output '" // path // "'")
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_fom_file

  !> The scene group: obstacles in a uniform vertex representation, exit, plot domain.
  subroutine write_scene(h5, scene, error)
    type(h5file_t), intent(inout) :: h5
    type(scene_t), intent(in) :: scene
    type(error_t), allocatable, intent(out) :: error
    integer :: n, k, nv
    integer, allocatable :: kind(:), start(:)
    real(wp), allocatable :: rad(:), verts(:,:)
    real(wp) :: ex(2, 2), dom(4)
    real(wp), allocatable :: exits(:,:)
    n = scene%n_obstacles()
    allocate(kind(n), start(n + 1), rad(n))
    start(1) = 0
    do k = 1, n
      kind(k) = scene%obstacles(k)%kind
      rad(k) = scene%obstacles(k)%radius
      start(k + 1) = start(k) + size(scene%obstacles(k)%vertices, 2)
    end do
    allocate(verts(2, start(n + 1)))
    do k = 1, n
      nv = size(scene%obstacles(k)%vertices, 2)
      verts(:, start(k) + 1:start(k) + nv) = scene%obstacles(k)%vertices
    end do
    call h5%make_group("scene", error); if (allocated(error)) return
    call h5%write("scene/obstacle_kind", kind, error); if (allocated(error)) return
    call h5%write("scene/obstacle_radius", rad, error); if (allocated(error)) return
    call h5%write("scene/obstacle_vertex_start", start, error); if (allocated(error)) return
    call h5%write("scene/obstacle_vertices", verts, error); if (allocated(error)) return
    ex(:, 1) = [scene%x_lo, scene%width]
    ex(:, 2) = [scene%x_hi, scene%width]
    call h5%write("scene/exit_segment", ex, error); if (allocated(error)) return
    ! every exit: x0, y0, x1, y1 of each opening [4, n_exits] (exit 1 top wall, exit 2 right wall)
    call exit_segments(scene, exits)
    call h5%write("scene/exit_segments", exits, error); if (allocated(error)) return
    dom = [-scene%wall, -scene%wall, scene%length + scene%wall, &
      scene%width + scene%wall + 0.3_wp * scene%width]
    call h5%write("scene/domain", dom, error); if (allocated(error)) return
    call h5%write_attr("scene", "hall_length", scene%length, error); if (allocated(error)) return
    call h5%write_attr("scene", "hall_width", scene%width, error); if (allocated(error)) return
    call h5%write_attr("scene", "wall_thickness", scene%wall, error); if (allocated(error)) return
    call h5%write_attr("scene", "l_exit", scene%l_exit, error); if (allocated(error)) return
    call h5%write_attr("scene", "n_exits", size(exits, 2), error); if (allocated(error)) return
    call h5%write_attr("scene", "n_walls", scene%n_walls, error)
  end subroutine write_scene
end module cr_fom_file
