#!/usr/bin/env bash
# Careless use: a program given an input holding none of the groups it needs (empty, whitespace
# only, binary, HDF5, JSON, CSV, plain text, another program's input) stops with exit 2 and
# exactly one `error:` line naming the file and what is missing, and writes nothing.
#   foreign_input.sh PROGRAM [OTHER_PROGRAMS_INPUT ...]
set -u
prog=$1; shift
work=$(mktemp -d "${TMPDIR:-/tmp}/foreign_input.XXXXXX")
trap 'rm -rf "$work"' EXIT
cd "$work" || exit 1
mkdir family
: > family/empty.nml
printf '   \n\t\n\n        \n' > family/blank.nml
cp "$prog" family/binary.nml
{ printf '\211HDF\r\n\032\n'; head -c 2048 /dev/zero; } > family/hdf5.h5
printf '{"program": "crowd_fom", "scene": {"hall_length": 1.3}, "agents": 20}\n' > family/summary.json
printf 'setting,n,r,E_avg\n1,4,3,0.01\n2,6,4,0.005\n' > family/table.csv
printf 'This is a note, not a namelist.\nscene = hall, agents = 20\n' > family/notes.txt
k=0
for f in "$@"; do k=$((k + 1)); cp "$f" "family/other$k-$(basename "$f")"; done
pass=0; fail=0
for f in family/*; do
  name=$(basename "$f")
  before=$(ls -A)
  log=$("$prog" "$f" --summary out.json 2>&1); rc=$?
  after=$(ls -A)
  why=""
  [ $rc -eq 2 ] || why="exit status $rc (expected 2)"
  nerr=$(grep -c '^error:' <<<"$log")
  [ -z "$why" ] && [ "$nerr" -ne 1 ] && why="$nerr error lines (expected 1)"
  line=$(grep '^error:' <<<"$log" | head -1)
  if [ -z "$why" ] && ! grep -qE "^error: .*family/$name: (namelist groups? .*(is|are) missing|not a namelist file)" <<<"$line"; then
    why="the error line does not name the file and what is missing"
  fi
  [ -z "$why" ] && [ "$before" != "$after" ] && why="files were written: $(comm -13 <(echo "$before") <(echo "$after") | tr '\n' ' ')"
  if [ -z "$why" ] && grep -qiE "backtrace|SIGSEGV|Program received signal" <<<"$log"; then why="a crash trace"; fi
  if [ -n "$why" ]; then
    echo "FAIL: $name: $why"; echo "$log" | head -20; fail=$((fail + 1))
  else
    echo "ok: $name: $line"; pass=$((pass + 1))
  fi
done
echo "$pass passed, $fail failed"
[ $fail -eq 0 ]
