#!/usr/bin/env bash
# Valgrind memcheck over the test programs of the Debug build: finds reads of uninitialised
# memory (e.g. a workspace array read before it is written) that the Debug flags cannot see
# (-finit-real=snan does not cover allocatable arrays, whose bytes are whatever malloc returns).
# A tool, not part of scripts/test.sh (about 5 min for the unit tests with -j 2 on this machine).
#   scripts/dev/memcheck.sh [-L LABEL_REGEX] [-R NAME_REGEX] [-j N]
#   scripts/dev/memcheck.sh --wrap DIR
# Defaults: -L '^unit$' (the unit tests; '^(unit|regression|extremes)$' adds the programs of the
# other labels). Test commands that run a program of build-debug/tests are
# taken, directly or through mpiexec with at most MEMCHECK_NP ranks (default 1: the MPI tests'
# 1-rank runs, one valgrind per rank), not script-driven tests. Builds build-debug first (Debug).
# Each program runs under `valgrind --tool=memcheck --track-origins=yes` with Open MPI's
# suppressions and scripts/dev/memcheck.supp, XML logs in build-debug/memcheck/;
# scripts/dev/memcheck_report.py then prints every error whose stack reaches our code (src/,
# drivers/, tests/) before the MPI stack, with the origin of the undefined value.
# Exit status: non-zero if a test failed under valgrind or an error was found in our code.
# --wrap DIR: write to DIR one wrapper per program of build-debug/bin that runs it under
# memcheck (logs in build-debug/memcheck/wrap/), for the pipelines: e.g.
#   scripts/dev/memcheck.sh --wrap /tmp/vbin && CROWDROM_BIN=/tmp/vbin scripts/run_study.sh hall20
#   CROWDROM_BIN=/tmp/vbin .venv/bin/python -m pytest scripts/tests/test_crowd1000_mini.py
#   python3 scripts/dev/memcheck_report.py . build-debug/memcheck/wrap/*.xml
# (mpirun then starts one valgrind per rank.) Valgrind sees memory never written since malloc;
# a read of a stale but defined value (left by an earlier call) is for tests/test_stale_workspace.
# Environment: MEMCHECK_TIMEOUT (seconds per program, 1800), MEMCHECK_NP (1), VALGRIND_OPTS.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
BUILD=$ROOT/build-debug
LABEL='^unit$'; NAME=''; JOBS=1; WRAP=''
while [ $# -gt 0 ]; do
  case $1 in
    -L) LABEL=$2; shift 2 ;;
    -R) NAME=$2; shift 2 ;;
    -j) JOBS=$2; shift 2 ;;
    --wrap) WRAP=$2; shift 2 ;;
    -h|--help) sed -n '2,26p' "$0"; exit 0 ;;
    *) echo "memcheck: unknown argument '$1' (use -L, -R, -j, --wrap)" >&2; exit 2 ;;
  esac
done
command -v valgrind >/dev/null || { echo "memcheck: valgrind not found (apt-get install valgrind)" >&2; exit 2; }

if [ ! -f "$BUILD/build.ninja" ]; then
  cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Debug >/dev/null
fi
cmake --build "$BUILD" -j "$(nproc)" >/dev/null

LOGS=$BUILD/memcheck
SUPP=()
for f in /usr/share/openmpi/openmpi-valgrind.supp "$ROOT/scripts/dev/memcheck.supp"; do
  [ -f "$f" ] && SUPP+=("--suppressions=$f")
done
VG=(valgrind --tool=memcheck --track-origins=yes --leak-check=no --errors-for-leak-kinds=none --num-callers=30 "${SUPP[@]}")

