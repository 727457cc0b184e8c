!> The online side of a ROM file (schema crowdrom-rom, version >= 2): its header, the list of
!> prepared pairs (N, R), and one pair loaded with its basis, cone candidates and stored
!> hyper-reduction (EIM bases and indices, EQ indices and weights).
module cr_rom_model
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error, prefix_error
  use cr_strings, only: str
  use cr_h5file, only: h5file_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_hyper_terms, only: hyper_terms_t
  implicit none
  private
  public :: rom_header_t, rom_pair_data_t, term_data_t, read_rom_header, load_rom_pair, find_pair

  character(len=2), parameter :: TERMS(3) = ['s1', 's2', 's3']

  !> What the ROM file says about itself.
  type :: rom_header_t
    character(len=:), allocatable :: path, database, db_hash, config
    integer :: n_agents = 0, n_dof = 0, n_steps = 0, n_dict = 0, n_pairs = 0
    real(wp) :: radius = 0, dt = 0
    integer, allocatable :: dict_ia(:), dict_ib(:), dict_ob(:)
    !> (N, R, basis size, hyper stored 1/0) of every pair [n_pairs]
    integer, allocatable :: pair_n(:), pair_r(:), pair_nb(:), pair_hyper(:)
  end type rom_header_t

  !> Stored hyper-reduction of one term.
  type :: term_data_t
    integer :: p = 0, m_eim = 0, m_eq = 0
    !> EIM basis [p, m_eim] and indices [m_eim]
    real(wp), allocatable :: eim_basis(:,:)
    integer, allocatable :: eim_idx(:)
    !> EQ indices [m_eq] and weights: w(1:k, k) after k points [m_eq, m_eq]
    integer, allocatable :: eq_idx(:)
    real(wp), allocatable :: eq_w(:,:)
  end type term_data_t

  !> One prepared reduced model.
  type :: rom_pair_data_t
    integer :: index = 0, n = 0, r = 0, n_pga = 0, nb = 0
    logical :: hyper = .false.
    !> velocity basis [n_dof, nb]
    real(wp), allocatable :: v(:,:)
    type(hyper_terms_t) :: terms
    type(term_data_t) :: term(3)
  end type rom_pair_data_t

