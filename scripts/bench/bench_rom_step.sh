#!/usr/bin/env bash
# Time per reduced step of crowd_rom on congested150, (N, R) = (50, 75), validation set, for
# each given reduced solver (default: dual nnls): eq / cone on the 50 samples (fastest of 5 runs
# per sample), none / online and eq / cone with the local exact correction on the first 10
# samples (one run each), next to the full-order steps timed in the same runs (the exact
# reference: the fastest exact solver of the build). Needs the offline products of inputs/congested150_study.nml
# (stages 1-2 of scripts/run_study.sh) in results/.
#   scripts/bench/bench_rom_step.sh [solver ...]
# Writes results/bench_rom_step_<solver>_{eq,online,local}.nml/.h5/.csv and prints crowd_rom's lines
# with the figures (time per step and its parts, hand-overs to the NNLS, active rows).
# Single-threaded BLAS; OPENBLAS_CORETYPE is left as the caller sets it.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
[ -f results/congested150_rom.h5 ] || { echo "bench_rom_step: error: results/congested150_rom.h5 not found (run stages 1-2 of scripts/run_study.sh congested150)" >&2; exit 2; }
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
SOLVERS=("$@")
[ ${#SOLVERS[@]} -gt 0 ] || SOLVERS=(dual nnls)
run() {  # run <solver> <tag> <hyper> <contacts> <n_samples> <repeats> [correction]
  local f=results/bench_rom_step_$1_$2.nml
  cat > "$f" <<NML
&rom
  rom_file = 'results/congested150_rom.h5', output = 'results/bench_rom_step_$1_$2.h5',
  table = 'results/bench_rom_step_$1_$2.csv', sets = 'valid', n_samples = $5, timing_repeats = $6
/
&fom_timing samples = 2, uzawa_steps = 1 /
&reduced solver = '$1' /
&sweep n = 50, r = 75, hyper = '$3', contacts = '$4', correction = '${7:-none}' /
NML
  echo "=== solver $1, $3 / $4 / correction ${7:-none} ($5 samples, fastest of $6 runs)"
  build/bin/crowd_rom "$f" 2>&1 | grep -E "s/step \(largest|reference:|E_avg|dual active|local correction|time per step|warn" | grep -v "sample .* of" || true
}
for s in "${SOLVERS[@]}"; do
  run "$s" eq eq cone 0 5
  run "$s" online none online 10 1
  run "$s" local eq cone 10 1 local
done
