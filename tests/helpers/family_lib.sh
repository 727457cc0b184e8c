# Shared by the generated bad-input families (sourced): run one case in its own scratch
# directory and require exit status 2, exactly one `error:` line matching a regex, no crash
# trace, and no file created or changed (the directory is compared before and after).
#   refused NAME REGEX command args...   (run inside the case directory, see case_dir)
pass=0; fail=0
family_root=$(mktemp -d "${TMPDIR:-/tmp}/family.XXXXXX")
trap 'rm -rf "$family_root"' EXIT
case_dir() { d="$family_root/$1"; mkdir -p "$d"; cd "$d" || exit 1; }
snapshot() { find . -print0 | sort -z | xargs -0 -r stat -c '%n %s %Y %F' 2>/dev/null; }
refused() {
  local name=$1 regex=$2; shift 2
  local before after log rc why="" n
  before=$(snapshot)
  log=$(timeout 120 "$@" 2>&1); rc=$?
  after=$(snapshot)
  [ $rc -eq 2 ] || why="exit status $rc (expected 2)"
  n=$(grep -c '^error:' <<<"$log")
  [ -z "$why" ] && [ "$n" -ne 1 ] && why="$n error lines (expected 1)"
  [ -z "$why" ] && ! grep -qE "^error: .*($regex)" <<<"$log" && why="no error line matching /$regex/"
  [ -z "$why" ] && grep -qiE "backtrace|signal|segmentation|traceback" <<<"$log" && why="a crash trace"
  [ -z "$why" ] && [ "$before" != "$after" ] && why="files changed: $(diff <(echo "$before") <(echo "$after") | grep '^[<>]' | tr '\n' ' ')"
  if [ -n "$why" ]; then
    echo "FAIL: $name: $why"; echo "$log" | head -15; fail=$((fail + 1))
  else
    echo "ok: $name: $(grep '^error:' <<<"$log")"; pass=$((pass + 1))
  fi
}
finish() { echo "$pass passed, $fail failed"; [ $fail -eq 0 ]; }
