#!/usr/bin/env bash
# A command must be refused: exit status 2, exactly one `error:` line matching REGEX, no crash
# trace, and no file created or changed in the working directory (the command runs in a scratch
# copy of the directory given by --in DIR, default an empty one).
#   expect_refusal.sh [--in DIR] REGEX command args...
set -u
src=""
if [ "$1" = "--in" ]; then src=$2; shift 2; fi
regex=$1; shift
work=$(mktemp -d "${TMPDIR:-/tmp}/refusal.XXXXXX")
trap 'chmod -R u+w "$work" 2>/dev/null; rm -rf "$work"' EXIT
if [ -n "$src" ]; then cp -a "$src"/. "$work"/; fi
cd "$work" || exit 1
snap() { find . -path ./.snap -prune -o -print0 | sort -z | xargs -0 -r stat -c '%n %s %Y %F' 2>/dev/null; }
before=$(snap)
log=$("$@" 2>&1); rc=$?
after=$(snap)
fail() { echo "FAIL: $1"; echo "$log" | head -30; echo "0 passed, 1 failed"; exit 1; }
[ $rc -eq 2 ] || fail "exit status $rc (expected 2)"
n=$(grep -c '^error:' <<<"$log")
[ "$n" -eq 1 ] || fail "$n error lines (expected exactly 1)"
grep -qE "^error: .*($regex)" <<<"$log" || fail "the error line does not match /$regex/"
if grep -qiE "backtrace|signal|segmentation|Traceback" <<<"$log"; then fail "a crash trace"; fi
[ "$before" = "$after" ] || fail "files changed: $(diff <(echo "$before") <(echo "$after") | grep '^[<>]' | tr '\n' ' ')"
echo "ok: $(grep '^error:' <<<"$log")"
echo "1 passed, 0 failed"
