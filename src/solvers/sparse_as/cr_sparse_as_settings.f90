!> Tuning knobs of the sparse dual active-set projection (sparse_active_set) beyond the shared
!> projection_settings_t, with their measured defaults, and their validation (every solve
!> checks them first; a bad knob is an error naming it, never a division by zero later).
module cr_sparse_as_settings
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  use cr_kinds, only: wp
  use cr_error, only: error_t, set_error
  use cr_strings, only: str
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: sparse_as_settings_t, dep_tol

  !> relative pivot (rows of unit norm) below which an entering row counts as dependent
  real(wp), parameter :: dep_tol = 1.0e-10_wp

  !> The knobs of sparse_active_set (the solver's component `knobs`).
  type :: sparse_as_settings_t
    !> compare updated and fresh factors at every refresh (tests; costs one extra solve)
    logical :: check_drift = .false.
    !> more violated rows than max(bulk_min, k / bulk_div) enter by refactorisation
    integer :: bulk_min = 24, bulk_div = 4
    !> at most this many primal-dual active-set sweeps before the monotone loop
    integer :: pdas_max = 30
    !> the sweeps are used on problems with at least this many rows; off by default (measured:
    !> the monotone loop alone takes 2.4x fewer instructions on congested1000 and 12% less CPU
    !> time on congested100000, where the sweeps cycle; the sweeps save 14% on congested10000)
    integer :: pdas_rows = huge(1)
    !> step back by a projected search: lambda moves to the minimiser of f along the path
    !> max(0, lambda + t (z - lambda)), t in [0, 1], past as many breakpoints as f keeps
    !> falling (every row reaching zero on the way leaves P at once); otherwise the classical
    !> step to the first breakpoint
    logical :: proj_search = .true.
    !> only violated rows with a slack below add_frac times the most negative one enter at an outer
    !> iteration (0: every violated row), on problems with fewer than add_frac_rows rows. Measured
    !> (docs/benchmarks.md#tuned-parameters-of-sparse_active_set, add_frac): 0.5 takes 12% fewer
    !> instructions on congested150, 19% on congested1000 and halves the CPU time of the crowd1000
    !> scene; on congested10000 and congested100000 (one global threshold holds back the many
    !> separate jams) every violated row entering is 10-20% cheaper
    real(wp) :: add_frac = 0.5_wp
    integer :: add_frac_rows = 10000
    !> warm start by the step back from the warm multipliers (projected search towards the minimiser
    !> on the warm passive set) instead of dropping every row whose minimiser is not positive, on
    !> problems with fewer than warm_search_rows rows. Measured
    !> (docs/benchmarks.md#tuned-parameters-of-sparse_active_set, warm_search): 22% fewer row
    !> updates on congested150; on congested10000 1.7% more instructions than without
    logical :: warm_search = .true.
    integer :: warm_search_rows = 10000
    !> a row that a projected search brings from lambda > 0 to zero but that is violated at the new
    !> point (its slack, the gradient of f, is below -thr there) stays in P at zero instead of
    !> leaving: it would enter again at the next outer iteration (a deletion, an addition and an
    !> iteration saved). Only in the first keep_searches searches of a step back, and never for a
    !> row that was at zero when the search began, so the step back stays finite. Measured
    !> (docs/benchmarks.md#tuned-parameters-of-sparse_active_set, keep_violated): 2-3% fewer
    !> instructions on congested150 (four seeds), -0.7% on congested1000
    logical :: keep_violated = .true.
    integer :: keep_searches = 4
    !> rows analysed (the set W that can become active): warm-start rows and rows whose slack
    !> at u = v is below w_margin * (velocity scale); a violated row outside W enlarges W
    !> (re-analysis). w_margin < 0: every row is analysed.
    real(wp) :: w_margin = 1.0_wp
    !> reuse the analysis of an earlier solve: the analysed matrix is indexed by slots, one per
    !> row analysed, named by the row's contact identity. A later solve whose rows that can become
    !> active all have a slot factorises on the same analysis. The analysis is redone when a row
    !> that may become active has no slot, or when fewer than reuse_fill of the slots hold a row.
    !> A fresh analysis takes the rows whose slack at u = v is below a_margin (>= w_margin) times
    !> the velocity scale, so that it lasts. The rows that may become active: warm-start rows and
    !> rows whose slack at u = v is below r_margin times the velocity scale (0: the violated ones).
    !> Measured on congested150 (docs/benchmarks.md#tuned-parameters-of-sparse_active_set,
    !> a_margin): r_margin 0 and a_margin 2 take the fewest instructions.
    logical :: reuse_analysis = .true.
    real(wp) :: a_margin = 2.0_wp, reuse_fill = 0.5_wp, r_margin = 0.0_wp
    !> a fresh analysis appends tail_slots empty slots, ordered after the others; a violated row
    !> without a slot takes the next one instead of an enlargement of W (cr_sparse_as_slots)
    integer :: tail_slots = 16
  contains
    procedure :: validate => settings_validate
  end type sparse_as_settings_t

contains

  !> Every knob in its range (reals finite); error (code 2) naming the first one that is not.
  subroutine settings_validate(this, error)
    class(sparse_as_settings_t), intent(in) :: this
    type(error_t), allocatable, intent(out) :: error
    call int_at_least("bulk_min", this%bulk_min, 0, error); if (allocated(error)) return
    call int_at_least("bulk_div", this%bulk_div, 1, error); if (allocated(error)) return
    call int_at_least("pdas_max", this%pdas_max, 0, error); if (allocated(error)) return
    call int_at_least("pdas_rows", this%pdas_rows, 0, error); if (allocated(error)) return
    call int_at_least("add_frac_rows", this%add_frac_rows, 0, error); if (allocated(error)) return
    call int_at_least("warm_search_rows", this%warm_search_rows, 0, error)
    if (allocated(error)) return
    call int_at_least("keep_searches", this%keep_searches, 0, error); if (allocated(error)) return
    call int_at_least("tail_slots", this%tail_slots, 0, error); if (allocated(error)) return
    ! add_frac > 1 would let no violated row enter (a false convergence)
    call real_in("add_frac", this%add_frac, 0.0_wp, 1.0_wp, error); if (allocated(error)) return
    call real_in("reuse_fill", this%reuse_fill, 0.0_wp, 1.0_wp, error); if (allocated(error)) return
    call real_in("w_margin", this%w_margin, -huge(1.0_wp), huge(1.0_wp), error)
    if (allocated(error)) return
    call real_in("a_margin", this%a_margin, 0.0_wp, huge(1.0_wp), error); if (allocated(error)) return
    call real_in("r_margin", this%r_margin, 0.0_wp, huge(1.0_wp), error)
  end subroutine settings_validate

  subroutine int_at_least(name, value, lo, error)
    character(len=*), intent(in) :: name
    integer, intent(in) :: value, lo
    type(error_t), allocatable, intent(inout) :: error
    if (value < lo) call set_error(error, "sparse_active_set: knob " // name // " must be >= " // &
      str(lo) // ", got " // str(value), EXIT_BAD_INPUT)
  end subroutine int_at_least

  subroutine real_in(name, value, lo, hi, error)
    character(len=*), intent(in) :: name
    real(wp), intent(in) :: value, lo, hi
    type(error_t), allocatable, intent(inout) :: error
    if (.not. ieee_is_finite(value)) then
      call set_error(error, "sparse_active_set: knob " // name // " must be finite, got " // str(value), EXIT_BAD_INPUT)
    else if (value < lo .or. value > hi) then
      if (hi >= huge(1.0_wp)) then
        call set_error(error, "sparse_active_set: knob " // name // " must be >= " // str(lo) // &
          ", got " // str(value), EXIT_BAD_INPUT)
      else
        call set_error(error, "sparse_active_set: knob " // name // " must be in [" // str(lo) // ", " // &
          str(hi) // "], got " // str(value), EXIT_BAD_INPUT)
      end if
    end if
  end subroutine real_in
end module cr_sparse_as_settings
