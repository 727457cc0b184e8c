!> Exact projection by clusters: the contact graph (agents linked by rows) is split into
!> connected components; agents without rows keep u_i = v_i, and each component is projected
!> by the sparse dual active-set solver of cr_contact_ldp (Cholesky of the passive Gram
!> matrix), warm started from the rows with lambda > 0 on entry. A cluster that solver cannot
!> finish (iteration cap, infeasible cluster) is handed to the dense least-distance solver of
!> cr_nnls (LDP -> Lawson-Hanson NNLS), which also returns least-violation velocities.
!> Clusters whose dense data would exceed max_dense_bytes are refused with an error.
module cr_active_set
  use cr_kinds, only: wp
  use cr_grow, only: igrow => grow_int, rgrow => grow_real
  use cr_error, only: error_t, prefix_error, set_error
  use cr_strings, only: str
  use cr_contact_set, only: contact_set_t
  use cr_nnls, only: nnls_work_t, ldp_stats_t, ldp_solve
  use cr_contact_ldp, only: contact_ldp_work_t, contact_ldp_stats_t, contact_ldp_solve, &
    contact_ldp_bytes
  use cr_projection, only: projection_solver_t, solve_stats_t, finish_stats, check_sizes, add_note
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: active_set_solver_t, default_max_dense_bytes

  !> default limit of the dense storage of one contact cluster: 2 GiB
  real(wp), parameter :: default_max_dense_bytes = 2.0_wp * 1024.0_wp**3

  !> Exact (active-set) projection, one dense LDP per contact cluster.
  type, extends(projection_solver_t) :: active_set_solver_t
    !> NNLS work space, reused across clusters and calls
    type(nnls_work_t) :: work
    !> work space of the sparse dual active-set solver
    type(contact_ldp_work_t) :: cwork
    !> largest dense storage (bytes) one cluster may need; larger clusters are an error
    real(wp) :: max_dense_bytes = default_max_dense_bytes
    !> union-find parents and component data [n_agents]
    integer, allocatable :: parent(:), comp(:), local(:), agents(:), astart(:)
    !> rows sorted by component and offsets [n rows], [n_comp + 1]
    integer, allocatable :: rows(:), rstart(:)
    !> dense cluster data
    real(wp), allocatable :: bm(:,:), dl(:), vl(:), ul(:), ll(:)
    !> sparse cluster rows: local agents [maxr], coefficients [2, maxr]
    integer, allocatable :: ial(:), ibl(:)
    real(wp), allocatable :: cl(:,:)
  contains
    procedure :: solve => active_set_solve
    procedure :: free => active_set_free
  end type active_set_solver_t

