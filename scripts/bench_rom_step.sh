#!/usr/bin/env bash
# Time per reduced step of crowd_rom on congested150, (N, R) = (50, 75), validation set, with the
# dual active-set solver and with the Lawson-Hanson NNLS, for eq / cone and none / online, next
# to the exact full-order step timed in the same run. Needs the offline products of
# inputs/congested150_study.nml (stages 1-2 of scripts/run_study.sh) in results/.
#   scripts/bench_rom_step.sh [solver ...]       (default: dual nnls)
# Writes results/bench_rom_step_<solver>.nml, .h5, .csv and prints the log lines with the
# figures. Single-threaded BLAS; OPENBLAS_CORETYPE is left as the caller sets it.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
[ -f results/congested150_rom.h5 ] || { echo "bench_rom_step: error: results/congested150_rom.h5 not found (run stages 1-2 of scripts/run_study.sh congested150)" >&2; exit 2; }
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
SOLVERS=("$@")
[ ${#SOLVERS[@]} -gt 0 ] || SOLVERS=(dual nnls)
for s in "${SOLVERS[@]}"; do
  f=results/bench_rom_step_$s.nml
  cat > "$f" <<NML
&rom
  rom_file = 'results/congested150_rom.h5', output = 'results/bench_rom_step_$s.h5',
  table = 'results/bench_rom_step_$s.csv', sets = 'valid', fom_timing_samples = 2, fom_uzawa_steps = 2,
  timing_repeats = 3, solver = '$s',
  n        = 50,     50
  r        = 75,     75
  hyper    = 'eq',   'none'
  contacts = 'cone', 'online'
/
NML
  echo "=== solver $s"
  build/bin/crowd_rom "$f" 2>&1 | grep -E "full-order|E_avg|dual active|s/step|warn" || true
done
