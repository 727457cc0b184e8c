!> Assembly of the reduced problem of one time step (the abstract `reduced_ops_t` and
!> `eval_ctx_t` of cr_reduced_base, re-exported here), by one of
!>   - a hyper-reduction method from the factory (cr_hyper_factory: 'none', 'eim', 'eq',
!>     'eq_deim'; each method's module in src/hyper holds its online assembly) with the
!>     cone's rows (contacts = 'cone'), from the data the ROM file stores for the pair;
!>   - 'online' (contacts = 'online'): the rows of B V of the contacts near in the reduced
!>     positions at this step (cell-list search, as the full-order model), each enforced on
!>     its own; vhat exact.
!> Each variant lists the agents whose positions it reads (`agents`); the stepper rebuilds
!> only those positions from the reduced coefficients.
module cr_reduced_ops
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t
  use cr_neighbours, only: cell_list_t, build_contacts
  use cr_rom_file, only: rom_pair_t
  use cr_lapack, only: la_gemv
  use cr_reduced_base, only: eval_ctx_t, reduced_ops_t, add_row
  use cr_hyper_method, only: hyper_method_t
  use cr_hyper_factory, only: HYPER_NAMES, new_hyper
  use cr_hyper_eim, only: ops_eim_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: eval_ctx_t, reduced_ops_t, make_reduced_ops, HYPER_NAMES, eim_exact_rows

  !> Near contacts of the reduced positions, each row enforced.
  type, extends(reduced_ops_t) :: ops_online_t
    type(cell_list_t) :: cells
    type(contact_set_t) :: cs
    real(wp) :: cutoff_factor = 1.5_wp
    real(wp), allocatable :: vfull(:)
  contains
    procedure :: assemble => online_assemble
  end type ops_online_t

contains

  !> Build the variant `hyper` (a factory name) with contacts 'cone' or 'online' for `pair`;
  !> m_req = requested (m_v, m_b, m_d), 0 = the method's default. `where` prefixes error
  !> messages.
  subroutine make_reduced_ops(hyper, contacts, pair, m_req, cutoff_factor, where, ops, error)
    character(len=*), intent(in) :: hyper, contacts
    type(rom_pair_t), intent(in) :: pair
    integer, intent(in) :: m_req(3)
    real(wp), intent(in) :: cutoff_factor
    character(len=*), intent(in) :: where
    class(reduced_ops_t), allocatable, intent(out) :: ops
    type(error_t), allocatable, intent(out) :: error
    class(hyper_method_t), allocatable :: method
    integer :: k, j, n_agents
    if (contacts == 'online') then
      n_agents = size(pair%v, 1) / 2
      allocate(ops_online_t :: ops)
      call ops%init_base(pair%v, pair%terms%w, pair%terms%ia, pair%terms%ib, pair%terms%ob)
      select type (ops)
      type is (ops_online_t)
        ops%cutoff_factor = cutoff_factor
        ops%fixed_rows = .false.
        allocate(ops%vfull(2 * n_agents))
        call ops%cs%init(n_agents, 1.0_wp, 8 * n_agents)
        ! Gram entries of contact rows (4 dofs each) for the dual active-set solver
        ops%zmax = 4
        ops%has_gram = pair%nb >= 16 .and. 2 * n_agents <= 4000
        if (ops%has_gram) ops%pmat = matmul(pair%v, transpose(pair%v))
        allocate(ops%zn(0), ops%zdof(4, 0), ops%zval(4, 0), ops%keys(0))
      end select
      ops%agents = [(k, k = 1, n_agents)]
      return
    end if
    call new_hyper(hyper, method, error)
    if (allocated(error)) then
      error%message = where // ": " // error%message; return
    end if
    if (method%storage() == '') then
      call method%make_ops(trim(hyper), pair%v, pair%terms, pair%n, pair%r, m_req, where, ops, error)
      return
    end if
    j = 0
    if (pair%hyper .and. allocated(pair%methods)) then
      do k = 1, size(pair%methods)
        if (pair%methods(k)%m%storage() == method%storage()) j = k
      end do
    end if
    if (j == 0) then
      call set_error(error, where // ": the ROM file stores no hyper-reduction '" // method%storage() // &
        "' for (N, R) = (" // str(pair%n) // ", " // str(pair%r) // ") (&hyper enabled = .false.); use hyper = 'none'", &
        EXIT_BAD_INPUT)
      return
    end if
    call pair%methods(j)%m%make_ops(trim(hyper), pair%v, pair%terms, pair%n, pair%r, m_req, where, ops, error)
  end subroutine make_reduced_ops

  subroutine online_assemble(this, ctx, q, vhat, bt, dhat)
    class(ops_online_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    real(wp) :: vmax, cutoff
    integer :: l, a, b, i
    call ctx%desired%evaluate(q, ctx%speeds, this%vfull)
    call la_gemv('N', 1.0_wp, this%vt, this%vfull, 0.0_wp, vhat)
    vmax = 0
    do i = 1, size(ctx%speeds)
      vmax = max(vmax, norm2(this%vfull(2*i-1:2*i)))
    end do
    ! the full-order model's candidate rule (the reduced velocity is not known yet)
    cutoff = max(this%cutoff_factor * 2 * ctx%h * vmax, 1.0e-12_wp * ctx%radius)
    this%cs%h = ctx%h
    call build_contacts(ctx%scene, q, ctx%radius, cutoff, this%cells, this%cs)
    if (allocated(bt)) then
      if (size(bt, 2) /= this%cs%n) deallocate(bt, dhat)
    end if
    if (.not. allocated(bt)) allocate(bt(this%nb, this%cs%n), dhat(this%cs%n))
    if (size(this%keys) < this%cs%n) then
      deallocate(this%keys, this%zn, this%zdof, this%zval)
      allocate(this%keys(2 * this%cs%n), this%zn(2 * this%cs%n), this%zdof(4, 2 * this%cs%n), &
        this%zval(4, 2 * this%cs%n))
    end if
    do l = 1, this%cs%n
      a = this%cs%ia(l); b = this%cs%ib(l)
      bt(:, l) = 0
      call add_row(bt(:, l), this%vt, ctx%h, a, b, this%cs%g(:, l))
      dhat(l) = this%cs%gap(l)
      this%keys(l) = this%cs%key(l)
      if (this%has_gram) then
        this%zn(l) = 0
        call this%z_add(l, 1.0_wp, a, b, this%cs%g(:, l), ctx%h)
      end if
    end do
  end subroutine online_assemble

  !> Rows the EIM assembly evaluated exactly since `ops` was made (interpolated normal shorter
  !> than 1/2); 0 for the other variants.
  integer function eim_exact_rows(ops) result(n)
    class(reduced_ops_t), intent(in) :: ops
    n = 0
    select type (ops)
    type is (ops_eim_t)
      n = ops%n_exact_rows
    end select
  end function eim_exact_rows
end module cr_reduced_ops
