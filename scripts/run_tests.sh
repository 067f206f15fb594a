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

# A gtest binary its tree did not build shows up as one unlabelled "<name>_NOT_BUILT" test,
# which a labelled run (-L asan) skips silently: refuse it, naming the binary.
unbuilt() {
  local names
  names=$(cd "$1" && ctest -N | grep -o '[A-Za-z0-9_]*_NOT_BUILT' | sort -u)
  if [ -n "$names" ]; then
    echo "== $1: gtest binaries not built, so their tests would not run: ${names//_NOT_BUILT/}" >&2
    echo "   (build them: they belong to the tree's ltb_test_binaries target)" >&2
    return 1
  fi
}

t=$(now)
(cd "$BUILD" && LTB_TEST_SCALE=$SCALE ctest --output-on-failure -j "$JOBS")
REL_RC=$?
unbuilt "$BUILD" || REL_RC=1
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
  unbuilt "$BUILD_ASAN" || ASAN_RC=1
fi

echo "== make test phases: release tests ${REL_S} s (exit $REL_RC); sanitizer build ${ASAN_BUILD_S} s" \
     "(exit $ASAN_BUILD_RC; ${WAIT_S} s waited after the release tests); sanitizer tests ${ASAN_S} s (exit $ASAN_RC);" \
     "total $(( $(now) - T0 )) s"
rm -rf "$LOGS"
[ "$REL_RC" -eq 0 ] && [ "$ASAN_BUILD_RC" -eq 0 ] && [ "$ASAN_RC" -eq 0 ]
