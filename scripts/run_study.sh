#!/usr/bin/env bash
# The whole parametric study on one case: set up (packages, venv, Release build), snapshots on
# 2 ranks, offline bases on 2 ranks, the online ROM sweep, the ML correction, all figures, and
# the accuracy/speed table.
#   scripts/run_study.sh [CASE]        (default: hall20)
# CASE: hall20, congested150, crowd1000 (the paper's two studies and the 1 000-agent hall), or the
# evacuation scenes congested150_evac, hetero1000 (docs/scenes.md)
# Inputs: inputs/<case>_study.nml (&study + &offline), inputs/<case>_rom.nml (&rom),
# inputs/<case>_ml.json (ML settings); for the evacuation cases also inputs/<case>_questions.json
# and inputs/<case>_models.json (stage 7, the answers with a stated error, docs/answers.md). Results in results/: <case>_snapshots.h5, <case>_rom.h5,
# <case>_romrun.h5, <case>_table.csv, <case>_ml.h5, figures in results/<case>_figures/
# (evacuation figures and table of scripts/post/evac_figures.py in results/<case>_figures/evac/);
# evacuation cases: results/<case>_answers.md / .json / .png.
# A complete snapshot database of the same configuration is reused (crowd_snapshots resumes).
# Environment: NP (ranks, 2), CROWDROM_BIN (programs; default build/bin after scripts/setup.sh;
# given: no setup), CROWDROM_WORK (folder holding inputs/ and results/; default the repository).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
CASE=${1:-hall20}
CASES="hall20, congested150, congested150_evac, crowd1000, crowd1000_calibrated, hetero1000"
NP=${NP:-2}
if [ -z "${CROWDROM_BIN:-}" ]; then "$ROOT/scripts/setup.sh"; fi
BIN=${CROWDROM_BIN:-$ROOT/build/bin}
cd "${CROWDROM_WORK:-$ROOT}"
for f in "inputs/${CASE}_study.nml" "inputs/${CASE}_rom.nml" "inputs/${CASE}_ml.json"; do
  [ -f "$f" ] || { echo "run_study: error: $f not found (cases: $CASES)" >&2; exit 2; }
done
mkdir -p results
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
if [ "$(id -u)" -eq 0 ]; then export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1; fi
export OMPI_MCA_rmaps_base_oversubscribe=${OMPI_MCA_rmaps_base_oversubscribe:-1}
PY=$ROOT/.venv/bin/python
SCRIPTS=$ROOT/scripts
t0=$(date +%s)
stage() { echo; echo "=== run_study [$CASE] stage $1 of 7: $2 (elapsed $(( $(date +%s) - t0 )) s)"; }

stage 1 "snapshots (mpirun -np $NP crowd_snapshots)"
mpirun -np "$NP" "$BIN/crowd_snapshots" "inputs/${CASE}_study.nml" --summary "results/${CASE}_snapshots.json"
stage 2 "offline bases (mpirun -np $NP crowd_offline)"
mpirun -np "$NP" "$BIN/crowd_offline" "inputs/${CASE}_study.nml" --summary "results/${CASE}_offline.json"
stage 3 "online reduced model sweep (crowd_rom)"
"$BIN/crowd_rom" "inputs/${CASE}_rom.nml" --summary "results/${CASE}_rom.json"
# the ML correction uses the setting given in the ML file's "_setting" key (default: the first
# uncorrected 'eq' / 'cone' setting with the largest N among those run on both sets)
SETTING=$($PY - "$CASE" <<'PYEOF'
import csv, json, sys
case = sys.argv[1]
cfg = json.load(open("inputs/%s_ml.json" % case))
if "_setting" in cfg:
    print(cfg["_setting"]); sys.exit()
table = list(csv.DictReader(open("results/%s_table.csv" % case)))
# the ML correction learns on the training set: a setting run on the validation set only
# (&sweep sets(k) = 'valid') cannot be corrected
trained = {r["setting"] for r in table if r["set"] == "train"}
rows = [r for r in table if r["set"] == "valid" and r["setting"] in trained
        and r["hyper"] == "eq" and r["contacts"] == "cone" and r.get("correction", "none") == "none"]
# a setting with diverged reduced trajectories cannot be corrected (on either set)
bad = {r["setting"] for r in csv.DictReader(open("results/%s_table.csv" % case))
       if int(r.get("samples_diverged", "0")) > 0}
rows = [r for r in rows if r["setting"] not in bad]
if not rows:
    sys.exit("run_study: error: no 'eq' / 'cone' setting without diverged samples for the ML correction "
             "(set \"_setting\" in inputs/%s_ml.json)" % case)
best = max(rows, key=lambda r: (int(r["n"]), -int(r["setting"])))
print(best["setting"])
PYEOF
)
stage 4 "ML correction (scripts/pipeline/ml_correct.py, setting $SETTING)"
$PY "$SCRIPTS/pipeline/ml_correct.py" "results/${CASE}_romrun.h5" --setting "$SETTING" --config "inputs/${CASE}_ml.json" \
  -o "results/${CASE}_ml.h5" --models-dir "results/${CASE}_ml_models" --csv "results/${CASE}_ml.csv"
stage 5 "figures (scripts/post/make_figures.py)"
$PY "$SCRIPTS/post/make_figures.py" --database "results/${CASE}_snapshots.h5" --rom "results/${CASE}_rom.h5" \
  --romrun "results/${CASE}_romrun.h5" --csv "results/${CASE}_table.csv" --ml "results/${CASE}_ml.h5" \
  --setting "$SETTING" -o "results/${CASE}_figures"
$PY "$SCRIPTS/post/evac_figures.py" --database "results/${CASE}_snapshots.h5" --romrun "results/${CASE}_romrun.h5" \
  --csv "results/${CASE}_table.csv" --ml "results/${CASE}_ml.h5" -o "results/${CASE}_figures/evac"
stage 6 "accuracy / cost table and the cheapest setting without overlap per error level (scripts/post/study_table.py)"
$PY "$SCRIPTS/post/study_table.py" "results/${CASE}_table.csv" --ml "results/${CASE}_ml.csv" \
  -o "results/${CASE}_study_table.md" --csv "results/${CASE}_cheapest.csv" --rows-csv "results/${CASE}_study_rows.csv"
if [ -f "inputs/${CASE}_questions.json" ] && [ -f "inputs/${CASE}_models.json" ]; then
  stage 7 "answers with a stated error (scripts/pipeline/crowd_answers.py; budget from inputs/${CASE}_models.json)"
  $PY "$SCRIPTS/pipeline/crowd_answers.py" "inputs/${CASE}_questions.json" --models "inputs/${CASE}_models.json" \
    --program "$BIN/crowd_predict" --cache "results/${CASE}_answers_cache" --out-prefix "results/${CASE}_answers"
else
  echo; echo "=== run_study [$CASE] stage 7 of 7: skipped (no inputs/${CASE}_questions.json and _models.json: not an evacuation case)"
fi
echo
echo "run_study [$CASE]: done in $(( $(date +%s) - t0 )) s; table results/${CASE}_table.csv, ML results/${CASE}_ml.csv, figures results/${CASE}_figures/"
