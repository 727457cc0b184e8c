#!/usr/bin/env bash
# crowd_project and its request file: a request it cannot open (empty, truncated, random bytes,
# superblock zeroed, text, a folder, an empty argument, a namelist, missing, another product) and
# a request whose parameters give no valid scene (an exit wider than the hall, a negative exit)
# are refused with one line and exit 2, no crash trace, nothing written; a good request runs.
#   project_requests.sh BIN_DIR INPUT PYTHON      (INPUT: tests/inputs/snap_tiny.nml)
set -u
bin=$1; input=$2; py=$3
. "$(dirname "$0")/family_lib.sh"
exe="$bin/crowd_project"
base="$family_root/base"
mkdir -p "$base"; cd "$base" || exit 1
cp "$input" study.nml
"$bin/crowd_snapshots" study.nml > snapshots.log 2>&1 || { cat snapshots.log; echo "FAIL: crowd_snapshots"; exit 1; }
# request(NAME, L_EXIT): the first validation sample's positions and parameters (l_exit replaced
# when given), two configurations; output next to the request
"$py" - "$base" <<'PY' || { echo "FAIL: writing the requests"; exit 1; }
import os, sys
import h5py
import numpy as np
base = sys.argv[1]
db = os.path.join(base, "snap_tiny.h5")
with h5py.File(db, "r") as f:
    n_dof = 2 * int(f.attrs["n_agents"][()])
    nt = int(f.attrs["n_steps"][()])
    q = f["valid/positions"][: nt + 1][[0, nt]]
    p = f["valid/params"][0:1]
for name, l_exit in (("good", None), ("wide_exit", 5.0), ("negative_exit", -0.1)):
    pp = p.copy()
    if l_exit is not None:
        pp[0, 0] = l_exit
    with h5py.File(os.path.join(base, name + ".h5"), "w") as f:
        a = f.attrs
        a["schema"], a["schema_version"] = np.bytes_("crowdrom-projreq"), np.int32(1)
        a["database"], a["output"] = np.bytes_(db), np.bytes_("result.h5")
        a["solver"], a["tol"] = np.bytes_(""), 0.0
        a["n_agents"], a["configs_per_sample"] = np.int32(n_dof // 2), np.int32(2)
        f["positions"], f["params"] = q, pp
PY
# the good request runs (so that the refusals below are not of a broken set-up)
case_dir good; cp "$base/good.h5" req.h5
if "$exe" req.h5 > log.txt 2>&1 && [ -f result.h5 ]; then echo "ok: good request projected"; pass=$((pass + 1))
else echo "FAIL: good request"; cat log.txt; fail=$((fail + 1)); fi
open_err="cannot open the projection request|is not a projection request"
case_dir empty; : > req.h5
refused empty "$open_err" "$exe" req.h5
case_dir truncated; head -c 1500 "$base/good.h5" > req.h5
refused truncated "$open_err" "$exe" req.h5
case_dir random; head -c 4096 /dev/urandom > req.h5
refused random "$open_err" "$exe" req.h5
case_dir superblock; cp "$base/good.h5" req.h5; dd if=/dev/zero of=req.h5 bs=512 count=1 conv=notrunc 2>/dev/null
refused superblock_zeroed "$open_err" "$exe" req.h5
case_dir text; printf 'a projection request, in words\n' > req.h5
refused text "$open_err" "$exe" req.h5
case_dir folder; mkdir req.h5
refused folder "$open_err|is a directory" "$exe" req.h5
case_dir empty_argument
refused empty_argument "no input file|cannot open|empty" "$exe" ""
case_dir namelist; cp "$input" req.h5
refused namelist "$open_err" "$exe" req.h5
case_dir missing
refused missing "$open_err|not found|does not exist" "$exe" req.h5
case_dir other_product
refused database_as_request "is not a projection request" "$exe" "$base/snap_tiny.h5"
case_dir wide_exit; cp "$base/wide_exit.h5" req.h5
refused wide_exit "dataset 'params': sample 1 gives no valid scene: .*l_exit" "$exe" req.h5
case_dir negative_exit; cp "$base/negative_exit.h5" req.h5
refused negative_exit "dataset 'params': sample 1 gives no valid scene: .*l_exit" "$exe" req.h5
finish
