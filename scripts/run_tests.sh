#!/usr/bin/env bash
# make test's runner (tests/README.md). The release tree's tests spend much of their time
# waiting on child processes, disks and daemons, so the sanitizer tree builds meanwhile;
# then the sanitizer tier runs. Prints the wall time of each phase; exits non-zero if any
# phase failed (every phase runs regardless, so one run reports every failure).
#
#   bash scripts/run_tests.sh BUILD BUILD_ASAN JOBS TEST_SCALE "ASAN_BUILD_COMMAND"
set -uo pipefail

BUILD=${1:?usage: run_tests.sh BUILD BUILD_ASAN JOBS TEST_SCALE ASAN_BUILD_COMMAND}
BUILD_ASAN=${2:?}
JOBS=${3:?}
SCALE=${4:?}
ASAN_BUILD=${5:?}

LOGS=$(mktemp -d /tmp/ltbake-test-logs.XXXXXX)
now() { date +%s; }
T0=$(now)

# The sanitizer tree builds in the background; its output goes to a log shown at the end
# (interleaved with the tests' output it would be unreadable).
( t=$(now); eval "$ASAN_BUILD" >"$LOGS/asan-build.log" 2>&1; rc=$?
  echo "$rc $(( $(now) - t ))" >"$LOGS/asan-build.rc" ) &
ASAN_PID=$!

t=$(now)
(cd "$BUILD" && LTB_TEST_SCALE=$SCALE ctest --output-on-failure -j "$JOBS")
REL_RC=$?
REL_S=$(( $(now) - t ))

t=$(now)
wait "$ASAN_PID"
read -r ASAN_BUILD_RC ASAN_BUILD_S <"$LOGS/asan-build.rc"
WAIT_S=$(( $(now) - t ))
echo "== sanitizer tree build (ran alongside the release tests): exit $ASAN_BUILD_RC, ${ASAN_BUILD_S} s; log:"
if [ "$ASAN_BUILD_RC" -ne 0 ]; then cat "$LOGS/asan-build.log"; else tail -n 3 "$LOGS/asan-build.log"; fi

ASAN_RC=1
ASAN_S=0
if [ "$ASAN_BUILD_RC" -eq 0 ]; then
  t=$(now)
  (cd "$BUILD_ASAN" && LTB_TEST_SCALE=$SCALE ctest --output-on-failure -j "$JOBS" -L asan)
  ASAN_RC=$?
  ASAN_S=$(( $(now) - t ))
fi

echo "== make test phases: release tests ${REL_S} s (exit $REL_RC); sanitizer build ${ASAN_BUILD_S} s" \
     "(exit $ASAN_BUILD_RC; ${WAIT_S} s waited after the release tests); sanitizer tests ${ASAN_S} s (exit $ASAN_RC);" \
     "total $(( $(now) - T0 )) s"
rm -rf "$LOGS"
[ "$REL_RC" -eq 0 ] && [ "$ASAN_BUILD_RC" -eq 0 ] && [ "$ASAN_RC" -eq 0 ]
