#!/usr/bin/env bash
# Load-independent cost of the exact projection (not a test): instructions executed inside
# sparse_as_solve over a crowd_fom run, counted by valgrind's callgrind, per time step, beside
# the solver's own counters from the run's summary.
#   scripts/bench/count_instructions.sh [--fom BIN] [--steps N] INPUT.nml [TAG]
# INPUT.nml is any crowd_fom input (its &output file is redirected to a scratch directory);
# prints one line: TAG, instructions/step, iterations/step, factorisations/step, factor row
# updates/step, largest scaled KKT residual, failed steps, fallbacks.
# Needs valgrind (Debian package `valgrind`, installed by scripts/setup.sh).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
fom="$ROOT/build/bin/crowd_fom"; steps=""
while [ $# -gt 0 ]; do
  case "$1" in
    --fom) fom=$2; shift 2 ;;
    --steps) steps=$2; shift 2 ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) break ;;
  esac
done
[ $# -ge 1 ] || { echo "error: count_instructions.sh: no input file given" >&2; exit 2; }
input=$1; tag=${2:-$(basename "$input" .nml)}
[ -r "$input" ] || { echo "error: count_instructions.sh: cannot read input file '$input'" >&2; exit 2; }
[ -x "$fom" ] || { echo "error: count_instructions.sh: no crowd_fom at '$fom' (build first)" >&2; exit 2; }
command -v valgrind >/dev/null || { echo "error: count_instructions.sh: valgrind not found (apt-get install valgrind)" >&2; exit 2; }
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
# the run's own output goes to the scratch directory; n_steps overridden when asked
sed -E "s#(file *= *)'[^']*'#\1'$work/out.h5'#" "$input" > "$work/in.nml"
if [ -n "$steps" ]; then sed -i -E "s/(n_steps *= *)[0-9]+/\1$steps/" "$work/in.nml"; fi
valgrind --tool=callgrind --callgrind-out-file="$work/cg.out" \
  --toggle-collect='__cr_sparse_as_MOD_sparse_as_solve' "$fom" "$work/in.nml" --summary "$work/s.json" \
  > "$work/log" 2>&1 || { echo "error: count_instructions.sh: crowd_fom failed:"; tail -5 "$work/log"; exit 1; } >&2
ir=$(callgrind_annotate "$work/cg.out" 2>/dev/null | awk '/PROGRAM TOTALS/ {gsub(",", "", $1); print $1}')
python3 - "$work/s.json" "$ir" "$tag" <<'P'
import json, sys
d = json.load(open(sys.argv[1])); ir = float(sys.argv[2]); n = d["steps"]
print("%s  instructions/step %.3f M  iterations %.1f  factorisations %.2f  row updates %.1f  "
      "largest KKT %.1e  failed %d  fallbacks %d" % (sys.argv[3], ir / n / 1e6, d["iterations_mean"],
      d["factorizations_per_step"], d["factor_updates_per_step"], d["largest_kkt_residual"],
      d["failed_steps"], d["fallback_solves"]))
P