if [ -n "$WRAP" ]; then
  mkdir -p "$WRAP" "$LOGS/wrap"
  WRAP=$(cd "$WRAP" && pwd)
  for prog in "$BUILD"/bin/*; do
    name=$(basename "$prog")
    printf '#!/usr/bin/env bash\n# %s under valgrind memcheck (scripts/dev/memcheck.sh --wrap)\nexec %s ${VALGRIND_OPTS:-} --xml=yes --xml-file=%q "%s" "$@"\n' \
      "$name" "${VG[*]}" "$LOGS/wrap/$name.%p.xml" "$prog" > "$WRAP/$name"
    chmod +x "$WRAP/$name"
  done
  echo "memcheck: wrappers in $WRAP (logs in $LOGS/wrap/); afterwards:"
  echo "  python3 $ROOT/scripts/dev/memcheck_report.py $ROOT $LOGS/wrap/*.xml"
  exit 0
fi
rm -rf "$LOGS"/*.xml "$LOGS"/*.out "$LOGS"/summary.txt "$LOGS"/tests.txt; mkdir -p "$LOGS"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1

# the test commands: "name<TAB>command" where the command runs a program of build-debug/tests/,
# directly or by mpiexec -n N with N <= MEMCHECK_NP
ctest_args=(-N -V -L "$LABEL")
[ -n "$NAME" ] && ctest_args+=(-R "$NAME")
mapfile -t TESTS < <(cd "$BUILD" && ctest "${ctest_args[@]}" | awk -v dir="$BUILD/tests/" -v maxnp="${MEMCHECK_NP:-1}" '
  /^[0-9]+: Test command: / { sub(/^[0-9]+: Test command: /, ""); cmd = $0; next }
  /^ *Test +#[0-9]+: / {
    name = $3; ok = index(cmd, dir) == 1
    if (!ok && index(cmd, dir) > 0 && cmd ~ /^[^ ]*mpiexec/ && match(cmd, /"-(n|np)" "[0-9]+"/)) {
      np = substr(cmd, RSTART, RLENGTH); gsub(/[^0-9]/, "", np); ok = np + 0 <= maxnp + 0
    }
    if (ok) print name "\t" cmd
    cmd = "" }')
[ ${#TESTS[@]} -gt 0 ] || { echo "memcheck: no serial test program matches -L '$LABEL' ${NAME:+-R '$NAME'}" >&2; exit 2; }

# run_one <name> <command>: the test under valgrind; prints "name rc seconds"
run_one() {
  local name=$1 cmd=$2 t0 rc=0
  t0=$(date +%s)
  # the command is ctest's, each word quoted: [mpiexec and its options] the program, its arguments
  eval "set -- $cmd"
  local pre=()
  while [ $# -gt 0 ] && [[ $1 != "$BUILD/tests/"* ]]; do pre+=("$1"); shift; done
  (cd "$BUILD/tests" && timeout "${MEMCHECK_TIMEOUT:-1800}" "${pre[@]}" "${VG[@]}" --error-exitcode=3 \
      ${VALGRIND_OPTS:-} --xml=yes --xml-file="$LOGS/$name.%p.xml" "$@" >"$LOGS/$name.out" 2>&1) || rc=$?
  echo "$name rc=$rc $(( $(date +%s) - t0 )) s"
}
echo "memcheck: ${#TESTS[@]} program(s), logs in $LOGS"
status=0
printf '%s\n' "${TESTS[@]}" > "$LOGS/tests.txt"
# one line per test: run them JOBS at a time
while IFS=$'\t' read -r name cmd; do
  while [ "$(jobs -rp | wc -l)" -ge "$JOBS" ]; do wait -n || true; done
  run_one "$name" "$cmd" </dev/null | tee -a "$LOGS/summary.txt" &
done < "$LOGS/tests.txt"
wait
if [ "$(wc -l < "$LOGS/summary.txt")" -ne ${#TESTS[@]} ]; then
  echo "memcheck: only $(wc -l < "$LOGS/summary.txt") of ${#TESTS[@]} programs ran"
  status=1
fi
# a test that failed under valgrind (rc 3 is valgrind's: errors, judged below by the report)
if grep -Ev ' rc=(0|3) ' "$LOGS/summary.txt"; then
  echo "memcheck: the test(s) above failed or timed out under valgrind"
  status=1
fi
python3 "$ROOT/scripts/dev/memcheck_report.py" "$ROOT" "$LOGS"/*.xml || status=1
exit "$status"
