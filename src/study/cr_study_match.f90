!> Does an input describe the study a snapshot database was made with? A later stage
!> (crowd_offline) reads the study's namelist file and the database; any contradiction
!> between the model configuration (and &study, when the input has it) and the effective
!> configuration stored in the database is refused, naming every variable that differs.
!> The stored config_hash decides equality (the same hash crowd_snapshots computes); the
!> per-variable comparison only explains a mismatch.
module cr_study_match
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_namelist_text, only: namelist_text_t
  use cr_config, only: config_t, parse_config, config_echo
  use cr_study_config, only: study_cfg_t, read_study, study_echo, study_hash
  use cr_snapshot_file, only: SNAP_SCHEMA_VERSION, snap_header_t, read_snap_header
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: check_database_matches, compare_with_database

  !> at most this many differing variables are listed
  integer, parameter :: MAX_LISTED = 8

contains

  !> Collective: rank 0 reads the database's header through the product reader
  !> (cr_snapshot_file: schema, version, completeness) and compares its stored configuration with the
  !> input (`cfg`, and &study from `nml` when present); every rank returns the same error.
  !> `where` starts the message (e.g. "in.nml: &offline").
  subroutine check_database_matches(env, where, db_path, cfg, nml, error)
    type(env_t), intent(in) :: env
    character(len=*), intent(in) :: where, db_path
    type(config_t), intent(in) :: cfg
    type(namelist_text_t), intent(in) :: nml
    type(error_t), allocatable, intent(out) :: error
    type(snap_header_t) :: hdr
    if (env%is_root()) then
      ! the product reader checks schema, version and completeness (input error, exit 2)
      call read_snap_header(db_path, where // ": database", hdr, error)
      if (.not. allocated(error)) call compare_with_database(cfg, nml, db_path, hdr%config_text, hdr%hash, &
        where, error)
    end if
    call env%agree_error(error)
  end subroutine check_database_matches

  !> Compare the input with a database's stored configuration `db_text` and `db_hash`.
  subroutine compare_with_database(cfg, nml, db_path, db_text, db_hash, where, error)
    type(config_t), intent(in) :: cfg
    type(namelist_text_t), intent(in) :: nml
    character(len=*), intent(in) :: db_path, db_text, db_hash, where
    type(error_t), allocatable, intent(out) :: error
    type(namelist_text_t) :: t
    type(config_t) :: cdb
    type(study_cfg_t) :: s_in, s_db
    type(error_t), allocatable :: e
    character(len=:), allocatable :: diffs
    logical :: has_study
    integer :: n
    has_study = nml%has_group('study')
    if (has_study) then
      call read_study(nml, s_in, e)
      if (.not. allocated(e)) then
        if (study_hash(cfg, s_in, SNAP_SCHEMA_VERSION) == db_hash) return
      end if
      if (allocated(e)) deallocate(e)
    end if
    call t%set_text(db_path // " (stored configuration)", db_text)
    call parse_config(t, cdb, e)
    if (allocated(e)) then
      call set_error(error, where // ": database '" // db_path // "': its stored configuration cannot be read (" // &
        e%message // ")", EXIT_BAD_INPUT); return
    end if
    diffs = ""; n = 0
    call diff_echo(config_echo(cdb), config_echo(cfg), diffs, n)
    if (has_study .and. t%has_group('study')) then
      call read_study(t, s_db, e)
      if (.not. allocated(e)) call diff_echo(study_echo(s_db, with_database=.false.), &
        study_echo(s_in, with_database=.false.), diffs, n)
    end if
    if (n == 0 .and. .not. has_study) return
    if (n == 0) then
      call set_error(error, where // ": database '" // db_path // "' was made with another configuration " // &
        "(config_hash " // db_hash // ", this input " // study_hash(cfg, s_in, SNAP_SCHEMA_VERSION) // ")", EXIT_BAD_INPUT)
      return
    end if
    if (n > MAX_LISTED) diffs = diffs // "; and " // str(n - MAX_LISTED) // " more"
    call set_error(error, where // ": database '" // db_path // "' was made with another configuration than " // &
      "this input (" // diffs // "); give the study's own namelist file", EXIT_BAD_INPUT)
  end subroutine compare_with_database

  !> Append "&group variable: database X, input Y" for every variable whose echo differs.
  !> &output and comments are not compared.
  subroutine diff_echo(e_db, e_in, diffs, n)
    character(len=*), intent(in) :: e_db, e_in
    character(len=:), allocatable, intent(inout) :: diffs
    integer, intent(inout) :: n
    character(len=:), allocatable :: groups(:), g, a, b
    integer :: k
    call group_names(e_db, groups)
    do k = 1, size(groups)
      g = trim(groups(k))
      if (g == 'output') cycle
      a = group_text(e_db, g)
      b = group_text(e_in, g)
      if (a == b) cycle
      call diff_items(g, a, b, diffs, n)
    end do
  end subroutine diff_echo

  !> Compare two echoes of one group item by item ("name = values").
  subroutine diff_items(g, a, b, diffs, n)
    character(len=*), intent(in) :: g, a, b
    character(len=:), allocatable, intent(inout) :: diffs
    integer, intent(inout) :: n
    character(len=:), allocatable :: ia, ib, name
    integer :: k, pa, pb
    k = 0
    do
      k = k + 1
      ia = item(a, k)
      ib = item(b, k)
      if (len(ia) == 0 .and. len(ib) == 0) exit
      if (ia == ib) cycle
      pa = index(ia, " = ")
      pb = index(ib, " = ")
      name = "?"
      if (pa > 0) then
        name = ia(1:pa-1)
      else if (pb > 0) then
        name = ib(1:pb-1)
      end if
      n = n + 1
      if (n > MAX_LISTED) cycle
      if (len(diffs) > 0) diffs = diffs // "; "
      diffs = diffs // "&" // g // " " // name // ": database " // value_of(ia) // ", input " // value_of(ib)
    end do
  end subroutine diff_items

  !> The value part of "name = value" (or "(none)").
  function value_of(it) result(v)
    character(len=*), intent(in) :: it
    character(len=:), allocatable :: v
    integer :: p
    p = index(it, " = ")
    if (len(it) == 0) then
      v = "(none)"
    else if (p > 0) then
      v = it(p+3:)
    else
      v = it
    end if
  end function value_of

  !> Item k of a group's text "name = v, name2 = v1, v2, ..." (commas inside a value list
  !> stay with their item); "" past the end.
  function item(text, k) result(it)
    character(len=*), intent(in) :: text
    integer, intent(in) :: k
    character(len=:), allocatable :: it
    integer :: i, start, count, j
    logical :: in_str
    character :: q
    it = ""
    count = 0; start = 1; in_str = .false.; q = ' '
    i = 1
    do while (i <= len(text) + 1)
      if (i <= len(text)) then
        if (in_str) then
          if (text(i:i) == q) in_str = .false.
          i = i + 1; cycle
        else if (text(i:i) == "'" .or. text(i:i) == '"') then
          in_str = .true.; q = text(i:i); i = i + 1; cycle
        end if
      end if
      if (i > len(text)) then
        j = i
      else if (text(i:i) == ',' .and. starts_item(text(i+1:))) then
        j = i
      else
        i = i + 1; cycle
      end if
      count = count + 1
      if (count == k) then
        it = trim(adjustl(text(start:j-1))); return
      end if
      start = j + 1
      i = j + 1
    end do
  end function item

  !> True if `s` starts (after blanks) with "identifier[(...)] =".
  logical function starts_item(s)
    character(len=*), intent(in) :: s
    integer :: i, p
    starts_item = .false.
    i = 1
    do while (i <= len(s))
      if (s(i:i) /= ' ') exit
      i = i + 1
    end do
    p = index(s(i:), "=")
    if (p <= 1) return
    starts_item = verify(trim(s(i:i+p-2)), "abcdefghijklmnopqrstuvwxyz_0123456789()") == 0
  end function starts_item

  !> The text of group &g in an echo (newlines as blanks, without "&g" and "/"), "" if absent.
  function group_text(e, g) result(s)
    character(len=*), intent(in) :: e, g
    character(len=:), allocatable :: s
    integer :: i0, i1, k
    s = ""
    i0 = index(new_line('a') // e, new_line('a') // "&" // g // " ")
    if (i0 == 0) return
    i0 = i0 + len(g) + 1
    i1 = index(e(i0:), " /")
    if (i1 == 0) then
      i1 = len(e)
    else
      i1 = i0 + i1 - 2
    end if
    s = e(i0:i1)
    do k = 1, len(s)
      if (s(k:k) == new_line('a')) s(k:k) = ' '
    end do
    s = trim(adjustl(s))
  end function group_text

  !> Names of the groups opened at the start of a line of an echo.
  subroutine group_names(e, names)
    character(len=*), intent(in) :: e
    character(len=:), allocatable, intent(out) :: names(:)
    character(len=32) :: found(64)
    integer :: n, i, j
    n = 0
    i = 1
    do while (i <= len(e))
      if (e(i:i) == '&' .and. (i == 1 .or. e(max(i-1, 1):max(i-1, 1)) == new_line('a'))) then
        j = i + 1
        do while (j <= len(e))
          if (e(j:j) == ' ') exit
          j = j + 1
        end do
        if (n < size(found)) then
          n = n + 1
          found(n) = e(i+1:j-1)
        end if
        i = j
      else
        i = i + 1
      end if
    end do
    allocate(character(len=32) :: names(n))
    names = found(1:n)
  end subroutine group_names
end module cr_study_match