contains

  subroutine active_set_solve(this, cs, v, u, lambda, stats, error)
    class(active_set_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: v(:)
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    type(solve_stats_t), intent(out) :: stats
    type(error_t), allocatable, intent(out) :: error
    integer :: na, n, c, ncomp, maxr, maxa, n_infeas

    call check_sizes("active_set", cs, v, u, lambda, error)
    if (allocated(error)) return
    na = cs%n_agents; n = cs%n
    stats%note = ""
    stats%converged = .true.
    if (.not. this%settings%warm_start) lambda(1:n) = 0.0_wp
    u = v
    if (n == 0) then
      call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
      return
    end if
    call igrow(this%parent, na); call igrow(this%comp, na); call igrow(this%local, na)
    call igrow(this%agents, na); call igrow(this%astart, na + 1)
    call igrow(this%rows, n); call igrow(this%rstart, na + 1)
    call find_clusters(this, cs, ncomp)
    call sort_clusters(this, cs, ncomp, maxr, maxa)
    call rgrow(this%dl, maxr); call rgrow(this%ll, maxr)
    call rgrow(this%vl, 2 * maxa); call rgrow(this%ul, 2 * maxa)
    call igrow(this%ial, maxr); call igrow(this%ibl, maxr)
    if (allocated(this%cl)) then
      if (size(this%cl, 2) < maxr) deallocate(this%cl)
    end if
    if (.not. allocated(this%cl)) allocate(this%cl(2, max(maxr, 16)))

    ! ---- one sparse dual active-set solve per component (dense LDP as fallback)
    n_infeas = 0
    do c = 1, ncomp
      call solve_cluster(this, cs, c, maxr, maxa, v, u, lambda, stats, n_infeas, error)
      if (allocated(error)) return
    end do
    if (n_infeas > 0) call add_note(stats, str(n_infeas) // " infeasible cluster(s): " // &
      "least-violation velocities returned")
    if (.not. stats%converged) call add_note(stats, "iteration cap reached (" // &
      str(this%settings%max_iter) // ") in at least one cluster")
    call finish_stats(cs, v, u, lambda, this%settings%tol, stats)
  end subroutine active_set_solve

  !> Connected components of the contact graph (union-find with path halving): comp(i) the
  !> component of agent i (0 for agents without rows), ncomp the number of components.
  subroutine find_clusters(this, cs, ncomp)
    class(active_set_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    integer, intent(out) :: ncomp
    integer :: na, n, l, i, a, b
    na = cs%n_agents; n = cs%n
    do i = 1, na
      this%parent(i) = i
    end do
    do l = 1, n
      if (cs%ib(l) > 0) then
        a = find(this, cs%ia(l)); b = find(this, cs%ib(l))
        if (a /= b) this%parent(max(a, b)) = min(a, b)
      end if
    end do
    ! number the components that own rows; comp(i) = 0 for agents without rows
    this%comp(1:na) = 0
    ncomp = 0
    this%local(1:na) = 0
    do l = 1, n
      a = find(this, cs%ia(l))
      if (this%local(a) == 0) then
        ncomp = ncomp + 1
        this%local(a) = ncomp
      end if
    end do
    do i = 1, na
      a = find(this, i)
      this%comp(i) = this%local(a)
    end do
  end subroutine find_clusters

  !> Agents and rows sorted by component (counting sort): agents(astart(c):astart(c+1)-1),
  !> rows(rstart(c):rstart(c+1)-1), local(i) the place of agent i in its component; maxr,
  !> maxa the largest numbers of rows and agents of a component.
  subroutine sort_clusters(this, cs, ncomp, maxr, maxa)
    class(active_set_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: ncomp
    integer, intent(out) :: maxr, maxa
    integer :: na, n, l, i, c, j
    na = cs%n_agents; n = cs%n
    this%astart(1:ncomp + 1) = 0
    do i = 1, na
      if (this%comp(i) > 0) this%astart(this%comp(i) + 1) = this%astart(this%comp(i) + 1) + 1
    end do
    this%rstart(1:ncomp + 1) = 0
    do l = 1, n
      c = this%comp(cs%ia(l))
      this%rstart(c + 1) = this%rstart(c + 1) + 1
    end do
    this%astart(1) = 1; this%rstart(1) = 1
    do c = 1, ncomp
      this%astart(c + 1) = this%astart(c + 1) + this%astart(c)
      this%rstart(c + 1) = this%rstart(c + 1) + this%rstart(c)
    end do
    do i = 1, na
      c = this%comp(i)
      if (c == 0) cycle
      this%agents(this%astart(c)) = i
      this%local(i) = this%astart(c)          ! temporary: slot, fixed below
      this%astart(c) = this%astart(c) + 1
    end do
    do l = 1, n
      c = this%comp(cs%ia(l))
      this%rows(this%rstart(c)) = l
      this%rstart(c) = this%rstart(c) + 1
    end do
    do c = ncomp, 1, -1
      this%astart(c + 1) = this%astart(c)
      this%rstart(c + 1) = this%rstart(c)
    end do
    this%astart(1) = 1; this%rstart(1) = 1
    maxr = 0; maxa = 0
    do c = 1, ncomp
      maxr = max(maxr, this%rstart(c + 1) - this%rstart(c))
      maxa = max(maxa, this%astart(c + 1) - this%astart(c))
      do j = this%astart(c), this%astart(c + 1) - 1
        this%local(this%agents(j)) = j - this%astart(c) + 1
      end do
    end do
  end subroutine sort_clusters

  !> The sparse dual active-set solve of cluster c (the dense LDP when it does not finish):
  !> its velocities into u, its multipliers into lambda.
  subroutine solve_cluster(this, cs, c, maxr, maxa, v, u, lambda, stats, n_infeas, error)
    class(active_set_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: c, maxr, maxa
    real(wp), intent(in) :: v(:)
    real(wp), intent(inout) :: u(:), lambda(:)
    type(solve_stats_t), intent(inout) :: stats
    integer, intent(inout) :: n_infeas
    type(error_t), allocatable, intent(out) :: error
    type(contact_ldp_stats_t) :: cst
    integer :: mr, nd, j, l, a, i
    real(wp) :: h
    h = cs%h
    mr = this%rstart(c + 1) - this%rstart(c)
    nd = 2 * (this%astart(c + 1) - this%astart(c))
    if (contact_ldp_bytes(mr, nd) > this%max_dense_bytes) then
      call too_large(this, nd, mr, contact_ldp_bytes(mr, nd), error)
      return
    end if
    do j = 1, mr
      l = this%rows(this%rstart(c) + j - 1)
      this%ial(j) = this%local(cs%ia(l))
      this%ibl(j) = 0
      if (cs%ib(l) > 0) this%ibl(j) = this%local(cs%ib(l))
      this%cl(:, j) = -h * cs%g(:, l)
      this%dl(j) = cs%gap(l)
      this%ll(j) = lambda(l)
    end do
    do j = this%astart(c), this%astart(c + 1) - 1
      a = this%agents(j); i = j - this%astart(c) + 1
      this%vl(2*i - 1:2*i) = v(2*a - 1:2*a)
    end do
    call contact_ldp_solve(this%ial(1:mr), this%ibl(1:mr), this%cl(:, 1:mr), this%dl(1:mr), &
      this%vl(1:nd), this%ul(1:nd), this%ll(1:mr), cst, error, warm=this%settings%warm_start, &
      max_iter=min(this%settings%max_iter, 10 * mr + 100), &
      tol=1.0e-3_wp * this%settings%tol, work=this%cwork)
    if (allocated(error)) then
      call prefix_error(error, "active_set: cluster " // str(c))
      return
    end if
    stats%iterations = stats%iterations + cst%iterations
    if (.not. cst%converged .or. cst%infeasible) then
      call dense_cluster(this, cs, c, mr, nd, maxr, maxa, lambda, stats, n_infeas, error)
      if (allocated(error)) return
    end if
    do j = this%astart(c), this%astart(c + 1) - 1
      a = this%agents(j); i = j - this%astart(c) + 1
      u(2*a - 1:2*a) = this%ul(2*i - 1:2*i)
    end do
    do j = 1, mr
      lambda(this%rows(this%rstart(c) + j - 1)) = this%ll(j)
    end do
  end subroutine solve_cluster

  !> The dense LDP (cr_nnls) on cluster c (mr rows, nd velocities), warm started from the
  !> rows on entry.
  subroutine dense_cluster(this, cs, c, mr, nd, maxr, maxa, lambda, stats, n_infeas, error)
    class(active_set_solver_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: c, mr, nd, maxr, maxa
    real(wp), intent(in) :: lambda(:)
    type(solve_stats_t), intent(inout) :: stats
    integer, intent(inout) :: n_infeas
    type(error_t), allocatable, intent(out) :: error
    type(ldp_stats_t) :: ls
    real(wp) :: need, h
    integer :: j, l, a, b
    h = cs%h
    ! bm [mr, nd], E and Q of the NNLS, and the least-violation NNLS of an infeasible
    ! cluster (mr (2 nd + mr) + mr^2 reals)
    need = 8.0_wp * (real(mr, wp) * nd + real(nd + 1, wp) * mr + real(nd + 1, wp)**2 + &
      real(mr, wp) * (2 * nd + mr) + real(mr, wp)**2)
    if (need > this%max_dense_bytes) then
      call too_large(this, nd, mr, need, error)
      return
    end if
    call rgrow2(this%bm, maxr, 2 * maxa)
    this%bm(1:mr, 1:nd) = 0.0_wp
    do j = 1, mr
      l = this%rows(this%rstart(c) + j - 1)
      a = this%local(cs%ia(l))
      this%bm(j, 2*a - 1) = -h * cs%g(1, l)
      this%bm(j, 2*a) = -h * cs%g(2, l)
      if (cs%ib(l) > 0) then
        b = this%local(cs%ib(l))
        this%bm(j, 2*b - 1) = h * cs%g(1, l)
        this%bm(j, 2*b) = h * cs%g(2, l)
      end if
      this%ll(j) = lambda(l)
    end do
    call ldp_solve(this%bm(1:mr, 1:nd), this%dl(1:mr), this%vl(1:nd), this%ul(1:nd), &
      this%ll(1:mr), ls, error, warm=this%settings%warm_start, &
      max_iter=this%settings%max_iter, work=this%work)
    if (allocated(error)) then
      call prefix_error(error, "active_set: cluster " // str(c))
      return
    end if
    stats%iterations = stats%iterations + ls%nnls%iterations
    if (.not. ls%nnls%converged) stats%converged = .false.
    if (ls%infeasible) n_infeas = n_infeas + 1
  end subroutine dense_cluster

  !> The error of a cluster of nd / 2 agents and mr rows that needs more than max_dense_bytes.
  subroutine too_large(this, nd, mr, bytes, error)
    class(active_set_solver_t), intent(in) :: this
    integer, intent(in) :: nd, mr
    real(wp), intent(in) :: bytes
    type(error_t), allocatable, intent(out) :: error
    call set_error(error, "active_set: a contact cluster of " // str(nd / 2) // " agents and " // &
      str(mr) // " rows needs " // str(bytes / 1.0e9_wp, "f0.2") // " GB of dense storage " // &
      "(limit " // str(this%max_dense_bytes / 1.0e9_wp, "f0.2") // " GB); use solver 'gpcg' " // &
      "for crowds this large", EXIT_BAD_INPUT)
  end subroutine too_large

  !> Root of x in the union-find forest (path halving).
  integer function find(this, x) result(r)
    class(active_set_solver_t), intent(inout) :: this
    integer, intent(in) :: x
    r = x
    do while (this%parent(r) /= r)
      this%parent(r) = this%parent(this%parent(r))
      r = this%parent(r)
    end do
  end function find

  subroutine active_set_free(this)
    class(active_set_solver_t), intent(inout) :: this
    this%work = nnls_work_t()
    this%cwork = contact_ldp_work_t()
    if (allocated(this%parent)) deallocate(this%parent)
    if (allocated(this%bm)) deallocate(this%bm)
  end subroutine active_set_free

  subroutine rgrow2(a, m, n)
    real(wp), allocatable, intent(inout) :: a(:,:)
    integer, intent(in) :: m, n
    if (allocated(a)) then
      if (size(a, 1) >= m .and. size(a, 2) >= n) return
      deallocate(a)
    end if
    allocate(a(max(m, 16), max(n, 16)))
  end subroutine rgrow2
end module cr_active_set
