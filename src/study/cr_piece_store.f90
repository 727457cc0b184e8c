!> The pieces directory of a study (`<database>.pieces/`): which samples are already stored, in
!> which piece, and whether every stored piece is what it claims to be.
!>
!> scan_pieces (collective) finds the pieces of earlier runs (a piece is named after its first
!> sample, so probing the names of the samples not yet covered finds them all), reads their
!> headers on rank 0, then has the pieces read in full and verified by the ranks in turn
!> (checksums, finiteness, shapes: read_piece; identity against the study's sampling:
!> check_sample). Pieces of another configuration stop the run (exit status 2). A bad piece
!> (unreadable, corrupted, renamed, claiming a sample another piece holds) is reported by name;
!> with `quarantine` it is moved to `<pieces>/quarantine/` and its samples are recomputed,
!> otherwise the run stops (status 2) naming every bad piece. Nothing is ever deleted here.
!> The samples of the good pieces are handed to the rank that verified them (`held`): they go
!> into the database from there, no piece is read twice.
module cr_piece_store
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_fsys, only: file_exists, make_dir, rename_file
  use cr_sampling, only: sample_set_t
  use cr_snapshot_piece, only: sample_result_t, move_sample, piece_header, read_piece, check_sample, piece_path, &
    write_piece
    use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: piece_index_t, piece_batch_t, scan_pieces, global_sample, set_of_sample, quarantine_piece

  !> A variable-length path.
  type :: path_t
    character(len=:), allocatable :: s
  end type path_t

  !> Where each sample of the study is stored.
  type :: piece_index_t
    !> number of samples of the study (train then valid) and of pieces found
    integer :: n_tot = 0, n_pieces = 0
    !> piece holding global sample g (0: none) and its position in the piece [n_tot]
    integer, allocatable :: piece_of(:), slot_of(:)
    !> path of each piece [n_pieces]
    type(path_t), allocatable :: path(:)
    !> pieces moved to quarantine by this scan
    integer :: n_quarantined = 0
    !> (rank 0) the directory did not exist before this scan: no piece, and no temporary of a
    !> killed run, can be in it
    logical :: fresh = .false.
  contains
    procedure :: path_of
  end type piece_index_t

  !> What the steps of scan_pieces pass on: each piece's flag (1: bad) [n], this rank's
  !> messages on its bad pieces, the pieces found, the verified samples held.
  type :: scan_state_t
    integer, allocatable :: bad(:)
    character(len=:), allocatable :: bad_msg
    integer :: n = 0, nh = 0
  end type scan_state_t

  !> The samples a rank computed in the current time slice, written together as one piece.
  type :: piece_batch_t
    type(env_t) :: env
    character(len=:), allocatable :: dir, hash
    !> time slice (s) and memory bound of one piece
    real(wp) :: slice = 2
    integer(i8) :: max_bytes = 256_i8 * 1024 * 1024
    !> samples held [n] and their global numbers
    integer :: n = 0
    integer(i8) :: bytes = 0
    type(sample_result_t), allocatable :: res(:)
    integer, allocatable :: g(:)
    !> pieces written so far: [n_1, g_1 .. g_n1, n_2, ...] (their files are removed once the database is complete)
    integer, allocatable :: written(:)
    !> pieces written, their data bytes and the wall time spent writing them (s)
    integer :: n_pieces = 0
    integer(i8) :: bytes_written = 0
    real(wp) :: t_write = 0
  contains
    procedure :: init => batch_init
    procedure :: add => batch_add
    procedure :: flush => batch_flush
  end type piece_batch_t

