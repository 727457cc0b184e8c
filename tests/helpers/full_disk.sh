#!/usr/bin/env bash
# Every program writing to a full disk (a 64 KiB tmpfs) prints one
# error line saying why ("No space left on device"), keeps the old output, leaves no
# temporary, and shuts MPI down cleanly (no SIGSEGV in MPI_Finalize); crowd_snapshots runs
# at 2 ranks. Needs root for `mount -t tmpfs`; skipped (exit 77) otherwise.
#   full_disk.sh BINDIR MPIEXEC STUDY_NML
set -u
bin=$1; mpiexec=$2; study=$3
work=$(mktemp -d "${TMPDIR:-/tmp}/full_disk.XXXXXX")
disk=$work/disk
mkdir -p "$disk"
cleanup() { umount "$disk" 2>/dev/null; rm -rf "$work"; }
trap cleanup EXIT
if ! mount -t tmpfs -o size=64k tmpfs "$disk" 2>/dev/null; then
  echo "skipped: cannot mount a small tmpfs (needs root)"; exit 77
fi
cd "$work" || exit 1
pass=0; fail=0
# products on the normal disk: database, ROM file
sed "s#database = 'snap_tiny.h5'#database = 'db.h5'#" "$study" > study.nml
{ cat study.nml; echo "&offline database = 'db.h5', rom_file = 'rom.h5' /"; echo "&pod energy = 0.0 /"; echo "&pairs n = 3, r = 3 /"; } > offline.nml
"$mpiexec" -np 2 --oversubscribe "$bin/crowd_snapshots" study.nml > prep.log 2>&1 &&
  "$bin/crowd_offline" offline.nml >> prep.log 2>&1 || { echo "FAIL: preparing the products"; tail -20 prep.log; exit 1; }
# check NAME OUTPUT command...: the command writes OUTPUT on the full disk (crowd_snapshots
# refuses any existing file under its database name, so its OUTPUT is a marker elsewhere)
check() {
  local name=$1 out=$2; shift 2
  echo "precious" > "$out"
  local log rc why=""
  log=$(timeout 300 "$@" 2>&1); rc=$?
  [ $rc -ne 0 ] || why="exit status 0 on a full disk"
  [ -z "$why" ] && [ $rc -ge 128 ] && why="killed by a signal (exit status $rc)"
  [ -z "$why" ] && grep -qiE "SIGSEGV|segmentation|backtrace|signal 11" <<<"$log" && why="a crash trace"
  [ -z "$why" ] && [ "$(grep -c '^error:' <<<"$log")" -ne 1 ] && why="not exactly one error line"
  [ -z "$why" ] && ! grep -q '^error: .*No space left on device' <<<"$log" && why="the error does not say why"
  [ -z "$why" ] && [ "$(cat "$out")" != "precious" ] && why="the old output was modified"
  [ -z "$why" ] && ls "$disk" | grep -q partial && why="a temporary was left: $(ls "$disk")"
  if [ -n "$why" ]; then echo "FAIL: $name: $why"; echo "$log" | tail -15; fail=$((fail + 1))
  else echo "ok: $name: $(grep '^error:' <<<"$log")"; pass=$((pass + 1)); fi
  rm -rf "$disk"/*
}
sed "s#^  log_level = 'info'#  log_level = 'info', file = '$disk/fom.h5'#" study.nml | grep -v '^&study' | sed '/^  n_params/,/^\//d' > fom.nml
check crowd_fom "$disk/fom.h5" "$bin/crowd_fom" fom.nml
sed "s#database = 'db.h5'#database = '$disk/db2.h5'#" study.nml > study2.nml
check crowd_snapshots_np2 "$work/marker" "$mpiexec" -np 2 --oversubscribe "$bin/crowd_snapshots" study2.nml
sed "s#rom_file = 'rom.h5'#rom_file = '$disk/rom2.h5'#" offline.nml > offline2.nml
check crowd_offline "$disk/rom2.h5" "$bin/crowd_offline" offline2.nml
printf "%s\n" "&rom rom_file = 'rom.h5', output = '$disk/run.h5', table = 'run.csv', timing_repeats = 1 /" "&sweep n = 3, r = 3 /" "&fom_timing samples = 1 /" > rom.nml
check crowd_rom "$disk/run.h5" "$bin/crowd_rom" rom.nml
# the table on the full disk, the run file elsewhere: the run file must not be replaced
printf "%s\n" "&rom rom_file = 'rom.h5', output = 'run.h5', table = '$disk/run.csv', timing_repeats = 1 /" "&sweep n = 3, r = 3 /" "&fom_timing samples = 1 /" > rom_table.nml
dd if=/dev/zero of="$disk/fill" bs=4k 2>/dev/null   # the table is small: fill the disk first
check crowd_rom_table "run.h5" "$bin/crowd_rom" rom_table.nml
# a disk that fills in the middle of the writing: a longer run (crowd_fom), and a study at 2
# ranks whose pieces (one per sample) fill it while its database is being written
umount "$disk" && mount -t tmpfs -o size=512k tmpfs "$disk" || exit 1
sed 's/n_steps = 10/n_steps = 3000/' fom.nml > fom_long.nml
check crowd_fom_midway "$disk/fom.h5" "$bin/crowd_fom" fom_long.nml
umount "$disk" && mount -t tmpfs -o size=1400k tmpfs "$disk" || exit 1
sed 's/n_steps = 10/n_steps = 200/' study2.nml > study3.nml
check crowd_snapshots_np2_assembly "$work/marker" "$mpiexec" -np 2 --oversubscribe "$bin/crowd_snapshots" study3.nml --batch-seconds 0
# a read-only file system: refused before any work (exit 2), saying why
umount "$disk" && mount -t tmpfs -o ro,size=64k tmpfs "$disk" || exit 1
for p in crowd_fom crowd_offline; do
  nml=fom.nml; [ $p = crowd_offline ] && nml=offline2.nml
  log=$("$bin/$p" $nml 2>&1); rc=$?
  if [ $rc -eq 2 ] && grep -q "^error: .*Read-only file system" <<<"$log" && [ "$(grep -c '^error:' <<<"$log")" -eq 1 ]; then
    echo "ok: ${p}_read_only: $(grep '^error:' <<<"$log")"; pass=$((pass + 1))
  else
    echo "FAIL: ${p}_read_only: exit $rc"; echo "$log" | tail -5; fail=$((fail + 1))
  fi
done
echo "$pass passed, $fail failed"
[ $fail -eq 0 ]
