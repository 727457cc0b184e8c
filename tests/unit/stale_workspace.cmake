# Solvers' results independent of their work space's content on entry (stale or never-written
# memory): see tests/unit/test_stale_workspace.f90 and scripts/dev/memcheck.sh.
cr_unit_test(test_stale_workspace)
