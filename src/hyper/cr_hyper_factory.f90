!> The hyper-reduction methods by name: the one place that lists them. A new method is a module
!> src/hyper/cr_hyper_<name>.f90 extending `hyper_method_t` (cr_hyper_method) plus its name in
!> HYPER_NAMES and one `case` in `new_hyper`; the offline stage builds, the ROM file stores and
!> reads, and crowd_rom assembles every registered method without further change.
module cr_hyper_factory
  use cr_error, only: error_t, set_error
  use cr_hyper_method, only: hyper_method_t, hyper_slot_t
  use cr_hyper_none, only: hyper_none_t
  use cr_hyper_eim, only: hyper_eim_t
  use cr_hyper_eq, only: hyper_eq_t
  use cr_exit_codes, only: EXIT_BAD_INPUT
  implicit none
  private
  public :: HYPER_NAMES, new_hyper, stored_hypers, hyper_known, hyper_name_list

  !> the accepted values of &sweep hyper
  character(len=8), parameter :: HYPER_NAMES(4) = [character(len=8) :: 'none', 'eim', 'eq', 'eq_deim']

contains

  !> The method serving `name` (code 2 and a one-line error naming the known ones otherwise).
  subroutine new_hyper(name, method, error)
    character(len=*), intent(in) :: name
    class(hyper_method_t), allocatable, intent(out) :: method
    type(error_t), allocatable, intent(out) :: error
    select case (trim(name))
    case ('none')
      allocate(hyper_none_t :: method)
    case ('eim')
      allocate(hyper_eim_t :: method)
    case ('eq', 'eq_deim')
      allocate(hyper_eq_t :: method)
    case default
      call set_error(error, "unknown hyper-reduction '" // trim(name) // "' (known: " // hyper_name_list() // ")", EXIT_BAD_INPUT)
    end select
  end subroutine new_hyper

  !> One fresh method per stored group (the methods the offline stage builds and a ROM file pair
  !> holds), in the order of HYPER_NAMES.
  subroutine stored_hypers(slots)
    type(hyper_slot_t), allocatable, intent(out) :: slots(:)
    class(hyper_method_t), allocatable :: m
    type(error_t), allocatable :: error
    character(len=16) :: groups(size(HYPER_NAMES))
    integer :: pick(size(HYPER_NAMES))
    integer :: k, n
    n = 0
    do k = 1, size(HYPER_NAMES)
      call new_hyper(HYPER_NAMES(k), m, error)
      if (m%storage() == '') cycle
      if (any(groups(1:n) == m%storage())) cycle
      n = n + 1
      groups(n) = m%storage()
      pick(n) = k
    end do
    allocate(slots(n))
    do k = 1, n
      call new_hyper(HYPER_NAMES(pick(k)), slots(k)%m, error)
    end do
  end subroutine stored_hypers

  !> Is `name` a registered method?
  pure logical function hyper_known(name)
    character(len=*), intent(in) :: name
    hyper_known = any(HYPER_NAMES == name)
  end function hyper_known

  !> "none, eim, eq, eq_deim"
  pure function hyper_name_list() result(list)
    character(len=:), allocatable :: list
    integer :: k
    list = trim(HYPER_NAMES(1))
    do k = 2, size(HYPER_NAMES)
      list = list // ", " // trim(HYPER_NAMES(k))
    end do
  end function hyper_name_list
end module cr_hyper_factory
