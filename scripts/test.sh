#!/usr/bin/env bash
# Set up (packages, venv, builds) and run the whole test suite on the Debug-checked build.
# Extra arguments go to ctest (e.g. -L unit, -L mpi, -L regression, -R test_nnls).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/setup.sh" --debug
cd "$ROOT/build-debug"
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
ctest --output-on-failure -j "$(nproc)" "$@"
