#!/usr/bin/env bash
# Checks of crowd_snapshots (registered in tests/regression/snapshots.cmake). Runs in its own directory.
#   snap_check.sh ranks NP BIN INPUT            run at NP ranks; NP > 1: compare with snap_np1/
#   snap_check.sh stop_resume BIN INPUT         --stop-after 4 at 2 ranks, resume at 3 ranks, compare
#   snap_check.sh kill_resume BIN INPUT         SIGKILL a running mpirun, resume, compare
#   snap_check.sh mismatch BIN INPUT OTHER      OTHER (another configuration) must refuse INPUT's database
#   snap_check.sh corrupt BIN INPUT PYTHON      corrupted pieces (bytes over velocities / lambda_value,
#                                               velocities * 1.001, a piece copied under another
#                                               sample's name, empty, truncated, NaN) are refused by
#                                               name; then
#                                               --quarantine-bad-pieces moves them aside and recomputes
# The database name is &study database = 'snap_tiny.h5' (snap_kill.h5 for kill_resume).
# Snapshots are compared bitwise with h5diff (data and attributes), except the per-sample
# wall time and rank (stats/time, stats/rank).
set -u
MPIRUN=${MPIEXEC:-mpiexec}
fail() { echo "FAIL: $*"; exit 1; }
same_db() {  # same_db A B
  h5diff --exclude-path /train/stats/time --exclude-path /train/stats/rank --exclude-path /train/stats/start \
         --exclude-path /valid/stats/time --exclude-path /valid/stats/rank --exclude-path /valid/stats/start \
         "$1" "$2" > h5diff.log 2>&1
  local rc=$?
  [ $rc -eq 0 ] || { head -30 h5diff.log; fail "$1 and $2 differ (h5diff status $rc)"; }
  h5dump -a /complete "$1" | grep -q "(0): 1" || fail "$1 is not marked complete"
}
samples_in_pieces() {  # number of samples held by the complete pieces in directory $1
  local f n=0 m
  for f in "$1"/*.h5; do
    [ -e "$f" ] || continue
    m=$(h5dump -a /n_samples "$f" 2>/dev/null | awk '/\(0\):/ {print $2}')
    n=$((n + ${m:-0}))
  done
  echo $n
}
mode=$1; shift
case $mode in
ranks)
  np=$1; bin=$2; input=$3
  dir=snap_np$np; rm -rf "$dir"; mkdir -p "$dir"; cd "$dir" || exit 1
  # np 1 and 2: batched pieces (default time slice); np 4: one sample per piece
  batch=""; [ "$np" = 4 ] && batch="--batch-seconds 0"
  "$MPIRUN" -np "$np" --oversubscribe "$bin" "$input" $batch --summary summary.json > log.txt 2>&1 || { cat log.txt; fail "run at $np ranks"; }
  [ -f snap_tiny.h5 ] || fail "no database"
  [ ! -e snap_tiny.h5.pieces ] || fail "pieces left behind after a complete run"
  grep -q '"samples_per_rank"' summary.json || fail "summary JSON incomplete"
  if [ "$np" != 1 ]; then same_db snap_tiny.h5 ../snap_np1/snap_tiny.h5; fi
  # a second run finds the complete database and does nothing
  "$MPIRUN" -np "$np" --oversubscribe "$bin" "$input" > log2.txt 2>&1 || { cat log2.txt; fail "rerun on a complete database"; }
  grep -q "already complete" log2.txt || fail "rerun did not recognise the complete database"
  ;;
stop_resume)
  bin=$1; input=$2
  rm -rf stop_resume; mkdir stop_resume; cd stop_resume || exit 1
  "$MPIRUN" -np 2 --oversubscribe "$bin" "$input" --stop-after 4 --batch-seconds 0 > log1.txt 2>&1; rc=$?
  [ $rc -eq 3 ] || { cat log1.txt; fail "--stop-after 4: exit status $rc, expected 3"; }
  [ ! -e snap_tiny.h5 ] || fail "an interrupted run left a database under the final name"
  [ ! -e snap_tiny.h5.partial ] || fail "a stopped run left its partial database behind"
  n=$(ls snap_tiny.h5.pieces/*.h5 2>/dev/null | wc -l)
  [ "$n" -eq 4 ] || fail "expected 4 complete pieces, found $n"
  "$MPIRUN" -np 3 --oversubscribe "$bin" "$input" --summary s.json > log2.txt 2>&1 || { cat log2.txt; fail "resume"; }
  grep -q '"samples_resumed": 4' s.json || { cat s.json; fail "the resumed run did not reuse the 4 pieces"; }
  same_db snap_tiny.h5 ../snap_np1/snap_tiny.h5
  # batched pieces (all samples of a rank in one piece): stop, resume at another rank count
  rm -rf b && mkdir b && cd b || exit 1
  "$MPIRUN" -np 2 --oversubscribe "$bin" "$input" --stop-after 5 --batch-seconds 1000 > log1.txt 2>&1; rc=$?
  [ $rc -eq 3 ] || { cat log1.txt; fail "batched --stop-after 5: exit status $rc, expected 3"; }
  n=$(ls snap_tiny.h5.pieces/*.h5 2>/dev/null | wc -l); m=$(samples_in_pieces snap_tiny.h5.pieces)
  [ "$m" -eq 5 ] && [ "$n" -le 2 ] || fail "batched: expected 5 samples in at most 2 pieces, found $m in $n"
  "$MPIRUN" -np 1 "$bin" "$input" --summary s.json > log2.txt 2>&1 || { cat log2.txt; fail "batched resume"; }
  grep -q '"samples_resumed": 5' s.json || { cat s.json; fail "the resumed run did not reuse the 5 batched samples"; }
  same_db snap_tiny.h5 ../../snap_np1/snap_tiny.h5
  ;;
kill_resume)
  bin=$1; input=$2
  rm -rf kill_resume; mkdir kill_resume; cd kill_resume || exit 1
  mkdir ref && (cd ref && "$MPIRUN" -np 1 "$bin" "$input" > log.txt 2>&1) || fail "reference run"
  # batched pieces of 0.05 s (a few samples each)
  setsid "$MPIRUN" -np 2 --oversubscribe "$bin" "$input" --batch-seconds 0.05 > log1.txt 2>&1 &
  pid=$!
  for i in $(seq 1 600); do
    n=$(ls snap_kill.h5.pieces/*.h5 2>/dev/null | wc -l)
    [ "$n" -ge 3 ] && break
    sleep 0.02
  done
  # like a batch system ending a job: SIGKILL mpirun and every process of its login group (sid; Open MPI
  # puts the ranks in their own process groups, so killing mpirun's group alone leaves them running)
  sid=$(ps -o sid= -p $pid | tr -d ' ')
  [ -n "$sid" ] || fail "mpirun ended before it could be killed (make the study longer)"
  pids=$(ps -eo pid=,sid= | awk -v s="$sid" '$2 == s {print $1}')
  kill -KILL $pids 2>/dev/null
  wait $pid 2>/dev/null
  for i in $(seq 1 50); do
    left=$(ps -eo pid=,sid= | awk -v s="$sid" '$2 == s {print $1}')
    [ -z "$left" ] && break
    sleep 0.1
  done
  [ -z "$left" ] || fail "processes of the killed run survive: $left"
  [ ! -e snap_kill.h5 ] || fail "the killed run left a database under the final name (or finished before the kill)"
  # the database is written as the samples come: the killed run leaves a partial one, which the
  # resumed run must replace, not trust
  [ -e snap_kill.h5.partial ] || echo "note: no partial database left by the killed run"
  p=$(ls snap_kill.h5.pieces/*.h5 2>/dev/null | wc -l)
  n=$(samples_in_pieces snap_kill.h5.pieces)
  echo "killed with $p complete pieces holding $n samples"
  "$MPIRUN" -np 2 --oversubscribe "$bin" "$input" --summary s.json > log2.txt 2>&1 || { cat log2.txt; fail "resume after SIGKILL"; }
  grep -q "\"samples_resumed\": $n" s.json || { cat s.json; fail "resume did not reuse the $n samples of the $p pieces"; }
  same_db snap_kill.h5 ref/snap_kill.h5
  [ ! -e snap_kill.h5.pieces ] || { ls -la snap_kill.h5.pieces; fail "pieces (or temporaries) left after the resumed run"; }
  [ ! -e snap_kill.h5.partial ] || fail "the partial database of the killed run survives the resumed run"
  ;;
mismatch)
  bin=$1; input=$2; other=$3
  rm -rf mismatch; mkdir mismatch; cd mismatch || exit 1
  cp ../snap_np1/snap_tiny.h5 . || fail "no reference database"
  cp snap_tiny.h5 before.h5
  out=$("$MPIRUN" -np 2 --oversubscribe "$bin" "$other" --summary s.json 2>&1); rc=$?
  [ $rc -ne 0 ] || fail "a database of another configuration was accepted"
  grep -qE "^error: database 'snap_tiny.h5' was written for a different configuration" <<<"$out" || { echo "$out"; fail "message"; }
  cmp -s snap_tiny.h5 before.h5 || fail "the existing database was modified"
  [ ! -e snap_tiny.h5.pieces ] && [ ! -e s.json ] || fail "a refused run created files"
  # pieces of another configuration are refused too
  rm snap_tiny.h5; mkdir snap_tiny.h5.pieces
  (mkdir p && cd p && "$MPIRUN" -np 1 "$bin" "$input" --stop-after 1 > /dev/null 2>&1; cp snap_tiny.h5.pieces/*.h5 ../snap_tiny.h5.pieces/)
  out=$("$MPIRUN" -np 1 "$bin" "$other" 2>&1); rc=$?
  [ $rc -ne 0 ] || fail "pieces of another configuration were accepted"
  grep -qE "^error: .*holds pieces of a different configuration" <<<"$out" || { echo "$out"; fail "message (pieces)"; }
  ;;
corrupt)
  bin=$1; input=$2; py=$3
  here=$(cd "$(dirname "$0")" && pwd)
  rm -rf corrupt; mkdir corrupt; cd corrupt || exit 1
  "$MPIRUN" -np 2 --oversubscribe "$bin" "$input" --stop-after 6 --batch-seconds 0 > log0.txt 2>&1; rc=$?
  [ $rc -eq 3 ] || { cat log0.txt; fail "--stop-after 6: exit status $rc, expected 3"; }
  cp -r snap_tiny.h5.pieces pristine
  P=snap_tiny.h5.pieces
  # a piece with stored multipliers, for the lambda_value case
  lam=$("$py" -c "
import h5py, glob, sys
for p in sorted(glob.glob('$P/*.h5')):
    with h5py.File(p) as f:
        if f['lambda_value'].size > 0:
            print(p); sys.exit(0)
sys.exit(1)") || fail "no piece with multipliers to corrupt"
  expect_refused() {  # expect_refused CASE REGEX [NP]: the run fails with status 2 and names the piece
    out=$("$MPIRUN" -np "${3:-2}" --oversubscribe "$bin" "$input" 2>&1); rc=$?
    [ $rc -eq 2 ] || { echo "$out"; fail "$1: exit status $rc, expected 2"; }
    grep -qE "$2" <<<"$out" || { echo "$out"; fail "$1: message"; }
    grep -q "quarantine-bad-pieces" <<<"$out" || { echo "$out"; fail "$1: no hint at --quarantine-bad-pieces"; }
    [ ! -e snap_tiny.h5 ] || fail "$1: a database was written"
    [ ! -e snap_tiny.h5.partial ] || fail "$1: a partial database was left behind"
    rm -rf $P; cp -r pristine $P
  }
  "$py" "$here/snap_corrupt.py" bytes $P/train_000002.h5 velocities || fail "corrupt (bytes)"
  expect_refused bytes_velocities "piece '$P/train_000002.h5' \\(train sample 2\\): checksum mismatch in dataset 'velocities'"
  "$py" "$here/snap_corrupt.py" bytes "$lam" lambda_value || fail "corrupt (bytes, lambda)"
  expect_refused bytes_lambda "piece '$lam' \\(train sample [0-9]+\\): checksum mismatch in dataset 'lambda_value'"
  "$py" "$here/snap_corrupt.py" scale $P/train_000004.h5 velocities || fail "corrupt (scale)"
  expect_refused scaled "piece '$P/train_000004.h5' \\(train sample 4\\): checksum mismatch in dataset 'velocities'"
  cp $P/train_000003.h5 $P/train_000005.h5
  expect_refused renamed "piece '$P/train_000005.h5' holds train sample 3 where train sample 5 belongs"
  : > $P/train_000003.h5
  expect_refused empty "piece '$P/train_000003.h5'.*not an HDF5 file \\(unreadable or incomplete piece\\)"
  head -c 2000 pristine/train_000003.h5 > $P/train_000003.h5
  expect_refused truncated "piece '$P/train_000003.h5'.*\\(unreadable or incomplete piece\\)"
  "$py" "$here/snap_corrupt.py" nan $P/train_000006.h5 velocities || fail "corrupt (nan)"
  expect_refused nan "piece '$P/train_000006.h5' \\(train sample 6\\): dataset 'velocities' holds a non-finite value"
  # contact indices out of range (or inconsistent) with the checksums re-stamped: only the
  # range checks can catch them, at 1 and 2 ranks
  for np_ in 1 2; do
    "$py" "$here/snap_corrupt.py" shift "$lam" lambda_ia 100 || fail "corrupt (shift ia)"
    expect_refused shifted_ia_np$np_ "piece '$lam' \\(train sample [0-9]+\\): dataset 'lambda_ia': index [0-9]+ outside 1\\.\\.8" $np_
    "$py" "$here/snap_corrupt.py" shift "$lam" lambda_ib 100 || fail "corrupt (shift ib)"
    expect_refused shifted_ib_np$np_ "piece '$lam' .*dataset 'lambda_ib': index [0-9]+ outside 0\\.\\.8" $np_
    "$py" "$here/snap_corrupt.py" shift "$lam" lambda_ob -1000 || fail "corrupt (shift ob)"
    expect_refused shifted_ob_np$np_ "piece '$lam' .*dataset 'lambda_ob': index -[0-9]+ negative" $np_
    "$py" "$here/snap_corrupt.py" shift "$lam" lambda_key 1 || fail "corrupt (shift key)"
    expect_refused shifted_key_np$np_ "piece '$lam' .*dataset 'lambda_key': not the key of" $np_
  done
  # several bad pieces at once, all named; --quarantine-bad-pieces moves them aside and the run
  # recomputes them: the database equals the uninterrupted one
  "$py" "$here/snap_corrupt.py" nan $P/train_000006.h5 velocities || fail "corrupt (nan)"
  cp $P/train_000003.h5 $P/train_000005.h5
  out=$("$MPIRUN" -np 2 --oversubscribe "$bin" "$input" 2>&1); rc=$?
  [ $rc -eq 2 ] && grep -q "2 bad piece(s)" <<<"$out" && grep -q "train_000005.h5" <<<"$out" && \
    grep -q "train_000006.h5" <<<"$out" || { echo "$out"; fail "two bad pieces not both named"; }
  "$MPIRUN" -np 2 --oversubscribe "$bin" "$input" --quarantine-bad-pieces --summary s.json > log1.txt 2>&1 || \
    { cat log1.txt; fail "run with --quarantine-bad-pieces"; }
  grep -q "moved bad piece" log1.txt || { cat log1.txt; fail "no report of the moved pieces"; }
  [ -f $P/quarantine/train_000005.h5 ] && [ -f $P/quarantine/train_000006.h5 ] || fail "bad pieces not kept in quarantine"
  grep -q '"samples_resumed": 4' s.json || { cat s.json; fail "the 4 good pieces were not reused"; }
  same_db snap_tiny.h5 ../snap_np1/snap_tiny.h5
  ;;
*) fail "unknown mode $mode" ;;
esac
echo "1 passed, 0 failed"
