!> The exit statuses of the programs, also the codes of `error_t` (`cr_error`): every driver
!> ends with the code of its error (`cr_program`'s program_finish), and the Python scripts use
!> the same values (`scripts/crowdrom_io.py`: EXIT_*; scripts/tests/test_agreement.py checks
!> that both agree).
module cr_exit_codes
  implicit none
  private
  public :: EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT, EXIT_STOPPED, EXIT_MPI

  !> success
  integer, parameter :: EXIT_OK = 0
  !> any other failure (the default code of an error_t): a failed write, a solver breakdown
  integer, parameter :: EXIT_FAILURE = 1
  !> bad input: a file, group, variable, dataset or argument refused with a one-line message
  integer, parameter :: EXIT_BAD_INPUT = 2
  !> the run stopped before its end on purpose or before any work (crowd_snapshots
  !> --stop-after; crowd_snapbench when its scratch file cannot be created)
  integer, parameter :: EXIT_STOPPED = 3
  !> a failed MPI call (set by env_t's status checks only; the program then ends by MPI_Abort)
  integer, parameter :: EXIT_MPI = 4
end module cr_exit_codes
