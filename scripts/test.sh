#!/usr/bin/env bash
# Set up (packages, venv, both builds) and run the test suite:
#   1. the `unit` and `mpi` labels on the Release build (build/, -O3: the build users run),
#   2. everything on the Debug-checked build (build-debug/: -fcheck=all, FP traps).
# Extra arguments go to both ctest runs (e.g. -L unit, -L regression, -R test_nnls; several -L
# must all match, so `-L regression` selects nothing in the Release run). The script fails if
# any test of either run fails; its last line is the combined count `N passed, N failed`.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/setup.sh" --debug
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
LOG=$(mktemp -d)
trap 'rm -rf "$LOG"' EXIT

passed=0; failed=0; status=0
# run <name> <build dir> <ctest args...>: run ctest, add its counts to the totals
run() {
  local name=$1 dir=$2 rc=0 line total nfail
  shift 2
  echo "== $name ($dir)"
  (cd "$ROOT/$dir" && ctest --output-on-failure --no-tests=ignore -j "$(nproc)" "$@") 2>&1 | tee "$LOG/$name.log" \
    || rc=$?
  [ "$rc" -eq 0 ] || status=1
  # ctest's closing line: "NN% tests passed, F tests failed out of T"
  line=$(grep -E "tests passed, [0-9]+ tests? failed out of [0-9]+" "$LOG/$name.log" | tail -n 1 || true)
  if [ -n "$line" ]; then
    total=$(sed -E 's/.* out of ([0-9]+).*/\1/' <<<"$line")
    nfail=$(sed -E 's/.*passed, ([0-9]+) tests? failed.*/\1/' <<<"$line")
  else
    total=0; nfail=0
    # no summary line: nothing ran (no test matched) or ctest itself failed
    [ "$rc" -eq 0 ] || nfail=1
  fi
  passed=$((passed + total - nfail)); failed=$((failed + nfail))
  echo "== $name: $((total - nfail)) passed, $nfail failed"
}

run release-unit-mpi build -L '^(unit|mpi)$' "$@"
run debug-all build-debug "$@"
echo "test.sh: Release unit+mpi and Debug all"
echo "$passed passed, $failed failed"
exit "$status"
