#!/usr/bin/env bash
# Bad-input check: the command must exit non-zero, print a one-line error matching REGEX,
# create neither OUTPUT nor OUTPUT.partial nor the JSON summary, and leave an existing
# OUTPUT untouched.
#   expect_fail.sh REGEX OUTPUT command args...
set -u
regex=$1; out=$2; shift 2
rm -f "$out" "$out.partial" "$out.json"
# first run: nothing may be created
log=$("$@" --summary "$out.json" 2>&1); rc=$?
if [ $rc -eq 0 ]; then echo "FAIL: exit status 0 for bad input"; echo "$log"; exit 1; fi
if ! grep -qE "^error: .*($regex)" <<<"$log"; then
  echo "FAIL: no 'error:' line matching /$regex/ in:"; echo "$log"; exit 1
fi
nerr=$(grep -c '^error:' <<<"$log")
if [ "$nerr" -ne 1 ]; then echo "FAIL: expected exactly one error line, got $nerr"; echo "$log"; exit 1; fi
for f in "$out" "$out.partial" "$out.json"; do
  if [ -e "$f" ]; then echo "FAIL: bad input created $f"; exit 1; fi
done
# second run: an existing result must survive
echo "precious result" > "$out"
"$@" >/dev/null 2>&1
if [ "$(cat "$out")" != "precious result" ]; then echo "FAIL: existing $out was modified"; exit 1; fi
rm -f "$out"
echo "ok: exit $rc, message: $(grep '^error:' <<<"$log")"
echo "1 passed, 0 failed"
