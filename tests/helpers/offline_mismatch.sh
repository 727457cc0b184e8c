#!/usr/bin/env bash
# crowd_offline refuses a study namelist that contradicts the database it reads (the
# stored effective configuration and config_hash), naming each variable that differs; the
# study's own namelist is accepted. A generated family of one-variable changes.
#   offline_mismatch.sh BINDIR STUDY_NML
set -u
bin=$1; study=$2
. "$(dirname "$0")/family_lib.sh"
case_dir prepare
sed "s#database = 'snap_tiny.h5'#database = 'db.h5'#" "$study" > study.nml
"$bin/crowd_snapshots" study.nml > snap.log 2>&1 || { echo "FAIL: crowd_snapshots"; tail -5 snap.log; exit 1; }
db=$PWD/db.h5
offline="&offline database = '$db', rom_file = 'rom.h5' / &pod energy = 0.0 / &pairs n = 3, r = 3 /"
# change NAME SED-EXPRESSION REGEX: the study file edited by SED-EXPRESSION must be refused
change() {
  case_dir "$1"
  { sed "s#database = 'snap_tiny.h5'#database = 'db.h5'#; $2" "$study"; echo "$offline"; } > in.nml
  if cmp -s <(sed "s#database = 'snap_tiny.h5'#database = 'db.h5'#" "$study") <(sed '$d' in.nml); then
    echo "FAIL: $1: the edit '$2' changed nothing"; fail=$((fail + 1)); return
  fi
  refused "$1" "database '.*db.h5' was made with another configuration than this input \\(.*$3" \
    "$bin/crowd_offline" in.nml
}
change hall_length 's/hall_length = 0.6/hall_length = 2.0/' "&scene hall_length: database 5.99.*E-01, input 2.0"
change hall_width 's/hall_width = 0.5/hall_width = 0.55/' "&scene hall_width"
change wall 's/wall_thickness = 0.05/wall_thickness = 0.06/' "&scene wall_thickness"
change disk_r 's/disk_r = 0.05/disk_r = 0.04/' "&obstacles disk_r\\(1\\)"
change n_agents 's/n_agents = 8/n_agents = 7/' "&agents n_agents: database 8, input 7"
change radius 's/radius = 0.04/radius = 0.041/' "&agents radius"
change agent_seed 's/speed = 1.0, seed = 3/speed = 1.0, seed = 4/' "&agents seed: database 3, input 4"
change dt 's/dt = 0.02/dt = 0.021/' "&time dt"
change n_steps 's/n_steps = 10/n_steps = 11/' "&time n_steps: database 10, input 11"
change solver 's/^&time/\&solver tol = 1e-9 \/\n\&time/' "&solver tol"
change n_train 's/n_train = 6/n_train = 5/' "&study n_train: database 6, input 5"
change study_seed 's/seed = 7/seed = 8/' "&study seed: database 7, input 8"
change param_max 's/param_max = 0.22/param_max = 0.23/' "&study param_max"
# the study's own file (with &output changed, which is not compared) passes the check
case_dir own
{ sed "s#database = 'snap_tiny.h5'#database = 'db.h5'#; s/log_level = 'info'/log_level = 'warn'/" "$study"; echo "$offline"; } > in.nml
if log=$("$bin/crowd_offline" in.nml 2>&1) && [ -f rom.h5 ]; then echo "ok: own study accepted"; pass=$((pass + 1))
else echo "FAIL: own study refused"; echo "$log" | grep error; fail=$((fail + 1)); fi
finish
