#!/usr/bin/env bash
# Set up (packages, venv, Release build), run the full-order model on a scene and draw it.
#   scripts/run_fom.sh [inputs/hall20.nml]
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/setup.sh"
cd "$ROOT"
INPUT=${1:-inputs/hall20.nml}
name=$(basename "$INPUT" .nml)
mkdir -p results
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
build/bin/crowd_fom "$INPUT" --summary "results/${name}_fom.json"
out=$(.venv/bin/python -c "import json,sys; print(json.load(open(sys.argv[1]))['output_file'])" "results/${name}_fom.json")
.venv/bin/python scripts/post/plot_scene.py "$out" -o "results/${name}_fom.png"
echo "picture: results/${name}_fom.png"