contains

  !> Read the header and pair list of ROM file `path`; `where` prefixes messages
  !> (e.g. "input.nml: &rom: rom_file").
  subroutine read_rom_header(path, where, hdr, error)
    character(len=*), intent(in) :: path, where
    type(rom_header_t), intent(out) :: hdr
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    character(len=:), allocatable :: schema
    integer :: version, k
    call h5%open(path, error)
    if (allocated(error)) then
      error%message = where // " '" // path // "': cannot open (" // error%message // ")"
      error%code = 2; return
    end if
    hdr%path = path
    call h5%read_attr("/", "schema", schema, error)
    if (allocated(error)) then
      call set_error(error, where // " '" // path // "' is not a ROM file (no schema attribute)", 2); goto 9
    end if
    if (schema /= "crowdrom-rom") then
      call set_error(error, where // " '" // path // "' is not a ROM file (schema '" // schema // "')", 2); goto 9
    end if
    call h5%read_attr("/", "schema_version", version, error); if (allocated(error)) goto 9
    if (version < 2) then
      call set_error(error, where // " '" // path // "' has ROM schema version " // str(version) // &
        " without prepared pairs: rerun crowd_offline", 2); goto 9
    end if
    call h5%read_attr("/", "database", hdr%database, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "database_config_hash", hdr%db_hash, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "config", hdr%config, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_agents", hdr%n_agents, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_steps", hdr%n_steps, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "agent_radius", hdr%radius, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "dt", hdr%dt, error); if (allocated(error)) goto 9
    call h5%read_attr("/", "n_pairs", hdr%n_pairs, error); if (allocated(error)) goto 9
    hdr%n_dof = 2 * hdr%n_agents
    call h5%read("contacts/ia", hdr%dict_ia, error); if (allocated(error)) goto 9
    call h5%read("contacts/ib", hdr%dict_ib, error); if (allocated(error)) goto 9
    call h5%read("contacts/ob", hdr%dict_ob, error); if (allocated(error)) goto 9
    hdr%n_dict = size(hdr%dict_ia)
    allocate(hdr%pair_n(hdr%n_pairs), hdr%pair_r(hdr%n_pairs), hdr%pair_nb(hdr%n_pairs), hdr%pair_hyper(hdr%n_pairs))
    do k = 1, hdr%n_pairs
      call h5%read_attr("pairs/" // str(k), "n", hdr%pair_n(k), error); if (allocated(error)) goto 9
      call h5%read_attr("pairs/" // str(k), "r", hdr%pair_r(k), error); if (allocated(error)) goto 9
      call h5%read_attr("pairs/" // str(k), "n_basis", hdr%pair_nb(k), error); if (allocated(error)) goto 9
      call h5%read_attr("pairs/" // str(k), "hyper", hdr%pair_hyper(k), error); if (allocated(error)) goto 9
    end do
9   call h5%close(e2)
    if (allocated(error)) then
      if (error%code /= 2) call prefix_error(error, where // " '" // path // "'")
      return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine read_rom_header

  !> Index of the pair (n, r) in the header, or an error listing the stored pairs.
  subroutine find_pair(hdr, n, r, where, k, error)
    type(rom_header_t), intent(in) :: hdr
    integer, intent(in) :: n, r
    character(len=*), intent(in) :: where
    integer, intent(out) :: k
    type(error_t), allocatable, intent(out) :: error
    character(len=:), allocatable :: list
    integer :: j
    do k = 1, hdr%n_pairs
      if (hdr%pair_n(k) == n .and. hdr%pair_r(k) == r) return
    end do
    list = ""
    do j = 1, hdr%n_pairs
      list = list // " (" // str(hdr%pair_n(j)) // ", " // str(hdr%pair_r(j)) // ")"
    end do
    k = 0
    call set_error(error, where // ": (N, R) = (" // str(n) // ", " // str(r) // ") is not prepared in ROM file '" // &
      hdr%path // "' (stored pairs (N, R):" // list // "; add it to &offline rom_n / rom_r and rerun crowd_offline)", 2)
  end subroutine find_pair

  !> Load pair k of the ROM file.
  subroutine load_rom_pair(hdr, k, pair, error)
    type(rom_header_t), intent(in) :: hdr
    integer, intent(in) :: k
    type(rom_pair_data_t), intent(out) :: pair
    type(error_t), allocatable, intent(out) :: error
    type(h5file_t) :: h5
    type(error_t), allocatable :: e2
    type(sparse_cone_t) :: cone
    character(len=:), allocatable :: g, t
    integer, allocatable :: rows(:), s2_row(:), s2_dof(:)
    real(wp), allocatable :: w(:,:)
    integer :: j, l, nz
    call h5%open(hdr%path, error)
    if (allocated(error)) return
    g = "pairs/" // str(k)
    pair%index = k
    pair%n = hdr%pair_n(k); pair%r = hdr%pair_r(k); pair%nb = hdr%pair_nb(k)
    pair%n_pga = pair%nb - pair%n
    pair%hyper = hdr%pair_hyper(k) == 1
    call h5%read(g // "/v", pair%v, error); if (allocated(error)) goto 9
    call h5%read(g // "/cand/rows", rows, error); if (allocated(error)) goto 9
    call h5%read(g // "/cand/w", w, error); if (allocated(error)) goto 9
    call h5%read(g // "/cand/s2_row", s2_row, error); if (allocated(error)) goto 9
    call h5%read(g // "/cand/s2_dof", s2_dof, error); if (allocated(error)) goto 9
    if (size(pair%v, 1) /= hdr%n_dof .or. size(pair%v, 2) /= pair%nb .or. size(w, 2) /= pair%r .or. &
        size(w, 1) /= size(rows)) then
      call set_error(error, "ROM file '" // hdr%path // "': pair " // str(k) // " has inconsistent sizes"); goto 9
    end if
    ! the cone over the dictionary, from its support rows
    cone%r = pair%r; cone%n_dict = hdr%n_dict
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
    call pair%terms%init(cone, pair%r, hdr%dict_ia, hdr%dict_ib, hdr%dict_ob, hdr%n_dof, error)
    if (allocated(error)) goto 9
    if (size(pair%terms%rows) /= size(rows) .or. size(pair%terms%s2_row) /= size(s2_row)) then
      call set_error(error, "ROM file '" // hdr%path // "': pair " // str(k) // " candidate lists do not match its cone")
      goto 9
    end if
    if (any(pair%terms%rows /= rows) .or. any(pair%terms%s2_row /= s2_row) .or. any(pair%terms%s2_dof /= s2_dof)) then
      call set_error(error, "ROM file '" // hdr%path // "': pair " // str(k) // " candidate lists do not match its cone")
      goto 9
    end if
    if (pair%hyper) then
      do j = 1, 3
        pair%term(j)%p = pair%terms%p(j)
        t = g // "/eim/" // TERMS(j)
        call h5%read_attr(t, "m", pair%term(j)%m_eim, error); if (allocated(error)) goto 9
        if (pair%term(j)%m_eim > 0) then
          call h5%read(t // "/basis", pair%term(j)%eim_basis, error); if (allocated(error)) goto 9
          call h5%read(t // "/indices", pair%term(j)%eim_idx, error); if (allocated(error)) goto 9
        end if
        t = g // "/eq/" // TERMS(j)
        call h5%read_attr(t, "m", pair%term(j)%m_eq, error); if (allocated(error)) goto 9
        if (pair%term(j)%m_eq > 0) then
          call h5%read(t // "/indices", pair%term(j)%eq_idx, error); if (allocated(error)) goto 9
          call h5%read(t // "/weights", pair%term(j)%eq_w, error); if (allocated(error)) goto 9
        end if
      end do
    end if
9   call h5%close(e2)
    if (allocated(error)) then
      call prefix_error(error, "ROM file '" // hdr%path // "', pair " // str(k)); return
    end if
    if (allocated(e2)) call move_alloc(e2, error)
  end subroutine load_rom_pair
end module cr_rom_model
