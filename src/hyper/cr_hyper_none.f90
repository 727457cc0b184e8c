!> Hyper-reduction 'none': the exact projection over every agent's desired velocity and every
!> support row of the cone (nothing stored; the reference the other methods approximate).
module cr_hyper_none
  use cr_kinds, only: wp
  use cr_error, only: error_t
  use cr_hyper_terms, only: hyper_terms_t
  use cr_hyper_method, only: hyper_method_t
  use cr_reduced_base, only: reduced_ops_t, eval_ctx_t, gram_setup, ensure
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
    !> the desired velocity of every agent [n_dof]
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
      call ops%init_base(v, terms%w, terms%ia, terms%ib, terms%ob)
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
    integer :: l
    call ctx%desired%evaluate(q, ctx%speeds, this%vfull)
    call la_gemv('N', 1.0_wp, this%vt, this%vfull, 0.0_wp, vhat)
    call ensure(bt, dhat, this%nb, this%r)
    bt = 0; dhat = 0
    if (this%has_gram) this%zn = 0
    do l = 1, size(this%ia)
      call eval_contact(ctx%scene, q, ctx%radius, this%ia(l), this%ib(l), this%ob(l), gap, g)
      call this%add_support_row(l, g, ctx%h, bt, gap, dhat)
    end do
  end subroutine exact_assemble
end module cr_hyper_none
