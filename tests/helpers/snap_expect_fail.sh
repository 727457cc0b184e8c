#!/usr/bin/env bash
# expect_fail.sh for crowd_snapshots: also checks that no pieces directory is created.
#   snap_expect_fail.sh REGEX DATABASE command args...
here=$(dirname "$0")
rm -rf "$2.pieces"
bash "$here/expect_fail.sh" "$@" || exit 1
if [ -e "$2.pieces" ]; then echo "FAIL: bad input created $2.pieces"; exit 1; fi
