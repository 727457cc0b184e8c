!> The Uzawa scheme of the paper (section 2, eqs. Uzawa_u / Uzawa_lambda):
!>   u_{k+1} = v - B^T lambda_k,  lambda_{k+1} = max(0, lambda_k + rho (B u_{k+1} - d)),
!> rho = uzawa_rho_factor / h^2, stopped when the relative changes of u and of lambda,
!> |x_k - x_{k-1}| / (|x_{k-1}| + 1), are both <= uzawa_eps.
!>
!> Divergence: with rho above the convergence bound the iterates may grow without limit.
!> Once h max(lambda) exceeds DIVERGED times the velocity scale of the problem (no converged
!> multiplier comes near: that would mean forces 1e100 times the desired motion), or an
!> iterate is not finite, the solve stops with an error naming rho and the bound, before
!> any overflow: there is no usable velocity to return.
module cr_uzawa
  use cr_kinds, only: wp
  use cr_grow, only: grow => grow_real
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t, velocity_scale
  use cr_projection, only: projection_solver_t, solve_stats_t, finish_stats, check_sizes, add_note
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: uzawa_solver_t

  !> divergence threshold on h max(lambda) / velocity scale
  real(wp), parameter :: DIVERGED = 1.0e100_wp

  !> Uzawa projection (fixed-step projected gradient on the dual).
  type, extends(projection_solver_t) :: uzawa_solver_t
    !> work arrays, grown when needed: [2*n_agents] and [n rows]
    real(wp), allocatable :: uold(:), lold(:), bu(:), btl(:)
  contains
    procedure :: solve => uzawa_solve
    procedure :: free => uzawa_free
  end type uzawa_solver_t

contains

  subroutine uzawa_solve(this, cs, v, u, lambda, stats, error)
    class(uzawa_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer :: n, nd, k
    real(wp) :: rho, lb, du, dl, nu, nl, sv

    call check_sizes("uzawa", cs, v, u, lambda, error)
    if (allocated(error)) return
    n = cs%n; nd = size(v)
    stats%note = ""
    call grow(this%uold, nd); call grow(this%btl, nd)
    call grow(this%lold, n); call grow(this%bu, n)
    if (.not. this%settings%warm_start) lambda(1:n) = 0.0_wp
    lambda(1:n) = max(lambda(1:n), 0.0_wp)
    if (n == 0) then
      u = v
      stats%converged = .true.
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      return
    end if
    rho = this%settings%uzawa_rho_factor / cs%h**2
    lb = cs%lipschitz_bound()
    if (lb > 0.0_wp .and. rho > 2.0_wp / lb) then
      stats%rho_above_bound = .true.
      call add_note(stats, "rho = " // str(rho, "es9.2") // " above the convergence bound 2/L = " &
        // str(2.0_wp / lb, "es9.2") // " (L: Gershgorin bound of ||B||^2)")
    end if
    sv = velocity_scale(cs, v)
    u = v
    do k = 1, this%settings%uzawa_max_iter
      this%uold(1:nd) = u
      this%lold(1:n) = lambda(1:n)
      call cs%apply_bt(lambda(1:n), this%btl(1:nd))
      u = v - this%btl(1:nd)
      call cs%apply_b(u, this%bu(1:n))
      lambda(1:n) = max(0.0_wp, lambda(1:n) + rho * (this%bu(1:n) - cs%gap(1:n)))
      stats%iterations = k
      if (.not. (cs%h * maxval(lambda(1:n)) <= DIVERGED * sv)) then
        call set_error(error, "uzawa: diverged at iteration " // str(k) // " (multipliers beyond 1e100 " // &
          "times the velocity scale): rho = uzawa_rho_factor / h^2 = " // str(rho, "es9.2") // " " // &
          trim(merge("exceeds ", "is below", rho > 2.0_wp / lb)) // " the convergence bound 2/L = " // &
          str(2.0_wp / lb, "es9.2") // "; lower uzawa_rho_factor (at most " // &
          str(2.0_wp * cs%h**2 / lb, "es9.2") // " is safe for these contacts)", EXIT_BAD_INPUT)
        return
      end if
      if (k > 1) then
        du = norm2(u - this%uold(1:nd)); nu = norm2(this%uold(1:nd))
        dl = norm2(lambda(1:n) - this%lold(1:n)); nl = norm2(this%lold(1:n))
        if (du <= this%settings%uzawa_eps * (nu + 1.0_wp) .and. &
            dl <= this%settings%uzawa_eps * (nl + 1.0_wp)) then
          stats%converged = .true.
          exit
        end if
      end if
    end do
    if (.not. stats%converged) call add_note(stats, "iteration cap reached (" // &
      str(this%settings%uzawa_max_iter) // ")")
    call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
  end subroutine uzawa_solve

  subroutine uzawa_free(this)
    class(uzawa_solver_t), intent(inout) :: this
    if (allocated(this%uold)) deallocate(this%uold)
    if (allocated(this%lold)) deallocate(this%lold)
    if (allocated(this%bu)) deallocate(this%bu)
    if (allocated(this%btl)) deallocate(this%btl)
  end subroutine uzawa_free

  !> Make sure a has at least n entries (contents not kept).
end module cr_uzawa
