!> The settings of the projection solvers (namelist group &solver, read by cr_config): a type
!> of its own in src/config so that the configuration does not depend on the solvers (the
!> solvers' module cr_projection re-exports it).
module cr_solver_settings
  use cr_kinds, only: wp
  implicit none
  private
  public :: projection_settings_t

  !> Settings of the projection solvers (one namelist group 'solver' upstream).
  type :: projection_settings_t
    !> solver name: 'sparse_active_set', 'active_set', 'gpcg', 'apgd' or 'uzawa'
    character(len=32) :: name = 'sparse_active_set'
    !> requested scaled KKT tolerance (see kkt_residuals)
    real(wp) :: tol = 1.0e-10_wp
    !> iteration cap of apgd, active_set and gpcg
    integer :: max_iter = 200000
    !> Uzawa step rho = uzawa_rho_factor / h^2
    real(wp) :: uzawa_rho_factor = 0.2_wp
    !> Uzawa stopping test on relative changes of u and lambda (paper's test)
    real(wp) :: uzawa_eps = 1.0e-12_wp
    !> Uzawa iteration cap
    integer :: uzawa_max_iter = 10000000
    !> start from the multipliers given on entry (otherwise from zero)
    logical :: warm_start = .true.
    !> sparse_active_set: problems with at most this many rows use the dense kernel
    integer :: dense_rows = 64
    !> sparse_active_set: refactorise after this many row additions/deletions of the factor
    integer :: refresh_every = 1000
  end type projection_settings_t
end module cr_solver_settings
