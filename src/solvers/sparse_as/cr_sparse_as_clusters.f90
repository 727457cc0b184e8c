!> Cluster split of the sparse dual active-set projection: the connected clusters of the contact
!> graph (union-find over the agents); the rows of clusters with at most dense_rows rows go to
!> the dense kernel, the others to the sparse path, each as its own contact set, and the two
!> answers are put back together (the two sets of clusters share no agent).
module cr_sparse_as_clusters
  use cr_kinds, only: wp
  use cr_contact_set, only: contact_set_t
  implicit none
  private
  public :: cluster_split_t

  type :: cluster_split_t
    !> clusters of the contact graph: union-find parents [n_agents], rows per cluster root
    integer, allocatable :: parent(:), crows(:)
    !> the rows of small clusters (dense kernel) and of large ones (sparse path)
    type(contact_set_t) :: cs_small, cs_large
    integer, allocatable :: map_small(:), map_large(:)
    real(wp), allocatable :: u_small(:), u_large(:), l_small(:), l_large(:)
  contains
    procedure :: find_clusters
    procedure :: split_rows
    procedure :: merge_back
  end type cluster_split_t

contains

  !> The clusters of the contact graph of cs (every agent's parent is its cluster's root) and
  !> their rows; ns: the rows in clusters of at most dense_rows rows.
  subroutine find_clusters(this, cs, dense_rows, ns)
    class(cluster_split_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    integer, intent(in) :: dense_rows
    integer, intent(out) :: ns
    integer :: m, na, i, j, a, b
    m = cs%n; na = cs%n_agents
    if (allocated(this%parent)) then
      if (size(this%parent) < na) deallocate(this%parent, this%crows)
    end if
    if (.not. allocated(this%parent)) allocate(this%parent(max(na, 16)), this%crows(max(na, 16)))
    do i = 1, na
      this%parent(i) = i
    end do
    do j = 1, m
      if (cs%ib(j) > 0) then
        a = find(this%parent, cs%ia(j)); b = find(this%parent, cs%ib(j))
        if (a /= b) this%parent(max(a, b)) = min(a, b)
      end if
    end do
    ! every agent points at its cluster's root from here on (find(x) = parent(x))
    do i = 1, na
      this%parent(i) = find(this%parent, i)
    end do
    this%crows(1:na) = 0
    do j = 1, m
      a = this%parent(cs%ia(j))
      this%crows(a) = this%crows(a) + 1
    end do
    ns = 0
    do j = 1, m
      if (this%crows(this%parent(cs%ia(j))) <= dense_rows) ns = ns + 1
    end do
  end subroutine find_clusters

  !> The rows of cs (and their warm multipliers from lambda) into cs_small (ns rows of small
  !> clusters) and cs_large (the others), with their positions in cs (map_small, map_large).
  subroutine split_rows(this, cs, lambda, dense_rows, ns)
    class(cluster_split_t), intent(inout) :: this
    type(contact_set_t), intent(in) :: cs
    real(wp), intent(in) :: lambda(:)
    integer, intent(in) :: dense_rows, ns
    integer :: m, na, j, nl, ks, kl
    logical :: to_dense
    m = cs%n; na = cs%n_agents
    nl = m - ns
    call this%cs_small%init(na, cs%h, ns); call this%cs_large%init(na, cs%h, nl)
    if (allocated(this%map_small)) deallocate(this%map_small, this%map_large, this%l_small, &
      this%l_large, this%u_small, this%u_large)
    allocate(this%map_small(ns), this%map_large(nl), this%l_small(ns), this%l_large(nl), &
      this%u_small(2 * na), this%u_large(2 * na))
    ks = 0; kl = 0
    do j = 1, m
      to_dense = this%crows(this%parent(cs%ia(j))) <= dense_rows
      if (to_dense) then
        call this%cs_small%add(cs%ia(j), cs%ib(j), cs%ob(j), cs%g(:, j), cs%gap(j))
        ks = ks + 1; this%map_small(ks) = j; this%l_small(ks) = lambda(j)
      else
        call this%cs_large%add(cs%ia(j), cs%ib(j), cs%ob(j), cs%g(:, j), cs%gap(j))
        kl = kl + 1; this%map_large(kl) = j; this%l_large(kl) = lambda(j)
      end if
    end do
  end subroutine split_rows

  !> u and lambda of the whole problem from the two solves: each solver leaves the other's
  !> agents at v, so u is u_large with the agents of small clusters taken from u_small.
  subroutine merge_back(this, na, dense_rows, u, lambda)
    class(cluster_split_t), intent(in) :: this
    integer, intent(in) :: na, dense_rows
    real(wp), intent(out) :: u(:)
    real(wp), intent(inout) :: lambda(:)
    integer :: i
    u = this%u_large
    do i = 1, na
      if (this%crows(this%parent(i)) > 0 .and. this%crows(this%parent(i)) <= dense_rows) &
        u(2*i - 1:2*i) = this%u_small(2*i - 1:2*i)
    end do
    lambda(this%map_small) = this%l_small
    lambda(this%map_large) = this%l_large
  end subroutine merge_back

  !> The root of x's cluster, halving the path on the way.
  integer function find(parent, x) result(r)
    integer, intent(inout) :: parent(:)
    integer, intent(in) :: x
    r = x
    do while (parent(r) /= r)
      parent(r) = parent(parent(r))
      r = parent(r)
    end do
  end function find
end module cr_sparse_as_clusters
