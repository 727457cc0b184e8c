!> A hyper-reduction method: one type that holds its offline build, its stored data and its
!> online assembly, so that a new method is one module (src/hyper/cr_hyper_<name>.f90) plus
!> one line in the factory (cr_hyper_factory).
!>
!> - Offline (`build`, collective, timed here): the method's `build_data` from the training set
!>   of one prepared pair (`hyper_train_t`: the pair's basis and cone candidates, the candidate
!>   snapshots of s1 = v(q), s2 = B(q), s3 = d(q) at the training configurations this rank
!>   holds, and those configurations); `max_points` caps the points of a term.
!> - Stored data (`write`, `read`): the method owns one group in each pair of the ROM file,
!>   `pairs/<k>/<storage()>`, with named datasets; the ROM file (cr_rom_file) calls these
!>   generically and writes the build time as the pair attribute `time_<storage()>`. A method
!>   whose `storage()` is '' stores nothing (the exact projection 'none').
!>   Each term k is one subgroup (`<storage()>/s1`, ...) whose attributes p (candidates),
!>   m (points) and an optional note are written and validated by `write_term_attrs` and
!>   `read_term_attrs`; the datasets below them are the method's.
!> - Online (`make_ops`): the assembly of the reduced problem of one time step, a
!>   `reduced_ops_t` (cr_reduced_base, whose `init_base` takes the basis, the support rows and
!>   the points), from the stored data; `choose_points` picks the points of each term.
module cr_hyper_method
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_env, only: env_t
  use cr_h5file, only: h5file_t
  use cr_scene, only: scene_t
  use cr_hyper_terms, only: hyper_terms_t
  use cr_reduced_base, only: reduced_ops_t
  use cr_product_check, only: product_error
  use cr_eim, only: eim_t, eim_build, eim_prefix
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: hyper_train_t, hyper_method_t, hyper_slot_t, choose_points, default_points, max_points, &
    points_cap, s1_eim, write_term_attrs, read_term_attrs, TERM_NAMES

  !> the three hyper-reduced terms s1 = v(q), s2 = B(q), s3 = d(q)
  character(len=2), parameter :: TERM_NAMES(3) = ['s1', 's2', 's3']

  !> What the offline build of one pair (N, R) sees.
  type :: hyper_train_t
    !> the pair's velocity basis [n_dof, nb] and cone candidates
    real(wp), allocatable :: v(:,:)
    type(hyper_terms_t) :: terms
    !> number of cone vectors R
    integer :: r = 0
    !> candidate snapshots at this rank's training configurations: s1 [p1, n_loc], s2 [p2, n_loc],
    !> s3 [p3, n_loc]
    real(wp), allocatable :: s1(:,:), s2(:,:), s3(:,:)
    !> this rank's training configurations q [n_dof, n_loc], their scenes (scene_of [n_loc]):
    !> the offline data's own arrays, not copies (valid during the build only)
    real(wp), pointer, contiguous :: q(:,:) => null()
    type(scene_t), pointer :: scenes(:) => null()
    integer, pointer, contiguous :: scene_of(:) => null()
    real(wp) :: radius = 0, dt = 0
    !> at most m_factor times the paper's default points (2 nb, R, 2 R); EQ tolerance
    real(wp) :: m_factor = 1, eq_tol = 0
    !> optional: the EIM of s1 built once for every pair (s1 = v(q) does not depend on the
    !> pair), requesting s1_shared_m >= this pair's points; `s1_eim` takes its prefix, which is
    !> bitwise what a new build would give (valid during the build only)
    type(eim_t), pointer :: s1_shared => null()
    integer :: s1_shared_m = 0
  end type hyper_train_t

  !> A hyper-reduction method (see the module header). The defaults of build_data, write, read
  !> and summary do nothing: a method that stores nothing implements storage and make_ops only.
  type, abstract :: hyper_method_t
    !> offline build time (s)
    real(wp) :: time = 0
  contains
    procedure(storage_i), deferred, nopass :: storage
    procedure(make_ops_i), deferred :: make_ops
    procedure, non_overridable :: build
    procedure :: build_data => no_build
    procedure :: write => no_write
    procedure :: read => no_read
    procedure :: summary => no_summary
  end type hyper_method_t

  !> One method (an array of different methods).
  type :: hyper_slot_t
    class(hyper_method_t), allocatable :: m
  end type hyper_slot_t

  abstract interface
    !> Name of the method's group in a pair of the ROM file ('' = nothing stored).
    function storage_i() result(g)
      character(len=:), allocatable :: g
    end function storage_i

    !> The online assembly `name` (a factory name served by this method's stored data) for the
    !> pair (n, r) with basis v [n_dof, nb] and candidates terms; m_req = requested points of
    !> s1, s2, s3 (0 = default); `where` prefixes error messages (code 2).
    subroutine make_ops_i(this, name, v, terms, n, r, m_req, where, ops, error)
      import :: hyper_method_t, hyper_terms_t, reduced_ops_t, error_t, wp
      class(hyper_method_t), intent(in) :: this
      character(len=*), intent(in) :: name, where
      real(wp), intent(in) :: v(:,:)
      type(hyper_terms_t), intent(in) :: terms
      integer, intent(in) :: n, r, m_req(3)
      class(reduced_ops_t), allocatable, intent(out) :: ops
      type(error_t), allocatable, intent(out) :: error
    end subroutine make_ops_i
  end interface

contains

  !> The offline build of one pair (collective): the method's build_data, timed (this%time).
  subroutine build(this, env, train, error)
    class(hyper_method_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(hyper_train_t), intent(in) :: train
    type(error_t), allocatable, intent(out) :: error
    real(wp) :: t0
    t0 = env%wtime()
    call this%build_data(env, train, error)
    if (allocated(error)) return
    this%time = env%wtime() - t0
  end subroutine build

  !> Build the stored data from the training set (collective; default: nothing to build).
  subroutine no_build(this, env, train, error)
    class(hyper_method_t), intent(inout) :: this
    type(env_t), intent(in) :: env
    type(hyper_train_t), intent(in) :: train
    type(error_t), allocatable, intent(out) :: error
  end subroutine no_build

  !> Write the stored data into `g // '/' // storage()` of an open ROM file (g: the pair's group).
  subroutine no_write(this, h5, g, error)
    class(hyper_method_t), intent(in) :: this
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: g
    type(error_t), allocatable, intent(out) :: error
  end subroutine no_write

  !> Read and validate the stored data from `g // '/' // storage()` of the ROM file `path`
  !> (terms: the pair's candidates, for the sizes); input errors (code 2) name file and dataset.
  subroutine no_read(this, h5, path, g, terms, error)
    class(hyper_method_t), intent(inout) :: this
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path, g
    type(hyper_terms_t), intent(in) :: terms
    type(error_t), allocatable, intent(out) :: error
  end subroutine no_read

  !> One-line summary of the stored data for the log.
  function no_summary(this) result(line)
    class(hyper_method_t), intent(in) :: this
    character(len=:), allocatable :: line
    line = ""
  end function no_summary

  !> Points per term: requested (m_req > 0), or the paper's default dflt capped by what is
  !> stored; refuses requests beyond the candidates cand or the stored points (code 2).
  subroutine choose_points(what, where, n, r, m_req, dflt, stored, cand, m, error)
    character(len=*), intent(in) :: what, where
    integer, intent(in) :: n, r, m_req(3), dflt(3), stored(3), cand(3)
    integer, intent(out) :: m(3)
    type(error_t), allocatable, intent(out) :: error
    character(len=3), parameter :: names(3) = ['m_v', 'm_b', 'm_d']
    integer :: j
    do j = 1, 3
      if (m_req(j) > cand(j)) then
        call set_error(error, where // ": " // names(j) // " = " // str(m_req(j)) // " is larger than the " // &
          str(cand(j)) // " " // what // " candidates of term s" // str(j) // " for (N, R) = (" // str(n) // &
          ", " // str(r) // ")", EXIT_BAD_INPUT); return
      end if
      if (m_req(j) > stored(j)) then
        call set_error(error, where // ": " // names(j) // " = " // str(m_req(j)) // " but the ROM file stores " // &
          str(stored(j)) // " " // what // " points for term s" // str(j) // " of (N, R) = (" // str(n) // &
          ", " // str(r) // ") (raise &hyper m_factor)", EXIT_BAD_INPUT); return
      end if
      if (m_req(j) > 0) then
        m(j) = m_req(j)
      else
        m(j) = min(dflt(j), stored(j))
      end if
    end do
  end subroutine choose_points

  !> The paper's default number of points of s1, s2, s3 for a basis of nb vectors and R cone
  !> vectors: (2 nb, R, 2 R).
  pure function default_points(nb, r) result(m)
    integer, intent(in) :: nb, r
    integer :: m(3)
    m = [2 * nb, r, 2 * r]
  end function default_points

  !> Most points the offline build of term k keeps: m_factor times the default
  !> (default_points), at least 1 and at most n_cand (the candidates).
  pure integer function max_points(train, k, n_cand) result(m_max)
    type(hyper_train_t), intent(in) :: train
    integer, intent(in) :: k, n_cand
    m_max = points_cap(size(train%v, 2), train%r, train%m_factor, k, n_cand)
  end function max_points

  !> max_points for a basis of nb vectors and R cone vectors (before the training set exists).
  pure integer function points_cap(nb, r, m_factor, k, n_cand) result(m_max)
    integer, intent(in) :: nb, r, k, n_cand
    real(wp), intent(in) :: m_factor
    integer :: mdef(3)
    mdef = default_points(nb, r)
    m_max = min(n_cand, max(1, ceiling(m_factor * mdef(k))))
  end function points_cap

  !> The EIM of s1 with m_max modes (collective): the prefix of the shared one when the
  !> training set carries one built for enough modes, else built from train%s1.
  subroutine s1_eim(env, train, m_max, eim, error)
    type(env_t), intent(in) :: env
    type(hyper_train_t), intent(in) :: train
    integer, intent(in) :: m_max
    type(eim_t), intent(out) :: eim
    type(error_t), allocatable, intent(out) :: error
    if (associated(train%s1_shared)) then
      if (m_max <= train%s1_shared_m) then
        call eim_prefix(train%s1_shared, train%s1_shared_m, m_max, eim, error)
        return
      end if
    end if
    call eim_build(env, train%s1, m_max, eim, error)
  end subroutine s1_eim

  !> Create the group t of one term and write its attributes: p (candidates), m (points) and
  !> the note when allocated.
  subroutine write_term_attrs(h5, t, p, m, note, error)
    type(h5file_t), intent(inout) :: h5
    character(len=*), intent(in) :: t
    integer, intent(in) :: p, m
    character(len=:), allocatable, intent(in) :: note
    type(error_t), allocatable, intent(out) :: error
    call h5%make_group(t, error); if (allocated(error)) return
    call h5%write_attr(t, "p", p, error); if (allocated(error)) return
    call h5%write_attr(t, "m", m, error); if (allocated(error)) return
    if (allocated(note)) call h5%write_attr(t, "note", note, error)
  end subroutine write_term_attrs

  !> Read and validate the attributes of the term group t written by write_term_attrs in the
  !> ROM file `path`: p must be p_expected (the candidates of the pair), m in 0..p; the note
  !> when present. Input errors (code 2) name the file and the group.
  subroutine read_term_attrs(h5, path, t, p_expected, p, m, note, error)
    type(h5file_t), intent(in) :: h5
    character(len=*), intent(in) :: path, t
    integer, intent(in) :: p_expected
    integer, intent(out) :: p, m
    character(len=:), allocatable, intent(inout) :: note
    type(error_t), allocatable, intent(out) :: error
    type(error_t), allocatable :: en
    character(len=:), allocatable :: s
    call h5%read_attr(t, "p", p, error); if (allocated(error)) return
    call h5%read_attr(t, "m", m, error); if (allocated(error)) return
    call h5%read_attr(t, "note", s, en)
    if (.not. allocated(en)) note = s
    if (p /= p_expected) then
      call product_error(path, "group '" // t // "': attribute p = " // str(p) // &
        ", but the pair has " // str(p_expected) // " candidates for this term", error); return
    end if
    if (m < 0 .or. m > p) then
      call product_error(path, "group '" // t // "': attribute m = " // str(m) // " outside 0.." // &
        str(p), error); return
    end if
  end subroutine read_term_attrs
end module cr_hyper_method
