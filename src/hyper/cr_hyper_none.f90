!> Hyper-reduction 'none': the exact projection over every agent's desired velocity and every
!> support row of the cone (nothing stored; the reference the other methods approximate).
module cr_hyper_none
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_hyper_terms, only: hyper_terms_t
  use cr_hyper_method, only: hyper_method_t
  use cr_reduced_base, only: reduced_ops_t, eval_ctx_t, gram_setup, add_row, ensure
  use cr_contact_eval, only: eval_contact
  use cr_lapack, only: la_gemv
  implicit none
  private
  public :: hyper_none_t, ops_exact_t

  type, extends(hyper_method_t) :: hyper_none_t
  contains
    procedure, nopass :: storage => none_storage
    procedure :: make_ops => none_make_ops
  end type hyper_none_t

  !> Exact projection over the cone's support rows.
  type, extends(reduced_ops_t) :: ops_exact_t
    integer, allocatable :: ia(:), ib(:), ob(:)
    !> cone on the support rows [p3, R]
    real(wp), allocatable :: w(:,:)
    real(wp), allocatable :: vfull(:)
  contains
    procedure :: assemble => exact_assemble
  end type ops_exact_t

contains

  function none_storage() result(g)
    character(len=:), allocatable :: g
    g = ""
  end function none_storage

  subroutine none_make_ops(this, name, v, terms, n, r, m_req, where, ops, error)
    class(hyper_none_t), intent(in) :: this
    character(len=*), intent(in) :: name, where
    real(wp), intent(in) :: v(:,:)
    type(hyper_terms_t), intent(in) :: terms
    integer, intent(in) :: n, r, m_req(3)
    class(reduced_ops_t), allocatable, intent(out) :: ops
    type(error_t), allocatable, intent(out) :: error
    integer :: k
    allocate(ops_exact_t :: ops)
    select type (ops)
    type is (ops_exact_t)
      call ops%init_base(v, terms%w)
      ops%ia = terms%ia; ops%ib = terms%ib; ops%ob = terms%ob
      ops%w = terms%w
      allocate(ops%vfull(size(v, 1)))
      ops%agents = [(k, k = 1, size(v, 1) / 2)]
      call gram_setup(ops, v, terms%w)
    end select
  end subroutine none_make_ops

  subroutine exact_assemble(this, ctx, q, vhat, bt, dhat)
    class(ops_exact_t), intent(inout) :: this
    type(eval_ctx_t), intent(in) :: ctx
    real(wp), intent(in) :: q(:)
    real(wp), intent(out) :: vhat(:)
    real(wp), allocatable, intent(inout) :: bt(:,:), dhat(:)
    real(wp) :: gap, g(2)
    integer :: k, a, b, j, p
    call ctx%desired%evaluate(q, ctx%speeds, this%vfull)
    call la_gemv('N', 1.0_wp, this%vt, this%vfull, 0.0_wp, vhat)
    call ensure(bt, dhat, this%nb, this%r)
    bt = 0; dhat = 0
    if (this%has_gram) this%zn = 0
    do k = 1, size(this%ia)
      a = this%ia(k); b = this%ib(k)
      call eval_contact(ctx%scene, q, ctx%radius, a, b, this%ob(k), gap, g)
      do p = this%wp0(k) + 1, this%wp0(k + 1)
        j = this%wk(p)
        call add_row(bt(:, j), this%vt, this%wv(p) * ctx%h, a, b, g)
        dhat(j) = dhat(j) + this%wv(p) * gap
        if (this%has_gram) call this%z_add(j, this%wv(p), a, b, g, ctx%h)
      end do
    end do
  end subroutine exact_assemble
end module cr_hyper_none
