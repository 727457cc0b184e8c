!> The three non-affine terms of the reduced problem and their candidate entries (the paper's
!> section 3.3): s1 = v(q) (desired velocities, one entry per dof), s2 = B(q) (the non-zeros
!> of the contact rows in the cone's support: 4 per agent pair, 2 per agent-obstacle row),
!> s3 = d(q) (the gaps of those rows). Only entries that can be non-zero are candidates.
!>
!> EIM interpolates the entries of each term (s2: the non-zeros of B). Empirical Quadrature
!> works on the projected quantities as sums over candidates (the paper's decomposition):
!>   Pi1 = V^T v   = sum_j v_j V(j,:)                       candidates: dofs j
!>   Pi2 = W^T B V = sum_l W(l,:)^T (x) (b_l(q) V)          candidates: rows l of B
!>   Pi3 = W^T d   = sum_l d_l W(l,:)                       candidates: rows l
!> so its Gramians are H1 = (sum s1 s1^T) o (V V^T), H3 = (sum s3 s3^T) o (W W^T) and
!> H2 = (sum_sigma Y Y^T) o (W W^T) with the row images Y(sigma) = B(q_sigma) V restricted to
!> the support rows [p3, Nb]; no dense q x p matrix is ever formed.
module cr_hyper_terms
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_scene, only: scene_t
  use cr_sparse_cone, only: sparse_cone_t
  use cr_contact_eval, only: eval_contact
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: hyper_terms_t, contact_row_image

  !> Candidate entries of s1, s2, s3 for one reduced cone.
  type :: hyper_terms_t
    integer :: n_dof = 0
    !> number of cone vectors R
    integer :: r = 0
    !> dictionary rows in the support of the cone [p3], their agents and obstacle [p3]
    integer, allocatable :: rows(:), ia(:), ib(:), ob(:)
    !> the cone restricted to its support rows [p3, R]
    real(wp), allocatable :: w(:,:)
    !> s2 candidates: position in rows (1..p3), dof (1..n_dof), sign (B = -h G: -1 on the
    !> first agent's slots, +1 on the second's) [p2]
    integer, allocatable :: s2_row(:), s2_dof(:)
    real(wp), allocatable :: s2_sgn(:)
  contains
    procedure :: init
    procedure :: p
    procedure :: kernel
    procedure :: row_images
    procedure :: snapshot
    procedure :: s2_value
  end type hyper_terms_t

contains

  !> Candidates of the first `r` vectors of `cone` over the dictionary (dict_* [n_dict]).
  subroutine init(this, cone, r, dict_ia, dict_ib, dict_ob, n_dof, error)
    class(hyper_terms_t), intent(inout) :: this
    type(sparse_cone_t), intent(in) :: cone
    integer, intent(in) :: r
    integer, intent(in) :: dict_ia(:), dict_ib(:), dict_ob(:)
    integer, intent(in) :: n_dof
    type(error_t), allocatable, intent(out) :: error
    logical, allocatable :: used(:)
    integer, allocatable :: pos(:)
    integer :: k, p, l, n3, n2
    if (r < 0 .or. r > cone%r) then
      call set_error(error, "hyper terms: R = " // str(r) // " but the cone has " // str(cone%r) // " vectors", EXIT_BAD_INPUT)
      return
    end if
    this%n_dof = n_dof
    this%r = r
    allocate(used(size(dict_ia)), pos(size(dict_ia)))
    used = .false.
    do k = 1, r
      do p = cone%ptr(k) + 1, cone%ptr(k + 1)
        if (cone%val(p) /= 0) used(cone%idx(p)) = .true.
      end do
    end do
    n3 = count(used)
    allocate(this%rows(n3))
    n3 = 0
    pos = 0
    do l = 1, size(used)
      if (used(l)) then
        n3 = n3 + 1
        this%rows(n3) = l
        pos(l) = n3
      end if
    end do
    this%ia = dict_ia(this%rows)
    this%ib = dict_ib(this%rows)
    this%ob = dict_ob(this%rows)
    allocate(this%w(n3, r))
    this%w = 0
    do k = 1, r
      do p = cone%ptr(k) + 1, cone%ptr(k + 1)
        if (pos(cone%idx(p)) > 0) this%w(pos(cone%idx(p)), k) = cone%val(p)
      end do
    end do
    n2 = 2 * n3 + 2 * count(this%ib > 0)
    allocate(this%s2_row(n2), this%s2_dof(n2), this%s2_sgn(n2))
    n2 = 0
    do k = 1, n3
      call add(k, 2 * this%ia(k) - 1, -1.0_wp)
      call add(k, 2 * this%ia(k), -1.0_wp)
      if (this%ib(k) > 0) then
        call add(k, 2 * this%ib(k) - 1, 1.0_wp)
        call add(k, 2 * this%ib(k), 1.0_wp)
      end if
    end do
  contains
    subroutine add(row, dof, sgn)
      integer, intent(in) :: row, dof
      real(wp), intent(in) :: sgn
      n2 = n2 + 1
      this%s2_row(n2) = row; this%s2_dof(n2) = dof; this%s2_sgn(n2) = sgn
    end subroutine add
  end subroutine init

  !> Number of candidates of term k (1, 2, 3).
  pure integer function p(this, k)
    class(hyper_terms_t), intent(in) :: this
    integer, intent(in) :: k
    select case (k)
    case (1)
      p = this%n_dof
    case (2)
      p = size(this%s2_row)
    case default
      p = size(this%rows)
    end select
  end function p

  !> EQ kernel of term k for the velocity basis v [n_dof, Nb]: K [n, n] with n = n_dof
  !> (k = 1) or p3 (k = 2, 3: rows of the support).
  subroutine kernel(this, k, v, kmat)
    class(hyper_terms_t), intent(in) :: this
    integer, intent(in) :: k
    real(wp), intent(in) :: v(:,:)
    real(wp), allocatable, intent(out) :: kmat(:,:)
    if (k == 1) then
      kmat = matmul(v, transpose(v))
    else
      kmat = matmul(this%w, transpose(this%w))
    end if
  end subroutine kernel

  !> Row images y(k, :) = b_l(q) V of the support rows l = rows(k) at q: y [p3, Nb].
  subroutine row_images(this, scene, q, radius, h, v, y)
    class(hyper_terms_t), intent(in) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:), radius, h, v(:,:)
    real(wp), intent(out) :: y(:,:)
    real(wp) :: gap, g(2)
    integer :: k, a, b
    do k = 1, size(this%rows)
      a = this%ia(k); b = this%ib(k)
      call eval_contact(scene, q, radius, a, b, this%ob(k), gap, g)
      y(k, :) = contact_row_image(v, a, b, g, h)
    end do
  end subroutine row_images

  !> Value of s2 candidate i at positions q: the entry of B = -h G.
  real(wp) function s2_value(this, i, scene, q, radius, h) result(val)
    class(hyper_terms_t), intent(in) :: this
    integer, intent(in) :: i
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:), radius, h
    real(wp) :: gap, g(2)
    integer :: k
    k = this%s2_row(i)
    call eval_contact(scene, q, radius, this%ia(k), this%ib(k), this%ob(k), gap, g)
    val = this%s2_sgn(i) * h * g(2 - mod(this%s2_dof(i), 2))
  end function s2_value

  !> All candidate values at one configuration q [n_dof] with desired velocity vd [n_dof]:
  !> s1 [n_dof], s2 [p2], s3 [p3].
  subroutine snapshot(this, scene, q, vd, radius, h, s1, s2, s3)
    class(hyper_terms_t), intent(in) :: this
    type(scene_t), intent(in) :: scene
    real(wp), intent(in) :: q(:), vd(:), radius, h
    real(wp), intent(out) :: s1(:), s2(:), s3(:)
    real(wp), allocatable :: gx(:,:)
    real(wp) :: gap, g(2)
    integer :: k, i
    s1 = vd
    allocate(gx(2, size(this%rows)))
    do k = 1, size(this%rows)
      call eval_contact(scene, q, radius, this%ia(k), this%ib(k), this%ob(k), gap, g)
      s3(k) = gap
      gx(:, k) = g
    end do
    do i = 1, size(this%s2_row)
      s2(i) = this%s2_sgn(i) * h * gx(2 - mod(this%s2_dof(i), 2), this%s2_row(i))
    end do
  end subroutine snapshot
  !> b V for the contact row b of agents a, b (b = 0: obstacle) with unit normal g:
  !> B = -h G puts -h g on agent a's dofs and +h g on agent b's; v [n_dof, Nb] -> [Nb].
  pure function contact_row_image(v, a, b, g, h) result(y)
    real(wp), intent(in) :: v(:,:), g(2), h
    integer, intent(in) :: a, b
    real(wp) :: y(size(v, 2))
    y = -h * (g(1) * v(2*a-1, :) + g(2) * v(2*a, :))
    if (b > 0) y = y + h * (g(1) * v(2*b-1, :) + g(2) * v(2*b, :))
  end function contact_row_image
end module cr_hyper_terms