contains

  !> Path of piece p.
  function path_of(this, p) result(s)
    class(piece_index_t), intent(in) :: this
    integer, intent(in) :: p
    character(len=:), allocatable :: s
    s = this%path(p)%s
  end function path_of

  !> Global sample number (train 1..n_train, then valid) of sample k of set `name`; 0 if none.
  pure integer function global_sample(sets, name, k) result(g)
    type(sample_set_t), intent(in) :: sets(2)
    character(len=*), intent(in) :: name
    integer, intent(in) :: k
    g = 0
    if (trim(name) == trim(sets(1)%name)) then
      if (k >= 1 .and. k <= sets(1)%n) g = k
    else if (trim(name) == trim(sets(2)%name)) then
      if (k >= 1 .and. k <= sets(2)%n) g = sets(1)%n + k
    end if
  end function global_sample

  !> Set (1 train, 2 valid) and index in the set of global sample g.
  pure subroutine set_of_sample(sets, g, is, k)
    type(sample_set_t), intent(in) :: sets(2)
    integer, intent(in) :: g
    integer, intent(out) :: is, k
    if (g <= sets(1)%n) then
      is = 1; k = g
    else
      is = 2; k = g - sets(1)%n
    end if
  end subroutine set_of_sample

  !> Move a bad piece to `<dir>/quarantine/` (never deleting; an existing name gets a suffix).
  !> Returns the new path, or '' if it could not be moved.
  function quarantine_piece(dir, path) result(dest)
    character(len=*), intent(in) :: dir, path
    character(len=:), allocatable :: dest
    character(len=:), allocatable :: qdir, base
    integer :: i, n
    qdir = dir // "/quarantine"
    dest = ""
    if (make_dir(qdir) /= 0) return
    i = index(path, "/", back=.true.)
    base = path(i + 1:)
    dest = qdir // "/" // base
    n = 0
    do while (file_exists(dest))
      n = n + 1
      dest = qdir // "/" // base // "." // str(n)
    end do
    if (rename_file(path, dest) /= 0) dest = ""
  end function quarantine_piece

  !> Collective: find and verify the pieces in `dir` (see the module header): rank 0 reads
  !> the headers (scan_headers), the index goes to every rank (share_index), the pieces with
  !> good headers are verified round-robin (verify_pieces), and the bad ones stop the run or
  !> are moved aside (settle_bad).
  subroutine scan_pieces(env, dir, hash, sets, n_dof, n_steps, quarantine, idx, held, warnings, error)
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: dir, hash
    !> the study's samples (train, valid)
    type(sample_set_t), intent(in) :: sets(2)
    integer, intent(in) :: n_dof, n_steps
    !> move bad pieces aside (and recompute their samples) instead of stopping
    logical, intent(in) :: quarantine
    type(piece_index_t), intent(out) :: idx
    !> the samples of the good pieces this rank verified (for the database)
    type(sample_result_t), allocatable, intent(out) :: held(:)
    !> one line per quarantined piece (rank 0; '' if none)
    character(len=:), allocatable, intent(out) :: warnings
    type(error_t), allocatable, intent(out) :: error
    type(scan_state_t) :: st
    character(len=:), allocatable :: fatal
    warnings = ""
    allocate(held(0))
    idx%n_tot = sets(1)%n + sets(2)%n
    allocate(idx%piece_of(idx%n_tot), idx%slot_of(idx%n_tot), idx%path(0))
    idx%piece_of = 0; idx%slot_of = 0
    allocate(st%bad(0))
    st%bad_msg = ""
    fatal = ""
    if (env%is_root()) call scan_headers(dir, hash, sets, idx, st, fatal)
    call share_index(env, idx, st, fatal, error)
    if (allocated(error) .or. st%n == 0) return
    call verify_pieces(env, sets, n_dof, n_steps, idx, st, held)
    call env%allreduce(st%bad, 'max', error)
    if (allocated(error)) return
    held = held(1:st%nh)
    if (count(st%bad /= 0) == 0) return
    call settle_bad(env, dir, quarantine, idx, st, warnings, error)
  end subroutine scan_pieces

  !> Rank 0: the headers of the pieces in dir, each sample claimed by one piece; every piece
  !> found gets a number, good or bad (bad ones marked in st). fatal: why the run cannot go on
  !> ('' if it can).
  subroutine scan_headers(dir, hash, sets, idx, st, fatal)
    character(len=*), intent(in) :: dir, hash
    type(sample_set_t), intent(in) :: sets(2)
    type(piece_index_t), intent(inout) :: idx
    type(scan_state_t), intent(inout) :: st
    character(len=:), allocatable, intent(inout) :: fatal
    character(len=:), allocatable :: h, path, m
    character(len=8), allocatable :: hsets(:)
    integer, allocatable :: hidx(:), claimed(:)
    type(error_t), allocatable :: e
    integer :: g, is, k, j, p, gj
    ! (the directory is created with the first piece: a study too short to write one never
    ! has one)
    idx%fresh = .not. file_exists(dir // "/.")
    if (idx%fresh .and. file_exists(dir)) fatal = "'" // dir // "' exists and is not a directory: " // &
      "it cannot hold the pieces of '" // dir(1:len(dir) - 7) // "'"
    allocate(claimed(idx%n_tot))
    claimed = 0
    do g = 1, idx%n_tot
      if (len(fatal) > 0 .or. idx%fresh) exit
      if (idx%piece_of(g) > 0) cycle
      call set_of_sample(sets, g, is, k)
      path = piece_path(dir, sets(is)%name, k)
      if (.not. file_exists(path)) cycle
      call append_path(idx, path)
      p = idx%n_pieces
      call piece_header(path, h, hsets, hidx, e)
      if (allocated(e)) then
        call mark_bad(st, p, e%message // " (unreadable or incomplete piece)")
        deallocate(e)
        cycle
      end if
      if (h /= hash) then
        fatal = "'" // dir // "' holds pieces of a different configuration (piece config_hash " // h // &
          ", this input " // trim(hash) // "): refusing to mix them; remove the directory or restore the input"
        exit
      end if
      if (trim(hsets(1)) /= trim(sets(is)%name) .or. hidx(1) /= k) then
        call mark_bad(st, p, "piece '" // path // "' holds " // trim(hsets(1)) // " sample " // str(hidx(1)) // &
          " where " // trim(sets(is)%name) // " sample " // str(k) // " belongs (renamed or copied piece)")
        cycle
      end if
      m = ""
      do j = 1, size(hidx)
        gj = global_sample(sets, hsets(j), hidx(j))
        if (gj == 0) then
          m = "piece '" // path // "' holds " // trim(hsets(j)) // " sample " // str(hidx(j)) // &
            ", which this study does not have"
        else if (claimed(gj) /= 0) then
          m = "piece '" // path // "' holds " // trim(hsets(j)) // " sample " // str(hidx(j)) // &
            ", already held by piece '" // idx%path(claimed(gj))%s // "'"
        end if
        if (len(m) > 0) exit
      end do
      if (len(m) > 0) then
        call mark_bad(st, p, m); cycle
      end if
      do j = 1, size(hidx)
        gj = global_sample(sets, hsets(j), hidx(j))
        claimed(gj) = p
        idx%piece_of(gj) = p
        idx%slot_of(gj) = j
      end do
    end do
  end subroutine scan_headers

  !> Collective: rank 0's outcome [message length, pieces found] (a fresh study ends here: one
  !> broadcast; st%n = 0), then the index [piece_of, slot_of, bad, path lengths] and the paths
  !> in one text.
  subroutine share_index(env, idx, st, fatal, error)
    type(env_t), intent(in) :: env
    type(piece_index_t), intent(inout) :: idx
    type(scan_state_t), intent(inout) :: st
    character(len=:), allocatable, intent(inout) :: fatal
    type(error_t), allocatable, intent(out) :: error
    integer, allocatable :: lens(:), buf(:)
    character(len=:), allocatable :: all_msg
    integer :: head(2), p, j, k, n
    head = [len(fatal), idx%n_pieces]
    call env%bcast(head, error)
    if (allocated(error)) return
    if (head(1) > 0) then
      call env%bcast(fatal, error)
      if (.not. allocated(error)) call set_error(error, fatal, EXIT_BAD_INPUT)
      return
    end if
    n = head(2)
    st%n = n
    if (n == 0) return
    call resize_bad(st, n)
    allocate(lens(n))
    lens = 0
    all_msg = ""
    if (env%is_root()) then
      do p = 1, n
        lens(p) = len(idx%path(p)%s)
        all_msg = all_msg // idx%path(p)%s
      end do
    end if
    buf = [idx%piece_of, idx%slot_of, st%bad, lens]
    call env%bcast(buf, error)
    if (.not. allocated(error)) call env%bcast(all_msg, error)
    if (allocated(error)) return
    j = 2 * idx%n_tot
    idx%piece_of = buf(1:idx%n_tot); idx%slot_of = buf(idx%n_tot + 1:j)
    st%bad = buf(j + 1:j + n); lens = buf(j + n + 1:j + 2 * n)
    if (.not. env%is_root()) then
      deallocate(idx%path); allocate(idx%path(n))
      idx%n_pieces = n
      k = 0
      do p = 1, n
        idx%path(p)%s = all_msg(k + 1:k + lens(p))
        k = k + lens(p)
      end do
    end if
  end subroutine share_index

  !> Full verification of the pieces with good headers, round-robin over the ranks: the good
  !> ones' samples kept in held, the bad ones marked in st.
  subroutine verify_pieces(env, sets, n_dof, n_steps, idx, st, held)
    type(env_t), intent(in) :: env
    type(sample_set_t), intent(in) :: sets(2)
    integer, intent(in) :: n_dof, n_steps
    type(piece_index_t), intent(in) :: idx
    type(scan_state_t), intent(inout) :: st
    type(sample_result_t), allocatable, intent(inout) :: held(:)
    type(sample_result_t), allocatable :: res(:)
    type(error_t), allocatable :: e
    integer :: p, j, gj, is, k
    do p = 1, st%n
      if (st%bad(p) /= 0 .or. mod(p - 1, env%size) /= env%rank) cycle
      call read_piece(idx%path(p)%s, res, e)
      if (.not. allocated(e)) then
        do j = 1, size(res)
          gj = global_sample(sets, res(j)%set, res(j)%index)
          if (gj == 0) then
            call set_error(e, "piece '" // idx%path(p)%s // "' holds " // trim(res(j)%set) // " sample " // &
              str(res(j)%index) // ", which this study does not have")
          else if (idx%piece_of(gj) /= p .or. idx%slot_of(gj) /= j) then
            call set_error(e, "piece '" // idx%path(p)%s // "': sample " // str(j) // " disagrees with the header")
          else
            call set_of_sample(sets, gj, is, k)
            call check_sample(res(j), sets(is)%name, k, sets(is)%mu(:, k), n_dof, n_steps, &
              "piece '" // idx%path(p)%s // "'", e)
          end if
          if (allocated(e)) exit
        end do
      end if
      if (allocated(e)) then
        call mark_bad(st, p, e%message); deallocate(e)
      else
        call keep(st, held, res)
      end if
    end do
  end subroutine verify_pieces

  !> Collective, when some piece is bad: every rank's messages in rank order, the bad pieces'
  !> samples back to be computed, and then either the run stopped (error, code 2) or, with
  !> quarantine, the bad pieces moved aside by rank 0 (warnings) and dropped from the index.
  subroutine settle_bad(env, dir, quarantine, idx, st, warnings, error)
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: dir
    logical, intent(in) :: quarantine
    type(piece_index_t), intent(inout) :: idx
    type(scan_state_t), intent(inout) :: st
    character(len=:), allocatable, intent(inout) :: warnings
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: all_msg, m, h
    integer :: g, p, nbad
    nbad = count(st%bad /= 0)
    call env%gather_text(st%bad_msg, all_msg, error)
    if (allocated(error)) return
    do g = 1, idx%n_tot
      if (idx%piece_of(g) > 0) then
        if (st%bad(idx%piece_of(g)) /= 0) then
          idx%piece_of(g) = 0; idx%slot_of(g) = 0
        end if
      end if
    end do
    if (.not. quarantine) then
      call set_error(error, str(nbad) // " bad piece(s) in '" // dir // "':" // new_line('a') // all_msg // &
        "run again with --quarantine-bad-pieces to move them to '" // dir // "/quarantine' and recompute " // &
        "their samples", EXIT_BAD_INPUT)
      return
    end if
    m = ""
    if (env%is_root()) then
      do p = 1, st%n
        if (st%bad(p) == 0) cycle
        h = quarantine_piece(dir, idx%path(p)%s)
        if (len(h) == 0) then
          m = "cannot move the bad piece '" // idx%path(p)%s // "' to '" // dir // "/quarantine'"
          exit
        end if
        warnings = warnings // "moved bad piece '" // idx%path(p)%s // "' to '" // h // "'" // new_line('a')
      end do
      warnings = all_msg // warnings
    end if
    call env%bcast(m, error)
    if (allocated(error)) return
    if (len(m) > 0) then
      call set_error(error, m, EXIT_BAD_INPUT); return
    end if
    idx%n_quarantined = nbad
    call drop_bad(idx, st, nbad)
  end subroutine settle_bad

  !> Remove the nbad bad pieces from the index (renumbering the good ones).
  subroutine drop_bad(idx, st, nbad)
    type(piece_index_t), intent(inout) :: idx
    type(scan_state_t), intent(in) :: st
    integer, intent(in) :: nbad
    integer, allocatable :: newnum(:)
    type(path_t), allocatable :: t2(:)
    integer :: q, m2
    allocate(newnum(st%n), t2(st%n - nbad))
    m2 = 0
    do q = 1, st%n
      newnum(q) = 0
      if (st%bad(q) /= 0) cycle
      m2 = m2 + 1
      newnum(q) = m2
      call move_alloc(idx%path(q)%s, t2(m2)%s)
    end do
    do q = 1, idx%n_tot
      if (idx%piece_of(q) > 0) idx%piece_of(q) = newnum(idx%piece_of(q))
    end do
    call move_alloc(t2, idx%path)
    idx%n_pieces = m2
  end subroutine drop_bad

  !> Add path s to the index's pieces.
  subroutine append_path(idx, s)
    type(piece_index_t), intent(inout) :: idx
    character(len=*), intent(in) :: s
    type(path_t), allocatable :: tmp(:)
    integer :: q
    allocate(tmp(idx%n_pieces + 1))
    do q = 1, idx%n_pieces
      call move_alloc(idx%path(q)%s, tmp(q)%s)
    end do
    tmp(idx%n_pieces + 1)%s = s
    call move_alloc(tmp, idx%path)
    idx%n_pieces = idx%n_pieces + 1
  end subroutine append_path

  !> st%bad(1:m) (new entries 0)
  subroutine resize_bad(st, m)
    type(scan_state_t), intent(inout) :: st
    integer, intent(in) :: m
    integer, allocatable :: b2(:)
    if (size(st%bad) == m) return
    allocate(b2(m)); b2 = 0
    b2(1:min(m, size(st%bad))) = st%bad(1:min(m, size(st%bad)))
    call move_alloc(b2, st%bad)
  end subroutine resize_bad

  !> Piece p is bad, for the reason msg.
  subroutine mark_bad(st, p, msg)
    type(scan_state_t), intent(inout) :: st
    integer, intent(in) :: p
    character(len=*), intent(in) :: msg
    if (size(st%bad) < p) call resize_bad(st, p)
    st%bad(p) = 1
    st%bad_msg = st%bad_msg // "  " // msg // new_line('a')
  end subroutine mark_bad

  !> Keep the verified samples r (moved) among held (st%nh of them in use).
  subroutine keep(st, held, r)
    type(scan_state_t), intent(inout) :: st
    type(sample_result_t), allocatable, intent(inout) :: held(:)
    type(sample_result_t), intent(inout) :: r(:)
    type(sample_result_t), allocatable :: h2(:)
    integer :: q
    if (st%nh + size(r) > size(held)) then
      allocate(h2(max(2 * size(held), st%nh + size(r), 8)))
      do q = 1, st%nh
        call move_sample(held(q), h2(q))
      end do
      call move_alloc(h2, held)
    end if
    do q = 1, size(r)
      call move_sample(r(q), held(st%nh + q))
    end do
    st%nh = st%nh + size(r)
  end subroutine keep

  !> Start a batch: samples are kept until `slice` seconds have passed since the batch's first
  !> sample started (or the batch holds max_bytes of data), then written as one piece.
  subroutine batch_init(this, env, dir, hash, slice)
    class(piece_batch_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: dir, hash
    !> time slice of one piece (s); 0: one sample per piece
    real(wp), intent(in) :: slice
    this%env = env
    this%dir = dir
    this%hash = hash
    this%slice = slice
    this%n = 0
    this%bytes = 0
    if (allocated(this%res)) deallocate(this%res)
    if (allocated(this%g)) deallocate(this%g)
    allocate(this%res(8), this%g(8))
    if (allocated(this%written)) deallocate(this%written)
    allocate(this%written(0))
  end subroutine batch_init

  !> Add a computed sample (global number g; res%start set); writes the batch when it is due
  !> (`now`: seconds on the clock of res%start).
  subroutine batch_add(this, res, g, sets, now, error)
    class(piece_batch_t), intent(inout) :: this
    type(sample_result_t), intent(in) :: res
    integer, intent(in) :: g
    type(sample_set_t), intent(in) :: sets(2)
    real(wp), intent(in) :: now
    type(error_t), allocatable, intent(out) :: error
    type(sample_result_t), allocatable :: r2(:)
    integer, allocatable :: g2(:)
    if (this%n == size(this%res)) then
      allocate(r2(2 * this%n), g2(2 * this%n))
      r2(1:this%n) = this%res(1:this%n)
      g2(1:this%n) = this%g(1:this%n)
      call move_alloc(r2, this%res)
      call move_alloc(g2, this%g)
    end if
    this%n = this%n + 1
    this%res(this%n) = res
    this%g(this%n) = g
    this%bytes = this%bytes + 8_i8 * (size(res%q, kind=i8) + size(res%u, kind=i8) + size(res%v, kind=i8) + &
      2 * size(res%value, kind=i8))
    if (now - this%res(1)%start >= this%slice .or. this%bytes >= this%max_bytes) call this%flush(sets, error)
  end subroutine batch_add

  !> Write the samples held (if any) as one piece named after the first.
  subroutine batch_flush(this, sets, error)
    class(piece_batch_t), intent(inout) :: this
    type(sample_set_t), intent(in) :: sets(2)
    type(error_t), allocatable, intent(out) :: error
    integer :: is, k
    real(wp) :: t0
    if (this%n == 0) return
    call set_of_sample(sets, this%g(1), is, k)
    t0 = this%env%wtime()
    if (make_dir(this%dir) /= 0) then
      call set_error(error, "cannot create the directory '" // this%dir // "' for the pieces"); return
    end if
    call write_piece(piece_path(this%dir, sets(is)%name, k), this%hash, this%res(1:this%n), error)
    if (allocated(error)) return
    this%t_write = this%t_write + (this%env%wtime() - t0)
    this%n_pieces = this%n_pieces + 1
    this%bytes_written = this%bytes_written + this%bytes
    this%written = [this%written, this%n, this%g(1:this%n)]
    this%n = 0
    this%bytes = 0
  end subroutine batch_flush
end module cr_piece_store
